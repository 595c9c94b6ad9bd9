"""``s2a-capture listen / recover / replay / remote``: live capture, crash recovery, the simulated
iPhone and phone remote control. ``register(sub)`` adds them to the ``s2a-capture`` parser."""

from __future__ import annotations

import argparse
import contextlib
import glob
import json
import math
import os
import shutil
import signal
import socket
import stat
import sys
import threading
import time
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

from .audio_capture import AudioLog, DeviceAudioSource, FileAudioSource, check_regular_file
from .command import Terminated, emit_json, progress, sigterm_stops, warn
from .cps_control import PhoneStream
from .errors import InputError, S2AError, printable
from .file_lock import fcntl, try_lock
from .importer import find_sources, import_source
from .osc_remote import DEFAULT_OSC_PORT, PhoneRemote, check_record_start, check_subject, resolve_target
from .record_log import MAGIC, RECORD_HEADER, LogReader, LogWriter, RecordType
from .recorder import (
    AUDIO_LOG,
    DEFAULT_PORT,
    FRAMES_LOG,
    MAX_FLUSH_INTERVAL_S,
    MAX_STREAMS,
    LiveRecorder,
    parse_allow_list,
)
from .replay import Impairment, format_destination, parse_destination, replay_take
from .serial_sync import SerialSync, open_serial
from .session_takes import TAKE_COUNTS, build_takes, find_sessions
from .take import Take, is_take_dir, read_meta, read_take
from .workers import process_runs

# Held (flock) by ``listen`` in the session folder from before the recorder opens until the takes are
# built: ``recover`` leaves a session whose lock is held alone.
SESSION_LOCK = "listen.lock"
# A process counts as a session's recorder when it started no later than this after the session did
# (the tick and boot-time rounding of /proc); one started later got the recorder's pid after it died.
PID_START_SLACK_S = 2.0
# While ``listen`` sets up, stop signals wait for the bookkeeping under way (making the session folder, its
# lock and logs: milliseconds) for at most this long (seconds) and then stop it; one that comes later or in
# a step that waits (opening the sound device, reading --audio-file) stops it at once (``_SetUp``). A second
# one within the bookkeeping waits too: raised there, it could leave a log's writer thread or an open file
# behind, between its making and its keeping (two quick Ctrl-Cs did, about once in ten).
SETUP_DEFER_S = 0.2


def _whole_number_in(low: int, high: int):
    """An argparse type: a whole number in ``low``..``high`` (else a usage error)."""

    def whole_number(text: str) -> int:
        try:
            n = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"invalid int value: {text!r}") from None
        if not low <= n <= high:
            raise argparse.ArgumentTypeError(f"must be in {low}..{high}, not {n}")
        return n

    return whole_number


_stream_slots = _whole_number_in(1, MAX_STREAMS)
# A sound device's rate and channels as the audio log and a WAV header hold them: a negative rate (a
# negative buffer size) or a channel count past a C int was a traceback of the sound library (cffi's
# OverflowError), not PortAudio's one-line refusal.
_audio_rate = _whole_number_in(1, (1 << 32) - 1)
_audio_channels = _whole_number_in(1, (1 << 16) - 1)


def _flush_interval(text: str) -> float:
    try:
        seconds = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid float value: {text!r}") from None
    if not 0 < seconds <= MAX_FLUSH_INTERVAL_S:
        raise argparse.ArgumentTypeError(f"must be in (0, {MAX_FLUSH_INTERVAL_S:g}] seconds, not {text}")
    return seconds


def _bind_address(text: str) -> str:
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty address; all interfaces are 0.0.0.0 (IPv4) or :: (IPv6)")
    return text


