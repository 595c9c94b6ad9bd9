"""A probe that kills writers and exhausts the system: a full disk while a take's audio is written, a kill
while a take folder is replaced, an audio file that cannot be opened for want of file descriptors, a disk
that is full for a moment while listening. One line naming the file, never a traceback, never the loss
of what arrived, never a take that disappears."""

from __future__ import annotations

import errno
import io
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from live_helpers import start_recorder, synthetic_take

import capture.atomic as atomic
from capture import Audio, build_takes, read_take, write_audio, write_take
from capture.audio_capture import AudioLog
from capture.errors import InputError
from capture.file_lock import fcntl
from capture.livelink import frame_block, header_bytes
from capture.recorder import AUDIO_LOG

TESTS = Path(__file__).resolve().parent
VALS = np.linspace(-0.5, 1.0, 61).astype(np.float32)
FULL = "No space left on device"


class _FillingFile(io.FileIO):
    """A file on a disk with room for its first ``room`` bytes: a write past them is cut short, the next
    one fails with ENOSPC (as write(2) does); rewriting what is there (a WAV header) needs no room."""

    room = 0

    def write(self, data) -> int:
        allowed = self.room - self.tell()
        if allowed <= 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return super().write(memoryview(data)[:allowed])


def _disk_fills_up_in_audio(monkeypatch, times: int | None = None, room: int = 20_000) -> None:
    """The next ``times`` (None: all) audio.wav files are written to a disk with ``room`` bytes left."""
    real_open = open
    left = [times]

    def open_(path, mode="r", buffering=-1, **kwargs):
        if not str(path).endswith(".wav.partial") or left[0] == 0:
            return real_open(path, mode, buffering, **kwargs)
        left[0] = None if left[0] is None else left[0] - 1
        raw = _FillingFile(path, mode)
        raw.room = room
        return raw if buffering == 0 else io.BufferedWriter(raw, max(buffering, io.DEFAULT_BUFFER_SIZE))

    monkeypatch.setattr(atomic, "open", open_, raising=False)


def _hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def _take(take_id: str, seed: int):
    take = synthetic_take(60, seed=seed, audio=True)
    take.meta.id = take_id
    return take


# -- 1. a full disk while audio.wav is written -----------------------------------------------------------
def test_full_disk_while_the_audio_is_written_is_one_line(tmp_path, monkeypatch, capfd):
    _disk_fills_up_in_audio(monkeypatch)
    with pytest.raises(InputError) as err:
        write_take(_take("T", 0), tmp_path)
    assert str(err.value) == f"{tmp_path / 'T'}: cannot write the take: {FULL}"
    assert not list(tmp_path.iterdir())  # neither the take nor its partial
    with pytest.raises(OSError) as err:  # any writer of a WAV: an OSError naming the file
        write_audio(tmp_path / "a.wav", _take("T", 0).audio)
    assert err.value.filename == str(tmp_path / "a.wav") and err.value.strerror == FULL
    assert "Exception ignored" not in capfd.readouterr().err


def test_full_disk_for_one_take_of_a_session_leaves_the_others_written(tmp_path, monkeypatch):
    rec, port, runner = start_recorder(tmp_path, "s")
    audio_log = AudioLog(rec.session_dir / AUDIO_LOG)
    audio_log.start(16000, 1, "PCM_16", "file:test")
    audio_log.add_chunk(0, rec.clock.now_ns(), np.zeros((16000, 1), np.int16))
    audio_log.close()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for device in ("A", "B"):
            for f in range(30):
                s.sendto(
                    header_bytes(device, "iPhone") + frame_block(f, 0.0, 60, 1, VALS), ("127.0.0.1", port)
                )
    time.sleep(0.5)
    rec.request_stop()
    runner.join()
    rec.close()
    _disk_fills_up_in_audio(monkeypatch, times=1)  # the first take's audio: the disk has room again after it
    lines = build_takes(rec.session_dir, tmp_path / "takes")
    written = [x for x in lines if x["path"]]
    (failed,) = [x for x in lines if x.get("error")]
    assert len(written) == 1 and read_take(written[0]["path"]).audio is not None
    assert failed["error"].endswith(f": cannot write the take: {FULL}") and failed["path"] is None
    assert not (rec.session_dir / "complete.json").exists()  # recover retries the missing take
    assert _hidden(tmp_path / "takes") == []


