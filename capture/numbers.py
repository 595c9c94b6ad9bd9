"""Type checks of numbers read from JSON files, shared by every stage (capture → align → dataset → train)."""

from __future__ import annotations

from typing import Any


def is_count(value: Any) -> bool:
    """Whether ``value`` is a non-negative integer (``True`` and ``False`` are not)."""
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0
