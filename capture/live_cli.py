"""``s2a-capture listen / recover / replay / remote``: live capture, crash recovery, the simulated
iPhone and phone remote control. ``register(sub)`` adds them to the ``s2a-capture`` parser."""

from __future__ import annotations

import argparse
import contextlib
import math
import shutil
import signal
import sys
from collections.abc import Callable
from pathlib import Path

from .audio_capture import AudioLog, DeviceAudioSource, FileAudioSource
from .command import emit_json, progress
from .errors import InputError, S2AError
from .importer import find_sources, import_source
from .osc_remote import DEFAULT_OSC_PORT, PhoneRemote
from .recorder import AUDIO_LOG, DEFAULT_PORT, LiveRecorder
from .replay import Impairment, parse_destination, replay_take
from .serial_sync import SerialSync, open_serial
from .session_takes import build_takes, find_sessions
from .take import Take, is_take_dir, read_take


def register(sub: argparse._SubParsersAction) -> None:
    """Add the live-capture subcommands to the ``s2a-capture`` subparsers."""
    p = sub.add_parser(
        "listen",
        help="record Live Link UDP packets (and audio, sync markers) into takes, crash-safe",
        description="Record every Live Link device/subject as its own take until --duration, SIGINT or "
        "SIGTERM. Packets are logged crash-safely under OUT/<session>.recording/ while recording.",
    )
    p.add_argument("-o", "--out", type=Path, required=True, help="folder for the takes and the session log")
    p.add_argument(
        "--port", type=int, default=DEFAULT_PORT, help="UDP port (default 11111; 0 = any free port)"
    )
    p.add_argument(
        "--bind", default="127.0.0.1", help="address to listen on (a LAN address for a phone on Wi-Fi)"
    )
    p.add_argument(
        "--allow", nargs="+", metavar="ADDR", help="accept packets only from these source addresses"
    )
    p.add_argument("--duration", type=float, help="stop after this many seconds")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--audio-device", help="record audio from this sound device (index or name)")
    src.add_argument(
        "--audio-file", type=Path, help="play this sound file as the session audio (tests, replays)"
    )
    p.add_argument(
        "--audio-start",
        choices=("listen", "first-packet"),
        default="listen",
        help="when --audio-file playback starts (first-packet: at the first Live Link packet)",
    )
    p.add_argument("--audio-rate", type=int, default=48000, help="sound-device sample rate in Hz")
    p.add_argument("--audio-channels", type=int, default=1, help="sound-device channels")
    p.add_argument(
        "--serial", metavar="URL", help="sync box: serial device or pyserial URL (socket://, loop://)"
    )
    p.add_argument("--baud", type=int, default=115200, help="serial baud rate")
    p.add_argument("--flush-interval", type=float, default=0.1, help="seconds between log flushes (<= 0.25)")
    p.add_argument("--max-streams", type=int, default=512, help="most device/subject pairs recorded at once")
    p.add_argument("--json", action="store_true", help="print one JSON line per take when done")
    p.set_defaults(handler=cmd_listen)

    p = sub.add_parser(
        "recover",
        help="turn the logs a killed listen left behind into takes",
        description="Rebuild takes from unfinished sessions (*.recording folders) under DIR; a torn log "
        "tail is reported and everything before it is kept.",
    )
    p.add_argument("dir", type=Path, help="a listen output folder or one session folder")
    p.add_argument("-o", "--out", type=Path, help="where to write the takes (default: beside the session)")
    p.add_argument("--all", action="store_true", help="also rebuild sessions that finished cleanly")
    p.add_argument("--json", action="store_true", help="one JSON line per take")
    p.set_defaults(handler=cmd_recover)

    p = sub.add_parser(
        "replay",
        help="the simulated iPhone: send a take as Live Link packets",
        description="Send a take (take folder or Live Link Face CSV/take folder) as Live Link UDP packets "
        "in real time, optionally with seeded loss, reordering, duplication and jitter.",
    )
    p.add_argument("take", type=Path, help="a take folder, Live Link Face CSV or take folder")
    p.add_argument("--to", required=True, metavar="HOST:PORT", help="where the listener is")
    p.add_argument("--speed", type=float, default=1.0, help="playback speed (1 = real time)")
    p.add_argument("--loss", type=float, default=0.0, help="probability a packet is lost")
    p.add_argument("--reorder", type=float, default=0.0, help="probability a packet is held back")
    p.add_argument("--duplicate", type=float, default=0.0, help="probability a packet is sent twice")
    p.add_argument("--jitter-ms", type=float, default=0.0, help="uniform extra delay per packet, 0..MS")
    p.add_argument("--seed", type=int, default=0, help="seed of the fault generator")
    p.add_argument("--device", help="device id to send (default: the take's, or one derived from its id)")
    p.add_argument("--subject", help="subject name to send (default: the take's, or iPhone)")
    p.add_argument("--audio-out", type=Path, help="write the take's audio here for listen --audio-file")
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(handler=cmd_replay)

    p = sub.add_parser(
        "remote",
        help="control Live Link Face on the phone over OSC",
        description="Send OSC commands to Live Link Face (formats doc §6) and wait for its replies.",
    )
    p.add_argument("phone", help="the phone's address (HOST or HOST:PORT, OSC port default 8000)")
    p.add_argument("--reply-host", help="local address the phone answers to (default: the route to it)")
    p.add_argument("--reply-port", type=int, default=0, help="local UDP port for replies (default: any)")
    p.add_argument("--timeout", type=float, default=2.0, help="seconds to wait for each reply")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    actions = p.add_subparsers(dest="action", required=True)
    a = actions.add_parser("record-start", help="start recording a take on the phone")
    a.add_argument("slate")
    a.add_argument("take_number", type=int, metavar="take")
    actions.add_parser("record-stop", help="stop recording; prints the phone's CSV and MOV paths")
    a = actions.add_parser("target", help="stream Live Link to HOST:PORT (clears other targets)")
    a.add_argument("address", metavar="HOST:PORT")
    a.add_argument("--keep", action="store_true", help="add to the existing targets instead")
    actions.add_parser("battery", help="battery level")
    actions.add_parser("thermals", help="thermal state")
    a = actions.add_parser("subject", help="set the Live Link subject name")
    a.add_argument("name")
    actions.add_parser("stream-start", help="start Live Link streaming")
    actions.add_parser("stream-stop", help="stop Live Link streaming")
    p.set_defaults(handler=cmd_remote)


