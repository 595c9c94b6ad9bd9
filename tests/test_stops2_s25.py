"""Stops (Ctrl-C, SIGTERM) met at the edges of more of the toolkit's clean-ups, as in test_stops_s25: as a
hidden folder is made but not yet noted where its ``finally`` finds it, or as a ``finally`` removes a
partial file or folder and a second Ctrl-C comes. Each left its folder or file behind: an archive's
unpacked folder, a checkpoint's or a shard's partial file, a session's spilled rows, a pruned take. A
signal is raised inside the real call at that point, as a stop landing there would be met."""

from __future__ import annotations

import errno
import shutil
import signal
import tarfile
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
from live_helpers import record_packets
from test_stops_s25 import _python_ctrl_c, _stop_in  # noqa: F401 (the fixture: Python's Ctrl-C handler)

import capture.session_takes as session_takes
from align.batch import prune_orphans
from capture.errors import InputError
from capture.livelink import frame_block, header_bytes
from capture.record_log import RecordType
from capture.take_archive import unpacked
from dataset.shards import ShardReader, ShardWriter
from train.checkpoint import write_atomically


def _names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


@pytest.fixture
def archive(tmp_path) -> Path:
    """A take folder zipped as Finder does, and an empty folder to unpack it into (``tmp_path/unpack``)."""
    path = tmp_path / "take.zip"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("take/take.json", '{"slate": "A"}')
        zf.writestr("take/take.csv", "Timecode,BlendShapeCount\n")
    (tmp_path / "unpack").mkdir()
    return path


def test_a_stop_as_an_archive_s_folder_is_made_leaves_no_folder(archive, monkeypatch):
    into = archive.parent / "unpack"
    _stop_in(monkeypatch, tempfile, "mkdtemp", "returns")
    with pytest.raises(KeyboardInterrupt), unpacked(archive, into=into):
        pytest.fail("the block ran after the stop")
    assert _names(into) == []


def test_a_second_ctrl_c_as_an_unpacked_archive_goes_leaves_no_folder(archive, monkeypatch):
    into = archive.parent / "unpack"
    with pytest.raises(KeyboardInterrupt), unpacked(archive, into=into) as done:
        assert (done.folder / "take" / "take.json").is_file()
        _stop_in(monkeypatch, shutil, "rmtree")
        signal.raise_signal(signal.SIGINT)
    assert _names(into) == []


def _stopped_writing(tmp: Path) -> None:
    tmp.write_bytes(b"half a checkpoint")
    signal.raise_signal(signal.SIGINT)


def _disk_full(tmp: Path) -> None:
    tmp.write_bytes(b"half a checkpoint")
    raise OSError(errno.ENOSPC, "No space left on device")


@pytest.mark.parametrize("write", [_stopped_writing, _disk_full], ids=["second-ctrl-c", "disk-full"])
def test_a_ctrl_c_as_a_partial_checkpoint_goes_leaves_no_partial_file(tmp_path, monkeypatch, write):
    """A Ctrl-C (a second one, or the first as a full disk's partial file is removed) as ``.NAME.partial``
    is removed left it beside the run's checkpoints."""
    (tmp_path / "last.ckpt").write_bytes(b"the previous checkpoint")
    _stop_in(monkeypatch, Path, "unlink")
    with pytest.raises(KeyboardInterrupt):
        write_atomically(tmp_path / "last.ckpt", write, "checkpoint")
    assert _names(tmp_path) == ["last.ckpt"]
    assert (tmp_path / "last.ckpt").read_bytes() == b"the previous checkpoint"


def test_a_second_ctrl_c_as_a_partial_shard_goes_leaves_no_partial_file(tmp_path, monkeypatch):
    shard = tmp_path / "train-000000.tar"
    with pytest.raises(KeyboardInterrupt), ShardWriter(shard) as writer:
        writer.add("take-000", {"json": b"{}", "anim.npy": b"\x93NUMPY"})
        _stop_in(monkeypatch, Path, "unlink")
        signal.raise_signal(signal.SIGINT)
    assert _names(tmp_path) == []


