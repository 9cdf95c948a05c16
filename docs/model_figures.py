"""Two explanatory figures for docs/extensions.md: the vision cone and chirality.

``vision``: a focal particle heading along +x, its interaction circle (R = 1) and its cone of
half-angle theta_v = 2.1 rad, among neighbours placed at random (a fixed seed). Each
neighbour is coloured by the rule of docs/extensions.md: seen (closer than R and within theta_v
of the heading), hidden by the cone (closer than R, behind) or out of range. Before
drawing, the script takes one step of the engine (the ``cpu`` and ``reference`` backends,
no noise) from that very state and checks that the focal particle's new heading is the mean
of its own and the seen neighbours' headings, and, without the cone (theta_v = pi), the mean
over every neighbour in range; it stops with an error if the engine disagrees.

``chirality``: isolated particles (one a run, so no neighbours) with v0 = 0.5, dt = 1 and
the turning rates omega = 0.1, 0.2 and -0.15 (clockwise), run by the engine and recorded
every step for one turn, over the circle of radius v0 dt / (2 sin(omega dt / 2)) that
docs/extensions.md predicts (checked to 1e-9 before drawing); and, beside them, one chiral
particle with angular noise eta = 0.3 wandering away from its circle.

    python docs/model_figures.py vision --out docs/model-vision.png --theme light --size column
    python docs/model_figures.py chirality --out docs/model-chirality.png --theme light --size column
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from flocking import Model, Simulation, State
from flocking.viz import style as house

#: The vision cone: interaction radius R and half-angle theta_v (rad), as in the docs' text.
RADIUS, VISION = 1.0, 2.1
#: Neighbours of the focal particle, drawn with the numpy seed SEED: INSIDE of them
#: uniformly in the ring from CLEAR to R around it, OUTSIDE in the ring from R to SPREAD;
#: none closer than GAP to the circle or to the cone's edges (half an arrow: each arrow
#: lies on its own side, and rounding cannot change a class), and none closer than
#: SPACING to another.
INSIDE, OUTSIDE, SEED = 18, 14, 4
CLEAR, SPREAD = 0.5, 1.6
GAP, SPACING = 0.1, 0.2
#: Where the labels theta_v (inside the cone) and R (beside its lower edge) go: no
#: neighbour is placed within SPACING of them.
THETA_LABEL = 0.42 * np.array([math.cos(VISION / 2), math.sin(VISION / 2)])
R_LABEL = 0.62 * RADIUS * np.array([math.cos(VISION), -math.sin(VISION)]) \
    + 0.11 * np.array([-math.sin(VISION), -math.cos(VISION)])
#: The classes of a neighbour, in the legend's order.
SEEN, HIDDEN, OUT = 0, 1, 2

#: Chirality: v0, dt, the turning rates of the noise-free panel, and the noisy particle's
#: (omega, eta, steps, seed).
SPEED, DT = 0.5, 1.0
OMEGAS = (0.1, 0.2, -0.15)
NOISY = (0.2, 0.3, 400, 1)
#: A periodic box far larger than any trajectory; each particle starts at its centre
#: heading along +y.
BOX = 100.0


# -- the vision cone ---------------------------------------------------------------------------


def place_neighbours(seed: int = SEED) -> tuple[np.ndarray, np.ndarray]:
    """Offsets ``(n, 2)`` from the focal particle and unit headings ``(n, 2)`` of the
    neighbours: :data:`INSIDE` uniform in the ring from :data:`CLEAR` to R,
    :data:`OUTSIDE` uniform in the ring from R to :data:`SPREAD`, away from every
    boundary of the classes (see :data:`GAP`) and from each other (:data:`SPACING`).

    >>> offsets, headings = place_neighbours()
    >>> offsets.shape, bool(np.allclose(np.linalg.norm(headings, axis=1), 1.0))
    ((32, 2), True)
    >>> int((np.linalg.norm(offsets, axis=1) < RADIUS).sum())
    18
    """
    rng = np.random.default_rng(seed)
    offsets: list[np.ndarray] = []
    for count, low, high in ((INSIDE, CLEAR, RADIUS), (OUTSIDE, RADIUS, SPREAD)):
        placed = 0
        while placed < count:
            r = math.sqrt(rng.uniform(low * low, high * high))
            phi = rng.uniform(-math.pi, math.pi)
            p = r * np.array([math.cos(phi), math.sin(phi)])
            if (abs(r - RADIUS) < GAP or abs(r * (abs(phi) - VISION)) < GAP
                    or any(np.linalg.norm(p - q) < SPACING for q in [*offsets, THETA_LABEL, R_LABEL])):
                continue
            offsets.append(p)
            placed += 1
    angles = rng.uniform(-math.pi, math.pi, len(offsets))
    return np.array(offsets), np.stack([np.cos(angles), np.sin(angles)], axis=1)


def classify(offsets: np.ndarray, heading: np.ndarray) -> np.ndarray:
    """:data:`SEEN`, :data:`HIDDEN` or :data:`OUT` for each offset ``r_j - r_i``, by the
    rule of docs/model.md: in range if ``|r_j - r_i| < R``, seen if also
    ``u_i . (r_j - r_i) >= |r_j - r_i| cos(theta_v)``.

    >>> classify(np.array([[0.5, 0.0], [-0.5, 0.0], [2.0, 0.0]]), np.array([1.0, 0.0])).tolist()
    [0, 1, 2]
    """
    distance = np.linalg.norm(offsets, axis=1)
    in_cone = offsets @ heading >= distance * math.cos(VISION)
    return np.where(distance < RADIUS, np.where(in_cone, SEEN, HIDDEN), OUT)


def check_engine(offsets: np.ndarray, headings: np.ndarray, classes: np.ndarray) -> None:
    """Take one noise-free step of the engine (``cpu`` and ``reference``) from the drawn
    state, focal particle first heading along +x: with the cone its new heading must be the
    normalised sum of its own and the :data:`SEEN` headings, without it (theta_v = pi) that
    of its own and every neighbour in range. Raises ``RuntimeError`` otherwise."""
    if set(classes.tolist()) != {SEEN, HIDDEN, OUT}:
        raise RuntimeError("vision: the drawn neighbours must include every class, or the check proves little")
    focal = np.array([1.0, 0.0])
    centre = np.full(2, BOX / 2)
    positions = np.vstack([centre, centre + offsets])
    all_headings = np.vstack([focal, headings])
    for vision, counted in ((VISION, classes == SEEN), (math.pi, classes != OUT)):
        model = Model(dim=2, n=len(positions), box=BOX, vision=vision, noise=0.0, radius=RADIUS, speed=SPEED)
        total = focal + headings[counted].sum(axis=0)
        expected = total / np.linalg.norm(total)
        for backend in ("cpu", "reference"):
            state = State(positions, all_headings, np.full(len(positions), SPEED))
            sim = Simulation(model, state, backend=backend)
            sim.run(1)
            got = sim.state.headings[0]
            if not np.allclose(got, expected, rtol=0.0, atol=1e-12):
                raise RuntimeError(f"vision: the {backend} backend with theta_v = {vision:.4g} turns the focal "
                                   f"particle to {got.tolist()}, the figure's classes to {expected.tolist()}")


def draw_vision(args) -> None:
    """The vision-cone figure, checked against the engine, written to ``args.out``."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Arc, Circle, Wedge

    offsets, headings = place_neighbours()
    classes = classify(offsets, np.array([1.0, 0.0]))
    check_engine(offsets, headings, classes)

    t = house.get_theme(args.theme)
    width, height, _ = house.resolve_size(args.size)
    # a round picture beside its legend: no taller than that pair is wide, or a third is blank
    fig, ax = house.figure((width, min(height, 0.7 * width)), t)
    scale = house.fontsize(fig) / 8.0  # line widths and marks grow with the text
    colors = {SEEN: house.palette(t)[0], HIDDEN: house.palette(t)[1], OUT: t.edge}
    degrees = math.degrees(VISION)
    ax.add_patch(Wedge((0, 0), RADIUS, -degrees, degrees, facecolor=colors[SEEN], alpha=0.16, lw=0))
    ax.add_patch(Wedge((0, 0), RADIUS, degrees, 360 - degrees, facecolor=t.edge, alpha=0.12, lw=0,
                       hatch="////", edgecolor=(*t.edge, 0.35)))
    ax.add_patch(Circle((0, 0), RADIUS, fill=False, edgecolor=t.text, lw=0.8 * scale, ls=(0, (4, 3))))
    for sign in (1, -1):  # the cone's edges
        ax.plot([0, RADIUS * math.cos(VISION)], [0, sign * RADIUS * math.sin(VISION)], color=colors[SEEN],
                lw=1.0 * scale)
    ax.plot([0, RADIUS], [0, 0], color=t.text, lw=0.6 * scale, ls=":")
    ax.add_patch(Arc((0, 0), 0.56, 0.56, theta1=0, theta2=degrees, color=t.text, lw=0.7 * scale))
    for where, text in ((THETA_LABEL, r"$\theta_v$"), (R_LABEL, "$R$")):
        ax.text(*where, text, color=t.text, fontsize=house.fontsize(fig), ha="center", va="center")

    arrow = {"angles": "xy", "scale_units": "xy", "scale": 1, "pivot": "middle", "width": 0.012,
             "headwidth": 3.5, "headlength": 4, "headaxislength": 3.5}
    for kind, color in colors.items():
        chosen = classes == kind
        ax.quiver(offsets[chosen, 0], offsets[chosen, 1], 0.2 * headings[chosen, 0], 0.2 * headings[chosen, 1],
                  color=color, **arrow)
    ax.quiver([0], [0], [0.42], [0], color=t.text, **{**arrow, "pivot": "tail", "width": 0.022})
    ax.plot([0], [0], "o", color=t.text, ms=3 * scale)

    labels = {SEEN: "seen", HIDDEN: "hidden by the cone", OUT: "out of range"}
    handles = [Line2D([], [], ls="none", marker=r"$\rightarrow$", ms=9 * scale, color=colors[kind],
                      label=f"{labels[kind]} ({np.count_nonzero(classes == kind)})") for kind in labels]
    house.legend(ax, t, handles=handles, loc="center left", bbox_to_anchor=(1.0, 0.5), handletextpad=0.3)
    # the drawn neighbours' extent (and the circle's), not the box they were drawn in
    low = np.minimum(offsets.min(axis=0), -RADIUS) - 0.15
    high = np.maximum(offsets.max(axis=0), RADIUS) + 0.15
    ax.set(xlim=(low[0], high[0]), ylim=(low[1], high[1]))
    ax.set_aspect("equal", adjustable="box")
    ax.set_anchor("E")  # a narrower box stays against its legend, which the layout placed
    ax.set_axis_off()
    house.title(fig, "The vision cone", f"$R$ = {RADIUS:g} · $\\theta_v$ = {VISION:g} rad "
                f"({degrees:.0f}°) · classes checked against a step of the engine")
    house.save(fig, args.out)


