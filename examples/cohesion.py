"""A cohesive flock (Gregoire and Chate, PRL 92, 025702 (2004)): with attraction-repulsion
between neighbours, a group stays together in an open space at low noise, and dissolves at
high noise; without cohesion the same group spreads out.

Every run starts from one group: the particles uniform in a disc (density 2) in the middle
of a periodic box of side 80, far larger than the group (N = 512: density 0.08 over the
box), headings random. Speed v0 = 0.05, R = 1, vectorial noise eta, cohesion beta = 0.3
with Gregoire and Chate's radii (hard core 0.2, equilibrium 0.5, full attraction from 0.8).
Each run's numbers are means over its second half (steps 10000 to 20000, one sample every
500 steps): the share of the particles in the largest cluster (particles closer than R
linked, flocking.analysis.Clusters) and the polar order. Points: means over seeds, bars:
standard errors of those means.

    python examples/cohesion.py --out cohesion.png --theme light --size page
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from flocking import Frame, Model, Simulation, State
from flocking.analysis import Clusters
from flocking.state import frame_arrays
from flocking.viz import style as house
from flocking.viz.scene import plot_frame

BASE = dict(n=512, box=80.0, speed=0.05, radius=1.0, noise_type="vectorial", cohesion=0.3)
NOISES = (0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6)
SHOWN = (0.1, 0.5)  # the two noises whose last frames are drawn
SEEDS = 3
STEPS, SAMPLE = 20_000, 500
START_DENSITY = 2.0


def group(model: Model, seed: int) -> State:
    """The particles uniform in a disc of density :data:`START_DENSITY` in the middle of the
    box, headings uniform on the circle."""
    rng = np.random.default_rng(seed)
    n, centre = model.n, np.asarray(model.box) / 2
    r = np.sqrt(n / (np.pi * START_DENSITY) * rng.uniform(0.0, 1.0, n))
    a, theta = rng.uniform(0.0, 2 * np.pi, n), rng.uniform(0.0, 2 * np.pi, n)
    positions = centre + np.stack([r * np.cos(a), r * np.sin(a)], axis=1)
    return State(positions, np.stack([np.cos(theta), np.sin(theta)], axis=1), np.full(n, model.speed))


def run(noise: float, seed: int, cohesion: float = BASE["cohesion"]) -> tuple[float, float, Simulation]:
    """The means of the largest cluster's share and of the polar order over the second half."""
    model = Model(**{**BASE, "cohesion": cohesion}, noise=noise, seed=seed)
    sim = Simulation(model, group(model, seed))
    largest, phi = [], []
    while sim.step < STEPS:
        sim.run(SAMPLE)
        if sim.step > STEPS // 2:
            frame = (model.box, sim.state.positions - np.asarray(model.box) / 2)  # centred, as frames are
            largest.append(Clusters(radius=model.radius).compute(frame).largest_fraction)
            phi.append(sim.state.polar_order())
    return float(np.mean(largest)), float(np.mean(phi)), sim


def last_frame(sim: Simulation) -> Frame:
    """The simulation's state as a frame, centred as GSD files hold it."""
    state, box = sim.state, np.asarray(sim.model.box)
    points, velocities = frame_arrays(state, box)
    return Frame(sim.step, 2, list(box), points, velocities)


