"""``flocking run``: simulate one flock and leave a folder a person can open."""

from __future__ import annotations

import os
import signal
import sys
import time

import click

from ..config import RunConfig
from ..files import write_text
from ..model import CHOICES, ParameterError

#: option name -> help; every model parameter of MODEL.md, same words as the docs
MODEL_OPTIONS = [
    ("--dim", click.INT, "Dimension, 2 or 3. [default: 2]"),
    ("--n", click.INT, "Number of particles (give at most two of n, density, box)."),
    ("--density", click.FLOAT, "Number density N / volume. [default: 2 when needed]"),
    ("--box", str, "Box side, or one per axis such as 4,5. [default: 32 when needed]"),
    ("--speed", click.FLOAT, "Speed v0 (> 0). [default: 0.5]"),
    ("--speeds", click.Choice(CHOICES["speeds"]), "All v0, or each uniform in (0, v0]. [default: constant]"),
    ("--neighbours", click.Choice(CHOICES["neighbours"]), "Metric (radius) or topological (k nearest)."),
    ("--radius", click.FLOAT, "Interaction radius R, metric neighbours. [default: 1]"),
    ("--k", click.INT, "Number of nearest neighbours, topological. [default: 7]"),
    ("--noise", click.FLOAT, "Noise amplitude eta: [0, 2 pi] for angular noise. [default: 1]"),
    ("--noise-scale", click.Choice(CHOICES["noise_scale"]),
     "'unit': --noise is eta' in [0, 1] (eta = 2 pi eta' for angular noise). [default: radians]"),
    ("--noise-type", click.Choice(CHOICES["noise_type"]), "Angular (Vicsek) or vectorial (Gregoire-Chate)."),
    ("--alignment", click.FLOAT, "Fraction epsilon in [0, 1] of the turn toward the neighbours. [default: 1]"),
    ("--delay", click.INT, "Neighbours are seen this many steps late (>= 0). [default: 0]"),
    ("--dt", click.FLOAT, "Time step (> 0). [default: 1]"),
    ("--update", click.Choice(CHOICES["update"]), "Move along the new (backward) or old (forward) heading."),
    ("--seed", click.INT, "The one integer that fixes every random number. [default: 0]"),
    # the extensions (docs/model.md); obstacles, species and coupling come from --config
    ("--boundary", str, "periodic or wall, for every axis or one per axis such as periodic,wall. "
                        "[default: periodic]"),
    ("--vision", click.FLOAT, "Half-angle of the cone in front inside which neighbours are seen, in (0, pi]. "
                              "[default: pi, all around]"),
    ("--alignment-rule", click.Choice(CHOICES["alignment_rule"]),
     "polar, or nematic: anti-parallel neighbours count reversed. [default: polar]"),
    ("--chirality", click.FLOAT, "Turn omega (radians per unit time, counter-clockwise) every step, 2D only. "
                                 "[default: 0]"),
    ("--field", str, "Direction g of an external field such as 1,0 (any length). [default: none]"),
    ("--field-strength", click.FLOAT, "Strength h >= 0 of the field: S += h n g. [default: 0]"),
]


def model_options(func):
    for name, kind, text in reversed(MODEL_OPTIONS):
        func = click.option(name, type=kind, default=None, help=text)(func)
    return func


def check_output_folder(out: str, force: bool) -> None:
    """Refuse an existing non-empty folder unless ``force``; refuse a file."""
    if os.path.exists(out):
        if not os.path.isdir(out):
            raise ParameterError(f"out: {out!r} exists and is not a folder")
        if os.listdir(out) and not force:
            raise ParameterError(f"out: folder {out!r} is not empty; use --force to overwrite or another --out")


def default_output_folder() -> str:
    """``runs/run-0001``, ``runs/run-0002``, ...: the first that does not exist."""
    i = 1
    while os.path.exists(os.path.join("runs", f"run-{i:04d}")):
        i += 1
    return os.path.join("runs", f"run-{i:04d}")


@click.command()
@model_options
@click.option("--steps", type=click.INT, default=None,
              help="Number of steps (with --resume: the run's new total). [default: 1000]")
@click.option("--every", type=click.INT, default=None,
              help="A frame every K steps; 0 keeps only the first and the last. [default: 10]")
