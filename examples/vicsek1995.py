"""Vicsek, Czirok, Ben-Jacob, Cohen and Shochet, PRL 75, 1226 (1995): Fig. 2a (the order
v_a against the noise eta at density 4 for several N), Fig. 2b (v_a against the density at
L = 20, eta = 2) and the two exponents they fitted, beta from
v_a ~ ((eta_c(L) - eta) / eta_c(L))^beta and delta from v_a ~ rho^delta at small density.

Conventions, as the paper states them: speed v0 = 0.03, radius R = 1, time step 1; every
particle takes the mean direction of the particles within R (itself included) plus an
angle uniform in [-eta/2, eta/2] (``noise`` in radians, angular noise: the same eta), and
moves with the velocity it had before the update (``update = "forward"``); random positions
and headings at t = 0; v_a = |sum of the velocities| / (N v0), our polar order. The density
is N / L^2, so rho = 4 gives L = sqrt(N / 4).

Every point runs ``--replicas`` systems (seeds) for ``--steps`` steps from a random start,
except that N >= ``--aligned-from`` (10 000) starts with every heading equal (positions
still random): from random headings N = 10 000 has not settled after 8000 steps, and at
N = 4000 the two starts give the same v_a within the errors. Each system's v_a is its time
mean after ``--discard`` steps; a point is the mean over the systems, its error bar the
standard error of that mean (the spread between systems). The exponents are fitted as the
paper plots them: for beta, a straight line in ln v_a against ln((eta_c - eta) / eta_c)
for each of ``--beta-sizes`` (4000, the largest N run from the paper's random start, and
10 000, which also run the finer noises of ``--beta-noises``), over the noises from
``--beta-from`` up to the last one below the peak of its susceptibility
chi = N (<v_a^2> - <v_a>^2) (the finite system's transition), eta_c(L) a parameter of
the fit (the value that makes the line straightest); for delta, a straight line
in ln v_a against ln rho over the densities up to ``--delta-max``. Their intervals are the
16th to 84th percentiles over ``--bootstrap`` resamplings of the systems of every point.

    python examples/vicsek1995.py --out examples/vicsek1995-figures.png
    # 2638 CPU-seconds on one thread (the default --threads 1): 44 min of wall clock on the
    # project's 2 cores; N = 10 000 (19 noises) takes 1646 s of it, N = 4000 719 s.
    # The figure committed.

The paper's numbers beside ours: beta = 0.45 and delta = 0.35 as the paper quotes them
(PAPER below). Its curves are not overlaid point by point: we could not read its Fig. 2
here, so the figure draws its power laws through our data instead.
"""

from __future__ import annotations

import argparse
import time

import numba
import numpy as np
from matplotlib.ticker import FormatStrFormatter, LogLocator, NullFormatter
from scipy.optimize import least_squares

from flocking import Ensemble, Model
from flocking.viz import style as house

BASE = dict(speed=0.03, radius=1.0, update="forward", noise_type="angular", noise_scale="radians")
PAPER = {"beta": (0.45, 0.07), "delta": (0.35, 0.06)}  # the paper's text, value and its +-
NOISES = (0.0, 0.5, 1.0, 1.5, 2.0, 2.25, 2.5, 2.75, 3.0, 3.25, 3.5, 3.75, 4.0, 4.5, 5.0)
BETA_NOISES = (1.75, 2.125, 2.375, 2.625)  # more points near the peak of chi, for the sizes fitted
SIZES = (40, 100, 400, 4000, 10000)
BETA_POINTS = 3  # the fit of beta has three parameters (beta, eta_c, the amplitude)
DENSITIES = (0.1, 0.15, 0.2, 0.3, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0)


