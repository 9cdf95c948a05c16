"""``flocking run``: simulate one flock and leave a folder a person can open."""

from __future__ import annotations

import inspect
import math
import os
import re
import signal
import sys
import time

import click

from ..checks import comma_numbers
from ..config import RUN_DEFAULTS, RunConfig
from ..files import write_text
from ..model import CHOICES, DEFAULT_BOX, DEFAULT_DENSITY, Model, ParameterError
from . import options as opt

#: option name -> help; every model parameter, same words as docs/model.md (defaults: :func:`shown_default`)
MODEL_OPTIONS = [
    ("--dim", click.INT, "Dimension, 2 or 3."),
    ("--n", click.INT, "Number of particles (give at most two of n, density, box)."),
    ("--density", click.FLOAT, "Number density N / volume."),
    ("--box", str, "Box side, or one per axis such as 4,5."),
    ("--speed", click.FLOAT, "Speed v0 (> 0)."),
    ("--speeds", opt.OneOf(CHOICES["speeds"]), "All v0, or each uniform in (0, v0]."),
    ("--neighbours", opt.OneOf(CHOICES["neighbours"]), "Metric (radius), topological (k nearest) or voronoi (docs/voronoi.md)."),
    ("--radius", click.FLOAT, "Interaction radius R, metric neighbours."),
    ("--k", click.INT, "Number of nearest neighbours, topological."),
    ("--noise", click.FLOAT, "Noise amplitude eta: [0, 2 pi] for angular noise."),
    ("--noise-scale", opt.OneOf(CHOICES["noise_scale"]),
     "'unit': --noise is eta' in [0, 1] (eta = 2 pi eta' for angular noise)."),
    ("--noise-type", opt.OneOf(CHOICES["noise_type"]), "Angular (Vicsek) or vectorial (Gregoire-Chate)."),
    ("--alignment", click.FLOAT, "Fraction epsilon in [0, 1] of the turn toward the neighbours."),
    ("--delay", click.INT, "Neighbours are seen this many steps late (>= 0)."),
    ("--dt", click.FLOAT, "Time step (> 0)."),
    ("--update", opt.OneOf(CHOICES["update"]), "Move along the new (backward) or old (forward) heading."),
    ("--seed", click.INT, "The one integer that fixes every random number."),
    # the extensions (docs/model.md); obstacles and two species are options of flocking run, the rest of
    # the lists and tables come from --config
    ("--boundary", str, "periodic or wall, for every axis or one per axis such as periodic,wall."),
    ("--vision", click.FLOAT, "Half-angle of the cone in front inside which neighbours are seen, in (0, pi]."),
    ("--alignment-rule", opt.OneOf(CHOICES["alignment_rule"]),
     "polar, or nematic: anti-parallel neighbours count reversed."),
    ("--chirality", click.FLOAT, "Turn omega (radians per unit time, counter-clockwise) every step, 2D only."),
    ("--field", str, "Direction g of an external field such as 1,0 (any length)."),
    ("--field-strength", click.FLOAT, "Strength h >= 0 of the field: S += h n g."),
    ("--cohesion", click.FLOAT, "Strength beta in [0, 1000] of the neighbours' attraction-repulsion (Gregoire-Chate)."),
    ("--cohesion-radii", str, "Hard core, equilibrium and full attraction r_c,r_e,r_a such as 0.2,0.5,0.8."),
]


#: Defaults shown in words rather than as the value.
SHOWN = {"vision": "pi, all around", "field": "none", "cohesion_radii": "0.2,0.5,0.8 x R", "fields": "none",
         "fields_every": "as --every"}


