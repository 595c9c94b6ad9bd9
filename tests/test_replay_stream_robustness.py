"""Bad input to ``s2a-capture replay`` and ``s2a-view stream``: one-line errors, never NaN weights."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import run_cli
from live_helpers import datagrams, synthetic_take, udp_receiver

from capture import FrameStatus, Take, read_livelink_csv, write_livelink_csv, write_take
from capture import livelink as ll
from capture.errors import InputError
from capture.replay import Impairment, replay_take


def _with_bad_values(n: int = 40) -> Take:
    take = synthetic_take(n, seed=6)
    take.values[5, 3] = np.nan  # one NaN cell: the app's CSV reader marks the row BAD_VALUE
    take.frame_status[5] = FrameStatus.BAD_VALUE
    take.values[9] = np.nan
    take.frame_status[9] = FrameStatus.BAD_VALUE
    take.values[12] = np.nan
    take.frame_status[12] = FrameStatus.FACE_LOST
    take.frame_status[20] = FrameStatus.DROPPED
    return take


def _values(packets: list[bytes]) -> list[np.ndarray]:
    """The value arrays of the packets that carry values (no-face packets carry none)."""
    out = []
    for p in packets:
        offset, reason = ll.parse_header(p)
        assert reason is None, reason
        if len(p) > offset + ll.FRAME_TIME_BYTES:
            out.append(np.frombuffer(p[-4 * ll.BLENDSHAPE_COUNT :], dtype=">f4"))
    return out


def test_replay_sends_bad_value_frames_as_no_face_packets():
    take = _with_bad_values()
    with udp_receiver() as sock:
        report = replay_take(take, "127.0.0.1", sock.getsockname()[1], speed=50.0)
        packets = datagrams(sock)
    assert report.bad_values == 2 and report.face_lost == 1 and report.no_face == 3
    assert report.packets_sent == len(packets) == 39  # the dropped frame is not sent
    values = _values(packets)
    assert len(values) == report.frames == 36
    assert all(np.isfinite(v).all() for v in values)
    assert report.to_json()["bad_values"] == 2
    assert report.frames + report.no_face == report.packets_sent


def test_stream_warns_about_bad_value_frames(tmp_path):
    """A CSV with `nan`/`inf` cells: its rows are BAD_VALUE frames, streamed as no-face packets."""
    csv = write_livelink_csv(synthetic_take(40, seed=6), tmp_path / "nan.csv")
    lines = csv.read_text().splitlines()
    for row, cell in [(6, "nan"), (10, "inf")]:
        cells = lines[row].split(",")
        cells[5] = cell
        lines[row] = ",".join(cells)
    csv.write_text("\n".join(lines) + "\n")
    with udp_receiver() as sock:
        r = run_cli("viewer", "stream", csv, "--to", f"127.0.0.1:{sock.getsockname()[1]}", "--speed", "50")
        packets = datagrams(sock)
    assert r.returncode == 0, r.stderr
    assert "warning: 2 frames with NaN/inf values sent as no-face packets" in r.stderr
    values = _values(packets)
    assert len(packets) == 40 and len(values) == 38 and all(np.isfinite(v).all() for v in values)


def test_replay_seed_and_oversized_names_are_input_errors():
    take = synthetic_take(10)
    with pytest.raises(InputError, match="--seed"):
        replay_take(take, "127.0.0.1", 44999, impairment=Impairment(seed=-1))
    with pytest.raises(InputError, match="1024-byte datagram limit"):
        replay_take(take, "127.0.0.1", 44999, speed=50.0, subject="x" * 3000)
    # The longest names that fit give packets of exactly the limit.
    device = take.meta.device
    subject = "s" * (ll.MAX_PACKET_BYTES - ll.FRAME_BLOCK_BYTES - 9 - len(device))
    with udp_receiver() as sock:
        report = replay_take(take, "127.0.0.1", sock.getsockname()[1], speed=50.0, subject=subject)
        packets = datagrams(sock)
    assert report.packets_sent == 10 and {len(p) for p in packets} == {ll.MAX_PACKET_BYTES}
    with pytest.raises(InputError, match="datagram limit"):
        replay_take(take, "127.0.0.1", 44999, speed=50.0, subject=subject + "s")


def test_replay_audio_out_folders(tmp_path):
    take = synthetic_take(30, audio=True)
    (tmp_path / "afile.csv").write_text("")
    (tmp_path / "folder").mkdir()
    with udp_receiver() as sock:
        port = sock.getsockname()[1]
        replay_take(take, "127.0.0.1", port, audio_out=tmp_path / "new" / "a" / "x.wav")
        assert (tmp_path / "new" / "a" / "x.wav").is_file()
        for out, message in [
            (tmp_path / "folder", "is a folder"),
            (tmp_path / "afile.csv" / "x.wav", "cannot create the output's folder"),
            ("/proc/x.wav", "cannot write --audio-out"),
        ]:
            with pytest.raises(InputError, match=message):
                replay_take(take, "127.0.0.1", port, audio_out=out)


@pytest.mark.parametrize(
    "tool, args, needle",
    [
        ("capture", ["replay", "TAKE", "--seed", "-1"], "--seed must be a non-negative"),
        ("capture", ["replay", "TAKE", "--subject", "x" * 3000], "datagram limit"),
        ("capture", ["replay", "TAKE", "--audio-out", "TMP"], "is a folder"),
        ("viewer", ["stream", "TAKE", "--subject", "x" * 3000], "datagram limit"),
        ("viewer", ["stream", "TMP", "--speed", "50"], "found 2 takes under it"),
    ],
)
def test_cli_errors_are_one_line_before_anything_is_sent(tmp_path, tool, args, needle):
    folder = write_take(synthetic_take(10, audio=True), tmp_path / "takes")
    write_take(synthetic_take(10, seed=1), tmp_path / "takes")
    names = {"TAKE": str(folder), "TMP": str(tmp_path / "takes")}
    with udp_receiver() as sock:
        to = f"127.0.0.1:{sock.getsockname()[1]}"
        r = run_cli(tool, *[names.get(a, a) for a in args], "--to", to)
        assert datagrams(sock) == []
    assert r.returncode == 1
    assert needle in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_export_csv_writes_nonfinite_frames_as_face_lost_rows(tmp_path):
    """A hand-edited take with NaN/inf in tracked frames: the CSV holds no `nan` cell or partial row."""
    take = synthetic_take(30, seed=3)
    take.values[4, 7] = np.nan
    take.values[9, 60] = np.inf
    folder = write_take(take, tmp_path / "takes")
    r = run_cli("capture", "export-csv", folder, "-o", tmp_path / "x.csv", "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["nonfinite_rows"] == 2
    assert "2 frames with NaN/inf values written as face-lost rows" in r.stderr
    text = (tmp_path / "x.csv").read_text()
    assert "nan" not in text.lower() and "inf" not in text.lower()
    rows = text.splitlines()[1:]
    assert len(rows) == 30 and rows[4].endswith(",0") and rows[9].endswith(",0")
    back = read_livelink_csv(tmp_path / "x.csv")
    lost = np.flatnonzero(back.frame_status == FrameStatus.FACE_LOST)
    assert lost.tolist() == [4, 9]
    keep = np.setdiff1d(np.arange(30), lost)
    np.testing.assert_allclose(back.values[keep], take.values[keep], atol=1e-6)