# -- chirality ------------------------------------------------------------------------------


def trajectory(omega: float, noise: float = 0.0, steps: int | None = None, seed: int = 0) -> np.ndarray:
    """Positions ``(steps + 1, 2)`` of one particle with chirality ``omega``, relative to
    its start (heading +y) and unwrapped across the periodic box, recorded every step of
    the engine; by default one turn: ``ceil(2 pi / (|omega| dt))`` steps."""
    if steps is None:
        steps = math.ceil(2 * math.pi / (abs(omega) * DT))
    model = Model(dim=2, n=1, box=BOX, noise=noise, speed=SPEED, dt=DT, chirality=omega, seed=seed)
    start = np.full((1, 2), BOX / 2)
    sim = Simulation(model, State(start, np.array([[0.0, 1.0]]), np.array([SPEED])))
    points = [start[0]]
    for _ in range(steps):
        sim.run(1)
        points.append(sim.state.positions[0].copy())
    moves = np.diff(points, axis=0)
    moves -= BOX * np.round(moves / BOX)  # a jump across the box is a short move
    return np.vstack([np.zeros(2), np.cumsum(moves, axis=0)])


def predicted_circle(omega: float) -> tuple[np.ndarray, float]:
    """Centre and radius of the circle through the noise-free trajectory from the origin,
    heading +y: the radius ``v0 dt / (2 sin(omega dt / 2))`` of docs/model.md, the centre
    to the left of the first move (``omega > 0``) or to its right.

    >>> centre, radius = predicted_circle(0.2)
    >>> round(radius, 4), centre.round(4).tolist()
    (2.5042, [-2.4917, -0.25])
    """
    signed = SPEED * DT / (2 * math.sin(omega * DT / 2))
    psi = math.pi / 2 + omega * DT / 2  # the first move's direction, less half a turn
    return signed * np.array([-math.sin(psi), math.cos(psi)]), abs(signed)


