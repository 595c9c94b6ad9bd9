"""Audio decoded by PyAV (a take's .mov, an .m4a, .mp3, .ogg ...) is held once while it is decoded.

Each decoded frame was kept as a chunk of its own and the chunks joined at the end: for a while the audio
was in memory twice (an hour of a take's AAC audio: 635 MB more at import). The frames are now written
one after another into one array (``_Samples``), with the same samples, dtype, padding trim and repairs as
joining the chunks gave.
"""

from __future__ import annotations

import io
from pathlib import Path

import av
import numpy as np
import pytest
from test_long_take_memory import _traced_peak

from capture import Audio, InputError
from capture.audio_io import (
    _decode_frames,
    _in_recorded_format,
    _JoinedPart,
    _Samples,
    _to_channels,
    check_samples,
    decode_with_pyav,
)

RATE = 44100


def _tone(channels: int, seconds: float, rate: int) -> np.ndarray:
    """channels x samples of a tone with a little noise, in [-0.5, 0.5]."""
    t = np.arange(int(rate * seconds)) / rate
    x = 0.4 * np.sin(2 * np.pi * 330 * t) + 0.01 * np.random.default_rng(1).standard_normal(t.size)
    return np.tile(x, (channels, 1))


def _encoded(codec: str, container: str, sample_format: str, channels: int, seconds: float = 0.5) -> bytes:
    """``seconds`` of a tone encoded by FFmpeg's ``codec`` into ``container``, given to it as
    ``sample_format`` (packed formats interleaved)."""
    rate = 48000 if codec == "libopus" else RATE  # Opus encodes 48 kHz only
    x = _tone(channels, seconds, rate)
    dtypes = {"s16": (np.int16, 32767), "s32": (np.int32, 2**31 * 0.99), "flt": (np.float32, 1)}
    dtype, scale = dtypes[sample_format.rstrip("p")]
    samples = (x * scale).astype(dtype)
    if not sample_format.endswith("p"):
        samples = samples.T.reshape(1, -1)
    layout = "mono" if channels == 1 else "stereo"
    out = io.BytesIO()
    with av.open(out, "w", format=container) as c:
        stream = c.add_stream(codec, rate=rate, layout=layout)
        frame = av.AudioFrame.from_ndarray(np.ascontiguousarray(samples), format=sample_format, layout=layout)
        frame.sample_rate, frame.pts = rate, 0
        for packet in [*stream.encode(frame), *stream.encode(None)]:
            c.mux(packet)
    return out.getvalue()


def _one_layout(chunks: list[np.ndarray]) -> tuple[np.ndarray, int, int]:
    """How decoded chunks were joined before (``np.concatenate``), each mixed to the first chunk's channel
    count; with the number of samples that were mixed and the sample where the first of them starts."""
    channels = chunks[0].shape[1]
    changed, first_changed, at = 0, 0, 0
    for i, arr in enumerate(chunks):
        if arr.shape[1] != channels:
            first_changed = first_changed if changed else at
            changed += len(arr)
            chunks[i] = _to_channels(arr, channels)
        at += len(arr)
    return np.concatenate(chunks, axis=0), changed, first_changed


def _joined_chunks(path: Path, skip_damaged: bool = False):
    """What decoding gave before: the decoded chunks joined (``_one_layout``), the AAC padding cut, in the
    recorded format; with the repairs noted."""
    repairs: list = []
    chunks: list[np.ndarray] = []  # each decoded frame as it comes
    decoded = _decode_frames(
        str(path), path, 0, repairs, skip_damaged, into=lambda _stream: _JoinedPart(chunks)
    )
    data, changed, _ = _one_layout(chunks)
    if decoded.declared is not None and 0 < data.shape[0] - decoded.declared < decoded.last_frame:
        data = data[: decoded.declared]
    return _in_recorded_format(data, decoded.rate, decoded.sample_format), changed


CASES = {
    "aac_mono.m4a": ("aac", "ipod", "fltp", 1),
    "aac_stereo.m4a": ("aac", "ipod", "fltp", 2),
    "aac_mono.mov": ("aac", "mov", "fltp", 1),
    "s16_stereo.mov": ("pcm_s16le", "mov", "s16", 2),
    "s24_mono.mov": ("pcm_s24le", "mov", "s32", 1),
    "float_stereo.mov": ("pcm_f32le", "mov", "flt", 2),
    "stereo.mp3": ("libmp3lame", "mp3", "fltp", 2),
    "mono.ogg": ("libopus", "ogg", "flt", 1),
    "stereo.flac": ("flac", "flac", "s16", 2),
}


