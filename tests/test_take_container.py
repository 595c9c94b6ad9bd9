"""The take container: exact round trips, atomic writes, and clear errors for damaged folders."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from capture import Audio, FrameStatus, InputError, Take, TakeMeta, find_takes, read_take, write_take
from capture.take import META_FILE

names = st.lists(
    st.text("abcdefghijklmnopqrstuvwxyzABCXYZ_0123456789", min_size=1, max_size=12),
    min_size=1,
    max_size=8,
    unique_by=str.lower,
)


@st.composite
def takes(draw):
    channels = draw(names)
    n = draw(st.integers(1, 40))
    steps = draw(hnp.arrays(np.float64, n, elements=st.floats(1e-4, 1.0)))
    time = np.cumsum(steps) - steps[0] + draw(st.floats(-10, 10))
    values = draw(
        hnp.arrays(
            np.float32,
            (n, len(channels)),
            elements=st.floats(-3, 3, width=32) | st.just(float("nan")),
        )
    )
    status = draw(hnp.arrays(np.uint8, n, elements=st.sampled_from([int(s) for s in FrameStatus])))
    meta = TakeMeta(
        id=draw(st.text("abc_-0123", min_size=1, max_size=10)),
        source_kind="test",
        fps=draw(st.sampled_from([30.0, 60.0, 59.94])),
        channels=channels,
        slate=draw(st.none() | st.text(max_size=8)),
        take_number=draw(st.none() | st.integers(0, 999)),
        start_timecode=draw(st.none() | st.just("10:00:00:00.000")),
        repairs=[{"line": 3, "kind": "bad_value", "message": "ü"}],
        extra={"x": [1, 2.5, "y"]},
    )
    take = Take(meta, time, values, status)
    if draw(st.booleans()):
        take.neutral = draw(hnp.arrays(np.float32, len(channels), elements=st.floats(0, 1, width=32)))
    kind = draw(st.sampled_from(["none", "PCM_16", "FLOAT", "PCM_24"]))
    if kind != "none":
        frames = draw(st.integers(1, 500))
        rate = draw(st.sampled_from([16000, 44100, 48000]))
        chans = draw(st.integers(1, 2))
        if kind == "PCM_16":
            samples = draw(hnp.arrays(np.int16, (frames, chans)))
        elif kind == "PCM_24":
            samples = draw(hnp.arrays(np.int32, (frames, chans), elements=st.integers(-(2**23), 2**23 - 1)))
            samples = samples << 8  # 24-bit PCM as soundfile presents it in int32
        else:
            samples = draw(hnp.arrays(np.float32, (frames, chans), elements=st.floats(-1, 1, width=32)))
        take.attach_audio(Audio(samples, rate, kind), draw(st.floats(-1, 1)), "test")
    return take


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(take=takes())
def test_write_then_read_is_exact(tmp_path, take):
    folder = write_take(take, tmp_path)
    back = read_take(folder)
    assert back.meta == take.meta
    assert np.array_equal(back.time, take.time)
    assert np.array_equal(back.values, take.values, equal_nan=True)
    assert np.array_equal(back.frame_status, take.frame_status)
    assert (back.neutral is None) == (take.neutral is None)
    if take.neutral is not None:
        assert np.array_equal(back.neutral, take.neutral)
    if take.audio is None:
        assert back.audio is None
    else:
        assert back.audio.sample_rate == take.audio.sample_rate
        assert back.audio.subtype == take.audio.subtype
        assert np.array_equal(back.audio.samples, take.audio.samples)


def small_take(take_id="t1") -> Take:
    meta = TakeMeta(id=take_id, source_kind="test", fps=60.0, channels=["jawOpen", "mouthClose"])
    return Take(meta, np.arange(5) / 60, np.zeros((5, 2)), np.zeros(5))


def test_failed_write_leaves_no_partial_take(tmp_path):
    take = small_take()
    take.attach_audio(Audio(np.zeros((10, 1), np.float32), 16000, "NOT_A_SUBTYPE"))
    with pytest.raises(ValueError, match="subtype"):
        write_take(take, tmp_path)
    assert os.listdir(tmp_path) == []


def test_a_take_read_take_would_refuse_is_never_written(tmp_path):
    """Code that set a meta field to a value of the wrong type (csv = None) used to write a take that
    every command then refused to read."""
    take = small_take()
    take.meta.csv = None
    with pytest.raises(InputError, match="csv must be an object"):
        write_take(take, tmp_path)
    take = small_take()
    take.meta.channels = ["jawOpen", "JAWOPEN"]
    with pytest.raises(InputError, match="twice"):
        write_take(take, tmp_path)
    assert os.listdir(tmp_path) == []


def test_overwrite_replaces_whole_take(tmp_path):
    a = small_take()
    a.attach_audio(Audio(np.zeros((10, 1), np.int16), 16000, "PCM_16"))
    folder = write_take(a, tmp_path)
    b = small_take()
    b.values[:] = 1
    assert write_take(b, tmp_path) == folder
    back = read_take(folder)
    assert back.audio is None and not (folder / "audio.wav").exists()
    assert np.all(back.values == 1)
    assert sorted(os.listdir(tmp_path)) == ["t1"]
    with pytest.raises(InputError, match="exists"):
        write_take(b, tmp_path, overwrite=False)


def test_find_takes_skips_hidden_partial_folders(tmp_path):
    write_take(small_take("a"), tmp_path / "x")
    write_take(small_take("b"), tmp_path / "x" / "deeper")
    (tmp_path / "x" / ".b.partial-123").mkdir()
    (tmp_path / "x" / ".b.partial-123" / META_FILE).write_text("{}")
    found = find_takes([tmp_path])
    assert [p.name for p in found] == ["a", "b"]


def test_damaged_takes_give_clear_errors(tmp_path):
    folder = write_take(small_take(), tmp_path)
    meta = json.loads((folder / META_FILE).read_text())
    (folder / META_FILE).write_text(json.dumps(meta | {"schema_version": 99}))
    with pytest.raises(InputError, match="schema version 99"):
        read_take(folder)
    (folder / META_FILE).write_text("{not json")
    with pytest.raises(InputError, match="not valid JSON"):
        read_take(folder)
    (folder / META_FILE).write_text(json.dumps(meta))
    (folder / "frames.npz").write_bytes(b"PK\x03\x04truncated")
    with pytest.raises(InputError, match="unreadable"):
        read_take(folder)


def test_frames_are_never_unpickled(tmp_path):
    folder = write_take(small_take(), tmp_path)
    with open(folder / "frames.npz", "wb") as f:
        np.savez(f, time=np.arange(5) / 60, values=np.array([object()] * 10).reshape(5, 2), frame_status=0)
    with pytest.raises(InputError, match="unreadable"):
        read_take(folder)


def test_inconsistent_arrays_are_refused():
    meta = TakeMeta(id="x", source_kind="test", fps=60.0, channels=["a"])
    with pytest.raises(InputError, match="do not match"):
        Take(meta, np.arange(3.0), np.zeros((3, 2)), np.zeros(3))
    with pytest.raises(InputError, match="increasing"):
        Take(meta, np.array([0.0, 0.0, 1.0]), np.zeros((3, 1)), np.zeros(3))


def test_float_wav_bytes_do_not_depend_on_when_they_were_written(tmp_path):
    """libsndfile stamps a float WAV's PEAK chunk with the current second; the same samples must give
    the same bytes (content hashes find re-imported duplicates), so no PEAK chunk is written."""
    from capture.audio_io import read_audio, write_audio

    audio = Audio(np.linspace(-0.5, 0.5, 1600, dtype=np.float32), 16000)
    write_audio(tmp_path / "a.wav", audio)
    write_audio(tmp_path / "b.wav", audio)
    a, b = (tmp_path / "a.wav").read_bytes(), (tmp_path / "b.wav").read_bytes()
    assert b"PEAK" not in a  # the chunk that holds the time stamp
    assert a == b
    back = read_audio(tmp_path / "a.wav")
    assert back.sample_rate == 16000 and np.array_equal(back.samples[:, 0], audio.samples[:, 0])


def test_safe_id_keeps_long_ids_short_and_apart():
    from capture.take import MAX_ID_BYTES, safe_id

    long_a, long_b = "S" * 300, "S" * 299 + "T"
    assert len(safe_id(long_a).encode()) <= MAX_ID_BYTES and safe_id(long_a) != safe_id(long_b)
    assert len(safe_id("é" * 200).encode()) <= MAX_ID_BYTES  # two bytes per letter in UTF-8
    assert safe_id("Phone A/../x") == "Phone_A_.._x" and safe_id("...") == "take"


def test_a_take_whose_frame_rate_could_not_be_read_back_is_not_written(tmp_path):
    import math

    from capture.take import MAX_FPS

    take = small_take()
    for fps in (0.0, -60.0, math.nan, MAX_FPS * 2):
        take.meta.fps = fps
        with pytest.raises(InputError, match="frame rate"):
            write_take(take, tmp_path)
    assert not any(tmp_path.iterdir())