def register(sub: argparse._SubParsersAction) -> None:
    """Add the live-capture subcommands to the ``s2a-capture`` subparsers."""
    p = sub.add_parser(
        "listen",
        help="record Live Link UDP packets (and audio, sync markers) into takes, crash-safe",
        description="Record every Live Link device/subject as its own take until --duration, SIGINT, "
        "SIGTERM or SIGHUP. Packets are logged crash-safely under OUT/<session>.recording/ while recording.",
    )
    p.add_argument("-o", "--out", type=Path, required=True, help="folder for the takes and the session log")
    p.add_argument(
        "--port",
        type=int,
        help="UDP port (default: 11111, with --phone any free port; 0 = any free port)",
    )
    p.add_argument(
        "--bind",
        metavar="ADDR",
        type=_bind_address,
        help="address to listen on (default: 127.0.0.1; with --phone 0.0.0.0 for a phone given by its IPv4 "
        "address, else ::; a LAN address for a phone on Wi-Fi; 0.0.0.0 or :: for all)",
    )
    p.add_argument(
        "--phone",
        metavar="HOST:PORT",
        help="record Live Link Face's realtime stream (the app's Unreal Engine 5.6+ mode): connect to the "
        "phone's control port as the app shows it and ask it to stream an ARKit subject here",
    )
    p.add_argument(
        "--allow", nargs="+", metavar="ADDR", help="accept packets only from these source addresses"
    )
    p.add_argument("--duration", metavar="S", type=float, help="stop after this many seconds")
    src = p.add_mutually_exclusive_group()
    src.add_argument(
        "--audio-device", metavar="DEVICE", help="record audio from this sound device (index or name)"
    )
    src.add_argument(
        "--audio-file",
        metavar="FILE",
        type=Path,
        help="play this sound file as the session audio (tests, replays)",
    )
    p.add_argument(
        "--audio-start",
        choices=("listen", "first-packet"),
        default="listen",
        help="when --audio-file playback starts (first-packet: at the first Live Link packet)",
    )
    p.add_argument(
        "--audio-rate", metavar="HZ", type=_audio_rate, default=48000, help="sound-device sample rate in Hz"
    )
    p.add_argument(
        "--audio-channels", metavar="N", type=_audio_channels, default=1, help="sound-device channels"
    )
    p.add_argument(
        "--serial", metavar="URL", help="sync box: serial device or pyserial URL (socket://, loop://)"
    )
    p.add_argument("--baud", type=int, default=115200, help="serial baud rate")
    p.add_argument(
        "--flush-interval",
        metavar="S",
        type=_flush_interval,
        default=0.1,
        help=f"seconds between log flushes (at most {MAX_FLUSH_INTERVAL_S:g})",
    )
    p.add_argument(
        "--max-streams",
        metavar="N",
        type=_stream_slots,
        default=512,
        help=f"most device/subject pairs recorded at once (1..{MAX_STREAMS})",
    )
    p.add_argument("--json", action="store_true", help="print one JSON line per take when done")
    p.set_defaults(handler=cmd_listen)

    p = sub.add_parser(
        "recover",
        help="turn the logs a killed listen left behind into takes",
        description="Rebuild takes from unfinished sessions (*.recording folders) under DIR; a torn log "
        "tail is reported and everything before it is kept. Sessions a running listen is still recording "
        "are skipped (that listen builds their takes when it stops).",
    )
    p.add_argument("dir", type=Path, help="a listen output folder or one session folder")
    p.add_argument("-o", "--out", type=Path, help="where to write the takes (default: beside the session)")
    p.add_argument("--all", action="store_true", help="also rebuild sessions that finished cleanly")
    p.add_argument("--json", action="store_true", help="one JSON line per take")
    p.set_defaults(handler=cmd_recover)

    p = sub.add_parser(
        "replay",
        help="the simulated iPhone: send a take as Live Link packets",
        description="Send a take (a take folder, ours or the app's, or a Live Link Face CSV) as Live Link "
        "UDP packets in real time, optionally with seeded loss, reordering, duplication and jitter.",
    )
    p.add_argument("take", type=Path, help="a take folder (ours or the app's) or a Live Link Face CSV")
    p.add_argument(
        "--to",
        required=True,
        metavar="HOST:PORT",
        help="where the listener is (with --protocol realtime: where the phone's control server listens)",
    )
    p.add_argument(
        "--protocol",
        choices=("classic", "realtime"),
        default="classic",
        help="classic: Live Link UDP packets to --to; realtime: be the phone of Live Link Face's realtime "
        "stream, serving its control session on --to for listen --phone (default: classic)",
    )
    p.add_argument("--speed", type=float, default=1.0, help="playback speed (1 = real time)")
    p.add_argument("--loss", type=float, default=0.0, help="probability a packet is lost")
    p.add_argument("--reorder", type=float, default=0.0, help="probability a packet is held back")
    p.add_argument("--duplicate", type=float, default=0.0, help="probability a packet is sent twice")
    p.add_argument("--jitter-ms", type=float, default=0.0, help="uniform extra delay per packet, 0..MS")
    p.add_argument("--seed", metavar="N", type=int, default=0, help="seed of the fault generator")
    p.add_argument("--device", help="device id to send (default: the take's, or one derived from its id)")
    p.add_argument("--subject", help="subject name to send (default: the take's, or iPhone)")
    p.add_argument(
        "--audio-out", metavar="FILE", type=Path, help="write the take's audio here for listen --audio-file"
    )
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(handler=cmd_replay)

    p = sub.add_parser(
        "remote",
        help="control Live Link Face on the phone over OSC",
        description="Send OSC commands to Live Link Face (formats doc §6) and wait for its replies.",
    )
    p.add_argument("phone", help="the phone's address (HOST or HOST:PORT, OSC port default 8000)")
    remote_options = (  # each help says its default: an action's --help shows them without one
        (
            "--reply-host",
            {"metavar": "ADDR", "help": "local address the phone answers to (default: the route to it)"},
        ),
        (
            "--reply-port",
            {
                "metavar": "PORT",
                "type": int,
                "default": 0,
                "help": "local UDP port for replies (default: any)",
            },
        ),
        (
            "--timeout",
            {
                "metavar": "S",
                "type": float,
                "default": 2.0,
                "help": "seconds to wait for each reply (default: 2)",
            },
        ),
        ("--json", {"action": "store_true", "help": "print the result as JSON"}),
    )
    for option, how in remote_options:
        p.add_argument(option, **how)
    actions = p.add_subparsers(dest="action", required=True)
    a = actions.add_parser("record-start", help="start recording a take on the phone")
    a.add_argument("slate", help="the slate name the phone gives the take")
    a.add_argument("take_number", type=int, metavar="take", help="the take number (1 or more)")
    actions.add_parser("record-stop", help="stop recording; prints the phone's CSV and MOV paths")
    a = actions.add_parser("target", help="stream Live Link to HOST:PORT (clears other targets)")
    a.add_argument("address", metavar="HOST:PORT", help="where Live Link packets go (this machine's listen)")
    a.add_argument("--keep", action="store_true", help="add to the existing targets instead")
    actions.add_parser("battery", help="battery level")
    actions.add_parser("thermals", help="thermal state")
    a = actions.add_parser("subject", help="set the Live Link subject name")
    a.add_argument("name", help="the subject name the packets carry")
    actions.add_parser("stream-start", help="start Live Link streaming")
    actions.add_parser("stream-stop", help="stop Live Link streaming")
    for action in actions.choices.values():  # the options also after the action: remote PHONE battery --json
        for option, how in remote_options:  # (its default would replace the value given before the action)
            action.add_argument(option, **how | {"default": argparse.SUPPRESS})
    p.set_defaults(handler=cmd_remote)


# What the commonest rejections usually mean, printed under the take lines (or the no-take line).
REJECT_HINTS = {
    "version": "packets that are not Live Link Face version 6: set the app to Live Link (ARKit); "
    "its MetaHuman Animator mode and UE4-era senders use other protocols",
    "oversized": "datagrams over 1024 bytes: the app's packet is 312 bytes, and a device id and subject "
    "of more than 754 UTF-8 bytes together do not fit (use a shorter subject), or another protocol",
    "count": "the app's packets carry 61 values; this sender's count differs. A sender built on "
    "PyLiveLinkFace writes the subject's length in characters, not UTF-8 bytes, so a subject with "
    "non-ASCII letters (é, 話) shifts the rest of its packet: give it an ASCII subject",
    "bad_rate": "a frame rate numerator of 0 or below, a negative denominator, or above 1000 fps",
    "bad_frame_time": "a negative frame number or a sub-frame outside [0, 1): a sub-frame of 1.0 is the "
    "next frame's 0.0 (the sender rounds it up), a negative frame number a clock before its origin",
    "not_allowed": "the sender's address is not in --allow",
    "bad_length": "a device id or subject length that runs past the datagram: the packet is big-endian "
    "(network byte order), and a sender that writes its lengths little-endian (a C#/Unity "
    "BinaryWriter, struct.pack('<i')) has all its packets rejected so",
    "bad_text": "a device id or subject that is not UTF-8 text (the app sends UTF-8): a sender that "
    "writes its names in another encoding (Latin-1, UTF-16) needs ASCII names or UTF-8",
    "size_mismatch": "datagrams longer than the packet they hold (261 bytes after the names): a sender "
    "that pads its packets to a fixed buffer size; send only the packet's bytes",
    "short": "datagrams that end before the packet does (a sender that cuts its packets to a fixed "
    "buffer size, or another protocol)",
    # the relay of --phone (``cps_control.PhoneStream``): realtime packets it did not pass on
    "realtime_not_allowed": "realtime packets from an address other than the phone's (and not in --allow)",
    "realtime_oversized": "realtime datagrams over 8192 bytes: no Live Link Face realtime packet",
    "realtime_short": "realtime datagrams that end before the packet does (another protocol on that port)",
    "realtime_bad_text": "realtime packets whose subject id is not UTF-8 text",
    "realtime_not_streaming": "realtime packets that came while the phone streamed no subject to this "
    "listen (before its control session began, or between two)",
    "realtime_unknown_subject": "realtime packets of a subject the phone does not stream to this listen "
    "(another receiver's, or one from before the phone restarted its stream)",
    "realtime_control_count": "realtime packets whose control count is not the subject's: the phone "
    "changed its subject; listen restarts the control session, as Unreal does",
}


def _printable(line: str) -> str:
    """``line`` with the characters a terminal acts on (escape sequences, carriage returns, bells) written
    as Python escapes: device ids and subjects are what a sender chose, and a hostile one could otherwise
    rewrite the terminal (clear it, forge lines, set the clipboard through an escape sequence)."""
    if line.isprintable():
        return line
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in line)


