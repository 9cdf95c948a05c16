"""Sweeps on the GPU: points that share a shape run as ensembles, with the records of single runs.

The cuda path is run under numba's CUDA simulator, in one subprocess (the simulator must
be on before numba is imported; see tests/test_cuda.py), on a grid kept tiny because
the simulator takes about a second per step of a few dozen particles. Without a GPU,
the refusals and failure records are checked in this process; tests marked ``gpu`` need
a real device and skip cleanly without one.
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys

import numpy as np
import pytest

xr = pytest.importorskip("xarray")
distributed = pytest.importorskip("distributed")

from flocking.cli import main  # noqa: E402
from flocking.model import ParameterError  # noqa: E402
from flocking.sweep import ensembles  # noqa: E402
from flocking.sweep.ensembles import jobs, run_group  # noqa: E402
from flocking.sweep.executors import Dask, Serial  # noqa: E402
from flocking.sweep.point import MOMENTS  # noqa: E402
from flocking.sweep.runner import PointStore, execute, task_of  # noqa: E402
from flocking.sweep.spec import SweepSpec  # noqa: E402
from gpu_marks import CUDA_RUNS, gpu, no_gpu  # noqa: E402

SRC = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir, "src"))

#: Four runs (two noises x two replicas) of one shape: one ensemble. Five steps, the
#: last three measured.
TINY = """
[sweep]
seed = 5
replicas = 2
discard = 2

[base]
n = 16
box = 4.0
steps = 5
backend = "cuda"

[grid]
noise = [0.5, 4.0]
"""

HARNESS = r"""
import json, os, sys, tempfile
import numpy as np
from click.testing import CliRunner
import distributed
from flocking.cli import main
from flocking.sweep.executors import Dask
from flocking.sweep.results import gather, open_results
from flocking.sweep.point import run_point
from flocking.sweep.runner import PointStore, execute, task_of
from flocking.sweep.spec import SweepSpec

folder = tempfile.mkdtemp()
os.chdir(folder)
with open("tiny.toml", "w") as f:
    f.write(sys.argv[1])
spec = SweepSpec.load("tiny.toml")
points = spec.points()
store = PointStore("tiny")

def records():
    return {p.id: store.load(p.id) for p in points}

def without_time(rs):  # what differs between runs of a record: its time, host and ensemble size
    return {k: {f: v for f, v in r.items() if f not in ("elapsed", "host", "ensemble")} for k, r in rs.items()}

out = {}
cli = CliRunner().invoke(main, ["sweep", "tiny.toml", "-q"])  # the file says cuda: in this process
out["cli"] = [cli.exit_code, cli.output]
first = records()
out["status"] = [r["status"] for r in first.values()]
out["ensemble"] = [r.get("ensemble") for r in first.values()]
out["records"] = {p.id: first[p.id] for p in points}

# each point alone on the cuda backend (Simulation, the path of a single run): the same record
# (two: one of each noise, one of each replica; each run here takes seconds)
alone = {p.id: run_point(task_of(p, "tiny", spec, None)) for p in points[1:3]}
out["alone"] = alone
out["same_as_alone"] = without_time({k: first[k] for k in alone}) == without_time(alone)

# a rerun computes nothing and rewrites identical results
whole = open_results("tiny").drop_vars("elapsed")
again = CliRunner().invoke(main, ["sweep", "tiny.toml"])
out["rerun"] = [again.exit_code, again.output]
out["rerun_identical"] = whole.identical(open_results("tiny").drop_vars("elapsed"))

# two points lost: the rerun runs an ensemble of those two, with the same records
for p in points[1:3]:
    os.remove(store.path(p.id))
summary = execute(spec, "tiny", progress=False, report=lambda text: None)
out["resume"] = [summary["done"], summary["skipped"]]
out["resumed_ensemble"] = [store.load(p.id)["ensemble"] for p in points]
out["resume_identical"] = without_time(records()) == without_time(first)

# on a Dask cluster: one task per ensemble, the same records
with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tcp://",
                              host="127.0.0.1", dashboard_address="127.0.0.1:0") as cluster:
    executor = Dask(scheduler=cluster.scheduler_address, report=lambda text: None)
    summary = execute(spec, "dask", executor, progress=False, report=lambda text: None)
    out["dask"] = [summary["done"], summary["where"]]