def check_circle(points: np.ndarray, omega: float) -> None:
    """Raise ``RuntimeError`` unless every point lies on :func:`predicted_circle` to 1e-9."""
    centre, radius = predicted_circle(omega)
    off = np.abs(np.linalg.norm(points - centre, axis=1) - radius).max()
    if off > 1e-9:
        raise RuntimeError(f"chirality: omega = {omega:g} leaves the predicted circle by {off:.3g}")


def draw_chirality(args) -> None:
    """The chirality figure, its noise-free trajectories checked, written to ``args.out``:
    two panels on one scale (the same length of x and y per inch in both)."""
    noisy_omega, eta, steps, seed = NOISY
    noisy = trajectory(noisy_omega, eta, steps, seed)
    clean = {omega: trajectory(omega) for omega in OMEGAS}
    for omega, points in clean.items():
        check_circle(points, omega)
    pad = 0.8
    spans = [(min(p[:, a].min() for p in group) - pad, max(p[:, a].max() for p in group) + pad)
             for group in (list(clean.values()), [noisy]) for a in (0, 1)]
    (lx, ly), (rx, ry) = spans[:2], spans[2:]
    y = (min(ly[0], ry[0]), max(ly[1], ry[1], 2.2 + pad))
    t = house.get_theme(args.theme)
    fig, (left, right) = house.figure(args.size, t, 1, 2, width_ratios=(lx[1] - lx[0], rx[1] - rx[0]),
                                      sharey=True)
    scale = house.fontsize(fig) / 8.0
    size = house.fontsize(fig)
    colors = house.palette(t)
    ring = np.linspace(0, 2 * math.pi, 200)
    circle = np.stack([np.cos(ring), np.sin(ring)], axis=1)

    for (omega, points), color in zip(clean.items(), colors):
        centre, radius = predicted_circle(omega)
        left.plot(*(centre + radius * circle).T, color=color, lw=3.5 * scale, alpha=0.3, solid_capstyle="butt")
        left.plot(*points.T, color=color, lw=0.6 * scale, marker="o", ms=1.3 * scale, label=f"$\\omega = {omega:g}$")
    house.legend(left, t, loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=len(OMEGAS), handlelength=1.2,
                 columnspacing=1.0, handletextpad=0.4, borderaxespad=0.2)

    points = noisy
    centre, radius = predicted_circle(noisy_omega)
    right.plot(*(centre + radius * circle).T, color=t.text, lw=0.7 * scale, ls=(0, (3, 2)), alpha=0.8)
    right.plot(*points.T, color=colors[3], lw=0.7 * scale)
    right.text(0.5, 1.02, f"$\\omega = {noisy_omega:g}$, $\\eta = {eta:g}$\n{steps} steps", color=colors[3],
               fontsize=0.85 * size, ha="center", va="bottom", transform=right.transAxes)

    for ax, xlim in ((left, lx), (right, rx)):
        ax.annotate("", xy=(0, 2.2), xytext=(0, 0),
                    arrowprops={"arrowstyle": "-|>", "color": t.text, "lw": 0.9 * scale,
                                "mutation_scale": 7 * scale})
        ax.plot([0], [0], "o", color=t.text, ms=2.5 * scale)
        ax.set_xlim(*xlim)
        ax.set_ylim(*y)
        ax.set_aspect("equal", adjustable="box")  # equal heights (shared y), so equal scales
        ax.tick_params(labelsize=0.8 * size, labelleft=True)
    house.label_axes(left, r"$x - x_0$ (units of $R$)", r"$y - y_0$ (units of $R$)")
    house.label_axes(right, "$x - x_0$\n(units of $R$)")
    house.title(fig, "Chirality: particles that turn by themselves",
                f"$v_0$ = {SPEED:g} $R$ per unit time · $\\Delta{{t}}$ = {DT:g} · $\\omega$ in rad per unit time · "
                "from the start $(x_0, y_0)$ heading "
                "$+y$ (arrow) · both panels on one scale · dots: the engine, a step each · "
                "band: radius $v_0\\Delta{t}/(2\\sin(\\omega\\Delta{t}/2))$ · dashed: the same without noise")
    house.save(fig, args.out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("figure", choices=("vision", "chirality"), help="which figure to draw")
    parser.add_argument("--out", default=None, help="the figure (.png, .svg, .pdf); default model-FIGURE.png")
    parser.add_argument("--theme", default="light", help="dark or light")
    parser.add_argument("--size", default="column", help="column, page or slide")
    args = parser.parse_args()
    args.out = args.out or f"model-{args.figure}.png"
    house.check_format(args.out)
    started = time.perf_counter()
    (draw_vision if args.figure == "vision" else draw_chirality)(args)
    print(f"{args.out}: {time.perf_counter() - started:.1f} s")


if __name__ == "__main__":
    main()