def mean_error(values) -> tuple[float, float]:
    values = np.asarray(values)
    return float(values.mean()), float(values.std(ddof=1) / np.sqrt(len(values)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="cohesion.png", help="the figure (.png, .svg, .pdf)")
    parser.add_argument("--theme", default="light", help="dark or light")
    parser.add_argument("--size", default="page", help="column, page or slide")
    args = parser.parse_args()
    house.check_figure_args(parser, args)
    started = time.perf_counter()
    rows, last = [], {}
    for noise in NOISES:
        results = [run(noise, seed) for seed in range(1, SEEDS + 1)]
        last[noise] = results[0][2]
        rows.append((mean_error([r[0] for r in results]), mean_error([r[1] for r in results])))
        (lm, le), (pm, pe) = rows[-1]
        print(f"eta {noise:<4g} largest cluster {lm:.3f} +- {le:.3f}   polar order {pm:.3f} +- {pe:.3f}", flush=True)
    plain = [run(0.1, seed, cohesion=0.0)[:2] for seed in range(1, SEEDS + 1)]
    (bm, be), (qm, qe) = mean_error([r[0] for r in plain]), mean_error([r[1] for r in plain])
    print(f"eta 0.1  no cohesion: largest cluster {bm:.3f} +- {be:.3f}   polar order {qm:.3f} +- {qe:.3f}")
    print(f"{(len(NOISES) + 1) * SEEDS} runs in {time.perf_counter() - started:.0f} s")

    t = house.get_theme(args.theme)
    width, _, fs = house.resolve_size(args.size)
    side = house.panels_across(width, fs) >= 2  # the snapshots and the charts side by side (not in a column)
    if side:
        fig = house.new_figure(width, 0.42 * width + 1.0, t, fs)
        grid = fig.add_gridspec(2, 3, width_ratios=[1, 1, 1.3])
        snapshots = [fig.add_subplot(grid[:, c]) for c in range(2)]
        cluster_ax = fig.add_subplot(grid[0, 2])
        order_ax = fig.add_subplot(grid[1, 2], sharex=cluster_ax)
    else:  # the snapshots above the charts
        fig = house.new_figure(width, 1.3 * width + 1.6, t, fs)
        grid = fig.add_gridspec(3, 2, height_ratios=[1.2, 1, 1])
        snapshots = [fig.add_subplot(grid[0, c]) for c in range(2)]
        cluster_ax = fig.add_subplot(grid[1, :])
        order_ax = fig.add_subplot(grid[2, :], sharex=cluster_ax)
    colours = house.palette(t)
    for ax, noise in zip(snapshots, SHOWN):
        house.style_axes(ax, t)
        plot_frame(last_frame(last[noise]), ax=ax, theme=args.theme, style="arrows", arrow_scale=2.0)
        house.label_axes(ax, "x", "y")
        ax.set_title(f"$\\eta$ = {noise:g}, step {STEPS:,}", color=t.text, fontsize=house.fontsize(fig))
    # one quantity a panel, each a share in [0, 1]; beta = 0 beside both at eta = 0.1
    gap = "\n" if side else " "  # a short chart's label on two lines
    for ax, row, marker, label, plain_point in ((cluster_ax, 0, "o", f"largest{gap}cluster / $N$", (bm, be)),
                                               (order_ax, 1, "s", f"polar{gap}order $\\varphi$", (qm, qe))):
        house.style_axes(ax, t)
        ax.errorbar(NOISES, [r[row][0] for r in rows], yerr=[r[row][1] for r in rows], color=colours[0],
                    marker=marker, ms=4, lw=1.2, capsize=2.5, label=f"$\\beta$ = {BASE['cohesion']:g}")
        ax.errorbar([0.1], [plain_point[0]], yerr=[plain_point[1]], color=colours[1], marker="D", ms=5, lw=0,
                    elinewidth=1.2, capsize=2.5, label="$\\beta$ = 0")
        house.label_axes(ax, None, label)
        ax.set_ylim(0.0, 1.0)
    cluster_ax.tick_params(labelbottom=False)
    house.label_axes(order_ax, "vectorial noise $\\eta$")
    house.legend(cluster_ax, t, loc="upper right")
    house.title(fig, "A cohesive flock holds together at low noise and dissolves at high noise",
                f"$N$ = {BASE['n']} from a group of density {START_DENSITY:g} in a periodic box of side "
                f"{BASE['box']:g} (box coordinates, units of $R$) · $v_0$ = {BASE['speed']:g} · cohesion "
                f"$\\beta$ = {BASE['cohesion']:g}, $r_c, r_e, r_a$ = 0.2, 0.5, 0.8 · bars: standard error over "
                f"{SEEDS} seeds · means over steps 10,000-20,000 · without cohesion ($\\beta$ = 0) the group "
                "spreads out")
    house.save(fig, args.out)


if __name__ == "__main__":
    main()
