"""The finite-size study of Chate, Ginelli, Gregoire and Raynaud (PRE 77, 046113 (2008)):
the polar order <phi>, its susceptibility chi = N (<phi^2> - <phi>^2) and the Binder
cumulant G = 1 - <phi^4> / (3 <phi^2>^2) against the noise, for a series of box sizes L.

The Vicsek model with angular noise (eta in [0, 1], noise_scale = "unit"), density 2,
v0 = 0.5, R = 1. Every (L, eta) point runs ``--replicas`` replicas (seeds); all points of
one L run as one :class:`flocking.Ensemble` (on the cpu backend one system after another;
with ``--backend cuda`` in one set of launches). Moments are time averages after
``--equilibrate`` steps, pooled over replicas; error bars are standard errors over the
replicas. Every ``--block`` steps the study saves the replicas' exact states and its sums
in ``--state`` (one folder per L), so a study stopped at any time goes on from there when
the same command is given again, bit for bit as if it had never stopped.

    python examples/finite_size.py --sizes 16,32 --steps 10000 --equilibrate 3000 --out finite_size.png
    # cpu: 13.5 min on 2 busy cores (load about 10), the figure committed as examples/finite_size.png
    python examples/finite_size.py --sizes 64,128,256 --backend cuda --precision float32 --steps 100000
"""

from __future__ import annotations

import argparse
import json
import os

import numpy as np

from flocking import Ensemble, Model
from flocking.files import replace_atomically
from flocking.state import State
from flocking.viz import style as house

BASE = dict(density=2.0, speed=0.5, radius=1.0, noise_type="angular", noise_scale="unit")
NOISES = (0.35, 0.45, 0.5, 0.55, 0.6, 0.65, 0.75)


def models_of(size: float, noises, replicas: int) -> list[Model]:
    """The replicas of every noise at box side ``size``, noise by noise."""
    return [Model(box=size, noise=eta, seed=1000 * i + r, **BASE)
            for i, eta in enumerate(noises) for r in range(replicas)]


def save(folder: str, ens: Ensemble, sums: np.ndarray, done: int) -> None:
    """The replicas' states and memories, the moment sums and the steps done (atomically:
    the states first, then the progress file that points at them)."""
    arrays = {"sums": sums}
    for r, (state, memory) in enumerate(zip(ens.states, ens.memory())):
        arrays.update({f"{r}_positions": state.positions, f"{r}_headings": state.headings,
                       f"{r}_speeds": np.ascontiguousarray(state.speeds)})
        arrays.update({f"{r}_memory_{k}": v for k, v in memory.items()})
    with replace_atomically(os.path.join(folder, f"states-{done}.npz"), "wb") as f:
        np.savez(f, **arrays)
    old = progress(folder)
    with replace_atomically(os.path.join(folder, "progress.json"), "w") as f:
        json.dump({"done": done}, f)
    if old and old != done:
        os.remove(os.path.join(folder, f"states-{old}.npz"))


def progress(folder: str) -> int:
    path = os.path.join(folder, "progress.json")
    if not os.path.exists(path):
        return 0
    with open(path, encoding="utf-8") as f:
        return int(json.load(f)["done"])


def load(folder: str, models: list[Model], done: int):
    """``(states, memories, sums)`` saved after ``done`` steps."""
    with np.load(os.path.join(folder, f"states-{done}.npz")) as data:
        states = [State(data[f"{r}_positions"], data[f"{r}_headings"], data[f"{r}_speeds"], done)
                  for r in range(len(models))]
        memories = [{k.split("_memory_")[1]: data[k] for k in data.files if k.startswith(f"{r}_memory_")}
                    for r in range(len(models))]
        return states, memories, data["sums"].copy()


def study_size(size: float, args, stop_after: int | None = None) -> np.ndarray | None:
    """The sums ``(replicas, 4)`` of 1, phi, phi^2, phi^4 over the measured steps of every
    replica at box side ``size`` (``None`` if stopped after ``stop_after`` blocks)."""
    folder = os.path.join(args.state, f"L{size:g}")
    os.makedirs(folder, exist_ok=True)
    models = models_of(size, args.noises, args.replicas)
    done = progress(folder)
    if done:
        states, memories, sums = load(folder, models, done)
        ens = Ensemble(models, states, backend=args.backend, precision=args.precision, memories=memories)
    else:
        sums = np.zeros((len(models), 4))
        ens = Ensemble(models, backend=args.backend, precision=args.precision)
    blocks = 0
    while done < args.steps:
        steps = min(args.block, args.steps - done)
        phi = ens.advance(steps)
        measured = phi[:, max(0, args.equilibrate - done):]
        sums += np.stack([np.full(len(models), measured.shape[1]), measured.sum(1), (measured**2).sum(1),
                          (measured**4).sum(1)], axis=1)
        done += steps
        save(folder, ens, sums, done)
        blocks += 1
        if stop_after is not None and blocks >= stop_after and done < args.steps:
            return None
    return sums


