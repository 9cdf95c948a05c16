"""Running a sweep: one pure task per point, a folder of finished points, any executor.

Every point is a task ``run_point(task) -> record`` that never raises: a failure comes
back as a record with ``status = "failed"`` and the error. The process that drives the
sweep stores each record as it arrives, atomically, in ``OUT/points/<id>.json`` (written
to a temporary file, then ``os.replace``). A point whose file says ``done`` is never run
again; anything else (missing, failed, or stored by a flocking that measured less,
see :data:`RECORD_FORMAT`) is run by the next invocation. The ``id`` hashes the point's whole
configuration, so a changed base or grid recomputes exactly what changed.

Workers need only the ``flocking`` package: tasks carry plain dicts, records come back as
plain dicts, and only ``keep_trajectories`` needs a folder the workers can write to. Where
tasks run is an executor's business (:mod:`flocking.sweep.executors`).

>>> import tempfile
>>> from flocking.sweep.spec import SweepSpec
>>> spec = SweepSpec.from_dict({"base": {"n": 30, "density": 1.0, "steps": 20},
...                             "grid": {"noise": [0.5, 6.0]}})
>>> out = tempfile.mkdtemp()
>>> summary = execute(spec, out, progress=False)  # in this process
>>> summary["done"], summary["failed"], summary["skipped"]
(2, 0, 0)
>>> execute(spec, out, progress=False)["skipped"]
2
>>> record = PointStore(out).load(spec.points()[0].id)
>>> sorted(record["errors"]), record["tau"] >= 0.5
(['binder', 'mean', 'phi2', 'phi4', 'susceptibility'], True)
"""

from __future__ import annotations

import json
import math
import os
import socket
import time
import traceback
from typing import Any, Callable

from ..files import write_text
from ..observables import extra_names
from ..writers import Writer
from .spec import Point, SweepSpec

POINTS = "points"
#: Version of the records written now: 2 added within-run errors (``errors``, ``tau``,
#: ``drift``, ``samples``), 3 the other observables of extended models (``extra``);
#: records without ``format`` are version 1.
RECORD_FORMAT = 3
#: The moments a record holds, named as :class:`flocking.analysis.PolarOrder` names them.
MOMENTS = ("mean", "phi2", "phi4", "susceptibility", "binder")


def task_of(point: Point, out: str, spec: SweepSpec, threads: int | None) -> dict[str, Any]:
    """What a worker needs to run ``point``: plain data only."""
    trajectory = None
    if spec.keep_trajectories:
        trajectory = os.path.join(os.path.abspath(out), POINTS, point.id, "trajectory.gsd")
    return {"id": point.id, "params": point.params, "replica": point.replica,
            "config": point.config.to_dict(), "discard": point.discard,
            "time_series": spec.time_series, "trajectory": trajectory, "threads": threads}


def run_point(task: dict[str, Any]) -> dict[str, Any]:
    """Run one point here and return its record; errors become a ``failed`` record."""
    record = new_record(task)
    start = time.perf_counter()
    try:
        record.update(measure(task))
        record["status"] = "done"
    except Exception as err:  # a failed point must not stop the sweep
        fail(record, err)
    record["elapsed"] = time.perf_counter() - start
    return record


def new_record(task: dict[str, Any]) -> dict[str, Any]:
    """What every record of ``task`` holds, done or failed."""
    return {"id": task["id"], "params": task["params"], "replica": task["replica"],
            "seed": task["config"]["seed"], "host": socket.gethostname()}


def fail(record: dict[str, Any], err: BaseException) -> dict[str, Any]:
    """Mark ``record`` failed by ``err`` (with the traceback being handled, if any)."""
    record["status"] = "failed"
    record["error"] = f"{type(err).__name__}: {err}"
    record["traceback"] = "".join(traceback.format_exception(err))
    return record


def measure(task: dict[str, Any]) -> dict[str, Any]:
    """Simulate the task's configuration and measure it after the transient
    (:func:`summarise`)."""
    from ..config import RunConfig
    from ..simulation import Simulation

    if task.get("threads"):
        import numba

        numba.set_num_threads(min(int(task["threads"]), numba.config.NUMBA_NUM_THREADS))
    cfg = RunConfig.from_dict(task["config"])
    sim = Simulation(cfg.model, cfg.initial_state(), backend=cfg.backend, **cfg.backend_options())
    trajectory = start_trajectory(task, cfg)
    if trajectory is not None:
        sim.info["run"] = trajectory[1]
        sim.writers.append(trajectory[0])
    extra = Extra(sim.step + task["discard"])
    if extra_names(cfg.model):
        sim.writers.append(extra)
    sim.run(cfg.steps)
    return summarise(task, cfg, sim.polar_order[task["discard"] + 1:], sim.step, extra.series)


def start_trajectory(task: dict[str, Any], cfg) -> tuple[Any, dict[str, Any]] | None:
    """A GSD writer for the task's kept trajectory (its folder and config.toml made), and
    the run's information for the file; ``None`` when trajectories are not kept."""
    if not task.get("trajectory"):
        return None
    from ..writers import GSDWriter

    folder = os.path.dirname(task["trajectory"])
    os.makedirs(folder, exist_ok=True)
    write_text(os.path.join(folder, "config.toml"), cfg.to_toml())
    return (GSDWriter(task["trajectory"], every=cfg.every),
            {"steps": cfg.steps, "every": cfg.every, "init": cfg.to_dict()["init"]})


