"""Chate, Ginelli, Gregoire and Raynaud, PRE 77, 046113 (2008), three of its results on
the Vicsek model: giant number fluctuations in the statistically homogeneous ordered
phase, the travelling bands near the threshold, and (quoted, not rerun) the small-L
Binder cumulant of examples/finite_size.py.

Conventions, from the paper: angular ("intrinsic") noise, theta_i(t+1) = arg sum_j
exp(i theta_j) + eta xi with xi uniform in [-pi, pi] and eta in [0, 1] (noise_scale =
"unit"); v0 = 0.5, R = 1, time step 1; the backward update (positions move with the new
headings); periodic boxes. Every run starts from uniform positions with every heading along
+x (State.aligned), which skips the slow ordering of a random start.

1. Number fluctuations: density 2, eta = 0.3 (ordered, far from the threshold), a square
   box of side --gnf-box. Frames every --gnf-every steps after --gnf-equilibrate steps;
   flocking.analysis.NumberFluctuations counts particles in square sub-boxes of side
   L / m and fits dn ~ <n>^alpha (its error: the larger of the fit's and a jackknife over
   frames).
2. Bands: density 1, eta = 0.4 (just below the onset at this density: eta = 0.45 and 0.5
   stayed disordered in the same box), boxes --band-boxes long along x and 32 across.
   flocking.analysis.DensityProfile along x (slabs of R/2) finds the bands of each frame
   and their speed between frames. The profile in the band's frame is the mean over the
   frames that hold exactly one band of their profiles shifted so that the band's front
   sits at x = 0, x growing along the motion. Front and tail: exponentials fitted to the
   excess rho - rho_gas (rho_gas: the median of the mean profile) where it falls from 50 %
   to 5 % of the peak's, ahead of the peak and behind it.
3. The Binder cumulant at L = 16 and 32 (density 2), read from examples/finite_size.png
   (its command is in docs/figures.toml; 13.5 min on 2 busy cores), +-0.005.

The paper's values are printed beside ours. The exponent 0.8 is the value the paper gives
for the 2D Vicsek model's ordered phase; the paper's own figures could not be read here,
so no band speed, band width or decay length of the paper is quoted (see
docs/literature.md).

    python examples/chate2008.py --out chate2008.png
    # 2.7 to 6 min wall clock (about 100 s of CPU time) on the project's 2 cores, as other
    # programs kept them busy (load average 5 to 14)
    # the scale of tests/test_literature_chate2008.py (about a minute):
    python examples/chate2008.py --gnf-box 64 --gnf-steps 3000 --gnf-equilibrate 1000 \
        --band-boxes 256 --band-steps 2000 --band-equilibrate 4000 --out small.png
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from flocking import Model, Simulation, State
from flocking.analysis import DensityProfile, NumberFluctuations
from flocking.state import frame_arrays
from flocking.trajectory import Frame
from flocking.viz import style as house

BASE = dict(speed=0.5, radius=1.0, noise_type="angular", noise_scale="unit")
GNF = dict(density=2.0, noise=0.3)
BANDS = dict(density=1.0, noise=0.4)
BAND_WIDTH_Y = 32.0
SLAB = 0.5  # the band profile's slab width
#: the paper's values (see the module docstring)
PAPER_ALPHA = 0.8
POISSON_ALPHA = 0.5
#: examples/finite_size.png, read by eye (+-0.005): G against eta for L = 16 and 32
FINITE_SIZE_NOISES = (0.35, 0.45, 0.5, 0.55, 0.6, 0.65, 0.75)
FINITE_SIZE_BINDER = {16: (0.665, 0.625, 0.522, 0.450, 0.357, 0.365, 0.337),
                      32: (0.665, 0.603, 0.450, 0.375, 0.345, 0.349, 0.334)}
READ_PRECISION = 0.005


def frames_of(model: Model, steps: int, equilibrate: int, every: int, seed_state: State | None = None):
    """``(frames, polar orders)``: a run from the aligned state, a frame every ``every``
    steps after ``equilibrate``."""
    sim = Simulation(model, seed_state if seed_state is not None else State.aligned(model))
    sim.run(equilibrate)
    frames, phi = [], []
    while sim.step < equilibrate + steps:
        sim.run(every)
        points, velocities = frame_arrays(sim.state, model.box)
        frames.append(Frame(sim.step, 2, model.box, points, velocities))
        phi.append(sim.state.polar_order())
    return frames, np.array(phi)


def fluctuations(box: float, steps: int, equilibrate: int, every: int, seed: int = 1) -> dict:
    """Giant number fluctuations in the ordered phase: ``<n>``, ``dn`` per sub-box side,
    ``alpha`` and its error, the mean polar order."""
    model = Model(box=box, seed=seed, **GNF, **BASE)
    frames, phi = frames_of(model, steps, equilibrate, every)
    nf = NumberFluctuations().compute(frames)
    # dn's error bar: the spread of dn over four quarters of the run (frames close in time
    # are correlated, so the counts' own sampling error would understate it)
    quarters = [NumberFluctuations(sizes=nf.sizes).compute(q).std for q in np.array_split(np.arange(len(frames)), 4)
                for q in [[frames[i] for i in q]]]
    std_error = np.std(quarters, axis=0, ddof=1) / 2.0
    return {"box": box, "n": model.n, "frames": len(frames), "sizes": nf.sizes, "mean": nf.mean, "std": nf.std,
            "std_error": std_error,
            "fitted": nf.fitted, "alpha": float(nf.alpha), "alpha_error": float(nf.alpha_error),
            "intercept": float(nf.intercept), "order": float(phi.mean())}


def front_slab(profile: np.ndarray) -> int:
    """The front of the densest band of a profile (``x`` along the motion): the last slab
    ahead of the densest one where the profile, smoothed over three slabs, is still above
    half-way between its median and its maximum."""
    smooth = (np.roll(profile, 1) + profile + np.roll(profile, -1)) / 3.0
    level = 0.5 * (np.median(smooth) + smooth.max())
    j = int(np.argmax(smooth))
    for _ in range(len(profile)):
        if smooth[(j + 1) % len(profile)] < level:
            break
        j += 1
    return j % len(profile)


def fall(x: np.ndarray, excess: np.ndarray, high: float, low: float) -> tuple[float, np.ndarray]:
    """From the peak outward (``x``, ``excess`` ordered away from it): the distance over
    which the excess first falls from ``high`` to ``low``, and the mask of those points."""
    below_high = int(np.argmax(excess <= high))
    below_low = int(np.argmax(excess <= low))
    mask = np.zeros(len(x), bool)
    mask[below_high:below_low + 1] = True
    return float(abs(x[below_low] - x[below_high])), mask


def decay_length(x: np.ndarray, excess: np.ndarray, mask: np.ndarray) -> tuple[float, float]:
    """``(length, error)`` of an exponential fitted to ``excess`` over ``mask``: the slope
    of ``log excess`` against ``|x|`` (least squares, its formal error); NaN with fewer
    than three points."""
    if mask.sum() < 3:
        return float("nan"), float("nan")
    (slope, _), cov = np.polyfit(np.abs(x[mask]), np.log(excess[mask]), 1, cov=True)
    return float(-1.0 / slope), float(np.sqrt(cov[0, 0]) / slope**2)


def bands(length: float, steps: int, equilibrate: int, every: int, seed: int = 3) -> dict:
    """The bands of one run in a ``length x 32`` box: their number per frame, speed, the
    mean profile in the band's frame (each frame's profile shifted so that the front of its
    densest band sits at x = 0), the distances over which the excess density falls from
    50 % to 5 % of the peak's ahead of and behind the peak, and the decay lengths of
    exponentials fitted to the excess over those stretches (the front's and the tail's)."""
    model = Model(box=(length, BAND_WIDTH_Y), seed=seed, **BANDS, **BASE)
    frames, phi = frames_of(model, steps, equilibrate, every)
    dp = DensityProfile(direction=0, bin_width=SLAB).compute(frames)
    profiles = dp.profiles[:, ::dp.heading_sign]  # x grows along the motion
    nbins = profiles.shape[1]
    width = dp.period / nbins
    home = (3 * nbins) // 4  # the front's slab after the shift: most of the box lies behind it
    single = dp.band_counts == 1  # the profile of one band: frames holding exactly one
    chosen = profiles[single] if single.any() else profiles
    mean = np.array([np.roll(p, home - front_slab(p)) for p in chosen]).mean(axis=0)
    x = (np.arange(nbins) - home) * width
    gas = float(np.median(mean))
    excess = mean - gas
    peak = int(np.argmax(mean))
    top = excess[peak]
    ahead, ahead_mask = fall(x[peak:], excess[peak:], 0.5 * top, 0.05 * top)
    behind, mask = fall(x[peak::-1], excess[peak::-1], 0.5 * top, 0.05 * top)
    speeds = dp.band_speeds[np.isfinite(dp.band_speeds)]
    return {"box": (length, BAND_WIDTH_Y), "n": model.n, "frames": len(frames), "order": float(phi.mean()),
            "band_counts": dp.band_counts, "band_width": float(dp.band_width),
            "speed": float(speeds.mean()) if len(speeds) else float("nan"),
            "speed_error": float(speeds.std(ddof=1) / np.sqrt(len(speeds))) if len(speeds) > 1 else float("nan"),
            "profiled": len(chosen), "x": x, "profile": mean, "gas": gas, "peak_density": float(mean[peak]),
            "peak_x": float(x[peak]),
            "ahead": ahead, "behind": behind, "tail_points": int(mask.sum()), "front_points": int(ahead_mask.sum()),
            "front": decay_length(x[peak:], excess[peak:], ahead_mask),
            "tail": decay_length(x[peak::-1], excess[peak::-1], mask)}


def figure(gnf: dict, runs: list[dict], path: str, theme: str, size: str) -> None:
    """Left: dn against <n> with the fit, the paper's 0.8 and the Poisson 1/2; middle: the
    band profile in its frame (log scale of the excess); right: the Binder cumulant read
    from examples/finite_size.png."""
    fig, axes = house.panels(size, theme, 3)
    colours = house.palette(theme)
    ax = axes[0]
    mean, std, fitted = gnf["mean"], gnf["std"], gnf["fitted"]
    ax.errorbar(mean, std, yerr=gnf["std_error"], fmt="o", ms=3.5, capsize=2, color=colours[0],
                label=f"ours, L = {gnf['box']:g}")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ref = mean[fitted][0]
    x = np.geomspace(mean.min(), mean.max(), 50)
    ax.loglog(x, np.exp(gnf["intercept"]) * x ** gnf["alpha"], "-", color=colours[0], lw=1,
              label=rf"fit $\alpha$ = {gnf['alpha']:.3f} ± {gnf['alpha_error']:.3f}")
    y0 = np.exp(gnf["intercept"]) * ref ** gnf["alpha"]
    ax.loglog(x, y0 * (x / ref) ** PAPER_ALPHA, "--", color=colours[1], lw=1, label=rf"paper $\alpha$ = {PAPER_ALPHA}")
    ax.loglog(x, y0 * (x / ref) ** POISSON_ALPHA, ":", color=colours[-1], lw=1, label=r"Poisson $\alpha$ = 1/2")
    house.label_axes(ax, r"$\langle n\rangle$", r"$\Delta n$")
    house.legend(ax, theme, loc="upper left")
    ax = axes[1]
    for k, run in enumerate(runs):
        ax.semilogy(run["x"], np.clip(run["profile"] - run["gas"], 1e-3, None), "-", lw=1.2,
                    color=colours[(k + 2) % len(colours)],
                    label=(f"{run['box'][0]:g}×{run['box'][1]:g}: front {run['front'][0]:.1f}, "
                           f"tail {run['tail'][0]:.1f}"))
    ax.set_xlim(-110, 30)
    ax.set_ylim(1e-2, 40.0)
    house.label_axes(ax, r"$x$ along the motion (band frame)", r"$\rho - \rho_{gas}$")
    house.legend(ax, theme, loc="upper left")
    ax = axes[2]
    for k, (length, values) in enumerate(FINITE_SIZE_BINDER.items()):
        ax.errorbar(FINITE_SIZE_NOISES, values, yerr=READ_PRECISION, fmt="o-", ms=3, lw=1, capsize=2,
                    color=colours[k % len(colours)], label=f"L = {length}")
    ax.axhline(1 / 3, color=colours[-1], lw=0.8, ls=":")
    house.label_axes(ax, r"noise $\eta$", "G (read from finite_size.png)")
    house.legend(ax, theme, loc="upper right")
    house.title(fig, "Chaté et al. 2008: number fluctuations, bands, Binder cumulant",
                r"angular noise · $v_0$ = 0.5 · GNF $\rho$ = 2, $\eta$ = 0.3 · bands $\rho$ = 1, $\eta$ = 0.4")
    house.save(fig, path)


def report(gnf: dict, runs: list[dict]) -> None:
    """Print every number docs/literature.md quotes, the paper's beside ours."""
    print(f"GNF: L = {gnf['box']:g}, N = {gnf['n']}, {gnf['frames']} frames, <phi> = {gnf['order']:.3f}")
    for side, m, s, e, f in zip(gnf["sizes"], gnf["mean"], gnf["std"], gnf["std_error"], gnf["fitted"]):
        print(f"  l = {side:7.3f}  <n> = {m:9.2f}  dn = {s:8.3f} +- {e:.3f}{'' if f else '  (not fitted)'}")
    print(f"  alpha = {gnf['alpha']:.3f} +- {gnf['alpha_error']:.3f}   paper: {PAPER_ALPHA}   Poisson: {POISSON_ALPHA}")
    for run in runs:
        counts = run["band_counts"]
        values, times = np.unique(counts, return_counts=True)
        share = ", ".join(f"{v}: {t}" for v, t in zip(values, times))
        print(f"bands: box {run['box'][0]:g} x {run['box'][1]:g}, N = {run['n']}, {run['frames']} frames, "
              f"<phi> = {run['order']:.3f}")
        print(f"  bands per frame (count: frames) {share}; equivalent width {run['band_width']:.1f}")
        print(f"  speed = {run['speed']:.3f} +- {run['speed_error']:.3f} (v0 = {BASE['speed']})")
        print(f"  profile of the {run['profiled']} frames with one band: peak density {run['peak_density']:.2f}, "
              f"gas {run['gas']:.3f} (mean {BANDS['density']:g})")
        print(f"  excess from 50 % to 5 % of the peak's: over {run['ahead']:.1f} ahead of the peak, "
              f"{run['behind']:.1f} behind it (peak at x = {run['peak_x']:.1f} from the front)")
        print(f"  decay length: front {run['front'][0]:.2f} +- {run['front'][1]:.2f} ({run['front_points']} slabs "
              f"of {SLAB}), tail {run['tail'][0]:.2f} +- {run['tail'][1]:.2f} ({run['tail_points']} slabs)")
    for length, values in FINITE_SIZE_BINDER.items():
        low = int(np.argmin(values))
        print(f"Binder (read from examples/finite_size.png, +-{READ_PRECISION}): L = {length}: "
              f"smallest G = {values[low]:.3f} at eta = {FINITE_SIZE_NOISES[low]}, "
              f"G(0.75) = {values[-1]:.3f}; none below 1/3")


