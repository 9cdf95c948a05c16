"""What a picture says in words: the title and caption naming what was simulated and the
parameters that matter (:func:`describe`), and the readout of the step and the order beside
the box (:func:`time_text`).
"""

from __future__ import annotations

import numpy as np

from ..model import Model, ParameterError


def as_parameters(parameters) -> dict | None:
    """A run's parameters (``{"model": {...}, ...}``) from a :class:`~flocking.Model`, the
    parameters a trajectory stored, or a model's ``to_dict()``; ``None`` stays ``None``."""
    if parameters is None:
        return None
    if isinstance(parameters, Model):
        return {"model": parameters.to_dict()}
    if isinstance(parameters, dict):
        return parameters if "model" in parameters else {"model": dict(parameters)}
    raise ParameterError(f"parameters: must be a Model or a dict of parameters (got {type(parameters).__name__})")


def _g(value) -> str:
    return f"{value:.3g}" if isinstance(value, float) else str(value)


def describe(parameters, dim: int, n: int, box_lengths) -> tuple[str, str]:
    """Title and caption (mathtext): what was simulated, and the parameters that matter,
    joined by ``" \u00b7 "`` so :func:`.style.title` can wrap them. The caption starts
    with the density and the noise (its kind and amplitude), the two control parameters.

    >>> describe(Model(n=2048, box=32.0, noise=1.0), 2, 2048, (32.0, 32.0))[1].split(" \u00b7 ")[:3]
    ['$\\\\rho$ = 2', 'angular noise $\\\\eta$ = 1', '$v_0$ = 0.5']
    """
    sides = [float(x) for x in box_lengths]
    box = f"$L$ = {sides[0]:.4g}" if len(set(sides)) == 1 else "box " + " \u00d7 ".join(f"{x:.4g}" for x in sides)
    first = f"Vicsek model \u00b7 {dim}D \u00b7 $N$ = {n:,} \u00b7 {box}"
    parameters = as_parameters(parameters)
    if not parameters:
        return first, ""
    m = parameters["model"]
    density = fr"$\rho$ = {n / float(np.prod(sides[:dim])):.3g}"
    noise = f"{m.get('noise_type', 'angular')} noise " + fr"$\eta$ = {_g(m['noise'])}"
    near = (f"$k$ = {m['k']} nearest" if m.get("neighbours") == "topological" else f"$R$ = {_g(m['radius'])}")
    parts = [density, noise, f"$v_0$ = {_g(m['speed'])}", near]
    if m.get("speeds") == "uniform":
        parts.append("speeds uniform")
    if m.get("alignment", 1.0) != 1.0:
        parts.append(fr"$\varepsilon$ = {_g(m['alignment'])}")
    if m.get("delay", 0):
        parts.append(fr"delay $\tau$ = {m['delay']}")
    if m.get("dt", 1.0) != 1.0:
        parts.append(fr"$\Delta t$ = {_g(m['dt'])}")
    if m.get("update", "backward") != "backward":
        parts.append(f"{m['update']} update")
    parts += _extension_parts(m, dim)
    parts.append(f"seed {m.get('seed', 0)}")
    return first, " \u00b7 ".join(parts)


def _extension_parts(m: dict, dim: int) -> list[str]:
    """Caption parts of the extensions a model's dict has on (docs/model.md's symbols)."""
    parts = []
    boundary = str(m.get("boundary", "periodic")).split(",")
    boundary = boundary * dim if len(boundary) == 1 else boundary
    walled = [axis for axis, kind in zip("xyz", boundary) if kind == "wall"]
    if walled:
        parts.append("walls" if len(walled) == dim else "walls on " + " and ".join(f"${a}$" for a in walled))
    if m.get("obstacles"):
        count = len(m["obstacles"])
        parts.append(f"{count} obstacle{'s' * (count > 1)}")
    if len(m.get("species") or ()) > 1:
        symbols = {"speed": "$v_0$", "noise": r"$\eta$", "alignment": r"$\varepsilon$", "chirality": r"$\omega$",
                   "field_strength": "$h$"}

        def one(sp):
            own = [f"{symbol} = {_g(sp[key])}" for key, symbol in symbols.items() if sp.get(key) is not None]
            return str(sp.get("name", "?")) + (f" ({', '.join(own)})" if own else "")

        parts.append("species " + ", ".join(one(sp) for sp in m["species"]))
    if m.get("coupling") is not None:
        parts.append("coupled species")
    if m.get("vision") is not None and m["vision"] < np.pi:
        parts.append(fr"vision $\theta_v$ = {_g(m['vision'])}")
    if m.get("alignment_rule", "polar") != "polar":
        parts.append(f"{m['alignment_rule']} alignment")
    if m.get("chirality"):
        parts.append(fr"$\omega$ = {_g(m['chirality'])}")
    if m.get("field_strength"):
        parts.append(f"field $h$ = {_g(m['field_strength'])}")
    return parts


#: The readout names each species' polar order for up to this many species.
READOUT_SPECIES = 4


def readout_lines(types, dt: float = 1.0, nematic: bool = False) -> int:
    """How many lines :func:`time_text` writes for these species, ``dt`` and alignment."""
    return 2 + (dt != 1.0) + bool(nematic) + (len(types) if 1 < len(types) <= READOUT_SPECIES else 0)


def time_text(frame, dt: float = 1.0, nematic: bool = False) -> str:
    """The readout under a picture's key, a line each: the step (and the time if
    ``dt != 1``), the nematic order ``S`` (for a run with nematic alignment, whose
    polar order tells little), each species' polar order (with several, up to
    :data:`READOUT_SPECIES`: species that move apart can each be ordered when the whole
    flock is not) and the polar order."""
    from ..analysis.order import mathtext_text, nematic_order

    lines = [f"step {frame.step:,}"]
    if dt != 1.0:
        lines.append(f"$t$ = {frame.step * dt:,.6g}")
    if nematic:
        lines.append(f"$S$ = {nematic_order(frame.headings):.3f}")
    if 1 < len(frame.types) <= READOUT_SPECIES:
        headings = frame.headings
        for s, name in enumerate(frame.types):
            mine = headings[frame.typeid == s]
            phi = float(np.linalg.norm(mine.sum(axis=0)) / len(mine)) if len(mine) else float("nan")
            lines.append(fr"$\varphi_{{\mathrm{{{mathtext_text(name)}}}}}$ = {phi:.3f}")
    return "\n".join([*lines, fr"$\varphi$ = {frame.polar_order:.3f}"])

