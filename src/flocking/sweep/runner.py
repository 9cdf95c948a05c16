"""Running a sweep: one pure task per point, a folder of finished points, any executor.

Every point is a task (:func:`task_of`) that :func:`~flocking.sweep.point.run_point`
turns into a record without ever raising. The process that drives the sweep
(:func:`execute`) stores each record as it arrives, atomically, in ``OUT/points/<id>.json``
(written to a temporary file, then ``os.replace``). A point whose file says ``done`` is never
run again; anything else (missing, failed, or stored by a flocking that measured less, see
:data:`~flocking.sweep.point.RECORD_FORMAT`) is run by the next invocation. The ``id`` hashes
the point's whole configuration, so a changed base or grid recomputes exactly what changed.

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
import os
from typing import Any, Callable

from ..files import write_text
from ..observables import extra_names
from .ensembles import jobs
from .executors import Serial
from .point import RECORD_FORMAT
from .spec import Point, SweepSpec

#: The folder of ``OUT`` that holds the records.
POINTS = "points"


def task_of(point: Point, out: str, spec: SweepSpec, threads: int | None) -> dict[str, Any]:
    """What a worker needs to run ``point``: plain data only."""
    trajectory = None
    if spec.keep_trajectories:
        trajectory = os.path.join(os.path.abspath(out), POINTS, point.id, "trajectory.gsd")
    return {"id": point.id, "params": point.params, "replica": point.replica,
            "config": point.config.to_dict(), "discard": point.discard,
            "time_series": spec.time_series, "trajectory": trajectory, "threads": threads}


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
