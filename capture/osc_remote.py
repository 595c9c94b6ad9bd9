"""Remote control of Live Link Face over OSC (formats doc §6): record, stream target, battery, heat.

The phone listens for OSC on UDP (default port 8000) and answers to the address set with
``/OSCSetSendTarget <ip> <port>``. ``PhoneRemote`` binds one local UDP socket, tells the phone to
answer there, and then sends commands from it and waits for the confirmations. Only datagrams from the
phone's address count as replies: the app answers from a socket of its own (formats doc §6 names no port
it answers from), so its host is matched, not its port; anyone else's are ignored and named when the
reply does not come.
"""

from __future__ import annotations

import ipaddress
import math
import socket
import struct
import time
from typing import Any

from .command import warn
from .errors import InputError, printable

DEFAULT_OSC_PORT = 8000
INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1  # OSC 'i' arguments are 32-bit (formats doc §6: <take:i>)
# The thermal states ``/Thermals <i>`` reports (iOS ProcessInfo.ThermalState): 0 nominal .. 3 critical.
THERMAL_STATES = ("nominal", "fair", "serious", "critical")
BUNDLE_TAG = b"#bundle\0"
MAX_BUNDLE_DEPTH = 8  # bundles within bundles a reply may nest
# A reply that did not come names the other messages the phone sent meanwhile: at most this many, each
# address cut to this many characters
MAX_SHOWN_OTHERS, MAX_SHOWN_ADDRESS = 5, 60


def osc_text(value: str, what: str) -> str:
    """``value`` if OSC can send it as a string (UTF-8, no NUL byte); else an ``InputError`` naming
    ``what``. Arguments read from a command line in another encoding hold undecodable bytes as lone
    surrogates: they are shown as the bytes given."""
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        try:
            shown = repr(value.encode("utf-8", "surrogateescape"))
        except UnicodeEncodeError:
            shown = ascii(value)
        raise InputError(
            f"{what} {shown} is not UTF-8 text, which OSC strings must be (check the terminal's encoding)"
        ) from None
    if "\0" in value:
        raise InputError(f"{what} {value!r} holds a NUL character, which an OSC string cannot")
    return value


def osc_int32(value: int, what: str, low: int = INT32_MIN) -> int:
    """``value`` if it is an integer in ``low``..2**31-1 (an OSC 'i' argument); else an ``InputError``."""
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= INT32_MAX:
        raise InputError(f"{what} must be an integer in {low}..{INT32_MAX}, not {value!r}")
    return value


def _osc():
    try:
        from pythonosc.osc_message import OscMessage
        from pythonosc.osc_message_builder import OscMessageBuilder
    except ImportError:
        raise InputError("phone remote control needs the Python package python-osc") from None
    return OscMessage, OscMessageBuilder


def bundled_messages(dgram: bytes, depth: int = 0) -> list[bytes]:
    """The OSC messages of a datagram: itself, or the elements of a bundle (OSC 1.0: ``#bundle\\0``, an
    8-byte time tag, then elements of an int32 size and that many bytes), nested bundles opened.
    ``ValueError`` for a bundle that does not hold together: an element size that is not positive, not a
    multiple of 4 or past the datagram's end, or bundles nested deeper than ``MAX_BUNDLE_DEPTH``
    (python-osc's own bundle parser loops forever on a negative size)."""
    if not dgram.startswith(BUNDLE_TAG):
        return [dgram]
    if depth >= MAX_BUNDLE_DEPTH:
        raise ValueError(f"bundles nested more than {MAX_BUNDLE_DEPTH} deep")
    messages: list[bytes] = []
    at = len(BUNDLE_TAG) + 8  # past the time tag
    if len(dgram) < at:
        raise ValueError("bundle cut short in its time tag")
    while at < len(dgram):
        if len(dgram) - at < 4:
            raise ValueError(f"{len(dgram) - at} stray bytes after the last bundle element")
        (size,) = struct.unpack_from(">i", dgram, at)
        at += 4
        if size <= 0 or size % 4 or size > len(dgram) - at:
            raise ValueError(f"bundle element size {size} at byte {at - 4} of {len(dgram)}")
        messages += bundled_messages(dgram[at : at + size], depth + 1)
        at += size
    return messages


