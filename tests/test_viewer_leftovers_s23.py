"""``s2a-view`` leftovers: a video's speech is cut, converted, resampled and encoded a block at a time (an
MP4 of a 2 h take held its whole audio span as float32), and an input without jawOpen says which frame
``render`` shows and which channel ``plot`` draws instead of frame 0 and an error about a default."""

from __future__ import annotations

import json
import tracemalloc

import numpy as np
import pytest
import soxr
from conftest import run_here

import viewer.render
from align import resample
from capture import Audio
from viewer.render import OPENING_MOUTH, Animation, Speech, span_blocks, speech_for_video, write_mp4

CSV = "livelinkface/alexdjulin_S07/S07-001.csv"  # jawOpen and mouthFunnel move from its first rows
FRAME = np.zeros((16, 16, 3), np.uint8)


def _speaking(seconds: float, rate: int = 16000, start_s: float = -0.25) -> Animation:
    """Two frames over ``seconds`` with int16 speech from ``start_s`` (take time) to ``seconds``."""
    n = int(round((seconds - start_s) * rate))
    pcm = (9000 * np.sin(np.arange(n) / 3.0) * np.sin(np.arange(n) / 4000.0)).astype(np.int16)
    return Animation(
        "a", 2 / seconds, np.array([0.0, seconds]), np.zeros((2, 61)), Audio(pcm, rate, "PCM_16"), start_s
    )


def _span(anim: Animation, t0: float, seconds: float) -> np.ndarray:
    """``anim``'s speech from take time ``t0`` for ``seconds``, its blocks joined into one array."""
    return np.concatenate(list(span_blocks(anim, t0, seconds).blocks))


def _traced_peak(step) -> int:
    tracemalloc.start()
    try:
        step()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_a_videos_speech_is_encoded_a_block_at_a_time(tmp_path, monkeypatch):
    """The speech of a video was converted to one float32 array of its whole span before it was encoded
    (460 MB for 2 h at 16 kHz): its traced peak grew by that. Now a block is converted as the encoder
    asks for it: the peak does not grow with the speech's length (blocks made small here, so that a few
    seconds hold many of them). The whole-array way, measured the same way, grows by the float copy."""
    monkeypatch.setattr(resample, "_CHUNK", 8192)
    monkeypatch.setattr(viewer.render, "AUDIO_BLOCK", 8192)

    def encode(anim: Animation, seconds: float, held: bool) -> None:
        voice, speech = speech_for_video([anim], seconds)
        if held:
            whole = _span(voice, 0.0, seconds)
            speech = Speech([whole], speech.rate, whole.size)
        write_mp4(tmp_path / f"{seconds}_{held}.mp4", lambda k: FRAME, 2, anim.fps, speech)

    streamed, whole = {}, {}
    for seconds in (1.0, 2.0, 8.0):  # the first one warms up: the modules it imports are no samples
        anim = _speaking(seconds)
        streamed[seconds] = _traced_peak(lambda: encode(anim, seconds, False))  # noqa: B023 (called here)
        whole[seconds] = _traced_peak(lambda: encode(anim, seconds, True))  # noqa: B023
    extra = 6.0 * 16000 * 4  # the float32 samples of 6 s more
    assert whole[8.0] - whole[2.0] > extra / 2, whole  # the measure sees a held span
    assert streamed[8.0] - streamed[2.0] < extra / 4, streamed
    assert (tmp_path / "8.0_False.mp4").read_bytes() == (tmp_path / "8.0_True.mp4").read_bytes()


def test_speech_in_blocks_of_any_size_encodes_to_the_stream_of_one_block(tmp_path):
    """The AAC encoder takes 1024 samples a frame: blocks whose ends fall inside a frame are joined, so
    the file is byte for byte the one of the whole array."""
    rate = 16000
    samples = _span(_speaking(3.0, rate), 0.0, 3.0)
    cuts = [0, 1000, 1001, 7777, 20480, 30000, samples.size]
    blocks = [samples[a:b] for a, b in zip(cuts, cuts[1:])]
    write_mp4(tmp_path / "whole.mp4", lambda k: FRAME, 2, 1.0, Speech([samples], rate, samples.size))
    write_mp4(tmp_path / "blocks.mp4", lambda k: FRAME, 2, 1.0, Speech(blocks, rate, samples.size))
    assert (tmp_path / "blocks.mp4").read_bytes() == (tmp_path / "whole.mp4").read_bytes()


@pytest.mark.parametrize("t0, seconds", [(-1.0, 0.5), (-0.5, 1.0), (0.3, 0.4), (1.5, 1.0), (4.0, 1.0)])
def test_the_span_in_blocks_is_the_cut_of_the_whole_speech_zero_padded(monkeypatch, t0, seconds):
    """Before the speech, across its start, inside it, across its end and after it."""
    monkeypatch.setattr(resample, "_CHUNK", 4096)
    monkeypatch.setattr(viewer.render, "AUDIO_BLOCK", 4096)
    anim = _speaking(2.0, 8000, start_s=0.0)
    whole = np.concatenate([np.zeros(8 * 8000, np.float32), anim.audio.mono_float(), np.zeros(8 * 8000)])
    speech = span_blocks(anim, t0, seconds)
    got = np.concatenate(list(speech.blocks))
    first = 8 * 8000 + int(round(t0 * 8000))
    assert got.dtype == np.float32 and speech.frames == got.size == int(seconds * 8000)
    np.testing.assert_array_equal(got, whole[first : first + got.size])


