"""The live Live Link recorder: a UDP socket loop that logs every accepted packet crash-safely.

One ``LiveRecorder`` owns a session folder ``<out>/<session>.recording/`` holding ``frames.log``
(packets, stream announcements, sync events, rejection counts) and, with audio, ``audio.log``. The
socket loop does as little as possible per datagram: check the header (a byte comparison against the
last stream's header in the common case), stamp the arrival on the session clock and append one
checksummed record with the packet's raw frame block (FRAME), or with its frame time alone for a
packet the app sends while it sees no face (NO_FACE: the frame is kept, as FACE_LOST). Decoding into
values, duplicate removal, ordering and gap filling happen when the takes are built from the log
(``session_takes``), so memory stays flat however long the session runs. A stream is a device id and
subject from one source address: another source of known names gets a stream of its own (``_stream_key``),
which the take builder joins to the first unless it is a second sender; a sender that sends from a new
source port again and again goes on in one stream (``PORT_HOPS``). At a stop the datagrams already queued
are read too; those the system dropped with the receive queue full are counted (``receive_queue_drops``).
Buffers are handed to the log writer thread at least every ``flush_interval_s`` (default 0.1 s), which
writes and fsyncs them.
"""

from __future__ import annotations

import contextlib
import ipaddress
import os
import socket
import struct
import time
import zlib
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from . import livelink as ll
from .errors import InputError
from .record_log import RECORD_HEADER, LogWriter, RecordType, json_record
from .serial_sync import SyncEvent, sync_record
from .session_clock import SessionClock

FRAMES_LOG = "frames.log"
AUDIO_LOG = "audio.log"
COMPLETE_FILE = "complete.json"
SESSION_SUFFIX = ".recording"
DEFAULT_PORT = 11111
FRAME_PREFIX = struct.Struct("<BHq")  # record type, stream id, arrival ns
MAX_STREAM_ID = 0xFFFF  # stream ids are 16-bit in the frame records
MAX_STREAMS = MAX_STREAM_ID + 1  # ids 0..0xFFFF: the most streams a session tells apart
FRAME_PAYLOAD_BYTES = FRAME_PREFIX.size + ll.FRAME_BLOCK_BYTES  # 272
NO_FACE_PAYLOAD_BYTES = FRAME_PREFIX.size + ll.FRAME_TIME_BYTES  # 27
_RECV_BYTES = 65536  # larger than any UDP datagram, so an oversized one is seen whole and counted


def new_session_id() -> str:
    """``live-YYYYmmddTHHMMSSZ-<pid>``: sortable, unique per process and second."""
    return time.strftime("live-%Y%m%dT%H%M%SZ", time.gmtime()) + f"-{os.getpid()}"


class AllowList:
    """The source addresses ``listen --allow`` accepts: IP addresses and networks (``192.168.1.0/24``).

    On a dual-stack socket (``--bind ::``) an IPv4 sender shows as ``::ffff:a.b.c.d``: it matches its IPv4
    address or network as well (and an IPv4-mapped entry matches the IPv4 sender); a link-local source's
    ``%scope`` is ignored. ``host in allow`` is a set lookup for the listed addresses; other sources are
    matched once and remembered.
    """

    _MEMO = 4096  # sources remembered; a flood of spoofed sources only costs a rematch

    def __init__(self, addresses: Iterable[str]):
        exact: set[str] = set()
        networks: list[ipaddress.IPv4Network | ipaddress.IPv6Network] = []
        for a in addresses:
            text = a.strip()
            try:
                if "/" in text:
                    net = ipaddress.ip_network(text, strict=False)
                    if net.num_addresses == 1:
                        exact.add(str(net.network_address))
                    else:
                        networks.append(net)
                else:
                    ip = ipaddress.ip_address(text)
                    exact.add(str(ip.ipv4_mapped or ip) if ip.version == 6 else str(ip))
            except ValueError:
                raise InputError(f"--allow takes IP addresses or networks (a.b.c.d/n), not {a!r}") from None
        self.entries = sorted(exact) + sorted({str(n) for n in networks})
        # Each IPv4 address also as a dual-stack socket reports it (IPv4-mapped entries were made IPv4).
        self.exact = frozenset(exact | {f"::ffff:{e}" for e in exact if ":" not in e})
        self.networks = tuple(networks)
        self._memo: dict[str, bool] = {}

    def __contains__(self, host: str) -> bool:
        if host in self.exact:
            return True
        found = self._memo.get(host)
        if found is None:
            found = self._match(host)
            if len(self._memo) >= self._MEMO:
                self._memo.clear()
            self._memo[host] = found
        return found

    def _match(self, host: str) -> bool:
        try:
            ip = ipaddress.ip_address(host.split("%", 1)[0])
        except ValueError:
            return False
        forms: list[ipaddress.IPv4Address | ipaddress.IPv6Address] = [ip]
        if ip.version == 6 and ip.ipv4_mapped is not None:
            forms.append(ip.ipv4_mapped)
        elif ip.version == 4:
            forms.append(ipaddress.IPv6Address(f"::ffff:{ip}"))
        return any(
            str(f) in self.exact or any(f.version == n.version and f in n for n in self.networks)
            for f in forms
        )


