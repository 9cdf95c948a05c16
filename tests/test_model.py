import math

import pytest

from flocking import Model, ParameterError
from flocking.config import RunConfig
from flocking.model import dumps_toml, loads_toml


@pytest.mark.parametrize("kwargs, message", [
    (dict(dim=4), "dim: must be one of 2, 3"),
    (dict(dim=2.5), "dim: must be a whole number"),
    (dict(n=0), "n: must be a whole number >= 1"),
    (dict(n=-5), "n: must be a whole number >= 1"),
    (dict(density=0.0), "density: must be a finite number > 0"),
    (dict(density=float("nan")), "density: must be a finite number > 0"),
    (dict(box=-1.0), "box: must be a finite number > 0"),
    (dict(box="4,x"), "box: must be a positive number or one per axis"),
    (dict(box=(1.0, 2.0, 3.0)), "box: must be one number or 2 numbers for dim=2"),
    (dict(speed=0.0), "speed: must be a finite number > 0"),
    (dict(speed=float("inf")), "speed: must be a finite number > 0"),
    (dict(speeds="random"), "speeds: must be one of 'constant', 'uniform'"),
    (dict(neighbours="delaunay"), "neighbours: must be one of 'metric', 'topological', 'voronoi' (got 'delaunay')"),
    (dict(radius=0), "radius: must be in (0, 1e+150]"),
    (dict(radius=1e200), "radius: must be in (0, 1e+150]"),
    (dict(box=1e160), "box: must be sides whose product (the volume) is a finite number"),
    (dict(box=1e100), "box: must be small enough for at most 2e+09 particles at density 2"),
    (dict(k=0), "k: must be a whole number >= 1"),
    (dict(noise=-0.1), "noise: must be in [0, 2*pi]"),
    (dict(noise=6.3), "noise: must be in [0, 2*pi]"),
    (dict(noise="loud"), "noise: must be a number"),
    (dict(noise=1.5, noise_scale="unit"), "noise: must be in [0, 1]"),
    (dict(noise=-1.0, noise_type="vectorial"), "noise: must be in [0, 1000] for vectorial noise"),
    (dict(noise=1e308, noise_type="vectorial"), "noise: must be in [0, 1000] for vectorial noise"),
    (dict(speed=6.0, dt=2.0, box=10.0), "speed: must be at most 5 with dt = 2"),
    (dict(n=1, box=1e-200), "box: must be sides whose product (the volume) is a finite number above 0"),
    (dict(noise_type="gaussian"), "noise_type: must be one of 'angular', 'vectorial'"),
    (dict(noise_scale="degrees"), "noise_scale: must be one of 'radians', 'unit'"),
    (dict(alignment=1.5), "alignment: must be in [0, 1]"),
    (dict(alignment=-0.1), "alignment: must be in [0, 1]"),
    (dict(delay=-1), "delay: must be a whole number >= 0"),
    (dict(delay=1.5), "delay: must be a whole number >= 0"),
    (dict(dt=0), "dt: must be a finite number > 0"),
    (dict(update="sideways"), "update: must be one of 'backward', 'forward'"),
    (dict(seed=-1), "seed: must be a whole number >= 0"),
    (dict(seed=True), "seed: must be a whole number >= 0"),
    (dict(n=10, density=1.0, box=3.0), "give at most two of them"),
    (dict(density=1e-6, box=2.0), "density: must be large enough for at least one particle"),
])
def test_invalid_parameters_are_refused_with_the_name(kwargs, message):
    with pytest.raises(ParameterError) as err:
        Model(**kwargs)
    assert message in str(err.value)
    assert "\n" not in str(err.value)


def test_sizes_resolve_from_any_two():
    assert Model(n=100, box=10.0).density == pytest.approx(1.0)
    assert Model(density=2.0, box=(4.0, 5.0)).n == 40
    m = Model(n=1000, density=4.0, dim=3)
    assert m.box == pytest.approx((250 ** (1 / 3),) * 3)
    assert Model().n == 2048 and Model().box == (32.0, 32.0)
    assert Model(box="4,5").box == (4.0, 5.0)
    assert Model(dim=3, box=2.0, density=1.0).n == 8
    # density is rounded to the nearest particle count
    assert Model(density=2.0, box=(1.5, 1.5)).n == round(4.5)


def test_unit_noise_scale_maps_to_radians():
    assert Model(noise=0.25, noise_scale="unit").noise == pytest.approx(math.pi / 2)
    assert Model(noise=0.25, noise_scale="unit", noise_type="vectorial").noise == 0.25
    assert Model(noise=2 * math.pi).noise == 2 * math.pi


def test_dict_and_toml_round_trip_every_parameter():
    m = Model(dim=3, n=123, box=(3.3, 4.1, 5.7), speed=0.1 + 0.2, speeds="uniform",
              neighbours="topological", k=5, noise=1 / 3, noise_type="vectorial", alignment=0.7,
              delay=4, dt=0.1, update="forward", seed=99)
    assert Model.from_dict(m.to_dict()) == m
    assert Model.from_dict(loads_toml(dumps_toml(m.to_dict()))) == m
    cfg = RunConfig(m, steps=17, every=0, init="aligned", backend="reference")
    assert RunConfig.from_toml(cfg.to_toml()) == cfg


def test_unknown_keys_name_the_key_and_suggest():
    with pytest.raises(ParameterError, match=r"^nosie: unknown parameter; did you mean 'noise'\?$"):
        Model.from_dict({"nosie": 1.0})
    with pytest.raises(ParameterError, match=r"^colour: unknown parameter$"):
        RunConfig.from_dict({"colour": "red"})


def test_run_config_errors():
    with pytest.raises(ParameterError, match="steps: must be a whole number >= 0"):
        RunConfig.from_dict({"steps": -1})
    with pytest.raises(ParameterError, match="every: must be a whole number >= 0"):
        RunConfig.from_dict({"every": 1.5})
    with pytest.raises(ParameterError, match="init: must be 'random', 'aligned' or an existing .gsd file"):
        RunConfig.from_dict({"init": "/nonexistent.gsd"})
    with pytest.raises(ParameterError, match="backend: must be one of"):
        RunConfig.from_dict({"backend": "gpu"})
    with pytest.raises(ParameterError, match="not valid TOML"):
        RunConfig.from_toml("noise = = 3")


def test_replace_keeps_size_unless_changed():
    m = Model(n=50, box=5.0, noise=1.0)
    assert m.replace(noise=2.0).n == 50
    assert m.replace(density=4.0).n == 4 * 32 * 32  # new density, default box
    assert m.replace(n=10).box == pytest.approx((math.sqrt(5.0),) * 2)  # n with the default density