def test_speech_resampled_for_aac_a_block_at_a_time_is_soxrs_whole_resampling():
    """Speech at a rate AAC does not take (37.8 kHz) was resampled whole; now as its blocks come."""
    from viewer.render import resample_speech

    x = _span(_speaking(3.0, 37800), 0.0, 3.0)
    blocks = [x[i : i + 10_000] for i in range(0, x.size, 10_000)]
    speech = resample_speech(Speech(blocks, 37800, x.size), 44100)
    got = np.concatenate(list(speech.blocks))
    assert speech.rate == 44100 and abs(speech.frames - got.size) <= 1
    assert np.array_equal(got, soxr.resample(x, 37800, 44100, quality="VHQ"))


def _csv_without(samples, folder, column: str, rows: int = 40, still: tuple[str, ...] = ()) -> str:
    """The first ``rows`` frames of the sample CSV without ``column`` (as the app writes one without it);
    the columns in ``still`` held at 0.1 on every frame."""
    with open(samples / CSV, encoding="utf-8") as f:
        lines = [next(f).rstrip("\n").split(",") for _ in range(rows + 1)]
    drop = lines[0].index(column)
    held = [lines[0].index(c) for c in still]
    for row in lines[1:]:
        row[1] = str(int(row[1]) - 1)  # BlendShapeCount
        for j in held:
            row[j] = "0.1"
    folder.mkdir(exist_ok=True)
    path = folder / "take.csv"
    path.write_text("".join(",".join(r[:drop] + r[drop + 1 :]) + "\n" for r in lines), encoding="utf-8")
    return path


def test_render_of_an_input_without_jaw_open_shows_and_names_its_widest_mouth(samples, tmp_path):
    """A CSV without jawOpen rendered frame 0 (a closed face, mid-breath) without a word."""
    from capture import read_livelink_csv

    csv = _csv_without(samples, tmp_path / "t", "JawOpen")
    proc = run_here("viewer", "render", csv, "-o", tmp_path / "f.png", "--size", 32, "--json")
    assert proc.returncode == 0, proc.stderr
    take = read_livelink_csv(csv)
    moving = {c: np.ptp(take.channel(c)) for c in OPENING_MOUTH}  # they move in this take: chosen first
    mouth = max(moving, key=moving.__getitem__)
    k = int(np.argmax(take.channel(mouth)))
    assert k > 0 and json.loads(proc.stdout)["time_s"] == pytest.approx(take.time[k] - take.time[0], abs=1e-6)
    notes = [line for line in proc.stderr.splitlines() if line.startswith("note: ")]
    assert notes == [
        f"note: {csv} holds no jawOpen: frame {k} shown, where {mouth} (the mouth channel that moves most, "
        "lips parting first) is highest; give --frame or --time to pick another"
    ], proc.stderr


def test_plot_of_inputs_without_jaw_open_draws_the_mouth_channel_that_moves_most(samples, tmp_path):
    """``plot``'s default channel missing was an error ("no input holds channel 'jawOpen'") that did not
    say jawOpen was only the default."""
    csv = _csv_without(samples, tmp_path / "t", "JawOpen")
    proc = run_here("viewer", "plot", csv, "-o", tmp_path / "p.png", "--vad", "none", "--json")
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout)
    (mouth,) = s["channels"]
    assert mouth in OPENING_MOUTH
    note = (
        f"no input holds jawOpen, the default channel: plotted {mouth}, the mouth channel that moves most, "
        "lips parting first; give --channels to choose"
    )
    assert s["channel_note"] == note and f"note: {note}" in proc.stderr.splitlines()
    named = run_here("viewer", "plot", csv, "-o", tmp_path / "q.png", "--channels", "jawOpen")
    assert named.returncode == 1 and "no input holds channel 'jawOpen'" in named.stderr  # asked for: an error


def test_plot_of_inputs_without_jaw_open_nor_a_moving_mouth_says_the_default_is_missing(samples, tmp_path):
    with open(samples / CSV, encoding="utf-8") as f:
        names = next(f).strip().split(",")
    mouth = [c for c in names if c.startswith(("Jaw", "Mouth")) and c != "JawOpen"]
    csv = _csv_without(samples, tmp_path / "t", "JawOpen", still=tuple(mouth))
    proc = run_here("viewer", "plot", csv, "-o", tmp_path / "p.png", "--vad", "none")
    assert proc.returncode == 1
    (line,) = proc.stderr.strip().splitlines()
    default = "no input holds jawOpen, the default channel, and no mouth channel of theirs moves"
    assert line.startswith(f"s2a-view: error: {default}: give --channels, "), line
    assert not (tmp_path / "p.png").exists()


def test_the_speech_of_many_channels_with_a_short_last_block_is_cut(monkeypatch):
    """Each block of the span was made a new ``Audio``, which refused a last block of fewer frames than
    channels (over 64 of them) as (channels, samples): the render failed on a valid recording."""
    monkeypatch.setattr(resample, "_CHUNK", 4096)
    monkeypatch.setattr(viewer.render, "AUDIO_BLOCK", 4096)
    x = np.random.default_rng(3).normal(0, 0.1, (4096 + 10, 70)).astype(np.float32)
    anim = Animation("a", 60.0, np.arange(2) / 60, np.zeros((2, 61)), Audio(x, 48000))
    speech = span_blocks(anim, 0.0, 0.2)
    samples = np.concatenate(list(speech.blocks))
    np.testing.assert_array_equal(samples[: x.shape[0]], anim.audio.mono_float())
    assert speech.rate == 48000 and not samples[x.shape[0] :].any()
