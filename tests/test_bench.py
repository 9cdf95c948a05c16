"""The benchmark suite: cases, states, tables and the command's error paths (tiny sizes)."""

import json
import os

import numpy as np
import pytest
from click.testing import CliRunner

from flocking import Model, State
from flocking import throughput as bench
from flocking.cli import main

REFS = os.path.join(os.path.dirname(__file__), os.pardir, "benchmarks")


def test_crowding_is_one_plus_poisson_term_for_a_gas_and_grows_with_clusters():
    model = Model(n=40000, box=100.0, noise=1.0)
    gas = bench.crowding(State.random(model).positions, model.box, 1.0)
    mean = 40000 / 100**2
    assert abs(gas - (1 + 1 / mean)) < 0.05
    lump = np.random.default_rng(1).uniform(0, 10, (40000, 2))
    assert bench.crowding(lump, model.box, 1.0) > 50


def test_clustered_state_tiles_a_small_run():
    model = Model(n=4 * 10000, density=2.0, noise=1.0)  # 2 x 2 tiles of 10^4
    state = bench.clustered_state(model, steps=3)
    assert state.n == model.n and state.positions.min() >= 0
    assert np.all(state.positions < np.asarray(model.box))
    half = model.box[0] / 2
    a = state.positions[:10000]
    b = state.positions[10000:20000]  # the next tile along the last axis
    np.testing.assert_allclose(np.mod(b - a, model.box), [[0.0, half]] * 10000, atol=1e-9)
    np.testing.assert_array_equal(state.headings[:10000], state.headings[10000:20000])


def test_clustered_state_rejects_indivisible_n():
    with pytest.raises(bench.ParameterError, match="n: a clustered state"):
        bench.clustered_state(Model(n=10**5 + 1, density=2.0, noise=1.0), steps=1)


def test_run_case_times_flocking_and_the_kdtree_reference(tmp_path):
    case = bench.Case("2d-metric", "tiny", dict(bench.BASE_2D, n=2000), "random", steps=2, warmup=1,
                      refs=("kdtree",))
    rows = bench.run_case(case, bench.find_refs(REFS), repeats=2, long_steps=2, log=lambda s: None)
    assert [r["implementation"] for r in rows] == ["flocking", "kdtree"]
    for r in rows:
        assert r["particle_steps_per_s"] > 0 and r["n"] == 2000
    assert rows[1]["flocking_speedup"] == pytest.approx(
        rows[0]["particle_steps_per_s"] / rows[1]["particle_steps_per_s"])
    result = {"machine": bench.machine(), "full": False, "rows": rows, "memory_bytes_per_particle": {},
              "summary": bench.summarise(rows)}
    paths = bench.write_results(result, tmp_path)
    assert {p.name for p in paths} == {"results.json", "results.md", "throughput.png"}
    assert json.loads((tmp_path / "results.json").read_text())["rows"][0]["implementation"] == "flocking"
    table = (tmp_path / "results.md").read_text()
    assert "| 2d-metric | tiny | kdtree | " in table and result["machine"]["cpu"] in table


def test_kdtree_reference_agrees_with_flocking_without_noise():
    """Same physics: with eta = 0 one step of the reference equals one flocking step."""
    ref = bench._load_kdtree(bench.find_refs(REFS))
    model = Model(n=500, box=16.0, noise=0.0)
    state = State.random(model)
    sim = ref(state.positions, 16.0, 1.0, 0.5, 0.0, 1.0, headings=state.headings)
    sim.step()
    from flocking.backends.cpu import CPUBackend

    cpu = CPUBackend(model, state)
    cpu.advance(1)
    np.testing.assert_allclose(sim.head, cpu.state.headings, atol=1e-12)


def test_summary_ratios():
    rows = [dict(group="delay", case="tau=0 N=1", implementation="flocking", particle_steps_per_s=2.0, threads=2),
            dict(group="delay", case="tau=10 N=1", implementation="flocking", particle_steps_per_s=1.6, threads=2),
            dict(group="threads", case="a", implementation="flocking", particle_steps_per_s=1.0, threads=1),
            dict(group="threads", case="b", implementation="flocking", particle_steps_per_s=1.9, threads=2)]
    s = bench.summarise(rows)
    assert s["delay 10 cost N=1"] == pytest.approx(1.25) and s["2 threads / 1 thread"] == pytest.approx(1.9)


@pytest.mark.parametrize("args, message", [
    (["--repeats", "0"], "--repeats: must be at least 1"),
    (["--group", "nope"], "--group: must be one of"),
    (["--refs", "/nonexistent-folder"], "--refs: no kdtree_reference.py"),
])
def test_bench_bad_options(args, message, tmp_path):
    result = CliRunner().invoke(main, ["bench", "--out", str(tmp_path / "o"), *args])
    assert result.exit_code == 2
    assert message in result.output
    assert not (tmp_path / "o").exists()
