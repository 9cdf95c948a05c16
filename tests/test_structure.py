"""The structure factor: the exact sums against a plain direct sum, exact lattices, the
ideal gas within its errors, fields against the particles of the same run, the bin
window's deconvolution, and every refusal."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

import flocking
from flocking.analysis import StructureFactor
from flocking.analysis.structure import modes, particle_sums, window
from flocking.checks import ParameterError
from flocking.fields import FieldsWriter, Grid, bin_sums
from flocking.space import Space


def direct(space: Space, points: np.ndarray, n: np.ndarray) -> np.ndarray:
    """|sum_j exp(-i k.r_j)|^2, one wavevector at a time."""
    k = 2 * np.pi * n / space.lengths
    return np.array([abs(np.exp(-1j * points @ q).sum()) ** 2 for q in k])


@pytest.mark.parametrize("box", [(7.0, 5.0), (4.0, 5.0, 6.0)])
def test_particle_sums_equal_the_direct_sum(box, monkeypatch):
    """Chunks of 3 particles (the chunk rule forced small) or all at once: the direct sum's
    values, to rounding."""
    space = Space(box)
    points = np.random.default_rng(1).uniform(0, 1, (50, len(box))) * space.lengths
    n = modes(space, 4.0)
    expected = direct(space, points, n)
    assert np.allclose(particle_sums(space, points, n), expected, rtol=1e-10, atol=1e-9)
    monkeypatch.setattr("flocking.analysis.structure.CHUNK_VALUES", 3 * 60)
    assert np.allclose(particle_sums(space, points, n), expected, rtol=1e-10, atol=1e-9)


def test_modes_are_one_of_each_pair_within_k_max():
    space = Space((6.0, 9.0, 4.0))
    n = modes(space, 3.0)
    k = 2 * np.pi * n / space.lengths
    assert np.all(np.linalg.norm(k, axis=1) <= 3.0) and not np.any(np.all(n == 0, axis=1))
    assert len({tuple(v) for v in n} & {tuple(-v) for v in n}) == 0
    grid = np.stack(np.meshgrid(*[np.arange(-6, 7)] * 3, indexing="ij"), -1).reshape(-1, 3)
    inside = np.linalg.norm(2 * np.pi * grid / space.lengths, axis=1) <= 3.0
    assert 2 * len(n) == inside.sum() - 1  # every wavevector but 0, as +-k


@pytest.mark.parametrize("dim", [2, 3])
def test_a_lattice_scatters_at_its_reciprocal_vectors_only(dim):
    """a^d particles on a square (cubic) lattice of spacing L/a: S = N at the wavevectors
    whose n are multiples of a, 0 at every other."""
    a, length = 4, 8.0
    points = np.stack(np.meshgrid(*[np.arange(a) * length / a] * dim, indexing="ij"), -1).reshape(-1, dim) + 0.3
    sf = StructureFactor(k_max=2 * np.pi * a / length * 1.5).compute([(length, points)])
    n = np.rint(sf.wavevectors * length / (2 * np.pi)).astype(int)
    bragg = np.all(n % a == 0, axis=1)
    assert bragg.sum() >= dim
    assert np.allclose(sf.s_modes[bragg], a**dim) and np.allclose(sf.s_modes[~bragg], 0, atol=1e-9)


def test_an_ideal_gas_has_s_one_within_its_errors():
    """Each wavevector's S of an ideal gas is exponential with mean 1; the shells' means
    over 10 frames have standard errors the spread measures: within 4 of them, and the
    pooled mean within 4 of its own."""
    rng = np.random.default_rng(7)
    frames = [(40.0, rng.uniform(0, 40, (3000, 2))) for _ in range(10)]
    sf = StructureFactor().compute(frames)
    assert sf.num_frames == 10 and sf.n == 3000 and sf.source == "particles"
    assert np.all(np.abs(sf.s - 1) < 4 * sf.s_error)
    pooled = np.average(sf.s, weights=sf.counts)
    assert abs(pooled - 1) < 4 / np.sqrt(sf.counts.sum() * 10)
    assert sf.k_max == pytest.approx(2 * np.pi * 32 / 40) and np.all(np.diff(sf.k) > 0)
    one = StructureFactor(k_max=2.0).compute(frames[:1])
    assert np.all(np.abs(one.s - 1) < 5 * one.s_error) and "one frame" in one.notes[-1]


def test_fields_at_bin_centres_deconvolve_the_particles_sums_exactly():
    """Particles at their bins' centres: the counts' FFT is the particles' rho_k, so the
    fields' S is 1 + (S_particles - 1) / W exactly."""
    model = flocking.Model(n=600, box=(12.0, 8.0), seed=2)
    grid = Grid.of(model, 1.0)
    rng = np.random.default_rng(3)
    cells = rng.integers(0, 12, 600), rng.integers(0, 8, 600)
    centres = np.stack([cells[0] + 0.5, cells[1] + 0.5], axis=1)
    random = flocking.State.random(model)
    sums = bin_sums(grid, flocking.State(centres, random.headings, random.speeds))

    ds = xr.Dataset({"count": (("time", "y", "x"), sums[0, 0].reshape(1, 8, 12))}, coords={"step": ("time", [0])},
                    attrs={"bin_widths": [1.0, 1.0], "box": [12.0, 8.0]})
    fields = StructureFactor(k_max=2.5).compute(ds)
    particles = StructureFactor(k_max=2.5).compute([(np.array([12.0, 8.0]), centres)])
    assert fields.source == "fields" and np.allclose(fields.wavevectors, particles.wavevectors)
    n = np.rint(fields.wavevectors * np.array([12.0, 8.0]) / (2 * np.pi)).astype(int)
    assert np.allclose(fields.s_modes, 1 + (particles.s_modes - 1) / window(n, (12, 8)))


