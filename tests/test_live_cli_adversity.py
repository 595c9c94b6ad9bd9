"""listen / recover / remote / replay against what goes wrong around them: recover run on a session
that is still recording, a terminal that closes, a sync box that is unplugged, arguments OSC cannot
carry, options that make no sense. Real loopback sockets and real subprocesses throughout."""

from __future__ import annotations

import json
import os
import pty
import queue
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from live_helpers import Listener, run_cli, synthetic_take, wait_for_logged_frames
from test_osc_remote import FakePhone

from capture import InputError, read_take, write_take
from capture.cli import main as capture_main
from capture.livelink import frame_block, header_bytes
from capture.osc_remote import PhoneRemote
from capture.record_log import LogWriter, RecordType, json_record
from capture.session_takes import build_takes

DEVICE = "ADVERSITY-DEVICE"
VALUES = [0.25] * 61


def _send(port: int, numbers, host: str = "127.0.0.1", family: int = socket.AF_INET) -> None:
    header = header_bytes(DEVICE, "iPhone")
    with socket.socket(family, socket.SOCK_DGRAM) as s:
        for i, n in enumerate(numbers):
            s.sendto(header + frame_block(n, 0.0, 60, 1, VALUES), (host, port))
            if i % 50 == 49:
                time.sleep(0.005)  # pace: loopback drops what the receive queue cannot hold


def _takes(out: Path) -> list[str]:
    return sorted(p.name for p in out.iterdir() if not p.name.endswith(".recording"))


def _json_lines(text: str) -> list[dict]:
    return [json.loads(x) for x in text.splitlines() if x.strip()]


def _stderr_lines(proc: subprocess.Popen) -> queue.Queue:
    """The process's stderr lines as they come (a reader thread), so a test can wait for one."""
    lines: queue.Queue = queue.Queue()

    def read() -> None:
        for line in proc.stderr:
            lines.put(line)
        lines.put(None)

    threading.Thread(target=read, daemon=True).start()
    return lines


def _wait_for_line(lines: queue.Queue, text: str, timeout: float = 10.0) -> str:
    deadline = time.monotonic() + timeout
    seen = []
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=max(0.01, deadline - time.monotonic()))
        except queue.Empty:
            break
        if line is None:
            break
        seen.append(line)
        if text in line:
            return line
    raise AssertionError(f"no line with {text!r} on stderr: {''.join(seen)}")


# -- recover and a session that is still recording ---------------------------------------------------------
def test_recover_leaves_a_session_that_is_still_recording_alone(tmp_path):
    out = tmp_path / "out"
    listener = Listener(out)
    try:
        _send(listener.port, range(1000, 1060))
        wait_for_logged_frames(listener.session_dir, 60)
        for extra in ([], ["--all"]):
            r = run_cli("recover", str(out), "--json", *extra)
            assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
            (line,) = _json_lines(r.stdout)
            assert line["skipped"] is True and line["path"] is None, line
            assert line["session"] == str(listener.session_dir)
            assert f"process {listener.proc.pid} on {socket.gethostname()}" in line["reason"]
            assert f"skipping {listener.session_dir}: still being recorded" in r.stderr
        assert not (listener.session_dir / "complete.json").exists() and _takes(out) == []
        _send(listener.port, range(1060, 1120))
        wait_for_logged_frames(listener.session_dir, 120)
    finally:
        listener.kill()  # the crash after which recover must still find the session
    r = run_cli("recover", str(out), "--json")
    assert r.returncode == 0, r.stderr
    (line,) = _json_lines(r.stdout)
    assert line["recovered"] is True and line["frames"] == 120 and line["valid_frames"] == 120


def _session_folder(path: Path, pid: int, wall_origin_ns: int) -> None:
    """A session folder as a recorder without the lock (an older listen, LiveRecorder used directly)
    leaves it: only a SESSION record naming its process."""
    path.mkdir(parents=True)
    log = LogWriter(path / "frames.log")
    session = {"session": path.stem, "clock": {"origin_ns": 0, "wall_origin_ns": wall_origin_ns}}
    log.put(json_record(RecordType.SESSION, session | {"pid": pid, "host": socket.gethostname()}))
    log.close()


