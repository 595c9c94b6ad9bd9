"""Takes from a live session's logs: used when ``listen`` stops and by ``recover`` after a crash.

Per device/subject stream, frames are read from ``frames.log`` into arrays (frames of a rate above
``livelink.MAX_RATE_FPS`` dropped), cut into recordings where the phone's frame clock
restarted (``_recordings``); per recording, duplicates (same phone frame number) are dropped keeping
the first arrival, the rest are ordered by frame number and split
into segments wherever the phone's frame time between two frames with a face jumps by more than
``MAX_GAP_S`` (a phone restart, a long pause or a long time without a face, a corrupt frame number).
Each segment with at least ``MIN_TAKE_FRAMES`` frames with a face becomes a take, from its first to its
last frame with a face; the no-face packets in between become FACE_LOST frames (NaN values, their own
time and arrival, as the app's face-lost CSV rows), gaps in the frame numbers DROPPED frames
(``csv_take.fill_dropped``, as for CSV takes) within a budget (``MAX_DROPPED_PER_FRAME``) that
bounds what a frame clock can make us allocate. A live stream has no record start or stop, so no-face
packets before a take's first face or after its last are not part of it (``face_lost_outside_takes``).

A stream whose frame clock cannot be trusted (``frame_clock_problem``: most packets repeat the frame
time before them, or the frame time jumps back far more often than a phone restarts, as senders
built on PyLiveLinkFace do, whose frame numbers are milliseconds counted as frames) is placed by
arrival time instead (``arrival_clock``): packets in arrival order on the declared rate's grid,
gaps as DROPPED frames; the take's ``meta.extra.frame_clock`` and a ``frame_clock`` repair say so.

Clocks: take time 0 is the segment's first phone frame time. The phone clock is put on the session
clock with ``offset = min(arrival_s - frame_time_s)`` over the segment (the packet that travelled
fastest), so recorder time ``m`` is take time ``m - offset - frame_time_0``. The audio's first sample,
stamped on the session clock, lands at ``start_s = audio_first_s - offset - frame_time_0`` and sync
events likewise.
"""

from __future__ import annotations

import json
import shutil
import struct
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from . import livelink as ll
from .atomic import write_json_atomic
from .audio_capture import read_audio_log
from .channels import ARKIT61
from .csv_take import detect_fps, fill_dropped, missing_frames
from .errors import InputError, S2AError
from .record_log import LogReader, RecordType
from .recorder import (
    AUDIO_LOG,
    COMPLETE_FILE,
    FRAME_PAYLOAD_BYTES,
    FRAMES_LOG,
    NO_FACE_PAYLOAD_BYTES,
    SESSION_SUFFIX,
)
from .serial_sync import decode_sync_record
from .take import MAX_FPS, FrameStatus, Take, TakeMeta, safe_id, write_take
from .timecode import Timecode

MAX_GAP_S = 5.0
MIN_TAKE_FRAMES = 10
# A frame time this far behind the newest, followed by another one behind, is a restart of the phone's
# frame clock (a new recording of the stream), not a late packet.
RESTART_WINDOW_S = 1.0
# A phone's frame clock moves forward with its packets and restarts rarely: a stream where most packets
# repeat or go back from the frame time before them, or whose frame time jumps back by more than
# RESTART_WINDOW_S at least MIN_CLOCK_JUMPS times and more than once per CLOCK_JUMP_S of arrivals, has
# a frame clock that says nothing about time. (Its speed against the arrivals says nothing: a replay
# at --speed 50 runs 50 times fast.)
MIN_CLOCK_JUMPS = 4
CLOCK_JUMP_S = 10.0
# DROPPED frames a take may get per received frame (plus MAX_GAP_S at the stream's rate): past that,
# as only a corrupt or hostile frame clock needs, the gaps are left unfilled.
MAX_DROPPED_PER_FRAME = 4
SPILL_BYTES = 64 << 20
# One logged frame: arrival ns (little-endian, ours) + the packet's frame block (big-endian, the app's).
ROW_DTYPE = np.dtype(
    [
        ("arrival_ns", "<i8"),
        ("frame_number", ">i4"),
        ("sub_frame", ">f4"),
        ("rate_numerator", ">i4"),
        ("rate_denominator", ">i4"),
        ("count", "u1"),
        ("values", ">f4", (ll.BLENDSHAPE_COUNT,)),
    ]
)
_STREAM_ID = struct.Struct("<H")
_FRAME_AT = 1 + 2  # payload offset of arrival ns (after type and stream id)
# What a no-face record's row gets after its frame time: count 0 and NaN values (big-endian like the rest).
_NO_FACE_TAIL = bytes([0]) + np.full(ll.BLENDSHAPE_COUNT, np.nan, dtype=">f4").tobytes()


