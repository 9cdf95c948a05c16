"""Where the points of a sweep run: in this process, or on a Dask cluster.

An executor is a context manager with a ``where`` text, the numba ``threads`` each task
may use (``None``: all of them), ``check_gpu()``, which raises a one-line
:class:`ParameterError` unless it can run the ``cuda`` backend somewhere, and
``records(jobs)``, which runs jobs (lists of tasks, :mod:`flocking.sweep.ensembles`)
somehow and yields one record per task in any order
(:func:`~flocking.sweep.ensembles.run_job` gives the records of one job). Entering it
acquires what it needs (a cluster, a connection) and fails there, before
:func:`~flocking.sweep.runner.execute` writes anything; leaving it releases everything.
Another executor only has to follow the same rules.

Jobs on the GPU (ensembles) go to the workers that had a GPU when ``check_gpu`` asked,
by host name: every worker on those hosts, when not every worker has one.

The local Dask cluster listens on ``127.0.0.1`` only (scheduler, nannies, workers and the
dashboard), and speaks TLS with a key made for it in memory: no other machine can reach it,
and no other user of this machine can submit work to it (a Dask scheduler runs any code
that it is sent).

>>> with Serial() as ex:
...     ex.where, ex.threads
('in-process', None)
>>> check_address("10.0.0.1:8786")  # Dask's default protocol
('tcp', '10.0.0.1:8786')
"""

from __future__ import annotations

import os
import socket
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from ..model import ParameterError
from .ensembles import run_job
from .point import new_record

#: Seconds to wait for a scheduler's TCP port to answer before giving up.
CONNECT_TIMEOUT = 5.0


class Serial:
    """Run tasks one after another in this process (numba uses every core for each)."""

    where = "in-process"
    threads = None

    def __enter__(self) -> Serial:
        return self

    def __exit__(self, *exc) -> None:
        return None

    def check_gpu(self) -> None:
        gpu_here()

    def records(self, jobs: Iterable[list[dict[str, Any]]]) -> Iterator[dict[str, Any]]:
        for job in jobs:
            yield from run_job(job)