def parse_allow_list(addresses: Iterable[str] | None) -> AllowList | None:
    """The allow-list of ``--allow`` (``InputError`` for anything but IP addresses and networks)."""
    if not addresses:
        return None
    return AllowList(addresses)


def receive_queue_drops(sock: socket.socket) -> int | None:
    """Datagrams the system dropped because ``sock``'s receive queue was full (the listener suspended or
    behind in a burst): they never reach ``recvfrom``, so only the kernel's count tells of them. Linux
    gives it per socket in the ``drops`` column of /proc/net/udp(6), found by the socket's inode; None
    where it cannot be read (another system, no /proc)."""
    try:
        inode = str(os.fstat(sock.fileno()).st_ino)
        for table in ("/proc/self/net/udp", "/proc/self/net/udp6"):
            with open(table, encoding="ascii", errors="replace") as f:
                next(f, None)  # the column titles
                for line in f:
                    fields = line.split()
                    # sl local remote st tx:rx tr:when retrnsmt uid timeout inode ref pointer drops
                    if len(fields) >= 13 and fields[9] == inode:
                        return int(fields[12])
    except (OSError, ValueError):
        return None
    return None


def _unspecified(host: str) -> bool:
    """Whether ``host`` is the all-interfaces address (``0.0.0.0``, ``::``)."""
    try:
        return ipaddress.ip_address(host.split("%", 1)[0]).is_unspecified
    except ValueError:
        return False


# A known stream that sends another rate (the app restarted with another frame-rate setting) goes on as a
# new recording once this many packets in a row carry the new rate; until then they are held back, and
# if the old rate comes back first they are rejected (``rate_changed``: a corrupt or spoofed packet).
RATE_CHANGE_PACKETS = 3
# A packet of the old rate among those held back at a new one is late (it leaves them held, see
# ``LiveRecorder._old_rate_packet``) when its frame time is at most this much (seconds) before theirs; one
# from later, or from further back, is the old rate coming back.
LATE_PACKET_S = 0.25
# A rate within RATE_JITTER (relative) of the stream's is no change of setting but a sender that declares
# its measured rate (a PC app or script: 58-62 around 60): logged as it comes, the take builder decides.
RATE_JITTER = 0.08


def close_rates(num_a: int, den_a: int, num_b: int, den_b: int) -> bool:
    """Whether two declared rates are within ``RATE_JITTER`` of each other (in integers)."""
    a, b = num_a * ll.rate_denominator(den_b), num_b * ll.rate_denominator(den_a)
    return abs(a - b) <= RATE_JITTER * min(a, b)


# When every --max-streams slot is taken, a stream that has sent at most STRAY_PACKETS datagrams and
# nothing for STRAY_SILENT_S seconds (a stray or spoofed packet) gives its slot to a new stream; its
# packets stay in the log. Checked at most once per second, on the slow path of a new stream only.
STRAY_PACKETS = 5
STRAY_SILENT_S = 10.0