class SessionLog:
    """Everything a session's ``frames.log`` holds, with per-stream frame rows as arrays."""

    def __init__(self, session_dir: str | Path):
        self.dir = Path(session_dir)
        self.session: dict[str, Any] = {}
        self.streams: dict[int, dict[str, Any]] = {}
        self.rejected: dict[str, int] = {}
        self.sync: list[Any] = []
        self.notes: list[dict[str, Any]] = []
        self.end: dict[str, Any] | None = None
        self.frame_counts: dict[int, int] = {}
        # Rows wait in memory per stream; past SPILL_BYTES in all they go to files, so that building
        # the takes of many long streams needs one stream's rows in memory at a time.
        self._pending: dict[int, bytearray] = {}
        self._pending_bytes = 0
        self._spill_dir: Path | None = None
        first_stamp: int | None = None
        reader = LogReader(self.dir / FRAMES_LOG)
        for payload in reader:
            kind = payload[0]
            size = len(payload)
            if (kind == RecordType.FRAME and size == FRAME_PAYLOAD_BYTES) or (
                kind == RecordType.NO_FACE and size == NO_FACE_PAYLOAD_BYTES
            ):
                (sid,) = _STREAM_ID.unpack_from(payload, 1)
                if sid not in self.frame_counts:
                    self.frame_counts[sid] = 0
                    self._pending[sid] = bytearray()
                    (stamp,) = struct.unpack_from("<q", payload, _FRAME_AT)
                    first_stamp = stamp if first_stamp is None else min(first_stamp, stamp)
                self.frame_counts[sid] += 1
                self._pending[sid] += payload[_FRAME_AT:]
                if kind == RecordType.NO_FACE:
                    self._pending[sid] += _NO_FACE_TAIL
                self._pending_bytes += ROW_DTYPE.itemsize
                if self._pending_bytes > SPILL_BYTES:
                    self._spill()
            elif kind == RecordType.SYNC:
                self.sync.append(decode_sync_record(payload))
            elif kind in (
                RecordType.SESSION,
                RecordType.STREAM,
                RecordType.REJECTS,
                RecordType.END,
                RecordType.NOTE,
            ):
                try:
                    data = json.loads(bytes(payload[1:]))
                except (UnicodeDecodeError, json.JSONDecodeError):
                    continue  # a checksummed record does not go bad; this is a foreign writer's
                if kind == RecordType.SESSION:
                    self.session = data
                elif kind == RecordType.STREAM:
                    self.streams[int(data["stream"])] = data
                elif kind == RecordType.REJECTS:
                    self.rejected = {k: v for k, v in data.items() if v}
                elif kind == RecordType.END:
                    self.end = data
                else:
                    self.notes.append(data)
        if self._spill_dir is not None:
            self._spill()
        self.torn_tail = reader.torn_tail
        self.damage = reader.skipped
        origin = self.session.get("clock", {}).get("origin_ns")
        if origin is None:
            # Killed before the session record reached the disk: use the first stamp as the origin.
            origin = first_stamp or 0
        self.origin_ns = int(origin)

    def _spill(self) -> None:
        if self._spill_dir is None:
            try:
                self._spill_dir = Path(tempfile.mkdtemp(prefix=".build-", dir=self.dir))
            except OSError:  # a read-only session folder (recover -o elsewhere): the system's temp
                self._spill_dir = Path(tempfile.mkdtemp(prefix="s2a-build-"))
        for sid, buf in self._pending.items():
            if buf:
                with open(self._spill_dir / f"{sid}.rows", "ab") as f:
                    f.write(buf)
                buf.clear()
        self._pending_bytes = 0

    def stream_ids(self) -> list[int]:
        return sorted(self.frame_counts)

    def stream_rows(self, sid: int) -> np.ndarray:
        """The logged frames of one stream, in log (= arrival) order, as ``ROW_DTYPE`` records (no-face
        packets with ``count`` 0 and NaN values)."""
        if self._spill_dir is None:
            return np.frombuffer(self._pending[sid], dtype=ROW_DTYPE)
        return np.fromfile(self._spill_dir / f"{sid}.rows", dtype=ROW_DTYPE)

    def close(self) -> None:
        """Remove the spilled rows."""
        if self._spill_dir is not None:
            shutil.rmtree(self._spill_dir, ignore_errors=True)
            self._spill_dir = None

    def seconds(self, ns) -> Any:
        return (np.asarray(ns, dtype=np.int64) - self.origin_ns) / 1e9