class Dask:
    """Run tasks on a Dask cluster: a running one at ``scheduler``, or a local one.

    The local cluster has ``workers`` single-threaded worker processes (default: one per
    core) and binds every port, the dashboard's included, to ``host`` (default
    ``127.0.0.1``). ``report`` receives one line with the dashboard's address.
    """

    threads = 1  # one numba thread per task: a worker per core is the right layout

    def __init__(self, scheduler: str | None = None, workers: int | None = None, host: str | None = None,
                 report: Callable[[str], None] = print):
        if scheduler is not None and (workers is not None or host is not None):
            option = "workers" if workers is not None else "host"
            raise ParameterError(f"{option}: sets up the local cluster; a --scheduler brings its own")
        if scheduler is not None:
            check_address(scheduler)
        self.scheduler, self.workers, self.host = scheduler, workers, host or "127.0.0.1"
        self.report = report
        self.where = scheduler or "local cluster"
        self._client = self._cluster = None
        self._gpu_hosts: list[str] | None = None  # None: any worker may run a GPU job

    def __enter__(self) -> Dask:
        from distributed import Client, LocalCluster

        if self.scheduler is None:
            try:
                self._cluster = LocalCluster(
                    n_workers=self.workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                    host=self.host, dashboard_address=f"{_bracketed(self.host)}:0", security=True,
                    env={"NUMBA_NUM_THREADS": "1"})
            except (OSError, RuntimeError) as err:  # distributed wraps the OSError of a failed bind
                cause = err if isinstance(err, OSError) else err.__cause__
                if not isinstance(cause, OSError):
                    raise
                raise ParameterError(f"host: cannot listen on {self.host!r} ({cause.strerror or cause})") from None
            self._client = Client(self._cluster)
        else:
            reach(self.scheduler)
            try:
                self._client = Client(self.scheduler, timeout=f"{2 * CONNECT_TIMEOUT}s")
            except OSError as err:  # a TCP port answered, but not a Dask scheduler we may use
                raise ConnectionError(f"scheduler: cannot connect to {self.scheduler!r} ({err})") from None
        workers = len(self._client.scheduler_info()["workers"])
        self.where = f"{workers} Dask workers at {self._client.scheduler.address}"
        self.report(f"flocking sweep: Dask dashboard at {self._client.dashboard_link}")
        return self

    def __exit__(self, *exc) -> None:
        if self._client is not None:
            self._client.close()
        if self._cluster is not None:
            self._cluster.close()
        self._client = self._cluster = None

    def check_gpu(self) -> None:
        """Ask every worker whether it can run the ``cuda`` backend; refuse if none can."""
        from distributed.comm import get_address_host

        answers = self._client.run(_gpu_answer)
        able = sorted(address for address, why in answers.items() if why is None)
        if not able:
            why = next(iter(answers.values()), "no workers").removeprefix("backend: ")
            raise ParameterError(f"backend: none of the {len(answers)} Dask workers at "
                                 f"{self._client.scheduler.address} can run 'cuda' ({why})")
        if len(able) < len(answers):
            self._gpu_hosts = sorted({get_address_host(a) for a in able})
        self.where += f", {len(able)} with a GPU"

    def records(self, jobs: Iterable[list[dict[str, Any]]]) -> Iterator[dict[str, Any]]:
        import hashlib

        from distributed import as_completed

        by_key = {}
        for job in jobs:
            if len(job) == 1:
                key = f"flocking-point-{job[0]['id']}"
            else:
                key = "flocking-group-" + hashlib.sha256(" ".join(t["id"] for t in job).encode()).hexdigest()[:16]
            hosts = self._gpu_hosts if job[0]["config"]["backend"] == "cuda" else None
            future = self._client.submit(run_job, job, key=key, pure=False, workers=hosts)
            by_key[future.key] = (future, job)
        for future in as_completed([f for f, _ in by_key.values()]):
            job = by_key.pop(future.key)[1]
            try:
                records = future.result()
            except Exception as err:  # the worker died (KilledWorker) or could not run the job
                records = [{**new_record(task), "host": None, "status": "failed",
                            "error": f"{type(err).__name__}: {err}", "elapsed": float("nan")} for task in job]
            future.release()
            yield from records


def gpu_here() -> None:
    """Raise the ``cuda`` backend's one-line error unless this process can run it."""
    from ..backends.cuda import require_cuda

    require_cuda()


def _gpu_answer() -> str | None:
    """On a worker: ``None`` if it can run the ``cuda`` backend, else why not (one line)."""
    try:
        gpu_here()
    except ParameterError as err:
        return str(err)
    return None


def check_address(address: str) -> tuple[str, str]:
    """``(scheme, location)`` of a Dask address, refused in one line when malformed."""
    from distributed.comm import parse_address, parse_host_port
    from distributed.comm.registry import backends

    def bad(why: str) -> ParameterError:
        return ParameterError(f"scheduler: must be an address such as tcp://10.0.0.1:8786 (got {address!r}: {why})")

    try:
        scheme, location = parse_address(address)
        if scheme in ("tcp", "tls"):
            parse_host_port(location)
    except ValueError as err:
        raise bad(str(err)) from None
    if scheme not in backends:
        raise bad(f"unknown protocol {scheme!r}; known: {', '.join(backends)}")
    return scheme, location


def reach(address: str, timeout: float = CONNECT_TIMEOUT) -> None:
    """Raise :class:`ConnectionError` (one line) unless a TCP scheduler address answers."""
    from distributed.comm import parse_host_port

    scheme, location = check_address(address)
    if scheme not in ("tcp", "tls"):
        return  # other protocols are checked by the client itself
    host, port = parse_host_port(location)
    try:
        socket.create_connection((host, port), timeout=timeout).close()
    except OSError as err:
        why = f"no answer within {timeout:g} s" if isinstance(err, TimeoutError) else (err.strerror or str(err))
        raise ConnectionError(f"scheduler: cannot reach {address!r} ({why})") from None


def _bracketed(host: str) -> str:
    """An IPv6 literal in brackets, as addresses with a port write it."""
    return f"[{host}]" if ":" in host and not host.startswith("[") else host


__all__ = ["Dask", "Serial", "check_address", "gpu_here", "reach"]