# The socket loop wakes up at least this often (seconds) to flush, check the duration and signals.
SOCKET_WAKE_S = 0.05
# What a stop may spend reading the datagrams still queued (a sender flooding on is cut off there).
STOP_DRAIN_S = 0.5

# A sender whose packets of one device id and subject come from this many source ports of one address in a
# row, each of the earlier ones used for at most PORT_HOP_PACKETS packets (a script opening a socket per
# packet), is taken to hop ports: its packets from further ports go on in the stream of its latest port.
# Without this each packet made a stream: the --max-streams slots filled, and the rest of its packets were
# rejected (``too_many_streams``). A sender restarted on a new port has sent for longer than that.
PORT_HOPS = 4
PORT_HOP_PACKETS = 120

# Longest wait between log flushes: what a crash can cost of the packets received (0.25 s of frames).
MAX_FLUSH_INTERVAL_S = 0.25


def _frame_seconds(frame: float, num: int, den: int) -> float:
    """A frame time (frame number and sub-frame) in seconds at the declared rate ``num/den``."""
    return frame * ll.rate_denominator(den) / num


def bound_udp_socket(bind: str, port: int, wake_s: float) -> socket.socket:
    """A UDP socket bound to ``bind``:``port`` that wakes every ``wake_s`` s, with a deep receive queue
    (it rides out disk hiccups and bursts; capped by net.core.rmem_max), ``::`` taking IPv4 senders too;
    an ``InputError`` naming the address when it cannot be had."""
    try:
        family = socket.AF_INET6 if ":" in bind else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_DGRAM)
    except OSError as exc:
        raise InputError(f"cannot create a UDP socket: {exc}") from None
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
        if family == socket.AF_INET6 and _unspecified(bind):
            # ``::`` takes IPv4 senders too (as ::ffff:a.b.c.d), whatever the system's default.
            with contextlib.suppress(OSError, AttributeError):
                sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 0)
        sock.bind((bind, port))
    except (OSError, OverflowError) as exc:
        sock.close()
        raise InputError(f"cannot listen on UDP {bind}:{port}: {exc}") from None
    except BaseException:  # a stop signal (listen's set-up): the socket is not kept yet
        sock.close()
        raise
    sock.settimeout(wake_s)
    return sock


