"""Coarse-grained fields: every backend's sums against the NumPy oracle, exact totals, the
netCDF file a run writes, its rewind, the CLI, the field movie, and the number fluctuations
from fields against those from the particles of the same run."""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest

import flocking
from flocking.backends.cpu import CPUBackend
from flocking.backends.reference import ReferenceBackend
from flocking.checks import ParameterError
from flocking.fields import FieldsWriter, Grid, bin_sums
from flocking.fields import open as open_fields

MODELS = {
    "2d": dict(n=500, box=10.0),
    "3d": dict(dim=3, n=400, box=(6.0, 5.0, 4.0)),
    "nematic-species": dict(n=500, box=10.0, alignment_rule="nematic",
                            species=[{"fraction": 0.3}, {"fraction": 0.7, "name": "B"}]),
    "3d-nematic": dict(dim=3, n=300, box=5.0, alignment_rule="nematic"),
}


def model_of(name: str) -> flocking.Model:
    return flocking.Model(**{"seed": 3, "noise": 0.8, **MODELS[name]})


def check_totals(grid: Grid, sums: np.ndarray, state: flocking.State) -> None:
    """Counts: whole numbers adding up to each species' size; heading sums: the state's
    polarisation per species, to rounding."""
    counts = sums[:, 0]
    assert np.array_equal(counts, np.rint(counts))
    assert counts.sum(axis=1).tolist() == [b - a for a, b in zip(grid.bounds, grid.bounds[1:])]
    for s, (a, b) in enumerate(zip(grid.bounds, grid.bounds[1:])):
        total = state.headings[a:b].sum(axis=0)
        assert np.abs(sums[s, 1 : 1 + grid.dim].sum(axis=1) - total).max() < 1e-12 * max(b - a, 1)


#: 3D with nematic products compiles a kernel of its own (88 s of the default suite's
#: cold start): in the slow stage, beside 3D and nematic alignment apart in the default one
SLOW_FIELDS = {"3d-nematic"}


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW_FIELDS else n
                                  for n in MODELS])
def test_cpu_fields_equal_the_oracle_and_the_particles_totals(name):
    model = model_of(name)
    backend = CPUBackend(model, flocking.State.random(model))
    backend.advance(2)
    grid = Grid.of(model, 1.3)
    sums = backend.fields(grid)
    state = backend.state
    oracle = bin_sums(grid, state)
    assert sums.shape == (len(model.species_counts), grid.width, grid.bins)
    assert np.array_equal(sums[:, 0], oracle[:, 0])  # counts exactly
    assert np.abs(sums - oracle).max() < 1e-12
    check_totals(grid, sums, state)


@pytest.mark.parametrize("name", ["2d", "3d-nematic"])
def test_reference_fields_are_the_oracles(name):
    model = model_of(name)
    backend = ReferenceBackend(model, flocking.State.random(model))
    backend.advance(1)
    grid = Grid.of(model, 2.0)
    assert np.array_equal(backend.fields(grid), bin_sums(grid, backend.state))


def test_bins_follow_the_cell_rule_at_the_edges():
    """x = L (reachable at a wall), beyond it, below 0 and NaN are clamped as cell_index does."""
    model = flocking.Model(n=5, box=4.0)
    grid = Grid.of(model, 1.0)
    positions = np.array([[4.0, 0.0], [9.0, 1.5], [-1.0, 3.999], [np.nan, 2.0], [1.0, 1.0]])
    state = flocking.State(positions, np.tile([1.0, 0.0], (5, 1)), np.ones(5))
    counts = bin_sums(grid, state)[0, 0].reshape(4, 4)  # (y, x)
    assert counts[0, 3] == 1 and counts[1, 3] == 1 and counts[3, 0] == 1 and counts[2, 0] == 1
    assert counts[1, 1] == 1 and counts.sum() == 5
    cpu = flocking.fields.bin_sums  # the compiled pass bins the same positions alike
    from flocking.backends.field_kernels import cpu_fields

    got = cpu_fields(grid, positions.T.copy(), state.headings.T.copy(), np.arange(5, dtype=np.int32))
    assert np.array_equal(got, cpu(grid, state))