# What the commonest rejections usually mean, for the line printed when no take was recorded.
REJECT_HINTS = {
    "version": "packets that are not Live Link Face version 6: set the app to Live Link (ARKit); "
    "its MetaHuman Animator mode and UE4-era senders use other protocols",
    "count": "the app's packets carry 61 values; this sender's count differs",
    "bad_rate": "a frame rate numerator of 0 or below, a negative denominator, or above 1000 fps",
    "not_allowed": "the sender's address is not in --allow",
}


def _report(summaries: list[dict], as_json: bool) -> None:
    for s in summaries:
        if as_json:  # stdout stays one JSON object per line; the warnings go to stderr as well
            emit_json(s)
            for line in _warnings(s):
                progress(f"{s.get('path')}: {line}")
            continue
        if s.get("error"):
            progress(f"{s.get('device')} / {s.get('subject')}: {s['error']}")
            continue
        if s.get("path") is None:
            progress(f"no take recorded; rejected datagrams: {s.get('rejected')}")
            for reason in sorted(s.get("rejected") or {}, key=lambda r: -s["rejected"][r]):
                if reason in REJECT_HINTS:
                    progress(f"  {reason}: {REJECT_HINTS[reason]}")
            continue
        progress(
            f"{s['device']} / {s['subject']} -> {s['path']}: {s['frames']} frames, "
            f"{s['dropped_frames']} dropped, {s.get('face_lost_frames', 0)} face lost, "
            f"{s.get('duplicates', 0)} duplicates, "
            f"{s.get('out_of_order', 0)} out of order; rejected {s.get('rejected')}"
        )
        if "torn_tail" in s:
            progress(f"  torn log tail discarded: {s['torn_tail']}")
        for line in _warnings(s):
            progress(f"  {line}")


