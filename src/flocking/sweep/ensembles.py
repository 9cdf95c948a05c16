"""Jobs: what one worker runs at once. On the GPU, points that share a shape run as one ensemble.

A job is a list of tasks (:func:`~flocking.sweep.runner.task_of`); :func:`run_job` runs
it and returns one record per task, never raising. A point on the ``cpu`` or
``reference`` backend is a job of its own (a worker per core runs them side by side).
Points on the ``cuda`` backend are grouped (:func:`jobs`): those with the same precision,
number of steps and everything :func:`flocking.ensemble.groups` asks to share (dimension,
size, box, radius, neighbour rule, noise type, update, ``dt``) form one
:class:`flocking.Ensemble`, advanced by one set of launches on one GPU, whatever their
noise, alignment, speed, delay, seed or replica. A group holds at most
:data:`MAX_PARTICLES` particles and :data:`MAX_VALUES` values of the polar order; larger
ones are split.

Each replica of an ensemble takes, bit for bit, the steps of its model alone on the
``cuda`` backend (tested under numba's CUDA simulator), so a record does not depend on
the group it ran in: a cuda point gives the same record run alone
(:func:`~flocking.sweep.point.run_point`), in a group of any size, in this process or on
a Dask worker.

>>> from flocking.sweep.spec import SweepSpec
>>> from flocking.sweep.runner import task_of
>>> spec = SweepSpec.from_dict({"sweep": {"replicas": 2}, "grid": {"noise": [0.5, 1.0], "n": [20, 30]},
...                             "base": {"box": 4.0, "steps": 10, "backend": "cuda"}})
>>> [[t["params"]["n"] for t in job] for job in jobs([task_of(p, "out", spec, None) for p in spec.points()])]
[[20, 20, 20, 20], [30, 30, 30, 30]]
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..observables import extra_names
from .point import Extra, fail, new_record, run_point, start_trajectory, summarise

#: Most particles (replicas x n) of one ensemble, and most polar order values (replicas
#: x steps) it returns at once: a group beyond either is split.
MAX_PARTICLES = 2**24
MAX_VALUES = 2**26


def jobs(tasks: list[dict[str, Any]]) -> list[list[dict[str, Any]]]:
    """``tasks`` as jobs, in order of first appearance: one per task, except on the
    ``cuda`` backend, where tasks that can share an ensemble form one job."""
    from ..config import RunConfig
    from ..ensemble import groups

    out: list[list[dict[str, Any]]] = []
    gpu: dict[tuple, list[dict[str, Any]]] = {}
    for task in tasks:
        config = task["config"]
        if config["backend"] != "cuda":
            out.append([task])
            continue
        key = (config["precision"], config["steps"])
        if key not in gpu:
            gpu[key] = []
            out.append(gpu[key])  # in place of the first of its tasks
        gpu[key].append(task)
    result = []
    for job in out:
        if job[0]["config"]["backend"] != "cuda":
            result.append(job)
            continue
        models = [RunConfig.from_dict(t["config"]).model for t in job]
        for group in groups(models):
            size = max(1, min(MAX_PARTICLES // models[group[0]].n, MAX_VALUES // max(job[0]["config"]["steps"], 1)))
            result.extend([job[i] for i in group[start:start + size]] for start in range(0, len(group), size))
    return result


def run_job(job: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Run a job here: one record per task (a failure is a ``failed`` record)."""
    if job[0]["config"]["backend"] == "cuda":
        return run_group(job)
    return [run_point(task) for task in job]


def run_group(tasks: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Run ``tasks`` (which can share an ensemble, see :func:`jobs`) as ensembles: one
    per step their initial states start from (a state read from a file may start late).

    A task whose configuration or initial state cannot be made fails alone; an ensemble
    that fails fails its tasks. ``elapsed`` is the ensemble's time over its replicas.
    """
    from ..config import RunConfig

    records, ready = [], {}
    for task in tasks:
        try:
            cfg = RunConfig.from_dict(task["config"])
            state = cfg.initial_state()
        except Exception as err:  # a failed point must not stop the others
            records.append({**fail(new_record(task), err), "elapsed": float("nan")})
            continue
        ready.setdefault(state.step, []).append((task, cfg, state))
    for items in ready.values():
        records.extend(_ensemble(items))
    return records


def _ensemble(items: list[tuple[dict[str, Any], Any, Any]]) -> list[dict[str, Any]]:
    from ..ensemble import Ensemble
    from ..simulation import NonFiniteError

    records = [new_record(task) for task, _, _ in items]
    start = time.perf_counter()
    try:
        first = items[0][1]
        ens = Ensemble([cfg.model for _, cfg, _ in items], [state for _, _, state in items],
                       backend=first.backend, precision=first.precision)
        writers, infos, extras = [], [], []
        for task, cfg, _ in items:
            trajectory = start_trajectory(task, cfg)
            # the observables of extended models (per species, nematic), as run_point keeps them
            extras.append(Extra(ens.step + task["discard"]))
            writers.append(([trajectory[0]] if trajectory else []) + ([extras[-1]] if extra_names(cfg.model) else []))
            infos.append({"run": trajectory[1]} if trajectory else {})
        phi = ens.run(first.steps, writers, infos)
    except Exception as err:  # the whole ensemble failed: so did each of its points
        elapsed = (time.perf_counter() - start) / len(items)
        return [{**fail(record, err), "elapsed": elapsed} for record in records]
    elapsed = (time.perf_counter() - start) / len(items)
    for r, (record, (task, cfg, _)) in enumerate(zip(records, items)):
        finite = np.isfinite(phi[r])
        if not finite.all():
            step = ens.origin + int(np.argmin(finite)) + 1
            fail(record, NonFiniteError(f"the run became non-finite at step {step}: a position or "
                                        f"heading is NaN or infinite"))
        else:
            record.update(summarise(task, cfg, phi[r, task["discard"]:], ens.step, extras[r].series))
            record["status"] = "done"
        record["elapsed"], record["ensemble"] = elapsed, len(items)
    return records


__all__ = ["MAX_PARTICLES", "jobs", "run_group", "run_job"]
