"""The numbers examples/README.md quotes, measured on a run folder (or a .gsd file): means
over the frames of the second half of the run.

    python examples/measure.py mill

It prints what applies to the run:

* the polar order phi and the direction of the mean heading (degrees from +x);
* with obstacles, the milling order around the first one, M = <(r_i - c)/|r_i - c| x u_i>
  (2D, minimum image on periodic axes): +1 when every particle circles it counter-clockwise,
  -1 clockwise, near 0 for a flock that does not go round it;
* with several species, each species' polar order and heading, and the fraction of
  neighbour pairs (closer than R) of the same species, beside what a random mixture gives;
* the nematic order S = |<exp(2 i theta)>|, the direction of the common axis (degrees from
  +x, in (-90, 90]), the fraction of neighbour pairs moving the same way along the common
  axis (sorted by sense: near 1; mixed at random: the value printed beside it), and the
  fraction of the particles in the densest quarter of the box across the axis (32 strips
  parallel to the box side or diagonal nearest the axis, the densest 8 in a row,
  periodically): 0.25 for a uniform density, up to 1 for a dense band along the axis (a
  nematic lane).
"""

from __future__ import annotations

import argparse
import itertools
import os

import numpy as np

import flocking


def pairs(frame, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(i, j)``, ``i < j``, of the particles closer than ``radius`` (minimum image
    along periodic axes), from a grid of cells at least ``radius`` wide."""
    dim = frame.dim
    box = frame.box_lengths[:dim].astype(np.float64)
    periodic = ~np.asarray(frame.walls)[:dim]
    x = frame.points[:, :dim].astype(np.float64) + box / 2  # in [0, L] per axis
    x = np.where(periodic, np.mod(x, box), x)
    nc = np.maximum((box // radius).astype(np.int64), 1)
    cell = np.minimum((x / box * nc).astype(np.int64), nc - 1)
    key = np.ravel_multi_index(cell.T, nc)
    order = np.argsort(key, kind="stable")
    first = np.searchsorted(key[order], np.arange(np.prod(nc) + 1))
    found = []
    # the shifts to the neighbouring cells, each distinct cell once (a periodic axis of one
    # or two cells would otherwise repeat them)
    shifts = [sorted({k % n for k in (-1, 0, 1)}) if p else [-1, 0, 1] for n, p in zip(nc, periodic)]
    for shift in itertools.product(*shifts):
        other = cell + np.array(shift)
        other = np.where(periodic, np.mod(other, nc), other)
        i = np.flatnonzero(np.all((other >= 0) & (other < nc), axis=1))
        b = np.ravel_multi_index(other[i].T, nc)
        count = first[b + 1] - first[b]
        # every particle of cell b for each i: their places in ``order``
        start = np.repeat(first[b] - np.cumsum(count) + count, count)
        j = order[start + np.arange(count.sum())]
        i = np.repeat(i, count)
        found.append((i[i < j], j[i < j]))
    i, j = (np.concatenate(a) for a in zip(*found))
    d = x[i] - x[j]
    d = np.where(periodic, d - box * np.round(d / box), d)
    keep = np.einsum("ij,ij->i", d, d) < radius * radius
    return i[keep], j[keep]


def same_fraction(labels: np.ndarray, i: np.ndarray, j: np.ndarray) -> tuple[float, float]:
    """The fraction of pairs with equal labels, and its expectation for random labels."""
    counts = np.bincount(labels).astype(np.float64)
    n = counts.sum()
    return float(np.mean(labels[i] == labels[j])), float(np.sum(counts * (counts - 1)) / (n * (n - 1)))


def band(frame, axis: float, strips: int = 32) -> float:
    """The fraction of the particles in the densest ``strips // 4`` adjacent strips of
    ``strips`` parallel to the periodic line nearest the angle ``axis`` (radians): a box
    side or a diagonal, the directions along which a band closes on itself."""
    lx, ly = frame.box_lengths[:2]
    x, y = frame.points[:, 0] / lx, frame.points[:, 1] / ly
    lines = {0.0: y, np.pi / 2: x, np.arctan2(ly, lx): y - x, -np.arctan2(ly, lx): y + x}
    nearest = min(lines, key=lambda a: abs(np.sin(axis - a)))  # a coordinate across each line
    where = np.mod(lines[nearest], 1.0)  # positions centred on the box or not
    counts = np.bincount(np.minimum((where * strips).astype(np.int64), strips - 1), minlength=strips)
    window = np.convolve(np.concatenate([counts, counts[: strips // 4 - 1]]), np.ones(strips // 4), "valid")
    return float(window.max() / len(frame.points))


def angle(vector: np.ndarray) -> float:
    return float(np.degrees(np.arctan2(vector[1], vector[0])))


def measure(path: str) -> dict[str, float]:
    """The means over the second half of the frames of ``path``."""
    gsd = os.path.join(path, "trajectory.gsd") if os.path.isdir(path) else path
    traj = flocking.open(gsd)
    model = traj.parameters["model"]
    frames = [traj[k] for k in range(len(traj) // 2, len(traj))]
    nematic = model.get("alignment_rule") == "nematic"
    rows = []
    for frame in frames:
        u = frame.headings[:, : frame.dim].astype(np.float64)
        mean = u.mean(axis=0)
        row = {"phi": np.linalg.norm(mean), "heading": mean / np.linalg.norm(mean)}
        if len(frame.obstacles):
            c = frame.obstacles[0, : frame.dim]
            r = frame.points[:, : frame.dim] - c
            r = np.where(~np.asarray(frame.walls), r - frame.box_lengths * np.round(r / frame.box_lengths), r)
            r /= np.linalg.norm(r, axis=1)[:, None]
            row["milling"] = np.mean(r[:, 0] * u[:, 1] - r[:, 1] * u[:, 0])
        if len(frame.types) > 1 or nematic:  # the pair fractions below
            i, j = pairs(frame, model["radius"])
        if len(frame.types) > 1:
            for s, name in enumerate(frame.types):
                m = u[frame.typeid == s].mean(axis=0)
                row[f"phi_{name}"], row[f"heading_{name}"] = np.linalg.norm(m), m / np.linalg.norm(m)
            row["same_species"], row["same_species_random"] = same_fraction(frame.typeid.astype(np.int64), i, j)
        if nematic:
            theta = np.arctan2(u[:, 1], u[:, 0])
            q = np.mean(np.exp(2j * theta))
            row["nematic"] = abs(q)
            row["axis"] = np.array([q.real, q.imag]) / abs(q)  # the axis at twice its angle
            sense = (np.cos(theta - np.angle(q) / 2) > 0).astype(np.int64)
            row["same_sense"], row["same_sense_random"] = same_fraction(sense, i, j)
            row["band"] = band(frame, np.angle(q) / 2)
        rows.append(row)
    # a heading is the direction of the mean of the frames' unit mean headings
    means = {key: np.mean([r[key] for r in rows], axis=0) for key in rows[0]}
    result = {key: angle(v) if key.startswith("heading") else float(v) for key, v in means.items() if key != "axis"}
    if "axis" in means:
        result["axis"] = angle(means["axis"]) / 2
    return result | {"frames": len(rows), "from_step": frames[0].step, "to_step": frames[-1].step}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", help="a run folder or a .gsd file")
    args = parser.parse_args()
    if not os.path.exists(args.run):
        parser.error(f"run: no such folder or file (got {args.run!r})")
    for key, value in measure(args.run).items():
        print(f"{key:22s} {value:.3f}" if isinstance(value, float) else f"{key:22s} {value}")


if __name__ == "__main__":
    main()