def shown_default(name: str, defaults: dict | None = None) -> str:
    """What ``--help`` shows as the default of an option: the value :class:`Model` or
    :class:`RunConfig` takes when the option is not given (options default to ``None``
    so that a config file can set them), or the command's own ``defaults``.

    >>> shown_default("--noise-type"), shown_default("--radius"), shown_default("--every")
    ('angular', '1', '10')
    >>> shown_default("--box"), shown_default("--box", {"n": 4000, "density": 2.0})
    ('32 when needed', 'from n and density')
    """
    key = name.lstrip("-").replace("-", "_")
    defaults = defaults or {}
    if key in SHOWN:
        return SHOWN[key]
    if key in defaults:
        value = defaults[key]
    elif key in ("n", "density", "box"):
        if key == "box" and {"n", "density"} <= defaults.keys():
            return "from n and density"
        return {"n": "density x volume", "density": f"{DEFAULT_DENSITY:g} when needed",
                "box": f"{DEFAULT_BOX:g} when needed"}[key]
    else:
        value = RUN_DEFAULTS[key] if key in RUN_DEFAULTS else inspect.signature(Model).parameters[key].default
    return f"{value:g}" if isinstance(value, float) else str(value)


def with_default(text: str, name: str, defaults: dict | None = None) -> str:
    """An option's help followed by its default, as click shows it."""
    return f"{text}  [default: {shown_default(name, defaults)}]"


def model_options(func=None, *, defaults: dict | None = None):
    """Decorator: every model parameter as an option. ``@model_options`` shows the model's
    defaults; ``@model_options(defaults={...})`` those a command uses instead."""
    def decorate(func):
        for name, kind, text in reversed(MODEL_OPTIONS):
            func = click.option(name, type=kind, default=None, help=with_default(text, name, defaults))(func)
        return func

    return decorate if func is None else decorate(func)


#: What a run folder holds that flocking writes: the run's files, the pictures and movie
#: of ``flocking run`` and ``flocking animate``, and ``flocking analyze``'s default outputs.
#: ``--force`` removes these (and their temporaries) and nothing else.
RUN_FILES = ("trajectory.gsd", "fields.nc", "observables.csv", "config.toml", "checkpoint.npz", "movie.mp4", "analysis.json",
             *(f"{stem}.{ext}" for stem in ("snapshot", "polar_order") for ext in opt.FORMATS))

#: Choices about what a run leaves besides its data, with their defaults; a resumed run
#: keeps the choices its first part made unless the command line says otherwise.
OUTPUT_CHOICES = {"plots": True, "movie": False}


def written_by_flocking(name: str) -> bool:
    """Whether a file called ``name`` in a run folder is one that flocking writes there
    (or a temporary it leaves when killed while writing one).

    >>> [written_by_flocking(x) for x in ("snapshot.png", "msd.csv", "config.toml.812.tmp", "notes.txt")]
    [True, True, True, False]
    """
    from .analyze import written_stems

    extensions = (".csv", *(f".{e}" for e in opt.FORMATS))
    names = set(RUN_FILES) | {stem + ext for stem in written_stems() for ext in extensions}
    for name_ in names:
        ext = os.path.splitext(name_)[1]
        if re.fullmatch(re.escape(name_) + r"(\.\d+)?\.tmp", name) or name == f".{name_}.part{ext}":
            return True
    return name in names


def check_output_folder(out: str, force: bool) -> None:
    """Refuse a file, a folder that cannot be made or written (:func:`.options.check_folder`),
    and an existing non-empty folder unless ``force``."""
    opt.check_folder("out", out)
    if os.path.exists(out):
        if os.listdir(out) and not force:
            raise ParameterError(f"out: folder {out!r} is not empty; use --force to replace the run in it "
                                 f"or another --out")


def clear_output_folder(out: str, init: str) -> tuple[list[str], list[str]]:
    """Remove from ``out`` the files an earlier run left there (:func:`written_by_flocking`),
    so that nothing of it stays beside the new run; return ``(removed, kept)`` names. A run
    that starts from a trajectory it would remove is refused first."""
    if not os.path.isdir(out):
        return [], []
    names = sorted(os.listdir(out))
    removed = [n for n in names if written_by_flocking(n) and os.path.isfile(os.path.join(out, n))]
    if os.path.isfile(init) and any(os.path.samefile(init, os.path.join(out, n)) for n in removed):
        raise ParameterError(f"init: {init!r} is in the folder --force would clear; copy it elsewhere or "
                             f"choose another --out")
    for name in removed:
        os.remove(os.path.join(out, name))
    return removed, [n for n in names if n not in removed]


def default_output_folder() -> str:
    """``runs/run-0001``, ``runs/run-0002``, ...: the first that does not exist."""
    i = 1
    while os.path.exists(os.path.join("runs", f"run-{i:04d}")):
        i += 1
    return os.path.join("runs", f"run-{i:04d}")


