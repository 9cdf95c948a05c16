"""MeanSquareDisplacement against exact answers: brute force, random walks, unwrapping limits."""

import math
import time
import warnings

import numpy as np
import pytest

import flocking
import flocking.analysis as fa
from flocking.analysis import msd as msd_module


def brute_force(pos, steps):
    """MSD per step difference over every pair of frames, from unwrapped positions (F, N, d)."""
    sums = {}
    for a in range(len(steps)):
        for b in range(a + 1, len(steps)):
            sums.setdefault(int(steps[b] - steps[a]), []).append(((pos[b] - pos[a]) ** 2).sum(axis=1).mean())
    lags = sorted(sums)
    return np.array(lags), np.array([np.mean(sums[k]) for k in lags]), np.array([len(sums[k]) for k in lags])


@pytest.mark.parametrize("dim", [2, 3])
def test_fft_equals_every_pair_with_uneven_frames(dim):
    rng = np.random.default_rng(dim)
    steps = np.array([0, 2, 3, 7, 8, 9, 15, 16, 20, 40])  # gaps: a grid of 41 points, 10 frames
    pos = np.cumsum(rng.normal(0, 0.4, (len(steps), 60, dim)), axis=0) + 5.0
    frames = [(10.0, p % 10.0) for p in pos]
    msd = fa.MeanSquareDisplacement().compute(frames, steps=steps)
    lags, expected, origins = brute_force(pos, steps)
    np.testing.assert_array_equal(msd.lag_steps, lags)
    np.testing.assert_allclose(msd.msd, expected, rtol=1e-11)
    np.testing.assert_array_equal(msd.origins, origins)
    # the two summation methods agree on the grid, lag by lag
    centred = pos - pos.mean(axis=0)
    fft_sums, fft_pairs = msd_module.grid_sums(centred, steps, 41)
    direct, direct_pairs = msd_module.direct_sums(centred, steps, 41)
    np.testing.assert_allclose(fft_sums, direct, rtol=1e-10, atol=1e-9)
    np.testing.assert_array_equal(fft_pairs, direct_pairs)


def test_fft_keeps_its_precision_far_from_the_origin():
    # ballistic walkers 1000 box sides from where they started: lag 1 is still exact
    steps = np.arange(400)
    pos = np.zeros((400, 50, 2))
    pos[:, :, 0] = 0.3 * steps[:, None] + 1e4
    msd = fa.MeanSquareDisplacement().compute([(10.0, p % 10.0) for p in pos], steps=steps)
    np.testing.assert_allclose(msd.msd, (0.3 * msd.lag_steps) ** 2, rtol=1e-9)


def persistent_walk_msd(n, v, eta):
    c = math.sin(eta / 2) / (eta / 2)
    m = np.arange(1, n)
    return v * v * (n + 2 * np.sum((n - m) * c**m))


def test_persistent_random_walk_msd():
    rng = np.random.default_rng(2)
    n, steps, v, eta, box = 3000, 60, 0.7, 1.5, 12.0
    theta = rng.uniform(0, 2 * np.pi, n)
    pos = rng.uniform(0, box, (n, 2))
    frames = []
    for t in range(steps + 1):
        u = np.c_[np.cos(theta), np.sin(theta)]
        frames.append((box, pos.copy(), u))
        theta = theta + eta * rng.uniform(-0.5, 0.5, n)
        pos = (pos + v * np.c_[np.cos(theta), np.sin(theta)]) % box  # backward update
    msd = fa.MeanSquareDisplacement(dt=0.5).compute(frames, steps=np.arange(steps + 1))
    exact = np.array([persistent_walk_msd(k, v, eta) for k in msd.lag_steps])
    np.testing.assert_allclose(msd.msd, exact, rtol=0.05)
    assert msd.lag_steps.tolist() == list(range(1, steps + 1))
    np.testing.assert_array_equal(msd.lag_times, 0.5 * msd.lag_steps)
    assert msd.origins[0] == steps and msd.dt_used == 0.5


def test_msd_of_the_engine_without_neighbours(tmp_path):
    # a radius far below the spacing: every particle is a persistent random walker
    model = flocking.Model(n=2000, box=40.0, radius=1e-4, noise=1.0, speed=0.5, dt=0.5, seed=3)
    sim = flocking.Simulation(model)
    path = tmp_path / "t.gsd"
    sim.writers.append(flocking.GSDWriter(path, every=2))
    sim.run(60)
    with flocking.open(path) as traj:
        msd = fa.MeanSquareDisplacement(max_lag=40).compute(traj)
    exact = np.array([persistent_walk_msd(k, 0.25, 1.0) for k in msd.lag_steps])  # v dt = 0.25 per step
    np.testing.assert_allclose(msd.msd, exact, rtol=0.08)
    assert msd.lag_steps.max() == 40 and msd.dt_used == 0.5
    np.testing.assert_array_equal(msd.lag_times, msd.lag_steps * 0.5)