def _segments(frame_time: np.ndarray) -> list[slice]:
    breaks = np.flatnonzero(np.diff(frame_time) > MAX_GAP_S) + 1
    bounds = [0, *breaks.tolist(), frame_time.size]
    return [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]


def _recordings(frame_time: np.ndarray) -> list[slice]:
    """Slices (in arrival order) of the recordings of one stream: a new one starts where the phone's
    frame time falls more than ``RESTART_WINDOW_S`` behind the newest so far and the next packet
    stays behind too (the phone or its timecode restarted). A single late packet is not a restart."""
    times = frame_time.tolist()
    starts = [0]
    newest = -np.inf
    for i, t in enumerate(times):
        behind = newest - RESTART_WINDOW_S
        if t < behind and i + 1 < len(times) and times[i + 1] < behind:
            starts.append(i)
            newest = t
        elif t > newest:
            newest = t
    bounds = [*starts, len(times)]
    return [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]


def frame_clock_problem(frame_time: np.ndarray, arrival_s: np.ndarray) -> str | None:
    """Why a stream's frame times (in arrival order) cannot place its frames, or None."""
    n = frame_time.size
    if n < 2 * MIN_TAKE_FRAMES:
        return None
    step = np.diff(frame_time)
    repeats = int(np.count_nonzero(step == 0))
    if repeats > step.size / 2:
        return f"{repeats} of {n} packets repeat the frame time of the packet before them"
    back = int(np.count_nonzero(step < 0))
    if back > step.size / 2:
        return f"the frame time goes back from {back} of {n} packets to the next"
    jumps = int(np.count_nonzero(step < -RESTART_WINDOW_S))
    span = float(arrival_s[-1] - arrival_s[0])
    if jumps >= MIN_CLOCK_JUMPS and jumps > span / CLOCK_JUMP_S:
        return f"the frame time jumps back {jumps} times in {span:.1f} s of arrivals"
    return None


def arrival_clock(arrival_s: np.ndarray, period: float) -> np.ndarray:
    """Frame times from arrival times (in arrival order) on a grid of ``period``: frame ``i`` takes the
    grid slot nearest its arrival, at least one after the frame before (a burst of packets the network
    held back fills consecutive slots; a pause leaves empty slots, later DROPPED frames)."""
    slots = np.rint((arrival_s - arrival_s[0]) / period)
    # k_i = max(k_{i-1} + 1, slot_i): a running maximum of slot_i - i, plus i.
    index = np.arange(slots.size)
    return arrival_s[0] + (np.maximum.accumulate(slots - index) + index) * period