#: What ``flocking run --help`` shows after the options: a config file for what no option sets.
CONFIG_EXAMPLE = """\b
A config file (--config FILE.toml, the names of the options with _ for -) sets anything
an option sets, and the lists and tables that no option covers, such as three species
with their own parameters and the coupling matrix J (row: who aligns, column: with whom):
\b
  n = 3000
  box = 40.0
  boundary = "wall"
  obstacles = [{centre = [12.0, 20.0], radius = 3.0}, {centre = [28.0, 20.0], radius = 3.0}]
  species = [{name = "A", fraction = 0.6},
             {name = "B", fraction = 0.3, noise = 2.0},
             {name = "C", fraction = 0.1, speed = 1.0, field_strength = 0.5}]
  coupling = [[1.0, 1.0, -1.0], [1.0, 1.0, 0.0], [1.0, 1.0, 1.0]]
  field = [1.0, 0.0]
\b
Positions (--obstacle, centre) are box coordinates, each axis from 0 to L. docs/model.md
gives every parameter's meaning and range."""


@click.command(short_help="Simulate a flock into a run folder.", epilog=CONFIG_EXAMPLE)
@model_options
@click.option("--obstacle", "obstacles", multiple=True, metavar="X,Y,R",
              help="A disc of radius R centred at (X, Y), box coordinates from 0 to L (3D: X,Y,Z,R, a sphere); "
                   "repeat for more. Replaces the config file's obstacles.  [default: none]")
@click.option("--species-b", type=click.FLOAT, default=None, metavar="FRACTION",
              help="A second species, B, with this fraction of the particles (A has the rest). Replaces the "
                   "config file's species and coupling.  [default: none, one species]")
@click.option("--cross-coupling", type=click.FLOAT, default=None, metavar="J",
              help="With two species: weight J of the other species' headings in a particle's sum (1: align "
                   "with them as with one's own, -1: turn away from them, 0: ignore them); own species 1.  "
                   "[default: 1]")
@click.option("--steps", type=click.INT, default=None,
              help=with_default("Number of steps (with --resume: the run's new total).", "--steps"))
@click.option("--every", type=click.INT, default=None,
              help=with_default("A frame every K steps; 0 keeps only the first and the last.", "--every"))
@click.option("--checkpoint-every", type=click.INT, default=None,
              help=with_default("A checkpoint every K steps (0: only at the end or on a stop).", "--checkpoint-every"))
@click.option("--fields", type=click.FLOAT, default=None, metavar="BIN",
              help="Coarse-grained fields (count, polarisation) on bins of about this size into fields.nc "
                   "(docs/fields.md).  [default: none]")
@click.option("--fields-every", type=click.INT, default=None, metavar="K",
              help="Fields every K steps.  [default: as --every]")
@click.option("--init", default=None,
              help=with_default("random, aligned, or a GSD file whose last frame starts the run.", "--init"))
@opt.backend("cpu (numba, multi-threaded), reference (NumPy, slow, the oracle) or cuda (an NVIDIA GPU).")
@click.option("--precision", type=opt.OneOf(["float64", "float32"]), default=None,
              help=with_default("Floating-point precision; float32 with --backend cuda only.", "--precision"))
@click.option("--config", "config_file", type=click.Path(dir_okay=False), default=None,
              help="A TOML file of parameters; options given here override it.")
@click.option("--resume", "resume_dir", default=None,
              help="Continue the run in this folder from its last checkpoint, bit for bit.")
@opt.out("Output folder.", "runs/run-NNNN, a new one")
@click.option("--force", is_flag=True,
              help="Use a non-empty --out: the files flocking wrote there go, others stay.")
@opt.quiet()
@opt.plots("snapshot.png and polar_order.png at the end.", "--plots; with --resume, as the run began")
@click.option("--movie/--no-movie", default=None,
              help="movie.mp4 at the end (see flocking animate).  [default: --no-movie; with --resume, as the run "
                   "began]")