def _tell(message: str) -> None:
    """``progress`` of a line that may quote what a sender sent (``_printable``)."""
    progress(_printable(message))


# The summary keys of the warnings that are about its whole stream (``_report``); those of a take's own
# counts (``TAKE_COUNTS``) are about that take.
_STREAM_WARNINGS = ("device", "subject", "frame_clock", "clock_steps", "senders", "packets_outside_takes")


def _report(summaries: list[dict], as_json: bool) -> None:
    hinted = False
    # a session's warnings (audio, the receive queue) are in every take's summary, a stream's in each of its
    # takes': each said once, a stream's once per stream (two phones whose clocks both stepped back once
    # get a line each), and a take's with its own counts, for each take it happened in
    said: set[tuple[Any, str]] = set()

    def warnings(s: dict) -> list[str]:
        of_take = set(_warnings({k: s[k] for k in TAKE_COUNTS if k in s}))
        of_stream = set(_warnings({k: s[k] for k in _STREAM_WARNINGS if k in s}))

        def whose(line: str) -> Any:
            if line in of_take:
                return "take", s.get("path")
            return (s.get("device"), s.get("subject")) if line in of_stream else None

        keys = [(whose(line), line) for line in _warnings(s)]
        new = [key for key in keys if key not in said]
        said.update(new)
        return [line for _, line in new]

    for s in summaries:
        if as_json:  # stdout stays one JSON object per line; the warnings go to stderr as well
            emit_json(s)
            for line in warnings(s):
                warn(_printable(f"{s.get('path')}: {line}"))
            continue
        if s.get("error"):
            _tell(f"{s.get('device')} / {s.get('subject')}: {s['error']}")
            continue
        if s.get("path") is None:
            _tell(f"no take recorded; rejected datagrams: {s.get('rejected')}")
            for line in [f"warning: {w}" for w in warnings(s)] + _rejection_hints(s.get("rejected") or {}):
                _tell(f"  {line}")
            hinted = True
            continue
        _tell(
            f"{s['device']} / {s['subject']} -> {s['path']}: {s['frames']} frames, "
            f"{s['dropped_frames']} dropped, {s.get('face_lost_frames', 0)} face lost, "
            f"{s.get('duplicates', 0)} duplicates, "
            f"{s.get('out_of_order', 0)} out of order; rejected {s.get('rejected')}"
        )
        if "torn_tail" in s:
            _tell(f"  torn log tail discarded: {s['torn_tail']}")
        for line in warnings(s):
            _tell(f"  warning: {line}")
    # A stream rejected whole beside one that made takes (or with --json): say once what it means.
    hints = [] if hinted or not summaries else _rejection_hints(summaries[0].get("rejected") or {})
    if hints:
        _tell("rejected datagrams, what they usually mean:")
    for line in hints:
        _tell(f"  {line}")


def _rejection_hints(rejected: dict[str, int]) -> list[str]:
    """What the session's rejections usually mean, commonest first (the reasons with a hint)."""
    return [
        f"{reason}: {REJECT_HINTS[reason]}"
        for reason in sorted(rejected, key=lambda r: -rejected[r])
        if reason in REJECT_HINTS
    ]


def _warnings(s: dict) -> list[str]:
    """What in a take's summary the person recording should hear about even with --json, as warnings
    without their prefix (``_report`` says how each is printed)."""
    lines = list(s.get("errors") or [])  # audio and sync-box failures
    if "frame_clock" in s:
        lines.append(f"frames placed by arrival time: {s['frame_clock']['reason']}")
    if s.get("same_time_dropped"):
        lines.append(
            f"{s['same_time_dropped']} frames repeat the frame time of another frame with other "
            "values: the first of each frame time is kept, the others are only in the session log"
        )
    elif s.get("same_time_frames"):
        lines.append(
            f"{s['same_time_frames']} frames share their frame time with another frame (the sender "
            "sends more frames than its frame clock tells apart): spread evenly over their frame period"
        )
    if s.get("clock_steps"):
        lines.append(
            f"the frame clock jumped forward {s['clock_steps']} time(s) while packets kept coming "
            "(a clock correction, no lost frames): the stream is cut there, each part on its own clock"
        )
    if s.get("clock_steps_back"):
        lines.append(
            f"the phone's clock stepped back {s['clock_steps_back']} time(s) while packets kept "
            "coming (a timecode re-sync): the frames after each step are placed where they arrived (see the "
            "take's clock_step_back repair)"
        )
    if s.get("rate_jitter_packets"):
        lines.append(
            f"{s['rate_jitter_packets']} packets declared a frame rate that wavered around one "
            "value (a sender reporting its measured rate): read at the rate most packets declared"
        )
    if s.get("packets_outside_takes"):
        lines.append(
            f"{s['packets_outside_takes']} packets of device {s.get('device')} / subject {s.get('subject')} "
            "are in no take (stray frame numbers, no face before, between or after takes, too few frames "
            "for a take): they stay in the session log, counted in the takes' stream_counts"
        )
    if s.get("receive_queue_drops"):
        lines.append(
            f"{s['receive_queue_drops']} datagrams reached this computer but were dropped before "
            "listen read them (its receive queue was full: listen was suspended or fell behind in a burst); "
            "the takes lack their frames. A larger queue rides out bursts: sysctl -w "
            "net.core.rmem_max=8388608"
        )
    if s.get("senders"):
        lines.append(
            f"{len(s['senders'])} senders ({', '.join(s['senders'])}) sent device "
            f"{s.get('device')} / subject {s.get('subject')} at the same time: each is a stream of its own "
            "(take names -2, -3...); give them different subjects"
        )
    for key, what in (("log_damage", "frame log"), ("audio_log_damage", "audio log")):
        if s.get(key):
            lost = sum(d["bytes_discarded"] for d in s[key])
            lines.append(f"{len(s[key])} damaged stretch(es) of the {what} skipped ({lost} bytes)")
    return lines


def _say(message: str, say: Callable[[str], None] = progress) -> None:
    """``progress`` (or ``warn``: ``say``) for while recording: stderr that cannot be written (a closed
    terminal, a full disk) must not stop the recording."""
    with contextlib.suppress(OSError):
        say(message)


def _status_line(counts: dict, stream: PhoneStream | None = None) -> None:
    """The status line of ``counts`` (``LiveRecorder.run``'s); with ``stream``, its subject logged with its
    own controls (CONTROLS records, which the recorder does not see) counts as the relayed ones do."""
    if stream is not None:
        counts = counts | {
            "accepted": counts["accepted"] + stream.logged,
            "streams": counts["streams"] + stream.logged_streams,
        }
    failed = f", {counts['failed_writes']} failed log writes" if counts.get("failed_writes") else ""
    if counts.get("receive_queue_drops"):
        failed += f", {counts['receive_queue_drops']} dropped in a full receive queue"
    _say(
        f"{counts['elapsed_s']:.0f} s: {counts['accepted']} packets from {counts['streams']} stream(s), "
        f"{counts['rejected']} rejected{failed}"
    )


