"""``listen --phone`` records a MetaHuman Animator subject of the newer app's realtime stream as takes of
its own controls (CONTROLS records in the frames log, ``capture.cps_control.PhoneStream``), and
``recover`` rebuilds them; against the simulated phone over real loopback sockets."""

from __future__ import annotations

import json

import numpy as np
import pytest
from live_helpers import Listener, run_cli, synthetic_take, wait_until

from capture import cps_control as cps
from capture.realtime_packet import HEAD_CHANNELS, controls_record, decode_realtime_packet
from capture.record_log import LogReader, LogWriter, RecordType, json_record
from capture.simulate.cps_phone import DEVICE_ID, MHA_CONTROLS, RealtimeFrames, SimulatedPhone
from capture.take import read_take


def _quantized(frames: RealtimeFrames, n: int) -> np.ndarray:
    """The first ``n`` controls as the phone sends them (u16 / 65535)."""
    return (np.rint(np.clip(frames.controls[:, :n].astype(np.float64), 0, 1) * 65535) / 65535).astype(
        np.float32
    )


def _logged(session_dir, kind: RecordType) -> list[bytes]:
    return [bytes(p) for p in LogReader(session_dir / "frames.log") if p[0] == kind]


def _listen_to(phone: SimulatedPhone, out) -> Listener:
    host, port = phone.start()
    return Listener(out, "--phone", f"{host}:{port}")


def test_listen_phone_records_an_mha_subject_as_takes_of_its_own_controls(tmp_path):
    frames = RealtimeFrames.of_take(synthetic_take(180))
    with SimulatedPhone(frames, behaviour="mha") as phone:
        listener = _listen_to(phone, tmp_path / "out")
        try:
            wait_until(phone.finished, "all frames sent")
            wait_until(
                lambda: len(_logged(listener.session_dir, RecordType.CONTROLS)) >= 180, "frames logged"
            )
        finally:
            summaries, err, code = listener.stop()
    assert code == 0, err
    assert "Traceback" not in err
    assert "streams subject iPhone (8 MetaHuman Animator controls)" in err
    (stream,) = [json.loads(p[1:]) for p in _logged(listener.session_dir, RecordType.STREAM)]
    assert (
        stream["controls"] == [*MHA_CONTROLS, *HEAD_CHANNELS] and stream["source_kind"] == "livelink_realtime"
    )
    (take_summary,) = summaries
    assert take_summary["device"] == DEVICE_ID and take_summary["subject"] == "iPhone"
    assert take_summary["valid_frames"] == 180 and take_summary["dropped_frames"] == 0
    take = read_take(take_summary["path"])
    assert (
        take.meta.channels == [*MHA_CONTROLS, *HEAD_CHANNELS] and take.meta.source_kind == "livelink_realtime"
    )
    assert take.meta.fps == 60
    np.testing.assert_array_equal(take.values[:, :8], _quantized(frames, 8))
    np.testing.assert_array_equal(take.values[:, 8:], frames.head_pose[:, [2, 1, 0]])
    # recover rebuilds the same take from the session log
    rebuilt = run_cli("recover", str(listener.session_dir.parent), "--all", "-o", str(tmp_path / "again"))
    assert rebuilt.returncode == 0, rebuilt.stderr
    (again,) = (tmp_path / "again").iterdir()
    again_take = read_take(again)
    assert again_take.meta.channels == [*MHA_CONTROLS, *HEAD_CHANNELS]
    np.testing.assert_array_equal(again_take.values, take.values)


def test_recover_after_a_kill_keeps_the_mha_frames_logged(tmp_path):
    frames = RealtimeFrames.of_take(synthetic_take(600))
    with SimulatedPhone(frames, behaviour="mha") as phone:
        listener = _listen_to(phone, tmp_path / "out")
        try:
            wait_until(lambda: len(_logged(listener.session_dir, RecordType.CONTROLS)) >= 60, "frames logged")
        finally:
            listener.kill()
    logged = len(_logged(listener.session_dir, RecordType.CONTROLS))
    rebuilt = run_cli("recover", str(listener.session_dir.parent), "-o", str(tmp_path / "again"), "--json")
    assert rebuilt.returncode == 0, rebuilt.stderr
    (again,) = (tmp_path / "again").iterdir()
    take = read_take(again)
    assert take.meta.channels == [*MHA_CONTROLS, *HEAD_CHANNELS]
    assert take.values.shape == (logged, 11)
    np.testing.assert_array_equal(take.values[:, :8], _quantized(frames, 8)[:logged])


def test_a_stream_whose_control_names_the_log_lost_keeps_its_frames(tmp_path):
    """CONTROLS records without their STREAM record (a damaged stretch): the frames stay, as control_0..."""
    session = tmp_path / "s.recording"
    session.mkdir()
    frames = RealtimeFrames.of_take(synthetic_take(60))
    log = LogWriter(session / "frames.log", fsync=False)
    log.put(json_record(RecordType.SESSION, {"session": "s", "clock": {"origin_ns": 0}}))
    for k in range(60):
        packet = decode_realtime_packet(frames.packet(k, controls=3))
        log.put(controls_record(5, 10_000_000 + k * 16_666_667, packet))
    log.put(json_record(RecordType.CONTROLS, {"not": "a frame"}))  # a CONTROLS record of no frame
    log.close()
    rebuilt = run_cli("recover", str(session), "-o", str(tmp_path / "takes"), "--json")
    assert rebuilt.returncode == 0, rebuilt.stderr
    (folder,) = (tmp_path / "takes").iterdir()
    take = read_take(folder)
    assert take.meta.channels == ["control_0", "control_1", "control_2"]
    assert any(r["kind"] == "controls_unnamed" for r in take.meta.repairs)
    np.testing.assert_array_equal(take.values, _quantized(frames, 3))


@pytest.mark.parametrize(
    ("controls", "why"),
    [
        (["CTRL_a", "ctrl_A"], "names a control twice (CTRL_a, ctrl_A; case is ignored)"),
        ([], "has an empty control list or an empty control name"),
    ],
)
def test_an_mha_subject_whose_controls_cannot_be_channels_is_refused_with_a_line(controls, why):
    subject = cps.RemoteSubject("id1", "Face", "mha", 1, controls)
    with pytest.raises(
        cps.ControlError,
        match=r"lists no subject to stream \(subject 'id1' " + why.replace("(", r"\(").replace(")", r"\)"),
    ):
        cps.choose_subject([subject], [])
