"""``s2a-capture import`` of audio FFmpeg decodes (the AAC track of a take folder's .mov, an .m4a, PCM in a
.mov) writes it a block at a time into a scratch WAV as it is decoded and copies that into the take's
audio.wav, instead of holding the decoded audio whole (an hour of 48 kHz stereo AAC: 1.4 GB of float32).
The take folder is the one the whole-array way writes, to the byte; the scratch file is removed however
the import ends. Only within ``audio_left_in_files`` (the import command): other callers hold it as before.
"""

from __future__ import annotations

from pathlib import Path

import av
import numpy as np
import pytest
from conftest import run_here
from test_audio_decode_memory import CASES, _encoded
from test_long_take_memory import _traced_peak

from capture import InputError, audio_io, read_audio, write_take
from capture.audio_io import FileAudio, audio_left_in_files, write_audio
from capture.importer import import_source

TAKE_CSV = Path("livelinkface") / "alexdjulin_S07" / "S07-001.csv"


def _take_folder(samples: Path, folder: Path, mov: bytes) -> Path:
    """A Live Link Face take folder: the app's CSV (its first 4 s) and a .mov of the take's name beside it."""
    folder.mkdir(parents=True)
    lines = (samples / TAKE_CSV).read_text().splitlines(keepends=True)
    (folder / "S07-001.csv").write_text("".join(lines[:241]))
    (folder / "S07-001.mov").write_bytes(mov)
    return folder


def _files(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if p.is_file()]


SECONDS = 4.0


@pytest.fixture(scope="module")
def aac_mov() -> bytes:
    """A .mov holding 4 s of 44.1 kHz stereo AAC, as the app's take folders do (1.4 MB decoded)."""
    return _encoded("aac", "mov", "fltp", 2, seconds=SECONDS)


def _damaged(data: bytes) -> bytes:
    """``data`` with 400 bytes two thirds of the way in overwritten: audio FFmpeg stops decoding there."""
    damaged = bytearray(data)
    at = len(damaged) * 2 // 3
    damaged[at : at + 400] = bytes(range(256)) + bytes(144)
    return bytes(damaged)


def test_aac_of_a_take_folders_mov_is_never_held_whole(samples, tmp_path):
    """The import held the decoded AAC whole from the decoding to the end of the write: its peak grew with
    the audio, by all of it; now a block of it is held, whatever its length, and the take folder is the
    one the whole-array way writes, to the byte."""
    short = _take_folder(
        samples, tmp_path / "short" / "S07-001", _encoded("aac", "mov", "fltp", 2, seconds=2.0)
    )
    long = _take_folder(
        samples, tmp_path / "long" / "S07-001", _encoded("aac", "mov", "fltp", 2, seconds=10.0)
    )
    added_bytes = 8 * 44100 * 2 * 4

    def imported(take: Path, out: Path) -> Path:
        with audio_left_in_files(tmp_path):
            return write_take(import_source(take), out)

    imported(short, tmp_path / "first")  # what a first import loads once is no sample
    _, short_peak = _traced_peak(imported, short, tmp_path / "short_take")
    new, peak = _traced_peak(imported, long, tmp_path / "new")
    assert peak - short_peak < 0.25 * added_bytes, (
        f"traced peak {peak / 2**20:.2f} MB, {short_peak / 2**20:.2f} MB for 2 s of audio; "
        f"the audio added {added_bytes / 2**20:.2f} MB"
    )
    whole = write_take(import_source(long), tmp_path / "whole")
    for name in ("audio.wav", "meta.json", "frames.npz"):
        assert (new / name).read_bytes() == (whole / name).read_bytes(), name


@pytest.fixture
def small_blocks(monkeypatch):
    """Blocks of 1000 frames: a short file is written in many, its padding cut across the last ones."""
    monkeypatch.setattr(audio_io, "WRITE_FRAMES", 1000)


def test_every_decoded_format_writes_the_audio_and_repairs_of_the_whole_array_way(small_blocks, tmp_path):
    """AAC (.m4a, .mov: its padding cut where the declared duration ends), PCM 16/24-bit and float in a
    .mov, a channel change mid-stream (ADTS mono then stereo: mixed, noted), NaN and infinities (set to
    0, noted): decoded into a scratch file, the same audio.wav and repairs as decoded whole."""
    inputs = {name: _encoded(*CASES[name], seconds=0.4) for name in CASES if name.endswith((".m4a", ".mov"))}
    inputs["changed.aac"] = _encoded("aac", "adts", "fltp", 1) + _encoded("aac", "adts", "fltp", 2)
    bad = bytearray(_encoded("pcm_f32le", "mov", "flt", 1, seconds=0.4))
    at = bad.index(b"mdat") + 4 + 4 * 5000
    bad[at : at + 12] = np.array([np.nan, np.inf, -np.inf], "<f4").tobytes()
    inputs["nan.mov"] = bytes(bad)
    noted = set()
    for name, data in inputs.items():
        path = tmp_path / name
        path.write_bytes(data)
        whole_repairs, left_repairs = [], []
        whole = read_audio(path, whole_repairs)
        with audio_left_in_files(tmp_path):
            left = read_audio(path, left_repairs)
            assert isinstance(left, FileAudio) and not left.held, name
            write_audio(tmp_path / "left.wav", left)
        write_audio(tmp_path / "whole.wav", whole)
        assert (tmp_path / "left.wav").read_bytes() == (tmp_path / "whole.wav").read_bytes(), name
        assert left_repairs == whole_repairs, name
        noted |= {r["kind"] for r in left_repairs}
    assert noted == {"encoder_delay_unknown", "channels_changed", "bad_audio"}


