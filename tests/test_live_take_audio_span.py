"""Each take of a live session gets its own span of the session's audio (plus a margin the aligner can
search in), placed so that every sample stays at its take time. Sessions are real logs: a frames log
written record by record as the recorder writes them (arrival times chosen, so takes can lie minutes
apart), and an audio log written by ``AudioLog``; one session is recorded over real UDP on loopback."""

from __future__ import annotations

import json
import subprocess
import sys
from fractions import Fraction

import numpy as np
import pytest
from live_helpers import record_packets, run_cli

from align.aligner import BEYOND_RANGE_S, align_with_report
from align.content import ANALYSIS_RATE
from align.options import AlignOptions
from align.resample import TARGET_RATE
from align.transient import CLAP_SURROUNDINGS_S
from align.vad import LEVEL_FRAME_S
from capture import ARKIT61, Audio, build_takes, read_take
from capture.audio_capture import CHUNK_S, AudioLog, index_audio_log
from capture.errors import InputError
from capture.livelink import frame_block, header_bytes
from capture.record_log import LogWriter, RecordType, encode_record, json_record
from capture.recorder import AUDIO_LOG, FRAME_PREFIX, FRAMES_LOG
from capture.session_takes import AUDIO_MARGIN_S, AUDIO_SPAN_GRID_S, SessionLog

FPS = 60
PHONE_AHEAD_S = 100.0  # the phone's frame clock runs this far ahead of the session clock
VALUES = np.linspace(-0.5, 1.0, 61).astype(np.float32)