def summarise(task: dict[str, Any], cfg, phi, step: int, extra: dict[str, list] | None = None) -> dict[str, Any]:
    """The measured part of a record: the moments of the polar order ``phi`` (the steps
    after the transient, ending at ``step``), their within-run errors and autocorrelation
    time (:class:`flocking.analysis.PolarOrder`), and the mean and error of each other
    observable of the model over the same steps (per-species polar order, nematic order)."""
    import warnings

    import numpy as np

    from ..analysis import PolarOrder

    phi = np.asarray(phi, dtype=np.float64)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # not equilibrated: the drift is stored instead
        op = PolarOrder().compute(phi, n=cfg.model.n)
        others = {name: PolarOrder().compute(np.concatenate(parts)) for name, parts in (extra or {}).items()}
    result = {"format": RECORD_FORMAT,
              "moments": {name: getattr(op, name) for name in MOMENTS},
              "errors": {name: _finite(getattr(op, name + "_error")) for name in MOMENTS},
              "tau": op.tau, "drift": _finite(op.drift), "samples": op.samples,
              "extra": {name: {"mean": o.mean, "error": _finite(o.mean_error)} for name, o in others.items()},
              "first_step": step - len(phi) + 1, "steps": cfg.steps, "n": cfg.model.n,
              "config": cfg.to_toml()}
    if task.get("time_series"):
        result["phi"] = phi.tolist()
    return result


class Extra(Writer):
    """A writer that keeps the observables beyond the polar order
    (:func:`flocking.observables.extra_names`) of the steps after ``after``."""

    def __init__(self, after: int):
        self.after = after
        self.series: dict[str, list] = {}

    def observe(self, steps, phi, extra=None) -> None:
        keep = steps > self.after
        for name, values in (extra or {}).items():
            self.series.setdefault(name, []).append(values[keep])


def _finite(value: float) -> float | None:
    """JSON has no NaN or infinity: a value that is not finite is stored as ``null``."""
    return value if math.isfinite(value) else None


class PointStore:
    """The folder ``OUT/points``: one JSON record per finished point."""

    def __init__(self, out: str | os.PathLike):
        self.folder = os.path.join(os.fspath(out), POINTS)

    def path(self, point_id: str) -> str:
        return os.path.join(self.folder, point_id + ".json")

    def load(self, point_id: str) -> dict[str, Any] | None:
        """The stored record of a point, or ``None`` (never stored, or unreadable)."""
        try:
            with open(self.path(point_id), encoding="utf-8") as f:
                return json.load(f)
        except (OSError, ValueError):
            return None

    def state(self, point: Point) -> str:
        """``done``, ``outdated`` (done by a flocking that stored less: no within-run
        errors, or no other observables where the model has them), ``failed`` or ``missing``."""
        record = self.load(point.id)
        if record is None:
            return "missing"
        if record.get("status") != "done":
            return "failed"
        version = record.get("format", 1)
        if version >= RECORD_FORMAT or (version == 2 and not extra_names(point.config.model)):
            return "done"
        return "outdated"

    def is_done(self, point: Point) -> bool:
        return self.state(point) == "done"

    def save(self, record: dict[str, Any]) -> None:
        os.makedirs(self.folder, exist_ok=True)
        write_text(self.path(record["id"]), json.dumps(record, indent=1))


def execute(spec: SweepSpec, out: str | os.PathLike, executor=None, *, progress: bool = True,
            report: Callable[[str], None] = print) -> dict[str, Any]:
    """Run every point of ``spec`` that ``out`` does not hold yet on ``executor`` (default:
    :class:`~flocking.sweep.executors.Serial`); return a summary.

    The executor is entered (a cluster started, a scheduler reached) and, for points on
    the ``cuda`` backend, asked whether it has a GPU before anything is written, and only
    if some point is left to run. Points run in jobs (:func:`~flocking.sweep.ensembles.jobs`:
    on the GPU, ensembles of points). Interrupting (Ctrl-C) loses only the points in flight.
    """
    from .ensembles import jobs
    from .executors import Serial

    executor = Serial() if executor is None else executor
    out = os.fspath(out)
    store = PointStore(out)
    points = list({p.id: p for p in spec.points()}.values())
    todo = [p for p in points if not store.is_done(p)]
    summary = {"points": len(points), "skipped": len(points) - len(todo), "done": 0, "failed": 0,
               "failures": [], "where": executor.where}
    if not todo:
        write_text(os.path.join(out, "sweep.toml"), spec.text)
        return summary

    def store_record(record: dict[str, Any]) -> None:
        store.save(record)
        if record["status"] == "done":
            summary["done"] += 1
        else:
            summary["failed"] += 1
            summary["failures"].append(record)
            label = ", ".join(f"{k}={v!r}" for k, v in record["params"].items())
            report(f"flocking sweep: point {record['id']} ({label}, replica={record['replica']}) "
                   f"failed: {record['error'].splitlines()[0]}")  # one line each; the record keeps all

    with executor:
        tasks = [task_of(p, out, spec, executor.threads) for p in todo]
        if any(task["config"]["backend"] == "cuda" for task in tasks):
            executor.check_gpu()
        os.makedirs(store.folder, exist_ok=True)
        write_text(os.path.join(out, "sweep.toml"), spec.text)
        summary["where"] = executor.where
        bar = _bar(len(tasks), progress)
        try:
            for record in executor.records(jobs(tasks)):
                store_record(record)
                bar.update(1)
        finally:
            bar.close()
    return summary


def _bar(total: int, progress: bool):
    from tqdm.auto import tqdm

    return tqdm(total=total, unit="point", dynamic_ncols=True, disable=True if not progress else None,
                desc="sweep")
