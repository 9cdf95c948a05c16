"""Honest failures: full or read-only disks, corrupt inputs, impossible systems."""

import os
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner

import flocking
from flocking.cli import main
from flocking.config import RunConfig
from flocking.model import ParameterError

SRC = os.path.dirname(os.path.dirname(flocking.__file__))


def flocking_cli(*args, cwd=None):
    env = dict(os.environ, PYTHONPATH=SRC)
    return subprocess.run([sys.executable, "-m", "flocking", *map(str, args)], env=env, cwd=cwd,
                          capture_output=True, text=True, timeout=300)


@pytest.fixture
def mount(tmp_path):
    """A tmpfs of a given size and mode, mounted for the test (root only; skipped elsewhere)."""
    mounted = []

    def make(size="256k", readonly=False):
        target = tmp_path / f"disk{len(mounted)}"
        target.mkdir()
        options = f"size={size}" + (",ro" if readonly else "")
        if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(target)],
                                               capture_output=True).returncode != 0:
            pytest.skip("cannot mount a tmpfs here (needs root)")
        mounted.append(target)
        return target

    yield make
    for target in mounted:
        subprocess.run(["umount", "-l", str(target)], capture_output=True)


@pytest.mark.parametrize("n, size", [(2000, "300k"), (70_000, "6m")], ids=["in-line", "threaded-frames"])
def test_full_disk_is_one_line_and_keeps_what_was_written(mount, n, size):
    """Small frames are written in line, large ones by a thread: either way the error."""
    disk = mount(size)
    out = disk / "run"
    r = flocking_cli("run", "--n", n, "--steps", 300, "--every", 1, "--checkpoint-every", 0, "--no-plots",
                     "--out", out, "-q")
    assert r.returncode == 1
    errors = [line for line in r.stderr.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and "No space left on device" in errors[0]
    assert "Traceback" not in r.stderr
    # every frame flushed before the disk filled is still readable
    with flocking.open(out / "trajectory.gsd") as t:
        assert len(t) >= 1 and all(f.n == n for f in t)
    assert not any(name.endswith(".tmp") for name in os.listdir(out))


def test_read_only_folder_is_one_line(mount):
    disk = mount(readonly=True)
    r = flocking_cli("run", "--n", 100, "--steps", 5, "--out", disk / "run")
    assert r.returncode == 1
    assert r.stderr.strip().splitlines()[-1].startswith("Error: Read-only file system")
    assert "Traceback" not in r.stderr


def test_truncated_trajectory_is_refused_as_init(tmp_path):
    r = flocking_cli("run", "--n", 200, "--steps", 20, "--every", 2, "--out", tmp_path / "a", "-q", "--no-plots")
    assert r.returncode == 0, r.stderr
    data = (tmp_path / "a" / "trajectory.gsd").read_bytes()
    for fraction in (0.9, 0.5, 0.05):
        bad = tmp_path / f"cut{fraction}.gsd"
        bad.write_bytes(data[: int(len(data) * fraction)])
        result = CliRunner().invoke(main, ["run", "--init", str(bad), "--out", str(tmp_path / "o")])
        assert result.exit_code == 2 and "--init: cannot read a frame" in result.output
        assert not (tmp_path / "o").exists()


def test_empty_and_foreign_files_are_refused(tmp_path):
    empty = tmp_path / "empty.gsd"
    empty.write_bytes(b"")
    text = tmp_path / "notes.gsd"
    text.write_text("hello")
    for path in (empty, text):
        result = CliRunner().invoke(main, ["run", "--init", str(path), "--out", str(tmp_path / "o")])
        assert result.exit_code == 2 and "--init: cannot read" in result.output


@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
def test_non_finite_values_are_refused(tmp_path, value):
    for option in ("--noise", "--speed", "--radius", "--dt", "--alignment", "--density"):
        result = CliRunner().invoke(main, ["run", option, value, "--out", str(tmp_path / "o")])
        assert result.exit_code == 2, option
        assert result.output.startswith(f"Error: {option}:")
    cfg = tmp_path / "c.toml"
    cfg.write_text(f"noise = {value.replace('inf', 'inf')}\n")
    result = CliRunner().invoke(main, ["run", "--config", str(cfg), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2 and "Error: --noise:" in result.output
    assert not (tmp_path / "o").exists()


def test_system_too_large_for_memory_is_refused_with_an_estimate(tmp_path):
    result = CliRunner().invoke(main, ["run", "--n", "1500000000", "--out", str(tmp_path / "o")])
    assert result.exit_code == 2
    assert "--n: 1500000000 particles need about" in result.output and "GiB" in result.output
    result = CliRunner().invoke(main, ["run", "--n", "300000", "--backend", "reference", "--out", str(tmp_path / "o")])
    assert result.exit_code == 2 and "with backend 'reference'" in result.output
    assert not (tmp_path / "o").exists()


def test_memory_check_uses_the_estimate():
    cfg = RunConfig.from_dict({"n": 1000})
    cfg.check_memory(available=10**12)
    with pytest.raises(ParameterError, match="need about"):
        cfg.check_memory(available=1000)


def test_config_with_a_typo_suggests_the_key(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text("nosie = 1.0\ndesnity = 2\n")
    result = CliRunner().invoke(main, ["run", "--config", str(cfg), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2
    assert result.output.strip() == "Error: nosie: unknown parameter; did you mean 'noise'?"


def test_failed_checkpoint_leaves_the_previous_one(tmp_path, monkeypatch):
    sim = flocking.Simulation(flocking.Model(n=50, box=5.0))
    path = tmp_path / "c.npz"
    sim.save_checkpoint(path)
    good = path.read_bytes()
    sim.run(3)

    def broken(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(np, "savez", broken)
    with pytest.raises(OSError, match="No space left on device"):  # the disk's own error, not another
        sim.save_checkpoint(path)
    assert path.read_bytes() == good
    assert sorted(os.listdir(tmp_path)) == ["c.npz"]  # no temporary left behind
