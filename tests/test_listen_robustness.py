"""Hostile or odd streams and a hostile environment: implausible rates, sub-frame tricks, a take that
cannot be built, colliding take names, a restarted frame counter, a full disk, an unwritable output
folder, a missing audio file and bad options. Never a traceback, never the loss of what arrived."""

from __future__ import annotations

import json
import resource
import signal
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from live_helpers import record_packets, run_cli, start_recorder

import capture.livelink as ll
import capture.session_takes as st
from capture import FrameStatus, LiveRecorder, build_takes, read_take
from capture.errors import InputError
from capture.livelink import frame_block, header_bytes

VALS = np.linspace(-0.5, 1.0, 61).astype(np.float32)


def _packets(device: str, subject: str, frames, num: int = 60, sub_frames=None, values=VALS) -> list[bytes]:
    head = header_bytes(device, subject)
    sub_frames = [0.0] * len(frames) if sub_frames is None else sub_frames
    return [head + frame_block(int(f), float(s), num, 1, values) for f, s in zip(frames, sub_frames)]


def _by_name(lines) -> dict[str, dict]:
    return {line["path"].rsplit("/", 1)[1]: line for line in lines if line["path"]}


# -- 1. what a stream can make the take builder allocate -----------------------------------------------
HOSTILE_FRAMES = [*range(20), *range(200_000, 200_020)]  # at 20 MHz: 0.01 s apart, 200k frame periods


def test_implausible_rate_is_rejected_on_arrival(tmp_path):
    packets = _packets("HOSTILE", "x", HOSTILE_FRAMES, num=20_000_000)
    packets += _packets("HOSTILE2", "x", range(20), num=0) + _packets("GOOD", "iPhone", range(100, 130))
    rec = record_packets(tmp_path, "r", packets)
    assert rec.rejected["bad_rate"] == 60 and rec.accepted == 30
    lines = build_takes(rec.session_dir, tmp_path)
    assert list(_by_name(lines)) == ["r_iPhone_GOOD"] and lines[0]["frames"] == 30


def test_recover_of_an_old_log_with_an_implausible_rate(tmp_path, monkeypatch):
    # A log written before the recorder bounded the rate: the builder drops those frames itself.
    monkeypatch.setattr(ll, "MAX_RATE_FPS", 10**9)
    rec = record_packets(tmp_path, "old", _packets("HOSTILE", "x", HOSTILE_FRAMES, num=20_000_000))
    monkeypatch.undo()
    rec2 = record_packets(tmp_path, "old2", _packets("GOOD", "iPhone", range(100, 130)))
    assert rec.accepted == 40 and rec2.accepted == 30
    r = run_cli("recover", str(tmp_path), "--json")
    assert r.returncode == 0, r.stderr
    lines = [json.loads(x) for x in r.stdout.splitlines()]
    assert [line["path"] for line in lines][0] is None and lines[0]["stray_streams"] == 1
    assert lines[1]["path"].endswith("old2_iPhone_GOOD") and lines[1]["frames"] == 30


def test_sub_frames_cannot_make_the_gaps_huge(tmp_path):
    # Sub-frames 0.999, 0.0, 0.999... make most frame-time steps 0.001 frames: the median frame period
    # (the fill's step) is then 1/60000 s, and one 2 s gap alone would take 120,000 DROPPED frames.
    frames = [*range(22), *range(142, 164)]
    subs = [0.999 if i % 2 == 0 else 0.0 for i in range(len(frames))]
    rec = record_packets(tmp_path, "sf", _packets("TRICK", "iPhone", frames, sub_frames=subs))
    (line,) = build_takes(rec.session_dir, tmp_path)
    take = read_take(line["path"])  # readable: the take keeps the stream's declared 60 fps
    assert take.meta.fps == 60.0 and line["frames"] - line["dropped_frames"] == 44
    assert line["dropped_frames"] <= st.MAX_DROPPED_PER_FRAME * 44 + st.MAX_GAP_S * 60
    # An ordinary lossy stream is still filled.
    rec = record_packets(tmp_path, "ok", _packets("LOSSY", "iPhone", [f for f in range(100, 400) if f % 3]))
    (line,) = build_takes(rec.session_dir, tmp_path)
    assert line["frames"] == 299 and line["dropped_frames"] == 99


