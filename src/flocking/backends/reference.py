"""The reference backend: plain NumPy, O(N^2), written to be obviously right.

It follows the model description (docs/model.md) line by line, extensions included, and
is the oracle the fast backends are tested against. Use it for a few thousand particles
at most.

>>> from flocking import Model, State
>>> from flocking.backends.reference import ReferenceBackend
>>> model = Model(n=50, box=5.0, noise=0.0, seed=1)
>>> backend = ReferenceBackend(model, State.random(model))
>>> phi = backend.advance(3)
>>> phi.shape, backend.state.step
((3,), 3)
"""

from __future__ import annotations

import collections

import numpy as np

from .. import rng
from ..model import Model
from ..observables import moment_width
from ..state import State, frame_arrays, random_unit_vectors
from .reference_voronoi import voronoi_matrix


def minimum_image(displacement: np.ndarray, box: np.ndarray, walls=None) -> np.ndarray:
    """Fold displacements (coordinates in ``(-L, L)``) into ``[-L/2, L/2]``, axis by axis;
    axes with walls (``walls[a]`` true) are left as they are."""
    half = box / 2
    if walls is not None:
        half = np.where(walls, np.inf, half)
    return np.where(displacement > half, displacement - box,
                    np.where(displacement < -half, displacement + box, displacement))


def neighbour_matrix(model: Model, positions: np.ndarray, headings: np.ndarray | None = None) -> np.ndarray:
    """``A[i, j]`` is True when ``j`` is in the neighbourhood of ``i`` (``i`` included):
    within ``R``, among the ``k`` nearest, or a Voronoi neighbour
    (:mod:`flocking.backends.reference_voronoi`).

    With a vision cone (``model.vision < pi``), ``j`` must lie within ``vision`` of the
    heading ``headings[i]``: ``u_i . (r_j - r_i) >= |r_j - r_i| cos(vision)``.
    """
    box = np.asarray(model.box)
    disp = minimum_image(positions[None, :, :] - positions[:, None, :], box, np.asarray(model.walls))
    d2 = np.zeros(disp.shape[:2])
    for a in range(model.dim):
        d2 += disp[:, :, a] * disp[:, :, a]
    n = len(positions)
    seen = np.ones((n, n), dtype=bool)
    if model.vision < np.pi:
        dot = np.zeros(disp.shape[:2])
        for a in range(model.dim):
            dot += headings[:, None, a] * disp[:, :, a]
        seen = dot >= np.sqrt(d2) * np.cos(model.vision)
    if model.neighbours == "voronoi":  # the cells' own definition, by brute force
        a = voronoi_matrix(positions, box, model.walls) & seen
        np.fill_diagonal(a, True)
        return a
    if model.neighbours == "metric":
        a = (d2 < model.radius * model.radius) & seen
        np.fill_diagonal(a, True)
        return a
    others = np.where(seen, d2, np.inf)
    np.fill_diagonal(others, np.inf)
    # a stable sort keeps equal distances in index order: ties go to the lower index
    nearest = np.argsort(others, axis=1, kind="stable")[:, : min(model.k, n - 1)]
    a = np.zeros((n, n), dtype=bool)
    rows = np.arange(n)[:, None]
    a[rows, nearest] = np.isfinite(others[rows, nearest])  # fewer than k in sight: only those
    np.fill_diagonal(a, True)
    return a


def species_of(model: Model) -> np.ndarray:
    """The species index of every particle (blocks of ids)."""
    return np.repeat(np.arange(len(model.species_counts)), model.species_counts)


def per_particle(model: Model, name: str) -> np.ndarray:
    """A per-species parameter, one value per particle."""
    return np.asarray(model.species_values(name), dtype=np.float64)[species_of(model)]


def weights(model: Model, a: np.ndarray, headings: np.ndarray) -> np.ndarray:
    """``W[i, j] = J[s_i][s_j] c_ij`` for the neighbours ``j != i`` in ``a``, 0 elsewhere:
    ``c_ij`` is 1 (polar) or the sign of ``u_i . u_j`` with sign(0) = 1 (nematic)."""
    w = a.astype(np.float64)
    np.fill_diagonal(w, 0.0)
    if model.coupling is not None:
        s = species_of(model)
        w *= np.asarray(model.coupling)[s[:, None], s[None, :]]
    if model.alignment_rule == "nematic":
        w *= np.where(headings @ headings.T >= 0.0, 1.0, -1.0)
    return w