class _Warnings:
    """A check for after every log flush (and once more at the stop): prints each problem as one
    warning line when it appears. A sync-box failure is also noted in the frames log at once, so that
    ``recover`` reports it after a later crash."""

    def __init__(self, recorder: LiveRecorder, audio_log: AudioLog | None, source, serial_sync):
        self.recorder, self.audio_log = recorder, audio_log
        self.source, self.serial_sync = source, serial_sync
        self.warned: set[str] = set()

    def __call__(self) -> None:
        problems = {
            "log": self.recorder.log is not None and self.recorder.log.error,
            "audio log": self.audio_log is not None and self.audio_log.writer.error,
            "audio": self.source is not None and self.source.error,
            "serial": self.serial_sync is not None and self.serial_sync.error,
        }
        for what, problem in problems.items():
            if problem and what not in self.warned:
                self.warned.add(what)
                if what == "serial":
                    self.recorder.note({"kind": "serial_error", "message": problem})
                    problem += "; recording goes on without sync markers (those received are kept)"
                if isinstance(problem, OSError):
                    problem = f"cannot write the {what} ({problem.strerror or problem}); recording goes on, "
                    problem += "holding what cannot be written in memory"
                _say(problem, warn)


def _check_audio_file(path: Path, first_packet: bool) -> None:
    """A missing or unreadable --audio-file is an error before anything is recorded. With
    first-packet it may still be written (by replay --audio-out) until the first packet: then its
    folder must exist, and a warning says the file has to be there by then."""
    if path.is_dir():
        raise InputError("the audio file is a folder", path)
    check_regular_file(path)
    if path.exists():
        try:
            with open(path, "rb"):
                pass
        except OSError as exc:
            raise InputError(f"cannot read the audio file: {exc.strerror or exc}", path) from None
    elif not first_packet:
        raise InputError("audio file not found", path)
    elif not path.parent.is_dir():
        raise InputError("audio file not found (nor its folder)", path)
    else:
        warn(f"{path} does not exist yet: it has to be there when the first packet arrives")


def _lock_session(session_dir: Path) -> tuple[int | None, bool]:
    """Make the session folder and take its lock (``SESSION_LOCK``) for as long as ``listen`` records
    and builds the takes: ``recover`` leaves a locked session alone. Returns the lock's descriptor
    (None without ``fcntl``; the lock goes with the process, however it ends) and whether this call made
    the folder (not when it was there already). ``OSError`` when the folder or its lock cannot be made
    (``_remove_unstarted_session`` removes a folder made for it)."""
    made = True
    try:
        session_dir.mkdir(parents=True)
    except FileExistsError:
        if not session_dir.is_dir():
            raise
        made = False
    if fcntl is None:  # pragma: no cover - Windows: recover goes by the session record's pid alone
        return None, made
    fd = os.open(session_dir / SESSION_LOCK, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o644)
    try:
        with contextlib.suppress(OSError):  # a file system without locks: recover goes by the pid then
            try_lock(fd)
    except BaseException:  # a stop signal meanwhile: nobody else would close it
        os.close(fd)
        raise
    return fd, made


def _remove_unstarted_session(session_dir: Path, made: bool) -> None:
    """Remove the session folder of a ``listen`` that stopped or failed before it recorded: only when
    this ``listen`` made it, and only the files it writes there (its lock and logs): a folder that was
    there before, or that holds anything else, stays."""
    if not made:
        return
    for name in (SESSION_LOCK, FRAMES_LOG, AUDIO_LOG):
        with contextlib.suppress(OSError):
            (session_dir / name).unlink()
    with contextlib.suppress(OSError):  # not empty: another file is not ours to remove
        session_dir.rmdir()


def _session_record(session: Path) -> dict[str, Any]:
    """The SESSION record a recorder writes first in its log (pid, host, clock), or {}."""
    reader = LogReader(session / FRAMES_LOG)
    records = iter(reader)
    try:
        payload = next(records, None)
        if payload is not None and payload[0] == RecordType.SESSION:
            data = json.loads(bytes(payload[1:]))
            return data if isinstance(data, dict) else {}
    except (S2AError, OSError, ValueError):
        pass
    finally:
        records.close()
    return {}


def _ended_cleanly(session: Path) -> bool:
    """Whether the frames log ends in the END record a recorder writes when it closes (read from the
    last 4 KiB only: the END record is small and always the last one)."""
    try:
        with open(session / FRAMES_LOG, "rb") as f:
            size = f.seek(0, os.SEEK_END)
            f.seek(max(len(MAGIC), size - 4096))
            tail = f.read()
    except OSError:
        return False
    for at in range(len(tail) - RECORD_HEADER.size - 1, -1, -1):
        length, crc = RECORD_HEADER.unpack_from(tail, at)
        payload = tail[at + RECORD_HEADER.size :]
        if len(payload) == length and payload[0] == RecordType.END and zlib.crc32(payload) == crc:
            return True
    return False


def _is_recorder(pid: int, record: dict[str, Any]) -> bool:
    """Whether the live process ``pid`` is the one that started the session of ``record`` and not one
    that got its pid later: it must have started before the session (Linux /proc; elsewhere a live
    process with the recorder's pid is taken for it)."""
    if not Path("/proc/self/stat").is_file():
        return True
    try:
        stat_line = Path(f"/proc/{pid}/stat").read_text()
        fields = stat_line[stat_line.rindex(")") + 2 :].split()
        with open("/proc/stat") as f:
            boot_s = next(float(line.split()[1]) for line in f if line.startswith("btime "))
        started_s = boot_s + int(fields[19]) / os.sysconf("SC_CLK_TCK")
    except FileNotFoundError:  # gone since it was looked for
        return False
    except (OSError, ValueError, IndexError, StopIteration):
        return True
    if fields[0] in ("Z", "X"):  # dead, not yet reaped by its parent
        return False
    wall_origin_ns = (record.get("clock") or {}).get("wall_origin_ns")
    if not isinstance(wall_origin_ns, (int, float)):
        return True
    return started_s <= wall_origin_ns / 1e9 + PID_START_SLACK_S


def _recorder_running(record: dict[str, Any]) -> bool:
    """Whether the process that recorded a session (its SESSION record's pid on this host) still runs."""
    pid, host = record.get("pid"), record.get("host")
    if not isinstance(pid, int) or isinstance(pid, bool) or pid <= 0 or pid == os.getpid():
        return False
    if os.name != "posix" or host != socket.gethostname():
        return False
    return process_runs(pid) and _is_recorder(pid, record)


def _session_in_use(session: Path) -> tuple[str | None, int | None]:
    """Why ``recover`` must leave ``session`` alone (a listen still records it), or None together
    with a descriptor holding the session's lock (shared) while recover rebuilds it, if it has one.
    Sessions of a listen that takes no lock (older versions, ``LiveRecorder`` used directly) go by
    the pid and host in their SESSION record, unless their log ends in an END record (the recorder
    closed)."""
    fd = None
    locked = False
    if fcntl is not None:
        try:
            fd = os.open(session / SESSION_LOCK, os.O_RDONLY | getattr(os, "O_CLOEXEC", 0))
        except OSError:
            fd = None
        if fd is not None:
            with contextlib.suppress(OSError):  # a file system without locks: go by the pid
                locked = not try_lock(fd, shared=True)
    record = _session_record(session)
    if locked or (not _ended_cleanly(session) and _recorder_running(record)):
        if fd is not None:
            os.close(fd)
        pid, host = record.get("pid"), record.get("host")
        who = f"process {pid} on {host}" if pid else "another process"
        return f"still being recorded by {who}", None
    return None, fd


