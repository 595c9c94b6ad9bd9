"""What the align stage can be told: frame rate, face lead, VAD, gap and evidence thresholds."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from capture import InputError

VAD_METHODS = ("silero", "webrtc", "none")
FRAME_CLOCKS = ("auto", "timecode", "index")

# The numeric options' ranges, in the units the command line gives them (s2a-align checks them as it
# parses its arguments, a usage error; ``AlignOptions.validate`` for callers from Python): (option,
# field of AlignOptions, the field's value per unit of the option, lowest, highest). Fields without an
# option of their own are named by the field.
RANGES: tuple[tuple[str, str, float, float, float], ...] = (
    ("--fps", "fps", 1.0, 1.0, 1000.0),
    ("--face-lead-ms", "face_lead_ms", 1.0, -500.0, 500.0),
    ("--max-gap-ms", "max_gap_s", 1e-3, 0.0, 60_000.0),
    ("--max-offset-ms", "max_offset_s", 1e-3, 20.0, 10_000.0),
    ("--offset-ms", "offset_s", 1e-3, -3_600_000.0, 3_600_000.0),
    ("--max-disagreement-ms", "max_disagreement_s", 1e-3, 0.0, 10_000.0),
    ("--min-segment-s", "min_segment_s", 1.0, 0.0, 3600.0),
    ("vad_pad_s", "vad_pad_s", 1.0, 0.0, 10.0),
    ("min_confidence", "min_confidence", 1.0, 0.0, 1.0),
    ("min_drift_take_s", "min_drift_take_s", 1.0, 0.0, 86_400.0),
)


def range_problem(option: str, value: float) -> str | None:
    """What is wrong with ``value`` (in the option's units) for ``option`` of ``RANGES``; None: nothing."""
    low, high = next((lo, hi) for opt, _name, _unit, lo, hi in RANGES if opt == option)
    if low <= value <= high:  # not NaN
        return None
    return f"must be between {low:.10g} and {high:.10g}, not {value:.10g}"


@dataclass(frozen=True)
class AlignOptions:
    """Options of ``align_take``. Times are seconds unless a name says ms.

    ``fps``: output frame rate (None: the take's own rate). ``face_lead_ms``: how far the speaker's face
    is assumed to move ahead of the sound; only used when content is the chosen evidence
    (``offset_s = content_lag_s + face_lead_ms / 1000``). ``vad``: ``silero`` (default), ``webrtc`` or
    ``none`` (keep the whole overlap). ``max_gap_s``: longest run of missing face frames filled by
    interpolation; longer gaps split the take. ``max_offset_s``: search range of the content and
    transient evidence around the timecode placement. ``max_disagreement_s``: two confident sources
    further apart than this (plus their own uncertainties) flag the take. ``frame_clock``: where the
    frames sit on the take clock before the offset is measured: ``timecode`` (the times the take holds,
    from the CSV timecodes or frame log), ``index`` (frame ``i`` at ``i / fps`` after the first frame,
    dropped-frame placeholders counted) or ``auto`` (``index`` when the audio is placed by a paired data
    set's frame convention, ``timecode`` otherwise; see docs/align.md, "Frame clock"). ``offset_s``: an
    offset the user knows (``--offset-ms``; at the first audio sample, as the report's ``offset_s``),
    used instead of the one the evidence would choose (the evidence is still measured and reported, and
    drift is measured around it); None: measured.
    """

    fps: float | None = None
    face_lead_ms: float = 0.0
    vad: str = "silero"
    max_gap_s: float = 0.25
    min_segment_s: float = 1.0
    vad_pad_s: float = 0.1
    max_offset_s: float = 0.5
    max_disagreement_s: float = 0.05
    min_confidence: float = 0.3
    drift: bool = True
    min_drift_take_s: float = 60.0
    use_video: bool = True
    frame_clock: str = "auto"
    offset_s: float | None = None

    def validate(self) -> None:
        if self.frame_clock not in FRAME_CLOCKS:
            raise InputError(
                f"--frame-clock must be one of {', '.join(FRAME_CLOCKS)}, not {self.frame_clock!r}"
            )
        if self.vad not in VAD_METHODS:
            raise InputError(f"--vad must be one of {', '.join(VAD_METHODS)}, not {self.vad!r}")
        for option, name, unit, _low, _high in RANGES:
            value = getattr(self, name)
            if value is None and name not in ("fps", "offset_s"):  # only these two mean "the take's own"
                raise InputError(f"{option} must be a number, not None")
            problem = None if value is None else range_problem(option, value / unit)
            if problem:
                raise InputError(f"{option} {problem}")

    def to_json(self) -> dict[str, Any]:
        # without a given offset, the options read as before it existed: takes aligned then stay unchanged
        d = asdict(self)
        if d["offset_s"] is None:
            del d["offset_s"]
        return d
