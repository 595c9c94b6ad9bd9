"""Damage inside one .mp3 (bytes overwritten in transfer or on a card): libsndfile's decoder resyncs after
it and FFmpeg's parser skips it, both without the frames whose headers were lost (600 bytes in a 44.1 kHz
file at 128 kbit/s: 2 frames, the sound after them 52 ms early, the face frames after it out of sync, no
repair said so). The frame scan finds where its frames were lost (``MpegRun.losses``) and how many (the
frames a Xing/Info frame declares less those found, else estimated from the bytes damaged), and puts as
many silent frames there: the audio keeps its length and every later sample its time (repair
``bad_audio``). The scan reads the file a block at a time (``_FileBytes``), not whole: a 60 MB cover
picture or an hour at 320 kbit/s (144 MB) held as bytes."""

from __future__ import annotations

import subprocess
import sys
from functools import cache

import numpy as np
import pytest
from conftest import ROOT, run_here
from test_audio_mp3_later_parts import mp3_bytes
from test_import_decoded_streaming import TAKE_CSV

from capture import read_audio
from capture.audio_io import _FileBytes, mpeg_runs, write_audio


def _speech_like(seconds: float, rate: int) -> np.ndarray:
    """A gliding tone under a syllable rate envelope, with some noise: no two stretches alike."""
    t = np.arange(round(seconds * rate)) / rate
    tone = np.sin(2 * np.pi * (200 + 150 * np.sin(2 * np.pi * 0.7 * t)) * t) * (0.5 + 0.5 * np.sin(6.3 * t))
    noise = np.random.default_rng(0).standard_normal(len(t))
    return (0.3 * tone + 0.05 * noise).astype(np.float32)


@cache
def _mp3(rate: int, channels: int, bit_rate: int, xing: bool) -> bytes:
    options = {} if xing else {"write_xing": "0"}
    return mp3_bytes(_speech_like(3.0, rate), rate, channels, bit_rate, **options)


def _damaged(data: bytes, *spans: tuple[float, int]) -> bytes:
    """``data`` with random bytes written over ``n`` bytes at each ``(fraction of the file, n)``."""
    out = bytearray(data)
    rng = np.random.default_rng(1)
    for at, n in spans:
        start = int(len(out) * at)
        out[start : start + n] = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
    return bytes(out)


def _lag(whole: np.ndarray, got: np.ndarray, at: int, window: int = 4096, reach: int = 6000) -> int:
    """Where ``whole[at:at + window]`` lies in ``got``, relative to ``at`` (cross-correlation)."""
    seg = got[at - reach : at + window + reach]
    return int(np.argmax(np.correlate(seg, whole[at : at + window], mode="valid"))) - reach


CASES = {
    # (rate, channels, bit rate, Xing/Info frame), damage: (fraction of the file, bytes)
    "info_mono_44k": ((44100, 1, 128000, True), [(0.5, 600)]),
    "info_stereo_48k_twice": ((48000, 2, 96000, True), [(0.3, 600), (0.6, 2000)]),
    "untagged_22k": ((22050, 1, 64000, False), [(0.5, 600)]),
}


