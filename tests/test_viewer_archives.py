"""``s2a-view`` on zip archives of takes, as a user gets them (a take folder compressed by Finder, a CSV
zipped with its audio, a download of several takes): read as the take unzipped, through capture's
archive checks, with nothing left unpacked after (also after an error, Ctrl-C or SIGTERM). And speech
given with ``--audio`` to a take folder that has its own, placed where the take's own speech was."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT, run_cli, run_here
from test_take_archives import _patched

from capture.errors import InputError
from capture.take_archive import UNPACK_PREFIX
from viewer.inputs import archives_unpacked, read_input, take_source

NEUROSYNC = "paired/neurosync-trainer-lite-testset"
S07 = "livelinkface/alexdjulin_S07/S07-001.csv"
S88 = "livelinkface/alexdjulin_S88/S88-001.csv"


def view(tmp: Path, *args: object, wait: bool = True) -> subprocess.CompletedProcess | subprocess.Popen:
    """``python -m viewer ARGS`` with its temporary folder in ``tmp`` (to see what it leaves there)."""
    tmp.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "viewer", *map(str, args)]
    env = os.environ | {"TMPDIR": str(tmp)}
    if not wait:
        return subprocess.Popen(
            cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
    # the command itself in this process (s2a-view runs as a real subprocess in the signal tests here and
    # in test_viewer_cli): its temporary folder is Python's, pointed at ``tmp`` for the call
    kept = tempfile.tempdir
    tempfile.tempdir = str(tmp)
    try:
        return run_here("viewer", *args)
    finally:
        tempfile.tempdir = kept


def summary(proc: subprocess.CompletedProcess) -> dict:
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def one_line_error(proc: subprocess.CompletedProcess) -> str:
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    (line,) = [x for x in proc.stderr.splitlines() if x.startswith("s2a-view: error:")]
    return line


def unpacked_left(tmp: Path) -> list[str]:
    return [p.name for p in tmp.iterdir() if p.name.startswith(UNPACK_PREFIX)] if tmp.is_dir() else []


def zip_files(archive: Path, files: dict[str, Path | bytes], finder: bool = False) -> Path:
    """A zip of ``files`` (member name -> file or bytes); ``finder`` adds Finder's ``__MACOSX/._X``."""
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as z:
        for name, what in files.items():
            if isinstance(what, bytes):
                z.writestr(name, what)
            else:
                z.write(what, name)
            if finder:
                parent, _, leaf = name.rpartition("/")
                z.writestr("/".join(filter(None, ["__MACOSX", parent, "._" + leaf])), b"\x00\x05\x16\x07")
    return archive


def zip_take_folder(folder: Path, archive: Path) -> Path:
    """``folder`` as Finder's Compress makes it: the folder inside, and the AppleDouble litter."""
    return zip_files(archive, {f"{folder.name}/{p.name}": p for p in sorted(folder.iterdir())}, finder=True)


@pytest.fixture(scope="module")
def real_pair(samples, tmp_path_factory) -> Path:
    """The real NeuroSync take as a user keeps it: its CSV and its speech in one folder."""
    folder = tmp_path_factory.mktemp("pair") / "neurosync"
    folder.mkdir()
    shutil.copy(samples / NEUROSYNC / "testset.csv", folder / "testset.csv")
    shutil.copy(samples / NEUROSYNC / "audio.wav", folder / "testset.wav")
    return folder


def pixels(path: Path) -> np.ndarray:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert img is not None, path
    return img


def test_a_take_folder_zipped_by_finder_renders_as_the_folder_does(sim_take, tmp_path):
    (tmp_path / "dl").mkdir()
    archive = zip_take_folder(sim_take, tmp_path / "dl" / "take.zip")
    before = sorted(p.name for p in archive.parent.iterdir())
    tmp = tmp_path / "tmp"
    got = summary(
        view(tmp, "render", archive, "-o", tmp_path / "zip.png", "--size", 64, "--frame", 60, "--json")
    )
    want = summary(
        view(tmp, "render", sim_take, "-o", tmp_path / "dir.png", "--size", 64, "--frame", 60, "--json")
    )
    assert np.array_equal(pixels(tmp_path / "zip.png"), pixels(tmp_path / "dir.png"))
    assert got["time_s"] == want["time_s"]
    mov = Path(want["audio_files"][0]).name
    assert got["audio_files"] == [f"{archive}/{sim_take.name}/{mov}"]  # the member, not the copy
    assert unpacked_left(tmp) == [] and sorted(p.name for p in archive.parent.iterdir()) == before