def test_fields_agree_with_the_particles_of_the_same_run(tmp_path):
    """An ordered flock (giant number fluctuations: S >> 1 at small k) written as particles
    and as fields of bin 1: their shells below half the Nyquist agree within their errors
    (4 combined standard errors; the frames are the same, so the errors are correlated
    and this is conservative)."""
    model = flocking.Model(n=4000, box=40.0, noise=0.4, seed=5)
    sim = flocking.Simulation(model)
    sim.writers.append(flocking.GSDWriter(tmp_path / "t.gsd", every=20))
    sim.writers.append(FieldsWriter(tmp_path / "f.nc", 1.0, every=20))
    sim.run(400)
    b = StructureFactor(start=100).compute(str(tmp_path / "f.nc"))
    a = StructureFactor(k_max=b.k_max, start=100).compute(str(tmp_path / "t.gsd"))
    assert b.source == "fields" and b.k_max == pytest.approx(np.pi / 2) and b.num_frames == a.num_frames == 16
    assert np.allclose(a.wavevectors, b.wavevectors) and np.allclose(a.k, b.k)
    assert b.s[0] > 5  # the largest scales: far from the ideal gas
    assert np.all(np.abs(a.s - b.s) < 4 * np.hypot(a.s_error, b.s_error))
    assert np.all(np.abs(a.s - b.s) < 0.05 * a.s)  # the binning's own error: measured at most 1.2 %


@pytest.mark.parametrize("k_max", [0, -1.0, float("nan"), float("inf"), True, "2"])
def test_a_bad_k_max_is_refused(k_max):
    with pytest.raises(ParameterError, match="k_max: must be a wavenumber > 0"):
        StructureFactor(k_max=k_max)


def test_k_max_below_the_box_and_above_the_grid_are_refused(tmp_path):
    points = np.random.default_rng(0).uniform(0, 20, (100, 2))
    with pytest.raises(ParameterError, match=r"k_max: must be at least 2 pi / L = 0.3142"):
        StructureFactor(k_max=0.3).compute([(20.0, points)])
    model = flocking.Model(n=300, box=10.0, seed=1)
    sim = flocking.Simulation(model)
    sim.writers.append(FieldsWriter(tmp_path / "f.nc", 2.0, every=5))
    sim.run(5)
    with pytest.raises(ParameterError, match=r"k_max: from fields of bin widths \[2.0, 2.0\], must be at most"):
        StructureFactor(k_max=2.0).compute(str(tmp_path / "f.nc"))
    assert StructureFactor(k_max=np.pi / 2).compute(str(tmp_path / "f.nc")).k_max == pytest.approx(np.pi / 2)


def test_frames_of_other_boxes_are_refused_and_walls_noted():
    rng = np.random.default_rng(0)
    with pytest.raises(ParameterError, match="system: every frame must have the same box"):
        StructureFactor().compute([(10.0, rng.uniform(0, 10, (50, 2))), (12.0, rng.uniform(0, 10, (50, 2)))])
    space = Space((10.0, 10.0), walls=(False, True), obstacles=[(5.0, 5.0, 1.0)])
    frame = flocking.analysis.snapshots.Snapshot(0, space, rng.uniform(2, 8, (200, 2)))
    sf = StructureFactor().compute([frame])
    assert any("walls on y" in note for note in sf.notes) and any("1 obstacle" in note for note in sf.notes)


def test_the_plot_and_the_results_before_compute():
    import matplotlib

    matplotlib.use("Agg")
    with pytest.raises(flocking.analysis.NotComputedError):
        _ = StructureFactor().s
    points = np.random.default_rng(0).uniform(0, 20, (400, 2))
    sf = StructureFactor().compute([(20.0, points)] * 2)
    ax = sf.plot(theme="light")
    assert ax.get_xscale() == "log" and "S(k)" in ax.get_ylabel()
    assert sf.to_dict()["quantity"] == "StructureFactor" and len(sf.to_dict()["s"]) == len(sf.k)


def test_analyze_takes_s_and_the_fluctuations_from_fields(tmp_path):
    """--from-fields: both quantities read fields.nc, the same frames as the particles; a
    folder without fields.nc and a bad --k-max are refused in one line, nothing written."""
    import json

    from click.testing import CliRunner

    from flocking.cli import main

    out = tmp_path / "run"
    res = CliRunner().invoke(main, ["run", "--n", "1000", "--box", "20", "--steps", "40", "--every", "10",
                                    "--fields", "1", "--out", str(out), "-q", "--no-plots"])
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(main, ["analyze", str(out), "--only", "fluctuations,structure", "--from-fields",
                                    "--start", "10", "--out", str(tmp_path / "a"), "--no-plots"])
    assert res.exit_code == 0, res.output
    data = json.loads((tmp_path / "a" / "analysis.json").read_text())
    assert data["structure"]["source"] == "fields" and data["structure"]["num_frames"] == 4
    assert data["fluctuations"]["num_frames"] == 4 and "from fields" in res.output
    header = (tmp_path / "a" / "structure_factor.csv").read_text().splitlines()[0]
    assert header == "k,S,S_error,wavevectors"
    bare = tmp_path / "bare"
    assert CliRunner().invoke(main, ["run", "--n", "100", "--steps", "5", "--out", str(bare), "-q",
                                     "--no-plots"]).exit_code == 0
    for args, message in ((["--from-fields"], "--from-fields: "), (["--k-max", "0"], "--k-max: must be a wavenumber")):
        res = CliRunner().invoke(main, ["analyze", str(bare), "--out", str(tmp_path / "b"), *args])
        assert res.exit_code == 2 and message in res.output and "Traceback" not in res.output
        assert not (tmp_path / "b").exists()