def _remove_partial_takes(session_id: str, out_dir: Path, summaries: list[dict]) -> list[str]:
    """Take folders of this session in ``out_dir`` that a ``recover`` wrote (``recovered``) and the
    complete build just made did not replace (a segment more, a different split): removed, so that
    no frame is in two takes. Nothing is removed when a take of the complete build failed."""
    if any(s.get("error") for s in summaries):
        return []
    kept = {os.path.normcase(os.path.abspath(s["path"])) for s in summaries if s.get("path")}
    removed = []
    try:
        candidates = sorted(out_dir.glob(glob.escape(session_id) + "_*"))
    except OSError:
        return []
    for folder in candidates:
        if os.path.normcase(os.path.abspath(folder)) in kept or not is_take_dir(folder):
            continue
        try:
            meta = read_meta(folder)
        except S2AError:
            continue
        extra = meta.extra or {}
        if meta.source_kind != "livelink_udp" or extra.get("session") != session_id:
            continue
        if extra.get("recovered") is not True:
            continue
        try:
            shutil.rmtree(folder)
        except OSError as exc:
            _say(f"{folder}: cannot remove this partial take of a recover: {exc.strerror or exc}", warn)
            continue
        removed.append(str(folder))
    return removed


def _quiet_terminal(*_) -> None:
    """After SIGHUP the terminal is gone and writing to it fails (EIO): send what stdout and stderr
    would print there to /dev/null (files and pipes stay as they are)."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
    except OSError:
        return
    for fd in (1, 2):
        with contextlib.suppress(OSError):
            if stat.S_ISCHR(os.fstat(fd).st_mode):
                os.dup2(devnull, fd)
    os.close(devnull)


class _SetUp:
    """Whether ``listen`` still sets up, and how a stop signal stops it meanwhile (``_stop_signals``): the
    first one is noted and the bookkeeping under way finishes (so that ``discard`` finds what to remove),
    unless the set-up waits (``waiting``: a sound device opening, a long --audio-file read) or has taken
    longer than ``SETUP_DEFER_S`` (a file system that stalls); so does a second one."""

    def __init__(self, stop: threading.Event | None = None) -> None:
        self.caught: list[int] = []  # the stop signals noted, in order
        self.stop = stop  # a library's stop (``cmd_listen``'s)
        self.active = True
        self.waiting = False
        self.started = time.monotonic()

    def stops_now(self) -> bool:
        """Whether the stop signal just noted in ``caught`` raises at once (and so ends the set-up)."""
        if not (self.active and self.caught):
            return False
        if self.waiting or time.monotonic() - self.started > SETUP_DEFER_S:
            self.active = False
            return True
        return False

    def stopped(self) -> bool:
        """Whether a stop signal or the library's stop came."""
        return bool(self.caught) or (self.stop is not None and self.stop.is_set())

    def wait(self) -> None:
        """The set-up begins a step that waits: a stop signal noted before (in the bookkeeping just done)
        raises now, and any from here at once."""
        self.waiting = True
        if self.stops_now():
            raise _stopped_before_recording(self.caught[0])