# -- 2. a kill while a take folder is written or replaced ------------------------------------------------
# A writer that kills itself (SIGKILL, no clean-up) at one step of write_take: "swap" right after the
# first rename of something in the output folder, or just before the first removal of a folder there
# (the old take, once the new one is in place); "fresh" at the first fsync (mid-way through the take).
KILLED_WRITER = """
import os, shutil, signal, sys
from pathlib import Path
sys.path.insert(0, {tests!r})
from live_helpers import synthetic_take
from capture import write_take
out, seed, step = Path(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
kill = lambda: os.kill(os.getpid(), signal.SIGKILL)
real_replace, real_rmtree, real_fsync = os.replace, shutil.rmtree, os.fsync
def replace(src, dst):
    real_replace(src, dst)
    if Path(src).parent == out:
        kill()
def rmtree(path, *args, **kwargs):
    if Path(path).parent == out:
        kill()
    real_rmtree(path, *args, **kwargs)
def fsync(fd):
    kill()
if step == "swap":
    os.replace, shutil.rmtree = replace, rmtree
else:
    os.fsync = fsync
take = synthetic_take(60, seed=seed, audio=True)
take.meta.id = "T"
write_take(take, out)
"""


def _killed_writer(out: Path, seed: int, step: str) -> None:
    code = KILLED_WRITER.format(tests=str(TESTS))
    r = subprocess.run(
        [sys.executable, "-c", code, str(out), str(seed), step], capture_output=True, timeout=60
    )
    assert r.returncode == -signal.SIGKILL, r.stderr


def test_a_kill_while_a_take_is_replaced_never_hides_it(tmp_path):
    write_take(_take("T", 0), tmp_path)
    _killed_writer(tmp_path, 1, "swap")
    take = read_take(tmp_path / "T")  # the old take or the new one, never none
    assert np.array_equal(take.values, _take("T", 1).values)
    assert _hidden(tmp_path)  # the killed writer's leftover (the old take)...
    write_take(_take("T", 2), tmp_path)
    assert _hidden(tmp_path) == []  # ... is removed by the next write of the take
    assert np.array_equal(read_take(tmp_path / "T").values, _take("T", 2).values)


def test_a_kill_while_a_take_is_first_written_leaves_nothing_for_long(tmp_path):
    _killed_writer(tmp_path, 1, "fresh")
    assert not (tmp_path / "T").exists() and _hidden(tmp_path)
    write_take(_take("T", 2), tmp_path)
    assert _hidden(tmp_path) == [] and read_take(tmp_path / "T").audio is not None


@pytest.mark.skipif(fcntl is None, reason="no flock: leftovers cannot be told from live writes")
def test_the_next_write_puts_back_a_take_a_killed_write_moved_aside(tmp_path, monkeypatch):
    # Where folders cannot be swapped in one step, the old take is moved aside for a moment
    # (.T.old-XXXX/take): a writer killed then left the take missing.
    monkeypatch.setattr(atomic, "_exchange", lambda a, b: False, raising=False)
    write_take(_take("T", 0), tmp_path)
    aside = tmp_path / ".T.old-abcd1234"
    aside.mkdir()
    os.replace(tmp_path / "T", aside / "take")
    dead_partial = tmp_path / ".T.partial-efgh5678"
    dead_partial.mkdir()
    live_partial = tmp_path / ".T.partial-live0001"  # a write of another process, still going on
    live_partial.mkdir()
    other = tmp_path / ".T.old-1.old-abcd1234"  # a leftover of the take "T.old-1", not of "T"
    other.mkdir()
    held = os.open(live_partial, os.O_RDONLY)
    try:
        fcntl.flock(held, fcntl.LOCK_EX)
        with monkeypatch.context() as m:  # the new take cannot be written: the old one is back
            _disk_fills_up_in_audio(m)
            with pytest.raises(InputError, match=FULL):
                write_take(_take("T", 1), tmp_path)
        assert np.array_equal(read_take(tmp_path / "T").values, _take("T", 0).values)
        assert _hidden(tmp_path) == [other.name, live_partial.name]
        write_take(_take("T", 1), tmp_path)
        assert np.array_equal(read_take(tmp_path / "T").values, _take("T", 1).values)
        assert _hidden(tmp_path) == [other.name, live_partial.name]
    finally:
        os.close(held)


