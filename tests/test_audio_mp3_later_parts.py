"""Joined .mp3 files whose later parts record no encoder delay, and an Info frame that undercounts its frames.

A file joined on without a LAME tag (LAME's ``-t``, FFmpeg's ``write_xing=0``) kept its priming samples in
the middle of the audio, unnoted: the sound after it 1105 samples (LAME: 576 + 529) late. LAME's output is
now recognised by the name it writes into frames' spare bits and its delay dropped; another encoder's is
kept and noted (repair ``encoder_delay_unknown``, from which second). A single file whose Info frame
declares two or more frames fewer than its byte count covers, with the frame after the count starting its
own bit reservoir, was split there as if joined (a frame's glitch, the sound after it early): it is read
whole, its count corrected.
"""

from __future__ import annotations

import io
from pathlib import Path

import av
import numpy as np
import soundfile as sf

from capture import read_audio
from capture.audio_io import _mpeg_frame, _mpeg_frame_table, _starts_reservoir, _tag_bytes, mpeg_runs

LAME_DELAY = 576 + 529  # what FFmpeg decodes before the sound of a LAME file without its tag


def mp3_bytes(signal: np.ndarray, rate: int, channels: int = 1, bit_rate: int = 0, **options: str) -> bytes:
    """``signal`` (mono float) encoded by LAME through FFmpeg, on each of ``channels``; FFmpeg's muxer
    ``options`` (default: an ID3v2 tag and an Info frame with a LAME tag)."""
    out = io.BytesIO()
    with av.open(out, "w", format="mp3", options=options) as container:
        stream = container.add_stream("libmp3lame", rate=rate, layout="mono" if channels == 1 else "stereo")
        if bit_rate:
            stream.bit_rate = bit_rate
        frame = av.AudioFrame.from_ndarray(
            np.tile(signal.astype(np.float32), (channels, 1)), format="fltp", layout=stream.layout.name
        )
        frame.sample_rate = rate
        for packet in [*stream.encode(frame), *stream.encode(None)]:
            container.mux(packet)
    return out.getvalue()


def ffmpeg_decoded(data: bytes) -> np.ndarray:
    with av.open(io.BytesIO(data), format="mp3") as container:
        return np.concatenate([f.to_ndarray()[0] for f in container.decode(audio=0)])


def lag(reference: np.ndarray, decoded: np.ndarray, most: int = 3000) -> int:
    """Samples from the start of ``decoded`` to where ``reference`` lies in it (cross-correlation peak)."""
    size = 1 << (len(decoded) + len(reference)).bit_length()
    cc = np.fft.irfft(np.fft.rfft(decoded, size) * np.conj(np.fft.rfft(reference, size)), size)
    lags = np.r_[0:most, -most:0]
    return int(lags[np.argmax(cc[lags])])


def speech(samples: Path, seconds: float) -> np.ndarray:
    wav = (
        samples
        / "speech"
        / "pocketsphinx-testdata-librivox"
        / "sense_and_sensibility_01_austen_64kb-0870.wav"
    )
    x, rate = sf.read(str(wav), dtype="float32")
    assert rate == 16000
    return x[: int(rate * seconds)]


def test_a_later_lame_file_without_its_tag_is_joined_on_time(tmp_path, samples):
    # real speech at 16 kHz (MPEG-2, frames of 576 samples), the later file with its ID3v2 tag; and a noise
    # at 44.1 kHz stereo, the later file bare (no tag at all: the walk splits it by the first file's count)
    rng = np.random.default_rng(0)
    noise = (0.2 * rng.standard_normal(88200)).astype(np.float32)
    for rate, channels, first, second, options in (
        (16000, 1, speech(samples, 1.0), speech(samples, 3.0)[16000:], {"write_xing": "0"}),
        (44100, 2, noise[:44100], noise[44100:], {"write_xing": "0", "id3v2_version": "0"}),
    ):
        path = tmp_path / f"joined{rate}.mp3"
        path.write_bytes(mp3_bytes(first, rate, channels) + mp3_bytes(second, rate, channels, **options))
        repairs: list = []
        x = read_audio(path, repairs).samples[:, 0]
        # the second file's sound follows the first one's at once (it was LAME_DELAY samples late)
        assert lag(second, x[len(first) :]) == 0
        assert lag(first, x) == 0 and repairs == []


def test_a_later_file_of_another_encoder_without_a_tag_keeps_its_delay_noted_from_its_second(tmp_path):
    rate = 44100
    rng = np.random.default_rng(1)
    first, second = (0.2 * rng.standard_normal((2, rate))).astype(np.float32)
    # LAME's bitstream without its name in the spare bits: an encoder whose delay is not known here
    bare = mp3_bytes(second, rate, write_xing="0", id3v2_version="0").replace(b"LAME", b"othr")
    path = tmp_path / "other.mp3"
    path.write_bytes(mp3_bytes(first, rate) + bare)
    repairs: list = []
    x = read_audio(path, repairs).samples[:, 0]
    assert lag(second, x[rate:]) == LAME_DELAY  # kept: its priming is not known to be LAME's
    assert [r["kind"] for r in repairs] == ["encoder_delay_unknown"]
    message = repairs[0]["message"]
    assert message.startswith(
        "other.mp3: the MP3 file joined on at 1.000 s does not record its encoder's delay"
    )
    assert "~50 ms late" in message