def stream_takes(
    log: SessionLog, sid: int, audio=None, audio_first_s: float | None = None
) -> tuple[list[Take], dict]:
    """The takes of one stream, and a report (packets, duplicates, out-of-order, restarts, stray frames,
    face-lost frames outside the takes, frames with an implausible rate, takes that could not be built)."""
    rows = log.stream_rows(sid)
    info = log.streams.get(sid, {})
    report: dict[str, Any] = {"packets": int(rows.size), "duplicates": 0, "out_of_order": 0, "restarts": 0}
    # Logs written before the recorder bounded the rate may hold any rate: such frames make no take.
    plausible = ll.plausible_rate(rows["rate_numerator"].astype(np.int64), rows["rate_denominator"])
    if not plausible.all():
        report["bad_rate_frames"] = int(np.count_nonzero(~plausible))
        rows = rows[plausible]
    num = rows["rate_numerator"].astype(np.float64)
    den = ll.rate_denominator(rows["rate_denominator"].astype(np.float64))
    frame_time = (rows["frame_number"].astype(np.float64) + rows["sub_frame"].astype(np.float64)) * den / num
    numbers = rows["frame_number"].astype(np.int64)
    arrival = log.seconds(rows["arrival_ns"])
    problem = frame_clock_problem(frame_time, arrival)
    if problem is not None:
        report["frame_clock"] = {"placed_by": "arrival", "reason": problem}
        frame_time = arrival_clock(arrival, float(den[0] / num[0]))
        numbers = np.rint((frame_time - frame_time[0]) * num[0] / den[0]).astype(np.int64)
    recordings = _recordings(frame_time)
    report["restarts"] = len(recordings) - 1
    # Per recording: duplicates dropped, frames put in frame-number order, cut into segments of the
    # frames with a face; the no-face frames between a segment's first and last face frame belong to it.
    segments: list[tuple[np.ndarray, np.ndarray]] = []
    face_lost = 0
    for recording in recordings:
        r, ft, fn = rows[recording], frame_time[recording], numbers[recording]
        prior_max = np.maximum.accumulate(fn)
        report["out_of_order"] += int(np.count_nonzero(fn[1:] < prior_max[:-1]))
        # np.unique gives the first occurrence in arrival order of each frame number, sorted.
        _, first = np.unique(fn, return_index=True)
        report["duplicates"] += int(r.size - first.size)
        r, ft = r[first], ft[first]
        # Sorted by frame number; sub-frames cannot reorder them, but guard the take invariant.
        keep = np.concatenate([[True], np.diff(ft) > 0]) if ft.size else np.zeros(0, bool)
        r, ft = r[keep], ft[keep]
        face_rows = np.flatnonzero(r["count"] != 0)
        face_lost += int(r.size - face_rows.size)
        for s in _segments(ft[face_rows]) if face_rows.size else []:
            seg = slice(int(face_rows[s][0]), int(face_rows[s][-1]) + 1)
            segments.append((r[seg], ft[seg]))
    takes: list[Take] = []
    stray = lost_in_takes = 0
    errors = []
    session = log.session.get("session", log.dir.name.removesuffix(SESSION_SUFFIX))
    base_id = f"{session}_{info.get('subject')}_{(info.get('device') or '')[:8]}"
    for k, (r, ft) in enumerate(segments):
        lost = r["count"] == 0
        n_lost = int(np.count_nonzero(lost))
        if r.size - n_lost < MIN_TAKE_FRAMES:
            stray += r.size - n_lost
            continue
        take_id = base_id + (f"_{k + 1}" if len(segments) > 1 else "")
        try:
            take = _segment_take(log, info, take_id, r, ft, audio, audio_first_s)
            if problem is not None:
                take.meta.extra["frame_clock"] = report["frame_clock"]
                take.meta.repairs.append(
                    {
                        "line": None,
                        "kind": "frame_clock",
                        "message": f"frames placed by arrival time: {problem}",
                    }
                )
            takes.append(take)
        except (MemoryError, ValueError, OverflowError, S2AError) as exc:  # one take, not the session
            errors.append(f"take {safe_id(take_id)} could not be built: {type(exc).__name__}: {exc}")
            continue
        lost_in_takes += n_lost
    report["stray_frames"] = stray
    report["face_lost_outside_takes"] = face_lost - lost_in_takes
    if errors:
        report["errors"] = errors
    return takes, report


