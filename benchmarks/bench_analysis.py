"""Time every analysis on one 10^6-particle 2D frame (density 2, R = 1).

    python benchmarks/bench_analysis.py [--n 1000000] [--ordered]

The frame is uniform (or, with --ordered, banded with aligned headings); the MSD uses
ten frames like it, as does the polar order. Compilation is excluded: each quantity runs once on a small frame first.
"""

import argparse
import time

import numpy as np

import flocking.analysis as fa
from flocking.analysis._input import from_box_points


def frame(n, ordered, rng, shift=0.0, step=0):
    box = float(np.sqrt(n / 2.0))
    pts = rng.uniform(0, box, (n, 2))
    if ordered:  # a third of the particles in a band, all heading along +x
        k = n // 3
        pts[:k, 0] = rng.uniform(0, box / 10, k)
        theta = rng.normal(0, 0.3, n)
    else:
        theta = rng.uniform(0, 2 * np.pi, n)
    pts[:, 0] = (pts[:, 0] + shift) % box
    return from_box_points(box, pts, np.c_[np.cos(theta), np.sin(theta)], step=step)


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
    small = frame(5000, args.ordered, rng)
    small_frames = [frame(5000, args.ordered, rng, 0.1 * t, t) for t in range(3)]
    big = frame(args.n, args.ordered, rng)
    many = [frame(args.n, args.ordered, rng, 0.3 * t, t) for t in range(10)]
    print(f"N = {args.n}, box {big.box[0]:.1f}, {'ordered' if args.ordered else 'uniform'}")
    for name, (make, data) in jobs.items():
        warm, system = (small_frames, many) if data == "frames" else (small, big)
        make().compute(warm)
        t0 = time.perf_counter()
        make().compute(system)
        print(f"{name:40s} {time.perf_counter() - t0:8.2f} s")


if __name__ == "__main__":
    main()
