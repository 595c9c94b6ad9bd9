"""Remote control of Live Link Face over OSC (formats doc §6): record, stream target, battery, heat.

The phone listens for OSC on UDP (default port 8000) and answers to the address set with
``/OSCSetSendTarget <ip> <port>``. ``PhoneRemote`` binds one local UDP socket, tells the phone to
answer there, and then sends commands from it and waits for the confirmations.
"""

from __future__ import annotations

import math
import socket
import time
from typing import Any

from .errors import InputError

DEFAULT_OSC_PORT = 8000


def _osc():
    try:
        from pythonosc.osc_message import OscMessage
        from pythonosc.osc_message_builder import OscMessageBuilder
    except ImportError:
        raise InputError("phone remote control needs the Python package python-osc") from None
    return OscMessage, OscMessageBuilder


def local_address_towards(host: str, family: int = socket.AF_INET) -> str:
    """The local IP the OS would use to reach ``host`` (a UDP connect sends nothing)."""
    try:
        with socket.socket(family, socket.SOCK_DGRAM) as s:
            s.connect((host, 9))
            return s.getsockname()[0]
    except OSError as exc:
        raise InputError(f"no route to the phone at {host}: {exc}") from None


class PhoneRemote:
    """OSC client for one phone. ``timeout_s`` bounds every wait for a reply (seconds)."""

    def __init__(
        self,
        host: str,
        port: int = DEFAULT_OSC_PORT,
        reply_host: str | None = None,
        reply_port: int = 0,
        timeout_s: float = 2.0,
    ):
        self._message, self._builder = _osc()
        self.host, self.port, self.timeout_s = host, port, timeout_s
        if not 1 <= port <= 65535:
            raise InputError(f"phone port {port} is out of range (1..65535)")
        if not 0 <= reply_port <= 65535:
            raise InputError(f"reply port {reply_port} is out of range (0..65535)")
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise InputError(f"the reply timeout must be a positive number of seconds, not {timeout_s}")
        try:
            found = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
        except (socket.gaierror, UnicodeError) as exc:
            raise InputError(f"cannot resolve the phone's address {host!r}: {exc}") from None
        # IPv4 when the name has both (as before IPv6 was supported), else the IPv6 address.
        family, _, _, _, self.target = min(found, key=lambda f: f[0] != socket.AF_INET)
        self.reply_host = reply_host or local_address_towards(self.target[0], family)
        self.sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            self.sock.bind((self.reply_host, reply_port))
        except OSError as exc:
            self.sock.close()
            raise InputError(f"cannot bind the reply port {self.reply_host}:{reply_port}: {exc}") from None
        self.reply_port = self.sock.getsockname()[1]
        self._target_set = False

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> PhoneRemote:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def send(self, address: str, *args: Any) -> None:
        """Send one OSC message (str, int and float arguments)."""
        b = self._builder(address=address)
        for a in args:
            b.add_arg(a)
        try:
            self.sock.sendto(b.build().dgram, self.target)
        except OSError as exc:
            raise InputError(f"cannot send OSC to {self.host}:{self.port}: {exc}") from None

    def wait_for(self, address: str) -> list[Any]:
        """Arguments of the next message with ``address``; ``InputError`` after the timeout."""
        deadline = time.monotonic() + self.timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise InputError(
                    f"no {address} from the phone at {self.host}:{self.port} within {self.timeout_s:g} s "
                    "(is Live Link Face running with OSC enabled on that port?)"
                )
            self.sock.settimeout(left)
            try:
                data, _ = self.sock.recvfrom(65536)
            except TimeoutError:
                continue
            except OSError:  # ICMP port unreachable comes back as a socket error: keep waiting
                continue
            try:
                msg = self._message(data)
            except Exception:  # python-osc raises its own parse errors: ignore foreign datagrams
                continue
            if msg.address == address:
                return list(msg.params)

    def request(self, address: str, reply: str, *args: Any) -> list[Any]:
        """Send a command and wait for its reply (setting the reply target first)."""
        self.ensure_target()
        self.send(address, *args)
        return self.wait_for(reply)

    def ensure_target(self) -> None:
        """``/OSCSetSendTarget`` to our reply socket, once, confirmed."""
        if not self._target_set:
            self.send("/OSCSetSendTarget", self.reply_host, self.reply_port)
            self.wait_for("/OSCSetSendTargetConfirm")
            self._target_set = True

    # -- commands (formats doc §6) ----------------------------------------------------------
    def record_start(self, slate: str, take: int) -> str:
        """Start recording a take; returns the timecode the phone confirms."""
        return str((self.request("/RecordStart", "/RecordStartConfirm", slate, int(take)) or [""])[0])

    def record_stop(self) -> dict[str, str]:
        """Stop recording; returns the timecode and the phone-side paths of the CSV and MOV."""
        args = self.request("/RecordStop", "/RecordStopConfirm") + ["", "", ""]
        return {"timecode": str(args[0]), "csv": str(args[1]), "mov": str(args[2])}

    def battery(self) -> float:
        """Battery level as the phone reports it (0..1)."""
        return float(self._number("/BatteryQuery", "/Battery", float))

    def thermals(self) -> int:
        """Thermal state (0 nominal, 1 fair, 2 serious, 3 critical)."""
        return int(self._number("/ThermalsQuery", "/Thermals", int))

    def _number(self, query: str, reply: str, kind: type) -> float | int:
        """The first argument of the reply to ``query`` as a finite ``kind``; anything else (no
        argument, text, NaN) is an ``InputError`` that shows the reply as received."""
        args = self.request(query, reply)
        try:
            value = kind(args[0])
            if math.isfinite(value):
                return value
        except (IndexError, TypeError, ValueError, OverflowError):
            pass
        shown = " ".join(repr(a) for a in args) or "(no value)"
        raise InputError(f"unexpected reply from the phone at {self.host}:{self.port}: {reply} {shown}")

    def set_livelink_target(self, host: str, port: int, clear: bool = True) -> None:
        """Make the phone stream Live Link to ``host:port`` (after clearing other targets)."""
        if clear:
            self.send("/ClearAllLiveLinkAddresses")
        self.send("/AddLiveLinkAddress", host, int(port))

    def set_subject(self, name: str) -> None:
        self.send("/LiveLinkSubject", name)

    def stream(self, on: bool) -> None:
        self.send("/LiveLinkStreamStart" if on else "/LiveLinkStreamStop")
