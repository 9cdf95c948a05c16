"""The numbers examples/README.md quotes, measured on a run folder (or a .gsd file): means
over the frames of the second half of the run; and the examples' figures, which show them.

    python examples/measure.py mill
    python examples/measure.py mill --figure mill.png --theme light --size page

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

``--figure`` draws the last frame (box coordinates, units of R) beside (``--layout side``)
or above (``below``; ``auto``: below in a paper column) the series of the order parameters
that tell the run's story, one value a frame: M for a mill, each species' polar order and
the whole flock's for a mixture, S and phi for nematic alignment, else phi; the second
half shaded, its means in the legend (the numbers printed).
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


def frame_values(frame, nematic: bool = False) -> dict:
    """The per-frame quantities of :func:`measure` that need no neighbour pairs: ``phi``
    and ``heading``; ``milling`` with obstacles; ``phi_<name>`` and ``heading_<name>``
    with several species; ``nematic`` and ``axis`` (a unit vector at twice the axis'
    angle) for a run with ``nematic`` alignment."""
    u = frame.headings[:, : frame.dim].astype(np.float64)
    mean = u.mean(axis=0)
    row = {"phi": np.linalg.norm(mean), "heading": mean / np.linalg.norm(mean)}
    if len(frame.obstacles):
        c = frame.obstacles[0, : frame.dim]
        r = frame.points[:, : frame.dim] - c
        r = np.where(~np.asarray(frame.walls), r - frame.box_lengths * np.round(r / frame.box_lengths), r)
        r /= np.linalg.norm(r, axis=1)[:, None]
        row["milling"] = np.mean(r[:, 0] * u[:, 1] - r[:, 1] * u[:, 0])
    if len(frame.types) > 1:
        for s, name in enumerate(frame.types):
            m = u[frame.typeid == s].mean(axis=0)
            row[f"phi_{name}"], row[f"heading_{name}"] = np.linalg.norm(m), m / np.linalg.norm(m)
    if nematic:
        q = np.mean(np.exp(2j * np.arctan2(u[:, 1], u[:, 0])))
        row["nematic"] = abs(q)
        row["axis"] = np.array([q.real, q.imag]) / abs(q)
    return row


def open_run(path: str):
    """The trajectory of a run folder or .gsd file, and its model's parameters."""
    gsd = os.path.join(path, "trajectory.gsd") if os.path.isdir(path) else path
    traj = flocking.open(gsd)
    return traj, traj.parameters["model"]


