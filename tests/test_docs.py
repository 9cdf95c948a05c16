"""The documentation's Python: every fenced ``python`` block of the pages runs, in order,
page by page, and the numbers the pages quote from it are the ones it computes.

A block that cannot run here (it needs a GPU, a cluster, a window) says why on the line
before it, ``<!-- not run: REASON -->``, with one of the reasons of :data:`NOT_RUN`. The
files a page's blocks read (a run folder, a trajectory) are made first by :data:`SETUP`,
with the commands the page itself gives for them.
"""

import glob
import json
import os
import re

import matplotlib
import numpy as np
import pytest
from click.testing import CliRunner

from flocking.cli import main

matplotlib.use("Agg")

ROOT = os.path.join(os.path.dirname(__file__), os.pardir)
PAGES = sorted(os.path.relpath(p, ROOT) for p in [*glob.glob(os.path.join(ROOT, "docs", "*.md")),
                                                  os.path.join(ROOT, "examples", "README.md"),
                                                  os.path.join(ROOT, "README.md"),
                                                  os.path.join(ROOT, "ARCHITECTURE.md")])

#: the only reasons a block may give for not running
NOT_RUN = {"needs an NVIDIA GPU", "needs a SLURM cluster and dask-jobqueue", "opens a window",
           "needs the results of the sweep of examples/vicsek1995.toml"}

FENCE = re.compile(r"(?:<!-- not run: (?P<why>[^>]*) -->\n)?```(?P<lang>python|py|pycon)\n(?P<code>.*?)```", re.S)


def blocks(page: str) -> list[tuple[str | None, str]]:
    text = open(os.path.join(ROOT, page), encoding="utf-8").read()
    return [(m["why"], m["code"]) for m in FENCE.finditer(text)]


def flocking(*args: str) -> None:
    result = CliRunner().invoke(main, list(args))
    assert result.exit_code == 0, result.output


def setup_analysis(ns: dict) -> None:
    # the demo run of analysis.md's "Command line", and a run with two species
    flocking("run", "--n", "2000", "--box", "32", "--noise", "0.3", "--steps", "3000", "--every", "20",
             "--out", "demo", "-q")
    flocking("run", "--n", "400", "--box", "14", "--species-b", "0.5", "--steps", "200", "--out", "runs/run-0001",
             "-q")


def setup_sweeps(ns: dict) -> None:
    ns.update(json=json, hashlib=__import__("hashlib"), p={"noise": 2.5, "n": 100}, r=3, S=7)


def setup_visualisation(ns: dict) -> None:
    import matplotlib.pyplot as plt

    # the run the page's repr comment describes
    flocking("run", "--n", "5000", "--box", "50", "--steps", "500", "--every", "10", "--out", "flock", "-q",
             "--no-plots")
    ns.update(my_axes=plt.subplots()[1], x=[0.0, 1.0, 2.0], y=[0.2, 0.5, 0.9])


SETUP = {"docs/analysis.md": setup_analysis, "docs/sweeps.md": setup_sweeps,
         "docs/visualisation.md": setup_visualisation}


def check_analysis(ns: dict) -> None:
    """The numbers analysis.md quotes: the snippet's, and those `flocking analyze demo` prints."""
    fa, traj = ns["fa"], ns["traj"]
    assert f"{fa.PolarOrder(start='auto').compute('demo').mean:.5f}" == "0.99217"
    assert f"{ns['nf'].alpha:.4f} +- {ns['nf'].alpha_error:.4f}" == "0.8903 +- 0.0026"
    assert f"{ns['vc'].correlation_length:.2f}" == "5.99"
    assert round(fa.Clusters().compute(traj).weight_average_size) == 1405
    assert fa.DensityProfile(start=0.75).compute(traj).lattice == (1, 1)
    result = CliRunner().invoke(main, ["analyze", "demo", "--only", "fluctuations,correlation,clusters",
                                       "--out", "demo-analysis"])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    for said in ("alpha 0.8887 ± 0.0022", "first zero of C(r) at r = 6.707", "weight-average size 1621"):
        assert said in text, (said, text)
    page = open(os.path.join(ROOT, "docs", "analysis.md"), encoding="utf-8").read()
    for number in ("0.8903", "5.99", "1405", "0.8887", "6.707", "1621"):
        assert number in page


def check_sweeps(ns: dict) -> None:
    from flocking.sweep import point_seed

    assert ns["seed"] == point_seed(ns["S"], ns["p"], ns["r"]) and 0 <= ns["seed"] < 2**53


def check_visualisation(ns: dict) -> None:
    shown = "Trajectory('flock/trajectory.gsd', frames=51, steps 0..500, n=5000, dim=2, box=[50.0, 50.0])"
    assert repr(ns["traj"]) == shown
    assert os.path.getsize("flock.mp4") > 0 and os.path.getsize("frame.svg") > 0


CHECK = {"docs/analysis.md": check_analysis, "docs/sweeps.md": check_sweeps,
         "docs/visualisation.md": check_visualisation}


def test_the_pages_have_python_and_say_why_a_block_does_not_run():
    found = {page: blocks(page) for page in PAGES}
    assert sum(len(b) for b in found.values()) >= 10
    for page, page_blocks in found.items():
        for why, _ in page_blocks:
            assert why is None or why in NOT_RUN, (page, why)
    # a reason is given only where it holds: the GPU blocks use the cuda backend, and so on
    for why, code in found["docs/gpu.md"]:
        assert why == "needs an NVIDIA GPU" and "cuda" in code


# the species run made for analysis.md's per-species lines is short: its window is not steady
@pytest.mark.filterwarnings("ignore:PolarOrder of species:RuntimeWarning")
@pytest.mark.parametrize("page", [p for p in PAGES if any(why is None for why, _ in blocks(p))])
def test_every_python_block_of_a_page_runs(page, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    ns: dict = {"__name__": "__docs__"}
    SETUP.get(page, lambda ns: None)(ns)
    for why, code in blocks(page):
        if why is None:
            exec(compile(code, f"{page} (fenced block)", "exec"), ns)
    CHECK.get(page, lambda ns: None)(ns)
    import matplotlib.pyplot as plt

    plt.close("all")


def test_a_block_that_fails_fails_the_test(tmp_path, monkeypatch):
    """The runner runs the code it finds: a wrong claim in a block raises."""
    monkeypatch.chdir(tmp_path)
    code = "import numpy as np\nassert np.array_equal(np.zeros(2), np.ones(2))\n"
    (why, found), = [(m["why"], m["code"]) for m in FENCE.finditer(f"```python\n{code}```\n")]
    assert why is None and found == code
    with pytest.raises(AssertionError):
        exec(compile(found, "example", "exec"), {})
    assert np.isfinite(1.0)


def test_the_pages_are_pages_not_logs():
    """No page of docs/ over 500 lines; the two reference pages on speed at most 250; each
    measurement table of those two is headed by its commit, machine and date."""
    lengths = {page: len(open(os.path.join(ROOT, page), encoding="utf-8").read().splitlines()) for page in PAGES
               if page.startswith("docs/")}
    assert max(lengths.values()) <= 500, lengths
    assert lengths["docs/performance.md"] <= 250 and lengths["docs/gpu.md"] <= 250
    for page in ("docs/performance.md", "docs/gpu.md"):
        text = open(os.path.join(ROOT, page), encoding="utf-8").read()
        assert "measured and left" not in text
        headed = re.findall(r"^Commit [0-9a-f]{7}, .+, 20\d\d-\d\d-\d\d", text, flags=re.M)
        assert headed, page
