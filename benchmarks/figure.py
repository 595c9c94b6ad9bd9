"""A measured figure and the reference it is compared with, measured in the same run."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any


@dataclass
class Figure:
    """One benchmark result. ``ratio`` = value / reference_value; ``higher_is_better`` says which way
    the target reads; ``target`` is the ratio the issue asks for (None: reported only)."""

    name: str
    value: float
    unit: str
    reference: str
    reference_value: float
    higher_is_better: bool
    target: float | None = None
    note: str = ""

    @property
    def ratio(self) -> float:
        return self.value / self.reference_value if self.reference_value else float("inf")

    @property
    def passed(self) -> bool | None:
        if self.target is None:
            return None
        return self.ratio >= self.target if self.higher_is_better else self.ratio <= self.target

    def to_json(self) -> dict[str, Any]:
        return asdict(self) | {"ratio": self.ratio, "passed": self.passed}

    def line(self) -> str:
        verdict = {True: "PASS", False: "FAIL", None: "info"}[self.passed]
        goal = ""
        if self.target is not None:
            goal = f" (target {'>=' if self.higher_is_better else '<='} {self.target:g})"
        return (
            f"[{verdict}] {self.name}: {self.value:.4g} {self.unit} vs {self.reference} "
            f"{self.reference_value:.4g} -> ratio {self.ratio:.3f}{goal}"
            + (f"  {self.note}" if self.note else "")
        )


def best_time(fn: Callable[[], Any], repeat: int = 3) -> float:
    """Best wall time in seconds of ``repeat`` calls (the least disturbed run)."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best