dask = PointStore("dask")
out["dask_identical"] = without_time({p.id: dask.load(p.id) for p in points}) == without_time(first)

# the same grid with extensions (two species that anti-align, walls along y, a vision cone):
# still one ensemble, the per-species observables in each record, as a single run gives them
with open("ext.toml", "w") as f:
    f.write(sys.argv[1].replace("[grid]", 'species = [{n = 8}, {n = 8, noise = 0.3}]\n'
                                "coupling = [[1.0, -1.0], [-1.0, 1.0]]\nboundary = \"periodic,wall\"\n"
                                "vision = 2.5\n\n[grid]"))
spec = SweepSpec.load("ext.toml")
points = spec.points()
execute(spec, "ext", progress=False, report=lambda text: None)
store = PointStore("ext")
ext = records()
out["ext_ensemble"] = [r.get("ensemble") for r in ext.values()]
out["ext_extra"] = [sorted(r["extra"]) for r in ext.values()]
alone = {p.id: run_point(task_of(p, "ext", spec, None)) for p in points[:2]}  # two are enough, and slow here
out["ext_same_as_alone"] = without_time({k: ext[k] for k in alone}) == without_time(alone)
print("RESULT" + json.dumps(out))
"""


@pytest.fixture(scope="module")
def simulated():
    env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1", "PYTHONPATH": SRC}
    proc = subprocess.run([sys.executable, "-c", HARNESS, TINY], env=env, capture_output=True, text=True,
                          timeout=900)
    lines = [line for line in proc.stdout.splitlines() if line.startswith("RESULT")]
    assert proc.returncode == 0 and lines, proc.stderr[-3000:]
    return json.loads(lines[-1][len("RESULT"):])


def test_simulated_cuda_sweep_runs_one_ensemble_with_the_records_of_single_runs(simulated):
    """The four points share a shape, so they ran as one ensemble of four; each record is,
    bit for bit, the one the same point gives run alone on the cuda backend (checked for
    one point of each noise and each replica)."""
    assert simulated["cli"] == [0, ""]
    assert simulated["status"] == ["done"] * 4 and simulated["ensemble"] == [4] * 4
    assert simulated["same_as_alone"]
    for record in simulated["records"].values():
        assert record["first_step"] == 3 and record["samples"] == 3 and record["steps"] == 5
        assert "backend = \"cuda\"" in record["config"]


def test_simulated_cuda_sweep_with_extensions_records_each_species(simulated):
    """A grid with two anti-aligning species, walls and a vision cone runs as one ensemble
    too, and each record holds each species' polar order, as the point run alone does
    (checked for two of the four points)."""
    assert simulated["ext_ensemble"] == [4] * 4
    assert simulated["ext_extra"] == [["polar_order_A", "polar_order_B"]] * 4
    assert simulated["ext_same_as_alone"]


def test_simulated_cuda_sweep_reruns_and_resumes_with_identical_records(simulated):
    assert simulated["rerun"][0] == 0 and "0 run, 0 failed, 4 already stored" in simulated["rerun"][1]
    assert simulated["rerun_identical"]
    assert simulated["resume"] == [2, 2] and simulated["resume_identical"]
    assert simulated["resumed_ensemble"] == [4, 2, 2, 4]


def test_simulated_cuda_sweep_on_dask_gives_the_same_records(simulated):
    done, where = simulated["dask"]
    assert done == 4 and where.endswith("1 with a GPU")
    assert simulated["dask_identical"]


def test_simulated_cuda_records_equal_cpu_records_to_rounding(simulated, tmp_path):
    """The same points on the cpu backend: the same seeds and so the same initial states,
    and steps that agree with the cuda backend's to rounding (1e-12 a step, tests/test_cuda.py),
    so over five steps the moments agree far below any statistical error (1e-9)."""
    spec = SweepSpec.from_toml(TINY.replace('backend = "cuda"', 'backend = "cpu"'))
    execute(spec, str(tmp_path), progress=False)
    store = PointStore(str(tmp_path))
    cuda = {(json.dumps(r["params"]), r["replica"]): r for r in simulated["records"].values()}
    for point in spec.points():
        cpu = store.load(point.id)
        gpu = cuda[(json.dumps(point.params), point.replica)]
        assert cpu["seed"] == gpu["seed"]
        for name in MOMENTS:
            assert abs(cpu["moments"][name] - gpu["moments"][name]) < 1e-9, name


# -- grouping and refusals, no GPU needed -----------------------------------------------------

def tasks_of(spec):
    return [task_of(p, "out", spec, None) for p in spec.points()]


def test_cuda_points_group_by_shape_steps_and_precision_and_others_run_alone(monkeypatch):
    spec = SweepSpec.from_dict({"sweep": {"replicas": 2}, "base": {"box": 4.0, "steps": 10},
                                "grid": {"backend": ["cuda", "cpu"], "n": [20, 30], "noise": [0.5, 1.0]}})
    found = jobs(tasks_of(spec))
    shapes = [[(t["config"]["backend"], t["config"]["n"]) for t in job] for job in found]
    assert shapes == [[("cuda", 20)] * 4, [("cuda", 30)] * 4] + [[("cpu", n)] for n in (20,) * 4 + (30,) * 4]
    # precision, steps and radius split groups; noise, delay and alignment do not
    spec = SweepSpec.from_dict({"base": {"n": 20, "box": 4.0, "backend": "cuda"},
                                "grid": {"precision": ["float64", "float32"], "steps": [10, 20],
                                         "radius": [1.0, 0.5], "delay": [0, 2], "alignment": [1.0, 0.5]}})
    assert [len(job) for job in jobs(tasks_of(spec))] == [4] * 8
    # a group beyond MAX_PARTICLES particles is split in order
    monkeypatch.setattr(ensembles, "MAX_PARTICLES", 50)
    spec = SweepSpec.from_dict({"sweep": {"replicas": 5}, "base": {"n": 20, "box": 4.0, "steps": 10,
                                                                   "backend": "cuda"}, "grid": {"noise": [0.5]}})
    found = jobs(tasks_of(spec))
    assert [[t["replica"] for t in job] for job in found] == [[0, 1], [2, 3], [4]]


@no_gpu
def test_an_ensemble_that_cannot_start_fails_each_point_and_a_bad_start_fails_alone(tmp_path):
    """Without a device the ensemble fails, and with it each of its points, with the
    backend's one-line reason; a point whose initial state cannot be read fails with its
    own reason. The next invocation retries them all; run in this process, it stops first."""
    bad = tmp_path / "start.gsd"
    bad.write_bytes(b"not a gsd file")
    spec = SweepSpec.from_dict({"sweep": {"discard": 2}, "base": {"n": 16, "box": 4.0, "steps": 5, "backend": "cuda"},
                                "grid": {"init": ["random", str(bad)], "noise": [0.5, 4.0]}})
    records = {(r["params"]["init"], r["params"]["noise"]): r for r in run_group(tasks_of(spec))}
    assert len(records) == 4 and all(r["status"] == "failed" for r in records.values())
    assert records["random", 0.5]["error"].startswith("ParameterError: backend: 'cuda' needs an NVIDIA GPU")
    assert records[str(bad), 4.0]["error"].startswith("ParameterError: init: cannot read a frame")
    assert all(r["traceback"].startswith("Traceback") for r in records.values())
    store = PointStore(str(tmp_path / "out"))
    for record in records.values():
        store.save(record)
    assert [store.state(p) for p in spec.points()] == ["failed"] * 4  # the next invocation runs them
    with pytest.raises(ParameterError, match=r"^backend: 'cuda' needs an NVIDIA GPU"):
        execute(spec, str(tmp_path / "elsewhere"), progress=False)  # in this process: checked first
    assert not (tmp_path / "elsewhere").exists()


@no_gpu
@pytest.mark.parametrize("args, text", [
    (["sweep", "g.toml", "--backend", "cuda", "-q"], "backend: 'cuda' needs an NVIDIA GPU with numba-cuda"),
    (["sweep", "g.toml", "--backend", "cuda", "--workers", "2"], "workers: a cuda sweep without --scheduler runs"),
    (["sweep", "c.toml", "--backend", "cpu"], "backend: the sweep file sweeps over backend ([grid])"),
    (["sweep", "f.toml", "--backend", "cpu"], "grid point {noise = 0.5}: precision: 'float32' needs the cuda"),
    (["sweep", "e.toml", "--backend", "cuda"], "grid point {noise = 0.5}: species: the cuda backend records at "
                                               "most 20 sums a step (5 species in 3D and the nematic order need 21)"),
])
def test_cuda_sweep_errors_are_one_line_and_nothing_is_written(tmp_path, args, text):
    from click.testing import CliRunner

    plain = TINY.replace('backend = "cuda"\n', "")
    files = {"g.toml": plain, "c.toml": plain.replace("noise = [0.5, 4.0]", 'backend = ["cpu", "cuda"]'),
             "f.toml": plain.replace("steps = 5", 'steps = 5\nprecision = "float32"'),
             "e.toml": plain.replace("n = 16", "n = 20").replace(  # 5 x 3 + 6 moment sums a step
                 "steps = 5", 'steps = 5\ndim = 3\nalignment_rule = "nematic"\nspecies = [' + ", ".join(["{n = 4}"] * 5) + "]")}
    runner = CliRunner()
    with contextlib.chdir(tmp_path):
        for name, content in files.items():
            with open(name, "w") as f:
                f.write(content)
        result = runner.invoke(main, args)
        assert result.exit_code == 2, result.output
        lines = result.output.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("Error: ") and text in lines[0]
        assert sorted(os.listdir(".")) == sorted(files)


@no_gpu
def test_a_cluster_without_a_gpu_is_refused_before_anything_is_written(tmp_path):
    spec = SweepSpec.from_toml(TINY)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tcp://",
                                  host="127.0.0.1", dashboard_address="127.0.0.1:0") as cluster:
        executor = Dask(scheduler=cluster.scheduler_address, report=lambda text: None)
        with pytest.raises(ParameterError, match=r"^backend: none of the 1 Dask workers at tcp://127\.0\.0\.1:\d+ "
                                                 r"can run 'cuda' \('cuda' needs an NVIDIA GPU"):
            execute(spec, str(tmp_path / "out"), executor, progress=False)
    assert os.listdir(tmp_path) == []


def test_serial_executor_checks_for_a_gpu_in_this_process():
    if CUDA_RUNS:
        Serial().check_gpu()
    else:
        with pytest.raises(ParameterError, match=r"^backend: 'cuda' needs an NVIDIA GPU"):
            Serial().check_gpu()


# -- real device --------------------------------------------------------------------------------

@pytest.mark.gpu
@gpu
@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_device_sweep_groups_equal_single_runs_and_the_cpu_statistics(tmp_path, precision):
    """On a GPU: 3 noises x 2 sizes x 4 replicas (two ensembles of 12) give, bit for bit,
    the records of single cuda runs; and in the ordered phase the mean order agrees with
    a cpu sweep of other replicas within their errors."""
    from flocking.sweep.point import run_point

    text = f"""
