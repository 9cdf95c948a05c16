"""examples/finite_size.py, scaled down: the study runs on the cpu backend, draws its
figure, and a study stopped after one block goes on to exactly the results of one that
never stopped."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scripts import load_script


@pytest.mark.slow
def test_finite_size_study_runs_resumes_and_draws(tmp_path):
    fs = load_script("examples/finite_size.py")

    def argv(name):
        return ["--sizes", "6,8", "--noises", "0.2,0.8", "--replicas", "3", "--steps", "90", "--equilibrate", "30",
                "--block", "30", "--state", str(tmp_path / name), "--out", str(tmp_path / f"{name}.png")]

    whole = fs.main(argv("whole"))
    assert fs.main(argv("stopped"), stop_after=1) is None
    assert json.loads((tmp_path / "stopped" / "L6" / "progress.json").read_text()) == {"done": 30}
    resumed = fs.main(argv("stopped"))
    assert resumed == whole  # bit for bit
    assert json.loads((tmp_path / "whole" / "results.json").read_text()) == whole
    for length, n in (("6", 72), ("8", 128)):
        res = whole[length]
        assert res["n"] == n
        low, high = res["order"]
        assert low > 0.6 and high < 0.5  # ordered at low noise, not at high
        assert all(0 <= g <= 2 / 3 + 1e-12 for g in res["binder"])
        assert all(np.isfinite(res["binder_error"]))
    assert (tmp_path / "whole.png").stat().st_size > 10_000
    again = fs.main(argv("whole"))  # a finished study only redraws
    assert again == whole
