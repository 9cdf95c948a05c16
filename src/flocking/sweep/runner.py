"""Running a sweep: one pure task per point, a folder of finished points, Dask or serial.

Every point is a task ``run_point(task) -> record`` that never raises: a failure comes
back as a record with ``status = "failed"`` and the error. The process that drives the
sweep stores each record as it arrives, atomically, in ``OUT/points/<id>.json`` (written
to a temporary file, then ``os.replace``). A point whose file says ``done`` is never run
again; anything else (missing, failed) is run by the next invocation. The ``id`` hashes the
point's whole configuration, so a changed base or grid recomputes exactly what changed.

Workers need only the ``flocking`` package: tasks carry plain dicts, records come back as
plain dicts, and only ``keep_trajectories`` needs a folder the workers can write to.

>>> import tempfile
>>> from flocking.sweep.spec import SweepSpec
>>> spec = SweepSpec.from_dict({"base": {"n": 30, "density": 1.0, "steps": 20},
...                             "grid": {"noise": [0.5, 6.0]}})
>>> out = tempfile.mkdtemp()
>>> summary = execute(spec, out, serial=True, progress=False)
>>> summary["done"], summary["failed"], summary["skipped"]
(2, 0, 0)
>>> execute(spec, out, serial=True, progress=False)["skipped"]
2
"""

from __future__ import annotations

import json
import os
import socket
import time
import traceback
from typing import Any, Callable

from ..files import write_text
from .spec import Point, SweepSpec

POINTS = "points"


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
    record = {"id": task["id"], "params": task["params"], "replica": task["replica"],
              "seed": task["config"]["seed"], "host": socket.gethostname()}
    start = time.perf_counter()
    try:
        record.update(measure(task))
        record["status"] = "done"
    except Exception as err:  # a failed point must not stop the sweep
        record["status"] = "failed"
        record["error"] = f"{type(err).__name__}: {err}"
        record["traceback"] = traceback.format_exc()
    record["elapsed"] = time.perf_counter() - start
    return record


def measure(task: dict[str, Any]) -> dict[str, Any]:
    """Simulate the task's configuration and measure the polar order after the transient."""
    import numpy as np

    from ..config import RunConfig
    from ..observables import polar_moments
    from ..simulation import Simulation
    from ..writers import GSDWriter

    if task.get("threads"):
        import numba

        numba.set_num_threads(min(int(task["threads"]), numba.config.NUMBA_NUM_THREADS))
    cfg = RunConfig.from_dict(task["config"])
    sim = Simulation(cfg.model, cfg.initial_state(), backend=cfg.backend)
    if task.get("trajectory"):
        folder = os.path.dirname(task["trajectory"])
        os.makedirs(folder, exist_ok=True)
        write_text(os.path.join(folder, "config.toml"), cfg.to_toml())
        sim.info["run"] = {"steps": cfg.steps, "every": cfg.every, "init": cfg.to_dict()["init"]}
        sim.writers.append(GSDWriter(task["trajectory"], every=cfg.every))
    sim.run(cfg.steps)
    phi = np.asarray(sim.polar_order[task["discard"] + 1:])
    result = {"moments": polar_moments(phi, cfg.model.n), "first_step": sim.step - len(phi) + 1,
              "steps": cfg.steps, "n": cfg.model.n, "config": cfg.to_toml()}
    if task.get("time_series"):
        result["phi"] = phi.tolist()
    return result


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

    def is_done(self, point_id: str) -> bool:
        record = self.load(point_id)
        return record is not None and record.get("status") == "done"

    def save(self, record: dict[str, Any]) -> None:
        os.makedirs(self.folder, exist_ok=True)
        write_text(self.path(record["id"]), json.dumps(record, indent=1))


def execute(spec: SweepSpec, out: str | os.PathLike, *, serial: bool = False, scheduler: str | None = None,
            workers: int | None = None, progress: bool = True,
            report: Callable[[str], None] = print) -> dict[str, Any]:
    """Run every point of ``spec`` that ``out`` does not hold yet; return a summary.

    ``serial`` runs in this process; otherwise ``scheduler`` is the address of a running
    Dask scheduler, or ``None`` for a local cluster of ``workers`` single-threaded worker
    processes (default: one per core). Interrupting (Ctrl-C) loses only the points in flight.
    """
    out = os.fspath(out)
    store = PointStore(out)
    points = list({p.id: p for p in spec.points()}.values())
    todo = [p for p in points if not store.is_done(p.id)]
    os.makedirs(store.folder, exist_ok=True)
    write_text(os.path.join(out, "sweep.toml"), spec.text)
    summary = {"points": len(points), "skipped": len(points) - len(todo), "done": 0, "failed": 0,
               "failures": [], "where": "in-process" if serial else scheduler or "local cluster"}
    if not todo:
        return summary
    threads = None if serial else 1
    tasks = [task_of(p, out, spec, threads) for p in todo]

    def store_record(record: dict[str, Any]) -> None:
        store.save(record)
        if record["status"] == "done":
            summary["done"] += 1
        else:
            summary["failed"] += 1
            summary["failures"].append(record)
            label = ", ".join(f"{k}={v!r}" for k, v in record["params"].items())
            report(f"flocking sweep: point {record['id']} ({label}, replica={record['replica']}) "
                   f"failed: {record['error']}")

    bar = _bar(len(tasks), progress)
    try:
        if serial:
            for task in tasks:
                store_record(run_point(task))
                bar.update(1)
        else:
            _run_dask(tasks, store_record, bar, scheduler, workers, summary)
    finally:
        bar.close()
    return summary


def _run_dask(tasks, store_record, bar, scheduler, workers, summary) -> None:
    from distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler is None:
        cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1,
                               processes=True, host="127.0.0.1", dashboard_address=":0",
                               env={"NUMBA_NUM_THREADS": "1"})
        client = Client(cluster)
    else:
        client = Client(scheduler, timeout="30s")
    summary["where"] = f"{len(client.scheduler_info()['workers'])} Dask workers at {client.scheduler.address}"
    by_key = {}
    try:
        futures = []
        for task in tasks:
            future = client.submit(run_point, task, key=f"flocking-point-{task['id']}", pure=False)
            by_key[future.key] = task
            futures.append(future)
        for future in as_completed(futures):
            task = by_key[future.key]
            try:
                record = future.result()
            except Exception as err:  # the worker died (KilledWorker) or could not run the task
                record = {"id": task["id"], "params": task["params"], "replica": task["replica"],
                          "seed": task["config"]["seed"], "status": "failed",
                          "error": f"{type(err).__name__}: {err}", "elapsed": float("nan")}
            future.release()
            store_record(record)
            bar.update(1)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _bar(total: int, progress: bool):
    from tqdm.auto import tqdm

    return tqdm(total=total, unit="point", dynamic_ncols=True, disable=True if not progress else None,
                desc="sweep")