def cohesion(model: Model, a: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gregoire and Chate's attraction-repulsion among the neighbours ``a`` (docs/model.md,
    Cohesion): per particle the pull ``sum_j f(r_ij) e_ij`` over the neighbours at
    ``r_ij >= r_c``, the push ``-sum_j e_ij`` over those inside the hard core
    ``0 < r_ij < r_c``, and how many those are; ``e_ij`` is the unit vector from ``i`` to
    ``j`` (minimum image), ``f(r) = (r - r_e) / (4 (r_a - r_e))`` below ``r_a`` and 1 beyond."""
    rc, re, ra = model.cohesion_radii
    disp = minimum_image(positions[None, :, :] - positions[:, None, :], np.asarray(model.box), np.asarray(model.walls))
    r = np.sqrt(np.sum(disp * disp, axis=2))
    others = a.copy()
    np.fill_diagonal(others, False)
    with np.errstate(divide="ignore", invalid="ignore"):
        e = np.where((r > 0)[..., None], disp / r[..., None], 0.0)
    core = others & (r > 0) & (r < rc)
    f = np.where(others & (r >= rc), np.where(r < ra, (r - re) / (4.0 * (ra - re)), 1.0), 0.0)
    pull = np.sum(f[..., None] * e, axis=1)
    push = -np.sum(np.where(core[..., None], e, 0.0), axis=1)
    return pull, push, core.sum(axis=1)


def align(u: np.ndarray, m: np.ndarray, epsilon: float) -> np.ndarray:
    """Rotate each ``u`` toward ``m`` by the fraction ``epsilon`` of the angle between them."""
    if epsilon == 1.0:
        return m
    c = np.sum(u * m, axis=1)
    if u.shape[1] == 2:
        s = u[:, 0] * m[:, 1] - u[:, 1] * m[:, 0]
        a = epsilon * np.arctan2(s, c)
        return rotate_2d(u, a)
    s = np.linalg.norm(np.cross(u, m), axis=1)
    alpha = np.arctan2(s, c)
    with np.errstate(divide="ignore", invalid="ignore"):
        w = (np.sin((1.0 - epsilon) * alpha)[:, None] * u + np.sin(epsilon * alpha)[:, None] * m) / s[:, None]
    degenerate = s < 1e-12  # parallel: already there; antiparallel: no plane, keep u
    w[degenerate] = np.where((c[degenerate] > 0)[:, None], m[degenerate], u[degenerate])
    return w


def rotate_2d(u: np.ndarray, angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([u[:, 0] * c - u[:, 1] * s, u[:, 0] * s + u[:, 1] * c], axis=1)


def angular_noise(w: np.ndarray, eta: float, z0: np.ndarray, z1: np.ndarray) -> np.ndarray:
    """Uniform on the arc (2D) or spherical cap (3D) of half-angle ``eta/2`` around ``w``."""
    if w.shape[1] == 2:
        return rotate_2d(w, eta * (z0 - 0.5))
    cos_b = 1.0 - z0 * (2.0 * np.sin(eta / 4.0) ** 2)  # 1 - cos(eta/2), accurate for small eta
    sin_b = np.sqrt(np.maximum(0.0, 1.0 - cos_b * cos_b))
    phi = 2.0 * np.pi * z1
    e1, e2 = perpendicular_frame(w)
    return cos_b[:, None] * w + sin_b[:, None] * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)


def perpendicular_frame(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing each unit ``w`` to a right-handed orthonormal frame."""
    a = np.zeros_like(w)
    use_x = np.abs(w[:, 0]) < 0.9
    a[use_x, 0] = 1.0
    a[~use_x, 1] = 1.0
    e1 = a - np.sum(a * w, axis=1)[:, None] * w
    e1 /= np.linalg.norm(e1, axis=1)[:, None]
    return e1, np.cross(w, e1)