@click.option("--checkpoint-every", type=click.INT, default=None,
              help="A checkpoint every K steps (0: only at the end or on a stop). [default: 1000]")
@click.option("--init", default=None, help="random, aligned, or a GSD file whose last frame starts the run.")
@click.option("--backend", default=None, help="cpu (numba, default), reference (NumPy) or cuda.")
@click.option("--precision", type=click.Choice(["float64", "float32"]), default=None,
              help="Floating-point precision; float32 with --backend cuda only. [default: float64]")
@click.option("--config", "config_file", type=click.Path(dir_okay=False), default=None,
              help="A TOML file of parameters; options given here override it.")
@click.option("--resume", "resume_dir", default=None,
              help="Continue the run in this folder from its last checkpoint, bit for bit.")
@click.option("--out", default=None, help="Output folder. [default: runs/run-NNNN, a new one]")
@click.option("--force", is_flag=True, help="Write into a non-empty output folder.")
@click.option("--quiet", "-q", is_flag=True, help="No progress bar, no summary.")
@click.option("--no-plots", is_flag=True, help="No snapshot.png and polar_order.png at the end.")
@click.option("--movie", is_flag=True, help="Write movie.mp4 at the end (see flocking animate).")
@click.option("--show", is_flag=True, help="A window that shows the flock while it runs.")
@click.option("--theme", default="dark", show_default=True, help="Pictures and movie: dark or light.")
@click.option("--dpi", type=click.FLOAT, default=None, help="Pictures: pixels per inch. [default: 200]")
@click.option("--plot-format", default="png", show_default=True, help="Pictures: png, svg or pdf.")
def run(config_file, resume_dir, out, force, quiet, no_plots, movie, show, theme, dpi, plot_format, **options):
    """Simulate a flock and write trajectory.gsd, observables.csv and config.toml into a folder.

    \b
    Examples:
      flocking run
      flocking run --n 10000 --noise 2.5 --steps 5000 --every 50 --out hot
      flocking run --dim 3 --neighbours topological --k 7 --noise-type vectorial --noise 0.4
      flocking run --config runs/run-0001/config.toml --out again   # bit for bit
      flocking run --resume hot --steps 10000                       # continue, or extend
    """
    looks = dict(theme=theme, dpi=dpi, fmt=plot_format)
    if movie or not no_plots:
        from ..viz.movie import check_picture_options

        check_picture_options(**looks)
    if resume_dir is not None:
        resume(resume_dir, config_file, out, quiet, options, show=show)
        return pictures(resume_dir, no_plots, movie, quiet, **looks)
    file_layer = RunConfig.load(config_file) if config_file else {}
    cfg = RunConfig.from_layers(file_layer, options)
    cfg.check_memory()
    out = out or default_output_folder()
    check_output_folder(out, force)
    state = cfg.initial_state()
    from ..simulation import Simulation

    sim = Simulation(cfg.model, state, backend=cfg.backend, history=False, **cfg.backend_options())
    execute(cfg, sim, out, quiet, show=show)
    pictures(out, no_plots, movie, quiet, **looks)


def pictures(out: str, no_plots: bool, movie: bool, quiet: bool, **looks) -> None:
    """snapshot and polar_order pictures (unless ``no_plots``), and movie.mp4 if asked;
    ``looks``: ``theme``, ``dpi``, ``fmt`` (png, svg or pdf) as :func:`flocking.viz.after_run`."""
    if movie or not no_plots:
        from ..viz import after_run

        after_run(out, plots=not no_plots, movie=movie, quiet=quiet, **looks)


