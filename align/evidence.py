"""The evidence for an audio↔face offset, one function per source, and how it is combined.

Every estimate is expressed as ``offset_s`` relative to the take's own audio placement
(``meta.audio.start_s``): ``offset_s`` > 0 means that in the raw take the face lags the audio by that
many seconds. Sources:

- ``timecode``: the placement itself (frame log, ``.mov`` timecode, recorder clock of a live capture)
  says 0, with a confidence by how the placement was made; it cannot see capture latencies.
- ``sync_event``: serial sync-box events (``meta.extra["sync_events"]``) matched with a clap in the audio
  (and the face when it shows one).
- ``clap``: one clap-like transient found both in the audio and in the blendshapes or reference video.
- ``content``: cross-correlation of the audio's energy envelope with the mouth opening
  (``content_lag_s``), minus the assumed face lead.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from .content import LagEstimate
from .transient import Transient

# How much a placement from each start_source is worth, and how far off it may be (s).
TIMECODE_TRUST = {
    "frame_log_audio": (0.5, 0.1),
    "recorder_clock": (0.5, 0.1),
    "mov_timecode": (0.4, 0.1),
    "frame_log_video": (0.3, 0.15),
    "paired_frame_convention": (0.4, 0.05),
    "paired_time_column": (0.4, 0.05),
}
# Placements of paired data, whose audio was cut to the frames: frame i at audio time i / fps
# (``paired_frame_convention``), or at the time its time column gives (``paired_time_column``).
PAIRED_SOURCES = ("paired_frame_convention", "paired_time_column")
# Paired audio and frames whose lengths differ by more than this (s) were not cut to each other (the
# real pairs differ by 0.03-0.08 s): the pairing then says nothing about where the audio starts (audio
# with a second of silence before the speech, or its first second cut away, differs by about that much).
PAIRED_SLACK_S = 0.5
SYNC_KINDS = ("CLAP", "MARK", "BUTTON", "SYNC", "SLATE")
# Content rests on how a speaker's mouth opening relates to the sound (a face lead and a bias of a few
# ms that differ between speakers), so it never reaches the confidence of a sync-box event (0.85+) and
# a strong clap seen in both streams outranks it.
CONTENT_MAX_CONFIDENCE = 0.8


@dataclass
class Evidence:
    """One source's estimate of ``offset_s`` (s) with its confidence (0..1) and uncertainty (s)."""

    source: str
    offset_s: float
    confidence: float
    uncertainty_s: float
    detail: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["offset_s"] = round(self.offset_s, 6)
        d["confidence"] = round(self.confidence, 4)
        d["uncertainty_s"] = round(self.uncertainty_s, 6)
        return d


def timecode_evidence(start_source: str | None, longer_s: float = 0.0) -> Evidence:
    """What the take's audio placement (``meta.audio.start_source``) is worth as evidence; ``longer_s``
    (how much longer the audio is than the paired frames reach from its start, s) makes a paired
    placement worthless when its size exceeds ``PAIRED_SLACK_S``."""
    source = start_source or "assumed"
    confidence, tolerance = TIMECODE_TRUST.get(source, (0.0, 1.0))
    detail: dict[str, Any] = {"start_source": source}
    if source in PAIRED_SOURCES and abs(longer_s) > PAIRED_SLACK_S:
        confidence = 0.0
        detail["pairing"] = (
            f"the audio is {abs(longer_s):.2f} s {'longer' if longer_s > 0 else 'shorter'} than the frames "
            "it was paired with: not cut to them, so the pairing does not say where the audio starts"
        )
    return Evidence("timecode", 0.0, confidence, tolerance, detail)


def content_confidence(est: LagEstimate, window_agreement: float) -> float:
    """0..1: how clearly the correlation peak stands out (against other lags and in absolute terms),
    how long the signals are, and how well separate windows of the take agree; at most
    ``CONTENT_MAX_CONFIDENCE``."""
    if est.at_edge or not np.isfinite(est.peak) or est.peak <= 0:
        return 0.0
    runner = est.runner_up if np.isfinite(est.runner_up) else 0.0
    sharp = float(np.clip((est.peak - max(runner, 0.0)) / 0.3, 0.0, 1.0))
    strength = float(np.clip(est.peak / 0.3, 0.0, 1.0))
    length = float(np.clip(est.seconds / 10.0, 0.0, 1.0))
    agreement = float(np.clip(window_agreement, 0.0, 1.0))
    return CONTENT_MAX_CONFIDENCE * sharp * strength * length * agreement


def content_evidence(
    est: LagEstimate, face_lead_s: float, agreement: float, spread_s: float, fps: float
) -> Evidence:
    """Content evidence: ``offset_s = content_lag_s + face_lead_s`` (a face that leads the sound by
    ``face_lead_s`` shows up ``face_lead_s`` earlier than the clock offset alone would put it)."""
    conf = content_confidence(est, agreement)
    return Evidence(
        "content",
        est.lag_s + face_lead_s,
        conf,
        max(spread_s, 0.25 / fps),
        {
            "content_lag_s": round(est.lag_s, 6),
            "face_lead_s": face_lead_s,
            "peak_correlation": round(est.peak, 4),
            "runner_up_correlation": round(est.runner_up, 4) if np.isfinite(est.runner_up) else None,
            "window_agreement": round(agreement, 4),
            "seconds": round(est.seconds, 3),
            "at_search_edge": est.at_edge,
        },
    )