def wrap(positions: np.ndarray, box: np.ndarray) -> np.ndarray:
    """Fold positions into ``[0, L)``."""
    x = positions - box * np.floor(positions / box)
    return np.where(x >= box, x - box, x)


def heading_update(model: Model, state: State, sums: np.ndarray, counts: np.ndarray,
                   core: np.ndarray | None = None) -> np.ndarray:
    """Steps 3 to 6 of the step, with the field and chirality: from the sums of headings
    ``S_i`` and their numbers of terms ``n_i`` to ``u_i(t+1)``; for the particles where
    ``core`` is true (a neighbour inside cohesion's hard core) neither the field nor
    vectorial noise is added."""
    ids = np.arange(state.n, dtype=np.uint64)
    z0 = rng.uniform(model.seed, state.step, ids, rng.NOISE)
    z1 = rng.uniform(model.seed, state.step, ids, rng.NOISE + 1)
    u = state.headings
    s = sums.copy()
    eta = model.noise if len(set(model.species_values("noise"))) == 1 else per_particle(model, "noise")
    h = per_particle(model, "field_strength")
    if core is not None:
        h = np.where(core, 0.0, h)
        if model.noise_type == "vectorial":
            eta = np.where(core, 0.0, eta)
    if h.any():
        s += (h * counts)[:, None] * np.asarray(model.field_direction)[None, :]
    if model.noise_type == "vectorial":
        s += (eta * counts)[:, None] * random_unit_vectors(model.dim, z0, z1)
    norm = np.linalg.norm(s, axis=1)
    m = np.where((norm > 0)[:, None], s / np.where(norm > 0, norm, 1.0)[:, None], u)
    epsilon = model.species_values("alignment")
    if len(set(epsilon)) == 1:
        w = align(u, m, epsilon[0])
    else:
        w = np.empty_like(u)
        eps = per_particle(model, "alignment")
        for e in set(epsilon):
            pick = eps == e
            w[pick] = align(u[pick], m[pick], e)
    omega = per_particle(model, "chirality") * model.dt
    if omega.any():
        w = rotate_2d(w, omega)
    if model.noise_type == "angular":
        w = angular_noise(w, eta, z0, z1)
    return w / np.linalg.norm(w, axis=1)[:, None]


