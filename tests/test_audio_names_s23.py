"""Audio files whose names are not UTF-8 (bytes ``x\\xff\\xfe.wav``, held by Python as surrogate escapes)
were a UnicodeEncodeError traceback from soundfile, which encodes a name given as text to UTF-8: libsndfile
is given the name's bytes now. And a stop (Ctrl-C) met while libsndfile opens ``write_audio``'s output
left the opened file unclosed: its header written into the closed output later, from cffi callbacks that
printed "Exception ignored ... seek of closed file"."""

from __future__ import annotations

import os
import textwrap
from pathlib import Path

import av
import numpy as np
import pytest
import soundfile as sf
from conftest import SAMPLES, run_cli, run_python
from test_audio_mp3_later_parts import mp3_bytes
from test_import_decoded_streaming import TAKE_CSV

from capture.audio_io import audio_left_in_files, read_audio, shown_name, write_audio

_ODD = b"x\xff\xfe"  # not UTF-8


def _tone(seconds: float, rate: int) -> np.ndarray:
    return (0.3 * np.sin(np.arange(round(seconds * rate)) * 0.05)).astype(np.float32)


def _m4a_bytes(signal: np.ndarray, rate: int, path: Path) -> bytes:
    with av.open(str(path), "w") as container:
        stream = container.add_stream("aac", rate=rate, layout="mono")
        frame = av.AudioFrame.from_ndarray(signal[None, :], format="fltp", layout="mono")
        frame.sample_rate = rate
        for packet in [*stream.encode(frame), *stream.encode(None)]:
            container.mux(packet)
    return path.read_bytes()


def _inputs(tmp: Path) -> dict[str, bytes]:
    tone = _tone(1.0, 16000)
    wav = tmp / "plain.wav"
    sf.write(wav, tone, 16000, subtype="PCM_16")
    cover = b"ID3\x04\x00\x00" + bytes([0, 0x48, 0, 0]) + bytes(0x48 << 14)  # a 1.1 MB tag: FFmpeg's subfile
    return {
        "wav": wav.read_bytes(),
        "mp3": mp3_bytes(tone, 16000),
        "joined.mp3": mp3_bytes(tone, 16000) + mp3_bytes(tone[:4000], 16000),  # FFmpeg's, as files joined
        "covered.mp3": cover + mp3_bytes(tone, 16000, id3v2_version="0"),
        "m4a": _m4a_bytes(tone, 16000, tmp / "plain.m4a"),
    }


@pytest.mark.parametrize("streamed", [False, True])
def test_audio_named_in_bytes_that_are_not_utf8_reads_and_writes_as_named_in_ascii(tmp_path, streamed):
    """Each kind of audio under a name that is not UTF-8 reads (whole, and left in files as in an import)
    and writes the samples and repairs it does under an ASCII name."""
    for kind, data in _inputs(tmp_path).items():
        plain = tmp_path / f"plain.{kind}"
        odd = Path(os.fsdecode(bytes(tmp_path) + b"/" + _ODD + b"." + kind.encode()))
        plain.write_bytes(data)
        odd.write_bytes(data)
        written = {}
        for name, path in (("plain", plain), ("odd", odd)):
            repairs: list[dict] = []
            out = Path(os.fsdecode(bytes(tmp_path) + b"/out-" + _ODD + name.encode() + b".wav"))
            if streamed:
                with audio_left_in_files(tmp_path):
                    write_audio(out, read_audio(path, repairs))
            else:
                write_audio(out, read_audio(path, repairs))
            written[name] = (
                out.read_bytes(),
                [r["message"].replace(shown_name(path), "NAME") for r in repairs],
            )
        assert written["odd"] == written["plain"], kind