def test_grid_sizes_and_refusals():
    model = flocking.Model(n=10, box=(10.0, 7.0))
    grid = Grid.of(model, 3.0)
    assert grid.shape == (3, 2) and grid.widths == (10.0 / 3, 3.5) and grid.frame_shape() == (2, 3)
    assert Grid.of(model, 100.0).shape == (1, 1)
    for bad in (0, -1.0, float("nan"), float("inf"), "x", None, True):
        with pytest.raises(ParameterError, match="^fields: must be a bin size > 0"):
            Grid.of(model, bad)
    with pytest.raises(ParameterError, match="^fields: a bin size of 0.0001 makes"):
        Grid.of(model, 1e-4)


def test_writer_file_holds_every_frame_with_exact_totals(tmp_path):
    model = model_of("nematic-species")
    path = tmp_path / "f.nc"
    sim = flocking.Simulation(model)
    sim.writers.append(FieldsWriter(path, 2.5, every=4))
    sim.writers.append(flocking.ObservablesWriter(tmp_path / "o.csv"))
    sim.run(10)
    ds = open_fields(path)
    assert ds["step"].values.tolist() == [0, 4, 8, 10]
    assert ds["count"].dims == ("time", "y", "x") and ds["count"].shape == (4, 4, 4)
    assert ds["count"].dtype == np.int64
    assert ds["count"].sum(("y", "x")).values.tolist() == [500] * 4
    assert ds["count_A"].sum(("y", "x")).values.tolist() == [150] * 4
    p = np.stack([ds[f"polarisation_{a}"].sum(("y", "x")).values for a in "xy"], axis=1)
    phi = np.loadtxt(tmp_path / "o.csv", delimiter=",", skiprows=1, usecols=1)[[0, 4, 8, 10]]
    assert np.allclose(np.hypot(*p.T) / 500, phi, rtol=0, atol=1e-13)
    assert np.allclose(p[-1], sim.state.headings.sum(axis=0), rtol=0, atol=1e-12)
    nem = ds["nematic_cos"].sum(("y", "x")).values[-1]
    u = sim.state.headings
    assert abs(nem - np.sum(u[:, 0] ** 2 - u[:, 1] ** 2)) < 1e-11
    assert np.allclose(ds["x"].values, [1.25, 3.75, 6.25, 8.75]) and ds.attrs["bin_widths"].tolist() == [2.5, 2.5]
    assert "fields" not in ds.attrs["parameters"] and '"n": 500' in ds.attrs["parameters"]


def test_writer_in_3d_has_z_y_x(tmp_path):
    model = model_of("3d")
    sim = flocking.Simulation(model)
    sim.writers.append(FieldsWriter(tmp_path / "f.nc", 2.0, every=0))
    sim.run(2)
    ds = open_fields(tmp_path / "f.nc")
    assert ds["count"].dims == ("time", "z", "y", "x") and ds["count"].shape == (2, 2, 2, 3)
    assert ds["count"].sum(("z", "y", "x")).values.tolist() == [400, 400]


def test_missing_netcdf_is_one_line_naming_the_extra(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "netCDF4", None)
    with pytest.raises(ParameterError, match=r"^fields: writing fields needs netCDF4 \(the sweep extra: pip "
                                             r"install '\.\[sweep\]'"):
        FieldsWriter(tmp_path / "f.nc", 1.0)
    assert not os.listdir(tmp_path)


def test_rewind_drops_frames_after_the_checkpoint(tmp_path):
    model = model_of("2d")
    path = tmp_path / "f.nc"
    sim = flocking.Simulation(model)
    sim.writers.append(FieldsWriter(path, 2.0, every=2))
    sim.run(7)
    before = open_fields(path)
    flocking.fields.rewind(str(path), 4)
    after = open_fields(path)
    assert after["step"].values.tolist() == [0, 2, 4]
    assert np.array_equal(after["count"].values, before["count"].values[:3])
    assert after.attrs["parameters"] == before.attrs["parameters"]
    flocking.fields.rewind(str(path), 4)  # nothing to drop: the file stays
    assert open_fields(path)["step"].values.tolist() == [0, 2, 4]


