"""Review of ``listen --phone`` (the newer app's realtime stream): names a classic packet cannot carry as
they came (a lone surrogate, which JSON's ``\\ud800`` gives), and the dual-stack relay of a phone given by
its IPv4-mapped address, which still refuses other senders; over real loopback sockets, against the
simulated phone (``capture.simulate.cps_phone``)."""

from __future__ import annotations

import hashlib
import json
import re
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from live_helpers import _raw_line, record_phone, synthetic_take, wait_for_logged_frames, wait_until

from capture import cps_control as cps
from capture.record_log import LogReader, RecordType
from capture.simulate.cps_phone import RealtimeFrames, SimulatedPhone


def test_a_device_id_and_subject_with_a_lone_surrogate_are_recorded_under_their_escapes(tmp_path):
    # The phone's JSON may hold "\ud800", which reads as a lone surrogate: no UTF-8 text, so no classic
    # packet's name. Old: a traceback in the relay thread at the first packet, no take.
    frames = RealtimeFrames.of_take(synthetic_take(60))
    summaries, err, code, session = record_phone(
        tmp_path / "out", frames, device="\ud800-phone", subject="Ann\udfff"
    )
    assert code == 0 and "Traceback" not in err, err
    (summary,) = summaries
    # as the takes of a MetaHuman Animator subject, logged with its own controls, name them
    assert (summary["device"], summary["subject"]) == ("\\ud800-phone", "Ann\\udfff")
    assert summary["valid_frames"] == 60 and summary["rejected"] == {}
    assert "a classic packet holds" not in err  # escaped, not shortened


def _rejected_in_log(session: Path) -> dict:
    """The last rejection counts the recorder logged (a REJECTS record at a flush where they changed)."""
    counts: dict = {}
    for payload in LogReader(session / "frames.log"):
        if payload[0] == RecordType.REJECTS:
            counts = json.loads(bytes(payload[1:]))
    return counts


def test_a_dual_stack_relay_for_an_ipv4_mapped_phone_refuses_other_senders(tmp_path):
    # --phone [::ffff:127.0.0.1]: the relay binds :: and compares senders unmapped. Packets of the same
    # subject from another address (127.0.0.2, a sender on the network) are not the phone's: refused.
    # Old: the phone's own packets were refused too (no take).
    try:
        stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        stranger.bind(("127.0.0.2", 0))
    except OSError:
        pytest.skip("no second loopback address here")
    frames = RealtimeFrames.of_take(synthetic_take(60))
    out = tmp_path / "out"
    with stranger, SimulatedPhone(frames) as phone:
        _, port = phone.start()
        cmd = [sys.executable, "-m", "capture", "listen", "-o", str(out), "--json", "--duration", "60"]
        listen = subprocess.Popen(
            [*cmd, "--phone", f"[::ffff:127.0.0.1]:{port}"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            line = _raw_line(listen.stderr.fileno())
            m = re.search(r"on udp://\[::\]:(\d+) -> (.*)$", line.strip())
            assert m, line
            relay_port, session = int(m.group(1)), Path(m.group(2))
            wait_until(lambda: cps.START_STREAMING in phone.requests, "the phone asked to stream")
            for k in range(30):
                stranger.sendto(frames.packet(k), ("127.0.0.1", relay_port))
            wait_until(
                lambda: _rejected_in_log(session).get("realtime_not_allowed") == 30, "30 packets refused"
            )
            wait_until(phone.finished, "all frames sent")
            wait_for_logged_frames(session, 60)
        finally:
            listen.send_signal(signal.SIGINT)
            stdout, err = listen.communicate(timeout=60)
    assert listen.returncode == 0 and "Traceback" not in err, err
    (summary,) = [json.loads(x) for x in stdout.splitlines() if x.strip()]
    assert summary["valid_frames"] == 60 and summary["rejected"] == {"realtime_not_allowed": 30}


def test_only_the_name_too_long_for_a_classic_packet_is_cut_and_the_line_says_which(tmp_path):
    # A short device id and a subject name of 800 bytes: the device id stays whole, the subject name is
    # cut and ends in '~' and 8 hex digits of its SHA-1. Old: every packet rejected as oversized, no take;
    # then the line said both were cut ("name them cut to fit, each ended by").
    subject = "Sprecherin " * 80
    frames = RealtimeFrames.of_take(synthetic_take(60))
    summaries, err, code, session = record_phone(tmp_path / "out", frames, device="phone-1", subject=subject)
    assert code == 0 and "Traceback" not in err, err
    (summary,) = summaries
    assert summary["valid_frames"] == 60 and summary["device"] == "phone-1"
    assert summary["subject"].endswith("~" + hashlib.sha1(subject.encode()).hexdigest()[:8])
    assert subject.startswith(summary["subject"][:-9])
    records = LogReader(session / "frames.log")
    notes = [json.loads(bytes(p[1:])) for p in records if p[0] == RecordType.NOTE]
    (note,) = [n for n in notes if n.get("kind") == "phone_names_shortened"]
    assert "the takes name the subject name cut to fit, ended by '~'" in note["message"]
    assert note["message"] in err
