"""``s2a-capture import`` of MP3 audio (``--audio take.mp3``) read it whole: 635 MB of float32 an hour of
44.1 kHz stereo, held from the decoding to the end of the take's write. It is decoded a block at a time
into a scratch WAV in the output folder now, as FFmpeg's audio is (``audio_left_in_files``), by the
decoder that read it whole: libsndfile's for one file, FFmpeg's per file for joined ones. The take's
audio.wav and repairs are the whole read's, to the byte: libsndfile's MP3 decoder (mpg123) gives mono
samples 1 ulp apart after a read that ends inside an MPEG frame, so its reads end where frames do."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from conftest import run_here
from test_audio_mp3_later_parts import mp3_bytes
from test_import_decoded_streaming import TAKE_CSV
from test_long_take_memory import _traced_peak

from capture import read_audio
from capture.audio_io import FileAudio, audio_left_in_files, write_audio


def _noise(seconds: float, rate: int, level: float = 0.2, seed: int = 0) -> np.ndarray:
    return (np.random.default_rng(seed).standard_normal(round(seconds * rate)) * level).astype(np.float32)


@cache
def _inputs() -> dict[str, bytes]:
    loud = np.clip(_noise(3.0, 16000, 3.0), -1, 1)  # clipped: decodes past full scale, looked at in passes
    later = mp3_bytes(_noise(0.5, 16000, seed=2), 16000, 1, write_xing="0")  # LAME's, its tag left out
    return {
        # mono with a LAME tag, 3 blocks: its reads must end where its frames do
        "tagged_mono.mp3": mp3_bytes(_noise(10.0, 16000), 16000, 1),
        "untagged_stereo.mp3": mp3_bytes(_noise(2.0, 22050), 22050, 2, write_xing="0"),
        "loud_mono.mp3": mp3_bytes(loud, 16000, 1),
        "one_frame.mp3": mp3_bytes(_noise(0.01, 16000), 16000, 1),
        "joined.mp3": mp3_bytes(_noise(1.0, 16000, seed=1), 16000, 2) + later,
        "cut_short.mp3": mp3_bytes(_noise(2.0, 16000), 16000, 1)[:9000],
    }


@pytest.mark.parametrize("name", list(_inputs()))
def test_mp3_is_decoded_into_a_scratch_file_to_the_byte_of_the_whole_read(tmp_path, name):
    """One file, tagged or not, mono or stereo, past full scale, a frame long, joined files (a channel
    change, a later LAME file without its tag), a file cut short: within an import's block it is a
    ``FileAudio`` of a scratch file, never held, written as the whole read writes it, repairs alike."""
    path = tmp_path / name
    path.write_bytes(_inputs()[name])
    whole_repairs: list = []
    write_audio(tmp_path / "whole.wav", read_audio(path, whole_repairs))
    repairs: list = []
    (tmp_path / "out").mkdir()
    with audio_left_in_files(tmp_path / "out"):
        audio = read_audio(path, repairs)
        assert isinstance(audio, FileAudio) and not audio.held
        write_audio(tmp_path / "left.wav", audio)
        assert not audio.held
    assert (tmp_path / "left.wav").read_bytes() == (tmp_path / "whole.wav").read_bytes()
    assert repairs == whole_repairs
    assert list((tmp_path / "out").iterdir()) == []  # the scratch folder went with the block


@pytest.mark.parametrize("joined", [False, True])
def test_an_mp3_import_holds_a_block_not_the_audio(tmp_path, joined):
    """Read whole, 40 s of 44.1 kHz mono MP3 peaked at its 7 MB of float32 (a joined file at twice that);
    now at a few blocks of it (2.4 MB)."""
    data = mp3_bytes(_noise(40.0, 44100), 44100, 1)
    path = tmp_path / "long.mp3"
    path.write_bytes(data + mp3_bytes(_noise(0.5, 44100), 44100, 1) if joined else data)
    decoded = 40 * 44100 * 4

    def imported() -> None:
        with audio_left_in_files(tmp_path):
            write_audio(tmp_path / "take.wav", read_audio(path, []))

    _, peak = _traced_peak(imported)
    assert peak < decoded / 2, f"traced peak {peak / 2**20:.1f} MB, the audio {decoded / 2**20:.1f} MB"


def test_the_import_command_writes_an_mp3_takes_audio_as_read_whole(samples, tmp_path):
    """``s2a-capture import take.csv --audio take.mp3``: the take's audio.wav is the whole read's, and
    nothing is left in the output folder but the take."""
    csv = tmp_path / "S07-001.csv"
    lines = (samples / TAKE_CSV).read_text().splitlines(keepends=True)
    csv.write_text("".join(lines[:241]))
    mp3 = tmp_path / "S07-001.mp3"
    mp3.write_bytes(mp3_bytes(_noise(4.0, 16000), 16000, 1))
    out = tmp_path / "out"
    run_here("capture", "import", csv, "--audio", mp3, "-o", out, check=True)
    (take,) = out.iterdir()
    write_audio(tmp_path / "whole.wav", read_audio(mp3, []))
    assert (take / "audio.wav").read_bytes() == (tmp_path / "whole.wav").read_bytes()
