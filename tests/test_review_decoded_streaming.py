"""Review of ``s2a-capture import``'s bounded-memory audio (``audio_left_in_files``: audio FFmpeg decodes
written into a scratch WAV in the output folder, float audio past full scale checked in passes over its
file): audio read outside an import stays readable after the block; a Vorbis file past full scale is
repaired as read whole (libsndfile's seek into it is not to the sample); SIGTERM mid-import leaves no
scratch folder; Ctrl-C during a write of libsndfile's is an interrupt, not a traceback; the tracks of a
.mov not used leave the disk once the choice is made."""

from __future__ import annotations

import os
import resource
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import soundfile as sf
from conftest import ROOT, run_here
from test_audio_decode_memory import _encoded
from test_import_decoded_streaming import TAKE_CSV, _float_mov

from capture import Audio, read_audio, write_reference_mov
from capture.audio_io import FileAudio, audio_left_in_files, write_audio
from capture.mov import choose_mov_audio


def test_decoded_audio_read_without_a_scratch_folder_outlives_the_block(tmp_path):
    """``audio_left_in_files()`` without a folder (``s2a-capture listen --audio-file``, which plays the
    file after reading it) decoded an .m4a into a scratch file in the system's temporary folder, removed
    as the block ended: playing it was "audio file cannot be read again". It is held whole there, as
    before."""
    m4a = tmp_path / "take.m4a"
    m4a.write_bytes(_encoded("aac", "ipod", "fltp", 2, seconds=0.3))
    with audio_left_in_files():
        audio = read_audio(m4a)
    assert np.array_equal(audio.samples, read_audio(m4a).samples)
    assert not isinstance(audio, FileAudio)


def test_vorbis_past_full_scale_is_repaired_as_read_whole(tmp_path):
    """Ogg Vorbis decodes to float that may pass full scale; its damaged samples were looked for in passes
    over the file, reading the samples around each where libsndfile's seek put them: hundreds of samples
    off in Vorbis, so 1 of 10 damaged samples was found. Read whole, as before: the same take audio and
    repairs as outside an import."""
    rng = np.random.default_rng(0)
    x = (rng.standard_normal((40000, 2)) * 0.3).astype(np.float32)
    x[rng.integers(0, 40000, 10), 1] = 20.0
    ogg = tmp_path / "loud.ogg"
    sf.write(ogg, x, 16000, format="OGG", subtype="VORBIS")
    whole_repairs, left_repairs = [], []
    write_audio(tmp_path / "whole.wav", read_audio(ogg, whole_repairs))
    with audio_left_in_files(tmp_path / "scratch"):
        write_audio(tmp_path / "left.wav", read_audio(ogg, left_repairs))
    assert (tmp_path / "left.wav").read_bytes() == (tmp_path / "whole.wav").read_bytes()
    assert left_repairs == whole_repairs and " 10 isolated sample(s)" in whole_repairs[0]["message"]


def test_sigterm_mid_import_leaves_no_scratch_folder(samples, tmp_path):
    """``kill`` (SIGTERM) of an import while it decodes a take folder's .mov ended the process at once:
    the decoded audio (1.4 GB an hour) and the lock stayed in the output folder until the next import
    there. It stops as on Ctrl-C now: exit 143, one line, nothing left."""
    folder = tmp_path / "src" / "S07-001"
    folder.mkdir(parents=True)
    lines = (samples / TAKE_CSV).read_text().splitlines(keepends=True)
    (folder / "S07-001.csv").write_text("".join(lines[:241]))
    _float_mov(folder / "S07-001.mov", np.zeros((60 * 48000, 2), np.float32), 48000)  # 23 MB
    out = tmp_path / "out"
    out.mkdir()
    cmd = [sys.executable, "-m", "capture", "import", folder.parent, "-o", out]
    proc = subprocess.Popen(list(map(str, cmd)), cwd=ROOT, stderr=subprocess.PIPE, text=True)
    try:
        while proc.poll() is None and not any(p.name.startswith(".unzip-audio-") for p in out.iterdir()):
            time.sleep(0.002)
        proc.send_signal(signal.SIGTERM)  # while it decodes or copies (0.3 s of it)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1] == "s2a-capture: terminated (SIGTERM)"
    assert not list(out.iterdir())


