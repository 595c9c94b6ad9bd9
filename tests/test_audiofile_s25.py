"""Audio left in its file (``FileAudio``) checked a block at a time as it is read again: ``listen
--audio-file`` whose file is rewritten in place while it plays logs none of the new samples and says so
when the changed block comes, keeping every sample played before it; and the MPEG leftovers."""

from __future__ import annotations

import numpy as np
import pytest
from live_helpers import listen_while_the_audio_file_changes
from test_audio_mp3_later_parts import frame_starts, lag, mp3_bytes
from test_import_mp3_damage import _lag, _speech_like, _write
from test_mp3_s24 import _with_vbri

from capture import Audio, InputError, read_audio
from capture.audio_capture import index_audio_log
from capture.audio_io import CHECK_FRAMES, _tag_bytes, audio_left_in_files, write_audio

FPS = 60
RATE = 48000


def _speech(frames: int, sign: int = 1) -> np.ndarray:
    return (sign * (np.arange(frames) % 2000 - 1000)).astype(np.int16)


def _rewritten_from(path, frames: int, changed_from: int, tmp_path) -> None:
    """``path``'s samples from ``changed_from`` on written over in place (the same size and header)."""
    new = _speech(frames)
    new[changed_from:] *= -1
    other = tmp_path / "other.wav"
    write_audio(other, Audio(new, RATE, "PCM_16"))
    data = other.read_bytes()
    assert len(data) == path.stat().st_size
    with open(path, "r+b") as f:
        f.write(data)


def test_an_audio_file_rewritten_while_it_plays_is_told_at_the_changed_block(tmp_path):
    """A 6 s --audio-file whose samples from its fourth block (4.1 s) on are rewritten in place after
    0.3 s of playing: the session logged the new samples from there on, and said so only at the file's
    end (a listen stopped before it said nothing at all). Now the changed block is told when it is read,
    before any of its samples is logged, and every sample before it is in the log."""
    frames = 6 * RATE
    wav = tmp_path / "speech.wav"
    write_audio(wav, Audio(_speech(frames), RATE, "PCM_16"))
    (line,), err, code, audio_log = listen_while_the_audio_file_changes(
        tmp_path, wav, 3, lambda: _rewritten_from(wav, frames, 3 * CHECK_FRAMES, tmp_path)
    )
    assert code == 1 and "Traceback" not in err, err
    last = err.splitlines()[-1]
    assert "the audio failed after 4.1 s of it (the takes hold those): " in last, err
    assert "changed since it was read" in last and "differ from 4.1 s on" in last, err
    session, report = index_audio_log(audio_log)
    assert report["gaps"] == [] and session.frames == 3 * CHECK_FRAMES  # all of it up to the change
    assert np.array_equal(session.read().samples[:, 0], _speech(frames)[: 3 * CHECK_FRAMES])
    assert line["frames"] == 120 and line["path"], line


