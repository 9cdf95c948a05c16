"""Property-based tests: every accepted configuration runs and agrees with the oracle; every
other input is a clean refusal."""

import math

import numpy as np
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from flocking import Model, ParameterError, State
from flocking.backends.cpu import CPUBackend
from flocking.backends.reference import ReferenceBackend
from flocking.config import RUN_KEYS, RunConfig
from flocking.model import loads_toml


@st.composite
def models(draw):
    dim = draw(st.sampled_from([2, 3]))
    noise_type = draw(st.sampled_from(["angular", "vectorial"]))
    box = tuple(draw(st.lists(st.floats(0.3, 8.0), min_size=dim, max_size=dim)))
    dt = draw(st.floats(0.01, 3.0))
    return Model(
        dim=dim,
        n=draw(st.integers(1, 60)),
        box=box,
        speed=draw(st.floats(1e-3, min(box) / dt)),  # a step longer than the box is refused
        speeds=draw(st.sampled_from(["constant", "uniform"])),
        neighbours=draw(st.sampled_from(["metric", "topological"])),
        radius=draw(st.floats(0.01, 10.0)),
        k=draw(st.integers(1, 12)),
        noise=draw(st.floats(0.0, 2 * math.pi if noise_type == "angular" else 3.0)),
        noise_type=noise_type,
        alignment=draw(st.floats(0.0, 1.0)),
        delay=draw(st.integers(0, 3)),
        dt=dt,
        update=draw(st.sampled_from(["backward", "forward"])),
        seed=draw(st.integers(0, 2**40)),
    )


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(models())
def test_any_valid_model_runs_and_matches_the_reference(model):
    state = State.random(model)
    ref, cpu = ReferenceBackend(model, state), CPUBackend(model, state)
    for _ in range(3):
        phi_ref, phi_cpu = ref.advance(1)[0], cpu.advance(1)[0]
        a, b = ref.state, cpu.state
        box = np.asarray(model.box)
        assert np.all(b.positions >= 0) and np.all(b.positions < box)
        assert np.allclose(np.linalg.norm(b.headings, axis=1), 1.0, atol=1e-13)
        d = a.positions - b.positions
        d -= box * np.round(d / box)
        assert np.abs(d).max() < 1e-9 and np.abs(a.headings - b.headings).max() < 1e-9
        assert abs(phi_ref - phi_cpu) < 1e-9
        if not model.delay:
            cpu = CPUBackend(model, a)


values = st.one_of(
    st.none(), st.booleans(), st.integers(-10**12, 10**12), st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12), st.lists(st.floats(-5, 50), max_size=4), st.lists(st.text(max_size=3), max_size=2),
    st.sampled_from(["metric", "topological", "angular", "vectorial", "uniform", "forward", "cpu", "random",
                     "aligned", "unit", "float32"]),
)
keys = st.one_of(st.sampled_from(RUN_KEYS), st.text(min_size=1, max_size=10))


@settings(max_examples=300, deadline=None)
@given(st.dictionaries(keys, values, max_size=6))
@example({"fields_every": 1.0})  # once written only beside fields, so read back as 0
def test_fuzzed_configs_are_accepted_or_cleanly_refused(data):
    data = {k: v for k, v in data.items() if v is not None}
    try:
        cfg = RunConfig.from_dict(data)
    except ParameterError as err:
        assert "\n" not in str(err) and ": " in str(err)
        return
    assert cfg.model.n >= 1
    assert RunConfig.from_toml(cfg.to_toml()) == cfg
    try:  # the CLI refuses what would not fit in memory before building anything
        cfg.check_memory(available=2**36)
    except ParameterError as err:
        assert "\n" not in str(err) and "need about" in str(err)
        return
    if cfg.model.n <= 3000 and cfg.model.delay <= 1000 and cfg.backend == "cpu":
        sim_state = cfg.initial_state()
        backend = CPUBackend(cfg.model, sim_state)
        phi = backend.advance(2)
        assert np.all((phi >= 0) & (phi <= 1 + 1e-12))


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=80))
def test_fuzzed_toml_text_parses_or_is_refused(text):
    try:
        data = loads_toml(text)
    except ParameterError as err:
        assert str(err).startswith("config: not valid TOML")
        return
    try:
        RunConfig.from_dict(data)
    except ParameterError:
        pass