def test_a_take_that_cannot_be_built_does_not_lose_the_others(tmp_path, monkeypatch):
    packets = _packets("BAD", "iPhone", range(100, 130), values=VALS + 7) + _packets(
        "GOOD", "iPhone", range(30)
    )
    rec = record_packets(tmp_path, "m", packets)
    fill = st.fill_dropped

    def fill_or_fail(t, values, status, period):
        if values[0, 0] > 5:
            raise MemoryError("Unable to allocate 18.2 GiB for an array")
        return fill(t, values, status, period)

    monkeypatch.setattr(st, "fill_dropped", fill_or_fail)
    lines = build_takes(rec.session_dir, tmp_path)
    assert list(_by_name(lines)) == ["m_iPhone_GOOD"]
    (failed,) = [x for x in lines if x.get("error")]
    assert failed["device"] == "BAD" and "18.2 GiB" in failed["error"] and "\n" not in failed["error"]
    assert not (rec.session_dir / "complete.json").exists()  # recover retries the missing take


# -- 2. take folder names that collide ------------------------------------------------------------------
def test_colliding_take_names_never_overwrite(tmp_path):
    packets = _packets("ABCDEFGH-1111", "Phone A", range(30)) + _packets(
        "ABCDEFGH-2222", "Phone_A", range(40)
    )
    packets += _packets("ABCDEFGH-3333", "Phone A", range(50), values=VALS + 1)
    lines = build_takes(record_packets(tmp_path, "c", packets).session_dir, tmp_path)
    got = {name: read_take(x["path"]) for name, x in _by_name(lines).items()}
    assert {n: (t.meta.device, t.time.size) for n, t in got.items()} == {
        "c_Phone_A_ABCDEFGH": ("ABCDEFGH-1111", 30),
        "c_Phone_A_ABCDEFGH-2": ("ABCDEFGH-2222", 40),
        "c_Phone_A_ABCDEFGH-3": ("ABCDEFGH-3333", 50),
    }
    # Rebuilding the session gives the same names (its own takes are replaced, nobody else's).
    again = build_takes(tmp_path / "c.recording", tmp_path)
    assert sorted(_by_name(again)) == sorted(got)


# -- 3. a frame counter that restarts lower ---------------------------------------------------------------
def test_restarted_frame_counter_starts_a_new_take(tmp_path):
    first = list(range(5000, 5200))
    first[150], first[151] = first[151], first[150]  # ordinary reordering
    first.insert(100, 5090)  # an ordinary duplicate
    late = [5120]  # one packet more than the restart window late: not a restart
    packets = _packets("DEV", "iPhone", first[:140] + late + first[140:])
    packets += _packets("DEV", "iPhone", range(10, 310), values=VALS + 1)  # the app restarted
    lines = build_takes(record_packets(tmp_path, "rs", packets).session_dir, tmp_path)
    one, two = (read_take(x["path"]) for x in lines)
    assert [x["path"].rsplit("/", 1)[1] for x in lines] == ["rs_iPhone_DEV_1", "rs_iPhone_DEV_2"]
    assert (
        one.time.size == 200
        and one.meta.extra["first_frame_number"] == 5000
        and one.count(FrameStatus.DROPPED) == 0
    )
    assert two.time.size == 300 and two.meta.extra["first_frame_number"] == 10
    assert np.array_equal(two.values[0], VALS + 1) and np.array_equal(one.values[-1], VALS)
    assert lines[0]["restarts"] == 1 and lines[0]["duplicates"] == 2 and lines[0]["out_of_order"] == 3


# -- 4. a full disk, an unwritable output folder ------------------------------------------------------------
def _limit_file_size(limit: int):
    # Writes past ``limit`` bytes in any one file fail (EFBIG): a full disk for the files that grow.
    return lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))


