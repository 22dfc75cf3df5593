"""Argument validation at the library's boundary, one message format for all.

Every check raises :class:`ValueError` (or :class:`TypeError` for a wrong kind of value) whose
message names the argument, says what was expected and what was given::

    latent_dim: expected an integer >= 1, got 0

as scikit-learn's ``utils/validation.py`` does. Checks return the value converted (``float``,
``int``, ``str``), so a constructor can validate and store in one line.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Collection
from typing import Any, TypeVar

__all__ = ["check_choice", "check_integer", "check_number"]

T = TypeVar("T")


def _bounds(low: float | None, high: float | None, low_open: bool, high_open: bool) -> str:
    if low is not None and high is not None:
        return f"in {'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"
    if low is not None:
        return f"{'>' if low_open else '>='} {low:g}"
    if high is not None:
        return f"{'<' if high_open else '<='} {high:g}"
    return "finite"


def check_number(
    value: Any,
    name: str,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
) -> float:
    """``value`` as a finite float within the bounds.

    Parameters
    ----------
    value : real number
    name : str
        The argument's name, for the message.
    low, high : float, optional
        Bounds (None: unbounded on that side).
    low_open, high_open : bool
        Exclude the bound itself.

    Raises
    ------
    ValueError
        Not a real number, not finite, or out of bounds.

    Examples
    --------
    >>> check_number(0.5, "blend", low=0, high=1)
    0.5
    >>> check_number(0, "scale", low=0, low_open=True)
    Traceback (most recent call last):
    ...
    ValueError: scale: expected a number > 0, got 0
    """
    expected = f"a number {_bounds(low, high, low_open, high_open)}"
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name}: expected {expected}, got {value!r}")
    number = float(value)
    ok = math.isfinite(number)
    if ok and low is not None:
        ok = number > low if low_open else number >= low
    if ok and high is not None:
        ok = number < high if high_open else number <= high
    if not ok:
        raise ValueError(f"{name}: expected {expected}, got {value!r}")
    return number


def check_integer(value: Any, name: str, *, low: int | None = None, high: int | None = None) -> int:
    """``value`` as an int within ``[low, high]`` (a float with an integral value is refused).

    Raises
    ------
    ValueError
        Not an integer, or out of bounds.

    Examples
    --------
    >>> check_integer(3, "k", low=1)
    3
    >>> check_integer(0, "k", low=1)
    Traceback (most recent call last):
    ...
    ValueError: k: expected an integer >= 1, got 0
    """
    expected = f"an integer {_bounds(low, high, False, False)}".replace(" finite", "")
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ValueError(f"{name}: expected {expected}, got {value!r}")
    number = int(value)
    if (low is not None and number < low) or (high is not None and number > high):
        raise ValueError(f"{name}: expected {expected}, got {value!r}")
    return number


def check_choice(value: T, name: str, choices: Collection[T]) -> T:
    """``value`` if it is one of ``choices``.

    Raises
    ------
    ValueError
        Naming the argument and listing the choices.

    Examples
    --------
    >>> check_choice("graph", "selector", ("graph", "brute-force"))
    'graph'
    >>> check_choice("kd", "selector", ("graph", "brute-force"))
    Traceback (most recent call last):
    ...
    ValueError: selector: expected one of 'graph', 'brute-force', got 'kd'
    """
    if value not in choices:
        listed = ", ".join(repr(c) for c in choices)
        raise ValueError(f"{name}: expected one of {listed}, got {value!r}")
    return value
