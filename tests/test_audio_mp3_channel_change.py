"""An .mp3 made by joining MP3 files end to end (``cat a.mp3 b.mp3 > c.mp3``) is read whole.

libsndfile (mpg123) stopped at the frame count of the first file's Xing/Info frame, and at the first change
of channel count; FFmpeg refused the tag of the second file in the middle ("Invalid data"). Each joined
file is now decoded on its own (its LAME tag's delay and padding dropped) and the later ones mixed to the
first one's channel count (repair ``channels_changed``); a change of sample rate is a clear error.
"""

from __future__ import annotations

from pathlib import Path

import av
import numpy as np
import pytest

from capture import InputError, read_audio

RATE = 44100
# decoded length of a part may differ from the samples encoded by one MP3 frame plus the encoder's delay
# (LAME: 576 + 529 decoder delay) where a file does not record them
TOLERANCE = 1152 + 1105


def mp3(path: Path, channels: int, seconds: float, hz: float, rate: int = RATE, **options: str) -> Path:
    """A tone of ``hz`` encoded by LAME (through FFmpeg) as a file of its own, with FFmpeg's muxer
    ``options`` (default: an ID3v2 tag and a Xing/Info frame with a LAME tag, as most tools write)."""
    with av.open(str(path), "w", format="mp3", options=options) as container:
        container.metadata["title"] = path.stem  # written to the ID3v1 tag too, with write_id3v1
        stream = container.add_stream("libmp3lame", rate=rate, layout="mono" if channels == 1 else "stereo")
        tone = (0.3 * np.sin(2 * np.pi * hz * np.arange(int(rate * seconds)) / rate)).astype(np.float32)
        frame = av.AudioFrame.from_ndarray(
            np.tile(tone, (channels, 1)), format="fltp", layout=stream.layout.name
        )
        frame.sample_rate = rate
        for packet in [*stream.encode(frame), *stream.encode(None)]:
            container.mux(packet)
    return path


def joined(path: Path, *parts: Path) -> Path:
    path.write_bytes(b"".join(p.read_bytes() for p in parts))
    return path


def main_frequency(x: np.ndarray, rate: int = RATE) -> float:
    spectrum = np.abs(np.fft.rfft(x * np.hanning(x.size)))
    return float(np.argmax(spectrum)) * rate / x.size


def kinds(repairs: list[dict]) -> list[str]:
    return [r["kind"] for r in repairs]


