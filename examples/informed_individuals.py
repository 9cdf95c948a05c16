"""Informed individuals steering a flock (Couzin, Krause, Franks and Levin, Nature 433, 513
(2005)): how well the group's mean heading follows a preferred direction g that only a
fraction p of its members knows.

The informed particles are a species with a field strength h > 0 (they add h n_i g to the
sum of their neighbours' headings); the others have none and only align. The accuracy of a
run is the mean, over its last steps, of cos(angle between the group's mean heading and g):
1 when the whole flock travels along g, 0 on average when it ignores g. Each point is the
mean over seeds, with the standard error of that mean (one time average per seed).

    python examples/informed_individuals.py --out accuracy.png --theme light --size column
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from flocking import Model, Simulation
from flocking.viz import style as house
from flocking.viz.timeseries import with_error

#: The flock: 256 particles at density 2 in a periodic box, angular noise 2 (ordered,
#: but turning noticeably), v0 = 0.5, R = 1; informed particles pull with h = 0.015 toward +x.
BASE = dict(n=256, density=2.0, speed=0.5, radius=1.0, noise=2.0, field=[1.0, 0.0])
FIELD_STRENGTH = 0.015
FRACTIONS = (0.0, 0.05, 0.1, 0.2, 0.4, 0.7, 1.0)
SEEDS = 8
STEPS, DISCARD, SAMPLE = 1500, 500, 10


def model(fraction: float, seed: int) -> Model:
    """The flock with ``fraction`` of informed particles (species ``informed``, ids first;
    none or all of them: one species, whose field strength is ``h`` or 0)."""
    n = BASE["n"]
    informed = round(fraction * n)
    if informed in (0, n):
        return Model(**BASE, field_strength=FIELD_STRENGTH if informed else 0.0, seed=seed)
    species = [{"name": "informed", "n": informed, "field_strength": FIELD_STRENGTH},
               {"name": "naive", "n": n - informed}]
    return Model(**BASE, species=species, seed=seed)


def accuracy(fraction: float, seed: int) -> float:
    """The mean of cos(mean heading, g) over the run after ``DISCARD`` steps."""
    sim = Simulation(model(fraction, seed))
    sim.run(DISCARD)
    samples = []
    while sim.step < STEPS:
        sim.run(SAMPLE)
        mean = sim.state.headings.mean(axis=0)
        samples.append(mean[0] / np.linalg.norm(mean))  # g = +x
    return float(np.mean(samples))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="informed_individuals.png", help="the figure (.png, .svg, .pdf)")
    parser.add_argument("--theme", default="light", help="dark or light")
    parser.add_argument("--size", default="column", help="column, page or slide")
    args = parser.parse_args()
    house.check_figure_args(parser, args)
    started = time.perf_counter()
    means, errors = [], []
    for p in FRACTIONS:
        values = np.array([accuracy(p, seed) for seed in range(SEEDS)])
        means.append(values.mean())
        errors.append(values.std(ddof=1) / np.sqrt(SEEDS))
        print(f"p = {p:<5g} informed {round(p * BASE['n']):3d}   accuracy {with_error(means[-1], errors[-1])}"
              .replace("$\\pm$", "+-"), flush=True)
    print(f"{len(FRACTIONS) * SEEDS} runs in {time.perf_counter() - started:.0f} s")

    t = house.get_theme(args.theme)
    width, height, _ = house.resolve_size(args.size)
    fig, ax = house.figure((width, height + 0.6), t)  # room for the caption's definitions
    ax.axhline(0.0, color=t.edge, lw=0.8)
    ax.errorbar(FRACTIONS, means, yerr=errors, color=house.palette(t)[0], marker="o", ms=4, lw=1.2, capsize=2.5)
    house.label_axes(ax, r"informed fraction $p$", r"accuracy $\langle\cos(\mathbf{m}, \mathbf{g})\rangle$")
    ax.set_ylim(min(-0.1, min(np.subtract(means, errors)) - 0.05), 1.05)  # every error bar whole
    house.title(fig, "Informed individuals steer the flock",
                f"$N$ = {BASE['n']} · $\\rho$ = {BASE['density']:g} · angular noise $\\eta$ = {BASE['noise']:g} · "
                f"the informed pull toward $\\mathbf{{g}}$ = $+x$ with field strength $h$ = {FIELD_STRENGTH:g} "
                "(adding $h\\, n_i\\, \\mathbf{g}$ to the sum of their $n_i$ neighbours' headings) · "
                f"$\\mathbf{{m}}$: the flock's mean heading, averaged over steps {DISCARD}-{STEPS} · "
                f"bars: standard error of the mean over {SEEDS} seeds")
    house.save(fig, args.out)


if __name__ == "__main__":
    main()