def test_full_disk_while_recording_is_a_warning_then_one_error(tmp_path):
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "capture", "listen", "-o", str(out), "--port", "0", "--duration", "60"]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True, preexec_fn=_limit_file_size(30_000))
    port = int(proc.stderr.readline().split("udp://127.0.0.1:")[1].split(" ")[0])
    # Steps 1, 1, 9: the take gets 8 DROPPED frames per 3 received, so it is larger than its log.
    frames = [f for f in range(1000, 1000 + 11 * 200) if f % 11 in (0, 1, 2)]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for p in _packets("FULLDISK", "iPhone", frames):
            s.sendto(p, ("127.0.0.1", port))
            time.sleep(0.001)
    time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    lines = err.splitlines()
    assert proc.returncode == 1 and "Traceback" not in err, err
    assert sum(x.startswith("s2a-capture: warning: cannot write the log") for x in lines) == 1, err
    session = next(out.glob("*.recording"))
    assert lines[-1].startswith(f"s2a-capture: error: {session}: writing the recorder log failed"), err
    assert "1 take(s) not written" in lines[-1]
    # Once there is room, recover builds the take from everything that reached the log.
    r = run_cli("recover", str(out), "--json")
    assert r.returncode == 0, r.stderr
    (line,) = [json.loads(x) for x in r.stdout.splitlines()]
    assert 50 < line["valid_frames"] < len(frames) and "torn_tail" in line