def test_cli_run_resume_and_animate(tmp_path):
    from click.testing import CliRunner

    from flocking.cli import main

    out = tmp_path / "run"
    runner = CliRunner()
    args = ["run", "--n", "400", "--box", "10", "--steps", "12", "--every", "6", "--fields", "2.5",
            "--fields-every", "4", "--checkpoint-every", "8", "--quiet", "--no-plots", "--out", str(out)]
    result = runner.invoke(main, args)
    assert result.exit_code == 0, result.output
    assert open_fields(out / "fields.nc")["step"].values.tolist() == [0, 4, 8, 12]
    assert "fields = 2.5" in (out / "config.toml").read_text()
    result = runner.invoke(main, ["run", "--resume", str(out), "--steps", "20", "--quiet"])
    assert result.exit_code == 0, result.output
    assert open_fields(out / "fields.nc")["step"].values.tolist() == [0, 4, 8, 12, 16, 20]
    result = runner.invoke(main, ["animate", str(out), "--from-fields", "-o", str(tmp_path / "f.png")])
    assert result.exit_code == 0, result.output
    from PIL import Image

    assert Image.open(tmp_path / "f.png").size[0] > 100
    result = runner.invoke(main, ["animate", str(out / "fields.nc"), "-o", str(tmp_path / "f.gif"), "--quiet"])
    assert result.exit_code == 0, result.output
    assert Image.open(tmp_path / "f.gif").n_frames == 6


@pytest.mark.parametrize("bad", ["0", "-2"])
def test_cli_refuses_a_bad_bin_before_writing(tmp_path, bad):
    from click.testing import CliRunner

    from flocking.cli import main

    out = tmp_path / "run"
    result = CliRunner().invoke(main, ["run", "--fields", bad, "--n", "50", "--box", "5", "--out", str(out)])
    if bad == "0":  # 0 is the config's "no fields"
        assert result.exit_code == 0 and not (out / "fields.nc").exists()
    else:
        assert result.exit_code == 2 and "fields: must be a bin size > 0" in result.output
        assert not out.exists()


def test_number_fluctuations_from_fields_equal_the_particles(tmp_path):
    """Sub-boxes of whole bins hold the same particles as the particles' sub-boxes: the
    same counts, so the same <n>, dn and alpha within (here: to) their errors."""
    model = flocking.Model(n=4000, box=40.0, noise=0.4, seed=5)
    sim = flocking.Simulation(model)
    sim.writers.append(flocking.GSDWriter(tmp_path / "t.gsd", every=10))
    sim.writers.append(FieldsWriter(tmp_path / "f.nc", 1.0, every=10))
    sim.run(60)
    sizes = [1.0, 2.0, 4.0, 5.0, 8.0]
    a = flocking.analysis.NumberFluctuations(sizes=sizes, start=20).compute(str(tmp_path / "t.gsd"))
    b = flocking.analysis.NumberFluctuations(sizes=sizes, start=20).compute(str(tmp_path / "f.nc"))
    assert a.num_frames == b.num_frames == 5
    assert np.allclose(a.mean, b.mean) and np.allclose(a.std, b.std, rtol=1e-3)
    assert abs(a.alpha - b.alpha) < max(a.alpha_error, b.alpha_error)
    with pytest.raises(ParameterError, match="whole number of bins"):
        flocking.analysis.NumberFluctuations(sizes=[1.5]).compute(str(tmp_path / "f.nc"))
    default = flocking.analysis.NumberFluctuations().compute(open_fields(tmp_path / "f.nc"))
    assert default.sizes.tolist() == [1.0, 2.0, 3.0, 4.0, 5.0] and np.isfinite(default.alpha)