[sweep]
seed = 2
replicas = 4
discard = 300
[base]
density = 2.0
steps = 800
backend = "cuda"
precision = "{precision}"
[grid]
noise = [0.5, 1.0, 5.0]
n = [256, 1024]
"""
    spec = SweepSpec.from_toml(text)
    out = str(tmp_path / "gpu")
    summary = execute(spec, out, Serial(), progress=False)
    assert (summary["done"], summary["failed"]) == (24, 0)
    store = PointStore(out)
    for point in spec.points()[::5]:
        alone = run_point(task_of(point, out, spec, None))
        stored = store.load(point.id)
        assert stored["ensemble"] == 12
        assert stored["moments"] == alone["moments"] and stored["errors"] == alone["errors"]
    cpu = SweepSpec.from_toml(text.replace('backend = "cuda"', 'backend = "cpu"').replace(f'precision = "{precision}"', "")
                              .replace("seed = 2", "seed = 3"))
    execute(cpu, str(tmp_path / "cpu"), Serial(), progress=False)
    from flocking.sweep.results import gather

    a, b = gather(spec, out), gather(cpu, str(tmp_path / "cpu"))
    for ds in (a, b):
        assert (ds["status"] == "done").all()
    ma, mb = a["order"].mean("replica"), b["order"].mean("replica")
    ea = np.sqrt((a["order_error"] ** 2).sum("replica")) / 4
    eb = np.sqrt((b["order_error"] ** 2).sum("replica")) / 4
    sa = a["order"].std("replica", ddof=1) / 2
    sb = b["order"].std("replica", ddof=1) / 2
    err = np.sqrt(np.maximum(ea, sa) ** 2 + np.maximum(eb, sb) ** 2)
    assert (abs(ma - mb) < 5 * err + 1e-3).all()
