"""A collector's session from live capture to align (review): what align says about live takes whose
audio span leaves part of the face without sound, and about a take too short to keep. Sessions are real
logs (``write_session``) built into takes by ``build_takes``; align runs as the user runs it."""

from __future__ import annotations

import json

import numpy as np
from conftest import SAMPLES, run_cli
from test_live_take_audio_span import syllables, write_session

from capture import build_takes, read_audio


def noisy_syllables(first: int, n: int, channels: int) -> np.ndarray:
    """8 kHz noise at a syllable loudness, the same at each session sample index."""
    k = np.arange(first, first + n)
    noise = np.sin(k * 12.9898) * 43758.5453 % 1.0 - 0.5
    return np.repeat((12000 * syllables(k / 8000) * noise)[:, None], channels, 1).astype(np.int16)


def aligned(tmp_path, takes, audio) -> tuple[list[dict], str, int]:
    """A session's takes aligned by ``s2a-align --vad none --json``: reports, stderr and exit code."""
    session = tmp_path / "s.recording"
    write_session(session, takes, audio, sound=noisy_syllables, mouth=syllables)
    paths = [s["path"] for s in build_takes(session, tmp_path / "takes")]
    r = run_cli("align", *paths, "-o", tmp_path / "aligned", "--vad", "none", "--json")
    return [json.loads(x) for x in r.stdout.splitlines()], r.stderr, r.returncode


def test_a_live_take_the_microphone_missed_the_start_of_says_how_much_face_has_no_audio(tmp_path):
    # The microphone started 3 s after the phone: the take's first 3 of 8 s have no sound. Align flagged
    # duration_mismatch and said nothing else: the flag's text (audio and face lengths differ) did not fit
    # a live take whose audio is longer than its face by design, and nothing said 3 s of face were cut.
    (report,), err, code = aligned(tmp_path, [(0.0, 480)], (3.0, 20.0))
    assert code == 0, err
    assert "duration_mismatch" in report["flags"]
    assert report["segment_list"][0]["start_s"] >= 3.0
    (warning,) = report["warnings"]
    assert "3.00 s of its 8.00 s of face have no audio" in warning
    assert "starts 3.00 s after its first frame" in warning and "only the 5.00 s with audio" in warning
    # a take the audio covers, with its margins: no flag, no warning
    (good,), err, code = aligned(tmp_path / "good", [(2.0, 480)], (0.0, 20.0))
    assert code == 0 and "duration_mismatch" not in good["flags"] and "warnings" not in good, err


def test_a_take_too_short_to_keep_says_how_long_its_longest_stretch_is(tmp_path):
    # 2.1 s of face, 0.4 s of it lost in the middle (the phone stopped for a moment): two stretches of
    # 0.83 s on align's grid. The error said only that no stretch of 1 s was there; now what there was.
    (report,), err, code = aligned(tmp_path, [(0.0, 51), (1.25, 51)], (0.0, 20.0))
    assert code == 1
    assert "no stretch of at least 1 s with both speech and a tracked face (the longest: 0.83 s;" in err
    assert "--min-segment-s" in err and len(err.splitlines()) == 1 and "Traceback" not in err


def test_a_build_that_aligns_a_raw_live_take_passes_on_what_align_warned(tmp_path):
    # The same late microphone, the take given raw to the build (which aligns it): the build said nothing
    # of the 3 s of face it left out, and the collector never ran align to see its warning.
    speech = read_audio(
        SAMPLES / "speech/pocketsphinx-testdata-librivox/sense_and_sensibility_01_austen_64kb-0890.wav"
    )
    speech = speech.samples[:, 0]  # 5.3 s read aloud, 16 kHz

    def spoken(first: int, n: int, channels: int) -> np.ndarray:
        k = np.clip(np.arange(first, first + n), 0, speech.size - 1)
        return np.repeat(speech[k][:, None], channels, 1)

    session = tmp_path / "s.recording"
    write_session(session, [(0.0, 480)], (3.0, 6.0), rate=16000, sound=spoken)
    (take,) = build_takes(session, tmp_path / "takes")
    r = run_cli("dataset", "build", take["path"], "-o", tmp_path / "ds")
    assert r.returncode == 0, r.stderr
    # the build's summary goes to stdout, its warnings to stderr
    assert "3.00 s of its 8.00 s of face have no audio (the session's audio starts 3.00 s after" in r.stderr