def test_mono_then_stereo_is_read_whole_and_mixed_to_mono(tmp_path):
    path = joined(
        tmp_path / "joined.mp3", mp3(tmp_path / "a.mp3", 1, 1.0, 440), mp3(tmp_path / "b.mp3", 2, 2.0, 660)
    )
    repairs: list = []
    audio = read_audio(path, repairs)
    assert audio.channels == 1 and audio.sample_rate == RATE
    assert abs(audio.frames - 3 * RATE) <= TOLERANCE  # was 1 s: the stereo part lost without a word
    x = audio.samples[:, 0]
    assert main_frequency(x[: RATE // 2]) == pytest.approx(440, abs=3)
    assert main_frequency(x[-RATE:]) == pytest.approx(660, abs=3)  # the second part's sound, at its level
    assert np.sqrt(np.mean(x[-RATE:] ** 2)) == pytest.approx(0.3 / np.sqrt(2), rel=0.1)
    assert kinds(repairs) == ["channels_changed"]  # both files record their delay: no other note
    message = repairs[0]["message"]
    assert message.startswith("joined.mp3: the audio's channel count changes mid-stream (from 1.0")
    assert "to the first frame's 1 channel(s)" in message
    assert read_audio(path).frames == audio.frames  # without a repair list: read whole all the same


def test_stereo_then_mono_keeps_two_channels_with_the_mono_part_on_both(tmp_path):
    path = joined(
        tmp_path / "sm.mp3", mp3(tmp_path / "a.mp3", 2, 1.0, 440), mp3(tmp_path / "b.mp3", 1, 1.0, 660)
    )
    repairs: list = []
    audio = read_audio(path, repairs)
    assert audio.channels == 2 and abs(audio.frames - 2 * RATE) <= TOLERANCE
    tail = audio.samples[-RATE // 2 :]
    assert np.array_equal(tail[:, 0], tail[:, 1]) and main_frequency(tail[:, 0]) == pytest.approx(660, abs=3)
    assert kinds(repairs) == ["channels_changed"] and "2 channel(s)" in repairs[0]["message"]


def test_two_files_of_the_same_channel_count_are_read_whole(tmp_path):
    # libsndfile stopped at the frame count the first file's Info frame declares: 1 s of 3
    path = joined(
        tmp_path / "mm.mp3", mp3(tmp_path / "a.mp3", 1, 1.0, 440), mp3(tmp_path / "b.mp3", 1, 2.0, 660)
    )
    repairs: list = []
    audio = read_audio(path, repairs)
    assert abs(audio.frames - 3 * RATE) <= TOLERANCE and audio.channels == 1
    assert main_frequency(audio.samples[-RATE:, 0]) == pytest.approx(660, abs=3)
    assert repairs == []  # nothing changed in the samples


@pytest.mark.parametrize(
    ("first", "second", "delay_unknown"),
    [
        # files without tags or Info frames: a bare change of channel mode mid-stream
        ({"id3v2_version": "0", "write_xing": "0"}, {"id3v2_version": "0", "write_xing": "0"}, True),
        # a second file without tag or Info frame after one that declares its frame count
        ({}, {"id3v2_version": "0", "write_xing": "0"}, False),
        # each file with an ID3v1 tag at its end (the first one's in the middle)
        ({"write_id3v1": "1"}, {"write_id3v1": "1"}, False),
    ],
)
def test_joined_files_without_tags_or_with_id3v1_are_read_whole(tmp_path, first, second, delay_unknown):
    path = joined(
        tmp_path / "j.mp3",
        mp3(tmp_path / "a.mp3", 1, 1.0, 440, **first),
        mp3(tmp_path / "b.mp3", 2, 1.0, 660, **second),
    )
    if "write_id3v1" in first:
        assert b"TAGa" in path.read_bytes()[:-128]  # the first file's ID3v1 tag, in the middle
    repairs: list = []
    audio = read_audio(path, repairs)
    assert audio.channels == 1 and abs(audio.frames - 2 * RATE) <= 2 * TOLERANCE
    assert main_frequency(audio.samples[-RATE // 2 :, 0]) == pytest.approx(660, abs=3)
    # the start's encoder delay is noted only when the first file does not record it
    assert kinds(repairs) == ["encoder_delay_unknown"] * delay_unknown + ["channels_changed"]


def test_a_plain_mp3_with_an_id3v1_tag_reads_as_before(tmp_path):
    path = mp3(tmp_path / "v1.mp3", 2, 1.0, 440, write_id3v1="1")
    assert path.read_bytes()[-128:].startswith(b"TAGv1")
    repairs: list = []
    audio = read_audio(path, repairs)
    assert audio.frames == RATE and audio.channels == 2 and repairs == []  # the LAME tag: exact length


def test_a_change_of_sample_rate_is_a_clear_error_saying_where(tmp_path):
    path = joined(
        tmp_path / "rates.mp3",
        mp3(tmp_path / "a.mp3", 1, 1.0, 440),
        mp3(tmp_path / "b.mp3", 2, 1.0, 660, rate=48000),
    )
    with pytest.raises(
        InputError, match=r"sample rate changes from 44100 to 48000 Hz at about 1\.\d+ s"
    ) as err:
        read_audio(path, [])
    assert str(path) in str(err.value) and "split it there" in str(err.value)


def test_stray_bytes_inside_a_joined_file_keep_the_sound_after_them_on_time(tmp_path):
    first, second = mp3(tmp_path / "a.mp3", 1, 1.0, 440), mp3(tmp_path / "b.mp3", 2, 2.0, 660)
    data = second.read_bytes()
    junk = np.random.default_rng(0).integers(0, 256, 300, dtype=np.uint8).tobytes()
    second.write_bytes(data[:12000] + junk + data[12000:])  # about 0.7 s into the second file
    path = joined(tmp_path / "junk.mp3", first, second)
    repairs: list = []
    audio = read_audio(path, repairs)
    # a frame FFmpeg cannot decode is silence of its length: what follows keeps its time
    assert abs(audio.frames - 3 * RATE) <= TOLERANCE
    assert main_frequency(audio.samples[-RATE // 2 :, 0]) == pytest.approx(660, abs=3)
    assert set(kinds(repairs)) <= {"channels_changed", "bad_audio"} and "channels_changed" in kinds(repairs)


def test_a_joined_file_cut_short_just_after_the_join_keeps_the_first_file(tmp_path):
    first, second = mp3(tmp_path / "a.mp3", 1, 1.0, 440), mp3(tmp_path / "b.mp3", 2, 2.0, 660)
    path = tmp_path / "cut.mp3"
    path.write_bytes(first.read_bytes() + second.read_bytes()[:400])  # its tag, Info frame and a scrap
    repairs: list = []
    audio = read_audio(path, repairs)
    assert abs(audio.frames - RATE) <= 1152 and main_frequency(audio.samples[:, 0]) == pytest.approx(
        440, abs=3
    )
