"""Review of the MP3 import change 90aa4bd (``capture/audio_io.py``): what it got wrong.

An untagged .mp3 with zeros or junk after its last frame (no frame count declared) was said to end "about
104 ms short" (a ``bad_audio`` repair, an import's WARNING) on a good file: the bytes after the last frame
were taken for frames lost, with no evidence of any.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import av
import numpy as np
import pytest
from test_audio_mp3_later_parts import mp3_bytes
from test_import_mp3_damage import _damaged, _mp3, _speech_like, _write
from test_mp3_leftovers_s23 import _adts, _cover

from capture import read_audio
from capture.audio_io import _FileBytes, _read_joined_mpeg_checked, mpeg_runs
from capture.errors import InputError

_LYRICS3 = b"LYRICSBEGIN" + b"IND0000210" + b"000021LYRICS200"


@pytest.mark.parametrize(
    "tail",
    [bytes(2000), bytes(range(1, 255)) * 8, _LYRICS3, bytes(300) + b"TAG" + bytes(125)],
    ids=["zeros", "junk_without_sync", "lyrics3", "zeros_then_id3v1"],
)
@pytest.mark.parametrize("xing", [False, True], ids=["untagged", "info_frame"])
def test_bytes_after_the_last_frame_that_start_no_frame_say_no_loss(tmp_path, tail, xing):
    """Zero padding, junk with no frame sync or a Lyrics3 tag after the last whole frame: no frame lost
    there, no ``bad_audio`` note (the untagged file's 2000 zeros: "about 131 ms short" before), nor a
    ``truncated_audio`` one (libsndfile's decoder gives up after 1 KB of them: "header declares 1.769 s of
    audio, the file holds 1.593 s (...; cut short?)", a frame of silence put after the sound): the audio
    as read without them (FFmpeg's frames only, where libsndfile gives up: within 1e-5)."""
    data = _mp3(22050, 1, 64000, xing)
    plain = read_audio(_write(tmp_path / "plain.mp3", data), []).mono_float()
    repairs: list = []
    audio = read_audio(_write(tmp_path / "padded.mp3", data + tail), repairs).mono_float()
    assert [r["kind"] for r in repairs if r["kind"] in ("bad_audio", "truncated_audio")] == []
    assert len(audio) == len(plain) and np.abs(audio - plain).max() < 1e-5


@pytest.mark.parametrize(
    ("joined", "kept"), [(False, 1 / 3), (True, 0.9)], ids=["damaged", "joined_after_a_file"]
)
def test_an_mp3_cut_short_while_ffmpeg_reads_it_is_one_clear_error(tmp_path, capfd, joined, kept):
    """A damaged .mp3 over a scan block (2 MB), or one joined on after a 1 s file, that another program
    cuts short after its frames were scanned: the read FFmpeg asks for fails (``_FileBytes``). Raised into
    FFmpeg, PyAV printed it ("PyAV library exception being dropped", a traceback, twice) and may drop it,
    the audio then ending where the read failed (Ctrl-C the same: 1 of 40 interrupted imports returned the
    audio 0.8 s short); a later file's failed read was taken for a file FFmpeg cannot open: its 63 s left
    out, "2436 damaged MPEG audio frame(s)". Now the one ``InputError`` saying the file got shorter."""
    one = mp3_bytes(_speech_like(3.0, 44100), 44100, 1, 320000, write_xing="0")
    (run,) = mpeg_runs(one)
    long = _damaged(one[: run.end] + one[run.start : run.end] * 20, (0.5, 3000))
    before = mp3_bytes(_speech_like(1.0, 44100), 44100) if joined else b""
    path = _write(tmp_path / "long.mp3", before + long)
    with _FileBytes.of(path) as data:
        runs = mpeg_runs(data)
        os.truncate(path, int(len(data) * kept))
        with pytest.raises(InputError, match="the file got shorter while it was read"):
            _read_joined_mpeg_checked(path, data, runs, [])
    assert "Traceback" not in capfd.readouterr().err


@pytest.mark.parametrize("cover", [0, 2 << 20], ids=["plain", "big_cover"])
@pytest.mark.parametrize("suffix", [".aac", ".mp3"])
def test_a_relative_name_with_a_colon_is_opened_by_ffmpeg_as_a_file(tmp_path, monkeypatch, suffix, cover):
    """ "take:1.aac" in the working folder: FFmpeg took "take" for a protocol ("Protocol not found": a raw
    .aac it decodes refused, an .mp3's check of its encoder delay silently skipped, no note). With a big
    cover, given through ``subfile``, the same. Now named for FFmpeg's ``file`` protocol: read, and the
    LAME file without its tag noted as any other is."""
    signal = _speech_like(1.0, 16000)
    body = _adts(signal, 16000) if suffix == ".aac" else mp3_bytes(signal, 16000, write_xing="0")
    _write(tmp_path / f"take:1{suffix}", (_cover(cover) if cover else b"") + body)
    monkeypatch.chdir(tmp_path)
    repairs: list = []
    audio = read_audio(Path(f"take:1{suffix}"), repairs)
    assert audio.frames >= len(signal)
    assert [r["kind"] for r in repairs] == ["encoder_delay_unknown"]


def _vbr_mp3(signal: np.ndarray, rate: int) -> bytes:
    """``signal`` encoded by LAME at variable bit rate (-q:a 4), no Xing header (FFmpeg's write_xing=0)."""
    out = io.BytesIO()
    with av.open(out, "w", format="mp3", options={"write_xing": "0"}) as container:
        options = {"flags": "+qscale", "global_quality": str(4 * 118)}
        stream = container.add_stream("libmp3lame", rate=rate, layout="mono", options=options)
        frame = av.AudioFrame.from_ndarray(signal[None], format="fltp", layout="mono")
        frame.sample_rate = rate
        for packet in [*stream.encode(frame), *stream.encode(None)]:
            container.mux(packet)
    return out.getvalue()


@pytest.mark.parametrize("tail", [b"", bytes(1500)], ids=["plain", "zeros_after"])
def test_a_short_vbr_mp3_without_a_xing_header_is_read_to_its_end(tmp_path, tail):
    """1.5 s at 11025 Hz, VBR, no Xing header: libsndfile's length (mpg123's estimate from the first
    frame's bit rate) was 8987 of the 17856 samples its frames code, read so, with no note: short by less
    than ``_MPG123_DROPS`` (9871 samples: the delay and padding a LAME tag records, which mpg123 drops only
    from a file whose header counts its frames). Now read as FFmpeg decodes its frames, to their end."""
    rate = 11025
    data = _vbr_mp3(_speech_like(1.5, rate), rate)
    with av.open(io.BytesIO(data), format="mp3") as container:
        decoded = sum(frame.samples for frame in container.decode(audio=0))
    audio = read_audio(_write(tmp_path / "vbr.mp3", data + tail), [])
    assert audio.frames == decoded
