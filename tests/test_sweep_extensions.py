"""The extensions in sweep files: scalar ones as grid axes, lists and tables as fixed values,
and the order of each species and the nematic order in the results."""

from __future__ import annotations

import json

import numpy as np
import pytest

xr = pytest.importorskip("xarray")

import flocking  # noqa: E402
from flocking.model import ParameterError  # noqa: E402
from flocking.sweep.results import gather  # noqa: E402
from flocking.sweep.point import RECORD_FORMAT  # noqa: E402
from flocking.sweep.runner import PointStore, execute  # noqa: E402
from flocking.sweep.spec import SweepSpec  # noqa: E402

FIXED = """
[base]
n = 40
box = 8.0
steps = 10
obstacles = [{centre = [4.0, 4.0], radius = 1.0}]
species = [{name = "A", fraction = 0.5}, {name = "B", fraction = 0.5, noise = 1.0}]
coupling = [[1.0, -1.0], [-1.0, 1.0]]
field = [1.0, 0.0]

[grid]
vision = [1.0, 3.0]
chirality = {start = 0.0, stop = 0.2, num = 2}
field_strength = [0.0, 0.2]
alignment_rule = ["polar", "nematic"]
boundary = ["periodic", "wall"]
"""


def test_scalar_extensions_are_axes_and_lists_and_tables_in_base_are_fixed():
    spec = SweepSpec.from_toml(FIXED)
    assert spec.dims == ("vision", "chirality", "field_strength", "alignment_rule", "boundary", "replica")
    assert spec.shape == (2, 2, 2, 2, 2, 1)
    points = spec.points()
    assert len(points) == 32
    for p in points:
        m = p.config.model
        assert (m.vision, m.chirality, m.field_strength, m.alignment_rule) == (
            p.params["vision"], p.params["chirality"], p.params["field_strength"], p.params["alignment_rule"])
        assert m.walls == ((True, True) if p.params["boundary"] == "wall" else (False, False))
        # the lists and tables are the same fixed value at every point
        assert m.obstacles == (flocking.extensions.Obstacle((4.0, 4.0), 1.0),)
        assert m.species_names == ("A", "B") and m.species_counts == (20, 20)
        assert m.coupling == ((1.0, -1.0), (-1.0, 1.0)) and m.field == (1.0, 0.0)
    assert points[-1].params == {"vision": 3.0, "chirality": 0.2, "field_strength": 0.2,
                                 "alignment_rule": "nematic", "boundary": "wall"}


def test_a_list_valued_axis_takes_whole_values():
    spec = SweepSpec.from_dict({"base": {"n": 40, "box": 8.0, "steps": 10, "field_strength": 0.5},
                                "grid": {"field": [[1.0, 0.0], [0.0, 1.0]],
                                         "obstacles": [[], [{"centre": [4.0, 4.0], "radius": 1.0}]]}})
    models = [p.config.model for p in spec.points()]
    assert [m.field for m in models] == [(1.0, 0.0), (1.0, 0.0), (0.0, 1.0), (0.0, 1.0)]
    assert [len(m.obstacles) for m in models] == [0, 1, 0, 1]
    ds = gather(spec, "nowhere")  # not run: every run missing, the coordinates as text
    assert ds["field"].values.tolist() == ["[1.0, 0.0]", "[0.0, 1.0]"]
    assert json.loads(ds["obstacles"].values[1]) == [{"centre": [4.0, 4.0], "radius": 1.0}]


