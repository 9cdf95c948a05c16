"""Throughput benchmarks: ``flocking`` against reference implementations, in one process.

A *case* is a model, an initial state and a number of steps. Each case is timed on the
CPU backend and, side by side in the same process, on the references that can run it:

- ``kdtree``: SciPy's periodic ``cKDTree`` + sparse distance matrix + sparse row sums
  (``benchmarks/kdtree_reference.py``, not part of the package);
- ``pyvicsek``: the C++ kernel of ``pip install pyvicsek`` on the same number of threads
  (skipped, with a note, when it is not installed).

Throughput is particle-steps per second: ``N * steps / time``, the median over
``repeats`` timed runs after a warm-up. Ratios are taken within the same run, so they
hold on a busy machine where absolute numbers do not. Peak memory comes from a separate
process per size (:func:`memory_probe`): the peak of all NumPy allocations of a run that
writes a GSD frame every 100 steps, per particle.

Initial states: ``random`` (measured after ``warmup`` steps: clusters and bands start to
form), ``aligned`` (all headings along x, homogeneous) and ``clustered``: a run of about
10^4 particles long enough to order into dense bands and clusters, tiled ``k x k`` to
reach N, so that every size sees the same long-run clustered structure.

>>> cases = standard_cases(full=False)
>>> sorted({c.group for c in cases})[:3]
['2d-metric', '3d-metric', 'delay']
>>> crowding(np.array([[0.5, 0.5], [0.6, 0.5], [3.5, 3.5]]), (4.0, 4.0), 1.0) > 1.0
True
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from .model import Model, ParameterError
from .state import State

#: parameters shared by every 2D case of the issue: density 2, R = 1, v0 = 0.5, dt = 1
BASE_2D = dict(dim=2, density=2.0, radius=1.0, speed=0.5, dt=1.0, noise=1.0)
BASE_3D = dict(dim=3, density=1.0, radius=1.0, speed=0.5, dt=1.0, noise=1.0)


@dataclasses.dataclass(frozen=True)
class Case:
    """One benchmark: ``group`` and ``label`` name it; ``refs`` lists the references to run."""

    group: str
    label: str
    model: dict
    init: str = "random"
    steps: int = 5
    warmup: int = 10
    refs: tuple = ("kdtree", "pyvicsek")
    threads: int | None = None  # None: every thread numba has

    def build_model(self) -> Model:
        return Model(**self.model)


def standard_cases(full: bool = False) -> list[Case]:
    """The table of the issue (``full``) or a quick subset that runs in seconds."""
    sizes_2d = [10**4, 10**5, 10**6, 10**7] if full else [10**4, 10**5]
    big = [10**5, 10**6] if full else [10**4]
    cases = []
    for n in sizes_2d:
        refs = ("kdtree", "pyvicsek") if n <= 10**6 else ()
        steps = max(2, min(20, 2 * 10**6 // n))
        for init in ("random", "clustered", "aligned"):
            m = n
            if init == "clustered":  # a whole number of tiles (see clustered_state)
                k2 = _tiles(n, 2) ** 2
                m = n // k2 * k2
            cases.append(Case("2d-metric", f"N={n:.0e} {init}", dict(BASE_2D, n=m), init, steps, refs=refs))
    for n in big:
        cases.append(Case("3d-metric", f"N={n:.0e}", dict(BASE_3D, n=n), steps=max(2, 10**6 // n), refs=("kdtree", "pyvicsek")))
        cases.append(Case("topological", f"k=7 N={n:.0e}", dict(BASE_2D, n=n, neighbours="topological", k=7),
                          steps=max(2, 10**6 // n), refs=()))
    n = 10**6 if full else 10**5
    steps = max(2, 10**6 // n) * 2
    cases.append(Case("vectorial", f"N={n:.0e}", dict(BASE_2D, n=n, noise_type="vectorial", noise=0.5), steps=steps,
                      refs=("pyvicsek",)))
    cases.append(Case("delay", f"tau=0 N={n:.0e}", dict(BASE_2D, n=n), steps=steps, refs=()))
    cases.append(Case("delay", f"tau=10 N={n:.0e}", dict(BASE_2D, n=n, delay=10), steps=steps, refs=()))
    cases.append(Case("threads", f"1 thread N={n:.0e}", dict(BASE_2D, n=n), steps=steps, refs=(), threads=1))
    cases.append(Case("threads", f"2 threads N={n:.0e}", dict(BASE_2D, n=n), steps=steps, refs=(), threads=2))
    return cases


# -- initial states ---------------------------------------------------------------------


def initial_state(case: Case, model: Model, long_steps: int) -> State:
    """The case's initial state (see the module docstring for ``clustered``)."""
    if case.init == "aligned":
        return State.aligned(model)
    if case.init == "random":
        return State.random(model)
    return clustered_state(model, long_steps)


