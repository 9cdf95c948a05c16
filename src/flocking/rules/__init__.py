"""The rules of the model, written once and compiled for every target.

The geometry (:mod:`flocking.rules.geometry`), the physics of a step
(:mod:`flocking.rules.physics`) and the random numbers (:func:`flocking.rng.draw`) are
plain scalar Python functions. :func:`compile` builds them for a target from that one
text, each function given a namespace in which its callees are their compiled versions
and the constants of its module (``ZERO``, ``ONE``, ..., and ``REAL``, the conversion)
have the target's float type:

- ``compile("cpu")``: numba ``njit`` functions for the CPU kernels
  (:mod:`flocking.backends.cpu_kernels`) and :mod:`flocking.space`'s NumPy face; the rules
  that take arrays and the update (each module's ``INLINED``) inlined by numba, the others
  by LLVM;
- ``compile("cuda", np.float32)`` (or ``np.float64``): CUDA device functions for
  :mod:`flocking.backends.cuda_kernels`, whose float32 kernels then never promote.

The result is a module object, so numba resolves ``R.wrap(...)`` inside a kernel to the
compiled function (a plain namespace would not be typed). A CPU function that compiles the
rules in and is cached on disk is made with :func:`cached`, whose cache name carries a
digest of the rules' text. The reference backend is the deliberate exception: it
transcribes docs/model.md in NumPy on its own, as the oracle these rules are tested
against.

>>> import numba
>>> R = compile("cpu")
>>> @numba.njit
... def f(x):
...     return R.wrap(x, 4.0)
>>> f(-0.25)
3.75
"""

from __future__ import annotations

import functools
import hashlib
import math
import sys
import types

import numba
import numpy as np

from .. import rng
from . import geometry, neighbours, physics, step

#: the modules of rules, callees first; each lists its rules in ``RULES``, callees first, and
#: those numba inlines (for the CPU) in ``INLINED``
MODULES = (rng, geometry, physics, neighbours, step)


def constants(real) -> dict:
    """The names the rules use for constants, as values of the float type ``real``."""
    return dict(REAL=real, ZERO=real(0.0), ONE=real(1.0), HALF=real(0.5), TWO=real(2.0), FOUR=real(4.0),
                TWO_PI=real(2.0 * math.pi), INF=real(np.inf), TINY=real(1e-12), NEAR_X=real(0.9),
                SUM0=tuple(real(0.0) for _ in step.SUMS))


def rebind(function, namespace: dict, qualname: str | None = None):
    """A copy of the plain function ``function`` whose globals are ``namespace`` (and whose
    qualified name, under which numba caches it, is ``qualname``): how a function is
    compiled with other values of the names it reads (here the float type's constants; the
    kernels' flags in :mod:`flocking.backends.cpu_kernels` and
    :mod:`flocking.backends.cuda_kernels`).

    ``namespace`` gets the registry a first warning would add to it (``__warningregistry__``)
    beforehand: numba's CUDA simulator iterates over a device function's globals at each
    call while the block's other threads run, and a warning in one of them (an overflow of
    the hash's multiplications, of a huge coordinate's square) adding the key stopped the
    run ("dictionary changed size during iteration")."""
    namespace.setdefault("__warningregistry__", {})
    out = types.FunctionType(function.__code__, namespace, function.__name__, function.__defaults__,
                             function.__closure__)
    out.__qualname__ = qualname or function.__qualname__
    out.__module__, out.__doc__ = function.__module__, function.__doc__
    return out


@functools.lru_cache(maxsize=None)
def source_digest(*modules: types.ModuleType) -> str:
    """A digest (12 hex digits) of the text of the rules' modules and of ``modules``.

    numba knows a cached function's kernel is out of date only by the stamp of the file
    that defines it, not by the files it compiles in: after a rule changed, a kernel
    compiled before would still be loaded. A function named with this digest
    (:func:`cached`) is looked up under a new name when any of that text changes, and
    compiled again; the entries of earlier text stay in the cache, never loaded. Read
    once a process: a module's functions share their digest.

    >>> from flocking.backends import cells
    >>> len(source_digest()), source_digest(cells) != source_digest()
    (12, True)
    """
    sha = hashlib.sha256()
    for module in dict.fromkeys((*MODULES, sys.modules[__name__], *modules)):
        with open(module.__file__, "rb") as f:
            sha.update(f.read())
    return sha.hexdigest()[:12]


