"""Observables of a step and statistics of the polar order over a window.

Every step records the polar order ``phi = |sum_i u_i| / N``; a model with several species
also records each species' polar order (``polar_order_<name>``), and a model with nematic
alignment the nematic order (``nematic_order``: in 2D ``|sum_i exp(2 i theta_i)| / N``, in
3D the largest eigenvalue of ``Q = (3/2) <u u^T> - (1/2) I``). Backends hand these over as
*moment sums* (:func:`moment_sums`: per species the sum of headings, then the sums of the
nematic products), which :func:`extra_values` turns into the columns :func:`extra_names`.

>>> import numpy as np
>>> m = polar_moments(np.array([0.5, 0.5, 0.5]), n=100)
>>> m["mean"], m["susceptibility"], round(m["binder"], 6)
(0.5, 0.0, 0.666667)
>>> from flocking import Model
>>> model = Model(n=4, box=4.0, alignment_rule="nematic", species=[{"n": 2}, {"n": 2, "name": "B"}])
>>> extra_names(model)
('polar_order_A', 'polar_order_B', 'nematic_order')
>>> u = np.array([[1.0, 0.0], [1.0, 0.0], [-1.0, 0.0], [0.0, 1.0]])
>>> [round(float(x), 12) for x in extra_values(model, moment_sums(model, u))]
[1.0, 0.707106781187, 0.5]
"""

from __future__ import annotations

import numpy as np


def polar_moments(phi, n: int) -> dict[str, float]:
    """``<phi>``, ``<phi^2>``, ``<phi^4>``, ``chi = N (<phi^2> - <phi>^2)`` and
    ``G = 1 - <phi^4> / (3 <phi^2>^2)`` of a time series ``phi`` of ``n`` particles."""
    phi = np.asarray(phi, dtype=np.float64)
    if phi.size == 0:
        raise ValueError("polar_moments: the window holds no value")
    mean, m2, m4 = phi.mean(), np.mean(phi**2), np.mean(phi**4)
    binder = 1.0 - m4 / (3.0 * m2 * m2) if m2 > 0 else float("nan")
    return {"mean": float(mean), "phi2": float(m2), "phi4": float(m4),
            "susceptibility": float(n * (m2 - mean * mean)), "binder": float(binder)}


def extra_names(model) -> tuple[str, ...]:
    """The columns a step records beyond ``polar_order``, for ``model``."""
    names = tuple(f"polar_order_{name}" for name in model.species_names) if len(model.species) > 1 else ()
    return names + (("nematic_order",) if model.alignment_rule == "nematic" else ())


def moment_width(model) -> int:
    """Length of ``model``'s vector of moment sums (:func:`sums_width`)."""
    return sums_width(model.dim, len(model.species_counts), model.alignment_rule == "nematic")


def sums_width(dim: int, species: int, nematic: bool) -> int:
    """Length of a vector of moment sums, the layout :func:`moment_sums` writes and both
    backends' kernels fill: ``dim`` per species, then the nematic products (2 in 2D, 6 in
    3D) if the order recorded is nematic.

    >>> sums_width(2, 1, False), sums_width(3, 2, True)
    (2, 12)
    """
    return dim * species + ((2 if dim == 2 else 6) if nematic else 0)


def heading_total(sums: np.ndarray, dim: int, species: int) -> np.ndarray:
    """The sum of every heading, ``(..., dim)``, from moment sums ``(..., width)`` in the
    layout of :func:`sums_width`: the species' sums added in species order.

    >>> heading_total(np.array([1.0, 2.0, 3.0, 4.0, 0.5, 0.5]), 2, 2).tolist()
    [4.0, 6.0]
    """
    sums = np.asarray(sums)
    return sums[..., : dim * species].reshape(*sums.shape[:-1], species, dim).sum(axis=-2)


def moment_sums(model, headings: np.ndarray) -> np.ndarray:
    """The moment sums of unit ``headings`` (id order): per species ``sum u``, then
    ``sum (ux^2 - uy^2), sum 2 ux uy`` (2D) or ``sum u_a u_b`` for xx, yy, zz, xy, xz, yz (3D)."""
    parts, first = [], 0
    for count in model.species_counts:
        parts.append(headings[first : first + count].sum(axis=0))
        first += count
    if model.alignment_rule == "nematic":
        u = headings
        if model.dim == 2:
            parts.append(np.array([np.sum(u[:, 0] * u[:, 0] - u[:, 1] * u[:, 1]), np.sum(2.0 * u[:, 0] * u[:, 1])]))
        else:
            parts.append(np.array([np.sum(u[:, a] * u[:, b]) for a, b in _PAIRS]))
    return np.concatenate(parts) if parts else np.zeros(0)


_PAIRS = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


def extra_values(model, sums: np.ndarray) -> np.ndarray:
    """The :func:`extra_names` columns from moment sums ``(..., moment_width)``."""
    sums = np.asarray(sums, dtype=np.float64)
    d, counts = model.dim, model.species_counts
    out = []
    if len(model.species) > 1:
        for s, count in enumerate(counts):
            v = sums[..., s * d : (s + 1) * d]
            out.append(np.sqrt(np.sum(v * v, axis=-1)) / max(count, 1))
    if model.alignment_rule == "nematic":
        q = sums[..., d * len(counts):] / model.n
        if d == 2:
            out.append(np.hypot(q[..., 0], q[..., 1]))
        else:
            m = np.empty(q.shape[:-1] + (3, 3))
            for i, (a, b) in enumerate(_PAIRS):
                m[..., a, b] = m[..., b, a] = 1.5 * q[..., i]
            m -= 0.5 * np.eye(3)
            out.append(np.linalg.eigvalsh(m)[..., -1])
    return np.stack(out, axis=-1) if out else np.zeros(sums.shape[:-1] + (0,))


def extra_observables(model, headings: np.ndarray | None = None, moments: np.ndarray | None = None
                      ) -> dict[str, np.ndarray]:
    """The :func:`extra_names` columns by name, from the moment sums of some steps
    ``(steps, moment_width)`` or from one state's unit ``headings`` (id order).

    >>> from flocking import Model
    >>> m = Model(n=2, box=4.0, alignment_rule="nematic")
    >>> extra_observables(m, headings=np.array([[1.0, 0.0], [-1.0, 0.0]]))["nematic_order"].tolist()
    [1.0]
    """
    if moments is None:
        moments = moment_sums(model, headings)[None]
    values = extra_values(model, moments)
    return {name: values[..., i] for i, name in enumerate(extra_names(model))}