def _nearest(items: list[Transient], t: float, window: float) -> list[Transient]:
    return [x for x in items if abs(x.time_s - t) <= window]


def clap_evidence(
    audio: list[Transient], face: list[Transient], kind: str, window_s: float
) -> Evidence | None:
    """A clap heard in the audio and seen in the face (``kind`` = blendshapes or video): the loudest
    audio clap with exactly one face transient within ``window_s`` (s) of it."""
    if not audio:
        return None
    a = max(audio, key=lambda c: c.strength)  # the loudest clap; speech bursts rarely come close
    near = _nearest(face, a.time_s, window_s)
    if len(near) != 1:
        return None
    f = near[0]
    conf = float(np.clip(min(a.strength, f.strength), 0.0, 1.5) / 1.5) * 0.9
    return Evidence(
        "clap",
        f.time_s - a.time_s,
        max(conf, 0.6),
        0.5 / 60.0,
        {"seen_in": kind, "audio_time_s": round(a.time_s, 6), "face_time_s": round(f.time_s, 6)},
    )


def sync_evidence(
    events: list[dict[str, Any]], audio: list[Transient], face: list[Transient], window_s: float
) -> Evidence | None:
    """Serial sync events (take time ``t``) matched with a clap in the audio: with the face's transient
    the offset is face minus audio; without it, the event time minus the audio clap time (the face is
    on the recorder's clock, the audio is checked against it)."""
    estimates = []
    for ev in events:
        if str(ev.get("kind", "")).upper() not in SYNC_KINDS or not isinstance(ev.get("t"), (int, float)):
            continue
        t = float(ev["t"])
        near_a = _nearest(audio, t, window_s)
        if len(near_a) != 1:
            continue
        near_f = _nearest(face, t, window_s)
        if len(near_f) == 1:
            estimates.append(near_f[0].time_s - near_a[0].time_s)
        else:
            estimates.append(t - near_a[0].time_s)
    if not estimates:
        return None
    spread = float(np.std(estimates)) if len(estimates) > 1 else 0.5 / 60.0
    return Evidence(
        "sync_event",
        float(np.median(estimates)),
        0.95 if len(estimates) > 1 else 0.85,
        max(spread, 0.002),
        {"events_matched": len(estimates), "estimates_s": [round(e, 6) for e in estimates]},
    )


@dataclass
class Decision:
    """The chosen evidence, the others, and the flags raised while choosing."""

    chosen: Evidence
    alternatives: list[Evidence]
    flags: list[str]
    disagreements: list[dict[str, Any]]


def combine(evidence: list[Evidence], min_confidence: float, max_disagreement_s: float) -> Decision:
    """Choose the most confident evidence; flag the take when another confident source disagrees by
    more than ``max_disagreement_s`` plus both sources' uncertainties, or when nothing is confident.

    Evidence below ``min_confidence`` never moves the face: when nothing reaches it, the take keeps
    its audio placement (the ``timecode`` evidence, offset 0) and is flagged ``low_confidence``; a
    correlation peak that barely stands out from noise is a guess, and a guess can be wrong by the
    whole search range."""
    flags: list[str] = []
    usable = [e for e in evidence if e.confidence > 0]
    if not usable:
        chosen = Evidence("none", 0.0, 0.0, float("inf"), {"note": "no evidence: audio placement kept"})
        return Decision(chosen, list(evidence), ["no_evidence"], [])
    chosen = max(usable, key=lambda e: e.confidence)
    if chosen.confidence < min_confidence:
        flags.append("low_confidence")
        placement = next((e for e in evidence if e.source == "timecode"), None)
        if chosen is not placement:
            note = f"no evidence reached confidence {min_confidence:g}: audio placement kept"
            if placement is None:
                kept = Evidence("none", 0.0, 0.0, float("inf"), {"note": note})
            else:
                kept = replace(placement, detail=placement.detail | {"note": note})
            others = [e for e in evidence if e is not placement]
            return Decision(kept, others, flags, [])
    disagreements = []
    for e in usable:
        if e is chosen or e.confidence < min_confidence:
            continue
        gap = abs(e.offset_s - chosen.offset_s)
        allowed = max_disagreement_s + e.uncertainty_s + chosen.uncertainty_s
        if gap > allowed:
            disagreements.append(
                {"source": e.source, "difference_s": round(gap, 6), "allowed_s": round(allowed, 6)}
            )
    if disagreements:
        flags.append("evidence_disagrees")
    return Decision(chosen, [e for e in evidence if e is not chosen], flags, disagreements)