def cached(*modules: types.ModuleType, **options):
    """``numba.njit(cache=True, **options)`` for a function that compiles in the rules and
    the functions of ``modules`` (besides its own module's): cached under its name and
    :func:`source_digest` of that text, so it is compiled again when any of it changes.

    >>> from flocking.backends import cells
    >>> cells.cell_indices.py_func.__qualname__ == "cell_indices_" + source_digest()
    True
    """
    digest = source_digest(*modules)

    def jit(function):
        return numba.njit(cache=True, **options)(rebind(function, function.__globals__,
                                                        f"{function.__qualname__}_{digest}"))

    return jit


def switch_constants(switches) -> dict[str, bool]:
    """The constants code is compiled with for ``switches``, a named tuple of booleans (a
    kernel's :class:`~flocking.backends.features.Features`): each field's name in capitals.

    >>> import typing
    >>> class On(typing.NamedTuple):
    ...     cone: bool = False
    >>> switch_constants(On(cone=True))
    {'CONE': True}
    """
    return {name.upper(): bool(on) for name, on in switches._asdict().items()}


def switch_bits(switches) -> str:
    """``switches`` as a string of bits, in field order: how a compiled variant is named
    (its module here, its kernels in numba's cache)."""
    return "".join("1" if on else "0" for on in switches)


@functools.lru_cache(maxsize=None)
def compile(target: str = "cpu", real=np.float64, switches=None) -> types.ModuleType:  # noqa: A001 - the verb is the point
    """Every rule compiled for ``target`` (``"cpu"`` or ``"cuda"``) with floats of type
    ``real``, as the attributes of a module ``flocking.rules.<target>``. ``switches``, a
    named tuple of booleans (a kernel's :class:`~flocking.backends.features.Features`),
    binds each of its fields, in capitals, as a constant of the rules (``CONE``,
    ``NEMATIC``, ...: the pair terms compiled in); without it every switch is off.

    >>> import typing
    >>> class On(typing.NamedTuple):
    ...     cone: bool = False
    >>> compile("cpu", switches=On(cone=True)).CONE
    True
    """
    if target == "cpu":
        # The rules that take arrays and the update (each module's INLINED) are inlined by
        # numba: called, they took the step with every extension 1.5 times, with topological
        # neighbours 3 times and in 3D 1.15 times as long. The others, small scalar
        # functions, are compiled on their own and LLVM inlines them: numba's inlining
        # types a callee again at each call site, which made compiling a kernel take 1.5 to
        # 2.5 times as long.
        jits = {False: numba.njit(fastmath=False, error_model="numpy"),
                True: numba.njit(inline="always", fastmath=False, error_model="numpy")}
    elif target == "cuda":
        from numba import cuda

        jits = dict.fromkeys((False, True), cuda.jit(device=True))
    else:
        raise ValueError(f"rules.compile: target must be 'cpu' or 'cuda' (got {target!r})")
    built: dict[str, object] = {}
    bound = constants(real)
    if switches is not None:
        bound.update(switch_constants(switches))
    for module in MODULES:
        namespace = dict(vars(module))
        namespace.update(bound)
        namespace.update(built)
        for name in module.RULES:
            built[name] = namespace[name] = jits[name in module.INLINED](rebind(getattr(module, name), namespace))
    tag = switch_bits(switches) if switches is not None else ""
    out = types.ModuleType(f"{__name__}.{target}_{np.dtype(real).name}{tag and '_' + tag}")
    vars(out).update(built)
    vars(out).update(bound)
    return out