def _warnings(s: dict) -> list[str]:
    """What in a take's summary the person recording should hear about even with --json."""
    lines = []
    if "frame_clock" in s:
        lines.append(f"warning: frames placed by arrival time: {s['frame_clock']['reason']}")
    for key, what in (("log_damage", "frame log"), ("audio_log_damage", "audio log")):
        if s.get(key):
            lost = sum(d["bytes_discarded"] for d in s[key])
            lines.append(f"warning: {len(s[key])} damaged stretch(es) of the {what} skipped ({lost} bytes)")
    return lines


def _status_line(counts: dict) -> None:
    failed = f", {counts['failed_writes']} failed log writes" if counts.get("failed_writes") else ""
    progress(
        f"{counts['elapsed_s']:.0f} s: {counts['accepted']} packets from {counts['streams']} stream(s), "
        f"{counts['rejected']} rejected{failed}"
    )


def _warn_once(recorder: LiveRecorder, audio_log: AudioLog | None, source) -> Callable[[], None]:
    """A check for after every log flush: prints each problem as one warning line when it appears."""
    warned: set[str] = set()

    def check() -> None:
        problems = {
            "log": recorder.log is not None and recorder.log.error,
            "audio log": audio_log is not None and audio_log.writer.error,
            "audio": source is not None and source.error,
        }
        for what, problem in problems.items():
            if problem and what not in warned:
                warned.add(what)
                if isinstance(problem, OSError):
                    problem = f"cannot write the {what} ({problem.strerror or problem}); recording goes on, "
                    problem += "holding what cannot be written in memory"
                progress(f"warning: {problem}")

    return check


def _check_audio_file(path: Path, first_packet: bool) -> None:
    """A missing or unreadable --audio-file is an error before anything is recorded. With
    first-packet it may still be written (by replay --audio-out) until the first packet: then its
    folder must exist, and a warning says the file has to be there by then."""
    if path.is_dir():
        raise InputError("the audio file is a folder", path)
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
        progress(f"warning: {path} does not exist yet: it has to be there when the first packet arrives")


def cmd_listen(args: argparse.Namespace) -> int:
    if args.duration is not None and not (math.isfinite(args.duration) and 0 < args.duration <= 1e9):
        raise InputError(f"--duration must be a positive number of seconds, not {args.duration}")
    if args.audio_file is not None:
        _check_audio_file(args.audio_file, args.audio_start == "first-packet")
    serial_port = open_serial(args.serial, args.baud) if args.serial else None
    out_is_new = not Path(args.out).exists()
    recorder = LiveRecorder(
        args.out,
        bind=args.bind,
        port=args.port,
        allow=args.allow,
        flush_interval_s=args.flush_interval,
        max_streams=args.max_streams,
    )
    try:
        host, port = recorder.open()
    except InputError:
        if serial_port is not None:
            serial_port.close()
        raise
    source = audio_log = serial_sync = None
    try:
        if args.audio_device is not None or args.audio_file is not None:
            try:
                audio_log = AudioLog(recorder.session_dir / AUDIO_LOG)
            except OSError as exc:
                raise InputError(
                    f"cannot write the audio log: {exc.strerror or exc}", recorder.session_dir
                ) from None
            if args.audio_device is not None:
                dev = int(args.audio_device) if args.audio_device.isdigit() else args.audio_device
                source = DeviceAudioSource(
                    audio_log, recorder.clock, dev, args.audio_rate, args.audio_channels
                )
            else:
                first = args.audio_start == "first-packet"
                source = FileAudioSource(
                    audio_log, recorder.clock, args.audio_file, start_on_first_packet=first
                )
                if first:
                    recorder.on_first_packet = source.trigger
    except InputError:
        # Nothing was received yet: leave no half-made session behind.
        if audio_log is not None:
            audio_log.close()
        recorder.close()
        shutil.rmtree(recorder.session_dir, ignore_errors=True)
        if out_is_new:  # nor the output folder this failed start made (rmdir: only when empty)
            with contextlib.suppress(OSError):
                Path(args.out).rmdir()
        if serial_port is not None:
            serial_port.close()
        raise
    if serial_port is not None:
        serial_sync = SerialSync(serial_port, recorder.clock, recorder.add_sync)
    previous = {
        s: signal.signal(s, lambda *_: recorder.request_stop()) for s in (signal.SIGINT, signal.SIGTERM)
    }
    progress(f"listening on udp://{host}:{port} -> {recorder.session_dir}")
    try:
        if source is not None:
            source.start()
        if serial_sync is not None:
            serial_sync.start()
        recorder.run(args.duration, status=_status_line, on_flush=_warn_once(recorder, audio_log, source))
    finally:
        if serial_sync is not None:
            serial_sync.stop()
            if serial_sync.error:
                recorder.note({"kind": "serial_error", "message": serial_sync.error})
        if source is not None:
            source.stop()
            if source.error:
                recorder.note({"kind": "audio_error", "message": source.error})
        if audio_log is not None:
            audio_log.close()
        recorder.close()
    summaries = build_takes(recorder.session_dir, args.out)
    for s in previous:
        signal.signal(s, previous[s])
    _report(summaries, args.json)
    # Takes hold everything that reached the disk; say loudly, in one line, what did not.
    problems = [recorder.error] if recorder.error else []
    if audio_log is not None and audio_log.writer.error:
        problems.append(
            f"writing the audio log failed: {audio_log.writer.error.strerror or audio_log.writer.error}"
        )
    if source is not None and source.error:
        problems.append(f"no audio was recorded: {source.error}")
    failed = sum(1 for s in summaries if s.get("error"))
    if failed:
        problems.append(f"{failed} take(s) not written (run s2a-capture recover on {args.out} to retry)")
    if problems:
        raise InputError("; ".join(problems), recorder.session_dir)
    return 0