def moments(sums: np.ndarray, n: int, noises, replicas: int) -> dict:
    """Per noise: <phi>, chi, G pooled over replicas, with standard errors over them."""
    per = sums.reshape(len(noises), replicas, 4)
    m1, m2, m4 = (per[..., k] / per[..., 0] for k in (1, 2, 3))  # each replica's time means
    out = {"noise": list(noises)}
    for name, values in (("order", m1), ("susceptibility", n * (m2 - m1**2)),
                         ("binder", 1.0 - m4 / (3.0 * m2**2))):
        pooled = {"order": m1.mean(1), "susceptibility": n * (m2.mean(1) - m1.mean(1) ** 2),
                  "binder": 1.0 - m4.mean(1) / (3.0 * m2.mean(1) ** 2)}[name]
        error = values.std(1, ddof=1) / np.sqrt(replicas) if replicas > 1 else np.full(len(noises), np.nan)
        out[name], out[name + "_error"] = pooled.tolist(), error.tolist()
    return out


def figure(results: dict, path: str, theme: str, size: str) -> None:
    """Order, susceptibility and Binder cumulant against the noise, a curve per L."""
    fig, axes = house.panels(size, theme, 3)
    colours = house.palette(theme)
    for k, (length, res) in enumerate(sorted(results.items(), key=lambda item: float(item[0]))):
        for ax, name in zip(axes, ("order", "susceptibility", "binder")):
            ax.errorbar(res["noise"], res[name], yerr=res[name + "_error"], fmt="o-", ms=3, lw=1, capsize=2,
                        color=colours[k % len(colours)], label=f"L = {float(length):g}")
    for ax, label in zip(axes, (r"$\langle\varphi\rangle$", r"$\chi$", "G")):
        house.label_axes(ax, r"noise $\eta$", label)
    axes[1].set_yscale("log")
    house.legend(axes[0], theme)
    house.title(fig, "Finite-size scaling of the Vicsek transition",
                r"angular noise · $\rho$ = 2 · $v_0$ = 0.5 · replicas pooled, bars: standard errors")
    house.save(fig, path)


def parse(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", default="16,32", help="box sides L, comma-separated")
    p.add_argument("--noises", default=",".join(map(str, NOISES)), help="eta in [0, 1], comma-separated")
    p.add_argument("--replicas", type=int, default=4)
    p.add_argument("--steps", type=int, default=20_000)
    p.add_argument("--equilibrate", type=int, default=5_000)
    p.add_argument("--block", type=int, default=1_000, help="steps between saved states")
    p.add_argument("--backend", default="cpu")
    p.add_argument("--precision", default="float64")
    p.add_argument("--state", default="finite_size_state", help="folder of the saved states and results")
    p.add_argument("--out", default="finite_size.png")
    p.add_argument("--theme", default="light")
    p.add_argument("--size", default="page")
    args = p.parse_args(argv)
    house.check_figure_args(p, args)
    args.sizes = [float(x) for x in args.sizes.split(",")]
    args.noises = [float(x) for x in args.noises.split(",")]
    return args


def main(argv=None, stop_after: int | None = None) -> dict | None:
    """Run (or go on with) the study; write ``results.json`` in ``--state`` and the figure.
    ``stop_after`` blocks (a test's interruption) returns ``None`` early."""
    args = parse(argv)
    results = {}
    for size in args.sizes:
        sums = study_size(size, args, stop_after)
        if sums is None:
            return None
        n = Model(box=size, **BASE).n
        results[f"{size:g}"] = {"n": n, **moments(sums, n, args.noises, args.replicas)}
    with replace_atomically(os.path.join(args.state, "results.json"), "w") as f:
        json.dump(results, f, indent=1)
    figure(results, args.out, args.theme, args.size)
    return results


if __name__ == "__main__":
    main()
