"""Counter-based random numbers shared by every backend.

Every random number of a run is a pure function of ``(seed, step, particle, stream)``:
a chain of splitmix64 finalisers absorbs the four integers, and the top 53 bits of the
result give a double in ``[0, 1)``. Nothing depends on thread scheduling, on the order in
which particles are visited or on the backend, so a run is bitwise reproducible for any
thread count and every backend draws exactly the same numbers.

The functions are written once, in NumPy's integer semantics, and used on every target:
vectorised over arrays by the NumPy reference backend (:func:`uniform`), and compiled by
:func:`flocking.rules.compile` for the CPU and CUDA kernels (:func:`draw`).

All stream identifiers of the package are listed here, so that no two purposes ever share
a random number:

>>> from flocking import rng
>>> u = rng.uniform(seed=1, step=0, particle=[0, 1, 2], counter=rng.NOISE)
>>> u.shape, bool(((0 <= u) & (u < 1)).all())
((3,), True)
>>> from flocking.rules import compile
>>> compile("cpu").draw(1, 0, 2, rng.NOISE) == float(u[2])  # the kernels' numbers
True
"""

import numpy as np

#: Initial positions: counter ``POSITION + axis``.
POSITION = 0
#: Initial headings: counter ``HEADING + j`` for the j-th number of the draw.
HEADING = 16
#: Per-particle speeds (``speeds = "uniform"``).
SPEED = 32
#: Noise of one step: counter ``NOISE + j`` for the j-th number of the draw.
NOISE = 48

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_S11 = np.uint64(11)
_INV53 = 1.0 / 9007199254740992.0  # 2**-53


#: the rules :func:`flocking.rules.compile` builds for the kernels, callees first
RULES = ("absorb", "mix", "draw")
#: the rules numba inlines into their callers (:func:`flocking.rules.compile` says which)
INLINED = ()


def absorb(h, x):
    """One round of splitmix64's finaliser absorbing the uint64 ``x`` into ``h``."""
    z = h + x
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


def mix(seed, step, particle, counter):
    """The four uint64 keys absorbed in turn; the top 53 bits as a double in ``[0, 1)``.
    Scalars or NumPy arrays alike."""
    h = absorb(_GOLDEN, seed)
    h = absorb(h, step)
    h = absorb(h, particle)
    h = absorb(h, counter)
    return (h >> _S11) * _INV53


def draw(seed, step, particle, counter):
    """One uniform double in ``[0, 1)`` from four integer keys: the kernels' form
    (compiled by :func:`flocking.rules.compile`)."""
    return mix(np.uint64(seed), np.uint64(step), np.uint64(particle), np.uint64(counter))


def uniform(seed, step, particle, counter):
    """Uniform doubles in ``[0, 1)``, vectorised over any of the four keys (NumPy)."""
    keys = [np.asarray(x).astype(np.uint64) for x in (seed, step, particle, counter)]
    keys = np.broadcast_arrays(*keys)
    with np.errstate(over="ignore"):
        return np.asarray(mix(*keys), dtype=np.float64)