def test_an_mp4_of_a_zipped_take_has_its_reference_video_and_speech(sim_take, tmp_path):
    archive = zip_take_folder(sim_take, tmp_path / "take.zip")
    tmp = tmp_path / "tmp"
    s = summary(
        view(tmp, "render", archive, "-o", tmp_path / "t.mp4", "--size", 64, "--video", "auto", "--json")
    )
    assert s["audio"] and s["audio_from"].startswith(f"{archive}/{sim_take.name}/")
    assert s["width"] > 64 and s["frames"] > 100  # the .mov read frame by frame from the unpacked copy
    assert unpacked_left(tmp) == []


def test_a_zipped_real_csv_with_its_audio_plots_and_renders_as_unzipped(real_pair, tmp_path):
    archive = zip_files(tmp_path / "ns.zip", {p.name: p for p in real_pair.iterdir()})
    tmp = tmp_path / "tmp"
    got = summary(view(tmp, "plot", archive, "-o", tmp_path / "zip.svg", "--vad", "energy", "--json"))
    want = summary(view(tmp, "plot", real_pair, "-o", tmp_path / "dir.svg", "--vad", "energy", "--json"))
    assert got["audio_file"] == f"{archive}/testset.wav"
    assert got["duration_s"] == want["duration_s"] and got["speech_segments"] == want["speech_segments"]
    view(tmp, "render", archive, "-o", tmp_path / "zip.png", "--size", 64, "--time", 3)
    view(tmp, "render", real_pair, "-o", tmp_path / "dir.png", "--size", 64, "--time", 3)
    assert np.array_equal(pixels(tmp_path / "zip.png"), pixels(tmp_path / "dir.png"))
    assert unpacked_left(tmp) == []


def test_a_zipped_csv_alone_streams(samples, tmp_path):
    archive = zip_files(tmp_path / "s07.zip", {"S07-001.csv": samples / S07})
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(0.2)
    try:
        s = summary(
            view(
                tmp_path / "tmp",
                "stream",
                archive,
                "--to",
                f"127.0.0.1:{rx.getsockname()[1]}",
                "--speed",
                200,
                "--json",
            )
        )
        received = 0
        while True:
            try:
                rx.recv(4096)
                received += 1
            except TimeoutError:
                break
    finally:
        rx.close()
    assert s["frames"] > 2000 and received > 0
    assert unpacked_left(tmp_path / "tmp") == []


def test_an_archive_of_several_takes_names_them_and_one_is_picked_by_its_path(samples, tmp_path):
    archive = zip_files(
        tmp_path / "takes.zip", {"S07/S07-001.csv": samples / S07, "S88/S88-001.csv": samples / S88}
    )
    tmp = tmp_path / "tmp"
    line = one_line_error(view(tmp, "render", archive, "-o", tmp_path / "x.png", "--size", 64))
    assert f"{archive}: render shows one take per input; found 2 takes" in line
    assert "S07/S07-001.csv, S88/S88-001.csv" in line and f"name one of them as {archive}/S07" in line
    s = summary(view(tmp, "render", archive / "S88", "-o", tmp_path / "x.png", "--size", 64, "--json"))
    assert s["input"] == str(archive / "S88")
    line = one_line_error(view(tmp, "plot", archive / "S99", "-o", tmp_path / "x.png"))
    assert line.endswith(f"{archive}: holds no S99 (it holds S07/, S88/)")
    # --compare reads archives too: the other take of the same archive beside the first
    summary(
        view(
            tmp,
            "render",
            archive / "S07",
            "--compare",
            archive / "S88/S88-001.csv",
            "-o",
            tmp_path / "c.png",
            "--size",
            64,
            "--json",
        )
    )
    assert unpacked_left(tmp) == []