def order(n: int, density: float, noises, replicas: int, steps: int, discard: int,
          seed: int, start: str = "random") -> tuple[np.ndarray, np.ndarray]:
    """Each system's time means of v_a and of v_a^2 after ``discard`` steps, two arrays
    ``(len(noises), replicas)``: the systems of every noise (``n`` particles at
    ``density``, from random positions and ``start`` headings: ``"random"`` or
    ``"aligned"``) advanced as one ensemble."""
    models = [Model(n=n, density=density, noise=eta, seed=seed + 1000 * i + r, **BASE)
              for i, eta in enumerate(noises) for r in range(replicas)]
    ens = Ensemble(models, [start] * len(models), backend="cpu")
    ens.advance(discard)
    phi = ens.advance(steps - discard)
    shape = (len(noises), replicas)
    return phi.mean(axis=1).reshape(shape), (phi**2).mean(axis=1).reshape(shape)


def susceptibility(n: int, m1: np.ndarray, m2: np.ndarray) -> np.ndarray:
    """chi = N (<v_a^2> - <v_a>^2), the moments pooled over the systems of each point."""
    return n * (m2.mean(-1) - m1.mean(-1) ** 2)


def mean_error(per: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean over systems (last axis) and the standard error of that mean."""
    return per.mean(-1), per.std(-1, ddof=1) / np.sqrt(per.shape[-1])


def fit_beta(noises, values, errors) -> tuple[float, float, float]:
    """``(beta, eta_c, ln A)`` of ln v_a = ln A + beta ln((eta_c - eta) / eta_c), weighted by
    the errors of ln v_a; eta_c is free, above the largest noise given."""
    x, y = np.asarray(noises, float), np.log(values)
    w = 1.0 / np.maximum(np.asarray(errors) / values, 1e-3)
    top = x.max()

    def residuals(p):
        beta, gap, lna = p
        eta_c = top + np.exp(gap)
        return w * (lna + beta * np.log((eta_c - x) / eta_c) - y)

    best = min((least_squares(residuals, [0.5, np.log(g), 0.0]) for g in (0.05, 0.2, 0.5, 1.0)),
               key=lambda r: r.cost)
    beta, gap, lna = best.x
    return float(beta), float(top + np.exp(gap)), float(lna)


def fit_delta(densities, values, errors) -> tuple[float, float]:
    """``(delta, ln B)`` of ln v_a = ln B + delta ln rho, weighted by the errors of ln v_a."""
    x, y = np.log(densities), np.log(values)
    w = 1.0 / np.maximum(np.asarray(errors) / values, 1e-3)
    delta, lnb = np.polyfit(x, y, 1, w=w)
    return float(delta), float(lnb)


def bootstrap(fit, xs, per: np.ndarray, count: int, seed: int) -> np.ndarray:
    """``fit``'s first value refitted to ``count`` resamplings of the systems of every point."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        pick = rng.integers(0, per.shape[1], size=per.shape)
        sample = np.take_along_axis(per, pick, axis=1)
        out.append(fit(xs, *mean_error(sample))[0])
    return np.asarray(out)


def interval(samples: np.ndarray) -> tuple[float, float]:
    lo, hi = np.percentile(samples, [16, 84])
    return float(lo), float(hi)


def noises_of(n: int, args) -> list[float]:
    """The noises size ``n`` runs, in the order its seeds are numbered: ``--noises``, then,
    for a size fitted for beta, those of ``--beta-noises`` not already among them."""
    extra = [eta for eta in args.beta_noises if eta not in args.noises] if n in args.beta_sizes else []
    return list(args.noises) + extra


def beta(n: int, args, noises, chi: np.ndarray, per: np.ndarray) -> dict | None:
    """The fit of beta for size ``n`` (``per``: each system's v_a, ``chi`` the
    susceptibility, at each of the ascending ``noises``) over the noises from
    ``--beta-from`` to below the susceptibility's peak, printed; None, and said so, when
    fewer than :data:`BETA_POINTS` noises lie there."""
    peak = noises[int(np.argmax(chi))]
    keep = [i for i, eta in enumerate(noises) if args.beta_from <= eta < peak]
    noises = np.asarray(noises)[keep]
    if len(keep) < BETA_POINTS:
        print(f"beta (N = {n}): not fitted: {len(keep)} noises from {args.beta_from:g} to below the "
              f"susceptibility's peak at {peak:g}, fewer than {BETA_POINTS}")
        return None
    bm, be = mean_error(per[keep])
    fit = fit_beta(noises, bm, be)
    lo, hi = interval(bootstrap(fit_beta, noises, per[keep], args.bootstrap, args.seed))
    print(f"beta (N = {n}, eta from {args.beta_from:g} to below the susceptibility's peak at {peak:g}, "
          f"{len(keep)} points): {fit[0]:.3f}, 68% interval [{lo:.3f}, {hi:.3f}], eta_c(L) = {fit[1]:.3f}; "
          f"paper {PAPER['beta'][0]} +- {PAPER['beta'][1]}")
    return {"noises": noises, "mean": bm, "error": be, "fit": fit, "interval": (lo, hi)}


def power_law(ax, args, colours, name: str, series, xlabel: str, title: str) -> None:
    """The panel of exponent ``name`` in log-log form: for each of ``series``, ``(x, res,
    label, colour)``, the fitted points ``res["mean"]`` against ``x`` with their errors and
    our fit (``res["fit"]``: the exponent first, the log of the amplitude last), labelled
    with its 68 % interval; the paper's exponent (dashed) drawn through the last series'
    points."""
    symbol = rf"$\{name}$"
    for x, res, label, colour in series:
        exponent, ln_amplitude = res["fit"][0], res["fit"][-1]
        lo, hi = res["interval"]
        ax.errorbar(x, res["mean"], yerr=res["error"], fmt="o", ms=3, capsize=2, color=colour)
        grid = np.geomspace(x.min(), x.max(), 50)
        ax.plot(grid, np.exp(ln_amplitude) * grid**exponent, color=colour, lw=1,
                label=f"{label}: {symbol} = {exponent:.2f} [{lo:.2f}, {hi:.2f}]")
    mid = np.exp(np.mean(np.log(x)))
    anchor = np.exp(ln_amplitude) * mid**exponent
    ax.plot(grid, anchor * (grid / mid) ** PAPER[name][0], color=house.get_theme(args.theme).text, lw=1, ls="--",
            label=f"paper: {symbol} = {PAPER[name][0]:g}")
    ax.set_xscale("log")
    ax.set_yscale("log")
    house.label_axes(ax, xlabel, r"$v_a$")
    house.legend(ax, args.theme, loc="upper left")
    ax.set_title(title, fontsize=house.fontsize(ax.figure))
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_locator(LogLocator(subs=(1, 2, 3, 5)))
        axis.set_major_formatter(FormatStrFormatter("%g"))
        axis.set_minor_formatter(NullFormatter())


def figure(res: dict, args, path: str) -> None:
    """Fig. 2a, Fig. 2b and the two fits in log-log form, the paper's exponents beside ours."""
    fig, (a, b, c, d) = house.panels(args.size, args.theme, 4)
    colours = house.palette(args.theme)
    for k, (n, (noises, m, e)) in enumerate(res["fig2a"].items()):
        a.errorbar(noises, m, yerr=e, fmt="o-", ms=3, lw=1, capsize=2, color=colours[k % len(colours)],
                   label=f"N = {n}" + (" (aligned start)" if n >= args.aligned_from else ""))
    house.label_axes(a, r"noise $\eta$", r"$v_a$")
    a.set_ylim(0, 1.02)
    a.set_title(r"Fig. 2a: $\rho$ = 4", fontsize=house.fontsize(fig))
    house.legend(a, args.theme)
    m, e = res["fig2b"]
    b.errorbar(args.densities, m, yerr=e, fmt="o-", ms=3, lw=1, capsize=2, color=colours[0], label="ours")
    house.label_axes(b, r"density $\rho$", r"$v_a$")
    b.set_ylim(0, 1.02)
    b.set_title(r"Fig. 2b: L = 20, $\eta$ = 2", fontsize=house.fontsize(fig))

    fitted = {n: fit for n, fit in res["beta"].items() if fit is not None}
    if not fitted:
        c.text(0.5, 0.5, f"$\\beta$ not fitted:\nfewer than {BETA_POINTS} noises\nbelow the peak of $\\chi$", ha="center",
               va="center", transform=c.transAxes, color=house.get_theme(args.theme).text, fontsize=house.fontsize(fig))
        c.set_axis_off()
    else:
        series = [((fit["fit"][1] - np.asarray(fit["noises"])) / fit["fit"][1], fit,
                   f"N = {n}", colours[args.sizes.index(n) % len(colours)]) for n, fit in fitted.items()]
        eta_c = ", ".join(f"{fit['fit'][1]:.2f}" for fit in fitted.values())
        power_law(c, args, colours, "beta", series, rf"$(\eta_c - \eta)/\eta_c$, $\eta_c$ = {eta_c}",
                  r"$\beta$: Fig. 2a below $\eta_c$")
    d.errorbar(args.densities, m, yerr=e, fmt="o", ms=3, capsize=2, color=colours[0], alpha=0.35)
    power_law(d, args, colours, "delta", [(np.asarray(res["delta"]["densities"]), res["delta"], "fitted", colours[0])],
              r"density $\rho$", r"$\delta$: Fig. 2b at small density")
    big = [n for n in args.sizes if n >= args.aligned_from]
    aligned = f" (headings aligned for N = {', '.join(f'{n:,}' for n in big)})" if big else ""
    house.title(fig, "Vicsek et al. 1995: order against noise and density, and the exponents",
                f"$v_0$ = 0.03 · R = 1 · forward update · noise uniform in [$-\\eta/2$, $\\eta/2$] · "
                f"random start{aligned} · {args.replicas} systems a point, {args.steps:,} steps, first {args.discard:,} left out · "
                "bars: standard errors · fits: [68 % interval] · dashed: the paper's exponents drawn through our points "
                "(its curves could not be read here)")
    house.save(fig, path)


def parse(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", default=",".join(map(str, SIZES)), help="N for Fig. 2a, comma-separated")
    p.add_argument("--noises", default=",".join(map(str, NOISES)), help="eta for Fig. 2a, comma-separated")
    p.add_argument("--densities", default=",".join(map(str, DENSITIES)), help="rho for Fig. 2b")
    p.add_argument("--replicas", type=int, default=4)
    p.add_argument("--steps", type=int, default=8_000)
    p.add_argument("--discard", type=int, default=3_000)
    p.add_argument("--aligned-from", type=int, default=10_000,
                   help="the smallest N started with every heading equal (smaller N: random headings, as the paper)")
    p.add_argument("--beta-sizes", default="4000,10000",
                   help="the N fitted for beta, each one of --sizes, comma-separated (default: the two largest)")
    p.add_argument("--beta-noises", default=",".join(map(str, BETA_NOISES)),
                   help="more noises run for each of --beta-sizes, comma-separated (empty: none)")
    p.add_argument("--beta-from", type=float, default=1.0,
                   help="the lowest noise fitted for beta (the highest: the last below the susceptibility's peak)")
    p.add_argument("--delta-max", type=float, default=1.0, help="the largest density fitted for delta")
    p.add_argument("--bootstrap", type=int, default=400)
    p.add_argument("--seed", type=int, default=1995)
    p.add_argument("--threads", type=int, default=1,
                   help="numba threads (1: on a shared machine small systems run faster on one)")
    p.add_argument("--out", default="vicsek1995-figures.png")
    p.add_argument("--theme", default="light")
    p.add_argument("--size", default="page")
    args = p.parse_args(argv)

    def numbers(name: str, text: str, kind, low: float, low_open: bool = False) -> list:
        try:
            values = [kind(x) for x in text.split(",")]
        except ValueError:
            values = []
        if not values or any(not (v > low if low_open else v >= low) for v in values):
            p.error(f"{name}: comma-separated numbers, each {'>' if low_open else '>='} {low:g} (got {text!r})")
        return values

    args.sizes = numbers("--sizes", args.sizes, int, 1)
    args.noises = numbers("--noises", args.noises, float, 0.0)
    args.densities = numbers("--densities", args.densities, float, 0.0, low_open=True)
    for name, value, low in (("--replicas", args.replicas, 2), ("--steps", args.steps, 1), ("--discard", args.discard, 0),
                             ("--bootstrap", args.bootstrap, 1), ("--threads", args.threads, 1)):
        if value < low:
            p.error(f"{name}: must be >= {low} (got {value})")
    if args.discard >= args.steps:
        p.error(f"--discard: must be below --steps {args.steps} (got {args.discard})")
    args.beta_sizes = numbers("--beta-sizes", args.beta_sizes, int, 1)
    if any(n not in args.sizes for n in args.beta_sizes):
        p.error(f"--beta-sizes: each must be one of --sizes {args.sizes} (got {args.beta_sizes})")
    args.beta_noises = numbers("--beta-noises", args.beta_noises, float, 0.0) if args.beta_noises else []
    if sum(eta >= args.beta_from for eta in args.noises) < BETA_POINTS:
        p.error(f"--beta-from: at least {BETA_POINTS} of --noises must be >= it, to fit beta (got {args.beta_from:g})")
    if sum(rho <= args.delta_max for rho in args.densities) < 2:
        p.error(f"--delta-max: at least 2 of --densities must be <= it, to fit delta (got {args.delta_max:g})")
    house.check_figure_args(p, args)
    return args


def main(argv=None) -> dict:
    args = parse(argv)
    numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    started = time.perf_counter()
    res: dict = {"fig2a": {}, "chi": {}}
    per_size = {}
    for n in args.sizes:
        t0 = time.perf_counter()
        start = "aligned" if n >= args.aligned_from else "random"
        noises = noises_of(n, args)
        m1, m2 = order(n, 4.0, noises, args.replicas, args.steps, args.discard, args.seed, start)
        rank = np.argsort(noises)  # the seeds follow noises_of's order; the results ascend
        noises, m1, m2 = np.asarray(noises)[rank], m1[rank], m2[rank]
        per_size[n] = m1
        m, e = mean_error(m1)
        res["fig2a"][n] = (noises, m, e)
        res["chi"][n] = susceptibility(n, m1, m2)
        print(f"Fig. 2a  N = {n} (L = {np.sqrt(n / 4):.2f}), {start} headings at the start, "
              f"{time.perf_counter() - t0:.0f} s", flush=True)
        for eta, mi, ei, chi in zip(noises, m, e, res["chi"][n]):
            print(f"  eta {eta:<5g} v_a {mi:.3f} +- {ei:.3f}   chi {chi:.2f}")

    t0 = time.perf_counter()
    per_rho = np.concatenate([order(int(round(rho * 400)), rho, [2.0], args.replicas, args.steps, args.discard,
                                    args.seed + 7 * k)[0] for k, rho in enumerate(args.densities)])
    res["fig2b"] = mean_error(per_rho)
    print(f"Fig. 2b  L = 20, eta = 2, {time.perf_counter() - t0:.0f} s", flush=True)
    for rho, mi, ei in zip(args.densities, *res["fig2b"]):
        print(f"  rho {rho:<5g} N {int(round(rho * 400)):<5d} v_a {mi:.3f} +- {ei:.3f}")

    res["beta"] = {n: beta(n, args, res["fig2a"][n][0], res["chi"][n], per_size[n]) for n in args.beta_sizes}

    keep = [i for i, rho in enumerate(args.densities) if rho <= args.delta_max]
    rho = np.asarray(args.densities)[keep]
    dm, de = mean_error(per_rho[keep])
    fit = fit_delta(rho, dm, de)
    boot = bootstrap(fit_delta, rho, per_rho[keep], args.bootstrap, args.seed + 1)
    res["delta"] = {"densities": rho, "mean": dm, "error": de, "fit": fit, "interval": interval(boot)}
    print(f"delta (L = 20, eta = 2, rho <= {args.delta_max:g}, {len(keep)} points): {fit[0]:.3f}, 68% interval "
          f"[{res['delta']['interval'][0]:.3f}, {res['delta']['interval'][1]:.3f}]; "
          f"paper {PAPER['delta'][0]} +- {PAPER['delta'][1]}")
    figure(res, args, args.out)
    print(f"total {time.perf_counter() - started:.0f} s wall clock")
    return res


if __name__ == "__main__":
    main()