def test_recover_without_a_lock_goes_by_the_recorders_pid_and_start_time(tmp_path):
    # This test process plays a recorder that is still running: alive, started before its session.
    _session_folder(tmp_path / "live-a.recording", os.getpid(), time.time_ns())
    # A process that got a dead recorder's pid: alive, but started after the session.
    newcomer = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        time.sleep(0.05)
        _session_folder(tmp_path / "live-b.recording", newcomer.pid, time.time_ns() - 60 * 10**9)
        r = run_cli("recover", str(tmp_path), "--json")
    finally:
        newcomer.kill()
        newcomer.wait()
    assert r.returncode == 0, r.stderr
    lines = {Path(x["session"]).name if x.get("skipped") else x["session"]: x for x in _json_lines(r.stdout)}
    assert lines["live-a.recording"]["skipped"] is True
    assert lines["live-b"]["recovered"] is True and "skipped" not in lines["live-b"]
    assert not (tmp_path / "live-a.recording" / "complete.json").exists()
    assert (tmp_path / "live-b.recording" / "complete.json").exists()


def test_a_partial_take_an_earlier_recover_wrote_is_replaced(tmp_path):
    out = tmp_path / "out"
    listener = Listener(out)
    _send(listener.port, range(1000, 1100))
    time.sleep(0.4)
    # What a recover that did not see the lock wrote (an older version, a network file system).
    partial = build_takes(listener.session_dir, out, recovered=True)
    assert [s["frames"] for s in partial] == [100] and Path(partial[0]["path"]).is_dir()
    _send(listener.port, range(1100, 1200))
    _send(listener.port, range(10, 210))  # the app restarted: the session now makes two takes
    time.sleep(0.4)
    lines, err, code = listener.stop()
    assert code == 0, err
    assert [(Path(s["path"]).name[-2:], s["frames"]) for s in lines] == [("_1", 200), ("_2", 200)]
    assert _takes(out) == sorted(Path(s["path"]).name for s in lines)  # no frame in two takes
    assert lines[0]["removed_partial_takes"] == [partial[0]["path"]]
    assert f"removed {partial[0]['path']}: a partial take" in err


# -- signals ------------------------------------------------------------------------------------------------
def test_sighup_from_a_closed_terminal_stops_cleanly(tmp_path):
    """ssh or the terminal window closes: stderr is a terminal that is gone, then SIGHUP comes."""
    master, slave = pty.openpty()
    cmd = [sys.executable, "-m", "capture", "listen", "-o", str(tmp_path / "out"), "--port", "0"]
    proc = subprocess.Popen(
        [*cmd, "--duration", "60", "--json"],
        stdout=subprocess.PIPE,
        stderr=slave,
        text=True,
        # as from a terminal: a suite run under nohup would pass SIGHUP ignored, which listen keeps so
        preexec_fn=lambda: signal.signal(signal.SIGHUP, signal.SIG_DFL),
    )
    os.close(slave)
    try:
        start = b""
        while b"\n" not in start:
            start += os.read(master, 1024)
        port = int(start.split(b"udp://127.0.0.1:")[1].split(b" ")[0])
        _send(port, range(1000, 1090))
        time.sleep(0.4)
    finally:
        os.close(master)  # writes to the terminal now fail (EIO)
    proc.send_signal(signal.SIGHUP)
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 0
    (line,) = _json_lines(out)
    assert line["frames"] == 90 and line["clean_end"] is True


