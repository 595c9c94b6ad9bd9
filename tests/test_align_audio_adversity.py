"""The align stage against audio as it comes from real rigs: a DC offset, an idle or timecode second
channel, dialogue on one channel of many, audio recorded with more pre-roll than the offset search
covers, and speech recorded far too quietly."""

from __future__ import annotations

import numpy as np
import pytest

from align import AlignOptions, align_with_report
from align.clipping import CLIPPED_AUDIO_SHARE, clipped_share
from align.resample import looks_like_timecode, mono_mix, to_16k_mono
from capture import Audio, Take
from capture.simulate import TakeSpec, simulate_take

RATE = 48000
FAST = AlignOptions(vad="none", use_video=False)


def _sim(speaker: int, take: int) -> tuple[Take, np.ndarray]:
    """A simulated 8 s take (the probe's takes: ``s2a-capture simulate --speakers 2 --takes 4 --seconds 8
    --sample-rate 48000 --mov``) and its int16 audio samples (frames x 1)."""
    s = simulate_take(TakeSpec(seed=0, speaker=speaker, take=take, seconds=8.0, sample_rate=RATE, mov=True))
    assert s.audio.samples.dtype == np.int16
    return s.take, s.audio.samples


def _with_audio(take: Take, samples: np.ndarray, start_s: float = 0.0, source: str = "assumed_first_csv_row"):
    take.attach_audio(Audio(np.ascontiguousarray(samples), RATE, "PCM_16"), start_s, source)
    return take


def _int16(x: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(x * 32768.0), -32768, 32767).astype(np.int16)


def _ltc(n: int, level: float = 0.3) -> np.ndarray:
    """A linear-timecode-like signal: biphase-mark code at 2,400 bits/s (30 fps x 80 bits), random bits:
    the level flips at every bit boundary and, for a 1, in the middle of the bit too."""
    rng = np.random.default_rng(5)
    cell = RATE / 4800.0  # half a bit
    bits = rng.integers(0, 2, int(n / (2 * cell)) + 2)
    flips = np.stack([np.ones_like(bits), bits], axis=1).ravel()  # per half-bit cell
    levels = np.cumprod(np.where(flips == 1, -1.0, 1.0))
    return (level * levels[(np.arange(n) / cell).astype(np.int64)]).astype(np.float32)


@pytest.fixture(scope="module")
def sim():
    return _sim(1, 2)


def _speech(sim) -> np.ndarray:
    return sim[1][:, 0].astype(np.float32) / 32768.0


# F2: DC offset and rumble.


def test_a_dc_offset_is_removed_from_the_aligned_audio_and_reported(sim):
    take, pcm = sim
    clean = align_with_report(_with_audio(take, pcm), FAST)
    x = _speech(sim)
    biased = align_with_report(_with_audio(take, _int16(x + 0.05)[:, None]), FAST)
    a = clean[0][0].audio.samples[:, 0]
    b = biased[0][0].audio.samples[:, 0]
    assert abs(float(np.mean(b))) < 1e-4  # was 0.05
    assert abs(float(np.mean(a))) < 1e-4
    assert np.max(np.abs(a - b)) < 2e-4  # the same audio as without the offset (int16 rounding apart)
    # the leading silence is silence again: its energy, which features read, is the clean take's
    lead = slice(0, 1600)
    assert np.mean(b[lead] ** 2) < 1.5 * np.mean(a[lead] ** 2) + 1e-12
    dc = biased[1]["audio_dc"]
    assert dc["dc_offset"] == pytest.approx(0.05, abs=1e-3) and "high-pass" in dc["message"]
    assert "audio_dc" not in clean[1]
    assert biased[1]["offset_s"] == clean[1]["offset_s"]


def test_rumble_goes_and_speech_frequencies_stay():
    t = np.arange(4 * 16000) / 16000
    for f, kept in ((5.0, False), (10.0, False), (60.0, True), (200.0, True), (4000.0, True)):
        y = to_16k_mono(Audio((0.3 * np.sin(2 * np.pi * f * t)).astype(np.float32), 16000, "FLOAT"))
        ratio = np.std(y[8000:-8000]) / (0.3 / np.sqrt(2))
        if kept:
            assert ratio > 0.94, f  # within 0.5 dB from 60 Hz up
        else:
            assert ratio < 0.05, f


