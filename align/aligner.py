"""``align_take``: one raw take in, one aligned take per usable segment out, with the report.

Steps: audio to 16 kHz mono; evidence for the offset (timecode placement, sync events, claps, content);
drift over long takes; face frames moved onto the audio clock by the chosen offset and drift; speech
found by VAD and leading/trailing silence trimmed; frames resampled onto a uniform grid, short gaps
interpolated (``INTERPOLATED``), long gaps splitting the take into segments.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np

from capture import Audio, FrameStatus, InputError, Take, TakeMeta
from capture.audio_io import SILENT_PEAK
from capture.errors import shown_against
from capture.paired import LENGTH_MISMATCH_S, paired_excess_s
from capture.runs import runs
from capture.timecode import Timecode

from . import content as ct
from .clipping import CLIPPED_AUDIO_SHARE, clipped_share
from .drift import WindowLags, arrival_drift_ppm, fit_drift, window_lags
from .evidence import (
    PAIRED_SOURCES,
    Decision,
    Evidence,
    clap_evidence,
    combine,
    content_confidence,
    content_evidence,
    sync_evidence,
    timecode_evidence,
)
from .grid import (
    INTERPOLATED,
    MOSTLY_INTERPOLATED_SHARE,
    UNCOVERED,
    cover,
    frame_period,
    interpolated_share,
    resample_values,
    usable_frames,
)
from .options import AlignOptions
from .recorded import audio_of
from .resample import TARGET_RATE, to_16k_mono
from .transient import audio_claps, step_transients, video_motion, video_transients
from .vad import speech_level_dbfs, speech_segments, vad_gain

# 2: sonorant-band envelope, 0.5-12 Hz content band, frame clock; 3: claps, flags; 4: DC/rumble high-pass,
# idle and timecode channels left out of the mix, clipping only at loud extremes, VAD on a level-raised
# copy (flag quiet_audio), content peaks outside the search range not trusted; 5: paired data placed by a
# time column on the timecode clock, paired audio not cut to its frames not taken as placed, paired
# duration_mismatch from 1 s; 6: paired audio searched as far as its gap to the frames, --offset-ms;
# 7: content judged after the drift is removed, every offset compared at the first audio sample
ALIGN_VERSION = 7
MIN_TAKE_S = 1.0
# Speech quieter than this (``vad.speech_level_dbfs``; real recordings speak at -12..-22 dBFS) is
# flagged ``quiet_audio``: 25 dB and more below an ordinary level, most of the converter's range unused.
QUIET_SPEECH_DBFS = -45.0
# How far beyond the search range (s) the content correlation is looked at, at least, to tell whether the
# peak found inside is the real one or the flank of a higher peak outside (see ``_content``).
BEYOND_RANGE_S = 0.25


def _check_audio(take: Take, x: np.ndarray) -> float:
    """The peak of ``x`` (16 kHz mono), after refusing audio too short or silent to align to."""
    tid = take.meta.id
    dur = x.size / TARGET_RATE
    if dur < MIN_TAKE_S:
        raise InputError(
            f"take {tid}: audio is {shown_against(dur, MIN_TAKE_S, 3)} s long, shorter than {MIN_TAKE_S:g} s"
        )
    # the largest magnitude without an absolute copy of the audio (230 MB an hour)
    peak = float(np.maximum(x.max(), -x.min())) if x.size else 0.0
    if peak < SILENT_PEAK:
        level = 20 * math.log10(peak) if peak > 0 else float("-inf")
        raise InputError(f"take {tid}: audio track is silent (peak {level:.1f} dBFS); nothing to align to")
    return peak


def _reference_video(take: Take) -> Path | None:
    for s in take.meta.sources:
        if s.role == "reference_video" and Path(s.path).is_file():
            return Path(s.path)
    return None


def _content(
    take: Take,
    x: np.ndarray,
    s0: float,
    usable: np.ndarray,
    period: float,
    placement: Evidence,
    length_gap_s: float,
    opts: AlignOptions,
):
    """Content lag estimate, its evidence, the per-frame mouth signal, a note, and the clock drift (to
    apply, and its report); ``placement`` is the audio placement's evidence (``timecode_evidence``),
    ``length_gap_s`` how much the audio and the tracked face differ in length (s).

    On a take whose clocks drift, the lag moves along the take (120 ms over a minute at 2,000 ppm) and
    one correlation over the whole take smears its peak: the drift is fitted on windows first, and the
    take is judged on the face moved onto the audio's clock rate around its weighted centre (the
    anchor), where the lag is the one at the anchor."""
    no_drift: tuple[float, dict[str, Any]] = (0.0, {"applied": False})
    picks = ct.mouth_channels(take.meta.channels)
    t = take.time
    mouth = ct.mouth_opening(take.values, usable, picks) if picks else np.full(t.size, np.nan)
    ok = usable & np.isfinite(mouth)
    if ok.sum() < 10:
        return None, None, mouth, {"note": "no moving mouth-opening channel"}, no_drift
    n = int(x.size / TARGET_RATE * ct.ANALYSIS_RATE)
    grid = s0 + np.arange(n) / ct.ANALYSIS_RATE
    env = ct.band_pass(ct.energy_envelope(x, TARGET_RATE, s0, grid))

    def correlate(face_t: np.ndarray) -> tuple[np.ndarray, np.ndarray, ct.CrossCorrelation]:
        weight = (cover(face_t, period, grid, opts.max_gap_s) != UNCOVERED).astype(np.float64)
        face = ct.band_pass(np.interp(grid, face_t, mouth[ok]))
        return weight, face, ct.CrossCorrelation(env, face, weight)

    weight, face, correlation = correlate(t[ok])
    est = correlation.peak(opts.max_offset_s)
    if est is None:
        return None, None, mouth, {"note": "too little overlap for content evidence"}, no_drift
    anchor = float(np.average(grid, weights=weight + 1e-12))
    wl = window_lags(env, face, weight, s0, est.lag_s)
    drift, drift_info = no_drift
    if opts.drift and x.size / TARGET_RATE >= opts.min_drift_take_s:
        # drift is measured around the offset the take gets (--offset-ms) when it is given
        around = (
            wl
            if opts.offset_s is None
            else window_lags(env, face, weight, s0, opts.offset_s - opts.face_lead_ms / 1000.0)
        )
        drift, drift_info = _drift(around, s0, x.size / TARGET_RATE, take.meta.fps)
    if drift:
        on_audio_rate = correlate(t[ok] - drift * (t[ok] - anchor))
        steady = on_audio_rate[2].peak(opts.max_offset_s)
        if steady is not None:  # else the whole take's correlation stands, with its own estimate
            (weight, face, correlation), est = on_audio_rate, steady
    # The peak inside the search range is only the offset when no higher peak lies beyond it: look at
    # least BEYOND_RANGE_S further (a peak near the edge may be the flank of a higher one outside). When
    # the audio's placement is no evidence (assumed: a CSV with audio recorded elsewhere), the offset
    # may lie as far off as the audio and face lengths differ: search the runner-up correlation over
    # that far, and judge the peak against the highest correlation at any of those lags (its
    # runner-up), so that a peak barely beating one a second away (speech rhythm repeats) gets the low
    # confidence it deserves. A real placement (frame log, timecode, paired data whose audio was cut to
    # its frames) bounds the offset by itself; paired audio that was not cut to the frames is no
    # placement (``timecode_evidence``: its lengths differ by more than ``PAIRED_SLACK_S``).
    placed = placement.confidence >= opts.min_confidence
    longer = 0.0 if placed else abs(length_gap_s)
    reach = opts.max_offset_s + max(longer, BEYOND_RANGE_S)
    wide = correlation.peak(reach)
    outside = wide is not None and abs(wide.lag_s) > opts.max_offset_s and wide.peak > est.peak
    # A higher correlation at the edge of that search is the flank of a peak further out: followed to
    # its top, so that its lag and confidence are measured (a paired take whose face lags by 0.8 s had
    # its peak cut at 0.75 s, of confidence 0: not credible, and the take kept offset 0 without a flag)
    if outside and wide.at_edge:
        wide = correlation.widened(reach, BEYOND_RANGE_S)[1] or wide
    judged = est
    if wide is not None and not outside and longer > opts.max_offset_s:
        if np.isfinite(wide.runner_up) and not wide.runner_up <= est.runner_up:
            judged = dataclasses.replace(est, runner_up=wide.runner_up)
    if wl.lag_s.size >= 2:
        expected = est.lag_s + drift * (wl.centre_s - anchor)  # each window's lag on the fitted line
        agree = float(np.mean(np.abs(wl.lag_s - expected) <= 1.0 / take.meta.fps))
        spread = float(np.std(wl.lag_s - expected) / math.sqrt(wl.lag_s.size))
    else:
        agree, spread = 1.0, 0.5 / take.meta.fps
    ev = content_evidence(judged, opts.face_lead_ms / 1000.0, agree, spread, take.meta.fps)
    if judged is not est:
        ev.detail["runner_up_searched_s"] = round(opts.max_offset_s + longer, 6)
    if outside:
        ev.confidence = 0.0
        ev.detail["best_lag_outside_range_s"] = round(wide.lag_s, 6)
        ev.detail["outside_peak_correlation"] = round(wide.peak, 4)
        ev.detail["outside_confidence"] = round(content_confidence(wide, 1.0), 4)
        ev.detail["note"] = (
            f"the correlation is higher at {wide.lag_s:+.3f} s, outside the search range "
            f"±{opts.max_offset_s:g} s: the peak inside it is not the offset"
        )
    ev.detail["anchor_s"] = round(anchor, 6)  # with drift, the lag is the one at this take time
    ev.detail["channels"] = [take.meta.channels[c] for c, _ in picks]
    return est, ev, mouth, {}, (drift, drift_info)


def _drift(wl: WindowLags, s0: float, audio_s: float, fps: float) -> tuple[float, dict[str, Any]]:
    """(drift to apply, s/s, and its report) from the content lags of windows along a long take:
    applied when it is clearly there (3 standard errors, and a quarter frame over the take)."""
    fit = fit_drift(wl, s0)
    if fit is None:
        return 0.0, {"applied": False}
    significant = abs(fit.drift) > 3 * fit.drift_se and abs(fit.drift) * audio_s > 0.25 / fps
    return fit.drift if significant else 0.0, {
        "applied": bool(significant),
        "estimate_ppm": round(fit.ppm, 3),
        "standard_error_ppm": round(fit.drift_se * 1e6, 3) if math.isfinite(fit.drift_se) else None,
        "windows": fit.windows,
        "residual_s": round(fit.residual_s, 6),
    }


def _transient_evidence(
    take: Take, x: np.ndarray, s0: float, usable: np.ndarray, mouth: np.ndarray, opts: AlignOptions
) -> list[Evidence]:
    out: list[Evidence] = []
    claps = audio_claps(x, s0)
    face_steps = step_transients(take.time[usable], mouth[usable]) if np.isfinite(mouth).any() else []
    events = take.meta.extra.get("sync_events")
    events = [e for e in events if isinstance(e, dict)] if isinstance(events, list) else []
    if events and claps:
        ev = sync_evidence(events, claps, face_steps, opts.max_offset_s)
        if ev is not None:
            out.append(ev)
    if not claps:
        return out
    ev = clap_evidence(claps, face_steps, "blendshapes", opts.max_offset_s)
    if ev is not None:
        out.append(ev)
    video = _reference_video(take) if opts.use_video else None
    if video is not None:
        motion = video_motion(video)
        # The app records one video frame per ARKit frame: video frame j is the j-th frame with a row.
        frame_t = take.time[take.frame_status != FrameStatus.DROPPED]
        ev = clap_evidence(claps, video_transients(motion, frame_t), "reference_video", opts.max_offset_s)
        if ev is not None:
            ev.source = "video_clap"
            out.append(ev)
    return out


def _suggest_ms(seconds: float) -> int:
    """A --max-offset-ms that covers ``seconds`` with room to spare (whole 100 ms)."""
    return int(math.ceil((abs(seconds) + BEYOND_RANGE_S) * 10.0)) * 100


def _check_range(
    tid: str,
    content_ev: Evidence | None,
    decision: Decision,
    longer_s: float,
    opts: AlignOptions,
    flags: list[str],
    warnings: list[str],
) -> bool:
    """Flags and warnings for an offset that may lie outside the search range ``--max-offset-ms``;
    whether it warned.

    When the content correlation peaks beyond the range (``_content``), the peak inside is not the offset
    (audio with pre-roll matched its speech to the face at a wrong lag inside the range before): the
    take keeps what else is confident, else its placement with ``low_confidence``; a placement that a
    confident content peak outside the range contradicts is flagged ``evidence_disagrees``. Audio and
    face lengths that differ by far more than the range (``longer_s``, audio minus face) are named when
    the offset was not measured."""
    chosen = decision.chosen
    outside = content_ev.detail.get("best_lag_outside_range_s") if content_ev is not None else None
    span = f"±{opts.max_offset_s * 1000:.0f} ms"
    lengths = (
        f"; the audio is {abs(longer_s):.2f} s {'longer' if longer_s > 0 else 'shorter'} than the face"
        if abs(longer_s) > opts.max_offset_s
        else ""
    )
    if outside is not None:
        strength = content_ev.detail.get("outside_confidence", 0.0)
        credible = strength >= opts.min_confidence
        if chosen.confidence < opts.min_confidence:
            if "no_evidence" in flags:  # something was measured: a peak where the offset was not looked for
                flags.remove("no_evidence")
            if "low_confidence" not in flags:
                flags.append("low_confidence")
        elif chosen.source in ("timecode", "none") and credible:
            flags.append("evidence_disagrees")
            decision.disagreements.append(
                {
                    "source": "content",
                    "difference_s": round(abs(outside - chosen.offset_s), 6),
                    "allowed_s": round(opts.max_offset_s, 6),
                    "note": "content peak outside the search range",
                }
            )
        else:
            return False
        wider = f"align again with --max-offset-ms {_suggest_ms(outside)}"
        advice = (
            f"; if the audio really started that far apart from the face, {wider}"
            if credible  # a match this weak is more likely another take's audio than an offset that far
            else f", and that match is weak (confidence {shown_against(strength, opts.min_confidence)}): "
            f"check that the audio is this take's, or {wider}"
        )
        warnings.append(
            f"take {tid}: the speech matches the face best at an offset of {outside:+.3f} s, outside the "
            f"{span} searched{lengths}: the speech could not confirm the offset{advice}"
        )
        return True
    if lengths and chosen.confidence < opts.min_confidence:
        warnings.append(
            f"take {tid}: the offset was not measured{lengths}, more than the {span} searched; if the audio "
            f"started that far apart from the face, align again with --max-offset-ms {_suggest_ms(longer_s)}"
        )
        return True
    return False


def _to_audio_start(evidence: list[Evidence], drift: float, s0: float) -> None:
    """Every offset as the one at the first audio sample (what ``offset_s`` and ``--offset-ms`` mean):
    with drift, an offset measured around a take time (content at its ``anchor_s``, a clap at its
    ``audio_time_s``) differs from it by ``drift`` times the time between; the measured one is kept in
    ``detail["offset_at_anchor_s"]``."""
    if not drift:
        return
    for ev in evidence:
        at = ev.detail.get("anchor_s", ev.detail.get("audio_time_s"))
        if at is not None:
            ev.detail["offset_at_anchor_s"] = ev.offset_s
            ev.offset_s -= drift * (float(at) - s0)


def _name_best_guess(tid: str, decision: Decision, opts: AlignOptions, warnings: list[str]) -> None:
    """A warning for a take whose evidence all fell short of ``--min-confidence``: what the most
    confident of it says (the offset at the first audio sample, as ``--offset-ms`` takes it), and how to
    use that offset when the user can confirm it."""
    guesses = [e for e in decision.alternatives if e.confidence > 0 and e.source != "timecode"]
    if not guesses:
        return
    best = max(guesses, key=lambda e: e.confidence)
    ms = best.offset_s * 1000.0
    warnings.append(
        f"take {tid}: no evidence reached confidence {opts.min_confidence:g}, so the audio stays where it "
        f"was placed; the best, {best.source}, puts the offset at {ms:+.0f} ms (confidence "
        f"{shown_against(best.confidence, opts.min_confidence)}): check the take (s2a-view render), and if "
        f"that offset is right, align it again with --offset-ms {ms:.0f}"
    )


# Audio placements that come with a frame-index convention: frame i belongs to audio i / fps. Paired
# data placed by a time column (``paired_time_column``: a generator's or a webcam's own frame times, which
# may jitter or run at 30.8 fps for "30") keeps those times: the timecode clock.
INDEX_CONVENTIONS = ("paired_frame_convention",)


def frame_clock(take: Take, choice: str) -> tuple[Take, dict[str, Any]]:
    """The take with its frames on the chosen clock, and what was chosen (see ``AlignOptions``).

    ``index`` puts frame ``i`` (dropped-frame placeholders counted, since they stand for frames the
    phone captured but did not write) at ``time[0] + i / fps``. The report gives the rate of the take's
    own times against the nominal rate, in ppm (Live Link Face CSVs: about +1,600, 59.90 rows per
    second of timecode for "60 fps")."""
    meta = take.meta
    n = take.time.size
    source = meta.audio.start_source if meta.audio is not None else None
    clock = choice
    if choice == "auto":
        clock = "index" if source in INDEX_CONVENTIONS else "timecode"
    info: dict[str, Any] = {"clock": clock, "choice": choice}
    if n > 1:
        period = (float(take.time[-1]) - float(take.time[0])) / (n - 1)
        info["timecode_vs_nominal_ppm"] = round((period * meta.fps - 1.0) * 1e6, 1)
    if clock == "index" and n > 1:
        time = float(take.time[0]) + np.arange(n) / meta.fps
        take = dataclasses.replace(take, time=time)
    return take, info


def _timecode_at(meta: TakeMeta, take_time: float) -> str | None:
    if not meta.start_timecode:
        return None
    try:
        tod = Timecode.parse(meta.start_timecode).seconds_of_day + take_time
    except ValueError:
        return None
    return Timecode.from_seconds(tod % 86400.0).format()


# repairs of a live take built without audio (capture/session_takes.py), whose messages say why
LIVE_AUDIO_LEFT_OUT = ("audio_outside_take", "audio_left_out")


def align_with_report(take: Take, options: AlignOptions | None = None) -> tuple[list[Take], dict[str, Any]]:
    """Align ``take``; returns the aligned segment takes and the take's report (see ``align_take``).
    A take read without its audio is aligned to its audio file read block by block when the call is
    made in ``recorded.reading_from_file`` (as ``align_folder`` does)."""
    opts = options or AlignOptions()
    opts.validate()
    meta = take.meta
    tid = meta.id
    audio = audio_of(take)
    if audio is None or meta.audio is None:
        # a live take the session's audio did not reach, or whose span could not be kept, says why
        why = [r["message"] for r in meta.repairs if r.get("kind") in LIVE_AUDIO_LEFT_OUT]
        hint = f" ({why[0]})" if why else " (import it with --audio)"
        raise InputError(f"take {tid} has no audio: align needs the speech{hint}")
    notes: list[dict[str, Any]] = []
    x = to_16k_mono(audio, tid, notes)
    mix_notes = [{k: v for k, v in n.items() if k != "kind"} for n in notes if n["kind"] == "audio_mix"]
    dc_notes = [{k: v for k, v in n.items() if k != "kind"} for n in notes if n["kind"] == "audio_dc"]
    peak = _check_audio(take, x)
    take, clock_info = frame_clock(take, opts.frame_clock)
    s0 = float(meta.audio.start_s)
    audio_dur = x.size / TARGET_RATE
    usable = usable_frames(take.frame_status, take.values)
    if not usable.any():
        raise InputError(f"take {tid}: no tracked frames")
    ft = take.time[usable]
    period = frame_period(ft, meta.fps)
    face_dur = float(ft[-1] - ft[0]) + period
    if face_dur < MIN_TAKE_S:
        raise InputError(
            f"take {tid}: the face is tracked for {shown_against(face_dur, MIN_TAKE_S, 3)} s, shorter than "
            f"{MIN_TAKE_S:g} s"
        )
    overlap = min(s0 + audio_dur, ft[-1] + period) - max(s0, ft[0])
    if overlap < MIN_TAKE_S:
        raise InputError(
            f"take {tid}: audio ({s0:.3f}..{s0 + audio_dur:.3f} s) and face ({ft[0]:.3f}..{ft[-1]:.3f} s) "
            f"overlap by {shown_against(max(overlap, 0), MIN_TAKE_S, 3)} s, less than {MIN_TAKE_S:g} s"
        )
    flags: list[str] = []
    # Channels that cancel are a fault of the recording; idle or timecode channels left out are not.
    warnings = [f"take {tid}: {n['message']}" for n in mix_notes if n["method"] == "louder_channel"]
    longer = audio_dur - face_dur
    # Paired audio was cut to its frames: how much longer it is than they reach, from its start (as the
    # importer's length_mismatch note measures it; a time column may start after the audio does).
    paired = meta.audio.start_source in PAIRED_SOURCES
    excess = paired_excess_s(take) if paired else 0.0
    # Paired audio and frames (``evidence.PAIRED_SOURCES``) whose lengths differ by more than the
    # importer's ``length_mismatch`` bound are flagged. The real pairs differ by 0.03-0.08 s; 30 fps
    # frames imported with --fps 29 or 31, by 3-4 s on a take of two minutes, which the general rule
    # (10 % of the duration) let pass.
    if abs(excess) > LENGTH_MISMATCH_S:
        # A wrong frame rate at import, or audio that was cut differently (the offset may then be off by
        # as much; see the evidence).
        flags.append("duration_mismatch")
        warnings.append(
            f"take {tid}: the audio is {abs(excess):.2f} s "
            f"{'longer' if excess > 0 else 'shorter'} than the frames it was paired with "
            f"({audio_dur:.2f} s against {audio_dur - excess:.2f} s): check the frame rate it was "
            "imported with (--fps for a matrix), and whether the audio was cut to these frames (silence "
            "before the speech, or its start cut away)"
        )
    elif meta.audio.start_source == "recorder_clock":
        # A live take's audio is its span of the session's, cut with a margin on each side on the face's
        # own clock: longer by design; what counts is the face it leaves without audio.
        if face_dur - overlap > max(1.0, 0.1 * face_dur):
            flags.append("duration_mismatch")
            late, early = s0 - ft[0], ft[-1] + period - (s0 + audio_dur)
            where = [
                f"starts {late:.2f} s after its first frame" if late > 0 else "",
                f"ends {early:.2f} s before its last frame ends" if early > 0 else "",
            ]
            warnings.append(
                f"take {tid}: {face_dur - overlap:.2f} s of its {face_dur:.2f} s of face have no audio (the "
                f"session's audio {' and '.join(w for w in where if w)}): only the {max(overlap, 0):.2f} s "
                "with audio are kept; start the audio before the phone streams and stop it after"
            )
    elif not paired and abs(longer) > max(1.0, 0.1 * max(audio_dur, face_dur)):
        flags.append("duration_mismatch")
    clipped = clipped_share(audio)
    if clipped > CLIPPED_AUDIO_SHARE:
        flags.append("clipped_audio")
        warnings.append(
            f"take {tid}: {clipped:.2%} of the audio samples are clipped (held flat at full scale): the "
            "recording was made too loud and its loudest sounds are distorted; record at a lower level"
        )
    speech_db = speech_level_dbfs(x)
    detector_gain = vad_gain(x, speech_db)  # measured once for the report and the detector
    level = {
        "speech_dbfs": round(speech_db, 1) if math.isfinite(speech_db) else None,
        "peak_dbfs": round(20 * math.log10(peak), 1),
        "vad_gain_db": round(20 * math.log10(detector_gain), 1) if opts.vad != "none" else 0.0,
    }
    if speech_db < QUIET_SPEECH_DBFS:
        flags.append("quiet_audio")
        warnings.append(
            f"take {tid}: the audio is very quiet (speech at {speech_db:.1f} dBFS, peak "
            f"{level['peak_dbfs']:.1f} dBFS; ordinary recordings speak at about -25..-12 dBFS): the speech "
            "was found on a raised copy and the audio keeps its level; record at a higher level"
        )

    # Evidence.
    placement = timecode_evidence(meta.audio.start_source, excess)
    # how far off an unconfirmed placement may be: the length difference, or for paired audio how far it
    # overshoots or falls short of its frames (a time column may start a second after the audio does)
    gap = excess if abs(excess) > abs(longer) else longer
    est, content_ev, mouth, content_note, (drift, drift_info) = _content(
        take, x, s0, usable, period, placement, gap, opts
    )
    evidence: list[Evidence] = [placement]
    if content_ev is not None:
        evidence.append(content_ev)
    evidence += _transient_evidence(take, x, s0, usable, mouth, opts)
    _to_audio_start(evidence, drift, s0)  # compared, chosen and reported at one take time
    if opts.offset_s is not None:
        given = Evidence("given", opts.offset_s, 1.0, 0.0, {"note": "given with --offset-ms"})
        decision = combine([given, *evidence], opts.min_confidence, opts.max_disagreement_s)
        # the user's own offset: measured evidence further off is reported (disagreements), not flagged
        decision.flags = [f for f in decision.flags if f != "evidence_disagrees"]
    else:
        decision = combine(evidence, opts.min_confidence, opts.max_disagreement_s)
    flags += decision.flags
    chosen = decision.chosen
    if not _check_range(tid, content_ev, decision, gap, opts, flags, warnings) and "low_confidence" in flags:
        _name_best_guess(tid, decision, opts, warnings)

    arrival_ppm = arrival_drift_ppm(take.time, take.arrival_s)
    if arrival_ppm is not None:
        drift_info["phone_vs_recorder_ppm"] = round(arrival_ppm, 3)
    offset_s = chosen.offset_s  # at the first audio sample (_to_audio_start)

    # Face times on the audio clock (s from the first raw audio sample).
    tau = ft - s0 - (offset_s + drift * (ft - s0))
    values = take.values[usable]

    # Speech and trim.
    speech = speech_segments(x, opts.vad, detector_gain)
    if not speech:
        raise InputError(
            f"take {tid}: no speech found by the {opts.vad} VAD in {audio_dur:.2f} s of audio "
            "(--vad none keeps the take as it is)"
        )
    a0 = max(0.0, speech[0][0] - opts.vad_pad_s, float(tau[0]) - period / 2)
    a1 = min(audio_dur, speech[-1][1] + opts.vad_pad_s, float(tau[-1]) + period / 2)
    fps = float(opts.fps or meta.fps)
    a0 = round(a0 * TARGET_RATE) / TARGET_RATE
    n_all = int(math.floor((a1 - a0) * fps + 1e-9))
    if n_all < 1:
        raise InputError(f"take {tid}: no time where both speech and face are present")
    g = a0 + np.arange(n_all) / fps
    status_all = cover(tau, period, g, opts.max_gap_s)
    min_frames = max(1, int(math.ceil(opts.min_segment_s * fps)))
    covered = runs(status_all != UNCOVERED)
    spans = [(s, e) for s, e in covered if e - s >= min_frames]
    if not spans:
        longest = max((e - s for s, e in covered), default=0) / fps
        heard = sum(b - a for a, b in speech)
        raise InputError(
            f"take {tid}: no stretch of at least {opts.min_segment_s:g} s with both speech and a tracked "
            f"face (the longest: {longest:.2f} s; {heard:.2f} s of speech in {audio_dur:.2f} s of audio): "
            "record whole sentences in a take, or align it with a lower --min-segment-s"
        )
    if len(spans) < len(covered):
        flags.append("short_segments_dropped")

    segments_out: list[Take] = []
    seg_reports = []
    total_interp = 0
    n_seg = len(spans)
    for k, (s, e) in enumerate(spans):
        n = e - s
        s_sample = int(round(g[s] * TARGET_RATE))
        t_local = np.arange(n) / fps
        seg_tau = s_sample / TARGET_RATE + t_local
        seg_values = resample_values(tau, values, seg_tau, 1.0 / period, fps)
        seg_status = status_all[s:e].copy()
        n_samples = int(math.ceil(n * TARGET_RATE / fps - 1e-6))
        samples = x[s_sample : s_sample + n_samples]
        if samples.size < n_samples:
            samples = np.concatenate([samples, np.zeros(n_samples - samples.size, np.float32)])
        seg_id = tid if n_seg == 1 else f"{tid}.seg{k + 1:02d}"
        start_audio = s_sample / TARGET_RATE
        speech_local = [
            [
                round(max(a, start_audio) - start_audio, 4),
                round(min(b, start_audio + n / fps) - start_audio, 4),
            ]
            for a, b in speech
            if b > start_audio and a < start_audio + n / fps
        ]
        interp = int(np.count_nonzero(seg_status == INTERPOLATED))
        total_interp += interp
        seg_reports.append(
            {
                "id": seg_id,
                "frames": n,
                "start_s": round(s0 + start_audio, 6),
                "duration_s": round(n / fps, 6),
                "gaps_interpolated": interp,
                "interpolated_share": interpolated_share(interp, n),
                "speech_segments": speech_local,
            }
        )
        seg_meta = TakeMeta(
            id=seg_id,
            source_kind="aligned",
            fps=fps,
            channels=list(meta.channels),
            slate=meta.slate,
            take_number=meta.take_number,
            subject=meta.subject,
            device=meta.device,
            start_timecode=_timecode_at(meta, s0 + start_audio),
            timecode_rate=meta.timecode_rate,
            sources=list(meta.sources),
            repairs=list(meta.repairs),
            extra={key: meta.extra[key] for key in ("simulation", "take_json") if key in meta.extra},
        )
        seg_take = Take(seg_meta, t_local, seg_values, seg_status, None, take.neutral)
        # the segment's samples are x's own (float32 already): no second copy of the take's audio
        seg_take.attach_audio(Audio(np.asarray(samples, np.float32), TARGET_RATE, "FLOAT"), 0.0, "aligned")
        segments_out.append(seg_take)
    if any(r["interpolated_share"] > MOSTLY_INTERPOLATED_SHARE for r in seg_reports):
        flags.append("mostly_interpolated")

    report: dict[str, Any] = {
        "id": tid,
        "offset_s": round(offset_s, 6),
        "offset_source": chosen.source,
        "offset_confidence": round(chosen.confidence, 4),
        "offset_uncertainty_s": round(chosen.uncertainty_s, 6)
        if math.isfinite(chosen.uncertainty_s)
        else None,
        "content_lag_s": round(est.lag_s, 6) if est is not None else None,
        "face_lead_s": opts.face_lead_ms / 1000.0,
        "alternatives": [e.to_json() for e in decision.alternatives],
        "chosen": chosen.to_json() if math.isfinite(chosen.uncertainty_s) else None,
        "disagreements": decision.disagreements,
        "flags": flags,
        "drift_ppm": round(drift * 1e6, 3),
        "drift": drift_info,
        "frame_clock": clock_info,
        "trim_s": [round(s0 + a0, 6), round(s0 + min(a1, a0 + n_all / fps), 6)],
        "speech_segments_raw": [[round(s0 + a, 4), round(s0 + b, 4)] for a, b in speech],
        "frames": int(sum(t.time.size for t in segments_out)),
        "fps": fps,
        "gaps_interpolated": total_interp,
        "interpolated_share": interpolated_share(total_interp, sum(r["frames"] for r in seg_reports)),
        "clipped_audio": round(clipped, 6),
        "audio_level": level,
        "segments": n_seg,
        "segment_list": seg_reports,
        "audio_s": round(audio_dur, 6),
        "face_s": round(face_dur, 6),
        "audio_start_s": s0,
        "audio_start_source": meta.audio.start_source,
        "subject": meta.subject,
        "options": opts.to_json(),
        "version": ALIGN_VERSION,
    }
    if content_note:
        report["content_note"] = content_note.get("note")
    if mix_notes:
        report["audio_mix"] = mix_notes[0]
    if dc_notes:
        report["audio_dc"] = dc_notes[0]
    if warnings:
        report["warnings"] = warnings
    for k, seg_take in enumerate(segments_out):
        seg = seg_reports[k]
        seg_take.meta.extra["align"] = {key: v for key, v in report.items() if key != "segment_list"} | {
            "segment": k + 1,
            "segment_count": n_seg,
            "segment_start_s": seg["start_s"],
            "speech_segments": seg["speech_segments"],
            "gaps_interpolated": seg["gaps_interpolated"],
            "interpolated_share": seg["interpolated_share"],
            "frames": seg["frames"],
            "parent": {"id": tid, "source_kind": meta.source_kind},
        }
    return segments_out, report


def align_take(take: Take, options: AlignOptions | None = None) -> list[Take]:
    """Align a raw take: audio as 16 kHz mono float32 starting at take time 0, frames on the grid
    ``time[i] = i / fps`` (s) over the same span, one take per segment (``<id>`` or ``<id>.segNN``).

    The report (offset, evidence, drift, trim, gaps) is in each result's ``meta.extra["align"]``.
    Raises ``InputError`` for a take that cannot be aligned (no audio, silent, shorter than 1 s, no
    speech, no overlap of face and audio)."""
    return align_with_report(take, options)[0]


def is_aligned(take: Take) -> bool:
    """True for a take written by the align stage (16 kHz float audio at 0 s, uniform frame grid)."""
    m = take.meta
    if m.source_kind != "aligned" or "align" not in m.extra or m.audio is None:
        return False
    if m.audio.sample_rate != TARGET_RATE or m.audio.start_s != 0.0 or m.audio.channels != 1:
        return False
    n = take.time.size
    return bool(np.allclose(take.time, np.arange(n) / m.fps, atol=1e-9))