@click.option("--show", is_flag=True, help="A window that shows the flock while it runs.")
@opt.theme
@opt.dpi()
@opt.picture_format
@opt.color
def run(config_file, resume_dir, out, force, quiet, plots, movie, show, theme, dpi, fmt, color, obstacles, species_b,
        cross_coupling, **options):
    """Simulate a flock and write trajectory.gsd, observables.csv, config.toml and
    checkpoint.npz into a folder, and two pictures: snapshot.png and polar_order.png.

    Every option is checked, and the kernels compiled, before anything is written.

    \b
    Examples:
      flocking run
      flocking run --n 10000 --noise 2.5 --steps 5000 --every 50 --out hot
      flocking run --dim 3 --neighbours topological --k 7 --noise-type vectorial --noise 0.4
      flocking run --boundary wall --obstacle 16,16,8 --noise 0.5 --steps 4000 --out mill
      flocking run --species-b 0.5 --cross-coupling -1 --out mixture
      flocking run --config runs/run-0001/config.toml --out again   # the same data
      flocking run --resume hot --steps 10000                       # continue, or extend
      flocking compare runs/run-0001 again                          # check it
    """
    looks = dict(theme=theme, dpi=dpi, fmt=fmt, color=color)
    asked = {"plots": plots, "movie": movie}
    show = show and {"theme": theme, "color": color}  # how the live view looks
    given = {"obstacle": obstacles or None, "species_b": species_b, "cross_coupling": cross_coupling}
    if resume_dir is not None:
        outputs = resume(resume_dir, config_file, out, quiet, {**options, **given}, asked, show=show)
        return pictures(resume_dir, quiet, **outputs, **looks)
    file_layer = RunConfig.load(config_file) if config_file else {}
    given_options = {k: v for k, v in options.items() if v is not None}
    layer = extension_layer(obstacles, species_b, cross_coupling, {**file_layer, **given_options})
    if "species" in layer:  # the file's coupling was for the file's species
        file_layer.pop("coupling", None)
    try:
        cfg = RunConfig.from_layers(file_layer, options, layer)
    except ParameterError as err:
        raise ParameterError(from_option(str(err), layer)) from None
    cfg.check_memory()
    if cfg.fields:
        from ..fields import require_netcdf

        require_netcdf()
    out = out or default_output_folder()
    check_output_folder(out, force)
    # "random" and "aligned" as kinds: the cuda backend draws them on the device
    state = cfg.init if cfg.init in ("random", "aligned") else cfg.initial_state()
    from ..simulation import Simulation

    sim = Simulation(cfg.model, state, backend=cfg.backend, history=False, **cfg.backend_options())
    prepare(cfg, sim, out, quiet)  # the kernels compiled and tried: nothing is written before
    if force:
        removed, kept = clear_output_folder(out, cfg.init)
        if removed and not quiet:
            click.echo(f"flocking: --force: removed {len(removed)} files of an earlier run from {out}"
                       + (f" (kept {', '.join(kept)})" if kept else ""), err=True)
    outputs = {k: OUTPUT_CHOICES[k] if v is None else v for k, v in asked.items()}
    execute(cfg, sim, out, quiet, show=show, outputs=outputs)
    pictures(out, quiet, **outputs, **looks)


#: the options that make a layer of lists and tables, and the key of the config each sets
EXTENSION_OPTIONS = {"obstacles": "obstacle", "species": "species_b", "coupling": "cross_coupling"}