@pytest.mark.parametrize("grid, message", [
    ({"species": [{"fraction": 0.5}, {"fraction": 0.5}]},
     "grid.species: one value is a list of species, so an axis is a list of such lists such as [[{fraction"),
    ({"obstacles": [{"centre": [4.0, 4.0], "radius": 1.0}]},
     "grid.obstacles: one value is a list of obstacles, so an axis is a list of such lists"),
    ({"obstacles": {"centre": [4.0, 4.0], "radius": 1.0}}, "grid.obstacles: one value is a list of obstacles"),
    ({"coupling": [[1.0, -1.0], [-1.0, 1.0]]},
     "grid.coupling: one value is a matrix (a list of rows), so an axis is a list of matrices"),
    ({"field": [1.0, 0.0]}, "grid.field: one value is a direction (a list), so an axis is a list of directions"),
    ({"field": {"start": 0.0, "stop": 1.0, "num": 2}}, "grid.field: one value is a direction"),
    ({"vision": [0.0, 1.0]}, "grid point {vision = 0.0}: vision: must be a half-angle in (0, pi]"),
    ({"alignment_rule": ["polar", "apolar"]}, "grid point {alignment_rule = 'apolar'}: alignment_rule: must be"),
    ({"boundary": ["periodic", "walls"]}, "grid point {boundary = 'walls'}: boundary:"),
    ({"chirality": [0.0, 4.0]}, "grid point {chirality = 4.0}: chirality: must be at most pi / dt"),
])
def test_bad_extension_entries_are_refused_in_one_line(grid, message):
    with pytest.raises(ParameterError) as err:
        SweepSpec.from_dict({"base": {"n": 40, "box": 8.0, "steps": 10}, "grid": grid})
    text = str(err.value)
    assert message in text and "\n" not in text, text


def test_species_and_nematic_order_are_measured_and_gathered(tmp_path):
    """The results hold the time average of each species' polar order and of the nematic
    order over the measured steps, as a run's observables.csv records them, with errors;
    NaN where the model has no such observable."""
    spec = SweepSpec.from_dict({
        "sweep": {"discard": 6, "replicas": 2},
        "base": {"n": 30, "box": 5.0, "steps": 16, "backend": "reference",
                 "species": [{"name": "fast", "fraction": 0.5, "speed": 0.8}, {"name": "slow", "fraction": 0.5}]},
        "grid": {"alignment_rule": ["polar", "nematic"], "noise": [0.3, 3.0]}})
    summary = execute(spec, str(tmp_path), progress=False)
    assert (summary["done"], summary["failed"]) == (8, 0)
    ds = gather(spec, str(tmp_path))
    names = ["polar_order_fast", "polar_order_fast_error", "polar_order_slow", "polar_order_slow_error",
             "nematic_order", "nematic_order_error"]
    assert [v for v in ds.data_vars if v in names] == names
    assert np.isnan(ds["nematic_order"].sel(alignment_rule="polar")).all()
    assert np.isfinite(ds["nematic_order"].sel(alignment_rule="nematic")).all()
    assert np.isfinite(ds["polar_order_slow"]).all() and (ds["polar_order_fast_error"] >= 0).all()
    point = spec.points()[6]  # nematic, noise 3.0, replica 0
    sim = flocking.Simulation(point.config.model, backend="reference")
    sim.writers.append(flocking.ObservablesWriter(tmp_path / "obs.csv"))
    sim.run(16)
    table = np.genfromtxt(tmp_path / "obs.csv", delimiter=",", names=True)
    window = table["step"] > 6
    at = ds.sel(alignment_rule="nematic", noise=3.0, replica=0)
    for name in ("polar_order_fast", "polar_order_slow", "nematic_order"):
        assert float(at[name]) == pytest.approx(table[name][window].mean(), abs=1e-12)
    assert float(at["order"]) == pytest.approx(table["polar_order"][window].mean(), abs=1e-12)


def test_records_without_the_other_observables_run_again_only_where_the_model_has_them(tmp_path):
    spec = SweepSpec.from_dict({"base": {"n": 20, "box": 4.0, "steps": 10},
                                "grid": {"alignment_rule": ["polar", "nematic"]}})
    store = PointStore(str(tmp_path))
    plain, nematic = spec.points()
    for point in (plain, nematic):
        store.save({"id": point.id, "status": "done", "format": 2})
    assert (store.state(plain), store.state(nematic)) == ("done", "outdated")
    store.save({"id": nematic.id, "status": "done", "format": RECORD_FORMAT})
    assert store.state(nematic) == "done"
    store.save({"id": plain.id, "status": "done"})  # format 1: no within-run errors
    assert store.state(plain) == "outdated"
