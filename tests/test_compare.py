"""`flocking compare`: identical data is recognised whatever the file layout, and any change,
down to one bit of one value, is found and named."""

import os
import shutil

import gsd.hoomd
import numpy as np
import pytest
from click.testing import CliRunner

from flocking.cli import main
from flocking.cli.compare import differences


def compare(a, b):
    return CliRunner().invoke(main, ["compare", str(a), str(b)])


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A run, its --config rerun, and a run of the same model with another seed."""
    root = tmp_path_factory.mktemp("runs")
    args = ["run", "--n", "150", "--box", "7", "--steps", "30", "--every", "10", "--no-plots", "-q"]
    for name, extra in (("a", []), ("other", ["--seed", "1"])):
        assert CliRunner().invoke(main, [*args, *extra, "--out", str(root / name)]).exit_code == 0
    assert CliRunner().invoke(main, ["run", "--config", str(root / "a" / "config.toml"), "--out", str(root / "b"),
                                     "--no-plots", "-q"]).exit_code == 0
    return root


def test_identical_data_in_a_different_file_layout(runs, tmp_path):
    # the same frames written by gsd.hoomd in one go: other bytes, the same data
    relaid = tmp_path / "relaid"
    shutil.copytree(runs / "b", relaid)
    with gsd.hoomd.open(runs / "b" / "trajectory.gsd") as src, gsd.hoomd.open(relaid / "trajectory.gsd", "w") as dst:
        for frame in src:
            dst.append(frame)
    assert (relaid / "trajectory.gsd").read_bytes() != (runs / "a" / "trajectory.gsd").read_bytes()
    result = compare(runs / "a", relaid)
    assert result.exit_code == 0 and "identical data" in result.output
    assert compare(runs / "a" / "trajectory.gsd", relaid / "trajectory.gsd").exit_code == 0


def test_one_bit_of_one_position_is_a_difference(runs, tmp_path):
    changed = tmp_path / "changed"
    shutil.copytree(runs / "b", changed)
    with gsd.hoomd.open(runs / "b" / "trajectory.gsd") as src, gsd.hoomd.open(changed / "trajectory.gsd", "w") as dst:
        for i, frame in enumerate(src):
            if i == 2:
                p = frame.particles.position
                p[17, 1] = np.nextafter(p[17, 1], np.float32(np.inf))
            dst.append(frame)
    result = compare(runs / "a", changed)
    assert result.exit_code == 1
    assert "1 frames differ; the first is frame 2 (step 20): particles.position: 1 of 150 differ" in result.output


def test_observables_and_checkpoint_are_compared(runs, tmp_path):
    changed = tmp_path / "changed"
    shutil.copytree(runs / "b", changed)
    lines = (changed / "observables.csv").read_text().splitlines()
    step, phi = lines[5].split(",")
    lines[5] = f"{step},{np.nextafter(float(phi), 2.0)!r}"
    (changed / "observables.csv").write_text("\n".join(lines) + "\n")
    with np.load(changed / "checkpoint.npz") as data:
        arrays = {k: data[k].copy() for k in data.files}
    arrays["headings"][3, 0] = -arrays["headings"][3, 0]
    np.savez(changed / "checkpoint.npz", **arrays)
    found = differences(str(runs / "a"), str(changed))
    assert len(found) == 2
    assert found[0] == f"observables: 1 rows differ; the first is step {step}: {step},{phi} and {lines[5]}"
    assert found[1].startswith("checkpoint: headings: 1 of 150 differ")
    os.remove(changed / "checkpoint.npz")
    assert differences(str(runs / "a"), str(changed))[-1] == f"checkpoint.npz: only in {runs / 'a'}"


def test_other_runs_differ_in_everything(runs):
    result = compare(runs / "a", runs / "other")
    assert result.exit_code == 1
    assert "parameters: seed 0 and 1" in result.output
    assert "trajectory: 4 frames differ; the first is frame 0 (step 0)" in result.output
    assert "observables: 31 rows differ" in result.output


def test_runs_recorded_at_other_steps_differ(runs, tmp_path):
    args = ["run", "--n", "150", "--box", "7", "--steps", "30", "--every", "7", "--no-plots", "-q"]
    assert CliRunner().invoke(main, [*args, "--out", str(tmp_path / "every7")]).exit_code == 0
    found = differences(str(runs / "a"), str(tmp_path / "every7"))
    assert "trajectory: 4 and 6 frames" in found
    assert any(line.startswith("trajectory: 3 frames differ; the first is frame 1 (step 10): configuration.step: "
                               "1 of 1 differ") for line in found)


@pytest.mark.parametrize("make, message", [
    (lambda root: root / "nowhere", "is not a run folder or a trajectory"),
    (lambda root: root / "empty", "is not a run folder or a trajectory"),
])
def test_errors_are_one_line_and_exit_code_2(runs, tmp_path, make, message):
    (tmp_path / "empty").mkdir()
    result = compare(runs / "a", make(tmp_path))
    assert result.exit_code == 2 and message in result.output and "Traceback" not in result.output


def test_a_corrupt_trajectory_is_refused_in_one_line(runs, tmp_path):
    (tmp_path / "bad.gsd").write_bytes(b"not a gsd file" * 20)
    result = compare(runs / "a", tmp_path / "bad.gsd")
    assert result.exit_code == 2 and "cannot read a trajectory" in result.output and "Traceback" not in result.output