def extension_layer(obstacles, species_b, cross_coupling, below: dict) -> dict:
    """The obstacles, species and coupling that ``--obstacle``, ``--species-b`` and
    ``--cross-coupling`` give, as config keys; ``below`` is what the config file and the
    other options say (for the dimension, and the species a coupling is for).

    >>> extension_layer(("16,16,4",), 0.25, -1.0, {})
    {'obstacles': [{'centre': [16.0, 16.0], 'radius': 4.0}], 'species': [{'fraction': 0.75}, {'fraction': 0.25}], \
'coupling': [[1.0, -1.0], [-1.0, 1.0]]}
    >>> extension_layer((), None, -1.0, {"species": [{"fraction": 0.5}] * 3})
    Traceback (most recent call last):
    ...
    flocking.checks.ParameterError: cross_coupling: needs two species, from --species-b or a config file (got 3)
    """
    layer = {}
    if obstacles:
        dim = below.get("dim") or 2
        example = "16,16,4" if dim == 2 else "16,16,16,4"
        layer["obstacles"] = []
        for text in obstacles:
            values = comma_numbers("obstacle", text, f"{dim + 1} numbers such as {example}")
            if len(values) != dim + 1:
                raise ParameterError(f"obstacle: must be {'X,Y,R' if dim == 2 else 'X,Y,Z,R'} in {dim}D, centre in "
                                     f"box coordinates and radius, such as {example} (got {text!r})")
            layer["obstacles"].append({"centre": values[:-1], "radius": values[-1]})
    if species_b is not None:
        if not 0 < species_b < 1:
            raise ParameterError(f"species_b: must be a fraction in (0, 1) (got {species_b})")
        layer["species"] = [{"fraction": 1 - species_b}, {"fraction": species_b}]
    if cross_coupling is not None:
        count = 2 if species_b is not None else len(below.get("species") or ())
        if count != 2:
            raise ParameterError(f"cross_coupling: needs two species, from --species-b or a config file (got {count})")
        layer["coupling"] = [[1.0, cross_coupling], [cross_coupling, 1.0]]
    return layer


def from_option(message: str, layer: dict) -> str:
    """A model's error about obstacles, species or coupling, in the words of the option
    that set them when one did (``obstacles: ...`` -> ``obstacle: ...``).

    >>> from_option("obstacles: radii above one step", {"obstacles": []})
    'obstacle: radii above one step'
    """
    key, sep, rest = message.partition(": ")
    if sep and key in layer and key in EXTENSION_OPTIONS:
        return f"{EXTENSION_OPTIONS[key]}: {rest}"
    return message


def pictures(out: str, quiet: bool, plots: bool, movie: bool, **looks) -> None:
    """snapshot and polar_order pictures if ``plots``, and movie.mp4 if ``movie``; ``looks``:
    ``theme``, ``dpi``, ``fmt`` (png, svg or pdf) as :func:`flocking.viz.after_run`."""
    if movie or plots:
        from ..viz import after_run

        after_run(out, plots=plots, movie=movie, quiet=quiet, **looks)


def resume(folder: str, config_file, out, quiet: bool, options: dict, asked: dict, show: bool = False) -> dict:
    """Continue the run in ``folder`` from its checkpoint, trimming what came after it.

    Returns the :data:`OUTPUT_CHOICES` of the run: those ``asked`` on the command line,
    the others as the run's checkpoint recorded them."""
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
    before = sim.info.get("run", {})
    outputs = {k: before.get(k, OUTPUT_CHOICES[k]) if v is None else v for k, v in asked.items()}
    prepare(cfg, sim, folder, quiet, resuming=True)
    rewind(folder, sim.step, sim.origin, cfg.every)
    execute(cfg, sim, folder, quiet, append=True, show=show, outputs=outputs)
    return outputs


def prepare(cfg: RunConfig, sim, out: str, quiet: bool, resuming: bool = False) -> None:
    """Say what runs where, and compile (or load) and try the kernels of the run on a tiny
    copy of its model (:func:`warm_up`), before anything is written."""
    if not quiet:
        verb = f"resuming at step {sim.step}" if resuming else "running"
        click.echo(f"flocking: {verb} {cfg.model} -> {out}", err=True)
    compiled = warm_up(cfg, announce=None if quiet else lambda: click.echo(
        f"flocking: compiling the kernels for this kind of run, {COMPILE_TIME} (only once: numba caches "
        f"them) ...", err=True))
    if compiled is not None and not quiet:
        click.echo(f"flocking: compiled in {compiled:.0f} s", err=True)