# F3: clipping on an idle, constant or timecode channel.


def test_an_idle_constant_or_timecode_channel_is_not_clipped(sim):
    x = _speech(sim)  # peaks about -18 dBFS: nowhere near clipping
    rng = np.random.default_rng(0)
    idle = rng.integers(-1, 2, x.size).astype(np.int16)
    for second in (
        idle,  # +-1 LSB of noise: was 17 % "clipped"
        np.full(x.size, -1, np.int16),  # -1 LSB of digital silence: was 100 %
        (idle + 9830).astype(np.int16),  # a constant 0.3 with +-1 LSB on it
        _int16(_ltc(x.size)),  # a timecode channel: was 99.9 %
        np.zeros(x.size, np.int16),
    ):
        stereo = np.stack([_int16(x), second], axis=1)
        assert clipped_share(Audio(stereo, RATE, "PCM_16")) == 0.0
    # real clipping is still found: speech driven 24 dB too hot, int16 and float clipped at 1.0, and the
    # flat tops of audio clipped and then scaled down to half
    hot = np.clip(16 * x, -1.0, 1.0 - 1 / 32768)
    assert clipped_share(Audio(np.stack([_int16(hot), idle], 1), RATE, "PCM_16")) > CLIPPED_AUDIO_SHARE
    assert clipped_share(Audio(hot.astype(np.float32), RATE, "FLOAT")) > CLIPPED_AUDIO_SHARE
    assert clipped_share(Audio((0.5 * hot).astype(np.float32), RATE, "FLOAT")) > CLIPPED_AUDIO_SHARE


def test_a_timecode_channel_is_neither_clipping_nor_mixed_in(sim):
    take, _ = sim
    x = _speech(sim)
    stereo = np.stack([_int16(x), _int16(_ltc(x.size))], axis=1)
    segs, rep = align_with_report(_with_audio(take, stereo), FAST)
    assert rep["clipped_audio"] == 0.0 and "clipped_audio" not in rep["flags"]
    assert rep["audio_mix"]["left_out"] == [{"channel": 2, "reason": "timecode"}]
    assert rep["audio_mix"]["used_channels"] == [1] and "warnings" not in rep
    assert looks_like_timecode(_ltc(RATE), RATE) and not looks_like_timecode(x, RATE)
    assert not looks_like_timecode(np.clip(16 * x, -1, 1), RATE)  # heavily clipped speech is speech


# F5: pre-roll beyond --max-offset-ms.


def test_pre_roll_beyond_the_search_range_is_flagged_not_trusted(sim):
    """2 s of digital silence before the speech of a CSV take whose audio placement is only assumed:
    the offset (-2.01 s) lies outside the +-0.5 s searched. Before, a peak inside the range (-0.4355 s,
    confidence 0.34) moved the face as trusted content evidence."""
    take, pcm = sim
    base = align_with_report(_with_audio(take, pcm), FAST)[1]
    assert base["offset_source"] == "content" and "low_confidence" not in base["flags"]
    pre = np.concatenate([np.zeros((2 * RATE, 1), np.int16), pcm])
    rep = align_with_report(_with_audio(take, pre), FAST)[1]
    assert rep["offset_source"] != "content" and rep["offset_s"] == 0.0
    assert "low_confidence" in rep["flags"]
    content = [e for e in rep["alternatives"] if e["source"] == "content"][0]
    assert content["detail"]["best_lag_outside_range_s"] == pytest.approx(base["offset_s"] - 2.0, abs=0.01)
    assert any("--max-offset-ms" in w and "outside" in w for w in rep["warnings"])
    # the same pre-roll with a real placement (the frame log says the audio started 2 s early) is fine
    placed = align_with_report(_with_audio(take, pre, -2.0, "frame_log_audio"), FAST)[1]
    assert placed["offset_source"] == "content" and placed["offset_s"] == pytest.approx(
        base["offset_s"], abs=1e-3
    )
    assert "low_confidence" not in placed["flags"] and "warnings" not in placed


