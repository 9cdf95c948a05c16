import numpy as np
from scipy import stats

from flocking import rng
from flocking.rules import compile as compile_rules


def test_numpy_and_numba_draw_identical_bits():
    draw = compile_rules("cpu").draw  # what the kernels draw
    ids = np.arange(2000, dtype=np.uint64)
    for seed, step, counter in [(0, 0, 0), (7, 123456, rng.NOISE + 1), (2**62, 2**40, rng.SPEED)]:
        u = rng.uniform(seed, step, ids, counter)
        v = np.array([draw(seed, step, int(i), counter) for i in ids[:300]])
        assert np.array_equal(u[:300], v)


def test_pure_function_of_its_keys():
    ids = np.arange(100)
    assert np.array_equal(rng.uniform(3, 5, ids, 1), rng.uniform(3, 5, ids, 1))
    # every key matters
    base = rng.uniform(3, 5, ids, 1)
    for other in (rng.uniform(4, 5, ids, 1), rng.uniform(3, 6, ids, 1), rng.uniform(3, 5, ids + 1, 1),
                  rng.uniform(3, 5, ids, 2)):
        assert not np.any(base == other)


def test_uniform_on_unit_interval():
    u = rng.uniform(11, 3, np.arange(200_000), rng.NOISE)
    assert u.min() >= 0.0 and u.max() < 1.0
    # Kolmogorov-Smirnov at the 1e-4 level: fails by chance once in 10^4 runs (fixed seed here)
    assert stats.kstest(u, "uniform").pvalue > 1e-4


def test_streams_and_neighbouring_keys_are_uncorrelated():
    n = 200_000
    ids = np.arange(n)
    a = rng.uniform(1, 0, ids, rng.NOISE)
    b = rng.uniform(1, 0, ids, rng.NOISE + 1)
    c = rng.uniform(1, 1, ids, rng.NOISE)
    # |r| of independent samples is ~ N(0, 1/n): 5 sigma
    for x, y in ((a, b), (a, c), (a[:-1], a[1:])):
        assert abs(np.corrcoef(x, y)[0, 1]) < 5 / np.sqrt(n)


#: each purpose's block of counters: from its stream id to the next purpose's (16 for the last)
BLOCKS = {"position": rng.POSITION, "heading": rng.HEADING, "speed": rng.SPEED, "noise": rng.NOISE}
#: models that draw every kind of number: speeds per particle, obstacles to redraw
#: positions from, 2D and 3D (a third position axis, a second heading number), both noises
STREAM_MODELS = [dict(dim=dim, n=40, box=6.0, speeds="uniform", noise_type=noise, seed=9,
                      obstacles=[{"centre": [3.0] * dim, "radius": 2.0}])
                 for dim in (2, 3) for noise in ("angular", "vectorial")]


def counters_by_purpose(monkeypatch) -> dict[str, set[int]]:
    """The counters each purpose draws, found by what they change: every counter the
    reference drawing asks for is perturbed alone (``u -> (u + 1/2) mod 1``), and the
    outputs that move name its purpose: a random state's positions, headings or speeds,
    or the headings after one step from a fixed state (the noise)."""
    from flocking import Model, State
    from flocking.backends import get

    original, perturbed, asked = rng.uniform, [None], set()

    def uniform(seed, step, particle, counter):
        asked.add(int(counter))
        u = original(seed, step, particle, counter)
        return (u + 0.5) % 1.0 if counter == perturbed[0] else u

    monkeypatch.setattr(rng, "uniform", uniform)
    reference = get("reference")
    runs = []
    for kw in STREAM_MODELS:
        model = Model(**kw)
        start = State.random(model)

        def draw(model=model, start=start):
            state = State.random(model)
            backend = reference(model, start)
            backend.advance(1)
            return {"position": state.positions, "heading": state.headings, "speed": state.speeds,
                    "noise": backend.state.headings}

        runs.append((draw, draw()))
    purposes: dict[str, set[int]] = {name: set() for name in BLOCKS}
    for counter in sorted(asked):
        perturbed[0] = counter
        moved = {name for draw, base in runs for name, value in draw().items() if not np.array_equal(value, base[name])}
        assert moved, f"counter {counter} is drawn but changes nothing"
        for name in moved:
            purposes[name].add(counter)
    return purposes


def test_stream_ids_are_disjoint(monkeypatch):
    purposes = counters_by_purpose(monkeypatch)
    assert all(purposes.values()) and len(purposes["position"]) == 3  # one counter per axis, up to 3D
    starts = sorted(BLOCKS.values())
    assert len(set(starts)) == 4
    for name, used in purposes.items():
        first = BLOCKS[name]
        end = min([s for s in starts if s > first], default=first + 16)
        # no counter serves two purposes, and each purpose stays within its own block
        assert all(used.isdisjoint(other) for other_name, other in purposes.items() if other_name != name), name
        assert all(first <= c < end for c in used), (name, sorted(used), first, end)