def ramp(first: int, n: int, channels: int) -> np.ndarray:
    """Session audio samples ``first`` .. ``first + n`` that name their own index (16-bit: channel 0 the
    index modulo 30000, channel 1 the index divided by 30000)."""
    k = np.arange(first, first + n)
    return np.stack([k % 30000, k // 30000], axis=1)[:, :channels].astype(np.int16)


def session_index(audio: np.ndarray) -> np.ndarray:
    """The session sample index each sample of a stereo ``ramp`` names."""
    return audio[:, 0].astype(np.int64) + 30000 * audio[:, 1].astype(np.int64)


def write_session(
    folder,
    takes: list[tuple[float, int]],
    audio: tuple[float, float] | None,
    rate: int = 8000,
    gaps=(),
    sound=ramp,
    mouth=None,
):
    """A session folder: per take (session time of its first frame, frames) 60 fps frames arriving on
    time; with ``audio`` (session time of its first sample, seconds) a stereo ``sound`` (by default the
    ``ramp``) logged in 0.1 s chunks, leaving out the chunks of the sample ranges in ``gaps``. ``mouth``:
    the jawOpen of each frame from its session time (else ``VALUES``)."""
    folder.mkdir(parents=True)
    log = LogWriter(folder / FRAMES_LOG, fsync=False)
    log.put(json_record(RecordType.SESSION, {"session": folder.stem, "clock": {"origin_ns": 0}}))
    stream = {"stream": 0, "device": "PHONE", "subject": "Ann", "rate_numerator": FPS, "rate_denominator": 1}
    log.put(json_record(RecordType.STREAM, stream))
    for start_s, frames in takes:
        first = round((start_s + PHONE_AHEAD_S) * FPS)
        for i in range(frames):
            arrival_ns = round((first + i) / FPS * 1e9 - PHONE_AHEAD_S * 1e9)
            prefix = FRAME_PREFIX.pack(RecordType.FRAME, 0, arrival_ns)
            values = VALUES.copy()
            if mouth is not None:
                values[ARKIT61.index("jawOpen")] = mouth(arrival_ns / 1e9)
            log.put(encode_record(prefix + frame_block(first + i, 0.0, FPS, 1, values)))
    log.close()
    if audio is None:
        return
    first_s, seconds = audio
    sound_log = AudioLog(folder / AUDIO_LOG, fsync=False)
    sound_log.start(rate, 2, "PCM_16", "test")
    chunk = int(rate * CHUNK_S)
    for first in range(0, int(rate * seconds), chunk):
        if not any(lo <= first < hi for lo, hi in gaps):
            sound_log.add_chunk(first, round((first_s + first / rate) * 1e9), sound(first, chunk, 2))
    sound_log.close()


def takes_of(session, out) -> list[tuple[dict, object]]:
    return [(s, read_take(s["path"])) for s in build_takes(session, out)]


def test_the_margin_covers_the_aligners_default_search():
    # align searches the offset within --max-offset-ms (default 500 ms), looks 0.25 s beyond it, and judges
    # a clap found there against the 0.5 s of sound around it; each take's audio reaches a frame further
    assert AUDIO_MARGIN_S >= AlignOptions().max_offset_s + max(BEYOND_RANGE_S, CLAP_SURROUNDINGS_S)
    # and a take's audio starts where each of align's steps from the audio's first sample starts anew: its
    # 16 kHz samples, 10 ms energy steps, 32 ms level and silero windows and 30 ms WebRTC frames
    for step in (
        Fraction(1, TARGET_RATE),
        Fraction(1, int(ANALYSIS_RATE)),
        Fraction(str(LEVEL_FRAME_S)),
        Fraction(3, 100),
    ):
        assert (AUDIO_SPAN_GRID_S / step).denominator == 1


def test_each_take_gets_only_its_own_span_of_the_session_audio_each_sample_at_its_take_time(tmp_path):
    # Before, each of the three takes of this 100 s session got all 100 s of its audio (800000 samples, the
    # second starting 40 s before its first frame); an hour's session with ten takes wrote ten hours.
    rate, starts = 8000, [10.0, 40.0, 80.0]
    write_session(tmp_path / "s.recording", [(s, 120) for s in starts], (0.0, 100.0), rate)
    takes = takes_of(tmp_path / "s.recording", tmp_path / "out")
    assert len(takes) == 3
    margin = AUDIO_MARGIN_S + 1 / FPS
    for start, (summary, take) in zip(starts, takes, strict=True):
        audio, placed = take.audio, take.meta.audio
        assert placed.start_source == "recorder_clock"
        # from a margin (and a frame, and less than the grid) before the first frame to as long after the
        # last frame's period; on the grid of the session's audio
        assert -margin - AUDIO_SPAN_GRID_S - 1 / rate < placed.start_s <= -margin
        assert (start + placed.start_s) / AUDIO_SPAN_GRID_S == pytest.approx(
            round((start + placed.start_s) / AUDIO_SPAN_GRID_S)
        )
        assert placed.start_s + audio.frames / rate == pytest.approx(2.0 + margin, abs=1.5 / rate)
        # sample k sits at take time start_s + k / rate, as it did in the session's audio (sample-exact)
        k = np.arange(audio.frames)
        assert np.array_equal(session_index(audio.samples), np.rint((start + placed.start_s) * rate) + k)
        assert take.meta.extra["session_audio"] == {
            "first_sample": round((start + placed.start_s) * rate),
            "session_samples": 100 * rate,
        }
        # what the summary and ``info`` say of the audio is the take's own
        assert summary["audio_duration_s"] == round(audio.frames / rate, 6)
        assert summary["audio_start_s"] == placed.start_s and "audio_gaps" not in summary
    info = run_cli("info", "--json", takes[1][0]["path"])
    assert json.loads(info.stdout)["audio_duration_s"] == takes[1][0]["audio_duration_s"] < 4.6


def test_margins_stop_at_the_audios_ends_and_a_take_the_audio_never_reaches_has_none(tmp_path):
    # The audio (29.8 s) starts 0.5 s after the first take's first frame and ends 0.8 s after the second
    # take's frames, less than the margin; the third take begins 9.2 s past its end. Before, all three got
    # the whole audio (the third with no word that its audio ended 9.2 s before its first frame).
    rate = 8000
    takes = [(0.5, 120), (28.0, 120), (40.0, 120)]
    write_session(tmp_path / "a.recording", takes, (1.0, 29.8), rate)
    (_, first), (_, last), (summary, none) = takes_of(tmp_path / "a.recording", tmp_path / "out")
    assert first.meta.audio.start_s == pytest.approx(0.5) and session_index(first.audio.samples)[0] == 0
    assert first.audio.frames / rate == pytest.approx(2.0 + AUDIO_MARGIN_S + 1 / FPS - 0.5, abs=1 / rate)
    end = last.meta.audio.start_s + last.audio.frames / last.audio.sample_rate
    assert end == pytest.approx(2.8) and session_index(last.audio.samples)[-1] == round(29.8 * rate) - 1
    assert none.audio is None and none.meta.audio is None and summary["audio_sample_rate"] is None
    (note,) = none.meta.repairs
    assert note["kind"] == "audio_outside_take" and "-39.000 s to -9.200 s" in note["message"]
    with pytest.raises(InputError, match=r"has no audio: align needs the speech \(the session's audio \("):
        align_with_report(none)  # align says why, not "import it with --audio"
    # a session without audio: takes without audio, and nothing to say about it
    write_session(tmp_path / "b.recording", takes[:1], None)
    ((summary, take),) = takes_of(tmp_path / "b.recording", tmp_path / "out-b")
    assert take.audio is None and take.meta.repairs == [] and summary["audio_duration_s"] is None


def test_audio_gaps_are_counted_for_the_take_whose_audio_crosses_them(tmp_path):
    # Chunks lost at 41.0-41.3 s of a session's audio: silence inside the second take's audio only. Before,
    # every take's summary counted the session's gap, the first take's too.
    rate = 8000
    gap = (41 * rate, round(41.3 * rate))
    write_session(tmp_path / "g.recording", [(10.0, 120), (40.0, 120)], (0.0, 60.0), rate, gaps=[gap])
    (first_summary, first), (summary, take) = takes_of(tmp_path / "g.recording", tmp_path / "out")
    assert "audio_gaps" not in first_summary and "audio_gaps" not in first.meta.extra
    assert summary["audio_gaps"] == 1
    lo = take.meta.extra["session_audio"]["first_sample"]
    assert take.meta.extra["audio_gaps"] == [{"at_sample": gap[0] - lo, "samples": gap[1] - gap[0]}]
    assert not take.audio.samples[gap[0] - lo : gap[1] - lo].any()
    assert np.array_equal(session_index(take.audio.samples[: gap[0] - lo]), np.arange(lo, gap[0]))


def test_a_session_recorded_over_udp_keeps_its_audio_in_sync_take_by_take(tmp_path):
    # Two takes from a real recorder (loopback UDP), 20 s apart on the phone's clock; audio logged from
    # 30 s before the first packet to 30 s after. Each take's first sample is the one the whole session's
    # audio put at the take time its audio now starts at.
    vals = np.linspace(-0.5, 1.0, 61).astype(np.float32)
    head = header_bytes("PHONE", "Ann")
    packets = [head + frame_block(f, 0.0, FPS, 1, vals) for f in [*range(600, 660), *range(1800, 1860)]]
    rec = record_packets(tmp_path, "udp", packets)
    log = SessionLog(rec.session_dir)
    arrival_ns = int(log.stream_rows(0)["arrival_ns"][0])
    log.close()
    rate = 8000
    sound = AudioLog(rec.session_dir / AUDIO_LOG, fsync=False)
    sound.start(rate, 2, "PCM_16", "test")
    for first in range(0, 60 * rate, 800):
        sound.add_chunk(first, arrival_ns - 30 * 10**9 + first * 10**9 // rate, ramp(first, 800, 2))
    sound.close()
    summaries = build_takes(rec.session_dir, tmp_path / "out")
    assert len(summaries) == 2
    log = SessionLog(rec.session_dir)
    audio_first_s = float(log.seconds(arrival_ns - 30 * 10**9))
    log.close()
    for summary in summaries:
        take = read_take(summary["path"])
        extra, start_s = take.meta.extra, take.meta.audio.start_s
        whole_start_s = audio_first_s - extra["clock_offset_s"] - extra["first_frame_number"] / FPS
        assert take.audio.frames < (1.0 + 2 * (AUDIO_MARGIN_S + 1 / FPS) + AUDIO_SPAN_GRID_S) * rate + 2
        first = session_index(take.audio.samples)
        assert first[0] == round((start_s - whole_start_s) * rate) == extra["session_audio"]["first_sample"]
        assert np.array_equal(first, first[0] + np.arange(take.audio.frames))


def test_a_long_sessions_take_reads_only_its_own_span(tmp_path):
    # 30 min of 8 kHz stereo (57.6 MB) and one 2 s take: building it added 65 MB to the peak memory before
    # (the whole audio held twice over: every chunk's bytes, then the samples); now it reads its 4 s span.
    rate = 8000
    write_session(tmp_path / "long.recording", [(900.0, 120)], (0.0, 1800.0), rate)
    script = (
        "import resource, sys; from capture import build_takes; "
        "before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss; "
        "build_takes(sys.argv[1], sys.argv[2]); "
        "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before)"
    )
    proc = subprocess.run(
        [sys.executable, "-c", script, str(tmp_path / "long.recording"), str(tmp_path / "out")],
        capture_output=True,
        text=True,
        check=True,
    )
    assert int(proc.stdout) < 20_000  # kB of peak memory added by building the take


def syllables(t: np.ndarray) -> np.ndarray:
    """A speech-like loudness, 0..1, at session times ``t`` (s): syllables at an uneven rate."""
    return 0.5 + 0.5 * np.sin(2 * np.pi * 3.1 * t + 2 * np.sin(2 * np.pi * 0.37 * t))


def test_align_finds_in_a_takes_span_what_it_found_in_the_whole_session_audio(tmp_path):
    # Noise at a syllable loudness (44.1 kHz), the face's jawOpen following it; the take starts 5.013 s into
    # the audio. With its span starting anywhere, align's 16 kHz samples and 10 ms energy steps fell
    # elsewhere than in the whole audio: the aligned take started at -0.008314 s, not 0.008333 s (a frame
    # apart), and a recorded session's aligned audio differed by up to 1e-3 (rms 0.05). The span starts on
    # AUDIO_SPAN_GRID_S of the session's audio: the same segment and samples as with the whole audio.
    rate = 44100

    def sound(first: int, n: int, channels: int) -> np.ndarray:
        k = np.arange(first, first + n)
        noise = np.sin(k * 12.9898) * 43758.5453 % 1.0 - 0.5  # the same at each sample index, chunk or not
        return np.repeat((12000 * syllables(k / rate) * noise)[:, None], channels, 1).astype(np.int16)

    write_session(tmp_path / "c.recording", [(5.013, 180)], (0.0, 12.0), rate, sound=sound, mouth=syllables)
    ((summary, take),) = takes_of(tmp_path / "c.recording", tmp_path / "out")
    whole = index_audio_log(tmp_path / "c.recording" / AUDIO_LOG)[0].read()
    lo = take.meta.extra["session_audio"]["first_sample"]
    assert take.audio.frames < 6 * rate  # not the 12 s of the session
    whole_take = read_take(summary["path"])
    whole_take.attach_audio(whole, take.meta.audio.start_s - lo / rate, "recorder_clock")
    options = AlignOptions(vad="none")
    (span_aligned,), span_report = align_with_report(take, options)
    (whole_aligned,), whole_report = align_with_report(whole_take, options)
    # the lag within the correlation's 0.1 ms step (its normalisation sees the span, not the session)
    assert span_report["content_lag_s"] == pytest.approx(whole_report["content_lag_s"], abs=1.5e-4)
    assert span_report["segment_list"] == whole_report["segment_list"]
    assert np.allclose(span_aligned.audio.samples, whole_aligned.audio.samples, atol=1e-6)
    # the span's margins (2.5 s more audio than the 3 s of face) are by design: no duration_mismatch, as
    # a face the audio leaves uncovered is
    assert "duration_mismatch" not in span_report["flags"]
    cut = read_take(summary["path"])
    ends = int((1.5 - take.meta.audio.start_s) * rate)  # the audio ends 1.5 s into the 3 s of face
    short = Audio(take.audio.samples[:ends], rate, take.audio.subtype)
    cut.attach_audio(short, take.meta.audio.start_s, "recorder_clock")
    assert "duration_mismatch" in align_with_report(cut, options)[1]["flags"]
