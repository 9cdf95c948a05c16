"""Checks of user-given values, shared by every part that takes parameters.

Each check returns the value in its canonical type or raises :class:`ParameterError` with
one line that names the parameter, what is allowed and what was given; the command line
prints that line as it is.

>>> real("speed", 0.5, low=0.0, low_open=True)
0.5
>>> integer("n", 3.0, 1)
3
>>> real("radius", -1.0, low=0.0, low_open=True)
Traceback (most recent call last):
...
flocking.checks.ParameterError: radius: must be a finite number > 0 (got -1.0)
"""

from __future__ import annotations

import difflib
import math
import numbers
from typing import Any


class ParameterError(ValueError):
    """An invalid parameter; the message names the parameter and what is allowed."""


def fail(name: str, allowed: str, value: Any) -> None:
    raise ParameterError(f"{name}: must be {allowed} (got {value!r})")


def real(name: str, value: Any, *, low: float | None = None, high: float | None = None,
          low_open: bool = False, allowed: str | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        fail(name, "a number", value)
    value = float(value)
    ok = math.isfinite(value)
    if ok and low is not None:
        ok = value > low if low_open else value >= low
    if ok and high is not None:
        ok = value <= high
    if not ok:
        if allowed is None:
            if high is None:
                allowed = f"a finite number {'>' if low_open else '>='} {low:g}"
            else:
                allowed = f"in {'(' if low_open else '['}{low:g}, {high:g}]"
        fail(name, allowed, value)
    return value


def integer(name: str, value: Any, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        else:
            fail(name, f"a whole number >= {low}", value)
    if value < low:
        fail(name, f"a whole number >= {low}", value)
    return int(value)


def comma_numbers(name: str, value: Any, allowed: str) -> Any:
    """A string such as ``"4,5"`` as a list of floats (refused naming ``name`` and what is
    ``allowed`` if it is not one); any other value as it is."""
    if not isinstance(value, str):
        return value
    try:
        return [float(x) for x in value.split(",")]
    except ValueError:
        fail(name, allowed, value)


def check_keys(data: dict[str, Any], allowed: tuple[str, ...]) -> None:
    """Refuse unknown keys, naming the key and the closest allowed one."""
    for key in data:
        if key not in allowed:
            close = difflib.get_close_matches(str(key), allowed, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            name = key if str(key).isidentifier() else repr(key)  # keep the message on one line
            raise ParameterError(f"{name}: unknown parameter{hint}")