def bounce(model: Model, positions: np.ndarray, headings: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """After a move: fold positions across walls, turning headings back into the box, then
    push particles out of obstacles (each in the listed order) to their mirror points,
    turning the headings that point inward; periodic axes are wrapped."""
    box = np.asarray(model.box)
    walls = np.asarray(model.walls)
    x, u = positions.copy(), headings.copy()
    for a in np.flatnonzero(walls):
        low, high = x[:, a] < 0.0, x[:, a] > box[a]
        x[low, a] = -x[low, a]
        u[low, a] = np.abs(u[low, a])
        x[high, a] = 2.0 * box[a] - x[high, a]
        u[high, a] = -np.abs(u[high, a])
    for ob in model.obstacles:
        c = np.asarray(ob.centre)
        r = minimum_image(x - c, box, walls)
        dist = np.sqrt(np.sum(r * r, axis=1))
        hit = dist < ob.radius
        if not hit.any():
            continue
        normal = np.where((dist[hit] > 0)[:, None], r[hit] / np.where(dist[hit] > 0, dist[hit], 1.0)[:, None],
                          -u[hit])
        x[hit] = c + (2.0 * ob.radius - dist[hit])[:, None] * normal
        x[hit] = np.where(walls, x[hit], wrap(x[hit], box))
        dot = np.sum(u[hit] * normal, axis=1)
        inward = dot < 0.0
        uh = u[hit]
        uh[inward] = uh[inward] - 2.0 * dot[inward, None] * normal[inward]
        u[hit] = uh
    return x, u


class ReferenceBackend:
    """Plain NumPy implementation of one step; the oracle of the other backends."""

    name = "reference"

    @staticmethod
    def bytes_needed(model: Model) -> int:
        """Peak memory of a step: the dense (N, N, d) displacements and their companions."""
        return model.n * model.n * (8 * model.dim + 24) + model.n * model.dim * 8 * (model.delay + 4)

    def __init__(self, model: Model, state: State, memory: dict | None = None):
        self.model = model
        self._state = state.copy()
        # the last `delay` states, oldest first; the initial state stands in for the past
        past = [self._state.copy()] * model.delay
        if memory and "positions" in memory:
            past = [State(p, h, state.speeds) for p, h in zip(memory["positions"], memory["headings"])]
        self._history = collections.deque(past, maxlen=max(model.delay, 1))

    def fields(self, grid) -> np.ndarray:
        """The sums ``(species, channel, bin)`` of :class:`flocking.fields.Grid` ``grid``, in NumPy."""
        from ..fields import bin_sums

        return bin_sums(grid, self._state)

    def memory(self) -> dict[str, np.ndarray]:
        """What the backend remembers beyond the state: the last ``delay`` states."""
        if not self.model.delay:
            return {}
        return {"positions": np.stack([s.positions for s in self._history]),
                "headings": np.stack([s.headings for s in self._history])}

    @property
    def state(self) -> State:
        return self._state.copy()

    def frame_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Centred positions and velocities, float32 ``(N, 3)`` in id order (a GSD frame's)."""
        return frame_arrays(self._state, self.model.box)

    @property
    def step(self) -> int:
        return self._state.step

    def advance(self, steps: int) -> np.ndarray:
        """Take ``steps`` steps; return the polar order after each (and keep the moment
        sums of each step in :attr:`moments`)."""
        phi = np.empty(steps)
        self.moments = np.empty((steps, moment_width(self.model)))
        for t in range(steps):
            self._step()
            phi[t] = self._state.polar_order()
            self.moments[t] = moments(self.model, self._state.headings)
        return phi

    def _step(self) -> None:
        model, now = self.model, self._state
        if model.delay == 0:
            seen = now
            a = neighbour_matrix(model, seen.positions, seen.headings)
        else:
            seen = self._history[0]  # the state tau steps ago
            a = neighbour_matrix(model, seen.positions, seen.headings)
            np.fill_diagonal(a, False)
        counts = a.sum(axis=1).astype(np.float64)
        if model.coupling is None and model.alignment_rule == "polar":
            sums = a.astype(np.float64) @ seen.headings
            if model.delay:
                sums += now.headings
        else:
            sums = now.headings + weights(model, a, seen.headings) @ seen.headings
        if model.delay:
            counts += 1.0
        core = None
        if model.cohesion:
            pull, push, inside = cohesion(model, a, seen.positions)
            core = inside > 0
            sums = np.where(core[:, None], push, sums + model.cohesion * pull)
        new = heading_update(model, now, sums, counts, core)
        moving = new if model.update == "backward" else now.headings
        box = np.asarray(model.box)
        positions = now.positions + (now.speeds * model.dt)[:, None] * moving
        if any(model.walls) or model.obstacles:
            positions = np.where(model.walls, positions, wrap(positions, box))
            positions, new = bounce(model, positions, new)
        else:
            positions = wrap(positions, box)
        if model.delay:
            self._history.append(now.copy())
        self._state = State(positions, new, now.speeds, now.step + 1)


def moments(model: Model, headings: np.ndarray) -> np.ndarray:
    """The moment sums of docs/model.md's observables, transcribed on their own: each
    species' summed heading, then for nematic alignment the summed tensor ``u u^T`` (2D: as
    the angles' ``cos 2 theta`` and ``sin 2 theta``; 3D: xx, yy, zz, xy, xz, yz)."""
    bounds = np.cumsum([0, *model.species_counts])[:-1]
    parts = [np.add.reduceat(headings, bounds, axis=0).ravel()]
    if model.alignment_rule == "nematic":
        if model.dim == 2:
            theta = np.arctan2(headings[:, 1], headings[:, 0])
            parts.append([np.cos(2.0 * theta).sum(), np.sin(2.0 * theta).sum()])
        else:
            q = np.einsum("ia,ib->ab", headings, headings)
            parts.append([q[0, 0], q[1, 1], q[2, 2], q[0, 1], q[0, 2], q[1, 2]])
    return np.concatenate(parts)
