"""Review of the live-capture and MP3 changes: inputs the change's own tests did not try (a phone's rate
set back and forth between nearby rates, a stall flushed out of order, two phones with the same warning,
an MP3 cut short with another joined on): real UDP on loopback, real session logs, real files."""

from __future__ import annotations

import numpy as np
import soundfile as sf
from live_helpers import record_packets
from scipy.signal import resample_poly
from test_audio_mp3_later_parts import lag, mp3_bytes

from capture import build_takes, read_audio, read_take
from capture.livelink import frame_block, header_bytes
from capture.session_takes import _undo_steps_back

DEVICE = "5904AA4B-AD9D-43E5-98AB-89AAEB8AB277"


def _packet(frame: int, num: int, den: int, marker: float) -> bytes:
    values = np.linspace(0.1, 0.7, 61, dtype=np.float32)
    values[0] = marker
    return header_bytes(DEVICE, "iPhone") + frame_block(frame, 0.0, num, den, values)


def test_a_rate_set_back_and_forth_between_nearby_rates_is_three_recordings(tmp_path):
    # 30 -> 29.97 -> 30 fps (and 24 -> 25 -> 24): each setting held for 100 packets. Read as one
    # "jittering" rate at the median, the 29.97 frames sat 36 s early in the day at the wrong fps (and
    # 24 -> 25 -> 24 lost 24 frames, the 25 fps ones 1500 s late): each is a recording of its own.
    for rates in ([(30, 1), (30000, 1001), (30, 1)], [(24, 1), (25, 1), (24, 1)]):
        packets = []
        for k, (num, den) in enumerate(rates):
            base = round((36000 + 20 * k) * num / den)  # 10:00:00, 10:00:20, 10:00:40
            packets += [_packet(base + i, num, den, 100 * k + i) for i in range(100)]
        rec = record_packets(tmp_path, f"setting{rates[1][0]}", packets)
        lines = build_takes(rec.session_dir, tmp_path / f"takes{rates[1][0]}")
        assert [line["frames"] for line in lines] == [100, 100, 100], lines
        assert all("rate_jitter_packets" not in line for line in lines)
        takes = [read_take(line["path"]) for line in lines]
        assert [t.meta.extra["rate"] for t in takes] == [list(r) for r in rates]
        starts = [t.meta.csv["start_seconds_of_day"] for t in takes]
        assert np.allclose(starts, [36000, 36020, 36040], atol=0.05), starts


def test_two_phones_with_the_same_warning_each_get_it_said(capsys):
    # The lines were said once in all: the second phone's own clock step went unsaid on the terminal.
    from capture.live_cli import _report

    base = {
        "frames": 100,
        "dropped_frames": 0,
        "rejected": {},
        "clock_steps_back": 1,
        "receive_queue_drops": 7,
    }
    summaries = [
        {**base, "device": "A", "subject": "iPhone", "path": "a"},
        {**base, "device": "A", "subject": "iPhone", "path": "a2"},  # a second take of the same stream
        {**base, "device": "B", "subject": "iPhone", "path": "b"},
    ]
    for as_json in (False, True):
        _report(summaries, as_json)
        err = capsys.readouterr().err
        # a take's own count (session_takes.TAKE_COUNTS): said for each take, a2's too (s23)
        assert err.count("clock stepped back 1 time(s)") == 3, err
        assert err.count("7 datagrams reached this computer") == 1, err  # the session's: once


def test_a_stall_the_network_flushes_out_of_order_is_no_step_back():
    # 1.5 s of packets held back, then delivered at once in any order (several queues of a Wi-Fi link):
    # the fastest packet's lateness rises for the flush only, and the frame times go back within it. Read
    # as a step back, every frame after it was moved 0.1 s late (5 in 80 recordings before).
    def steps(seed: int, fps: int) -> list:
        rng = np.random.default_rng(seed)
        sent = np.arange(30 * fps) / fps
        arrival = sent + rng.exponential(0.005, sent.size)
        held = np.flatnonzero((sent >= 10) & (sent < 11.5))
        arrival[held] = 11.5 + rng.permutation(held.size) * 1e-4
        order = np.argsort(arrival, kind="stable")
        return _undo_steps_back(sent[order], arrival[order], 1 / fps)[1]

    assert not [(seed, fps) for seed in range(40) for fps in (30, 60) if steps(seed, fps)]
    # a real step back 1 s before such a flush is still found and sized
    rng = np.random.default_rng(3)
    sent = np.arange(1800) / 60
    frame_time = np.where(sent >= 9, sent - 0.5, sent)
    arrival = sent + rng.exponential(0.005, sent.size)
    held = np.flatnonzero((sent >= 20) & (sent < 21.5))
    arrival[held] = 21.5 + rng.permutation(held.size) * 1e-4
    order = np.argsort(arrival, kind="stable")
    (step,) = _undo_steps_back(frame_time[order], arrival[order], 1 / 60)[1]
    assert abs(step[1] - 0.5) < 0.02 and abs(step[2] - 8.5) < 0.05, step


def test_an_mp3_cut_short_then_joined_loses_no_sound_at_its_count(tmp_path, samples):
    # A LAME file (Info frame: its frame and byte counts) cut mid-frame, another LAME file joined after
    # it: the cut file runs on into the second's frames and is split from them where its frame count ends,
    # mid-sound, at a frame whose sound starts in its own bytes (320 kbit/s). Taken for a bare LAME file's
    # first frame, 1105 samples of the second file's sound were dropped there: its end came early.
    x, rate = sf.read(
        str(samples / "paired" / "facegood-audio2face" / "wav" / "1114_2_02.wav"), dtype="float32"
    )
    signal = resample_poly(x[: rate * 3] if x.ndim == 1 else x[: rate * 3, 0], 48000, rate).astype(np.float32)
    whole = mp3_bytes(signal, 48000, 1, 320000)
    path = tmp_path / "cut_then_joined.mp3"
    path.write_bytes(whole[: len(whole) * 2 // 3] + whole)
    got = read_audio(path).samples
    got = got if got.ndim == 1 else got[:, 0]
    tail = got[len(got) - signal.size - 2000 :]
    assert lag(signal, tail, 5000) - 2000 in (-1, 0, 1)  # the second file whole, to its last sample