def test_an_archive_in_an_archive_is_named_by_its_path(samples, tmp_path):
    inner = zip_files(tmp_path / "S07.zip", {"S07-001.csv": samples / S07})
    outer = zip_files(
        tmp_path / "download.zip",
        {"S07.zip": inner, "S88.zip": zip_files(tmp_path / "S88.zip", {"S88-001.csv": samples / S88})},
    )
    tmp = tmp_path / "tmp"
    line = one_line_error(view(tmp, "render", outer, "-o", tmp_path / "x.png", "--size", 64))
    assert "2 zip archive(s) (S07.zip, S88.zip)" in line and f"as {outer}/S07.zip" in line
    summary(view(tmp, "render", outer / "S07.zip", "-o", tmp_path / "x.png", "--size", 64, "--json"))
    assert unpacked_left(tmp) == []


def test_hostile_and_unreadable_archives_are_one_line_and_write_nothing(samples, tmp_path):
    csv = (samples / S07).read_bytes()
    tmp = tmp_path / "tmp"
    cases = {}
    evil = tmp_path / "evil.zip"
    with zipfile.ZipFile(evil, "w") as z:
        z.writestr("ok.csv", csv)
        z.writestr("../escaped.csv", csv)
    cases[evil] = "would be written outside the folder unpacked into"
    cases[_locked := zip_files(tmp_path / "locked.zip", {"S07-001.csv": csv[:4000]})] = "is encrypted"
    _patched(_locked, 6, "<H", 0x1)
    cases[_zstd := zip_files(tmp_path / "zstd.zip", {"S07-001.csv": csv[:4000]})] = "Zstandard"
    _patched(_zstd, 8, "<H", 93)
    cases[_bomb := zip_files(tmp_path / "bomb.zip", {f"{i}.csv": b"0" * 100 for i in range(300)})] = (
        "unpacking it needs"
    )
    _patched(_bomb, 22, "<I", 0xFFFFFFF0)  # each member declares 4.3 GB: 1.3 TB in all, more than the disk
    (cut := tmp_path / "cut.zip").write_bytes(csv[:5000])
    cases[cut] = "not a readable zip archive"
    for archive, what in cases.items():
        line = one_line_error(view(tmp, "render", archive, "-o", tmp_path / "x.png", "--size", 64))
        assert f"{archive}: " in line and what in line, line
    assert (
        unpacked_left(tmp) == []
        and not (tmp_path / "escaped.csv").exists()
        and not (tmp / "escaped.csv").exists()
    )


def test_errors_after_unpacking_leave_nothing_unpacked(sim_take, tmp_path):
    archive = zip_take_folder(sim_take, tmp_path / "take.zip")
    tmp = tmp_path / "tmp"
    line = one_line_error(view(tmp, "render", archive, "-o", tmp_path / "x.png", "--frame", 99999))
    assert f"{archive}: --frame 99999 is outside" in line
    assert unpacked_left(tmp) == []