def test_a_pre_roll_peak_that_only_beats_the_true_one_by_a_little_is_not_trusted():
    """Pre-roll of 1.6 and 1.8 s on another take: the correlation's peak inside the range (-0.16 s,
    -0.36 s) is the highest anywhere but barely beats the true one outside it; judged against every lag
    the audio and face lengths allow, it is not confident."""
    take, pcm = _sim(0, 2)
    for pad in (1.6, 1.8):
        pre = np.concatenate([np.zeros((int(pad * RATE), 1), np.int16), pcm])
        rep = align_with_report(_with_audio(take, pre), FAST)[1]
        assert rep["offset_source"] != "content" and "low_confidence" in rep["flags"], pad
        assert any("--max-offset-ms" in w for w in rep["warnings"])


# F6: idle and timecode channels diluting the mix.


def test_channels_without_speech_are_left_out_of_the_mix(sim):
    x = _speech(sim)
    z = np.zeros_like(x)
    rng = np.random.default_rng(1)
    for chans, used in (
        ([x, z], [1]),
        ([z, z, x, z, z, z], [3]),
        ([x, z + 3e-5 * rng.standard_normal(x.size)], [1]),
    ):
        mono, note = mono_mix(Audio(np.stack(chans, 1).astype(np.float32), RATE, "FLOAT"))
        assert np.array_equal(mono, x) and note["method"] == "channels_left_out"
        assert note["used_channels"] == used and len(note["left_out"]) == len(chans) - 1
        assert all(d["reason"] == "idle" for d in note["left_out"])
    # a microphone pair (the second mic 10 dB down, with its own noise) is still averaged
    pair = np.stack([x, 0.3 * x + 0.002 * rng.standard_normal(x.size)], 1).astype(np.float32)
    mono, note = mono_mix(Audio(pair, RATE, "FLOAT"))
    assert note is None and np.allclose(mono, pair.mean(axis=1))


def test_dialogue_on_one_channel_keeps_its_level_and_the_take_aligns(sim):
    take, pcm = sim
    mono = align_with_report(_with_audio(take, pcm), AlignOptions(vad="webrtc", use_video=False))
    z = np.zeros_like(pcm)
    surround = np.concatenate([z, z, pcm, z, z, z], axis=1)
    five = align_with_report(_with_audio(take, surround), AlignOptions(vad="webrtc", use_video=False))
    a, b = mono[0][0].audio.samples[:, 0], five[0][0].audio.samples[:, 0]
    assert np.array_equal(a, b)  # was 15.6 dB down
    assert five[1]["audio_mix"]["used_channels"] == [3] and five[1]["frames"] == mono[1]["frames"]


# F7: quiet audio.


def test_quiet_speech_is_found_and_flagged_and_keeps_its_level(sim):
    take, _ = sim
    x = _speech(sim)
    x = x / np.max(np.abs(x))
    opts = AlignOptions(vad="silero", use_video=False)
    normal = align_with_report(_with_audio(take, _int16(0.5 * x)[:, None]), opts)[1]
    for db in (-60.0, -65.0):  # kept 88 of 353 frames at -60 dBFS, none at -65 ("no speech found")
        segs, rep = align_with_report(_with_audio(take, _int16(10 ** (db / 20) * x)[:, None]), opts)
        assert rep["frames"] >= 0.95 * normal["frames"], db
        assert "quiet_audio" in rep["flags"] and rep["audio_level"]["vad_gain_db"] > 20
        assert any("very quiet" in w and "dBFS" in w for w in rep["warnings"])
        peak = 20 * np.log10(np.max(np.abs(segs[0].audio.samples)))
        assert peak == pytest.approx(db, abs=1.0)  # the audio written keeps its level
    assert "quiet_audio" not in normal["flags"] and normal["audio_level"]["vad_gain_db"] == 0.0