def test_frames_too_far_apart_for_the_run_are_refused(tmp_path):
    # v0 dt = 0.5 in a box of 16: a frame every 16 steps could move a particle by 8 = L/2
    model = flocking.Model(n=100, box=16.0, speed=0.5, noise=1.0, seed=1)
    for every, refused in ((16, True), (15, False)):
        sim = flocking.Simulation(model)
        path = tmp_path / f"every{every}.gsd"
        sim.writers.append(flocking.GSDWriter(path, every=every))
        sim.run(every * 4)
        if refused:
            with pytest.raises(flocking.ParameterError, match=r"^system: frames 16 steps apart .* half the box "
                                                              r"side 16.*flocking run --every 15\)$"):
                fa.MeanSquareDisplacement().compute(path)
        else:
            with warnings.catch_warnings():
                warnings.simplefilter("error")
                assert fa.MeanSquareDisplacement().compute(path).lag_steps.tolist() == [15, 30, 45, 60]


def test_foreign_frames_far_apart_raise_a_warning():
    # the tester's walkers: 25 per frame in a box of 16 (truth: 625 lag^2; unwrapped: 49 lag^2)
    steps = np.arange(60)
    frames = [(16.0, np.c_[np.full(10, (25.0 * t) % 16), np.zeros(10)]) for t in steps]
    with pytest.warns(RuntimeWarning, match=r"move up to 7 between frames, more than a quarter of the box side 16"):
        msd = fa.MeanSquareDisplacement().compute(frames, steps=steps)
    np.testing.assert_array_equal(msd.max_frame_displacement, [7.0, 0.0])
    # at 3 per frame the same walkers are unwrapped exactly and nothing is said
    frames = [(16.0, np.c_[np.full(10, (3.0 * t) % 16), np.zeros(10)]) for t in steps]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        msd = fa.MeanSquareDisplacement().compute(frames, steps=steps)
    np.testing.assert_allclose(msd.msd, 9.0 * msd.lag_steps**2, rtol=1e-12)


def test_many_frames_are_fast():
    # 1001 frames x 2000 particles took 105 s with a Python loop over pairs of frames
    rng = np.random.default_rng(5)
    pos = np.cumsum(rng.normal(0, 0.3, (1001, 2000, 2)), axis=0)
    frames = fa.snapshots.Frames([fa.snapshots.Snapshot(t, [100.0, 100.0], p) for t, p in enumerate(pos)],
                              lambda f: f, np.arange(1001))
    fa.MeanSquareDisplacement().compute(frames[:3])  # compile
    t0 = time.perf_counter()
    msd = fa.MeanSquareDisplacement(max_lag=500).compute(frames)
    assert time.perf_counter() - t0 < 20
    assert msd.lag_steps[-1] == 500 and msd.origins[0] == 1000
    # Gaussian steps of variance 0.09 per axis: MSD = 0.18 lag. |dr|^2 / MSD is chi^2_2 / 2
    # (relative variance 1); origins lag apart are independent: relative error sqrt(lag / (N F))
    lag = msd.lag_steps[:10]
    np.testing.assert_allclose(msd.msd[:10], 0.18 * lag, rtol=5 * np.sqrt(10 / (2000 * 990)))


def test_msd_input_errors():
    pts = np.zeros((5, 2))
    with pytest.raises(flocking.ParameterError, match="at least two frames"):
        fa.MeanSquareDisplacement().compute((5.0, pts))
    with pytest.raises(flocking.ParameterError, match="^steps:"):
        fa.MeanSquareDisplacement().compute([(5.0, pts), (5.0, pts)], steps=[3, 1])
    with pytest.raises(flocking.ParameterError, match="frame steps must increase"):
        fa.MeanSquareDisplacement().compute([(5.0, pts), (5.0, pts)])
    with pytest.raises(flocking.ParameterError, match="same particles"):
        fa.MeanSquareDisplacement().compute([(5.0, pts), (5.0, pts[:3])], steps=[0, 1])
    for bad in ({"max_lag": 0}, {"max_lag": 2.5}, {"dt": 0}, {"dt": -1.0}):
        with pytest.raises(flocking.ParameterError):
            fa.MeanSquareDisplacement(**bad)