@pytest.mark.parametrize("as_it", ["starts", "returns"])
def test_a_stop_as_a_shard_is_opened_leaves_no_partial_file(tmp_path, monkeypatch, as_it):
    """Met as the tar is started in the file just made, before ``with`` holds the writer."""
    _stop_in(monkeypatch, tarfile, "open", as_it)
    with pytest.raises(KeyboardInterrupt), ShardWriter(tmp_path / "train-000000.tar"):
        pytest.fail("the block ran after the stop")
    assert _names(tmp_path) == []


def test_a_shard_written_whole_still_reads_back(tmp_path):
    with ShardWriter(tmp_path / "train-000000.tar") as writer:
        writer.add("take-000", {"json": b"{}"})
        writer.close()
    assert [key for key, _ in ShardReader(tmp_path / "train-000000.tar")] == ["take-000"]
    assert _names(tmp_path) == ["train-000000.tar"]


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    values = np.linspace(-0.5, 1.0, 61).astype(np.float32)
    packets = [header_bytes("P", "iPhone") + frame_block(i, 0.0, 60, 1, values) for i in range(120)]
    return record_packets(tmp_path_factory.mktemp("rec"), "stops", packets).session_dir


@pytest.fixture
def session(recorded, tmp_path) -> Path:
    """A recorded session of one phone's 120 frames, a test's own copy (its rows spill with a small
    ``SPILL_BYTES``)."""
    return Path(shutil.copytree(recorded, tmp_path / recorded.name))


def _spilled(session: Path) -> list[str]:
    return sorted(p.name for p in session.iterdir() if p.name.startswith(".build-"))


@pytest.mark.parametrize(
    "where, name, as_it",
    [
        (tempfile, "mkdtemp", "returns"),  # the spill folder made
        (session_takes.SessionLog, "_spill", "returns"),  # the log being read, rows spilled already
        (session_takes, "index_audio_log", "starts"),  # the session's audio indexed, the log read
    ],
    ids=["spill-folder-made", "log-read", "audio-indexed"],
)
def test_a_stop_as_a_session_s_takes_are_built_leaves_no_spilled_rows(
    session, tmp_path, monkeypatch, where, name, as_it
):
    monkeypatch.setattr(session_takes, "SPILL_BYTES", 1000)
    _stop_in(monkeypatch, where, name, as_it)
    with pytest.raises(KeyboardInterrupt):
        session_takes.build_takes(session, tmp_path / "takes")
    assert _spilled(session) == []
    assert [t["frames"] for t in session_takes.build_takes(session, tmp_path / "takes")] == [120]
    assert _spilled(session) == []


def test_an_error_while_a_session_s_log_is_read_leaves_no_spilled_rows(session, monkeypatch):
    monkeypatch.setattr(session_takes, "SPILL_BYTES", 1000)
    read = session_takes.json_fields

    def refused(payload, *args):  # the END record, after the frames' rows spilled
        if payload[0] == RecordType.END:
            raise InputError("damaged beyond reading", session)
        return read(payload, *args)

    monkeypatch.setattr(session_takes, "json_fields", refused)
    with pytest.raises(InputError):
        session_takes.SessionLog(session)
    assert _spilled(session) == []


@pytest.fixture
def orphan(tmp_path) -> Path:
    """An aligned take's folder whose raw take is gone, in the aligned takes' folder ``tmp_path/out``."""
    folder = tmp_path / "out" / "gone.seg01"
    folder.mkdir(parents=True)
    (folder / "frames.npz").write_bytes(b"frames")
    return folder


def test_a_stop_as_a_pruned_take_s_hidden_folder_is_made_leaves_neither(orphan, monkeypatch):
    _stop_in(monkeypatch, tempfile, "mkdtemp", "returns")
    with pytest.raises(KeyboardInterrupt):
        prune_orphans(orphan.parent, [(orphan, "/raw/gone")])
    assert _names(orphan.parent) == ["gone.seg01"]  # not pruned, nothing hidden beside it


def test_a_ctrl_c_as_a_pruned_take_goes_leaves_nothing(orphan, monkeypatch):
    _stop_in(monkeypatch, shutil, "rmtree")
    with pytest.raises(KeyboardInterrupt):
        prune_orphans(orphan.parent, [(orphan, "/raw/gone")])
    assert _names(orphan.parent) == []
