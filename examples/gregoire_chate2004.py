"""The discontinuous onset of collective motion of Gregoire and Chate (PRL 92, 025702
(2004)): the Vicsek model with vectorial noise, near its threshold. Two measurements:

1. The distribution of the polar order ``phi`` in one long run at a noise just at the
   threshold, for a size small enough to switch between the disordered state and the
   ordered (banded) one within the run: two peaks.
2. The Binder cumulant ``G = 1 - <phi^4> / (3 <phi^2>^2)`` against the noise for two or
   three sizes: 2/3 in the ordered phase, 1/3 in the disordered one (where the two
   components of the order are Gaussian); at a discontinuous transition it dips below
   1/3 at the threshold, where the two states coexist, and for sizes large enough below
   zero.

Conventions, all the package's and stated on docs/literature.md: vectorial ("extrinsic")
noise, ``theta_i(t+1) = arg(sum_j u_j + eta n_i xi_i)`` with ``xi_i`` a random unit vector
and ``n_i`` the number of neighbours (``i`` included); the backward update (each particle
moves along its new heading, ``x_i(t+1) = x_i(t) + v0 u_i(t+1)``); density 2, speed 0.5,
radius 1, time step 1; every run from random positions and headings. Moments are time
averages of one run per point after ``--equilibrate`` steps; their errors come from
flocking.analysis.PolarOrder (autocorrelation time, block jackknife), which near the
threshold, where a run switches only a few times, are rough: say so when quoting them.

    python examples/gregoire_chate2004.py --out examples/gregoire_chate2004_onset.png
    # the committed figure (N = 512 and 2048): 77 s wall clock, about 150 CPU-seconds, on
    # 2 otherwise idle cores (12 min 30 s when other programs kept them busy)
    python examples/gregoire_chate2004.py --steps 20000 --hist-steps 40000 --out quick.png
    # half the steps: about half the time

The sizes are modest: a box of 64 (N = 8192, four times the particles of a box of 32) was
not run here; N = 2048 already switches between its states too rarely for runs this long.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from flocking import Ensemble, Model
from flocking.analysis import PolarOrder
from flocking.viz import style as house

BASE = dict(density=2.0, speed=0.5, radius=1.0, noise_type="vectorial", update="backward")
NOISES = (0.605, 0.61, 0.6125, 0.615, 0.6175, 0.62, 0.63)

#: What we could read of the paper (see docs/literature.md): its abstract only, which states that
#: the onset is discontinuous. Its figures and their values were not available to us, so no
#: number of the paper is overlaid on ours.
PAPER = {"binder_at_threshold": "not read (only the abstract was available; it states a discontinuous onset)"}


def orders(size: float, noises, steps: int, seed: int) -> np.ndarray:
    """The polar order after every step, ``(len(noises), steps)``: one run per noise at box
    side ``size``, from random positions and headings (all runs of one size as one
    :class:`flocking.Ensemble`)."""
    models = [Model(box=size, noise=eta, seed=seed + k, **BASE) for k, eta in enumerate(noises)]
    return Ensemble(models, backend="cpu").advance(steps)


def moments(phi: np.ndarray, n: int, equilibrate: int) -> dict:
    """<phi> and G with their errors over the steps after ``equilibrate``."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a run that switches rarely drifts; its error says how rough it is
        op = PolarOrder(start=equilibrate).compute(phi, n=n)
    return {"order": op.mean, "order_error": op.mean_error, "binder": op.binder, "binder_error": op.binder_error,
            "tau": op.tau, "samples": op.samples}


def binder_curve(size: float, noises, steps: int, equilibrate: int, seed: int) -> dict:
    """``{"n", "noise", "order", "order_error", "binder", "binder_error"}`` at box side ``size``."""
    n = Model(box=size, **BASE).n
    phi = orders(size, noises, steps, seed)
    points = [moments(p, n, equilibrate) for p in phi]
    out = {"n": n, "noise": list(noises)}
    for key in ("order", "order_error", "binder", "binder_error", "tau"):
        out[key] = [p[key] for p in points]
    return out