@pytest.mark.parametrize("name", list(CASES))
def test_damage_inside_an_mp3_keeps_the_sound_after_it_on_time(tmp_path, name):
    """The damaged file decodes to the whole file's length, the sound after the damage where it was
    (no lag, the same samples but for the decoders' rounding), and a ``bad_audio`` repair says where and
    how much was put back as silence; estimated (no frame count) it says by how much the sound may be off."""
    (rate, channels, bit_rate, xing), spans = CASES[name]
    whole = read_audio(_write(tmp_path / "whole.mp3", _mp3(rate, channels, bit_rate, xing)), [])
    repairs: list = []
    path = _write(tmp_path / "damaged.mp3", _damaged(_mp3(rate, channels, bit_rate, xing), *spans))
    audio = read_audio(path, repairs)
    assert audio.frames == whole.frames
    a, b = whole.mono_float(), audio.mono_float()
    for at in (round(len(a) * max(f for f, _ in spans)) + rate // 2, len(a) - rate // 4 - 4096):
        assert _lag(a, b, at) == 0
        assert np.abs(a[at : at + 4096] - b[at : at + 4096]).max() < 1e-3
    notes = [r["message"] for r in repairs if r["kind"] == "bad_audio"]
    assert len(notes) == len(spans) and all("put back as silence" in note for note in notes)
    assert all(("may be shifted by up to" in note) != xing for note in notes)


def test_damage_in_an_mp3_cut_short_is_counted_from_its_bytes(tmp_path):
    """Damaged, then cut short: the frames its Info frame declares less those found count the lost tail
    too, so they disagree with the bytes damaged: those count (its silence 52 ms, not 1.2 s), said to be
    estimated; the sound between the damage and the cut keeps its time."""
    data = _mp3(44100, 1, 128000, True)
    whole = read_audio(_write(tmp_path / "whole.mp3", data), []).mono_float()
    repairs: list = []
    cut = _damaged(data, (0.4, 600))[: len(data) * 4 // 5]
    audio = read_audio(_write(tmp_path / "cut.mp3", cut), repairs).mono_float()
    assert _lag(whole, audio, round(len(whole) * 0.4) + 22050) == 0
    (note,) = [r["message"] for r in repairs if r["kind"] == "bad_audio"]
    assert "2 frame(s) lost" in note and "may be shifted by up to 52 ms" in note


def test_a_damaged_mp3_imports_on_time_into_a_scratch_file(tmp_path, samples):
    """``s2a-capture import``: the take's audio.wav is the damaged file's whole read (the scratch file's
    block-wise decode gives the same), its length the undamaged file's, the repair in meta.json."""
    csv = tmp_path / "S07-001.csv"
    csv.write_text("".join((samples / TAKE_CSV).read_text().splitlines(keepends=True)[:181]))
    mp3 = _write(tmp_path / "S07-001.mp3", _damaged(_mp3(44100, 1, 128000, True), (0.5, 600)))
    run_here("capture", "import", csv, "--audio", mp3, "-o", tmp_path / "out", check=True)
    (take,) = (tmp_path / "out").iterdir()
    repairs: list = []
    write_audio(tmp_path / "whole.wav", read_audio(mp3, repairs))
    assert (take / "audio.wav").read_bytes() == (tmp_path / "whole.wav").read_bytes()
    assert (
        read_audio(take / "audio.wav").frames
        == read_audio(_write(tmp_path / "u.mp3", _mp3(44100, 1, 128000, True))).frames
    )
    assert "put back as silence" in (take / "meta.json").read_text()


@pytest.mark.parametrize("rate", [44100, 16000])
def test_an_untagged_joined_file_with_another_after_it_says_its_padding_is_kept(tmp_path, rate):
    """Three files joined, the middle one LAME's without its tag: its padding (how many samples of its
    last frames are no sound) is recorded nowhere, and kept, so the third file's sound is late (875
    samples at 44.1 kHz, 175 at 16 kHz, 20 and 11 ms): a repair says from which second and by how much at
    most, and the lag is within it."""
    parts = [_speech_like(1.0, rate), _speech_like(1.0, rate)[::-1].copy(), 0.7 * _speech_like(1.5, rate)]
    data = (
        mp3_bytes(parts[0], rate, 1)
        + mp3_bytes(parts[1], rate, 1, write_xing="0")
        + mp3_bytes(parts[2], rate, 1)
    )
    repairs: list = []
    audio = read_audio(_write(tmp_path / "joined.mp3", data), repairs).mono_float()
    (note,) = [r["message"] for r in repairs if "padding" in r["message"]]
    most_ms = float(note.rsplit("up to ", 1)[1].split(" ms")[0])
    lag = _lag(np.concatenate(parts), audio, 2 * rate + rate // 2, 2048, 3000)
    assert "joined on at 1.000 s" in note and 0 < lag <= most_ms / 1000 * rate


def _write(path, data: bytes):
    path.write_bytes(data)
    return path


def _peak_growth_kb(script: str, *args) -> int:
    """How far ``script``'s work (a fresh interpreter, ``capture`` imported) raises its peak RSS, in KB: its
    VmHWM (``ru_maxrss`` starts at the forking parent's, pytest's)."""
    code = (
        "import re, sys\nfrom pathlib import Path\nimport capture.audio_io as aio\n"
        "def peak(): return int(re.search(r'VmHWM:\\s*(\\d+)', Path('/proc/self/status').read_text())[1])\n"
        f"before = peak()\n{script}\nprint(peak() - before)"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True, cwd=ROOT, timeout=60
    )
    assert proc.returncode == 0, proc.stderr
    return int(proc.stdout.split()[-1])


def _id3_cover(size: int) -> bytes:
    """An ID3v2.3 tag holding one picture frame of ``size`` bytes (a cover photo)."""
    frame = b"APIC" + size.to_bytes(4, "big") + b"\0\0" + bytes(size)
    declared = len(frame)
    return b"ID3\3\0\0" + bytes(declared >> shift & 0x7F for shift in (21, 14, 7, 0)) + frame


def test_an_mp3_with_a_big_cover_picture_is_imported_without_holding_it(tmp_path):
    """A 48 MB cover picture in its ID3v2 tag: read within an import's block, neither the frame scan nor
    libsndfile's decoder (which reads a tag it is shown whole) holds it: the peak is the picture-less
    file's (49 MB against 20 MB before: its bytes read whole), the audio the same to the sample."""
    body = _mp3(44100, 1, 128000, True)
    cover, plain = (
        _write(tmp_path / "cover.mp3", _id3_cover(48 << 20) + body),
        _write(tmp_path / "plain.mp3", body),
    )
    script = "with aio.audio_left_in_files(sys.argv[2]): aio.read_audio(Path(sys.argv[1]), [])"
    assert _peak_growth_kb(script, cover, tmp_path) < _peak_growth_kb(script, plain, tmp_path) + 8_000
    assert np.array_equal(read_audio(cover, []).samples, read_audio(plain, []).samples)


def test_the_frame_scan_of_a_long_mp3_holds_a_few_mb(tmp_path):
    """The frames of 40 MB at 320 kbit/s (17 min) scanned from the file a block at a time (frames across
    each block's end): one block held (40 MB read whole), the runs found the same as in its bytes read
    whole."""
    one = mp3_bytes(_speech_like(3.0, 44100), 44100, 2, 320000, write_xing="0")
    (run,) = mpeg_runs(one)
    data = one[: run.end] + one[run.start : run.end] * (40_000_000 // (run.end - run.start))
    path = _write(tmp_path / "long.mp3", data)
    script = "with aio._FileBytes.of(Path(sys.argv[1])) as data: runs = aio.mpeg_runs(data)"
    assert _peak_growth_kb(script, path) < 8_000
    with _FileBytes.of(path) as blocks:
        assert mpeg_runs(blocks) == mpeg_runs(data)
