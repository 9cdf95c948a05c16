"""Metric-free (Voronoi) neighbours against metric ones (Ginelli and Chate, PRL 105, 168103
(2010)): at the density and noise where the metric model forms travelling bands, the
Voronoi model orders homogeneously; and the Voronoi model's polar order against noise.

Conventions (the same for both models; flocking's defaults unless said): 2D, periodic box,
density rho = 2, speed v0 = 0.5, radius R = 1 (metric model; for the Voronoi model R only
sets the cell list), the backward update (move along the new heading), time step 1, and
Gregoire and Chate's vectorial noise: the new heading is the direction of the sum of the
neighbours' headings (the particle's own included) plus eta n_i times a random unit vector,
n_i the number of headings summed. The Voronoi neighbours are the particles whose Voronoi
cells share a side with the particle's own (docs/voronoi.md). Only the paper's title and
abstract could be read while this was written: its own noise convention and numbers were
not, so vectorial noise was chosen here because the metric model's bands are robust with it,
and no value of the paper is drawn.

1. Bands: a 256 x 32 box (N = 16384), eta = 0.6, every heading along +x at the start, the
   same seed for both models, STEPS steps. The band contrast of a frame is the variance of
   the relative density n_b / <n_b> over slabs 4 wide across x (the direction of motion),
   less the 1 / <n_b> an ideal gas gives: 0 for a homogeneous state, about 1 for the
   metric model's bands. Printed: its mean over the second half (a frame every 250 steps)
   +- the standard error of those frames, and the polar order's mean there.
2. Order against noise: the Voronoi model in square boxes L = 16 and 32 (N = 512, 2048)
   and the metric model at L = 32, from the aligned start, ORDER_STEPS steps; the mean of
   the second half +- its error from the integrated autocorrelation time
   (flocking.analysis.PolarOrder).

    python examples/ginelli_chate2010.py --out ginelli_chate2010.png --theme light --size page

Cost: 18 min wall clock on the project's 2-core machine while other programs kept it busy
(load average 8 to 14), the kernels compiled: the Voronoi band run 7 min (0.14 s a step),
the Voronoi curves 2.5 min (L = 16) and 7.3 min (L = 32), every metric run together
1.2 min. On a quiet machine the Voronoi band run took about 4 min.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from flocking import Frame, Model, Simulation, State
from flocking.analysis import PolarOrder
from flocking.state import frame_arrays
from flocking.viz import plot_frame
from flocking.viz import style as house

BASE = dict(density=2.0, speed=0.5, noise_type="vectorial", radius=1.0)
BAND_BOX = (256.0, 32.0)
BAND_NOISE = 0.6
STEPS, EVERY = 3000, 250
SLAB = 4.0  # width of the slabs of the density profile, along x
SIZES = (16.0, 32.0)
NOISES = (0.3, 0.4, 0.5, 0.55, 0.6, 0.65, 0.7, 0.8)
ORDER_STEPS = 3000
SEED = 1


def contrast(positions: np.ndarray, length: float, slab: float = SLAB) -> tuple[float, np.ndarray]:
    """The band contrast of one frame and its relative density profile along x: slabs of
    width ``slab`` (``length / slab`` of them, a whole number), ``var(n_b / <n_b>) - 1 / <n_b>``."""
    bins = int(round(length / slab))
    counts, _ = np.histogram(positions[:, 0], bins=bins, range=(0.0, length))
    mean = counts.mean()
    relative = counts / mean
    return float(relative.var() - 1.0 / mean), relative


def band_run(neighbours: str, box=BAND_BOX, noise: float = BAND_NOISE, steps: int = STEPS, every: int = EVERY,
             seed: int = SEED):
    """One run from the aligned start; returns the contrasts and polar orders of the frames
    of the second half (one every ``every`` steps), the last frame's profile, and the simulation."""
    model = Model(**BASE, box=box, noise=noise, neighbours=neighbours, seed=seed)
    sim = Simulation(model, State.aligned(model))
    contrasts, orders, profile = [], [], None
    while sim.step < steps:
        sim.run(every)
        if sim.step > steps // 2:
            c, profile = contrast(sim.state.positions, box[0])
            contrasts.append(c)
            orders.append(sim.state.polar_order())
    return np.array(contrasts), np.array(orders), profile, sim


def order_point(neighbours: str, side: float, noise: float, steps: int = ORDER_STEPS, seed: int = SEED):
    """The polar order's mean over the second half of one run and its error."""
    model = Model(**BASE, box=(side, side), noise=noise, neighbours=neighbours, seed=seed)
    sim = Simulation(model, State.aligned(model))
    sim.run(steps)
    op = PolarOrder(start=0.5).compute(np.asarray(sim.polar_order), n=model.n)
    return float(op.mean), float(op.mean_error)


def mean_error(values) -> tuple[float, float]:
    values = np.asarray(values)
    return float(values.mean()), float(values.std(ddof=1) / np.sqrt(len(values)))


