"""Type checks of numbers read from JSON files or handed in by a program, shared by every stage
(capture → align → dataset → train)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .errors import InputError


def is_count(value: Any) -> bool:
    """Whether ``value`` is a non-negative integer (``True`` and ``False`` are not)."""
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def number_array(data: Any, what: str) -> np.ndarray:
    """``data`` as a NumPy array of numbers (integers or floats): an ``InputError`` naming ``what`` for a
    ragged list, and for text ("0.5"), bools or objects, which a conversion would turn into numbers."""
    try:
        x = np.asarray(data)
    except (ValueError, TypeError) as exc:  # a ragged list
        raise InputError(f"{what} is not an array of numbers ({exc})") from None
    if x.dtype.kind not in "iuf":
        raise InputError(f"{what} must be numbers (integers or floats), not {x.dtype}")
    return x


def is_finite_number(v: Any) -> bool:
    """Whether ``v`` is a finite JSON number (an int or float, never a bool; a huge int counts as not)."""
    if not isinstance(v, (int, float)) or isinstance(v, bool):
        return False
    try:
        return math.isfinite(v)
    except OverflowError:  # a whole number beyond float range (JSON allows 1000 digits)
        return False