def resolve_target(host: str, port: int) -> str:
    """The IP address for ``/AddLiveLinkAddress`` (the app takes an address, not a name): ``host``
    resolved here, IPv4 first as for the phone; ``InputError`` when it does not resolve."""
    osc_text(host, "the Live Link target")
    try:
        found = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
    except (OSError, UnicodeError) as exc:  # socket.gaierror is an OSError
        raise InputError(f"cannot resolve the Live Link target {host!r}: {exc}") from None
    return str(min(found, key=lambda f: f[0] != socket.AF_INET)[4][0])


def local_address_towards(host: str, family: int = socket.AF_INET) -> str:
    """The local IP the OS would use to reach ``host`` (a UDP connect sends nothing)."""
    try:
        with socket.socket(family, socket.SOCK_DGRAM) as s:
            s.connect((host, 9))
            return s.getsockname()[0]
    except OSError as exc:
        raise InputError(f"no route to the phone at {host}: {exc}") from None


def check_record_start(slate: str, take: int) -> None:
    """``InputError`` unless ``/RecordStart`` can carry this slate (UTF-8 text) and take (int32, >= 0)."""
    osc_text(slate, "the slate")
    osc_int32(take, "the take number", low=0)


def check_subject(name: str) -> None:
    """``InputError`` unless ``name`` is a subject name ``/LiveLinkSubject`` can carry (UTF-8, not blank)."""
    osc_text(name, "the subject name")
    if not name.strip():
        raise InputError("the subject name is empty")


