"""A measured figure and the reference it is compared with, measured in the same run."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
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


# Runs a command and writes the command's own peak RSS (kB) to argv[1], its pid to argv[1] + ".pid",
# forwarding SIGINT/SIGTERM. Measuring through this small wrapper matters: Linux carries a process's
# high-water RSS into the children it forks, so getrusage() in a large benchmark process would report
# the benchmark's own memory, not the command's.
_PEAK_WRAPPER = r"""
import resource, signal, subprocess, sys
child = subprocess.Popen(sys.argv[2:])
open(sys.argv[1] + ".pid", "w").write(str(child.pid))
for s in (signal.SIGINT, signal.SIGTERM):
    signal.signal(s, lambda n, _f: child.send_signal(n))
rc = child.wait()
open(sys.argv[1], "w").write(str(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss))
sys.exit(rc)
"""


def peak_measured(cmd: list[str], peak_file: str | Path) -> list[str]:
    """``cmd`` wrapped so that its own peak RSS in kB lands in ``peak_file`` when it exits (and its pid
    in ``peak_file.pid`` once it starts). The wrapper's own ~10 MB is included."""
    return [sys.executable, "-c", _PEAK_WRAPPER, str(peak_file), *cmd]


def read_peak_kb(peak_file: str | Path) -> int:
    return int(Path(peak_file).read_text())