def test_unwritable_output_folder_is_one_line(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    r = run_cli("listen", "-o", str(blocker), "--port", "0", "--duration", "1")
    assert r.returncode == 1 and "Traceback" not in r.stderr and len(r.stderr.splitlines()) == 1, r.stderr
    assert r.stderr.startswith(f"s2a-capture: error: {blocker}/") and "session log" in r.stderr
    rec = record_packets(
        tmp_path, "w", _packets("A", "iPhone", range(30)) + _packets("B", "iPhone", range(30))
    )
    r = run_cli("recover", str(rec.session_dir), "-o", str(blocker / "takes"))
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    takes = [x for x in r.stderr.splitlines() if x.startswith(("A / iPhone: ", "B / iPhone: "))]
    assert len(takes) == 2 and all(str(blocker) in x for x in takes), r.stderr
    assert (
        r.stderr.splitlines()[-1]
        == f"s2a-capture: error: {rec.session_dir}: 2 take(s) not written to {blocker / 'takes'}"
    )
    r = run_cli("recover", str(rec.session_dir), "-o", str(tmp_path / "ok"))  # nothing was lost
    assert r.returncode == 0 and len(list((tmp_path / "ok").iterdir())) == 2, r.stderr


# -- 5. the audio file ---------------------------------------------------------------------------------------
def test_missing_audio_file_is_never_silent(tmp_path):
    r = run_cli(
        "listen",
        "-o",
        str(tmp_path),
        "--audio-file",
        str(tmp_path / "no-such-folder" / "x.wav"),
        "--audio-start",
        "first-packet",
    )
    assert r.returncode == 1 and "not found" in r.stderr and len(r.stderr.splitlines()) == 1, r.stderr
    assert not list(tmp_path.iterdir())
    r = run_cli("listen", "-o", str(tmp_path), "--audio-file", str(tmp_path), "--audio-start", "first-packet")
    assert r.returncode == 1 and "folder" in r.stderr and len(r.stderr.splitlines()) == 1, r.stderr
    # Still missing when the first packet arrives: a warning then, the take, and one error at the end.
    wav = tmp_path / "never.wav"
    cmd = [sys.executable, "-m", "capture", "listen", "-o", str(tmp_path / "out"), "--port", "0"]
    cmd += ["--duration", "60", "--json", "--audio-file", str(wav), "--audio-start", "first-packet"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stderr.readline().startswith(f"s2a-capture: warning: {wav} does not exist yet")
    port = int(proc.stderr.readline().split("udp://127.0.0.1:")[1].split(" ")[0])
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for p in _packets("A", "iPhone", range(30)):
            s.sendto(p, ("127.0.0.1", port))
    assert proc.stderr.readline().startswith("s2a-capture: warning: ")  # at the first packet, while recording
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 1 and "Traceback" not in err
    assert err.splitlines()[-1].startswith("s2a-capture: error: ") and "no audio was recorded" in err
    assert json.loads(out)["frames"] == 30


# -- 6. options --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("duration", ["nan", "inf", "-1", "1e300"])
def test_bad_duration_is_one_line_before_anything_is_made(tmp_path, duration):
    r = run_cli("listen", "-o", str(tmp_path / "out"), "--port", "0", "--duration", duration)
    assert r.returncode == 1 and "--duration" in r.stderr and len(r.stderr.splitlines()) == 1, r.stderr
    assert not (tmp_path / "out").exists()


# -- 7. stray packets do not lock a phone out -------------------------------------------------------------
def test_stray_streams_give_their_slots_to_a_real_phone(tmp_path, monkeypatch):
    import capture.recorder as recorder

    monkeypatch.setattr(recorder, "STRAY_SILENT_S", 0.2)
    rec, port, runner = start_recorder(tmp_path, "stray", max_streams=8)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for i in range(8):  # eight spoofed devices, one packet each: every slot taken
            s.sendto(_packets(f"junk-{i}", "x", [1])[0], ("127.0.0.1", port))
        time.sleep(0.4)  # they fall silent
        for p in _packets("REALPHONE-0001", "Ana", range(300)):
            s.sendto(p, ("127.0.0.1", port))
            time.sleep(0.0005)
    time.sleep(0.5)
    rec.request_stop()
    runner.join()
    rec.close()
    assert rec.evicted_streams == 8 and rec.rejected["too_many_streams"] == 0
    assert rec.stream_packets[-1] == 300  # the phone's stream, after the eight stray ones
    (line,) = [x for x in build_takes(rec.session_dir, tmp_path / "takes") if x["path"]]
    assert line["frames"] == 300 and line["subject"] == "Ana"
    # a stream that keeps sending is never evicted: with every slot busy, a new one is refused
    rec2 = LiveRecorder(tmp_path / "busy", port=0, session_id="busy", max_streams=1)
    _, port = rec2.open()
    runner = threading.Thread(target=rec2.run, kwargs={"duration_s": 30})
    runner.start()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for f in range(40):
            s.sendto(_packets("PHONE-A", "a", [f])[0], ("127.0.0.1", port))
            s.sendto(_packets("PHONE-B", "b", [f])[0], ("127.0.0.1", port))
            time.sleep(0.01)
    time.sleep(0.3)
    rec2.request_stop()
    runner.join()
    rec2.close()
    assert rec2.evicted_streams == 0 and rec2.rejected["too_many_streams"] == 40


def test_stream_ids_running_out_refuse_new_streams_instead_of_crashing(tmp_path, monkeypatch):
    import capture.recorder as recorder

    with pytest.raises(InputError, match="max_streams"):
        LiveRecorder(tmp_path, port=0, max_streams=0)
    # ids are 16-bit and never reused; make them scarce: 3 ids. The fourth stream evicts the three
    # stray ones, which frees slots but no ids.
    monkeypatch.setattr(recorder, "MAX_STREAMS", 3)
    monkeypatch.setattr(recorder, "STRAY_SILENT_S", 0.0)
    rec, port, runner = start_recorder(tmp_path, "ids", max_streams=3)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for i in range(5):
            s.sendto(_packets(f"junk-{i}", "x", [1])[0], ("127.0.0.1", port))
            time.sleep(0.02)
    time.sleep(0.3)
    rec.request_stop()
    runner.join()
    rec.close()
    assert len(rec.stream_packets) == 3 and rec.rejected["too_many_streams"] == 2
    build_takes(rec.session_dir, tmp_path / "takes")  # the log stays readable


# -- frame clocks that say nothing about time (other senders) ---------------------------------------------
def _pylivelinkface_frame(t: float, fps: int = 60) -> int:
    """The frame number PyLiveLinkFace sends for wall time ``t`` (s): its timecode library is fed
    hours:minutes:seconds:milliseconds, so milliseconds count as frames, 1-based."""
    whole = int(t)
    return whole * fps + int(round((t - whole) * 1000)) + 1


@pytest.mark.parametrize(
    "sender, fps", [("pylivelinkface", 60), ("pylivelinkface", 30), ("frozen", 60), ("countdown", 60)]
)
def test_a_sender_without_a_usable_frame_clock_is_placed_by_arrival(tmp_path, sender, fps):
    # PyLiveLinkFace's clock jumps back once a second: 5 s gives 5 jumps; the others betray themselves
    # on every packet, so 2 s (paced in real time) show it
    seconds = 5 if sender == "pylivelinkface" else 2
    n = seconds * fps
    den = fps // 60  # PyLiveLinkFace sends int(fps / 60): 0 at 30 fps
    if sender == "pylivelinkface":
        frames = [_pylivelinkface_frame(3600.0 + 0.25 + i / fps, fps) for i in range(n)]
        subs = [0.4730] * n  # its constant sub-frame
    elif sender == "frozen":  # a sender that never sets the frame number
        frames, subs = [0] * n, [0.0] * n
    else:  # one that counts down
        frames, subs = list(range(100_000, 100_000 - n, -1)), [0.0] * n
    values = [VALS + i / 1000 for i in range(n)]
    head = header_bytes("$" + "A" * 35, "Player")
    packets = [head + frame_block(f, s, fps, den, v) for f, s, v in zip(frames, subs, values)]
    rec = record_packets(tmp_path, f"{sender}{fps}", packets, rate=float(fps))
    assert rec.accepted == n
    (line,) = build_takes(rec.session_dir, tmp_path)
    assert line["frame_clock"]["placed_by"] == "arrival", line
    take = read_take(line["path"])
    assert take.meta.extra["frame_clock"] == line["frame_clock"]
    assert any(r["kind"] == "frame_clock" for r in take.meta.repairs)
    assert take.meta.fps == fps and line["restarts"] == 0 and line["duplicates"] == 0
    tracked = take.frame_status == FrameStatus.TRACKED
    assert tracked.sum() == n  # every packet is a frame, in the order sent
    np.testing.assert_allclose(take.values[tracked, 0], [v[0] for v in values], atol=1e-6)
    assert 0.9 * seconds < take.duration_s < seconds + 0.6  # real time, not 16x (ms as frames) or 0


def test_a_phone_clock_is_kept_however_fast_the_packets_come(tmp_path):
    """Replays faster than real time and a restart keep the phone's frame clock."""
    packets = _packets("DEV", "iPhone", range(1000, 1300)) + _packets("DEV", "iPhone", range(5, 300))
    lines = build_takes(record_packets(tmp_path, "fast", packets).session_dir, tmp_path)
    assert len(lines) == 2 and all("frame_clock" not in x for x in lines)
    assert [read_take(x["path"]).time.size for x in lines] == [300, 295]


def test_no_take_line_says_what_the_rejections_mean(tmp_path):
    """A phone in MetaHuman Animator mode (little-endian u16 version 1 packets, §5.6): no take, and the
    listener says which app setting to change."""
    cmd = [sys.executable, "-m", "capture", "listen", "-o", str(tmp_path), "--port", "0", "--duration", "3"]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    port = int(proc.stderr.readline().split("udp://127.0.0.1:")[1].split(" ")[0])
    subject = b"iPhone"
    mha = (1).to_bytes(2, "little") + len(subject).to_bytes(2, "little") + subject + bytes(1200)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for _ in range(20):
            s.sendto(mha, ("127.0.0.1", port))
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0 and "Traceback" not in err, err
    assert "no take recorded; rejected datagrams: {'version': 20}" in err
    assert "set the app to Live Link (ARKit)" in err