def execute(cfg: RunConfig, sim, out: str, quiet: bool, append: bool = False, show: bool = False,
            outputs: dict | None = None) -> None:
    """Run ``sim`` (built from ``cfg`` and :func:`prepare`-d) to ``cfg.steps`` into the folder
    ``out``; the checkpoints record ``outputs`` (:data:`OUTPUT_CHOICES`) for a later resume."""
    from ..writers import CheckpointWriter, GSDWriter, ObservablesWriter

    mode = "a" if append else "w"
    sim.info["run"] = {k: v for k, v in cfg.to_dict().items() if k in ("every", "init")}
    sim.info["run"].update(outputs or OUTPUT_CHOICES)
    os.makedirs(out, exist_ok=True)
    write_text(os.path.join(out, "config.toml"), cfg.to_toml())
    sim.writers.append(GSDWriter(os.path.join(out, "trajectory.gsd"), every=cfg.every, mode=mode))
    sim.writers.append(ObservablesWriter(os.path.join(out, "observables.csv"), mode=mode))
    if cfg.fields:
        from ..fields import FILENAME, FieldsWriter

        sim.writers.append(FieldsWriter(os.path.join(out, FILENAME), cfg.fields, every=cfg.fields_every or cfg.every,
                                        mode=mode))
    sim.writers.append(CheckpointWriter(os.path.join(out, "checkpoint.npz"), every=cfg.checkpoint_every))
    if show:
        from ..viz.live import LiveView

        sim.writers.append(LiveView(every=cfg.every or 10, **(show if isinstance(show, dict) else {})))
    interrupted = []

    def stop(signum, frame):
        interrupted.append(signum)
        sim.request_stop()
        signal.signal(signum, previous[signum])  # a second signal stops at once

    previous = {s: signal.signal(s, stop) for s in (signal.SIGINT, signal.SIGTERM)}
    # a file-size limit then raises OSError (EFBIG) like a full disk, instead of killing us
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
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


#: How long numba takes to compile the kernels of a new kind of run (2D or 3D, metric or
#: topological, angular or vectorial noise, delay or not): 12 to 50 s on the project's 2-core
#: machine, 1.5 to 3 minutes while other jobs shared it (docs/performance.md, "Compiling").
COMPILE_TIME = "under a minute on 2 cores, a few minutes on a busy machine"


def tiny_model(model: Model) -> Model:
    """A copy of ``model`` with a few dozen particles at the same density that takes the same
    kernels: where ``model``'s box sides are at least 3.5 R, so are the copy's (the CPU
    backend's fast metric path needs three cells of side R along every axis).

    >>> tiny_model(Model(n=100_000, radius=2.0)).box, tiny_model(Model(n=100_000)).n
    ((7.0, 7.0), 64)
    >>> tiny_model(Model(n=10)) == Model(n=10)
    True
    """
    side = (64 / model.density) ** (1.0 / model.dim)
    if model.neighbours == "metric":
        side = max(side, 3.5 * model.radius)
    box = [min(length, side) for length in model.box]
    n = max(len(model.species), round(model.density * math.prod(box)))
    if n >= model.n:
        return model
    # a short step and one small obstacle fit any tiny box; species as fractions of its n
    changes = dict(n=n, box=box, speed=min(model.speed, min(box) / (16 * model.dt)))
    if model.obstacles:
        changes["obstacles"] = [{"centre": [x / 2 for x in box], "radius": min(box) / 8}]
    if model.species:
        counts = model.species_counts
        changes["species"] = [{**{k: v for k, v in s.to_dict().items() if k not in ("n", "speed")},
                               "fraction": c / sum(counts)} for s, c in zip(model.species, counts)]
    return model.replace(**changes)


def warm_up(cfg: RunConfig, announce=None) -> float | None:
    """Run two steps of a tiny copy of the model and take a frame, so that numba compiles (or
    loads from its cache) the kernels before the timed run. ``announce()`` is called when a compilation
    starts (numba's ``numba:compile`` event fires on cache misses only); returns the
    seconds the warm-up took if something was compiled, else None."""
    from numba.core import event

    from ..simulation import Simulation
    from ..state import State

    class FirstCompile(event.Listener):
        started = False

        def on_start(self, ev):
            if not self.started:
                self.started = True
                if announce is not None:
                    announce()

        def on_end(self, ev):
            pass

    start = time.perf_counter()
    tiny = tiny_model(cfg.model)
    with event.install_listener("numba:compile", FirstCompile()) as listener:
        sim = Simulation(tiny, State.random(tiny), backend=cfg.backend, **cfg.backend_options())
        sim.run(2)
        sim.backend.frame_arrays()  # what the trajectory writer calls
    return time.perf_counter() - start if listener.started else None