def switching(size: float, noise: float, steps: int, equilibrate: int, seed: int, bins: int) -> dict:
    """One long run at ``noise``: its series, the histogram of ``phi`` after ``equilibrate``
    steps, the share of that time ordered (``phi`` above the histogram's deepest minimum
    between its two peaks, else above 0.4) and the number of switches between the two."""
    n = Model(box=size, **BASE).n
    phi = orders(size, [noise], steps, seed)[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        op = PolarOrder(start=equilibrate).compute(phi, n=n)
    hist = op.histogram(bins)
    cut = valley(hist.counts, hist.edges)
    window = phi[equilibrate:]
    # a switch: the run crosses from below 0.8 cut to above 1.2 cut, or back (a dead band
    # around the cut, so that fluctuations at the cut are not counted)
    state, switches = None, 0
    for x in window:
        now = True if x > 1.2 * cut else False if x < 0.8 * cut else state
        if state is not None and now != state:
            switches += 1
        state = now
    return {"n": n, "noise": noise, "steps": steps, "equilibrate": equilibrate, "series": phi,
            "edges": hist.edges, "density": hist.density, "counts": hist.counts, "cut": cut,
            "ordered_share": float(np.mean(window > cut)), "switches": switches,
            "order": op.mean, "order_error": op.mean_error, "binder": op.binder, "binder_error": op.binder_error}


def valley(counts: np.ndarray, edges: np.ndarray) -> float:
    """The centre of the emptiest bin between the two highest local maxima of ``counts``
    (0.4 when the histogram has a single peak)."""
    centres = 0.5 * (edges[1:] + edges[:-1])
    smooth = np.convolve(counts, np.ones(3) / 3, mode="same")
    peaks = [k for k in range(len(smooth)) if smooth[k] > 0 and smooth[k] >= smooth[max(k - 1, 0)]
             and smooth[k] >= smooth[min(k + 1, len(smooth) - 1)]]
    if len(peaks) < 2:
        return 0.4
    a, b = sorted(sorted(peaks, key=lambda k: smooth[k])[-2:])
    if b - a < 2:
        return 0.4
    return float(centres[a + int(np.argmin(smooth[a:b + 1]))])


def figure(hist: dict, curves: dict, path: str, theme: str, size: str) -> None:
    """Three panels: the switching run's series, its histogram, and G(eta) per size."""
    fig, axes = house.panels(size, theme, 3)
    colours = house.palette(theme)
    t = np.arange(1, len(hist["series"]) + 1)
    axes[0].plot(t, hist["series"], lw=0.4, color=colours[0])
    house.shade_window(axes[0], hist["equilibrate"], len(t), theme, label="measured")
    axes[0].axhline(hist["cut"], color=colours[1], lw=1, ls="--", label=f"cut {hist['cut']:.2f}")
    house.label_axes(axes[0], "step", r"$\varphi(t)$")
    axes[0].set_ylim(-0.03, 1.08)  # room above the series for the legend
    house.legend(axes[0], theme, loc="upper center", ncols=2)
    axes[1].stairs(hist["density"], hist["edges"], fill=True, color=colours[0], alpha=0.35)
    axes[1].stairs(hist["density"], hist["edges"], color=colours[0], lw=1,
                   label=rf"N = {hist['n']}, $\eta$ = {hist['noise']:g}")
    axes[1].axvline(hist["cut"], color=colours[1], lw=1, ls="--")
    house.label_axes(axes[1], r"$\varphi$", "probability density")
    house.legend(axes[1], theme, loc="upper left")
    ordered = sorted(curves.items(), key=lambda item: float(item[0]))
    for k, (length, res) in enumerate(ordered):
        axes[2].errorbar(res["noise"], res["binder"], yerr=res["binder_error"], fmt="o-", ms=3, lw=1, capsize=2,
                         color=colours[k % len(colours)], label=f"N = {res['n']}")
    axes[2].axhline(2 / 3, color=colours[-1], lw=0.8, ls=":")
    axes[2].axhline(1 / 3, color=colours[-1], lw=0.8, ls=":")
    house.label_axes(axes[2], "eta", "binder")
    house.legend(axes[2], theme, loc="lower left")  # left of the dip
    lengths, counts = ", ".join(length for length, _ in ordered), ", ".join(str(res["n"]) for _, res in ordered)
    house.title(fig, "Discontinuous onset with vectorial noise (Grégoire and Chaté 2004)",
                rf"$\rho$ = 2 ($L$ = {lengths} for $N$ = {counts}) · $v_0$ = 0.5 · R = 1 · backward update · "
                "one run per point, bars: jackknife errors")
    house.save(fig, path)


def parse(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", default="16,32", help="box sides L of the Binder curves, comma-separated")
    p.add_argument("--noises", default=",".join(map(str, NOISES)), help="eta of the Binder curves")
    p.add_argument("--steps", type=int, default=40_000, help="steps of each run of the Binder curves")
    p.add_argument("--equilibrate", type=int, default=4_000, help="steps left out at the start of every run")
    p.add_argument("--hist-size", type=float, default=16.0, help="box side of the switching run")
    p.add_argument("--hist-noise", type=float, default=0.615, help="noise of the switching run")
    p.add_argument("--hist-steps", type=int, default=80_000, help="steps of the switching run")
    p.add_argument("--bins", type=int, default=50)
    p.add_argument("--seed", type=int, default=2004)
    p.add_argument("--out", default="gregoire_chate2004_onset.png")
    p.add_argument("--theme", default="light")
    p.add_argument("--size", default="page")
    args = p.parse_args(argv)
    house.check_figure_args(p, args)
    args.sizes = [float(x) for x in args.sizes.split(",")]
    args.noises = [float(x) for x in args.noises.split(",")]
    return args


def main(argv=None) -> tuple[dict, dict]:
    args = parse(argv)
    began = time.perf_counter()
    hist = switching(args.hist_size, args.hist_noise, args.hist_steps, args.equilibrate, args.seed, args.bins)
    print(f"switching run: L = {args.hist_size:g} (N = {hist['n']}), eta = {args.hist_noise:g}, "
          f"{args.hist_steps} steps ({args.equilibrate} left out): <phi> = {hist['order']:.3f} +- "
          f"{hist['order_error']:.3f}, G = {hist['binder']:.3f} +- {hist['binder_error']:.3f}; ordered "
          f"(phi > {hist['cut']:.2f}) {hist['ordered_share']:.2f} of the time, {hist['switches']} switches")
    centres = 0.5 * (hist["edges"][1:] + hist["edges"][:-1])
    low, high = centres < hist["cut"], centres > hist["cut"]
    if low.any() and high.any() and hist["counts"][low].any() and hist["counts"][high].any():
        print(f"  histogram peaks at phi = {centres[low][np.argmax(hist['density'][low])]:.2f} and "
              f"{centres[high][np.argmax(hist['density'][high])]:.2f}")
    curves = {}
    for size in args.sizes:
        res = binder_curve(size, args.noises, args.steps, args.equilibrate, args.seed)
        curves[f"{size:g}"] = res
        for eta, m, me, g, ge, tau in zip(res["noise"], res["order"], res["order_error"], res["binder"],
                                          res["binder_error"], res["tau"]):
            print(f"L = {size:g} (N = {res['n']}) eta = {eta:g}: <phi> = {m:.3f} +- {me:.3f}, "
                  f"G = {g:.3f} +- {ge:.3f} (tau {tau:.0f} steps)")
        k = int(np.argmin(res["binder"]))
        print(f"L = {size:g}: lowest G = {res['binder'][k]:.3f} +- {res['binder_error'][k]:.3f} at eta = "
              f"{res['noise'][k]:g}")
    print(f"paper: Binder cumulant at the threshold {PAPER['binder_at_threshold']}")
    figure(hist, curves, args.out, args.theme, args.size)
    print(f"total {time.perf_counter() - began:.0f} s; wrote {args.out}")
    return hist, curves


if __name__ == "__main__":
    main()