def test_the_tracks_of_a_mov_not_used_leave_the_disk_at_once(tmp_path):
    """Every audio track of a .mov is decoded (each track's peak is noted) into a scratch file of its own,
    and all stayed on the disk until the take was written: an hour of 48 kHz stereo is 1.4 GB a track.
    The tracks not used are removed once the choice is made; the take's audio and repairs are as
    before."""
    t = np.arange(8000) / 16000
    tone = (np.stack([np.sin(2 * np.pi * 220 * t)] * 2, axis=1) * 8000).astype(np.int16)
    silent = Audio(np.zeros_like(tone), 16000)
    tracks = [silent, Audio(tone, 16000), Audio(-tone, 16000)]
    mov = write_reference_mov(tmp_path / "take.mov", 30, 15, tracks)
    whole_repairs, left_repairs = [], []
    write_audio(tmp_path / "whole.wav", choose_mov_audio(mov, whole_repairs)[0])
    scratch = tmp_path / "out"
    scratch.mkdir()
    with audio_left_in_files(scratch):
        audio, choice = choose_mov_audio(mov, left_repairs)
        assert [p.name for p in scratch.rglob("*.wav")] == [audio._read_from.name]
        write_audio(tmp_path / "left.wav", audio)
    assert choice["track"] == 2 and left_repairs == whole_repairs
    assert (tmp_path / "left.wav").read_bytes() == (tmp_path / "whole.wav").read_bytes()


def _interrupted(step, delays: np.ndarray) -> set[str]:
    """What ``step()`` ended with, each time given a real SIGINT ``delay`` seconds after it starts (one
    that comes after it ended is passed over)."""
    seen, running = set(), False

    def interrupt(signum, frame) -> None:
        if running:
            raise KeyboardInterrupt

    previous = signal.signal(signal.SIGINT, interrupt)
    try:
        for delay in delays:
            timer = threading.Timer(delay, os.kill, (os.getpid(), signal.SIGINT))
            try:
                running = True
                timer.start()
                step()
                seen.add("done")
            except BaseException as exc:  # noqa: BLE001 - what reached the command, whatever it is
                seen.add(type(exc).__name__)
            finally:
                running = False
                timer.join()
    finally:
        signal.signal(signal.SIGINT, previous)
    return seen


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_ctrl_c_while_libsndfile_writes_is_an_interrupt(tmp_path):
    """Ctrl-C met inside libsndfile's write callback (most of a write's time: the take's audio.wav, the
    scratch WAV decoded audio goes into) was printed there and lost ("Exception ignored from cffi
    callback"), and soundfile's check of the frames written failed: an AssertionError, a traceback and
    exit 1 instead of "interrupted" (130). It waits until libsndfile's call returns now: a
    KeyboardInterrupt, no partial file left."""
    audio = Audio(np.zeros((1 << 20, 2), np.float32), 48000)  # 8 MB
    target = tmp_path / "audio.wav"

    def write() -> None:
        target.unlink(missing_ok=True)
        write_audio(target, audio)

    seen = _interrupted(write, np.linspace(0.0005, 0.012, 24))
    assert seen <= {"KeyboardInterrupt", "done"} and "KeyboardInterrupt" in seen, seen
    assert {p.name for p in tmp_path.iterdir()} <= {"audio.wav"}  # no partial write left

    mov = _float_mov(tmp_path / "take.mov", audio.samples, 48000)
    scratch = tmp_path / "out"
    scratch.mkdir()

    def decode() -> None:
        with audio_left_in_files(scratch):
            read_audio(mov, [])

    seen = _interrupted(decode, np.linspace(0.002, 0.04, 12))
    assert seen <= {"KeyboardInterrupt", "done"} and "KeyboardInterrupt" in seen, seen
    assert not list(scratch.iterdir())