def last_frame(sim: Simulation) -> Frame:
    points, velocities = frame_arrays(sim.state, np.asarray(sim.model.box))
    return Frame(sim.step, 2, list(sim.model.box), points, velocities)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="ginelli_chate2010.png", help="the figure (.png, .svg, .pdf)")
    parser.add_argument("--theme", default="light", help="dark or light")
    parser.add_argument("--size", default="page", help="column, page or slide")
    args = parser.parse_args()
    house.check_figure_args(parser, args)
    started = time.perf_counter()

    bands = {}
    for neighbours in ("metric", "voronoi"):
        t0 = time.perf_counter()
        contrasts, orders, profile, sim = band_run(neighbours, BAND_BOX, BAND_NOISE, STEPS, EVERY)
        bands[neighbours] = (mean_error(contrasts), mean_error(orders), profile, sim)
        (cm, ce), (om, oe) = bands[neighbours][:2]
        print(f"{neighbours:<8} box {BAND_BOX[0]:g}x{BAND_BOX[1]:g} N {sim.model.n} eta {BAND_NOISE:g}: "
              f"band contrast {cm:.3f} +- {ce:.3f}, polar order {om:.3f} +- {oe:.3f}, "
              f"profile max {profile.max():.2f} min {profile.min():.2f}  ({time.perf_counter() - t0:.0f} s)",
              flush=True)

    curves = {}
    for neighbours, side in [("voronoi", s) for s in SIZES] + [("metric", SIZES[-1])]:
        t0 = time.perf_counter()
        curves[(neighbours, side)] = [order_point(neighbours, side, eta, ORDER_STEPS) for eta in NOISES]
        print(f"{neighbours:<8} L {side:g}: " + "  ".join(f"{eta:g}: {m:.3f} +- {e:.3f}" for eta, (m, e)
                                                          in zip(NOISES, curves[(neighbours, side)]))
              + f"  ({time.perf_counter() - t0:.0f} s)", flush=True)
    print(f"total {time.perf_counter() - started:.0f} s")

    t = house.get_theme(args.theme)
    width, _, fs = house.resolve_size(args.size)
    strip = 0.82 * width * BAND_BOX[1] / BAND_BOX[0]  # a snapshot's height, drawn to scale
    side = house.panels_across(width, fs) >= 2  # the profile and the order side by side (not in a column)
    lower = 0.3 * width if side else 0.45 * width
    rows = [strip + 0.6, strip + 0.6] + [lower + 0.6] * (1 if side else 2)  # each with room for title and ticks
    fig = house.new_figure(width, sum(rows) + 1.5, t, fs)
    grid = fig.add_gridspec(len(rows), 2 if side else 1, height_ratios=rows)
    colours = house.palette(t)
    for row, neighbours in enumerate(("metric", "voronoi")):
        ax = fig.add_subplot(grid[row, :])
        house.style_axes(ax, t)
        plot_frame(last_frame(bands[neighbours][3]), ax=ax, theme=args.theme, style="density")
        house.label_axes(ax, "x" if row else None, "y")
        (cm, ce) = bands[neighbours][0]
        ax.set_title(f"{neighbours} neighbours, step {STEPS:,}:{' ' if side else chr(10)}band contrast {cm:.2f} "
                     f"$\\pm$ {ce:.2f}", color=t.text, fontsize=house.fontsize(fig))
    profile_ax = fig.add_subplot(grid[2, 0])
    house.style_axes(profile_ax, t)
    centres = (np.arange(int(round(BAND_BOX[0] / SLAB))) + 0.5) * SLAB
    for i, neighbours in enumerate(("metric", "voronoi")):
        profile_ax.plot(centres, bands[neighbours][2], color=colours[i], lw=1.2, label=neighbours)
    profile_ax.axhline(1.0, color=t.edge, lw=0.8, ls=":")
    house.label_axes(profile_ax, "x (units of R)", "density / mean, slabs 4 wide")
    house.legend(profile_ax, t, loc="upper right")
    order_ax = fig.add_subplot(grid[2, 1] if side else grid[3, 0])
    house.style_axes(order_ax, t)
    styles = {("voronoi", SIZES[0]): (colours[1], "o", "--"), ("voronoi", SIZES[-1]): (colours[1], "s", "-"),
              ("metric", SIZES[-1]): (colours[0], "D", "-")}
    for key, values in curves.items():
        colour, marker, ls = styles[key]
        order_ax.errorbar(NOISES, [v[0] for v in values], yerr=[v[1] for v in values], color=colour, marker=marker,
                          ms=3.5, lw=1.1, ls=ls, capsize=2, label=f"{key[0]}, L = {key[1]:g}")
    order_ax.set_ylim(0.0, 1.0)
    house.label_axes(order_ax, "vectorial noise $\\eta$", "polar order $\\varphi$")
    house.legend(order_ax, t, loc="lower left")
    house.title(fig, "Voronoi neighbours order without bands where metric neighbours form them",
                f"Ginelli and Chaté 2010 · density 2, $v_0$ = 0.5, $R$ = 1, vectorial noise, backward update · top: "
                f"{BAND_BOX[0]:g} × {BAND_BOX[1]:g} box, $\\eta$ = {BAND_NOISE:g}, aligned start, the same seed; "
                f"contrast: variance of the slab density over its mean less shot noise, mean over steps "
                f"{STEPS // 2:,}-{STEPS:,} · {'right' if side else 'last'}: mean over the second half of {ORDER_STEPS:,} steps, bars from "
                "the autocorrelation time · the paper's numbers could not be read, so none are drawn")
    house.save(fig, args.out)


if __name__ == "__main__":
    main()