@pytest.mark.parametrize("name", list(CASES))
def test_decoded_audio_is_the_joined_chunks(tmp_path, name):
    path = tmp_path / name
    path.write_bytes(_encoded(*CASES[name]))
    audio = decode_with_pyav(path)
    expected, _ = _joined_chunks(path)
    assert audio.samples.dtype == expected.samples.dtype and audio.subtype == expected.subtype
    assert np.array_equal(audio.samples, expected.samples)


def test_a_channel_change_and_damaged_packets_are_repaired_as_before(tmp_path):
    # raw ADTS records no duration: the array grows as it is decoded
    mono, stereo = _encoded("aac", "adts", "fltp", 1), _encoded("aac", "adts", "fltp", 2)
    changed = tmp_path / "changed.aac"
    changed.write_bytes(mono + stereo)
    repairs: list = []
    audio = decode_with_pyav(changed, repairs=repairs)
    expected, mixed = _joined_chunks(changed)
    assert mixed and [r["kind"] for r in repairs] == ["encoder_delay_unknown", "channels_changed"]
    assert audio.channels == 1 and np.array_equal(audio.samples, expected.samples)

    damaged = bytearray(stereo + mono)
    damaged[len(stereo) // 2 : len(stereo) // 2 + 400] = bytes(range(256)) + bytes(144)
    (tmp_path / "damaged.aac").write_bytes(bytes(damaged))
    audio = decode_with_pyav(tmp_path / "damaged.aac", skip_damaged=True)
    expected, _ = _joined_chunks(tmp_path / "damaged.aac", skip_damaged=True)
    assert audio.samples.dtype == expected.samples.dtype
    assert np.array_equal(audio.samples, expected.samples)


def test_samples_grow_mix_promote_and_trim_like_joined_chunks():
    rng = np.random.default_rng(2)
    chunks = [
        rng.integers(-(2**15), 2**15, (n, c), dtype=np.int16) for n, c in [(5, 2), (7, 1), (0, 2), (9, 2)]
    ]
    for expected in (0, 3, 21, 1000):  # no guess, short guesses (grown in place), a generous one
        samples = _Samples(expected)
        for chunk in chunks:
            samples.append(chunk)
        joined, changed, at = _one_layout(list(chunks))
        assert (samples.changed, samples.first_changed) == (changed, at) == (7, 5)
        assert np.array_equal(samples.take(), joined)
    # silence before the first frame is float32 (its dtype unknown yet): the join is float32, as before
    samples = _Samples()
    for chunk in [np.zeros((4, 2), np.float32), *chunks]:
        samples.append(chunk)
    taken = samples.take(10)
    assert taken.dtype == np.float32 and np.array_equal(
        taken, _one_layout([np.zeros((4, 2), np.float32), *chunks])[0][:10]
    )


def test_an_hours_take_is_held_once_while_it_is_decoded(tmp_path):
    # numpy reports its arrays to tracemalloc: joining the chunks held the audio twice (peak ~2.07 x)
    for name in ("aac_mono.m4a", "s16_stereo.mov"):
        path = tmp_path / name
        path.write_bytes(_encoded(*CASES[name], seconds=2.0))
        audio, peak = _traced_peak(decode_with_pyav, path)
        assert peak < 1.3 * audio.samples.nbytes, (name, peak / audio.samples.nbytes)


def test_float_audio_is_checked_without_a_copy_of_it():
    """The check every float take audio gets (NaN and infinities, damaged samples) made a mask of all the
    samples and an |x| copy of each channel (606 MB for an hour of AAC decoded): it looks a block at a
    time now and takes |x| only of audio past full scale, with the same repairs."""
    rng = np.random.default_rng(3)
    samples = (rng.standard_normal((120 * 16000, 1)) * 0.1).astype(np.float32)
    samples[[1000, 500_000], 0] = [np.nan, np.inf]
    audio = Audio(samples, 16000, "FLOAT")
    repairs: list[dict] = []
    _, peak = _traced_peak(check_samples, audio, Path("take.wav"), repairs)
    assert peak < samples.nbytes / 8, (peak, samples.nbytes)
    assert [r["message"] for r in repairs] == ["take.wav: 2 NaN or infinite samples set to 0"]
    assert audio.samples[1000, 0] == 0 and audio.samples[500_000, 0] == 0 and np.isfinite(audio.samples).all()
    with pytest.raises(InputError, match="holds 1 NaN or infinite sample"):
        check_samples(Audio(np.array([[0.5], [np.nan]], np.float32), 16000, "FLOAT"), Path("t.wav"), None)
