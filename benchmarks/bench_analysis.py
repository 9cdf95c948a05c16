"""Time every analysis on one 10^6-particle 2D frame (density 2, R = 1).

    python benchmarks/bench_analysis.py [--n 1000000] [--ordered]

The frame is uniform (or, with --ordered, banded with aligned headings); the MSD uses
ten frames like it, as does the polar order, and also 1001 frames of 2000 random walkers
(the case that took 105 s before the MSD went to FFT). Compilation is excluded: each
quantity runs once on a small frame first.
"""

import argparse
import time

import numpy as np

import flocking.analysis as fa
from flocking.analysis.snapshots import from_box_points


def moved(base, rng, step):
    """``base`` a few steps later: every particle moved along +x by 0.3 per step, with jitter."""
    pts = base.positions + [0.3 * step, 0.0] + rng.normal(0, 0.05, base.positions.shape)
    return from_box_points(base.box, pts % base.box, base.headings, step=step)


def frame(n, ordered, rng):
    box = float(np.sqrt(n / 2.0))
    pts = rng.uniform(0, box, (n, 2))
    if ordered:  # a third of the particles in a band, all heading along +x
        k = n // 3
        pts[:k, 0] = rng.uniform(0, box / 10, k)
        theta = rng.normal(0, 0.3, n)
    else:
        theta = rng.uniform(0, 2 * np.pi, n)
    return from_box_points(box, pts, np.c_[np.cos(theta), np.sin(theta)])


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--n", type=int, default=1_000_000)
    parser.add_argument("--ordered", action="store_true")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    jobs = {
        "PolarOrder (10 frames)": (fa.PolarOrder, "frames"),
        "NumberFluctuations": (fa.NumberFluctuations, None),
        "VelocityCorrelation (cells, r_max 5)": (lambda: fa.VelocityCorrelation(r_max=5.0, method="cells"), None),
        "VelocityCorrelation (auto, r_max L/2)": (fa.VelocityCorrelation, None),
        "DensityProfile": (fa.DensityProfile, None),
        "Clusters (R = 1)": (lambda: fa.Clusters(radius=1.0), None),
        "BoxCounting": (fa.BoxCounting, None),
        "MeanSquareDisplacement (10 frames)": (fa.MeanSquareDisplacement, "frames"),
    }
    walkers = np.cumsum(rng.normal(0, 0.3, (1001, 2000, 2)), axis=0) % 100.0
    walks = [from_box_points(100.0, p, step=t) for t, p in enumerate(walkers)]
    small = frame(5000, args.ordered, rng)
    small_frames = [moved(small, rng, t) for t in range(3)]
    big = frame(args.n, args.ordered, rng)
    many = [moved(big, rng, t) for t in range(10)]
    print(f"N = {args.n}, box {big.box[0]:.1f}, {'ordered' if args.ordered else 'uniform'}")
    for name, (make, data) in jobs.items():
        warm, system = (small_frames, many) if data == "frames" else (small, big)
        make().compute(warm)
        t0 = time.perf_counter()
        make().compute(system)
        print(f"{name:40s} {time.perf_counter() - t0:8.2f} s")
    fa.MeanSquareDisplacement().compute(walks[:3])
    t0 = time.perf_counter()
    fa.MeanSquareDisplacement().compute(walks)
    print(f"{'MeanSquareDisplacement (1001 x 2000)':40s} {time.perf_counter() - t0:8.2f} s")


if __name__ == "__main__":
    main()
