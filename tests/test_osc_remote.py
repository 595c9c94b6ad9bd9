"""Phone remote control over OSC, against a python-osc server standing in for Live Link Face."""

from __future__ import annotations

import json
import threading
import time

import pytest
from live_helpers import run_cli
from pythonosc.dispatcher import Dispatcher
from pythonosc.osc_server import BlockingOSCUDPServer
from pythonosc.udp_client import SimpleUDPClient

from capture import InputError
from capture.osc_remote import PhoneRemote


class FakePhone:
    """Answers the §6 commands like the app; remembers what it was told."""

    def __init__(self, host: str = "127.0.0.1", battery=0.75, thermals=1):
        self.received: list[tuple] = []
        self.reply: SimpleUDPClient | None = None
        self.battery, self.thermals = battery, thermals
        d = Dispatcher()
        d.set_default_handler(self._any)
        self.server = BlockingOSCUDPServer((host, 0), d)
        self.port = self.server.server_address[1]
        self.thread = threading.Thread(
            target=self.server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True
        )
        self.thread.start()

    def _any(self, address, *args):
        self.received.append((address, *args))
        if address == "/OSCSetSendTarget":
            self._close_reply()  # a new target: the app answers there from now on
            self.reply = SimpleUDPClient(args[0], args[1])
            self.reply.send_message("/OSCSetSendTargetConfirm", [])
        elif self.reply is None:
            return
        elif address == "/RecordStart":
            self.reply.send_message("/RecordStartConfirm", ["00:00:00.000"])
        elif address == "/RecordStop":
            self.reply.send_message(
                "/RecordStopConfirm", ["00:01:02.500", "/takes/a_1_iPhone.csv", "/takes/a_1_iPhone.mov"]
            )
        elif address == "/BatteryQuery":
            self.reply.send_message("/Battery", [self.battery])
        elif address == "/ThermalsQuery":
            self.reply.send_message("/Thermals", [self.thermals])

    def _close_reply(self):
        if self.reply is not None:
            self.reply._sock.close()  # python-osc's client has no close of its own

    def close(self):
        self.server.shutdown()
        self.server.server_close()
        self._close_reply()


@pytest.fixture
def phone():
    p = FakePhone()
    yield p
    p.close()


def test_remote_api(phone):
    with PhoneRemote("127.0.0.1", phone.port, timeout_s=5) as remote:
        assert remote.record_start("MySlate", 7) == "00:00:00.000"
        assert remote.battery() == pytest.approx(0.75)
        assert remote.thermals() == 1
        stop = remote.record_stop()
        assert stop == {
            "timecode": "00:01:02.500",
            "csv": "/takes/a_1_iPhone.csv",
            "mov": "/takes/a_1_iPhone.mov",
        }
        remote.set_livelink_target("127.0.0.1", 11111)
        remote.set_subject("Alice")
        remote.stream(True)
    for _ in range(100):  # fire-and-forget commands: wait (bounded) for the phone to have handled them
        if len(phone.received) >= 9:
            break
        time.sleep(0.02)
    addresses = [r[0] for r in phone.received]
    assert addresses.count("/OSCSetSendTarget") == 1
    assert ("/RecordStart", "MySlate", 7) in phone.received
    assert ("/AddLiveLinkAddress", "127.0.0.1", 11111) in phone.received
    assert addresses.index("/ClearAllLiveLinkAddresses") < addresses.index("/AddLiveLinkAddress")
    assert ("/LiveLinkSubject", "Alice") in phone.received


def test_remote_cli_end_to_end(phone):
    r = run_cli("remote", f"127.0.0.1:{phone.port}", "--json", "record-start", "Slate", "3")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout) | {} == {
        "phone": f"127.0.0.1:{phone.port}",
        "action": "record-start",
        "timecode": "00:00:00.000",
        "slate": "Slate",
        "take": 3,
    }
    r = run_cli("remote", f"127.0.0.1:{phone.port}", "--json", "battery")
    assert json.loads(r.stdout)["battery"] == pytest.approx(0.75)
    r = run_cli("remote", f"127.0.0.1:{phone.port}", "--json", "target", "127.0.0.1:11111")
    assert r.returncode == 0 and json.loads(r.stdout)["target"] == "127.0.0.1:11111"


def test_silent_phone_is_a_one_line_error():
    with pytest.raises(InputError, match="OSCSetSendTargetConfirm"):
        with PhoneRemote("127.0.0.1", 9, timeout_s=0.3) as remote:
            remote.battery()
    r = run_cli("remote", "127.0.0.1:9", "--timeout", "0.3", "thermals")
    assert r.returncode == 1 and len(r.stderr.splitlines()) == 1 and "Traceback" not in r.stderr


def _one_line_error(r, text: str) -> None:
    assert r.returncode == 1, r.stderr
    assert text in r.stderr and "Traceback" not in r.stderr and len(r.stderr.splitlines()) == 1, r.stderr


def test_bad_options_and_addresses_are_one_line_errors():
    for args, text in [
        (["127.0.0.1", "--reply-port", "99999", "battery"], "--reply-port 99999 is out of range"),
        (["127.0.0.1:99999", "battery"], "port 99999 is out of range"),
        (["127.0.0.1:0", "battery"], "port 0 is out of range"),
        (["[::1", "battery"], "IPV6"),
        (["[::1]x", "battery"], "IPV6"),
        (["127.0.0.1:x", "battery"], "HOST:PORT"),
        (["127.0.0.1", "--timeout", "nan", "battery"], "--timeout"),
        (["127.0.0.1", "--timeout", "inf", "battery"], "--timeout"),
    ]:
        _one_line_error(run_cli("remote", *args), text)
    with pytest.raises(InputError, match="out of range"):
        PhoneRemote("127.0.0.1", 8000, reply_port=70000)


def test_ipv6_phone_with_and_without_port():
    phone = FakePhone("::1")
    try:
        r = run_cli("remote", f"[::1]:{phone.port}", "--timeout", "5", "--json", "battery")
        assert r.returncode == 0, r.stderr
        assert json.loads(r.stdout)["battery"] == pytest.approx(0.75)
        assert json.loads(r.stdout)["phone"] == f"[::1]:{phone.port}"
    finally:
        phone.close()
    # A bare IPv6 address takes the default OSC port: nobody answers there, so a timeout, not a parse error.
    r = run_cli("remote", "::1", "--timeout", "0.3", "battery")
    _one_line_error(r, "[::1]:8000" if "[::1]" in r.stderr else "::1")
    assert "OSCSetSendTargetConfirm" in r.stderr


@pytest.mark.parametrize(
    ("action", "battery", "thermals", "shown"),
    [
        ("battery", "full", 1, "/Battery 'full'"),
        ("thermals", 0.5, "hot", "/Thermals 'hot'"),
        ("battery", float("nan"), 1, "/Battery nan"),
    ],
)
def test_non_numeric_replies_are_unexpected(action, battery, thermals, shown):
    phone = FakePhone(battery=battery, thermals=thermals)
    try:
        r = run_cli("remote", f"127.0.0.1:{phone.port}", "--timeout", "5", action)
        _one_line_error(r, "unexpected reply")
        assert shown in r.stderr
    finally:
        phone.close()
