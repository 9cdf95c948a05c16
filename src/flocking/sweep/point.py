"""One point of a sweep, run here: a task of plain data in, a record of plain data out.

:func:`run_point` simulates a task (:func:`~flocking.sweep.runner.task_of`) and returns
its record; it never raises: a failure comes back as a record with ``status = "failed"``
and the error. :func:`summarise` measures a run's polar order (and the other observables
of extended models) into the record's moments and their within-run errors, whether the
run was a single simulation or a replica of an ensemble (:mod:`flocking.sweep.ensembles`).

>>> from flocking.sweep.spec import SweepSpec
>>> from flocking.sweep.runner import task_of
>>> spec = SweepSpec.from_dict({"base": {"n": 30, "density": 1.0, "steps": 20}, "grid": {"noise": [0.5]}})
>>> record = run_point(task_of(spec.points()[0], "out", spec, None))
>>> record["status"], sorted(record["errors"]), record["format"] == RECORD_FORMAT
('done', ['binder', 'mean', 'phi2', 'phi4', 'susceptibility'], True)
"""

from __future__ import annotations

import math
import os
import socket
import time
import traceback
from typing import Any

from ..files import write_text
from ..observables import extra_names
from ..writers import Writer

#: Version of the records written now: 2 added within-run errors (``errors``, ``tau``,
#: ``drift``, ``samples``), 3 the other observables of extended models (``extra``);
#: records without ``format`` are version 1.
RECORD_FORMAT = 3
#: The moments a record holds, named as :class:`flocking.analysis.PolarOrder` names them.
MOMENTS = ("mean", "phi2", "phi4", "susceptibility", "binder")


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


__all__ = ["MOMENTS", "RECORD_FORMAT", "Extra", "fail", "measure", "new_record", "run_point", "start_trajectory",
           "summarise"]
