"""What the align stage can be told: frame rate, face lead, VAD, gap and evidence thresholds."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from capture import InputError

VAD_METHODS = ("silero", "webrtc", "none")
FRAME_CLOCKS = ("auto", "timecode", "index")


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
        if self.fps is not None and not (1.0 <= self.fps <= 1000.0):
            raise InputError(f"--fps must be between 1 and 1000, not {self.fps:g}")
        if self.frame_clock not in FRAME_CLOCKS:
            raise InputError(
                f"--frame-clock must be one of {', '.join(FRAME_CLOCKS)}, not {self.frame_clock!r}"
            )
        if self.vad not in VAD_METHODS:
            raise InputError(f"--vad must be one of {', '.join(VAD_METHODS)}, not {self.vad!r}")
        if not (-500.0 <= self.face_lead_ms <= 500.0):
            raise InputError(f"--face-lead-ms must be within ±500 ms, not {self.face_lead_ms:g}")
        # (field, how the command line names it, its unit in seconds, lowest, highest in that unit)
        for name, option, unit, low, high in (
            ("max_gap_s", "--max-gap-ms", 1e-3, 0.0, 60_000.0),
            ("min_segment_s", "--min-segment-s", 1.0, 0.0, 3600.0),
            ("vad_pad_s", "vad_pad_s", 1.0, 0.0, 10.0),
            ("max_offset_s", "--max-offset-ms", 1e-3, 20.0, 10_000.0),
            ("max_disagreement_s", "--max-disagreement-ms", 1e-3, 0.0, 10_000.0),
            ("min_drift_take_s", "min_drift_take_s", 1.0, 0.0, 86_400.0),
        ):
            value = getattr(self, name) / unit
            if not low <= value <= high:  # also NaN
                raise InputError(f"{option} must be between {low:g} and {high:g}, not {value:g}")
        if self.offset_s is not None and not abs(self.offset_s) <= 3600.0:  # also NaN
            raise InputError(f"--offset-ms must be within ±3600000 ms, not {self.offset_s * 1000:g}")
        if not (0.0 <= self.min_confidence <= 1.0):
            raise InputError("--min-confidence must be between 0 and 1")

    def to_json(self) -> dict[str, Any]:
        # without a given offset, the options read as before it existed: takes aligned then stay unchanged
        d = asdict(self)
        if d["offset_s"] is None:
            del d["offset_s"]
        return d