def measure(path: str) -> dict[str, float]:
    """The means over the second half of the frames of ``path``."""
    traj, model = open_run(path)
    frames = [traj[k] for k in range(len(traj) // 2, len(traj))]
    nematic = model.get("alignment_rule") == "nematic"
    rows = []
    for frame in frames:
        row = frame_values(frame, nematic)
        u = frame.headings[:, : frame.dim].astype(np.float64)
        if len(frame.types) > 1 or nematic:  # the pair fractions below
            i, j = pairs(frame, model["radius"])
        if len(frame.types) > 1:
            row["same_species"], row["same_species_random"] = same_fraction(frame.typeid.astype(np.int64), i, j)
        if nematic:
            q = row["axis"][0] + 1j * row["axis"][1]
            sense = (np.cos(np.arctan2(u[:, 1], u[:, 0]) - np.angle(q) / 2) > 0).astype(np.int64)
            row["same_sense"], row["same_sense_random"] = same_fraction(sense, i, j)
            row["band"] = band(frame, np.angle(q) / 2)
        rows.append(row)
    # a heading is the direction of the mean of the frames' unit mean headings
    means = {key: np.mean([r[key] for r in rows], axis=0) for key in rows[0]}
    result = {key: angle(v) if key.startswith("heading") else float(v) for key, v in means.items() if key != "axis"}
    if "axis" in means:
        result["axis"] = angle(means["axis"]) / 2
    return result | {"frames": len(rows), "from_step": frames[0].step, "to_step": frames[-1].step}


# -- the figure ---------------------------------------------------------------------------------

#: The series a figure shows, by what the run has: (key of :func:`frame_values`, legend, symbol).
MILLING = [("milling", "milling order", "M")]
NEMATIC = [("nematic", "nematic order", "S"), ("phi", "polar order", r"\varphi")]


def story(model: dict, types) -> list[tuple[str, str, str]]:
    """The series that tell a run's story: ``(key, name, mathtext symbol)`` each."""
    if model.get("obstacles"):
        return MILLING
    if model.get("alignment_rule") == "nematic":
        return NEMATIC
    if len(types) > 1:
        return [(f"phi_{name}", f"polar order of {name}", rf"\varphi_{{\mathrm{{{name}}}}}") for name in types] + \
            [("phi", "polar order of all", r"\varphi")]
    return [("phi", "polar order", r"\varphi")]


#: What each symbol means, for the caption.
DEFINITIONS = {
    "M": r"$M = \langle \hat{\mathbf{r}}_i \times \mathbf{u}_i \rangle$ about the disc's centre "
         "(+1: all circling it counter-clockwise, \u22121: clockwise, 0: no rotation)",
    "S": r"$S = |\langle e^{2i\theta_i} \rangle|$ (1: all along one axis, either way)",
}


def short(value: float) -> str:
    """Two decimals, or two significant digits below 0.1: as examples/README.md quotes.

    >>> short(0.9583), short(-0.7237), short(0.01512)
    ('0.96', '-0.72', '0.015')
    """
    return f"{value:.2f}" if abs(value) >= 0.1 else f"{value:.2g}"


def figure(path: str, out: str, theme: str = "light", size: str = "page", layout: str = "auto",
           style: str = "auto", dpi: float | None = None) -> dict[str, float]:
    """Draw the run at ``path``: its last frame and its story's series (:func:`story`), one
    value a frame, the second half shaded with each series' mean there (the numbers of
    :func:`measure`); the series ``side`` by side with the frame or ``below`` it (``auto``:
    below in a figure narrower than 5 inches, a paper column). Writes ``out``; returns
    the means."""
    from flocking.viz import style as house
    from flocking.viz.caption import describe, readout_lines, time_text
    from flocking.viz.keys import heading_key, species_key
    from flocking.viz.particles import FrameArtist

    traj, model = open_run(path)
    nematic = model.get("alignment_rule") == "nematic"
    frames = [traj[k] for k in range(len(traj))]
    rows = [frame_values(frame, nematic) for frame in frames]
    steps = np.array([f.step for f in frames])
    last = frames[-1]
    shown = story(model, last.types)
    half = len(frames) // 2

    t = house.get_theme(theme)
    width, height, fs = house.resolve_size(size)
    if layout == "auto":
        layout = "side" if width >= 5.0 else "below"
    box = last.box_lengths[:2]
    aspect = box[1] / box[0]
    key = 9.0 * fs / 72
    if layout == "side":  # the box, its key, the series: the box as tall as the series
        square = min(0.52 * width - key, 3.0)
        height = square * aspect + 1.6
        fig = house.new_figure(width, height, t, fs, dpi or house.DPI)
        grid = fig.add_gridspec(1, 3, width_ratios=[square, key, width - square - key], wspace=0.08)
        ax, key_ax, plot = (fig.add_subplot(grid[0, k]) for k in range(3))
    else:  # the box and its key on top, the series in a strip below
        square = width - key - 0.6
        height = square * aspect + 2.9
        fig = house.new_figure(width, height, t, fs, dpi or house.DPI)
        grid = fig.add_gridspec(2, 2, width_ratios=[square, key], height_ratios=[square * aspect, 1.3])
        ax, key_ax, plot = fig.add_subplot(grid[0, 0]), fig.add_subplot(grid[0, 1]), fig.add_subplot(grid[1, :])
    house.style_axes(ax, t)
    ax.grid(False)
    ax.set_facecolor(t.background)
    house.label_axes(ax, "x", "y")
    ax.set_xlim(0, box[0])
    ax.set_ylim(0, box[1])
    ax.set_aspect("equal")
    key_ax.set_anchor("W")
    colour = "species" if len(last.types) > 1 else "heading"
    readout = readout_lines(last.types, model.get("dt", 1.0), nematic)
    if colour == "species":
        _, text = species_key(key_ax, last.types, t, fs, readout)
    else:
        _, text = heading_key(key_ax, 2, t, fs, readout=readout)
    house.style_axes(plot, t)
    fig.get_layout_engine().execute(fig)
    FrameArtist(ax, last, theme=t, style=style, color=colour)
    text.set_text(time_text(last, model.get("dt", 1.0), nematic=nematic))

    colours = house.palette(t)
    means = {}
    plot.axvspan(steps[half], steps[-1], color=t.edge, alpha=0.18, lw=0)
    for (name, label, symbol), colour in zip(shown, colours):
        values = np.array([r[name] for r in rows])
        means[name] = float(values[half:].mean())
        plot.plot(steps, values, color=colour, lw=1.2, marker="o", ms=0.3 * fs,
                  label=rf"${symbol}$, {label}: $\langle {symbol}\rangle$ = {short(means[name])}")
        plot.plot([steps[half], steps[-1]], [means[name]] * 2, color=colour, lw=1.0, ls="--")
    signed = shown is MILLING  # M runs from -1 to 1
    plot.set_ylim(-1.02 if signed else 0.0, 1.02)
    plot.set_xlim(steps[0], steps[-1])
    if signed:
        plot.axhline(0.0, color=t.edge, lw=0.8)
    house.label_axes(plot, "step", "order parameter")
    house.legend(plot, t, loc="upper right" if signed else "best", handlelength=1.2)
    main, details = describe(traj.parameters, 2, last.n, box)
    defined = [DEFINITIONS[s] for _, _, s in shown if s in DEFINITIONS]
    house.title(fig, main, " \u00b7 ".join([details, *defined, f"shaded: the second half, steps {steps[half]:,} "
                                              f"to {steps[-1]:,}; dashed: its means"]))
    traj.close()
    house.save(fig, out, dpi=dpi)
    return means


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", help="a run folder or a .gsd file")
    parser.add_argument("--figure", default=None, help="also draw the run's figure to this file (.png, .svg, .pdf)")
    parser.add_argument("--theme", default="light", help="the figure's: dark or light")
    parser.add_argument("--size", default="page", help="the figure's: column, page or slide")
    parser.add_argument("--layout", default="auto", choices=("auto", "side", "below"),
                        help="the series beside the frame, or below it (auto: below in a paper column)")
    parser.add_argument("--style", default="auto", help="the frame's: auto, arrows or density")
    parser.add_argument("--dpi", type=float, default=None, help="the figure's pixels per inch")
    args = parser.parse_args()
    if not os.path.exists(args.run):
        parser.error(f"run: no such folder or file (got {args.run!r})")
    for key, value in measure(args.run).items():
        print(f"{key:22s} {value:.3f}" if isinstance(value, float) else f"{key:22s} {value}")
    if args.figure:
        figure(args.run, args.figure, args.theme, args.size, args.layout, args.style, args.dpi)


if __name__ == "__main__":
    main()