def parse(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--gnf-box", type=float, default=128.0)
    p.add_argument("--gnf-steps", type=int, default=8_000, help="steps measured (after --gnf-equilibrate)")
    p.add_argument("--gnf-equilibrate", type=int, default=2_000)
    p.add_argument("--gnf-every", type=int, default=100)
    p.add_argument("--band-boxes", default="256,512", help="band box lengths along x, comma-separated")
    p.add_argument("--band-steps", type=int, default=4_000)
    p.add_argument("--band-equilibrate", type=int, default=8_000)
    p.add_argument("--band-every", type=int, default=50)
    p.add_argument("--out", default="chate2008.png")
    p.add_argument("--theme", default="light")
    p.add_argument("--size", default="page")
    args = p.parse_args(argv)
    house.check_figure_args(p, args)
    try:
        args.band_boxes = [float(x) for x in args.band_boxes.split(",")]
    except ValueError:
        p.error(f"--band-boxes: must be box lengths such as 256,512 (got {args.band_boxes!r})")
    for name in ("gnf_steps", "gnf_every", "band_steps", "band_every"):
        if getattr(args, name) <= 0:
            p.error(f"--{name.replace('_', '-')}: must be positive (got {getattr(args, name)})")
    if args.gnf_steps // args.gnf_every < 4:  # dn's error bars need four quarters of frames
        p.error(f"--gnf-steps: must give at least 4 frames, 4 x --gnf-every (got {args.gnf_steps})")
    if args.band_steps // args.band_every < 2:  # a speed needs two frames
        p.error(f"--band-steps: must give at least 2 frames, 2 x --band-every (got {args.band_steps})")
    return args


def main(argv=None) -> tuple[dict, list[dict]]:
    args = parse(argv)
    start = time.time()
    gnf = fluctuations(args.gnf_box, args.gnf_steps, args.gnf_equilibrate, args.gnf_every)
    runs = [bands(length, args.band_steps, args.band_equilibrate, args.band_every) for length in args.band_boxes]
    report(gnf, runs)
    figure(gnf, runs, args.out, args.theme, args.size)
    print(f"wall clock {time.time() - start:.0f} s")
    return gnf, runs


if __name__ == "__main__":
    main()