@pytest.mark.parametrize(("sig", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_ctrl_c_and_sigterm_remove_what_was_unpacked(real_pair, tmp_path, sig, code):
    archive = zip_files(tmp_path / "ns.zip", {p.name: p for p in real_pair.iterdir()})
    tmp = tmp_path / "tmp"
    proc = view(tmp, "render", archive, "-o", tmp_path / "ns.mp4", "--size", 64, wait=False)
    partial = tmp_path / ".ns.mp4.partial.mp4"  # the render under way (1,220 frames: a minute here)
    try:
        deadline = time.monotonic() + 120
        while not partial.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert partial.exists() and unpacked_left(tmp), proc.communicate()[1]
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == code and "Traceback" not in err, err
    assert unpacked_left(tmp) == [] and not (tmp_path / "ns.mp4").exists()


def test_report_on_a_zipped_folder_of_takes_names_the_archive(sim_take, tmp_path):
    assert run_cli("capture", "import", sim_take, "-o", tmp_path / "takes").returncode == 0
    (take,) = [p for p in (tmp_path / "takes").iterdir() if p.is_dir() and not p.name.startswith(".")]
    archive = zip_files(tmp_path / "takes.zip", {f"takes/{take.name}/{p.name}": p for p in take.iterdir()})
    tmp = tmp_path / "tmp"
    s = summary(view(tmp, "report", archive, "-o", tmp_path / "r.html", "--json"))
    assert s["takes"] == 1 and s["unreadable"] == []
    page = (tmp_path / "r.html").read_text()
    assert f"{archive}/takes" in page and str(tmp) not in page
    assert unpacked_left(tmp) == []


# -- --audio given to a take folder that has speech of its own ------------------------------------------
def test_a_take_paired_by_frame_index_given_its_own_audio_again_shows_the_same(samples, tmp_path):
    src = samples / NEUROSYNC
    out = tmp_path / "takes"
    proc = run_cli(
        "capture",
        "import",
        src / "testset.csv",
        "--audio",
        src / "audio.wav",
        "--audio-pairing",
        "frame-index",
        "-o",
        out,
    )
    assert proc.returncode == 0, proc.stderr
    (take,) = [p for p in out.iterdir() if p.is_dir() and not p.name.startswith(".")]
    own, _, _ = read_input(take, "one")
    again, _, given = read_input(take, "one", src / "audio.wav")
    # frame i at i/60 s, as without --audio: 1,217 / 60 s, not the timecodes' 20.316 s
    assert again.time[-1] == own.time[-1] == pytest.approx(1217 / 60)
    assert again.meta.audio.start_source == "paired_frame_convention" and given == src / "audio.wav"
    tmp = tmp_path / "tmp"  # and the face the command line shows near the end, where the clocks part most
    view(tmp, "render", take, "-o", tmp_path / "own.png", "--size", 64, "--time", 20)
    view(
        tmp,
        "render",
        take,
        "--audio",
        src / "audio.wav",
        "-o",
        tmp_path / "again.png",
        "--size",
        64,
        "--time",
        20,
    )
    assert np.array_equal(pixels(tmp_path / "own.png"), pixels(tmp_path / "again.png"))


def test_speech_given_to_a_take_folder_starts_where_its_own_did(sim_take, tmp_path):
    assert run_cli("capture", "import", sim_take, "-o", tmp_path / "takes").returncode == 0
    (take,) = [p for p in (tmp_path / "takes").iterdir() if p.is_dir() and not p.name.startswith(".")]
    own, _, own_file = read_input(take, "one")
    assert own.meta.audio.start_source == "frame_log_audio" and own.meta.audio.start_s != 0  # -34 ms
    again, _, given = read_input(take, "one", own_file)
    assert given == own_file
    assert (again.meta.audio.start_s, again.meta.audio.start_source) == (
        own.meta.audio.start_s,
        "frame_log_audio",
    )
    assert np.array_equal(again.time, own.time) and np.array_equal(again.audio.samples, own.audio.samples)


def test_speech_given_to_a_take_folder_without_any_starts_at_its_first_frame(samples, tmp_path):
    out = tmp_path / "takes"
    assert run_cli("capture", "import", samples / NEUROSYNC / "testset.csv", "-o", out).returncode == 0
    (take,) = [p for p in out.iterdir() if p.is_dir() and not p.name.startswith(".")]
    given, _, _ = read_input(take, "one", samples / NEUROSYNC / "audio.wav")
    csv, _, _ = read_input(samples / NEUROSYNC / "testset.csv", "one", samples / NEUROSYNC / "audio.wav")
    assert given.meta.audio.start_s == csv.meta.audio.start_s == float(given.time[0])
    assert given.meta.audio.start_source == csv.meta.audio.start_source == "assumed_first_csv_row"
    assert np.array_equal(given.time, csv.time)


def test_what_a_killed_viewer_left_unpacked_is_removed_by_the_next(samples, tmp_path):
    archive = zip_files(tmp_path / "s07.zip", {"S07-001.csv": samples / S07})
    tmp = tmp_path / "tmp"
    proc = view(tmp, "stream", archive, "--to", "127.0.0.1:9", "--speed", 0.01, wait=False)
    try:
        deadline = time.monotonic() + 60
        while not unpacked_left(tmp) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        (left,) = unpacked_left(tmp)
    finally:
        proc.kill()  # SIGKILL: no finally runs
        proc.communicate(timeout=60)
    assert unpacked_left(tmp) == [left]
    alive = tmp / f"{UNPACK_PREFIX}view-{os.getpid()}-x"  # a process that runs: its folder stays
    alive.mkdir()
    summary(view(tmp, "render", archive, "-o", tmp_path / "x.png", "--size", 64, "--json"))
    assert unpacked_left(tmp) == [alive.name]


# -- one take of an archive of several: only what it needs is unpacked -------------------------------
def _set_in_central_directory(archive: Path, members: set[str], offset: int, fmt: str, value: int) -> None:
    """Set a field of the central directory headers of ``members`` (offset from each one's signature):
    what the archive's list, and so its checks, read of them."""
    data = bytearray(archive.read_bytes())
    start = 0
    while (i := data.find(b"PK\x01\x02", start)) >= 0:
        (length,) = struct.unpack_from("<H", data, i + 28)
        if data[i + 46 : i + 46 + length].decode() in members:
            struct.pack_into(fmt, data, i + offset, value)
        start = i + 4
    archive.write_bytes(bytes(data))


def _unpacked_files(tmp: Path) -> list[str]:
    """The files unpacked in ``tmp``, relative to the folder each archive was unpacked into."""
    return sorted(
        p.relative_to(folder).as_posix()
        for d in tmp.iterdir()
        if d.name.startswith(UNPACK_PREFIX)
        for folder in d.iterdir()  # one, named as its archive
        for p in folder.rglob("*")
        if p.is_file()
    )


@pytest.fixture
def day_archive(sim_take, tmp_path) -> Path:
    """A day's takes zipped: T1, T2, T3 (each the simulated take folder), T2's .mov encrypted, T3 with
    300 clips beside its take, each declaring 4.3 GB (1.3 TB in all): only T1 can be unpacked whole."""
    files: dict[str, Path | bytes] = {
        f"day/{t}/{p.name}": p for t in ("T1", "T2", "T3") for p in sorted(sim_take.iterdir())
    }
    files["day/T1/Z broll.mov"] = next(sim_take.glob("*.mov"))  # a video the take reader does not read
    clips = {f"day/T3/clip{i:03d}.mov" for i in range(300)}
    archive = zip_files(tmp_path / "day.zip", files | dict.fromkeys(clips, b"0" * 100))
    _set_in_central_directory(archive, {f"day/T2/{next(sim_take.glob('*.mov')).name}"}, 8, "<H", 0x1)
    _set_in_central_directory(archive, clips, 24, "<I", 0xFFFFFFF0)  # uncompressed size
    return archive


def test_one_take_named_in_an_archive_of_several_unpacks_that_take_only(
    day_archive, sim_take, tmp_path, monkeypatch
):
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    csv = next(p.name for p in sim_take.glob("*.csv") if p.name != "frame_log.csv")
    mov = next(sim_take.glob("*.mov")).name
    want, _, _ = read_input(sim_take, "one")
    with archives_unpacked():
        by_folder, _, speech = read_input(day_archive / "day/T1", "one")
        assert speech == day_archive / "day/T1" / mov  # the member, its audio read from it
        assert _unpacked_files(tmp) == sorted(  # not its .wav: its .mov holds the audio read
            [f"day/T1/{p.name}" for p in sim_take.iterdir() if p.suffix != ".wav"] + ["day/T1/Z broll.mov"]
        )
    with archives_unpacked():  # a CSV named: the files of its folder its reader looks at, its .mov too
        by_csv, _, speech = read_input(day_archive / "day/T1" / csv, "one")
        assert speech == day_archive / "day/T1" / mov
        assert _unpacked_files(tmp) == sorted(
            f"day/T1/{p.name}" for p in sim_take.iterdir() if p.suffix != ".wav"
        )
    for got in (by_folder, by_csv):
        assert np.array_equal(got.values, want.values, equal_nan=True) and np.array_equal(got.time, want.time)
        assert np.array_equal(got.audio.samples, want.audio.samples)
    # the members a take needs are checked as ever: T2's .mov encrypted, T3's clips too large for the disk
    with archives_unpacked(), pytest.raises(InputError, match=f"member day/T2/{mov} is encrypted"):
        read_input(day_archive / "day/T2", "one")
    with archives_unpacked(), pytest.raises(InputError, match="unpacking it needs 1288.56 GB"):
        read_input(day_archive / "day/T3", "one")
    with archives_unpacked():  # its CSV named: the clips beside it are no video of its take
        assert len(read_input(day_archive / "day/T3" / csv, "one")[0].time) == len(want.time)
    assert unpacked_left(tmp) == []


def test_checks_of_names_still_see_the_whole_archive(samples, tmp_path):
    csv = (samples / S07).read_bytes()
    evil = tmp_path / "evil.zip"
    with zipfile.ZipFile(evil, "w") as z:
        z.writestr("S07/S07-001.csv", csv)
        z.writestr("S88/../../escaped.csv", csv)
    twice = tmp_path / "twice.zip"
    with pytest.warns(UserWarning, match="Duplicate name"), zipfile.ZipFile(twice, "w") as z:
        z.writestr("S07/S07-001.csv", csv)
        z.writestr("S88/S88-001.csv", csv)
        z.writestr("S88/S88-001.csv", b"x")
    for archive, what in ((evil, "would be written outside"), (twice, "holds two members named S88")):
        with archives_unpacked(), pytest.raises(InputError, match=what):
            read_input(archive / "S07", "one")


def test_an_archive_named_in_an_archive_is_the_only_member_unpacked(samples, tmp_path, monkeypatch):
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    outer = zip_files(
        tmp_path / "download.zip",
        {
            "S07.zip": zip_files(tmp_path / "S07.zip", {"S07-001.csv": samples / S07}),
            "S88.zip": zip_files(tmp_path / "S88.zip", {"S88-001.csv": samples / S88}),
            "S88-001.csv": samples / S88,
        },
    )
    with archives_unpacked():
        take, _, _ = read_input(outer / "S07.zip", "one")
        assert len(take.time) == 2030  # S07-001.csv's rows
        assert _unpacked_files(tmp) == ["S07-001.csv", "S07.zip"]  # download.zip's S07.zip, and what it holds
    with archives_unpacked(), pytest.raises(InputError, match=r"holds no S99.zip \(it holds S07.zip, S8"):
        read_input(outer / "S99.zip", "one")


# -- Ctrl-C while the unpacked copies are removed, and a process VTK ends itself -----------------------
_SECOND_CTRL_C = """
import os, signal, sys, threading, time
from pathlib import Path
from viewer.inputs import archives_unpacked, unpacked_input
from viewer.output import stopped_by_signals

def second_ctrl_c(folder):  # pressed again once the removal has begun
    count = len(os.listdir(folder))
    while os.path.isdir(folder) and len(os.listdir(folder)) == count:
        time.sleep(0.001)
    os.kill(os.getpid(), signal.SIGINT)

try:
    with stopped_by_signals(), archives_unpacked():
        folder, _ = unpacked_input(Path(sys.argv[1]))
        threading.Thread(target=second_ctrl_c, args=(folder,), daemon=True).start()
        os.kill(os.getpid(), signal.SIGINT)
except KeyboardInterrupt:
    sys.exit(130)  # as the command line does
"""

_CTRL_C_IN_VTK = """
import os, signal, sys
from pathlib import Path
from vtkmodules.vtkCommonCore import vtkObject
from viewer.inputs import archives_unpacked, unpacked_input
from viewer.output import stopped_by_signals

def observer(obj, event):
    os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C while VTK calls Python: VTK ends the process (Py_Exit)
    sum(range(100))

try:
    with stopped_by_signals(), archives_unpacked():
        unpacked_input(Path(sys.argv[1]))
        watched = vtkObject()
        watched.AddObserver("ModifiedEvent", observer)
        watched.Modified()
except KeyboardInterrupt:
    sys.exit(130)
"""


@pytest.mark.parametrize("script", [_SECOND_CTRL_C, _CTRL_C_IN_VTK], ids=["second-ctrl-c", "ctrl-c-in-vtk"])
def test_what_was_unpacked_is_removed_whatever_thread_or_call_a_ctrl_c_meets(tmp_path, script):
    archive = zip_files(tmp_path / "many.zip", {f"T/{i:04d}.json": b"{}" for i in range(3000)})
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    proc = subprocess.run(
        [sys.executable, "-c", script, str(archive)],
        cwd=ROOT,
        env=os.environ | {"TMPDIR": str(tmp)},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode > 0, proc.stderr  # stopped (130, or 1 from VTK), not killed by a signal
    assert unpacked_left(tmp) == [], proc.stderr


def test_one_csv_of_a_flat_folder_of_takes_unpacks_that_take_alone(sim_take, tmp_path, monkeypatch):
    """A Live Link Face export zipped flat: each take's CSV and .mov side by side, one take with a WAV of
    its name (and the iCloud placeholder left beside it once downloaded). A CSV of such a folder is read
    as its take, with the audio of the .mov named as it (as ``s2a-capture import`` reads it): of the
    archive, only that CSV and its take's .mov are unpacked (not its WAV, the .mov holding the audio read),
    not the other takes' .mov files, and it is read as from the folder unzipped."""
    csv = next(p for p in sim_take.glob("*.csv") if p.name != "frame_log.csv")
    flat = tmp_path / "export"
    flat.mkdir()
    for i in (1, 2, 3):
        shutil.copy(csv, flat / f"MySlate_{i}_iPhone.csv")
        shutil.copy(next(sim_take.glob("*.mov")), flat / f"MySlate_{i}_iPhone.mov")
    shutil.copy(next(sim_take.glob("*.wav")), flat / "MySlate_2_iPhone.wav")
    (flat / ".MySlate_2_iPhone.wav.icloud").write_bytes(b"bplist00")
    archive = zip_files(tmp_path / "takes.zip", {p.name: p for p in sorted(flat.iterdir())})
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    whole = sum(p.stat().st_size for p in flat.iterdir())
    mov_size = (flat / "MySlate_1_iPhone.mov").stat().st_size
    for name, unpacked in (
        ("MySlate_2_iPhone.csv", ["MySlate_2_iPhone.mov"]),  # its WAV unread: the .mov holds audio
        ("MySlate_1_iPhone.csv", ["MySlate_1_iPhone.mov"]),  # the WAV of another take is not its audio
    ):
        want, want_warnings, want_speech = read_input(flat / name, "one")
        with archives_unpacked():
            got, warnings, got_speech = read_input(archive / name, "one")
            files = _unpacked_files(tmp)
            written = sum(p.stat().st_size for p in tmp.rglob("*") if p.is_file())
        assert files == sorted([name, *unpacked]), files
        assert written == sum((flat / f).stat().st_size for f in files) <= whole - 2 * mov_size
        assert np.array_equal(got.values, want.values, equal_nan=True) and np.array_equal(got.time, want.time)
        assert got.audio is not None and want.audio is not None and want_speech.suffix == ".mov"
        assert np.array_equal(got.audio.samples, want.audio.samples)
        assert got.meta.audio.start_source == want.meta.audio.start_source == "mov_timecode"
        assert got_speech == archive / want_speech.name
        assert warnings == [w.replace(str(flat), str(archive)) for w in want_warnings]
    # the folder named whole holds several takes: listed, one to be named
    with pytest.raises(InputError, match="found 3 takes under it"):
        take_source(flat, "one")
    assert unpacked_left(tmp) == []