@pytest.mark.parametrize("change", ["in place", "grown", "cut"])
def test_audio_left_in_its_file_gives_no_sample_of_a_changed_block(tmp_path, change):
    """Read again after its check, a file rewritten in place from its second block on, grown by a block
    or cut short after its first: every block before the change is given (in blocks of the size asked
    for, the last before the change fewer), then one error naming when it differs, never a sample of
    the new file (they were given until the end of the file told the change)."""
    frames = 2 * CHECK_FRAMES if change == "grown" else 3 * CHECK_FRAMES + 100
    wav = tmp_path / "a.wav"
    write_audio(wav, Audio(_speech(frames), RATE, "PCM_16"))
    with audio_left_in_files():
        audio = read_audio(wav)
    if change == "in place":
        _rewritten_from(wav, frames, CHECK_FRAMES + 7, tmp_path)
    else:
        now = frames + CHECK_FRAMES if change == "grown" else CHECK_FRAMES
        write_audio(wav, Audio(_speech(now), RATE, "PCM_16"))
    kept = 2 * CHECK_FRAMES if change == "grown" else CHECK_FRAMES
    given = []
    with pytest.raises(InputError, match=rf"changed since it was read.* differ from {kept / RATE:.1f} s on"):
        for block in audio.blocks(5000):
            given.append(block[:, 0].copy())
    assert [len(b) for b in given] == [5000] * (kept // 5000) + [kept % 5000]
    assert np.array_equal(np.concatenate(given), _speech(kept))  # none of the new samples


def _first_frame_damaged(data: bytes, seed: int) -> bytes:
    """``data`` with random bytes written over its first frame after its ID3v2 tag (and maybe the next),
    the header's first two bytes left: the sync, the version and layer kept, its rate and size random."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(4, 800))
    start = _tag_bytes(data, 0) + 2
    return data[:start] + rng.integers(0, 256, n, dtype=np.uint8).tobytes() + data[start + n :]


@pytest.mark.parametrize("seed", [2, 7, 27])
def test_damage_over_the_first_frame_after_a_tag_is_damage_not_a_join(tmp_path, seed):
    """LAME's 44.1 kHz MP3 (ID3v2 tag, Info frame) damaged over its first frame, its header's sync kept:
    the random bytes formed a header of another rate, taken for a file's first frame, and the file was
    refused as joined to one at another rate (49 of 120 such damages at 16 to 48 kHz). Now it is damage
    at 0.000 s: noted, the frames lost put back as silence; the sound after it as late as the notes say
    it may be (the Info frame counted as a frame of sound, the delay its LAME tag recorded kept)."""
    rate = 44100
    first_frame_damage_read(tmp_path, mp3_bytes(_speech_like(3.0, rate), rate, 1, 128000), rate, seed)


def first_frame_damage_read(tmp_path, data: bytes, rate: int, seed: int) -> tuple[object, list]:
    """The MP3 ``data`` read with its first frame damaged (``_first_frame_damaged``), checked: the damage
    noted at 0.000 s and put back as silence, the sound after it as late as the notes say it may be (not
    early); the audio and its repairs."""
    whole = read_audio(_write(tmp_path / "whole.mp3", data), []).mono_float()
    repairs: list = []
    audio = read_audio(_write(tmp_path / "damaged.mp3", _first_frame_damaged(data, seed)), repairs)
    (lost,) = [r["message"] for r in repairs if r["kind"] == "bad_audio"]
    (delay,) = [r["message"] for r in repairs if r["kind"] == "encoder_delay_unknown"]
    assert "damaged MPEG audio at 0.000 s: " in lost and "put back as silence" in lost, lost
    shifted_ms = float(lost.split("shifted by up to ")[1].split(" ms")[0])
    late_ms = float(delay.split("up to ~")[1].split(" ms")[0])
    late = _lag(whole, audio.mono_float(), len(whole) // 2, 2048, 6000)
    assert 0 <= late <= (shifted_ms + late_ms) * rate / 1000, (late, lost, delay)
    return audio, repairs


@pytest.mark.parametrize("counts", ["no frame count", "no counts"])
def test_a_vbri_frame_declaring_no_frame_count_is_no_sound(tmp_path, counts):
    """A VBRI frame (Fraunhofer's encoders' first) declaring no frame count (and no byte count either)
    before LAME's frames at 16 kHz: decoded as a frame of silence, the sound 576 samples (36 ms) late.
    Now left out as one declaring its count is: the audio of the same frames without it."""
    rate = 16000
    signal = _speech_like(3.0, rate)
    frames = mp3_bytes(signal, rate, 1, 32000, write_xing="0", id3v2_version="0")
    vbri = _with_vbri(frames)  # the VBRI frame first: its byte count at 46, its frame count at 50
    vbri = vbri[:46] + (vbri[46:50] if counts == "no frame count" else bytes(4)) + bytes(4) + vbri[54:]
    plain = read_audio(_write(tmp_path / "plain.mp3", frames), []).mono_float()
    audio = read_audio(_write(tmp_path / "vbri.mp3", vbri), []).mono_float()
    assert len(audio) == len(plain) and lag(signal[:rate], audio) == lag(signal[:rate], plain)


def _free_format(data: bytes) -> bytes:
    """LAME's frames of one size (no padding) with bit rate index 0: the same stream in free format."""
    out = bytearray(data)
    for at in frame_starts(data):
        assert not out[at + 2] & 2
        out[at + 2] &= 0x0F
    return bytes(out)


@pytest.mark.parametrize(("channels", "xing"), [(1, "0"), (2, "0"), (1, "1")])
def test_free_format_mp3_without_a_lame_tag_notes_its_unknown_delay(tmp_path, channels, xing):
    """LAME's 48 kHz MP3 in free format, without its Info frame: read 1105 samples late, as the same
    frames at their bit rate are, but unnoted (FFmpeg cannot open free format to tell). Now noted as
    those are; with its Info frame (LAME tag) nothing is said, the sound on time."""
    rate = 48000
    signal = _speech_like(2.0, rate)
    data = mp3_bytes(signal, rate, channels, 128000 * channels, write_xing=xing)
    said = {}
    for name, d in (("bit rate", data), ("free", _free_format(data))):
        repairs: list = []
        audio = read_audio(_write(tmp_path / f"{name}.mp3", d), repairs).mono_float()
        said[name] = ([r["message"].split(": ", 1)[1] for r in repairs], lag(signal[:rate], audio))
    assert said["free"] == said["bit rate"], said
    notes, late = said["free"]
    if xing == "0":
        assert late == 1105 and len(notes) == 1 and notes[0].startswith("MP3 audio whose file does not"), said
    else:
        assert late == 0 and notes == [], said