def test_the_import_command_takes_audio_named_in_bytes_that_are_not_utf8(tmp_path):
    """``s2a-capture import take.csv --audio x\\xff\\xfe.mp3`` (a real process): the take's audio is the
    file's, no traceback."""
    csv = tmp_path / "S07-001.csv"
    lines = (SAMPLES / TAKE_CSV).read_text().splitlines(keepends=True)
    csv.write_text("".join(lines[:61]))
    tone = _tone(1.0, 16000)
    mp3 = Path(os.fsdecode(bytes(tmp_path) + b"/" + _ODD + b".mp3"))
    mp3.write_bytes(mp3_bytes(tone, 16000))
    out = tmp_path / "out"
    proc = run_cli("capture", "import", csv, "--audio", mp3, "-o", out)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    (take,) = out.iterdir()
    write_audio(tmp_path / "whole.wav", read_audio(mp3, []))
    assert (take / "audio.wav").read_bytes() == (tmp_path / "whole.wav").read_bytes()


def test_a_stop_met_while_the_output_wav_opens_closes_it_quietly(tmp_path):
    """A Ctrl-C (a real SIGINT) that reaches the process while libsndfile opens ``write_audio``'s output
    stops the write with KeyboardInterrupt, no partial file left, and nothing printed: the opened file is
    closed before the output is (was: 'Exception ignored from cffi callback ... seek of closed file')."""
    code = textwrap.dedent(
        """
        import gc, os, signal, sys
        import numpy as np, soundfile as sf
        from capture.audio_io import Audio, write_audio

        class Interrupted(sf.SoundFile):  # libsndfile's own file, a SIGINT met as it opens
            def __init__(self, *args, **kwargs):
                super().__init__(*args, **kwargs)
                os.kill(os.getpid(), signal.SIGINT)

        sf.SoundFile = Interrupted
        out = sys.argv[1]
        try:
            write_audio(out, Audio(np.zeros((16000, 1), np.float32), 16000, "PCM_16"))
        except KeyboardInterrupt:
            print("stopped")
        gc.collect()
        print(sorted(os.listdir(os.path.dirname(out))))
        """
    )
    proc = run_python(code, str(tmp_path / "take.wav"))
    assert proc.stdout.split("\n")[:2] == ["stopped", "[]"], proc.stdout + proc.stderr
    assert proc.stderr == "", proc.stderr


def _read_bytes() -> int:
    """The bytes this process has read from files so far (Linux: ``rchar`` of /proc/self/io)."""
    return int(dict(line.split(": ") for line in Path("/proc/self/io").read_text().splitlines())["rchar"])


@pytest.mark.skipif(not Path("/proc/self/io").exists(), reason="needs Linux's /proc/self/io")
def test_a_later_joined_file_without_a_lame_tag_is_not_read_through_for_lames_name(tmp_path):
    """A later file of a joined .mp3 with no LAME tag, LAME's name in its last frames only: it was looked
    for from the file's start, which read the file again (3.70 times the joined file's bytes read in all,
    here), now in its last frames only, the block the decoding reads from kept (2.73 times, as when the
    name is found in its first frame)."""
    silence = mp3_bytes(
        np.zeros(96000, np.float32), 48000, bit_rate=320000, write_xing="0", id3v2_version="0"
    )
    frame = len(silence) // 85  # 85 frames of 960 bytes (320 kbit/s, 48 kHz), the middle ones alike
    assert silence[5 * frame : 6 * frame] == silence[-6 * frame : -5 * frame]
    unnamed = silence[: -5 * frame].replace(b"LAME", b"lame")  # the name in unused bits
    later = unnamed[: 5 * frame] + unnamed[5 * frame : 6 * frame] * 3000 + silence[-5 * frame :]  # 2.9 MB
    path = tmp_path / "joined.mp3"
    path.write_bytes(mp3_bytes(_tone(1.0, 48000), 48000) + later)
    read_audio(path, [])  # once first: modules it imports on first use are read before the count starts
    before = _read_bytes()
    repairs: list[dict] = []
    audio = read_audio(path, repairs)
    read = _read_bytes() - before
    assert audio.frames > 72 * 48000 and repairs == []  # LAME's delay dropped, not noted unknown
    assert read < 3.2 * path.stat().st_size, f"{read / path.stat().st_size:.2f} times the file read"