class LiveRecorder:
    """Receives Live Link packets on a UDP socket and logs them; see the module docstring.

    Use: ``open()`` (binds, returns the address), ``run()`` until ``duration_s`` or ``request_stop()``,
    then ``close()``; build takes with ``session_takes.build_takes(recorder.session_dir, out_dir)``.
    """

    def __init__(
        self,
        out_dir: str | Path,
        bind: str = "127.0.0.1",
        port: int = DEFAULT_PORT,
        allow: Iterable[str] | None = None,
        flush_interval_s: float = 0.1,
        max_streams: int = 512,
        fsync: bool = True,
        session_id: str | None = None,
        clock: SessionClock | None = None,
    ):
        if not 0 <= port <= 65535:
            raise InputError(f"UDP port {port} is not in 0..65535")
        if not 0 < flush_interval_s <= MAX_FLUSH_INTERVAL_S:
            raise InputError(f"the flush interval must be in (0, {MAX_FLUSH_INTERVAL_S:g}] seconds")
        if not 1 <= max_streams <= MAX_STREAMS:
            raise InputError(f"max_streams must be in 1..{MAX_STREAMS}, got {max_streams}")
        self.out_dir = Path(out_dir)
        self.bind = bind
        self.port = port
        self.allow = parse_allow_list(allow)
        self.flush_interval_s = flush_interval_s
        self.max_streams = max_streams
        self.fsync = fsync
        self.session_id = session_id or new_session_id()
        self.clock = clock or SessionClock()
        self.session_dir = self.out_dir / (self.session_id + SESSION_SUFFIX)
        self.on_first_packet: Callable[[int], None] | None = None
        self.datagrams = 0
        self.accepted = 0
        self.rejected: dict[str, int] = dict.fromkeys(ll.REJECT_REASONS, 0)
        # header (or header and source address, see _stream_key) -> (id, offset, num, den)
        self.streams: dict[bytes | tuple[bytes, Any], tuple[int, int, int, int]] = {}
        # per stream id (ids are never reused): datagrams logged, the arrival of the last one, its source
        self.stream_packets: list[int] = []
        self.stream_last_ns: list[int] = []
        self.stream_sources: list[Any] = []
        self.evicted_streams = 0
        # stream key -> (new rate, records of the packets held back at it, the first one's frame time in
        # seconds); see RATE_CHANGE_PACKETS
        self._rate_pending: dict[bytes | tuple[bytes, Any], tuple[tuple[int, int], list[bytes], float]] = {}
        # stream key -> (its rate before its last change, the first frame time at the new one in seconds):
        # a late packet of the old setting after the change is logged (``_rate_change``), not rejected
        self._rate_changed: dict[bytes | tuple[bytes, Any], tuple[tuple[int, int], float]] = {}
        self._next_eviction_ns = 0
        # (header, source host) -> its last PORT_HOPS stream ids; the key a port-hopping host goes on in
        self._host_streams: dict[tuple[bytes, Any], list[int]] = {}
        self._port_hops: dict[tuple[bytes, Any], bytes | tuple[bytes, Any]] = {}
        self.socket_errors = 0
        # Datagrams the system dropped with this socket's receive queue full (``receive_queue_drops``):
        # read at the status lines and when closing; None where the system does not say.
        self.receive_drops: int | None = None
        self._stop = False
        self.sock: socket.socket | None = None
        self.log: LogWriter | None = None

    # -- set-up -------------------------------------------------------------------------------
    def open(self) -> tuple[str, int]:
        """Create the session folder and log, bind the socket; returns the bound (address, port)."""
        sock = bound_udp_socket(self.bind, self.port, SOCKET_WAKE_S)
        try:
            self.session_dir.mkdir(parents=True, exist_ok=True)
            self.log = LogWriter(self.session_dir / FRAMES_LOG, fsync=self.fsync)
        except BaseException as exc:  # a read-only or full output folder, a file in the way; a stop signal
            sock.close()
            if isinstance(exc, OSError):
                raise InputError(
                    f"cannot write the session log: {exc.strerror or exc}", self.session_dir
                ) from None
            raise
        self.sock = sock
        host, port = sock.getsockname()[:2]
        self.log.put(
            json_record(
                RecordType.SESSION,
                {
                    "session": self.session_id,
                    "clock": self.clock.to_json(),
                    "bind": host,
                    "port": port,
                    "allow": self.allow.entries if self.allow else None,
                    "pid": os.getpid(),
                    "host": socket.gethostname(),
                    "flush_interval_s": self.flush_interval_s,
                },
            )
        )
        return host, port

    def add_sync(self, event: SyncEvent) -> None:
        """Log a sync-box event (thread-safe; called from the serial reader)."""
        assert self.log is not None
        self.log.put(sync_record(event))

    def note(self, data: dict[str, Any]) -> None:
        """Log an event worth keeping (thread-safe)."""
        assert self.log is not None
        self.log.put(json_record(RecordType.NOTE, data))

    def request_stop(self) -> None:
        """Ask ``run`` to return (safe from signal handlers and other threads)."""
        self._stop = True

    # -- the socket loop ----------------------------------------------------------------------
    def run(
        self,
        duration_s: float | None = None,
        status: Callable[[dict[str, Any]], None] | None = None,
        status_every_s: float = 10.0,
        on_flush: Callable[[], None] | None = None,
    ) -> None:
        """Receive and log until ``duration_s`` (seconds) has passed or ``request_stop()``.

        ``status`` is called about every ``status_every_s`` seconds with the counts so far;
        ``on_flush`` after every flush (e.g. to warn at once of a failed log write).
        """
        assert self.sock is not None and self.log is not None, "open() first"
        sock, log, rejected = self.sock, self.log, self.rejected
        buf = bytearray(_RECV_BYTES)
        view = memoryview(buf)
        out = log.buffer
        now_ns = time.monotonic_ns
        crc32 = zlib.crc32
        pack_prefix = FRAME_PREFIX.pack
        frame_header = RECORD_HEADER.pack
        unpack_time = ll._FRAME_TIME.unpack_from
        unpack_len = ll._LEN.unpack_from
        streams = self.streams
        packets, last_seen, sources = self.stream_packets, self.stream_last_ns, self.stream_sources
        payload_len = FRAME_PAYLOAD_BYTES
        count = ll.BLENDSHAPE_COUNT
        block = ll.FRAME_BLOCK_BYTES
        allow = self.allow
        allow_exact = allow.exact if allow is not None else frozenset()
        pending_rates = self._rate_pending
        # The source address of every datagram (not only for --allow): senders sharing a device id and
        # subject are told apart by it (_stream_key).
        recvfrom_into = sock.recvfrom_into
        flush_ns = int(self.flush_interval_s * 1e9)
        start = now_ns()
        next_flush = start + flush_ns
        status_ns = int(status_every_s * 1e9)
        next_status = start + status_ns
        end = start + int(duration_s * 1e9) if duration_s is not None else None
        # The stream of the previous packet: most datagrams repeat its header byte for byte, from its source.
        last_hdr, last_size, last_off, last_sid, last_num, last_den = b"\xff", -1, 0, 0, 0, 0
        last_addr: Any = None
        datagrams = accepted = 0
        first_cb = self.on_first_packet
        last_rejects = dict(rejected)
        addr: Any = None
        # After request_stop the datagrams already in the receive queue are read too (they reached this
        # computer before the stop), without waiting for more, for at most STOP_DRAIN_S.
        draining_until = 0
        try:
            while True:
                if self._stop and not draining_until:
                    draining_until = now_ns() + int(STOP_DRAIN_S * 1e9)
                    sock.setblocking(False)
                try:
                    n, addr = recvfrom_into(buf)
                except TimeoutError:
                    n = -1
                except BlockingIOError:  # draining, and the queue is empty
                    break
                except OSError:
                    self.socket_errors += 1
                    n = -1
                t = now_ns()
                if n >= 0:
                    datagrams += 1
                    if allow is not None and addr[0] not in allow_exact and addr[0] not in allow:
                        rejected["not_allowed"] += 1
                    else:
                        sid = -1
                        if (
                            n == last_size
                            and not pending_rates  # a packet of the old rate then: ``_old_rate_packet``
                            and addr == last_addr
                            and buf.startswith(last_hdr)
                            and buf[last_off + 16] == count
                        ):
                            fn, sf, num, den = unpack_time(buf, last_off)
                            if num == last_num and den == last_den and fn >= 0 and 0.0 <= sf < 1.0:
                                sid, off = last_sid, last_off
                        elif n >= 9 and buf[0] == 6:
                            # Another known stream (several phones interleave): look its header up.
                            (n1,) = unpack_len(buf, 1)
                            if 0 <= n1 <= n - 9:
                                (n2,) = unpack_len(buf, 5 + n1)
                                off = 9 + n1 + n2
                                if n2 >= 0 and off + block == n and buf[off + 16] == count:
                                    key = skey = bytes(view[:off])
                                    known = streams.get(key)
                                    if known is None or sources[known[0]] != addr:  # the rare case
                                        skey = self._stream_key(key, addr)
                                        known = streams.get(skey)
                                    if known is not None:
                                        fn, sf, num, den = unpack_time(buf, off)
                                        if (
                                            num == known[2]
                                            and den == known[3]
                                            and fn >= 0
                                            and 0.0 <= sf < 1.0
                                        ):
                                            sid = known[0]
                                            last_hdr, last_size, last_off, last_sid = key, n, off, sid
                                            last_num, last_den, last_addr = num, den, addr
                                            if pending_rates and skey in pending_rates:
                                                self._old_rate_packet(skey, fn + sf, num, den)
                        if sid < 0:
                            found = self._classify(view, n, addr, t)
                            if found is None:  # held back (a rate change not yet confirmed)
                                last_hdr, last_size = b"\xff", -1  # its stream's next packet: looked up
                            elif isinstance(found, str):
                                rejected[found] += 1
                            else:
                                sid, off, last_num, last_den = found
                                last_hdr, last_size, last_off, last_sid = (
                                    bytes(buf[:off]),
                                    off + block,
                                    off,
                                    sid,
                                )
                                last_addr = addr
                        if sid >= 0:
                            packets[sid] += 1
                            last_seen[sid] = t
                            if n == off + block:
                                body = view[off : off + block]
                                prefix = pack_prefix(RecordType.FRAME, sid, t)
                                out += frame_header(payload_len, crc32(body, crc32(prefix)))
                            else:  # a no-face packet (only _classify accepts one): its frame time
                                body = view[off : off + ll.FRAME_TIME_BYTES]
                                prefix = pack_prefix(RecordType.NO_FACE, sid, t)
                                out += frame_header(NO_FACE_PAYLOAD_BYTES, crc32(body, crc32(prefix)))
                            out += prefix
                            out += body
                            accepted += 1
                            if first_cb is not None:
                                first_cb(t)
                                first_cb = None
                if t >= next_flush:
                    if rejected != last_rejects:
                        out += json_record(RecordType.REJECTS, rejected)
                        last_rejects = dict(rejected)
                    log.flush()
                    next_flush = t + flush_ns
                    if on_flush is not None:
                        on_flush()
                    if status is not None and t >= next_status:
                        next_status = t + status_ns
                        rejected_now = sum(rejected.values())
                        self.receive_drops = receive_queue_drops(sock)
                        status(
                            {
                                "elapsed_s": (t - start) / 1e9,
                                "datagrams": self.datagrams + datagrams,
                                "accepted": self.accepted + accepted,
                                "rejected": rejected_now,
                                "streams": len(streams),
                                "evicted_streams": self.evicted_streams,
                                "failed_writes": log.failed_writes,
                                "receive_queue_drops": self.receive_drops or 0,
                            }
                        )
                    if end is not None and t >= end:
                        break
                elif end is not None and t >= end:
                    break
                if draining_until and t >= draining_until:
                    break
        finally:
            if draining_until:
                sock.settimeout(SOCKET_WAKE_S)
            self.datagrams += datagrams
            self.accepted += accepted
            self.on_first_packet = first_cb
            log.flush()

    def _classify(
        self, view: memoryview, n: int, addr: Any, t: int
    ) -> tuple[int, int, int, int] | str | None:
        """Full check of a datagram that does not repeat the last stream's header (or is a no-face
        packet, which a new stream may also start with), arrived at ``t`` (ns).

        Returns (stream id, frame-block offset, rate numerator, denominator), a rejection reason, or None
        for a packet held back (a known stream at another rate, see ``RATE_CHANGE_PACKETS``).
        """
        off, reason = ll.parse_header(view, n)
        if reason is not None:
            return reason
        reason = ll.check_body(view, off, n)
        if reason is not None:
            return reason
        fn, sf, num, den = ll._FRAME_TIME.unpack_from(view, off)
        header = bytes(view[:off])
        key = self._stream_key(header, addr)
        known = self.streams.get(key)
        if known is not None:
            if (known[2], known[3]) != (num, den) and not close_rates(known[2], known[3], num, den):
                return self._rate_change(key, known, view, n, num, den, t)
            if key in self._rate_pending:
                self._old_rate_packet(key, fn + sf, num, den)
            return known
        names = ll.decode_strings(view, off)
        if names is None:
            return "bad_text"
        if len(self.streams) >= self.max_streams and not self._evict_stray_streams():
            return "too_many_streams"
        if len(self.stream_packets) >= MAX_STREAMS:  # ids are never reused: evicted streams keep theirs
            return "too_many_streams"
        sid = len(self.stream_packets)
        entry = (sid, off, num, den)
        record = {
            "stream": sid,
            "device": names[0],
            "subject": names[1],
            "rate_numerator": num,
            "rate_denominator": den,
            "source": addr[0] if addr else None,
            "port": addr[1] if addr else None,
        }
        if key != header:  # another source of these names: the take builder decides what it is
            record["alongside"] = self.streams[header][0]
        self.streams[key] = entry
        self._count_source_port(header, key, addr, sid)
        self.stream_packets.append(0)
        self.stream_last_ns.append(time.monotonic_ns())
        self.stream_sources.append(addr)
        assert self.log is not None
        self.log.buffer += json_record(RecordType.STREAM, record)
        return entry

    def _count_source_port(self, header: bytes, key: bytes | tuple[bytes, Any], addr: Any, sid: int) -> None:
        """Note a new stream ``sid`` of its host; when the host hops ports (``PORT_HOPS``), its later ports
        go on in this stream (noted in the log)."""
        if not addr:
            return
        host = (header, addr[0])
        recent = self._host_streams.setdefault(host, [])
        recent.append(sid)
        del recent[:-PORT_HOPS]
        earlier = recent[:-1]
        if len(earlier) == PORT_HOPS - 1 and all(self.stream_packets[s] <= PORT_HOP_PACKETS for s in earlier):
            if host not in self._port_hops:
                assert self.log is not None
                self.log.buffer += json_record(
                    RecordType.NOTE, {"kind": "port_hopping", "stream": sid, "source": addr[0]}
                )
            self._port_hops[host] = key

    def _stream_key(self, header: bytes, addr: Any) -> bytes | tuple[bytes, Any]:
        """The key of the stream a packet with ``header`` (device id and subject) from ``addr`` belongs to:
        ``header`` for the first source of these names, ``(header, addr)`` for any other. The recorder
        cannot tell yet what another source is (a second sender with the same names, the app sending to
        this computer twice from a socket per Live Link target, the app restarted on another port), so
        it logs it as a stream of its own whose STREAM record says ``alongside`` which; the take builder
        keeps it apart only when it sent at the same time as the first and not copies of its frames. A host
        that hops ports (``PORT_HOPS``) goes on in the stream of its latest new port."""
        own = (header, addr)
        if own in self.streams:
            return own
        known = self.streams.get(header)
        if known is None or self.stream_sources[known[0]] == addr:
            return header
        hop = self._port_hops.get((header, addr[0] if addr else None))
        return hop if hop in self.streams else own

    def _rate_change(
        self,
        key: bytes,
        known: tuple[int, int, int, int],
        view: memoryview,
        n: int,
        num: int,
        den: int,
        t: int,
    ) -> tuple[int, int, int, int] | None:
        """A packet of a known stream at another rate: held back until ``RATE_CHANGE_PACKETS`` in a row
        carry that rate; then the held packets are logged (the take builder starts a new recording where
        the rate changes), the stream goes on at the new rate, and its entry is returned for this packet."""
        sid, off, old_num, old_den = known
        fn, sf, _, _ = ll._FRAME_TIME.unpack_from(view, off)
        seconds = _frame_seconds(fn + sf, num, den)
        before = self._rate_changed.get(key)
        if (
            before is not None
            and close_rates(*before[0], num, den)
            and 0 < before[1] - seconds <= LATE_PACKET_S
        ):
            # a packet of the setting before the last change, from just before it, come late (after the
            # packets that confirmed it): logged as it is, the take builder puts it with its own setting
            return known
        held = self._rate_pending.get(key)
        if held is not None and held[0] != (num, den):  # yet another rate: the held packets were strays
            self._drop_rate_change(key)
            held = None
        if held is None:
            held = ((num, den), [], seconds)
            self._rate_pending[key] = held
        if len(held[1]) + 1 < RATE_CHANGE_PACKETS:
            held[1].append(self._frame_record(sid, view, off, n, t))
            return None
        del self._rate_pending[key]
        assert self.log is not None
        self.log.buffer += json_record(
            RecordType.NOTE,
            {"kind": "rate_change", "stream": sid, "from": [old_num, old_den], "rate": [num, den]},
        )
        for record in held[1]:
            self.log.buffer += record
        self.accepted += len(held[1])
        self.stream_packets[sid] += len(held[1])
        entry = (sid, off, num, den)
        self.streams[key] = entry
        self._rate_changed[key] = ((old_num, old_den), held[2])
        return entry

    def _old_rate_packet(self, key: bytes, frame: float, num: int, den: int) -> None:
        """A packet of stream ``key`` at its own rate (``frame``: its frame number and sub-frame) while
        packets at another rate are held back: the old rate came back, and they were strays
        (``_drop_rate_change``), unless it is a packet of the old setting from just before them
        (``LATE_PACKET_S``: late, or the copy of a sender that sends each packet twice), which leaves them
        held. Before, such a packet at the app's change of setting cost the new setting's first frames."""
        held = self._rate_pending[key]
        early_s = held[2] - _frame_seconds(frame, num, den)
        if not 0 < early_s <= LATE_PACKET_S:
            self._drop_rate_change(key)

    def _drop_rate_change(self, key: bytes) -> None:
        """Reject the packets held back at another rate for stream ``key`` (``rate_changed``)."""
        held = self._rate_pending.pop(key, None)
        if held is not None:
            self.rejected["rate_changed"] += len(held[1])

    @staticmethod
    def _frame_record(sid: int, view: memoryview, off: int, n: int, t: int) -> bytes:
        """The log record of a packet (FRAME, or NO_FACE for one that ends after the frame time)."""
        if n - off == ll.FRAME_TIME_BYTES:
            kind, size, body = RecordType.NO_FACE, NO_FACE_PAYLOAD_BYTES, bytes(view[off:n])
        else:
            kind, size, body = (
                RecordType.FRAME,
                FRAME_PAYLOAD_BYTES,
                bytes(view[off : off + ll.FRAME_BLOCK_BYTES]),
            )
        prefix = FRAME_PREFIX.pack(kind, sid, t)
        return RECORD_HEADER.pack(size, zlib.crc32(body, zlib.crc32(prefix))) + prefix + body

    def _evict_stray_streams(self) -> bool:
        """Free the slots of stray streams (see ``STRAY_PACKETS``); whether any was freed. At most once
        per second, so that a flood of new streams costs no more than a dictionary lookup each."""
        now = time.monotonic_ns()
        if now < self._next_eviction_ns:
            return False
        self._next_eviction_ns = now + 1_000_000_000
        silent_ns = int(STRAY_SILENT_S * 1e9)
        stray = [
            key
            for key, (sid, _off, _num, _den) in self.streams.items()
            if self.stream_packets[sid] <= STRAY_PACKETS and now - self.stream_last_ns[sid] > silent_ns
        ]
        for key in stray:
            del self.streams[key]
            self._rate_changed.pop(key, None)
            self._drop_rate_change(key)
        self.evicted_streams += len(stray)
        return bool(stray)

    # -- shutdown -----------------------------------------------------------------------------
    def close(self) -> None:
        """Log the final counts and an END record, close the socket and the log (waits for fsync)."""
        for key in list(self._rate_pending):  # a rate change that never got RATE_CHANGE_PACKETS in a row
            self._drop_rate_change(key)
        if self.sock is not None:
            self.receive_drops = receive_queue_drops(self.sock)
        if self.log is not None:
            self.log.buffer += json_record(RecordType.REJECTS, self.rejected)
            end: dict[str, Any] = {"datagrams": self.datagrams, "accepted": self.accepted}
            end["socket_errors"] = self.socket_errors
            if self.receive_drops is not None:
                end["receive_queue_drops"] = self.receive_drops
            self.log.buffer += json_record(RecordType.END, end)
            self.log.close()  # a failed write is kept in the log, not raised: the caller reports it
        if self.sock is not None:
            self.sock.close()
            self.sock = None