def frame_starts(data: bytes) -> list[int]:
    _mpeg_frame_table()
    pos, starts = _tag_bytes(data, 0), []
    while (frame := _mpeg_frame(data, pos)) is not None:
        starts.append(pos)
        pos += frame[0]
    return starts


def with_frame_count(data: bytes, count: int) -> bytes:
    """``data`` whose Info frame (its first frame, after its ID3v2 tag) declares ``count`` frames."""
    pos = _tag_bytes(data, 0)
    frame = _mpeg_frame(data, pos)
    assert frame is not None
    at = pos + frame[5][data[pos + 3] >= 0xC0] + 8
    return data[:at] + count.to_bytes(4, "big") + data[at + 4 :]


def test_an_undercounting_info_frame_before_a_frame_that_starts_its_reservoir_is_no_join(tmp_path):
    # at 320 kbit/s LAME's frames in quiet passages begin their sound in their own bytes (main_data_begin
    # 0), as a file's first frame does: the frame after a count too low looked like another file
    rate = 44100
    rng = np.random.default_rng(2)
    quiet, loud = np.zeros(rate // 2), 0.4 * rng.standard_normal(rate // 2)
    signal = np.concatenate([loud, quiet, loud, quiet]).astype(np.float32)
    data = mp3_bytes(signal, rate, bit_rate=320000)
    starts = frame_starts(data)  # the Info frame, then the audio frames 1, 2, ...
    fresh = [
        i
        for i in range(3, len(starts) - 3)
        if _starts_reservoir(data, starts[i], _mpeg_frame(data, starts[i]))
    ]
    assert fresh, "no frame of this encoding starts its own bit reservoir"
    path = tmp_path / "undercount.mp3"
    path.write_bytes(with_frame_count(data, fresh[0] - 1))  # that frame is the first past the count
    runs = mpeg_runs(path.read_bytes())
    assert len(runs) == 1 and runs[0].count_low  # was two files
    audio = read_audio(path, repairs := [])
    # exactly what the file decodes to with its right count: every frame, its delay and padding dropped
    assert np.array_equal(audio.samples[:, 0], ffmpeg_decoded(data)) and audio.frames == len(signal)
    assert repairs == []


def test_a_file_joined_on_where_the_first_files_byte_count_ends_is_still_a_join(tmp_path):
    rate = 44100
    rng = np.random.default_rng(3)
    first = mp3_bytes((0.2 * rng.standard_normal(rate)).astype(np.float32), rate)
    bare = mp3_bytes(
        (0.2 * rng.standard_normal(rate)).astype(np.float32), rate, write_xing="0", id3v2_version="0"
    )
    tag = _tag_bytes(first, 0)
    frame = _mpeg_frame(first, tag)
    assert frame is not None
    at = tag + frame[5][first[tag + 3] >= 0xC0] + 12  # the byte count, after the frame count
    declared = int.from_bytes(first[at : at + 4], "big")
    assert declared == len(first) - tag  # FFmpeg counts from its Info frame
    # some writers count the ID3v2 tag before it too (LAME's own): still where the first file ends
    counted_with_tag = first[:at] + (declared + tag).to_bytes(4, "big") + first[at + 4 :]
    for head in (first, counted_with_tag):
        runs = mpeg_runs(head + bare)
        assert [run.new_file for run in runs] == [True, True] and not runs[0].count_low


def test_a_bare_file_of_other_channels_joined_to_a_bare_one_is_joined_on_time(tmp_path):
    # neither file has a tag or an Info frame: only the change of channels tells the join. The second
    # was decoded on from the first, its priming kept in the middle, unnoted
    rate = 22050
    rng = np.random.default_rng(4)
    first, second = (0.2 * rng.standard_normal((2, rate))).astype(np.float32)
    bare = {"write_xing": "0", "id3v2_version": "0"}
    head = mp3_bytes(first, rate, 1, **bare)
    path = tmp_path / "bare.mp3"
    path.write_bytes(head + mp3_bytes(second, rate, 2, **bare))
    repairs: list = []
    x = read_audio(path, repairs).samples[:, 0]
    start = len(ffmpeg_decoded(head))  # the first file's priming and padding kept (it is the start)
    assert lag(first, x) == LAME_DELAY and lag(second, x[start:]) == 0
    assert [r["kind"] for r in repairs] == ["encoder_delay_unknown", "channels_changed"]