def _segment_take(
    log: SessionLog,
    info: dict[str, Any],
    take_id: str,
    r: np.ndarray,
    ft: np.ndarray,
    audio=None,
    audio_first_s: float | None = None,
) -> Take:
    """The take of one segment: rows ``r`` (frame-number order) with phone frame times ``ft``."""
    arr = log.seconds(r["arrival_ns"])
    lost = r["count"] == 0
    values = r["values"].astype(np.float32)
    finite = np.isfinite(values).all(axis=1)
    values[~np.isfinite(values)] = np.nan
    status = np.where(finite, FrameStatus.TRACKED, FrameStatus.BAD_VALUE).astype(np.uint8)
    status[lost] = FrameStatus.FACE_LOST
    finite |= lost  # NaN is what a face-lost frame holds, not a bad value
    t = ft - ft[0]
    fps, period = detect_fps(t)
    rate_num, rate_den = int(r["rate_numerator"][0]), int(ll.rate_denominator(int(r["rate_denominator"][0])))
    if not 0 < fps <= MAX_FPS:  # sub-frames that fool the median step: the stream's declared rate
        fps, period = rate_num / rate_den, rate_den / rate_num
    repairs = []
    # Bound what a frame clock can make us allocate: DROPPED frames at most MAX_DROPPED_PER_FRAME per
    # received frame plus MAX_GAP_S at the stream's rate; past that the gaps stay jumps in time.
    budget = MAX_DROPPED_PER_FRAME * t.size + MAX_GAP_S * rate_num / rate_den
    needed = float(missing_frames(t, period).sum())
    if needed <= budget:
        t_full, v_full, s_full, inserted = fill_dropped(t, values, status, period)
    else:
        t_full, v_full, s_full, inserted = t, values, status, 0
        repairs.append(
            {
                "line": None,
                "kind": "gaps_not_filled",
                "message": f"the gaps would need {needed:.0f} dropped frames for {t.size} received; "
                "left as jumps in time",
            }
        )
    arrival_full = np.full(t_full.size, np.nan)
    arrival_full[s_full != FrameStatus.DROPPED] = arr
    offset = float(np.min(arr - ft))
    latency = arr - ft - offset
    if not finite.all():
        repairs.append(
            {
                "line": None,
                "kind": "bad_value",
                "message": f"{int((~finite).sum())} frames held NaN/inf values",
            }
        )
    meta = TakeMeta(
        id=safe_id(take_id),
        source_kind="livelink_udp",
        fps=fps,
        channels=list(ARKIT61),
        subject=info.get("subject"),
        device=info.get("device"),
        start_timecode=Timecode.from_seconds(ft[0]).format(),
        timecode_rate=rate_num / rate_den,
        repairs=repairs,
        csv={"count_name": "BlendShapeCount", "start_seconds_of_day": float(ft[0] % 86400.0)},
    )
    sync = [(ev.to_json(), float(log.seconds(ev.arrival_ns))) for ev in log.sync]
    events = [j | {"arrival_s": a, "t": a - offset - float(ft[0])} for j, a in sync]
    meta.extra = {
        "session": log.session.get("session"),
        "rate": [rate_num, rate_den],
        "first_frame_number": int(r["frame_number"][0]),
        "clock_offset_s": offset,  # recorder clock minus phone frame time, fastest packet
        "latency_s": {
            "median": float(np.median(latency)),
            "p95": float(np.percentile(latency, 95)),
            "max": float(np.max(latency)),
        },
        "dropped_frames_inserted": inserted,
        "sync_events": events,
        "source": info.get("source"),
    }
    take = Take(meta, t_full, v_full, s_full, arrival_s=arrival_full)
    if audio is not None and audio_first_s is not None:
        take.attach_audio(audio, audio_first_s - offset - float(ft[0]), "recorder_clock")
    return take


def _unique_id(take_id: str, used: set[str]) -> str:
    """``take_id`` as a folder name no other take of the session has (``-2``, ``-3``... appended);
    compared case-folded, as on case-insensitive file systems."""
    name = safe_id(take_id)
    n = 1
    while name.casefold() in used:
        n += 1
        name = safe_id(f"{take_id}-{n}")
    used.add(name.casefold())
    return name


def find_sessions(path: str | Path, include_complete: bool = False) -> list[Path]:
    """Session folders (``*.recording`` with a frames log) under ``path``, oldest name first."""
    path = Path(path)
    if not path.exists():
        raise InputError("no such folder", path)
    if path.name.endswith(SESSION_SUFFIX) and (path / FRAMES_LOG).is_file():
        found = [path]
    else:
        found = sorted(p.parent for p in path.rglob(FRAMES_LOG) if p.parent.name.endswith(SESSION_SUFFIX))
    if not include_complete:
        found = [p for p in found if not (p / COMPLETE_FILE).is_file()]
    return found


