"""Long runs: no drift of speeds or unit headings, no memory growth (slow: run with -m slow)."""

import resource

import numpy as np
import pytest

from flocking import Model, Simulation


@pytest.mark.slow
@pytest.mark.parametrize("options", [dict(dim=2, speeds="uniform"), dict(dim=3, delay=3, alignment=0.5)])
def test_a_million_steps_keep_speeds_headings_and_memory(options):
    model = Model(n=32, box=4.0, noise=1.0, seed=1, **options)
    sim = Simulation(model, history=False)
    speeds = sim.state.speeds
    sim.run(10_000)  # warm up: compiled kernels, allocator pools
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    for _ in range(10):
        sim.run(99_000)
        state = sim.state
        assert np.array_equal(state.speeds, speeds)
        assert np.abs(np.linalg.norm(state.headings, axis=1) - 1.0).max() < 1e-13
        assert np.all(state.positions >= 0) and np.all(state.positions < model.box)
    assert sim.step == 1_000_000
    grown_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss
    assert grown_kib < 20_000, f"peak memory grew by {grown_kib} KiB"