def test_sighup_under_nohup_keeps_recording(tmp_path):
    cmd = [sys.executable, "-m", "capture", "listen", "-o", str(tmp_path / "out"), "--port", "0"]
    proc = subprocess.Popen(
        [*cmd, "--duration", "60", "--json"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGHUP, signal.SIG_IGN),
    )
    port = int(proc.stderr.readline().split("udp://127.0.0.1:")[1].split(" ")[0])
    proc.send_signal(signal.SIGHUP)
    _send(port, range(1000, 1030))
    time.sleep(0.4)
    assert proc.poll() is None
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert _json_lines(out)[0]["frames"] == 30


# -- the serial sync box ------------------------------------------------------------------------------------
def test_an_unplugged_sync_box_is_a_warning_at_once_and_keeps_its_events(tmp_path):
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    server.settimeout(20)
    go, unplug = threading.Event(), threading.Event()

    def sync_box():
        conn, _ = server.accept()
        with conn:
            go.wait(20)  # not at once: opening a socket:// port discards what is already there
            conn.sendall(b"CLAP\nMARK cut off mid-")
            unplug.wait(20)

    threading.Thread(target=sync_box, daemon=True).start()
    cmd = [sys.executable, "-m", "capture", "listen", "-o", str(tmp_path / "out"), "--port", "0"]
    cmd += ["--duration", "60", "--serial", f"socket://127.0.0.1:{server.getsockname()[1]}"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # text mode
    lines = _stderr_lines(proc)
    try:
        port = int(_wait_for_line(lines, "udp://").split("udp://127.0.0.1:")[1].split(" ")[0])
        go.set()
        _send(port, range(1000, 1030))
        time.sleep(0.3)
        unplug.set()
        warning = _wait_for_line(lines, "warning: serial port failed")  # while still recording
        assert "recording goes on" in warning and proc.poll() is None
        _send(port, range(1030, 1060))
        time.sleep(0.3)
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)
    finally:
        server.close()
        if proc.poll() is None:
            proc.kill()
    rest = []
    while (line := lines.get(timeout=10)) is not None:
        rest.append(line)
    # Exit 0: frames (and audio) are complete; the warning is repeated under the take.
    assert proc.returncode == 0, "".join(rest)
    assert any(x.startswith("  warning: serial port failed") for x in rest), rest
    take = read_take(next(p for p in (tmp_path / "out").iterdir() if not p.name.endswith(".recording")))
    events = take.meta.extra["sync_events"]
    # the line the box had not ended when it was unplugged is kept too
    assert [e["text"] for e in events] == ["CLAP", "MARK cut off mid-"] and take.time.size == 60, rest


# -- options ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("option", "value"),
    [
        ("--max-streams", "0"),
        ("--max-streams", "-1"),
        ("--max-streams", "65537"),
        ("--bind", ""),
        ("--bind", " "),
        ("--flush-interval", "0.5"),
        ("--flush-interval", "0"),
        ("--flush-interval", "nan"),
    ],
)
def test_options_that_make_no_sense_are_usage_errors(tmp_path, capsys, option, value):
    with pytest.raises(SystemExit) as exit_:
        capture_main(["listen", "-o", str(tmp_path / "out"), "--port", "0", "--duration", "1", option, value])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {option}:" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_an_audio_file_that_is_a_device_says_so(tmp_path, capsys):
    assert capture_main(["listen", "-o", str(tmp_path / "x"), "--audio-file", os.devnull]) == 1
    err = capsys.readouterr().err
    assert "not a regular file" in err and len(err.splitlines()) == 1 and not (tmp_path / "x").exists()


def test_first_packet_audio_is_never_opened_without_a_packet_and_ipv6_is_bracketed(tmp_path):
    # The file is no audio: opening it at the stop would fail.
    junk = tmp_path / "junk.wav"
    junk.write_text("not audio")
    args = ["-o", str(tmp_path / "out"), "--bind", "::1", "--port", "0", "--duration", "0.3", "--json"]
    r = run_cli("listen", *args, "--audio-file", str(junk), "--audio-start", "first-packet")
    assert r.returncode == 0, r.stderr
    assert r.stderr.startswith("listening on udp://[::1]:")


