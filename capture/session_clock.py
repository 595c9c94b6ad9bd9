"""The one clock of a live session: every packet, audio chunk and sync event is stamped with it.

It is the process's monotonic clock (``time.monotonic_ns``, CLOCK_MONOTONIC on Linux), which never
jumps with NTP or daylight saving. Times are kept as integer nanoseconds while recording and given
to takes as float64 seconds since the session's origin.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field


@dataclass
class SessionClock:
    """Monotonic nanoseconds with an origin; ``wall_origin_ns`` dates the origin (UTC epoch ns)."""

    origin_ns: int = field(default_factory=time.monotonic_ns)
    wall_origin_ns: int = field(default_factory=time.time_ns)

    @staticmethod
    def now_ns() -> int:
        """Current monotonic time in ns (same scale as ``origin_ns``)."""
        return time.monotonic_ns()

    def seconds(self, ns: int) -> float:
        """Seconds since the origin of a monotonic time in ns."""
        return (ns - self.origin_ns) / 1e9

    def to_json(self) -> dict[str, int]:
        return {"origin_ns": self.origin_ns, "wall_origin_ns": self.wall_origin_ns}