def cmd_recover(args: argparse.Namespace) -> int:
    sessions = find_sessions(args.dir, include_complete=args.all)
    if not sessions:
        raise InputError(
            "no unfinished recording session here (use --all to rebuild finished ones)", args.dir
        )
    failures = 0
    for session in sessions:
        progress(f"recovering {session}")
        try:
            summaries = build_takes(session, args.out or session.parent, recovered=True)
        except (S2AError, OSError) as exc:  # one unreadable session must not keep the others from recovering
            failures += 1
            message = str(exc) if isinstance(exc, S2AError) else f"{session}: {exc.strerror or exc}"
            print(f"s2a-capture: error: {message}", file=sys.stderr)
            if args.json:
                emit_json({"session": str(session), "error": message})
            continue
        _report(summaries, args.json)
        failed = sum(1 for s in summaries if s.get("error"))
        if failed:
            failures += 1
            out = args.out or session.parent
            print(f"s2a-capture: error: {session}: {failed} take(s) not written to {out}", file=sys.stderr)
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
    imp = Impairment(args.loss, args.reorder, args.duplicate, args.jitter_ms / 1000.0, args.seed)
    report = replay_take(take, host, port, args.speed, imp, args.device, args.subject, args.audio_out)
    summary = {"take": take.meta.id, "to": f"{host}:{port}"} | report.to_json()
    if args.audio_out is not None:
        summary["audio_out"] = str(args.audio_out)
    if args.json:
        emit_json(summary)
    else:
        progress(
            f"{take.meta.id} -> {host}:{port}: {report.frames} frames in {report.packets_sent} packets, "
            f"{report.lost} lost, {report.duplicated} duplicated, {report.reordered} reordered"
        )
    if report.bad_values:
        progress(f"warning: {report.bad_values} frames with NaN/inf values sent as no-face packets")
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
    host, port = parse_phone(args.phone)
    if not 0 <= args.reply_port <= 65535:
        raise InputError(f"--reply-port {args.reply_port} is out of range (0..65535)")
    if not (math.isfinite(args.timeout) and 0 < args.timeout <= 3600):
        raise InputError(f"--timeout must be in (0, 3600] seconds, not {args.timeout}")
    shown = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    result: dict = {"phone": shown, "action": args.action}
    with PhoneRemote(host, port, args.reply_host, args.reply_port, args.timeout) as phone:
        if args.action == "record-start":
            result["timecode"] = phone.record_start(args.slate, args.take_number)
            result |= {"slate": args.slate, "take": args.take_number}
        elif args.action == "record-stop":
            result |= phone.record_stop()
        elif args.action == "target":
            t_host, t_port = parse_destination(args.address)
            phone.set_livelink_target(t_host, t_port, clear=not args.keep)
            result["target"] = f"{t_host}:{t_port}"
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
