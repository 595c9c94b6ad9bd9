"""Second review of ``FileAudio``'s block checks and the MPEG leftovers: damage over a mono MP3's first
frame that formed a header of 2 channels is damage, not the file's first frame (read as stereo before);
a free-format MP3 whose audio holds a false frame is read at its rate (read as garbage at 8 kHz before)."""

from __future__ import annotations

import numpy as np
import pytest
from test_audio_mp3_later_parts import mp3_bytes
from test_audiofile_s25 import _first_frame_damaged, _free_format, first_frame_damage_read
from test_import_mp3_damage import _speech_like, _write

from capture import read_audio
from capture.audio_io import mpeg_runs


@pytest.mark.parametrize(
    ("rate", "bit_rate", "tagged", "seed"), [(16000, 32000, True, 7), (22050, 32000, False, 3)]
)
def test_damage_over_a_mono_files_first_frame_is_no_channel_change(tmp_path, rate, bit_rate, tagged, seed):
    """LAME's mono MP3 damaged over its first frame (after its ID3v2 tag and Info frame, or at the start
    of bare frames), the header's sync kept, the random bytes forming a header of the same rate but 2
    channels: taken for the file's first frame, the whole file was read as stereo ("the audio's channel
    count changes mid-stream ... mixed to the first frame's 2 channel(s)"; 18 of 240 such damages at 16 to
    44.1 kHz), the bare file's sound 1152 samples early. Now it is damage at 0.000 s, the file mono, its
    sound as late as the notes say it may be."""
    options = {} if tagged else {"write_xing": "0", "id3v2_version": "0"}
    data = mp3_bytes(_speech_like(3.0, rate), rate, 1, bit_rate, **options)
    audio, repairs = first_frame_damage_read(tmp_path, data, rate, seed)
    assert audio.channels == 1 and "channels_changed" not in [r["kind"] for r in repairs], repairs


def test_damage_over_the_first_frame_that_ffmpeg_could_not_decode_is_read(tmp_path):
    """LAME's mono 44.1 kHz MP3 whose first frame after its tag is damaged into a header of 2 channels
    (seed 6): taken for the first frame, the file went to FFmpeg as joined parts, which refused it
    ("audio could not be decoded (a truncated or damaged file?)"). Now read, the damage noted."""
    rate = 44100
    data = mp3_bytes(_speech_like(3.0, rate), rate, 1, 128000)
    repairs: list = []
    audio = read_audio(_write(tmp_path / "damaged.mp3", _first_frame_damaged(data, 6)), repairs)
    assert audio.channels == 1 and abs(audio.frames - 3 * rate) < 4 * 1152, audio.frames
    assert any(r["message"].split(": ", 1)[1].startswith("damaged MPEG audio at 0.000 s") for r in repairs)


@pytest.mark.parametrize(
    ("rate", "bit_rate", "xing"), [(48000, 160000, "0"), (32000, 64000, "0"), (48000, 160000, "1")]
)
def test_free_format_mp3_with_a_header_inside_its_audio_is_read_at_its_rate(tmp_path, rate, bit_rate, xing):
    """LAME's mono MP3 in free format whose audio holds, by chance, bytes the frame scan takes for a frame
    followed by another (a "run"): refused before ("audio could not be decoded"), then read from that false
    frame on as damage before a first frame: 48 kHz mono read as 8 kHz stereo, 15 s of it for 1.5 s. Now
    a free-format stream is told by its own header, repeated a frame on: read as the same frames at their
    bit rate are, the same samples."""
    data = mp3_bytes(_speech_like(1.5, rate), rate, 1, bit_rate, write_xing=xing, id3v2_version="0")
    assert len(mpeg_runs(_free_format(data))) == 1  # the false frame inside its audio
    plain = read_audio(_write(tmp_path / "bit rate.mp3", data), [])
    repairs: list = []
    audio = read_audio(_write(tmp_path / "free.mp3", _free_format(data)), repairs)
    assert (audio.sample_rate, audio.channels, audio.frames) == (rate, 1, plain.frames), repairs
    assert np.array_equal(audio.samples, plain.samples)
    assert [r["kind"] for r in repairs] == ([] if xing == "1" else ["encoder_delay_unknown"]), repairs