def _ip_of(host: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address | None:
    """The IP address ``host`` (numeric, an IPv6 scope left out) names; None when it names none."""
    try:
        return ipaddress.ip_address(host.split("%")[0])
    except ValueError:
        return None


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
        if reply_host is not None:  # sent to the phone in /OSCSetSendTarget: checked before anything
            osc_text(reply_host, "the reply address")
        try:
            found = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
        except (socket.gaierror, UnicodeError) as exc:
            raise InputError(f"cannot resolve the phone's address '{printable(host)}': {exc}") from None
        # IPv4 when the name has both (as before IPv6 was supported), else the IPv6 address.
        family, _, _, _, self.target = min(found, key=lambda f: f[0] != socket.AF_INET)
        self.reply_host = reply_host or local_address_towards(self.target[0], family)
        self.sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            self.sock.bind((self.reply_host, reply_port))
        except (OSError, UnicodeError) as exc:
            self.sock.close()
            raise InputError(f"cannot bind the reply port {self.reply_host}:{reply_port}: {exc}") from None
        self.reply_port = self.sock.getsockname()[1]
        self._target_set = False
        self.ignored_datagrams = 0  # replies that were not OSC (warned about once)
        # datagrams from hosts other than the phone's, ignored: how many, and their senders (HOST:PORT, in
        # the order they came; one more than are shown tells that there were more)
        self.stranger_datagrams = 0
        self.strangers: dict[str, None] = {}
        self._phone_ip = _ip_of(self.target[0])  # what ``from_phone`` compares senders with, parsed once

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> PhoneRemote:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def shown(self) -> str:
        """The phone's address as HOST:PORT (``[IPV6]:PORT``)."""
        from .replay import format_destination

        return format_destination(self.host, self.port)

    def message(self, address: str, *args: Any) -> bytes:
        """One OSC message as a datagram: str arguments as 's' (UTF-8, ``osc_text``), int as 'i' (32-bit),
        float as 'f'. Anything else, or a value OSC cannot carry, is an ``InputError``: callers build
        every message of a command before sending the first, so a bad argument sends nothing."""
        b = self._builder(address=address)
        for a in args:
            if isinstance(a, str):
                b.add_arg(osc_text(a, f"{address} argument"), "s")
            elif isinstance(a, int) and not isinstance(a, bool):
                b.add_arg(osc_int32(a, f"{address} argument"), "i")
            elif isinstance(a, float) and math.isfinite(a) and abs(a) <= 3.4e38:
                b.add_arg(a, "f")
            else:
                raise InputError(f"{address}: cannot send {a!r} as an OSC string, 32-bit integer or float")
        try:
            return b.build().dgram
        except Exception as exc:  # python-osc's BuildError; the checks above should leave none
            raise InputError(f"cannot build the OSC message {address}: {exc}") from None

    def send_datagram(self, dgram: bytes) -> None:
        try:
            self.sock.sendto(dgram, self.target)
        except OSError as exc:
            raise InputError(f"cannot send OSC to {self.shown()}: {exc}") from None

    def send(self, address: str, *args: Any) -> None:
        """Send one OSC message (str, int and float arguments, see ``message``)."""
        self.send_datagram(self.message(address, *args))

    def from_phone(self, sender: tuple) -> bool:
        """Whether a datagram's sender address (``recvfrom``'s) is the phone's host, the one commands go
        to (any port: the app answers from a socket of its own; an IPv6 scope is not compared). Commands
        sent to the unspecified address (``0.0.0.0``, ``::``) reach this machine, whose replies come from
        a loopback address."""
        phone, came_from = self._phone_ip, _ip_of(sender[0])
        if phone is None or came_from is None:
            return False
        return came_from == phone or (phone.is_unspecified and came_from.is_loopback)

    def _stranger(self, sender: tuple) -> None:
        """Count a datagram from a host that is not the phone (``from_phone``): ignored."""
        from .replay import format_destination

        self.stranger_datagrams += 1
        if len(self.strangers) <= MAX_SHOWN_OTHERS:
            self.strangers[format_destination(str(sender[0]), int(sender[1]))] = None

    def _strangers_note(self) -> str:
        """What a timeout says of the datagrams from other hosts that were ignored ('' for none)."""
        if not self.strangers:
            return ""
        shown = ", ".join(list(self.strangers)[:MAX_SHOWN_OTHERS])
        more = " ..." if len(self.strangers) > MAX_SHOWN_OTHERS else ""
        n = self.stranger_datagrams
        return f"; {n} datagram(s) from {shown}{more}, not the phone's address, were ignored"

    def wait_for(self, address: str) -> list[Any]:
        """Arguments of the next message with ``address`` from the phone's host (``from_phone``);
        ``InputError`` after the timeout, naming the other messages that came meanwhile (a phone that
        answered, but not this) and the hosts whose datagrams were ignored."""
        deadline = time.monotonic() + self.timeout_s
        others: dict[str, None] = {}  # addresses of the other messages, in the order they came
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                n = self.ignored_datagrams
                ignored = f"; {n} datagram(s) that were not OSC were ignored" if n else ""
                if others:
                    # (escaped: what a sender chose, kept to one line and off the terminal's controls)
                    cut = [a[:MAX_SHOWN_ADDRESS] for a in list(others)[:MAX_SHOWN_OTHERS]]
                    shown = ", ".join(a.encode("unicode_escape").decode("ascii") for a in cut)
                    why = f": it sent {shown}{' ...' if len(others) > MAX_SHOWN_OTHERS else ''} instead"
                else:
                    why = " (is Live Link Face running with OSC enabled on that port?)"
                raise InputError(
                    f"no {address} from the phone at {self.shown()} within {self.timeout_s:g} s{why}{ignored}"
                    + self._strangers_note()
                )
            self.sock.settimeout(left)
            try:
                data, sender = self.sock.recvfrom(65536)
            except TimeoutError:
                continue
            except OSError:  # ICMP port unreachable comes back as a socket error: keep waiting
                continue
            if not self.from_phone(sender):
                self._stranger(sender)
                continue
            for msg in self._messages(data):
                if msg.address == address:
                    return list(msg.params)
                if len(others) <= MAX_SHOWN_OTHERS:  # one more tells that there were more
                    others[msg.address] = None

    def _messages(self, data: bytes) -> list[Any]:
        """The OSC messages of a datagram: itself, or those of a bundle (OSC 1.0 lets a sender wrap its
        replies in one, nested too: ``bundled_messages``); none for a datagram that is not OSC, which is
        counted in ``ignored_datagrams`` and warned about on stderr the first time."""
        try:
            return [self._message(m) for m in bundled_messages(data)]
        except Exception as exc:  # python-osc raises its own parse errors: ignore foreign datagrams
            self.ignored_datagrams += 1
            if self.ignored_datagrams == 1:
                warn(
                    f"a datagram on the reply port {self.reply_port} is not OSC ({str(exc)[:200]}): ignored, "
                    "as are any more such"
                )
            return []

    def request(self, address: str, reply: str, *args: Any) -> list[Any]:
        """Send a command and wait for its reply (setting the reply target first; the command is built,
        and so its arguments checked, before anything is sent)."""
        dgram = self.message(address, *args)
        self.ensure_target()
        self.send_datagram(dgram)
        return self.wait_for(reply)

    def unexpected(self, reply: str, args: list[Any], note: str = "") -> InputError:
        """The error for a reply whose arguments are not what formats doc §6 says, shown as received."""
        shown = " ".join(repr(a) for a in args) or "(no value)"
        return InputError(f"unexpected reply from the phone at {self.shown()}: {reply} {shown}{note}")

    def _texts(self, reply: str, args: list[Any], n: int, note: str = "") -> list[str]:
        """The first ``n`` arguments of a reply that must be strings ('' for missing ones)."""
        if any(not isinstance(a, str) for a in args[:n]):
            raise self.unexpected(reply, args, note)
        return [*args[:n], *[""] * (n - len(args[:n]))]

    def ensure_target(self) -> None:
        """``/OSCSetSendTarget`` to our reply socket, once, confirmed."""
        if not self._target_set:
            self.send("/OSCSetSendTarget", self.reply_host, self.reply_port)
            self.wait_for("/OSCSetSendTargetConfirm")
            self._target_set = True

    # -- commands (formats doc §6) ----------------------------------------------------------
    def record_start(self, slate: str, take: int) -> str:
        """Start recording a take; returns the timecode the phone confirms."""
        check_record_start(slate, take)
        args = self.request("/RecordStart", "/RecordStartConfirm", slate, take)
        note = " (the phone did confirm the start)"
        return self._texts("/RecordStartConfirm", args, 1, note)[0]

    def record_stop(self) -> dict[str, str]:
        """Stop recording; returns the timecode and the phone-side paths of the CSV and MOV."""
        args = self.request("/RecordStop", "/RecordStopConfirm")
        note = " (the phone did confirm the stop)"
        timecode, csv, mov = self._texts("/RecordStopConfirm", args, 3, note)
        return {"timecode": timecode, "csv": csv, "mov": mov}

    def battery(self) -> float:
        """Battery level as the phone reports it (0..1): an OSC float (an integer is taken too), with the
        7 significant digits a 32-bit float holds (0.8, not 0.800000011920929)."""
        args = self.request("/BatteryQuery", "/Battery")
        value = args[0] if args else None
        if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
            return float(f"{value:.7g}")
        raise self.unexpected("/Battery", args)

    def thermals(self) -> int:
        """Thermal state (``THERMAL_STATES``: 0 nominal, 1 fair, 2 serious, 3 critical): an OSC integer (a
        float only when whole; 2.7 is no thermal state, nor is 7 or -1)."""
        args = self.request("/ThermalsQuery", "/Thermals")
        value = args[0] if args else None
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if isinstance(value, int) and not isinstance(value, bool) and 0 <= value < len(THERMAL_STATES):
            return value
        states = ", ".join(f"{i} {name}" for i, name in enumerate(THERMAL_STATES))
        raise self.unexpected("/Thermals", args, f" (the thermal states are {states})")

    def set_livelink_target(self, host: str, port: int, clear: bool = True) -> None:
        """Make the phone stream Live Link to ``host:port`` (after clearing other targets). ``host``
        is sent as given (the app wants an IP address: ``resolve_target`` gives one); both messages
        are built before the first is sent, so a bad target does not leave the phone without one."""
        osc_int32(port, "the Live Link target port", low=1)
        if port > 65535:
            raise InputError(f"the Live Link target port {port} is out of range (1..65535)")
        add = self.message("/AddLiveLinkAddress", osc_text(host, "the Live Link target"), port)
        if clear:
            self.send("/ClearAllLiveLinkAddresses")
        self.send_datagram(add)

    def set_subject(self, name: str) -> None:
        check_subject(name)
        self.send("/LiveLinkSubject", name)

    def stream(self, on: bool) -> None:
        self.send("/LiveLinkStreamStart" if on else "/LiveLinkStreamStop")