# -- 3 and 4. listen in a hostile system -----------------------------------------------------------------
# ``listen`` with a patch applied first: "no_fds" has the audio file opened when no file descriptor is
# left; "full_for_a_moment" fails the 2nd to 4th write of both logs with ENOSPC (the disk has room again
# afterwards); "audio_full" fails every write of the audio log after its first.
LISTEN = """
import errno, os, sys
import capture.audio_capture as ac
from capture.cli import main
patch = sys.argv.pop(1)
if patch == "no_fds":
    real_read_audio = ac.read_audio
    def read_audio(path):
        held = []
        try:
            while True:
                held.append(os.open(os.devnull, os.O_RDONLY))
        except OSError:
            pass
        try:
            return real_read_audio(path)
        finally:
            for fd in held:
                os.close(fd)
    ac.read_audio = read_audio
else:
    real_write, calls = os.write, {}
    def write(fd, data):
        try:
            name = os.path.basename(os.readlink(f"/proc/self/fd/{fd}"))
        except OSError:
            name = ""
        calls[name] = calls.get(name, 0) + 1
        if name == "audio.log" and patch == "audio_full" and calls[name] > 1:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        if name in ("frames.log", "audio.log") and patch == "full_for_a_moment" and 2 <= calls[name] <= 4:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real_write(fd, data)
    os.write = write
sys.exit(main())
"""


def _listen(tmp_path: Path, patch: str, *args: str) -> tuple[list[str], str, int]:
    """Run the patched ``listen``, send one stream of 60 frames over about a second, stop it with SIGINT;
    returns its stdout lines, stderr and exit code."""
    cmd = [sys.executable, "-c", LISTEN, patch, "listen", "-o", str(tmp_path / "out"), "--port", "0"]
    proc = subprocess.Popen(
        [*cmd, "--json", "--duration", "60", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        head = []
        while not head or "udp://127.0.0.1:" not in head[-1]:
            head.append(proc.stderr.readline())
            assert head[-1], "".join(head)
        port = int(head[-1].split("udp://127.0.0.1:")[1].split(" ")[0])
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for f in range(60):
                s.sendto(header_bytes("A", "iPhone") + frame_block(f, 0.0, 60, 1, VALS), ("127.0.0.1", port))
                time.sleep(0.02)
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    return out.splitlines(), "".join(head) + err, proc.returncode


def _wav(tmp_path: Path, seconds: float = 3.0) -> Path:
    path = tmp_path / "speech.wav"
    write_audio(path, Audio(np.zeros(int(16000 * seconds), np.int16), 16000, "PCM_16"))
    return path


def test_audio_file_that_cannot_be_opened_for_want_of_descriptors_is_never_silent(tmp_path):
    wav = _wav(tmp_path)
    lines, err, code = _listen(tmp_path, "no_fds", "--audio-file", str(wav), "--audio-start", "first-packet")
    assert "Traceback" not in err and "Exception in thread" not in err, err
    assert f"s2a-capture: warning: {wav}: cannot read the audio file: Too many open files" in err.splitlines()
    assert code == 1 and len(lines) == 1  # the take is written all the same
    last = err.splitlines()[-1]
    assert last.startswith("s2a-capture: error: ") and "no audio was recorded: " in last
    assert "Too many open files" in last


def test_log_writes_that_failed_for_a_moment_but_lost_nothing_are_a_warning(tmp_path):
    lines, err, code = _listen(tmp_path, "full_for_a_moment", "--audio-file", str(_wav(tmp_path)))
    assert code == 0 and "error" not in err, err
    assert f"warning: writing the recorder log failed 3 time(s) ({FULL}), but nothing was lost" in err
    assert f"warning: writing the audio log failed 3 time(s) ({FULL}), but nothing was lost" in err
    (line,) = lines
    take = read_take(json.loads(line)["path"])
    assert len(take.time) == 60 and take.audio is not None


def test_audio_log_writes_that_lost_bytes_say_how_many(tmp_path):
    lines, err, code = _listen(tmp_path, "audio_full", "--audio-file", str(_wav(tmp_path)))
    last = err.splitlines()[-1]
    assert code == 1 and "Traceback" not in err, err
    assert last.startswith("s2a-capture: error: ") and "writing the audio log failed (" in last
    lost = int(last.split("writing the audio log failed (")[1].split(" failed writes, ")[1].split(" ")[0])
    assert lost > 0 and f"bytes not on disk): {FULL}" in last