def _three_track_take(samples, folder, seconds: float = 2.0):
    """A take folder whose .mov holds three 16 kHz stereo tracks: silent, a tone, the tone inverted."""
    folder.mkdir(parents=True)
    lines = (samples / TAKE_CSV).read_text().splitlines(keepends=True)
    (folder / "S07-001.csv").write_text("".join(lines[:241]))
    t = np.arange(round(seconds * 16000)) / 16000
    tone = (np.stack([np.sin(2 * np.pi * 220 * t)] * 2, axis=1) * 8000).astype(np.int16)
    tracks = [Audio(np.zeros_like(tone), 16000), Audio(tone, 16000), Audio(-tone, 16000)]
    return write_reference_mov(folder / "S07-001.mov", 30, 15, tracks)


def _limited(limit: int):
    """For a subprocess: files past ``limit`` bytes refused by the system (EFBIG: Python ignores SIGXFSZ)."""
    return lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))


def test_a_refused_scratch_file_is_said_once_and_the_import_goes_on(samples, tmp_path):
    """A scratch file the system refuses (here past the process's file size limit, EFBIG: the scratch
    WAV's RF64 header is 36 bytes longer than the take's audio.wav, so only it is refused) made the import
    decode in memory without a word: an hour of 48 kHz stereo then needs 1.4 GB. It is said on stderr,
    once for the three tracks of a .mov, and the take is the one written with the scratch files."""
    folder = tmp_path / "src" / "S07-001"
    _three_track_take(samples, folder)
    run_here("capture", "import", folder.parent, "-o", tmp_path / "free", check=True)
    free = tmp_path / "free" / "S07-001"
    limit = (free / "audio.wav").stat().st_size
    assert max(p.stat().st_size for p in free.iterdir()) == limit  # the largest file written
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "capture", "import", folder.parent, "-o", out]
    proc = subprocess.run(
        list(map(str, cmd)), cwd=ROOT, capture_output=True, text=True, preexec_fn=_limited(limit), timeout=60
    )
    assert proc.returncode == 0, proc.stderr
    told = [line for line in proc.stderr.splitlines() if "decoded in memory instead" in line]
    assert len(told) == 1 and told[0].startswith("s2a-capture: warning: ") and "File too large" in told[0]
    for name in ("audio.wav", "frames.npz"):
        assert (out / "S07-001" / name).read_bytes() == (free / name).read_bytes(), name
    assert {p.name for p in out.iterdir()} == {"S07-001"}


def _most_on_disk(folder, step) -> int:
    """The most bytes the files under ``folder`` held at once while ``step()`` ran (looked at as often as
    the interpreter lets a thread)."""
    most, done = 0, threading.Event()

    def watch() -> None:
        nonlocal most
        while not done.is_set():
            total = 0
            try:
                for path in folder.rglob("*"):
                    total += path.stat().st_size
            except FileNotFoundError:  # removed as it was looked at
                continue
            most = max(most, total)

    watcher = threading.Thread(target=watch)
    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-4)  # the watcher looks every 0.1 ms of the step's Python code
    watcher.start()
    try:
        step()
    finally:
        done.set()
        watcher.join()
        sys.setswitchinterval(interval)
    return most


def test_a_mov_of_three_tracks_has_two_on_the_disk_at_most(samples, tmp_path):
    """The tracks of a .mov were all decoded into scratch files before one was chosen: three tracks of an
    hour were 3 x 1.4 GB on the disk at once. Each is let go once its peak is known unless it is the
    one chosen so far (the first silent track until one with sound comes): two at most, the same audio
    and repair."""
    mov = _three_track_take(samples, tmp_path / "src", seconds=30.0)
    track = 30 * 16000 * 2 * 2
    whole_repairs, left_repairs = [], []
    write_audio(tmp_path / "whole.wav", choose_mov_audio(mov, whole_repairs)[0])
    scratch = tmp_path / "out"
    scratch.mkdir()

    def chosen() -> None:
        with audio_left_in_files(scratch):
            audio, choice = choose_mov_audio(mov, left_repairs)
            write_audio(tmp_path / "left.wav", audio)
        assert choice["track"] == 2

    most = _most_on_disk(scratch, chosen)
    assert track < most < 2.25 * track, f"{most} bytes at once, a track {track}"
    assert left_repairs == whole_repairs
    assert (tmp_path / "left.wav").read_bytes() == (tmp_path / "whole.wav").read_bytes()