def _stop_signals(recorder: LiveRecorder, setup: _SetUp) -> dict[int, Any]:
    """SIGINT, SIGTERM and SIGHUP (a closed terminal or ssh session) stop the recording cleanly, each
    noted in ``setup.caught``; while ``setup`` is active they stop the set-up (``_SetUp``). The previous
    handlers, to restore; none off the main thread (a library's thread: only it can set handlers). A
    SIGHUP that is ignored (``nohup``) stays ignored."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    stops = [signal.SIGINT, signal.SIGTERM]
    hup = getattr(signal, "SIGHUP", None)
    if hup is not None and signal.getsignal(hup) is not signal.SIG_IGN:
        stops.append(hup)

    def stop(signum, _frame) -> None:
        if signum == hup:
            _quiet_terminal()
        setup.caught.append(signum)
        recorder.request_stop()
        if setup.stops_now():
            raise _stopped_before_recording(setup.caught[0])

    return {s: signal.signal(s, stop) for s in stops}


def _stopped_before_recording(signum: int) -> KeyboardInterrupt:
    """What a stop signal that came while ``listen`` set up raises once the half-made session is gone:
    the command then ends as on Ctrl-C (exit code 130) or, for SIGTERM, with exit code 143."""
    return Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


def _keep_stderr(fd: int, running: bool) -> None:
    """Put the process's stderr back on ``fd`` (a copy of it from before a set-up step that a stop left
    running): the step may have sent it elsewhere, and may do so again while it runs on (sounddevice sends
    it to /dev/null while PortAudio looks for devices, a device that hangs holds it there); the stop's
    line has to be seen. So ``sys.stderr``, when it is the process's own, writes to a copy of ``fd`` too,
    while the step still runs (``running``; one that ended leaves the stream as it is, and no copy)."""
    with contextlib.suppress(OSError):
        os.dup2(fd, 2)
    stream = sys.stderr
    if not running or stream is None or stream is not sys.__stderr__:  # over, or a caller's own stream
        return
    with contextlib.suppress(OSError, ValueError, AttributeError):
        if stream.fileno() == 2:
            stream.flush()
            sys.stderr = open(  # the process's stderr from here on
                os.dup(fd), "w", buffering=1, encoding=stream.encoding, errors=stream.errors
            )


# After a stop, how long ``listen`` waits for the set-up step it gave up (``_while_stoppable``) to end: a step
# in Python code (reading --audio-file) ends at its next function call; one that hangs in C (a sound device
# that never opens) cannot be ended, and is left to a daemon thread that stops what it made if it returns.
# Milliseconds when the machine is idle; a second covers a loaded one (two test workers on two cores
# beside the processes they start: 0.2 s was too short about once in ten), and only a hung device waits it.
SETUP_ABANDON_S = 1.0


# Where a given-up set-up step may be ended (``_while_stoppable``): in this package's code, which closes what
# it opened when it raises.
_PACKAGE_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "")


class _SetUpAbandoned(BaseException):
    """Raised inside a set-up step a stop gave up (``_while_stoppable``), to end its thread early."""


def _while_stoppable(make: Callable[[], Any], setup: _SetUp) -> Any:
    """``make()`` (a set-up step that may wait long: a sound device that hangs in opening, an hour of
    --audio-file read) in a thread of its own while this one waits for it, so that a stop signal stops
    ``listen`` at once (``setup.waiting``): a stop signal reaches Python only between its own steps, never
    inside a library's call. After such a stop the step is given up: it raises ``_SetUpAbandoned`` at its
    next Python function call (a trace of its calls, in its thread only), and ``listen`` waits up to
    ``SETUP_ABANDON_S`` for it to end, so that a library that called ``cmd_listen`` is left no thread nor
    open file. A step hung in C (a device that never opens) outlives that wait: a daemon thread holding
    only the device request, which stops what ``make`` returns if it ever does; the process's stderr is
    then kept where it was (``_keep_stderr``). Off the main thread (no stop signals to wait for) it runs in
    this one, unless a library gave ``cmd_listen`` a stop, which is waited for likewise."""
    if threading.current_thread() is not threading.main_thread() and setup.stop is None:
        return make()
    done: dict[str, Any] = {}
    guard = threading.Lock()
    abandoned = threading.Event()
    began = threading.Event()  # the thread runs: set by it first (a stop inside ``start()`` would not know)
    starting = False

    def work() -> None:
        began.set()
        if abandoned.is_set():  # given up while it started
            return
        # the thread's own trace (coverage's, a debugger's: ``threading.settrace``), called on as before
        own = sys.gettrace()

        def give_up(frame, event, arg):
            """The step's trace of calls: once it is given up, its next call of this package's code
            raises, once (in another library's code it could leave a file opened and not yet kept)."""
            if abandoned.is_set() and frame.f_code.co_filename.startswith(_PACKAGE_DIR):
                sys.settrace(own)  # its clean-up (``with``, ``finally``) runs as the rest of the thread
                raise _SetUpAbandoned
            return own(frame, event, arg) if own is not None else None

        sys.settrace(give_up)
        try:
            value = make()
        except _SetUpAbandoned:
            return
        except BaseException as exc:  # handed to the waiting thread, which raises it
            done["error"] = exc
            return
        finally:
            sys.settrace(own)
        with guard:
            if not abandoned.is_set():
                done["value"] = value
                return
        with contextlib.suppress(Exception):
            value.stop()

    thread = threading.Thread(target=work, name="listen-set-up", daemon=True)
    try:
        stderr: int | None = os.dup(2)
    except OSError:  # no stderr to keep
        stderr = None
    try:
        setup.wait()
        starting = True
        thread.start()
        while thread.is_alive():
            thread.join(0.05)
            if setup.stop is not None and setup.stop.is_set():
                raise _stopped_before_recording(signal.SIGINT)
    except BaseException:
        with guard:
            abandoned.set()
            value = done.pop("value", None)
        if value is not None:
            with contextlib.suppress(Exception):
                value.stop()
        # a stop that came inside ``thread.start()`` leaves it starting: it runs, sees it was given up, ends
        if starting and began.wait(SETUP_ABANDON_S):
            thread.join(SETUP_ABANDON_S)
        if stderr is not None:
            # the command's own stderr (on the main thread) is kept whatever the step did: a stop's line
            # was lost about once in ten runs when only a step still running was thought able to move it
            _keep_stderr(stderr, thread.is_alive() or threading.current_thread() is threading.main_thread())
        raise
    finally:
        setup.waiting = False
        if stderr is not None:
            os.close(stderr)
    if "error" in done:
        raise done["error"]
    return done["value"]


def cmd_listen(args: argparse.Namespace, stop: threading.Event | None = None) -> int:
    """``s2a-capture listen``. ``stop``: a library's stop (``cmd_listen`` run in a thread of its own, where
    no stop signal reaches it): once set, the recording ends as on SIGINT (the takes are written, 0 is
    returned), or, set while ``listen`` sets up, the set-up stops and leaves nothing, raising
    ``KeyboardInterrupt`` as a stop signal does then."""
    if args.duration is not None and not (math.isfinite(args.duration) and 0 < args.duration <= 1e9):
        raise InputError(f"--duration must be a positive number of seconds, not {args.duration}")
    if args.audio_file is not None:
        _check_audio_file(args.audio_file, args.audio_start == "first-packet")
    phone = parse_destination(args.phone) if args.phone else None
    phone_allow = parse_allow_list(args.allow) if phone else None
    serial_port = open_serial(args.serial, args.baud) if args.serial else None
    out_is_new = not Path(args.out).exists()
    try:
        recorder = LiveRecorder(  # with --phone, the relay of the phone's packets sends to it on loopback
            args.out,
            bind="127.0.0.1" if phone else args.bind or "127.0.0.1",
            port=0 if phone else DEFAULT_PORT if args.port is None else args.port,
            allow=["127.0.0.1"] if phone else args.allow,
            flush_interval_s=args.flush_interval,
            max_streams=args.max_streams,
        )
    except InputError:
        if serial_port is not None:
            serial_port.close()
        raise
    lock: int | None = None
    made = False  # whether this listen made the session folder (only then may a failed start remove it)
    source = audio_log = serial_sync = stream = None

    def discard() -> None:
        """A start that failed or was stopped: nothing was received yet, so leave no half-made session
        behind (``_remove_unstarted_session``)."""
        nonlocal lock
        if stream is not None:
            stream.stop()
        if audio_log is not None:
            audio_log.close()
        recorder.close()
        # a log a stop signal caught between its making and its keeping (``recorder.log``, ``audio_log``)
        LogWriter.close_open(recorder.session_dir)
        _remove_unstarted_session(recorder.session_dir, made)
        if lock is not None:
            os.close(lock)
            lock = None
        if out_is_new:  # nor the output folder this failed start made (rmdir: only when empty)
            with contextlib.suppress(OSError):
                Path(args.out).rmdir()
        if serial_port is not None:
            serial_port.close()

    # From before the session folder is made, a stop signal stops the set-up (``_SetUp``): one while the
    # folder, its lock and logs are made (the first milliseconds) is noted, and removes them all once they
    # are (``discard``), rather than leave a folder without a session record; one in a step that waits or
    # a later one stops it at once, and ``discard`` removes what there is. One after the set-up ends the
    # recording cleanly.
    setup = _SetUp(stop)
    previous: dict[int, Any] = {}
    try:
        try:
            try:
                previous = _stop_signals(recorder, setup)
                made = not os.path.lexists(recorder.session_dir)  # until _lock_session says (a stop within)
                try:
                    lock, made = _lock_session(recorder.session_dir)
                except OSError as exc:  # a read-only output folder, a file in the way
                    raise InputError(
                        f"cannot write the session log: {exc.strerror or exc}", recorder.session_dir
                    ) from None
                host, port = recorder.open()
                if phone is not None:
                    stream = _phone_stream(args, phone, phone_allow, recorder, (host, port))
                    host, port = stream.open()
                if args.audio_device is not None or args.audio_file is not None:
                    try:
                        audio_log = AudioLog(recorder.session_dir / AUDIO_LOG)
                    except OSError as exc:
                        raise InputError(
                            f"cannot write the audio log: {exc.strerror or exc}", recorder.session_dir
                        ) from None
                    log = audio_log
                    source = _while_stoppable(lambda: _audio_source(args, recorder, log), setup)
            finally:
                setup.active = False  # from here a stop signal is only noted
        except BaseException:  # an error, or a stop signal that stopped the set-up at once
            discard()
            raise
        if setup.stopped():  # stopped before the recording began: nothing to keep
            discard()
            raise _stopped_before_recording(setup.caught[0] if setup.caught else signal.SIGINT)
        if serial_port is not None:
            serial_sync = SerialSync(serial_port, recorder.clock, recorder.add_sync)
        via = f"Live Link Face realtime from phone {args.phone} " if phone else ""
        progress(f"listening {via}on udp://{format_destination(host, port)} -> {recorder.session_dir}")
        warnings = _Warnings(recorder, audio_log, source, serial_sync)
        try:
            if stream is not None:
                stream.start()
            if source is not None:
                source.start()
            if serial_sync is not None:
                serial_sync.start()
            recorder.run(
                args.duration,
                status=lambda counts: _status_line(counts, stream),
                on_flush=lambda: _flushed(warnings, setup),
            )
        finally:
            if stream is not None:
                stream.stop()  # ends the phone's session; the packets relayed before are in the log
            if serial_sync is not None:
                serial_sync.stop()
            if source is not None:
                source.stop()
            warnings()  # a failure since the last flush; notes the sync box's in the log
            if source is not None and source.error:
                recorder.note({"kind": "audio_error", "message": source.error})
            if audio_log is not None:
                audio_log.close()
            recorder.close()
        summaries = build_takes(recorder.session_dir, args.out)
        if recorder.receive_drops:  # never logged as packets: only the kernel counted them
            for s in summaries:
                s["receive_queue_drops"] = recorder.receive_drops
        if serial_sync is not None:  # lines of line noise are not in the log: only this process counted them
            for s in summaries:
                s["sync_lines_dropped"] = serial_sync.dropped
        removed = _remove_partial_takes(recorder.session_id, Path(args.out), summaries)
        # Said with the stop signals still only noted: the takes are written, and a stop now (one more
        # Ctrl-C, SIGTERM) must not cut their report short nor end listen as interrupted.
        for folder in removed:
            progress(f"removed {folder}: a partial take a recover wrote while this session was recording")
        if removed:
            for s in summaries:
                s["removed_partial_takes"] = removed
        _report(summaries, args.json)
        problems = _listen_problems(recorder, audio_log, source, summaries, args.out)
    finally:
        if lock is not None:
            os.close(lock)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if problems:
        raise InputError("; ".join(problems), recorder.session_dir)
    return 0


def _phone_stream(args: argparse.Namespace, phone, allow, recorder: LiveRecorder, to) -> PhoneStream:
    """The control session to ``--phone`` and the relay of its realtime packets to ``recorder`` at ``to``
    (``cps_control.PhoneStream``), on ``--bind`` (default all interfaces of the family the phone streams to,
    ``cps_control.relay_socket``) and ``--port`` (default any free port: the phone is told which)."""
    return PhoneStream(
        phone[0],
        phone[1],
        to,
        say=lambda line: _say(_printable(line)),
        rejected=recorder.rejected,
        note=recorder.note,
        record=recorder.log.put,  # a MetaHuman Animator subject's frames, logged with their own controls
        bind=args.bind,
        stream_port=args.port or 0,
        allow=allow,
    )


def _flushed(warnings: _Warnings, setup: _SetUp) -> None:
    """After every log flush of the recording: its warnings, and the library's stop (``cmd_listen``)."""
    warnings()
    if setup.stop is not None and setup.stop.is_set():
        warnings.recorder.request_stop()


def _audio_source(args: argparse.Namespace, recorder: LiveRecorder, audio_log: AudioLog):
    """The audio source ``listen`` records into ``audio_log``: a device, or a file played from the start
    or from the first packet."""
    if args.audio_device is not None:
        dev = int(args.audio_device) if args.audio_device.isdigit() else args.audio_device
        return DeviceAudioSource(audio_log, recorder.clock, dev, args.audio_rate, args.audio_channels)
    first = args.audio_start == "first-packet"
    source = FileAudioSource(audio_log, recorder.clock, args.audio_file, start_on_first_packet=first)
    if first:
        recorder.on_first_packet = source.trigger
    return source


def _listen_problems(recorder: LiveRecorder, audio_log, source, summaries: list[dict], out) -> list[str]:
    """What did not reach the takes, one phrase each (the takes hold everything that reached the disk). A
    sync box that failed is only a warning (given at once and per take): frames and audio are complete;
    so are log writes that failed while the disk was full when every byte held reached it later."""
    problems = []
    for what, writer in (("recorder log", recorder.log), ("audio log", audio_log and audio_log.writer)):
        if writer is None or writer.error is None:
            continue
        if writer.lost_nothing:  # the disk had room again: what was held reached it
            _say(
                f"writing the {what} failed {writer.failed_writes} time(s) "
                f"({writer.error.strerror or writer.error}), but nothing was lost: every byte held in memory "
                "reached the disk later",
                warn,
            )
        else:
            problems.append(writer.failure(what))
    if source is not None and source.error:
        if audio_log is not None and audio_log.format is not None and audio_log.samples:
            # a file changed or cut short while it played: the takes hold the audio up to there
            seconds = audio_log.samples / audio_log.format["sample_rate"]
            problems.append(
                f"the audio failed after {seconds:.1f} s of it (the takes hold those): {source.error}"
            )
        else:
            problems.append(f"no audio was recorded: {source.error}")
    failed = sum(1 for s in summaries if s.get("error"))
    if failed:
        problems.append(f"{failed} take(s) not written (run s2a-capture recover on {out} to retry)")
    return problems


def cmd_recover(args: argparse.Namespace) -> int:
    # SIGTERM stops it as Ctrl-C does (exit 143): the take being written goes with its partial folder and
    # its half-written audio, not left beside the takes until that take is written again
    with sigterm_stops():
        return _recover(args)


def _recover(args: argparse.Namespace) -> int:
    sessions = find_sessions(args.dir, include_complete=args.all)
    if not sessions:
        if not find_sessions(args.dir, include_complete=True):  # a wrong folder, not a finished one
            raise InputError("no recording session here", args.dir)
        # Nothing to do is no failure: a script may run recover after every session.
        progress(f"{args.dir}: nothing to recover, every session is finished (--all rebuilds them)")
        return 0
    failures = 0
    for session in sessions:
        busy, lock = _session_in_use(session)
        if busy is not None:
            # Not an error: that listen builds the takes itself when it stops (recover it if it dies).
            progress(f"skipping {session}: {busy}; its listen writes the takes when it stops")
            if args.json:
                emit_json({"session": str(session), "skipped": True, "reason": busy, "path": None})
            continue
        try:
            progress(f"recovering {session}")
            try:
                summaries = build_takes(session, args.out or session.parent, recovered=True)
            except (S2AError, OSError) as exc:  # one unreadable session must not stop the others
                failures += 1
                message = str(exc) if isinstance(exc, S2AError) else f"{session}: {exc.strerror or exc}"
                print(printable(f"s2a-capture: error: {message}"), file=sys.stderr)
                if args.json:
                    emit_json({"session": str(session), "error": message})
                continue
        finally:
            if lock is not None:
                os.close(lock)
        _report(summaries, args.json)
        failed = sum(1 for s in summaries if s.get("error"))
        if failed:
            failures += 1
            out = args.out or session.parent
            print(
                printable(f"s2a-capture: error: {session}: {failed} take(s) not written to {out}"),
                file=sys.stderr,
            )
    return 1 if failures else 0


def _load_take(path: Path) -> Take:
    if is_take_dir(path):
        return read_take(path)
    sources = find_sources([path])
    if len(sources) != 1:
        raise InputError(f"replay sends one take; found {len(sources)} under it", path)
    return import_source(sources[0])


def cmd_replay(args: argparse.Namespace) -> int:
    host, port = parse_destination(args.to)
    take = _load_take(args.take)
    if args.protocol == "realtime":
        return _replay_realtime(args, take, host, port)
    imp = Impairment(args.loss, args.reorder, args.duplicate, args.jitter_ms / 1000.0, args.seed)
    report = replay_take(take, host, port, args.speed, imp, args.device, args.subject, args.audio_out)
    summary = {"take": take.meta.id, "to": format_destination(host, port)} | report.to_json()
    if args.audio_out is not None:
        summary["audio_out"] = str(args.audio_out)
    if args.json:
        emit_json(summary)
    else:
        progress(
            f"{take.meta.id} -> {format_destination(host, port)}: {report.frames} frames in "
            f"{report.packets_sent} packets, "
            f"{report.lost} lost, {report.duplicated} duplicated, {report.reordered} reordered"
        )
    if report.bad_values:
        warn(f"{report.bad_values} frames with NaN/inf values sent as no-face packets")
    return 0


def _replay_realtime(args: argparse.Namespace, take: Take, host: str, port: int) -> int:
    """``replay --protocol realtime``: the simulated phone of the realtime stream (``cps_phone``) serves its
    control session on ``host:port`` and streams the take to the ``listen --phone`` that asks for it, until
    every frame is sent (or Ctrl-C)."""
    from .replay import check_speed, default_device
    from .simulate.cps_phone import RealtimeFrames, SimulatedPhone

    classic_only = {"--loss": args.loss, "--reorder": args.reorder, "--duplicate": args.duplicate}
    classic_only |= {"--jitter-ms": args.jitter_ms, "--audio-out": args.audio_out}
    given = [option for option, value in classic_only.items() if value]
    if given:
        raise InputError(f"{', '.join(given)}: for the classic stream only (--protocol classic)")
    check_speed(args.speed)
    frames = RealtimeFrames.of_take(take)
    if not frames.frame_number.size:
        raise InputError(f"take {take.meta.id} has no tracked frames to send")
    subject = args.subject or take.meta.subject or "iPhone"
    device = args.device or default_device(take)
    phone = SimulatedPhone(frames, host=host, port=port, speed=args.speed, subject=subject, device=device)
    try:
        phone.start()
    except OSError as exc:
        raise InputError(f"cannot serve the control session on {args.to}: {exc.strerror or exc}") from None
    try:
        progress(f"phone control server on {format_destination(host, port)}: waiting for listen --phone")
        while not phone.finished():
            time.sleep(0.1)
    finally:
        phone.stop()
    summary = {"take": take.meta.id, "phone": format_destination(host, port), "protocol": "realtime"}
    summary |= {"frames": int(frames.frame_number.size), "packets_sent": phone.sent}
    summary["control_sessions"] = phone.connections
    if args.json:
        emit_json(summary)
    else:
        progress(
            f"{take.meta.id} -> listen --phone {format_destination(host, port)}: {phone.sent} frames sent"
        )
    return 0


def parse_phone(text: str) -> tuple[str, int]:
    """``HOST``, ``HOST:PORT``, a bare IPv6 address or ``[IPV6]:PORT`` → (host, OSC port)."""
    usage = f"phone address must be HOST, HOST:PORT, IPV6 or [IPV6]:PORT, not {text!r}"
    port_text: str | None = None
    if text.startswith("["):
        host, sep, rest = text[1:].partition("]")
        if not sep or (rest and not rest.startswith(":")):
            raise InputError(usage)
        if rest:
            port_text = rest[1:]
    elif text.count(":") == 1:
        host, _, port_text = text.partition(":")
    else:  # a name, an IPv4 address or a bare IPv6 address (more than one colon)
        host = text
    if not host:
        raise InputError(usage)
    if port_text is None:
        return host, DEFAULT_OSC_PORT
    if not (port_text.isascii() and port_text.isdigit()):
        raise InputError(usage)
    if not 1 <= int(port_text) <= 65535:
        raise InputError(f"phone port {port_text} is out of range (1..65535)")
    return host, int(port_text)


def cmd_remote(args: argparse.Namespace) -> int:
    """``s2a-capture remote``. With ``--json`` a failure (a bad argument, a phone that does not answer) is
    one JSON line too, with ``error``, as ``import --json`` gives it: a script reads one line per call (Ctrl-C
    too: ``error`` "interrupted", exit code 130)."""
    result: dict = {"phone": args.phone, "action": args.action}  # the phone as given until it is parsed
    try:
        return _remote(args, result)
    except (S2AError, KeyboardInterrupt) as exc:  # Ctrl-C while the phone is awaited: "interrupted"
        if args.json:
            emit_json(result | {"error": str(exc) if isinstance(exc, S2AError) else "interrupted"})
        raise


def _remote(args: argparse.Namespace, result: dict) -> int:
    """``cmd_remote``'s work, filling ``result`` (the JSON line) as it goes."""
    host, port = parse_phone(args.phone)
    result["phone"] = format_destination(host, port)
    if not 0 <= args.reply_port <= 65535:
        raise InputError(f"--reply-port {args.reply_port} is out of range (0..65535)")
    if not (math.isfinite(args.timeout) and 0 < args.timeout <= 3600):
        raise InputError(f"--timeout must be in (0, 3600] seconds, not {args.timeout}")
    # Every argument is checked before anything is sent: a bad one must not leave the phone half-told
    # (target: its Live Link targets cleared and no new one added).
    if args.action == "record-start":
        check_record_start(args.slate, args.take_number)
    elif args.action == "subject":
        check_subject(args.name)
    elif args.action == "target":
        t_host, t_port = parse_destination(args.address)
        t_ip = resolve_target(t_host, t_port)  # the app takes an IP address, not a name
    with PhoneRemote(host, port, args.reply_host, args.reply_port, args.timeout) as phone:
        if args.action == "record-start":
            result["timecode"] = phone.record_start(args.slate, args.take_number)
            result |= {"slate": args.slate, "take": args.take_number}
        elif args.action == "record-stop":
            result |= phone.record_stop()
        elif args.action == "target":
            phone.set_livelink_target(t_ip, t_port, clear=not args.keep)
            result["target"] = format_destination(t_ip, t_port)
            if t_ip != t_host:
                result["target_name"] = t_host
        elif args.action == "battery":
            result["battery"] = phone.battery()
        elif args.action == "thermals":
            result["thermals"] = phone.thermals()
        elif args.action == "subject":
            phone.set_subject(args.name)
            result["subject"] = args.name
        elif args.action == "stream-start":
            phone.stream(True)
        elif args.action == "stream-stop":
            phone.stream(False)
    if args.json:
        emit_json(result)
    else:
        progress(" ".join(f"{k}={v}" for k, v in result.items()))
    return 0