def build_takes(
    session_dir: str | Path, out_dir: str | Path, recovered: bool = False
) -> list[dict[str, Any]]:
    """Write the takes of a session to ``out_dir``; returns one summary dict per take.

    The summary holds ``device``, ``subject``, ``frames``, ``dropped_frames``, ``rejected`` (session
    datagram counts by reason) and the take's ``info`` figures. With no take, one summary with
    ``device``/``subject`` None still reports the counts. Each take is built and written on its own:
    one that fails (memory, a full disk) adds a summary with ``path`` None and a one-line ``error``,
    and the others are still written. Marks the session complete afterwards unless a take failed.
    Take folder names are unique in the session (``-2``, ``-3``... when two streams' names collide).
    """
    session_dir = Path(session_dir)
    log = SessionLog(session_dir)
    audio, audio_first_ns, audio_report = read_audio_log(session_dir / AUDIO_LOG)
    audio_first_s = float(log.seconds(audio_first_ns)) if audio_first_ns is not None else None
    common: dict[str, Any] = {
        "session": log.session.get("session", session_dir.name),
        "rejected": dict(log.rejected),
        "datagrams": (log.end or {}).get("datagrams"),
        "accepted": (log.end or {}).get("accepted"),
        "clean_end": log.end is not None,
        "recovered": recovered,
        "sync_events": len(log.sync),
    }
    if log.end is None:
        # Killed: count what reached the disk (rejections as of the last flushed snapshot).
        common["accepted"] = int(sum(log.frame_counts.values()))
        common["datagrams"] = common["accepted"] + sum(log.rejected.values())
    if log.torn_tail is not None:
        common["torn_tail"] = log.torn_tail.to_json()
    if log.damage:
        common["log_damage"] = [d.to_json() for d in log.damage]
    if "torn_tail" in audio_report:
        common["audio_torn_tail"] = audio_report["torn_tail"]
    if "log_damage" in audio_report:
        common["audio_log_damage"] = audio_report["log_damage"]
    if audio_report.get("gaps"):
        common["audio_gaps"] = len(audio_report["gaps"])
    errors = [
        n.get("message")
        for n in audio_report.get("notes", []) + log.notes
        if n.get("kind", "").endswith("error")
    ]
    if errors:
        common["errors"] = errors
    summaries: list[dict[str, Any]] = []
    failed: list[dict[str, Any]] = []
    stray_streams = stray_frames = 0
    used: set[str] = set()  # take folder names of this session, case-folded
    try:
        for sid in log.stream_ids():
            info = log.streams.get(sid, {})
            who = {"device": info.get("device"), "subject": info.get("subject")}
            try:
                takes, report = stream_takes(log, sid, audio, audio_first_s)
            except (MemoryError, ValueError, OverflowError, OSError, S2AError) as exc:
                message = f"the takes of stream {sid} could not be built: {type(exc).__name__}: {exc}"
                failed.append(who | {"error": message})
                continue
            failed += [who | {"error": e} for e in report.pop("errors", [])]
            for take in takes:
                take.meta.id = _unique_id(take.meta.id, used)
                take.meta.extra["rejected"] = dict(log.rejected)
                take.meta.extra["recovered"] = recovered
                take.meta.extra |= {
                    k: report[k] for k in ("packets", "duplicates", "out_of_order", "restarts")
                }
                if log.torn_tail is not None:
                    take.meta.extra["torn_tail"] = log.torn_tail.to_json()
                if log.damage:
                    take.meta.extra["log_damage"] = common["log_damage"]
                try:
                    folder = write_take(take, out_dir)
                except (OSError, S2AError) as exc:  # a full disk, a read-only folder: this take only
                    where = Path(out_dir) / take.meta.id
                    message = f"{where}: cannot write the take: {getattr(exc, 'strerror', None) or exc}"
                    failed.append(who | {"error": str(exc) if isinstance(exc, S2AError) else message})
                    continue
                summaries.append(
                    take.summary()
                    | common
                    | report
                    | {"device": take.meta.device, "subject": take.meta.subject, "path": str(folder)}
                )
            if not takes:
                stray_streams += 1
                stray_frames += report["stray_frames"]
    finally:
        log.close()
    if not summaries and not failed:
        summaries.append(
            common | {"device": None, "subject": None, "frames": 0, "dropped_frames": 0, "path": None}
        )
    # A take that failed is reported in its own summary (path None, "error") after the written ones.
    summaries += [common | {"frames": 0, "dropped_frames": 0, "path": None} | f for f in failed]
    for s in summaries:
        # Streams too short for a take (a stray or corrupt packet) stay in the log and are counted here.
        s["stray_streams"] = stray_streams
        s["stray_stream_frames"] = stray_frames
    if not failed:
        # Not complete while a take is missing: ``recover`` retries it (e.g. once the disk has room).
        try:
            write_json_atomic(
                session_dir / COMPLETE_FILE,
                {"takes": [s.get("path") for s in summaries], "recovered": recovered},
            )
        except OSError as exc:
            message = f"{session_dir}: cannot mark the session complete: {exc.strerror or exc}"
            summaries.append(
                summaries[-1] | {"device": None, "subject": None, "path": None, "error": message}
            )
    return summaries