def test_replay_names_an_ipv6_destination_as_written(tmp_path, capsys):
    folder = write_take(synthetic_take(20, seed=3), tmp_path / "takes")
    with socket.socket(socket.AF_INET6, socket.SOCK_DGRAM) as sink:
        sink.bind(("::1", 0))
        port = sink.getsockname()[1]
        assert capture_main(["replay", str(folder), "--to", f"[::1]:{port}", "--speed", "100", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["to"] == f"[::1]:{port}"


# -- remote -------------------------------------------------------------------------------------------------
@pytest.fixture
def phone():
    p = FakePhone()
    yield p
    p.close()


def test_remote_checks_every_argument_before_sending_anything(phone):
    where = f"127.0.0.1:{phone.port}".encode()
    for args, text in [
        ([b"record-start", b"\xe9t\xe9", b"1"], "the slate b'\\xe9t\\xe9' is not UTF-8"),
        ([b"subject", b"Ren\xe9"], "the subject name b'Ren\\xe9' is not UTF-8"),
        ([b"target", b"h\xf4te:11111"], "the Live Link target b'h\\xf4te' is not UTF-8"),
        ([b"target", b"no-such-host.invalid:11111"], "cannot resolve the Live Link target"),
        ([b"record-start", b"S", b"99999999999"], "take number must be an integer in 0..2147483647"),
        ([b"record-start", b"S", b"-5"], "take number must be an integer in 0..2147483647"),
        ([b"subject", b""], "the subject name is empty"),
    ]:
        cmd = [sys.executable.encode(), b"-m", b"capture", b"remote", where, b"--timeout", b"2", *args]
        r = subprocess.run(cmd, capture_output=True, timeout=60)
        err = r.stderr.decode("utf-8", "replace")
        assert r.returncode == 1 and "Traceback" not in err and len(err.splitlines()) == 1, (args, err)
        assert text in err, (args, err)
    time.sleep(0.2)
    assert phone.received == []  # in particular no /ClearAllLiveLinkAddresses for a bad target


class OddPhone(FakePhone):
    """Answers with the types formats doc §6 does not give: a bool battery, a fractional thermal
    state, a blob where the stop's timecode belongs."""

    def __init__(self, battery, thermals, stop):
        super().__init__(battery=battery, thermals=thermals)
        self.stop_reply = stop

    def _any(self, address, *args):
        if address == "/RecordStop" and self.reply is not None:
            self.received.append((address, *args))
            self.reply.send_message("/RecordStopConfirm", self.stop_reply)
            return
        super()._any(address, *args)


def test_replies_of_the_wrong_type_are_errors_and_take_numbers_go_as_int32():
    phone = OddPhone(True, 2.7, [b"\x00\xff", 3, 2.5])
    try:
        with PhoneRemote("127.0.0.1", phone.port, timeout_s=5) as remote:
            with pytest.raises(InputError, match="/Battery True"):
                remote.battery()
            with pytest.raises(InputError, match=r"/Thermals 2\.7"):
                remote.thermals()
            with pytest.raises(InputError, match=r"/RecordStopConfirm b'\\x00\\xff' 3 2\.5 \(the phone did"):
                remote.record_stop()
            with pytest.raises(InputError, match="take number"):
                remote.record_start("S", 2**31)
            assert b",si\x00" in remote.message("/RecordStart", "S", 7)  # 'i', as the app reads it
    finally:
        phone.close()
    phone = OddPhone(0, 2.0, ["00:00:01.000", "/a.csv", "/a.mov"])  # whole numbers are numbers
    try:
        with PhoneRemote("127.0.0.1", phone.port, timeout_s=5) as remote:
            assert remote.battery() == 0.0 and remote.thermals() == 2
            assert remote.record_stop() == {"timecode": "00:00:01.000", "csv": "/a.csv", "mov": "/a.mov"}
    finally:
        phone.close()
