"""Review of the MP3 import change 6694eed (``capture/audio_io.py``): what it left wrong.

Damage right after an .mp3's first frame, that frame's header damaged too (another channel mode: a run of
its own, one frame long), had the frames lost estimated from that one run's bytes less the damage after
it, which lies outside them: a division by zero (a traceback from ``s2a-capture import``), or a negative
count ("-2 frame(s) lost there", the sound after it 2880 samples early at 16 kHz), or a file refused as
undecodable. The frames lost are now estimated at the whole file's mean bytes per frame.

A Lyrics3 tag, or an APE tag without a header, between two files joined without a LAME tag (a good file)
was warned of as bytes that may have held frames ("181 bytes that start no MPEG frame (damage, or a tag not
known here) ... up to 1 frame(s) (36 ms) of its sound are missing there"): they are tags, said nothing of.
"""

from __future__ import annotations

import pytest
from test_audio_mp3_later_parts import mp3_bytes
from test_import_mp3_damage import _lag, _speech_like, _write
from test_mp3_s24 import _joined, _later_at, _overwritten

from capture import read_audio
from capture.audio_io import mpeg_runs


@pytest.mark.parametrize(
    ("rate", "bit_rate", "zeros", "lost"),
    [(48000, 128000, 100, 2), (16000, 0, 300, 4), (44100, 0, 100, 2)],
    ids=["two_frames_lost_48k", "four_lost_16k", "two_lost_44k"],
)
def test_damage_after_a_damaged_first_frame_is_counted_at_the_files_bytes_per_frame(
    tmp_path, rate, bit_rate, zeros, lost
):
    """A bare LAME file (no tag, no Xing frame) whose first frame's channel mode was damaged (dual channel,
    not mono) and whose next frames' headers were zeroed. Old: ZeroDivisionError (48 kHz: the lost frame as
    long as the lone one), "-2 frame(s) lost" and the sound after it 2880 samples early (16 kHz), "audio
    could not be decoded" (44.1 kHz). Now the frames zeroed are put back as silence: the length and timing
    of the undamaged file, its damaged first frame counted lost too (put back as silence), the file mono."""
    data = mp3_bytes(_speech_like(2.0, rate), rate, 1, bit_rate, write_xing="0", id3v2_version="0")
    (run,) = mpeg_runs(data)
    size = (run.end - run.start) // run.frames  # a frame's bytes (the first frame starts the data)
    damaged = bytearray(data)
    damaged[3] = damaged[3] & 0x3F | 0x80  # dual channel
    damaged[size : size + zeros] = bytes(zeros)
    whole = read_audio(_write(tmp_path / "whole.mp3", data)).mono_float()
    repairs: list = []
    audio = read_audio(_write(tmp_path / "damaged.mp3", bytes(damaged)), repairs).mono_float()
    notes = [r["message"] for r in repairs if "lost there" in r["message"]]
    assert len(notes) == 1 and f": {lost} frame(s) lost there" in notes[0]
    assert len(audio) == len(whole)
    assert _lag(whole, audio, len(whole) // 2, 2048, 3000) == 0


def _ape_without_header() -> bytes:
    """An APEv2 tag of one item (a comment of 200 bytes, more than a frame's half), its footer only (as
    APEv1 and some taggers write it)."""
    item = (200).to_bytes(4, "little") + bytes(4) + b"Comment\0" + b"hello " * 33 + b"ok"
    fields = [(2000, 4), (len(item) + 32, 4), (1, 4), (0, 4)]  # version, its bytes, items, flags
    return item + b"APETAGEX" + b"".join(v.to_bytes(n, "little") for v, n in fields) + bytes(8)


LYRICS3 = b"LYRICSBEGININD0000210LYR00009some text000035LYRICS200" + b"TAG" + bytes(125)


@pytest.mark.parametrize("between", [LYRICS3, _ape_without_header(), None], ids=["lyrics3", "ape", "junk"])
def test_a_tag_before_a_joined_file_is_no_damage(tmp_path, between):
    """Two LAME files without their tag (nothing counts their frames) joined with a Lyrics3 tag (then an
    ID3v1 one) or a headerless APE tag between them: no ``bad_audio`` note (old: "... if they were frames,
    up to 1 frame(s) (36 ms) of its sound are missing there"), the sound as without the tag. Junk of the
    Lyrics3 and ID3v1 tags' length there (a frame's: no tag) is still said."""
    data, later, end = _joined("0")
    whole = read_audio(_write(tmp_path / "whole.mp3", data), []).mono_float()
    tag = LYRICS3 if between is None else between
    joined = data[:end] + tag + data[end:]
    if between is None:
        joined = _overwritten(joined, end, end + len(tag))
    repairs: list = []
    audio = read_audio(_write(tmp_path / "joined.mp3", joined), repairs).mono_float()
    notes = [r["message"] for r in repairs if r["kind"] == "bad_audio"]
    if between is None:
        assert len(notes) == 1
    else:
        assert notes == []
        assert len(audio) == len(whole) and _later_at(later, audio) == _later_at(later, whole)