def test_the_scratch_file_is_removed_on_success_error_and_interrupt(small_blocks, aac_mov, tmp_path):
    """The scratch WAV lies in the folder given (the import's output folder), is removed when the import
    ends, when decoding fails mid-way (blocks written already) and on Ctrl-C; audio of it read after the
    import is an error, not other samples."""
    work = tmp_path / "out"
    work.mkdir()
    mov = tmp_path / "take.mov"
    mov.write_bytes(aac_mov)
    with audio_left_in_files(work):
        audio = read_audio(mov, [])
        scratch = audio._read_from
        assert scratch.is_file() and scratch.is_relative_to(work) and audio.path == mov
    assert not work.exists() or not list(work.iterdir())
    with pytest.raises(InputError, match="cannot be read again"):
        write_audio(tmp_path / "late.wav", audio)

    (tmp_path / "damaged.mov").write_bytes(_damaged(aac_mov))
    with audio_left_in_files(work):
        with pytest.raises(InputError, match="could not be decoded"):
            read_audio(tmp_path / "damaged.mov", [])
        assert not _files(work)  # removed at once, not only when the import ends
    with pytest.raises(KeyboardInterrupt), audio_left_in_files(work):
        read_audio(mov, [])
        assert _files(work)
        raise KeyboardInterrupt
    assert not list(work.iterdir())


def test_the_import_command_leaves_nothing_but_the_takes(samples, aac_mov, tmp_path):
    """``s2a-capture import`` of a take folder whose .mov holds AAC, and of one whose AAC is damaged
    mid-way: the first take written, one error line for the second, no scratch file left in the
    output folder (where it was written)."""
    good = _take_folder(samples, tmp_path / "good" / "S07-001", aac_mov)
    _take_folder(samples, tmp_path / "bad" / "S07-001", _damaged(aac_mov))
    out = tmp_path / "takes"
    proc = run_here("capture", "import", tmp_path / "bad", good.parent, "-o", out)
    assert proc.returncode == 1
    errors = [line for line in proc.stderr.splitlines() if "error" in line]
    assert len(errors) == 1 and "could not be decoded" in errors[0], proc.stderr
    assert [p.name for p in out.iterdir()] == ["S07-001"]
    assert sorted(p.name for p in (out / "S07-001").iterdir()) == ["audio.wav", "frames.npz", "meta.json"]


def test_a_scratch_folder_the_system_refuses_decodes_whole_instead(tmp_path):
    """The system refusing the scratch file (a disk too full to hold the audio twice; here a folder that
    is gone) decodes the audio whole, as before there was a scratch file: an import that fitted in memory
    still works (it was an error)."""
    m4a = tmp_path / "take.m4a"
    m4a.write_bytes(_encoded("aac", "ipod", "fltp", 1))
    whole = read_audio(m4a, [])
    with audio_left_in_files(tmp_path / "missing"):
        audio = read_audio(m4a, [])
    assert not isinstance(audio, FileAudio) and audio.samples.tobytes() == whole.samples.tobytes()
    assert not (tmp_path / "missing").exists()


def _float_mov(path: Path, samples: np.ndarray, rate: int) -> Path:
    """``samples`` (frames x 2, float) as 32-bit float PCM in a .mov, 1024 frames a packet, as an editor
    exports it."""
    with av.open(str(path), "w", format="mov") as c:
        stream = c.add_stream("pcm_f32le", rate=rate, layout="stereo")
        for at in range(0, len(samples), 1024):
            part = np.ascontiguousarray(samples[at : at + 1024], np.float32).reshape(1, -1)
            frame = av.AudioFrame.from_ndarray(part, format="flt", layout="stereo")
            frame.sample_rate, frame.pts = rate, at
            for packet in stream.encode(frame):
                c.mux(packet)
        for packet in stream.encode(None):
            c.mux(packet)
    return path


def test_float_past_full_scale_is_mended_in_passes_over_the_file(tmp_path):
    """Float audio past full scale (an editor's export of a loud take, AAC decoded from one) with isolated
    damaged samples, at its ends too: its channels' level, the samples past 10 times it and their
    neighbours were found on whole channels (|x| of each: 691 MB an hour at 48 kHz), the audio read whole;
    now in passes over the scratch file, the same samples mended, the same repair noted."""
    rate, frames = 48000, 8 * 48000
    t = np.arange(frames) / rate
    x = np.stack([1.3 * np.sin(2 * np.pi * 220 * t), 0.4 * np.sin(2 * np.pi * 330 * t)], axis=1)
    x[[0, 70_000, 70_001, 200_000], 0] = [40.0, -60.0, 55.0, 80.0]
    x[[5, frames - 1], 1] = [30.0, -30.0]
    mov = _float_mov(tmp_path / "loud.mov", x, rate)
    whole_repairs, left_repairs = [], []
    _, whole_peak = _traced_peak(lambda: write_audio(tmp_path / "whole.wav", read_audio(mov, whole_repairs)))

    def left() -> None:
        with audio_left_in_files(tmp_path):
            audio = read_audio(mov, left_repairs)
            assert isinstance(audio, FileAudio) and not audio.held
            write_audio(tmp_path / "left.wav", audio)

    _, peak = _traced_peak(left)
    assert peak < whole_peak - 0.8 * frames * 2 * 4, (
        f"traced peak {peak / 2**20:.1f} MB, whole {whole_peak / 2**20:.1f} MB"
    )
    assert (tmp_path / "left.wav").read_bytes() == (tmp_path / "whole.wav").read_bytes()
    assert left_repairs == whole_repairs
    assert [r["kind"] for r in left_repairs] == ["bad_audio"] and " 6 isolated sample(s) up to 80" in (
        left_repairs[0]["message"]
    )
