"""Exact resume: a run that is stopped, killed or extended gives the same files as one that never was."""

import os
import random
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from click.testing import CliRunner

import flocking
from flocking.cli import main
from flocking.cli.compare import differences

SRC = os.path.dirname(os.path.dirname(flocking.__file__))


def cli(*args, code=0):
    result = CliRunner().invoke(main, ["run", *map(str, args)])
    assert result.exit_code == code, result.output
    return result


def frames(folder):
    with flocking.open(os.path.join(folder, "trajectory.gsd")) as t:
        return [(f.step, f.points.copy(), f.velocities.copy()) for f in t]


def assert_same_run(a, b):
    fa, fb = frames(a), frames(b)
    assert [f[0] for f in fa] == [f[0] for f in fb]
    for x, y in zip(fa, fb):
        assert np.array_equal(x[1], y[1]) and np.array_equal(x[2], y[2])
    with open(os.path.join(a, "observables.csv"), "rb") as fa_, open(os.path.join(b, "observables.csv"), "rb") as fb_:
        assert fa_.read() == fb_.read()
    assert differences(a, b) == []  # what `flocking compare` says about them


CASES = {
    "2d": ["--n", 300],
    "3d-topological-delay": ["--dim", 3, "--n", 200, "--neighbours", "topological", "--delay", 3],
    "delay-vectorial-uniform": ["--n", 300, "--delay", 4, "--noise-type", "vectorial", "--noise", 0.5,
                                "--speeds", "uniform"],
    "reference-delay": ["--n", 60, "--box", 4, "--delay", 2, "--backend", "reference"],
}


@pytest.mark.parametrize("case", CASES)
def test_finished_run_extended_equals_one_long_run(tmp_path, case):
    args = [*CASES[case], "--every", 7, "--checkpoint-every", 10, "-q"]
    cli(*args, "--steps", 40, "--out", tmp_path / "long")
    cli(*args, "--steps", 23, "--out", tmp_path / "short")
    cli("--resume", tmp_path / "short", "--steps", 40, "-q")
    assert_same_run(tmp_path / "long", tmp_path / "short")
    assert "steps = 40" in (tmp_path / "short" / "config.toml").read_text()


def test_resume_of_a_complete_run_changes_nothing(tmp_path):
    cli("--n", 100, "--steps", 10, "--out", tmp_path / "a", "-q")
    before = (tmp_path / "a" / "observables.csv").read_bytes()
    cli("--resume", tmp_path / "a", "-q")
    assert (tmp_path / "a" / "observables.csv").read_bytes() == before


def test_resume_keeps_the_choice_of_pictures_unless_told(tmp_path):
    out = tmp_path / "a"
    cli("--n", 100, "--steps", 10, "--no-plots", "--out", out, "-q")
    assert not (out / "snapshot.png").exists()
    cli("--resume", out, "--steps", 20, "-q")
    assert not (out / "snapshot.png").exists() and not (out / "polar_order.png").exists()
    cli("--resume", out, "--steps", 30, "--plots", "-q")  # told otherwise: pictures, and kept from then on
    assert (out / "snapshot.png").exists() and (out / "polar_order.png").exists()
    os.remove(out / "snapshot.png")
    cli("--resume", out, "--steps", 40, "-q")
    assert (out / "snapshot.png").exists()
    # a run made with the defaults draws its pictures again when resumed, and no movie
    cli("--n", 100, "--steps", 10, "--out", tmp_path / "b", "-q")
    os.remove(tmp_path / "b" / "snapshot.png")
    cli("--resume", tmp_path / "b", "--steps", 20, "-q")
    assert (tmp_path / "b" / "snapshot.png").exists() and not (tmp_path / "b" / "movie.mp4").exists()


def test_resume_errors(tmp_path):
    cli("--n", 100, "--steps", 10, "--out", tmp_path / "a", "-q")
    r = cli("--resume", tmp_path / "a", "--noise", 2.0, code=2)
    assert "only --steps and --checkpoint-every may change (got --noise)" in r.output
    r = cli("--resume", tmp_path / "a", "--steps", 5, code=2)
    assert "--steps: must be at least 10" in r.output
    r = cli("--resume", tmp_path / "nowhere", code=2)
    assert "is not a run folder" in r.output
    (tmp_path / "a" / "checkpoint.npz").write_bytes(b"garbage")
    r = cli("--resume", tmp_path / "a", "--steps", 20, code=2)
    assert "cannot read the checkpoint" in r.output and "Traceback" not in r.output
    os.remove(tmp_path / "a" / "checkpoint.npz")
    r = cli("--resume", tmp_path / "a", "--steps", 20, code=2)
    assert "has no checkpoint.npz" in r.output


def _start(out, extra=()):
    env = dict(os.environ, PYTHONPATH=SRC)
    args = [sys.executable, "-m", "flocking", "run", "--n", "20000", "--steps", "400", "--every", "10",
            "--checkpoint-every", "25", "--delay", "2", "--out", str(out), "-q", *extra]
    return subprocess.Popen(args, env=env, stderr=subprocess.PIPE, text=True)


def _wait_for_checkpoint(out, proc, timeout=120):
    deadline = time.time() + timeout
    while time.time() < deadline and proc.poll() is None:
        if (out / "checkpoint.npz").exists():
            return
        time.sleep(0.05)


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    out = tmp_path_factory.mktemp("whole") / "run"
    proc = _start(out)
    assert proc.wait(timeout=300) == 0, proc.stderr.read()
    return out


@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_signal_stops_with_a_checkpoint_and_resume_is_exact(tmp_path, uninterrupted, sig, code):
    out = tmp_path / "run"
    proc = _start(out)
    _wait_for_checkpoint(out, proc)
    time.sleep(0.3)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    if proc.returncode == 0:
        pytest.skip("the run finished before the signal arrived")
    assert proc.returncode == code and "--resume" in err and "Traceback" not in err
    cli("--resume", out, "-q")
    assert_same_run(uninterrupted, out)


@pytest.mark.parametrize("attempt", range(2))
def test_kill_9_at_a_random_moment_then_resume_is_exact(tmp_path, uninterrupted, attempt):
    out = tmp_path / "run"
    proc = _start(out)
    _wait_for_checkpoint(out, proc)
    time.sleep(random.Random(attempt).uniform(0.0, 1.5))
    proc.kill()
    proc.wait()
    # whatever was flushed is readable, with no torn row
    with flocking.open(out / "trajectory.gsd") as t:
        assert all(f.n == 20000 for f in t)
    rows = (out / "observables.csv").read_text().split("\n")
    assert all(len(r.split(",")) == 2 for r in rows[:-1] if r)
    cli("--resume", out, "-q")
    assert_same_run(uninterrupted, out)