def resume(folder: str, config_file, out, quiet: bool, options: dict, show: bool = False) -> None:
    """Continue the run in ``folder`` from its checkpoint, trimming what came after it."""
    from ..resume import rewind
    from ..simulation import Simulation

    extra = [k for k, v in options.items() if v is not None and k not in ("steps", "checkpoint_every")]
    if extra or config_file or out:
        names = ", ".join("--" + k.replace("_", "-") for k in extra + ["config"] * bool(config_file)
                          + ["out"] * bool(out))
        raise ParameterError(f"resume: continues a run as it was configured; only --steps and "
                             f"--checkpoint-every may change (got {names})")
    if not os.path.isdir(folder):
        raise ParameterError(f"resume: {folder!r} is not a run folder")
    path = os.path.join(folder, "config.toml")
    if not os.path.isfile(path):
        raise ParameterError(f"resume: {folder!r} has no config.toml")
    data = RunConfig.load(path)
    data.update({k: options[k] for k in ("steps", "checkpoint_every") if options[k] is not None})
    cfg = RunConfig.from_dict(data)
    checkpoint = os.path.join(folder, "checkpoint.npz")
    if not os.path.isfile(checkpoint):
        raise ParameterError(f"resume: {folder!r} has no checkpoint.npz to continue from")
    sim = Simulation.load_checkpoint(checkpoint, history=False)
    if sim.model != cfg.model:
        raise ParameterError(f"resume: the checkpoint of {folder!r} does not belong to its config.toml")
    remaining = sim.origin + cfg.steps - sim.step
    if remaining < 0:
        raise ParameterError(f"steps: must be at least {sim.step - sim.origin}, the steps already run "
                             f"(got {cfg.steps})")
    rewind(folder, sim.step, sim.origin, cfg.every)
    execute(cfg, sim, folder, quiet, append=True, show=show)


def execute(cfg: RunConfig, sim, out: str, quiet: bool, append: bool = False, show: bool = False) -> None:
    """Run ``sim`` (built from ``cfg``) to ``cfg.steps`` into the folder ``out``."""
    from ..writers import CheckpointWriter, GSDWriter, ObservablesWriter

    mode = "a" if append else "w"
    sim.info["run"] = {k: v for k, v in cfg.to_dict().items() if k in ("every", "init")}
    os.makedirs(out, exist_ok=True)
    write_text(os.path.join(out, "config.toml"), cfg.to_toml())
    sim.writers.append(GSDWriter(os.path.join(out, "trajectory.gsd"), every=cfg.every, mode=mode))
    sim.writers.append(ObservablesWriter(os.path.join(out, "observables.csv"), mode=mode))
    sim.writers.append(CheckpointWriter(os.path.join(out, "checkpoint.npz"), every=cfg.checkpoint_every))
    if show:
        from ..viz.live import LiveView

        sim.writers.append(LiveView(every=cfg.every or 10))
    if not quiet:
        verb = f"resuming at step {sim.step}" if append else "running"
        click.echo(f"flocking: {verb} {cfg.model} -> {out}", err=True)
    interrupted = []

    def stop(signum, frame):
        interrupted.append(signum)
        sim.request_stop()
        signal.signal(signum, previous[signum])  # a second signal stops at once

    previous = {s: signal.signal(s, stop) for s in (signal.SIGINT, signal.SIGTERM)}
    # a file-size limit then raises OSError (EFBIG) like a full disk, instead of killing us
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    compiled = warm_up(cfg)
    if compiled > 1.0 and not quiet:
        click.echo(f"flocking: compiled the kernels in {compiled:.0f} s (once: numba caches them)", err=True)
    start, first = time.perf_counter(), sim.step
    try:
        sim.run(sim.origin + cfg.steps - sim.step, progress=not quiet and sys.stderr.isatty())
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    elapsed = time.perf_counter() - start
    done = sim.step - first
    if interrupted:
        click.echo(f"flocking: stopped at step {sim.step} with a checkpoint; {out} holds every frame so far "
                   f"(flocking run --resume {out} continues)", err=True)
        sys.exit(130 if interrupted[0] == signal.SIGINT else 143)
    if not quiet:
        rate = done * cfg.model.n / elapsed if elapsed > 0 else float("inf")
        click.echo(f"flocking: {done} steps in {elapsed:.2f} s ({rate:.3g} particle-steps/s), "
                   f"polar order {sim.polar_order[-1]:.3f}; wrote {out}", err=True)


def warm_up(cfg: RunConfig) -> float:
    """Run two steps of a tiny copy of the model, so that numba compiles (or loads) the
    kernels before the timed run; returns the seconds it took."""
    from ..simulation import Simulation
    from ..state import State

    start = time.perf_counter()
    model = cfg.model
    # the kernels compiled depend on the types, not the values: a speed that suits the
    # tiny box (whose side may be below twice the real step) compiles the same code
    tiny = model.replace(n=min(model.n, 64), density=model.density, speed=1e-3, dt=1.0)
    Simulation(tiny, State.random(tiny), backend=cfg.backend, **cfg.backend_options()).run(2)
    return time.perf_counter() - start