def clustered_state(model: Model, steps: int) -> State:
    """A long run of about 10^4 particles at the model's density, tiled to ``model.n``."""
    from .backends.cpu import CPUBackend

    k = _tiles(model.n, model.dim)
    if model.n % k**model.dim:
        raise ParameterError(f"n: a clustered state needs n divisible by {k**model.dim} (got {model.n})")
    base = model.replace(n=model.n // k**model.dim, density=None, box=tuple(b / k for b in model.box))
    backend = CPUBackend(base, State.random(base))
    backend.advance(steps)
    small = backend.state
    shifts = np.stack(np.meshgrid(*[np.arange(k)] * model.dim, indexing="ij"), axis=-1).reshape(-1, model.dim)
    shifts = shifts * np.asarray(base.box)
    pos = (small.positions[None, :, :] + shifts[:, None, :]).reshape(-1, model.dim)
    head = np.tile(small.headings, (len(shifts), 1))
    return State(np.mod(pos, model.box), head, np.full(model.n, model.speed))


def _tiles(n: int, dim: int) -> int:
    """Tiles per axis so that each holds about 10^4 particles."""
    return max(1, round((n / 1e4) ** (1.0 / dim)))


def crowding(positions: np.ndarray, box, radius: float) -> float:
    """``<n_c^2> / <n_c>^2`` over cells of side about ``radius``: 1 for a Poisson gas
    (plus ``1/<n_c>``), larger when particles cluster. Pair work grows with it."""
    box = np.asarray(box, dtype=np.float64)
    nc = np.maximum(np.floor(box / radius), 1).astype(np.int64)
    idx = np.minimum((positions / box * nc).astype(np.int64), nc - 1)
    flat = np.ravel_multi_index(tuple(idx.T), tuple(nc))
    counts = np.bincount(flat, minlength=int(np.prod(nc))).astype(np.float64)
    return float(np.mean(counts**2) / np.mean(counts) ** 2)


# -- implementations --------------------------------------------------------------------


def find_refs(refs_dir: str | os.PathLike | None = None) -> Path | None:
    """The ``benchmarks/`` folder: ``refs_dir``, or next to the package source (a checkout)."""
    if refs_dir is not None:
        path = Path(refs_dir)
        if not (path / "kdtree_reference.py").is_file():
            raise ParameterError(f"refs: no kdtree_reference.py in {os.fspath(path)!r}")
        return path
    here = Path(__file__).resolve().parent.parent.parent / "benchmarks"
    return here if (here / "kdtree_reference.py").is_file() else None


def _load_kdtree(refs: Path):
    spec = importlib.util.spec_from_file_location("kdtree_reference", refs / "kdtree_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.KDTreeVicsek


def _runner_flocking(model: Model, state: State, threads: int):
    from .backends.cpu import CPUBackend

    return CPUBackend(model, state).advance


def _runner_kdtree(model: Model, state: State, threads: int, refs: Path):
    if len(set(model.box)) != 1:
        return None
    try:
        reference = _load_kdtree(refs)
    except ImportError:  # no SciPy here
        return None
    sim = reference(state.positions, model.box[0], model.radius, model.speed, model.noise, model.dt,
                             headings=state.headings, seed=model.seed)
    return sim.advance


def _runner_pyvicsek(model: Model, state: State, threads: int):
    try:
        import vicsek
    except ImportError:
        return None
    if not vicsek.kernel_available() or len(set(model.box)) != 1:
        return None
    from vicsek.models.particle import Particle

    vicsek.use_kernel(True, threads=threads)
    particles = [Particle(p, model.speed * h, "p", "particle") for p, h in zip(state.positions, state.headings)]
    sim = vicsek.Vicsek(model.box[0], particles, model.radius, model.speed, model.noise, model.dt, seed=model.seed)

    def advance(steps: int) -> None:
        for _ in range(steps):
            sim.step()

    return advance


def run_case(case: Case, refs: Path | None, repeats: int, long_steps: int, log=print) -> list[dict]:
    """Time one case on ``flocking`` and its references; one result row each.

    The implementations are timed in turn within each repeat, so a change in the load
    of the machine hits all of them alike; the median over repeats is kept, with the
    process CPU time per particle-step beside the wall-clock throughput.
    """
    import numba

    threads = case.threads or numba.config.NUMBA_NUM_THREADS
    numba.set_num_threads(threads)
    model = case.build_model()
    state = initial_state(case, model, long_steps)
    makers = {"flocking": lambda: _runner_flocking(model, state, threads)}
    if "kdtree" in case.refs:
        makers["kdtree"] = (lambda: _runner_kdtree(model, state, threads, refs)) if refs else None
    if "pyvicsek" in case.refs:
        makers["pyvicsek"] = lambda: _runner_pyvicsek(model, state, threads)
    rows, runners = [], {}
    for name, make in makers.items():
        row = dict(group=case.group, case=case.label, init=case.init, n=model.n, dim=model.dim,
                   implementation=name, threads=threads, steps=case.steps, repeats=repeats)
        advance = make() if make else None
        if advance is None:
            row["note"] = ("no benchmarks/ folder (use --refs)" if make is None
                           else "pyvicsek not installed" if name == "pyvicsek" else "SciPy not installed")
        else:
            # compiles once and lets a random start form clusters (the references need no
            # compiling: one step, so that a slow one does not take minutes here)
            advance(case.warmup if name == "flocking" else 1)
            runners[name] = advance
        rows.append(row)
    wall = {name: [] for name in runners}
    cpu = {name: [] for name in runners}
    for _ in range(repeats):
        for name, advance in runners.items():
            c0, t0 = time.process_time(), time.perf_counter()
            advance(case.steps)
            wall[name].append(time.perf_counter() - t0)
            cpu[name].append(time.process_time() - c0)
    for row in rows:
        name = row["implementation"]
        if name in runners:
            seconds = float(np.median(wall[name]))
            row["seconds_per_step"] = seconds / case.steps
            row["particle_steps_per_s"] = model.n * case.steps / seconds
            row["cpu_ns_per_particle_step"] = float(np.median(cpu[name])) * 1e9 / (model.n * case.steps)
    if case.init == "clustered":
        c = crowding(state.positions, model.box, model.radius)
        for row in rows:
            row["crowding"] = c
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    base = rows[0].get("particle_steps_per_s")
    for row in rows:
        if base and row.get("particle_steps_per_s"):
            row["flocking_speedup"] = base / row["particle_steps_per_s"]
        log(format_row(row))
    return rows


def format_row(row: dict) -> str:
    if "particle_steps_per_s" not in row:
        return f"{row['group']:12s} {row['case']:24s} {row['implementation']:9s} skipped: {row.get('note', '')}"
    ratio = row.get("flocking_speedup", 1.0)
    return (f"{row['group']:12s} {row['case']:24s} {row['implementation']:9s} "
            f"{row['particle_steps_per_s']:10.3g} p-steps/s {row['cpu_ns_per_particle_step']:7.0f} cpu-ns/p-step"
            f"   flocking x{ratio:6.2f}")


# -- memory -----------------------------------------------------------------------------

_PROBE = """
import sys, tempfile, os, tracemalloc
from flocking import Model, Simulation, GSDWriter
with tempfile.TemporaryDirectory() as tmp:
    small = Simulation(Model(n=1000, density=2.0, noise=1.0))  # compiles, outside the count
    small.writers.append(GSDWriter(os.path.join(tmp, "s.gsd"), 100))
    small.run(2)
    n, steps = int(sys.argv[1]), int(sys.argv[2])
    tracemalloc.start()
    sim = Simulation(Model(n=n, density=2.0, noise=1.0))
    sim.writers.append(GSDWriter(os.path.join(tmp, "t.gsd"), 100))
    sim.run(steps)
    print(tracemalloc.get_traced_memory()[1] / n)
"""


def memory_probe(n: int, steps: int = 101) -> float:
    """Peak bytes per particle of a 2D run of ``n`` particles writing a GSD frame every 100
    steps (initial state included), in a fresh process: every NumPy array, as traced by
    :mod:`tracemalloc`; the kernels allocate nothing per step."""
    src = str(Path(__file__).resolve().parent.parent)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([src, os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", _PROBE, str(n), str(steps)], env=env, check=True,
                         capture_output=True, text=True)
    return float(out.stdout.strip().splitlines()[-1])


# -- the suite --------------------------------------------------------------------------


def machine() -> dict:
    """CPU model and core count (``lscpu``), Python, NumPy and numba versions."""
    import numba

    info = {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
            "python": platform.python_version(), "numpy": np.__version__, "numba": numba.__version__,
            "threads": numba.config.NUMBA_NUM_THREADS}
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout
        for line in out.splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "Model name":
                info["cpu"] = value.strip()
    except (OSError, subprocess.CalledProcessError):
        pass
    try:
        import vicsek  # noqa: F401

        from importlib.metadata import version

        info["pyvicsek"] = version("pyvicsek")
    except ImportError:
        info["pyvicsek"] = None
    return info


def run_suite(full: bool = False, refs: Path | None = None, repeats: int = 3, memory: bool = True,
              groups: tuple = (), log=print) -> dict:
    """Every standard case (or those of ``groups``), then the memory probes."""
    long_steps = 2000 if full else 200
    rows = []
    for case in standard_cases(full):
        if groups and case.group not in groups:
            continue
        rows.extend(run_case(case, refs, repeats, long_steps, log))
    mem = {}
    if memory:
        for n in ([10**5, 10**6, 10**7] if full else [10**5]):
            mem[str(n)] = memory_probe(n)
            log(f"memory       N={n:.0e}: {mem[str(n)]:.0f} bytes per particle (peak, GSD every 100 steps)")
    return {"machine": machine(), "full": full, "rows": rows, "memory_bytes_per_particle": mem,
            "summary": summarise(rows)}


def _rate(rows, group, case, impl="flocking"):
    for r in rows:
        if r["group"] == group and r["case"] == case and r["implementation"] == impl:
            return r.get("particle_steps_per_s")
    return None


def summarise(rows: list[dict]) -> dict:
    """The derived ratios the targets are stated in (those the rows allow)."""
    out = {}
    for r in rows:
        if r["group"] == "2d-metric" and r["init"] == "clustered":
            homo = _rate(rows, "2d-metric", r["case"].replace("clustered", "aligned"))
            if homo and r.get("particle_steps_per_s") and r["implementation"] == "flocking":
                out[f"clustered slowdown {r['case'].split()[0]}"] = homo / r["particle_steps_per_s"]
    for label in {r["case"] for r in rows if r["group"] == "delay"}:
        if label.startswith("tau=10"):
            rest = label.split(" ", 1)[1]
            a, b = _rate(rows, "delay", f"tau=0 {rest}"), _rate(rows, "delay", label)
            if a and b:
                out[f"delay 10 cost {rest}"] = a / b
    one = [r for r in rows if r["group"] == "threads" and r["threads"] == 1]
    two = [r for r in rows if r["group"] == "threads" and r["threads"] == 2]
    if one and two and one[0].get("particle_steps_per_s") and two[0].get("particle_steps_per_s"):
        out["2 threads / 1 thread"] = two[0]["particle_steps_per_s"] / one[0]["particle_steps_per_s"]
    return out


def markdown(result: dict) -> str:
    """The results as a Markdown table, machine first."""
    m = result["machine"]
    lines = [f"Machine: {m['cpu']}, {m['cores']} cores; {m['threads']} numba threads; Python {m['python']}, "
             f"NumPy {m['numpy']}, numba {m['numba']}; pyvicsek {m.get('pyvicsek') or 'not installed'}.", "",
             "| group | case | implementation | threads | particle-steps/s | CPU ns per particle-step "
             "| flocking speed-up |",
             "| --- | --- | --- | ---: | ---: | ---: | ---: |"]
    for r in result["rows"]:
        rate = r.get("particle_steps_per_s")
        rate_s = f"{rate:.3g}" if rate else f"skipped ({r.get('note', '')})"
        ratio = f"{r['flocking_speedup']:.2f}x" if r.get("flocking_speedup") and r["implementation"] != "flocking" else ""
        extra = f" (crowding {r['crowding']:.2f})" if "crowding" in r and r["implementation"] == "flocking" else ""
        cpu = f"{r['cpu_ns_per_particle_step']:.0f}" if rate else ""
        lines.append(f"| {r['group']} | {r['case']}{extra} | {r['implementation']} | {r['threads']} | {rate_s} "
                     f"| {cpu} | {ratio} |")
    if result["summary"]:
        lines += ["", "| derived ratio | value |", "| --- | ---: |"]
        lines += [f"| {k} | {v:.2f} |" for k, v in sorted(result["summary"].items())]
    if result["memory_bytes_per_particle"]:
        lines += ["", "| N (2D, GSD frame every 100 steps) | peak bytes per particle (NumPy, tracemalloc) |",
                  "| ---: | ---: |"]
        lines += [f"| {int(n):.0e} | {v:.0f} |" for n, v in result["memory_bytes_per_particle"].items()]
    return "\n".join(lines) + "\n"


def plot(result: dict, path: str | os.PathLike, theme: str = "light", size: str = "page") -> None:
    """Throughput against N, 2D metric cases, in the house style (:mod:`flocking.viz.style`):
    a colour per implementation, a marker per start (random, clustered); the caption names
    the machine, the threads and the cases' parameters."""
    from .viz import style

    t = style.get_theme(theme)
    fig, ax = style.figure(size, t)
    colours = dict(zip(("flocking", "pyvicsek", "kdtree"), style.palette(t)))
    fs = style.fontsize(fig)
    for impl, colour in colours.items():
        for init, marker, line in (("random", "o", "-"), ("clustered", "s", "--")):
            pts = sorted((r["n"], r["particle_steps_per_s"]) for r in result["rows"]
                         if r["group"] == "2d-metric" and r["implementation"] == impl and r["init"] == init
                         and r.get("particle_steps_per_s"))
            if pts:
                ax.plot(*zip(*pts), ls=line, marker=marker, ms=0.5 * fs, lw=1.2, color=colour,
                        label=f"{impl}, {init} start")
    ax.set(xscale="log", yscale="log")
    style.label_axes(ax, "particles $N$", "particle-steps per second")
    style.legend(ax, t, loc="center left", bbox_to_anchor=(1.0, 0.5))
    m = result["machine"]
    threads = sorted({r["threads"] for r in result["rows"] if r["group"] == "2d-metric"})
    style.title(fig, "Throughput of the 2D metric Vicsek model",
                f"{m['cpu']}, {m['cores']} cores \u00b7 {', '.join(map(str, threads))} thread"
                f"{'s' * (threads != [1])} for every implementation \u00b7 density 2 \u00b7 $R$ = 1 \u00b7 "
                "$v_0$ = 0.5 \u00b7 angular noise $\\eta$ = 1 (pyvicsek: vectorial, its only kind) \u00b7 "
                f"median of {result['rows'][0].get('repeats', 1)} timed runs \u00b7 numba {m['numba']}")
    style.save(fig, path, dpi=150)


def write_results(result: dict, out_dir: str | os.PathLike) -> list[Path]:
    """``results.json``, ``results.md`` and ``throughput.png`` in ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(result, indent=1))
    (out / "results.md").write_text(markdown(result))
    paths = [out / "results.json", out / "results.md"]
    if any(r.get("particle_steps_per_s") for r in result["rows"] if r["group"] == "2d-metric"):
        plot(result, out / "throughput.png")
        paths.append(out / "throughput.png")
    return paths
