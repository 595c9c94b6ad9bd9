"""Takes from a live session's logs: used when ``listen`` stops and by ``recover`` after a crash.

Per device/subject stream, frames are read from ``frames.log`` into arrays (frames of a rate above
``livelink.MAX_RATE_FPS`` dropped); another source of the same names the recorder logged apart joins
the stream unless it is a second sender (``_streams_by_sender``). Each stretch of one declared rate (the
recorder logs a change of rate once it holds, see ``recorder.RATE_CHANGE_PACKETS``; a rate that jitters
within ``recorder.RATE_JITTER``, a sender declaring its measured rate, is one stretch read at its median
rate: ``_rate_stretches``), its wraps at midnight undone, is read as the phone's frame clock by
``follow_clock``: its recordings (a new one where the clock restarted: it went back and went on from
there), the late packets that belong to them (at most ``MAX_LATENESS_S`` behind, in a gap of it no
longer than that, ``_far_behind``, or going on from the current recording's frames without a gap,
``_continuing``, or filling a gap of an earlier one from end to end, ``_bridging``: a clock that stepped
forward and then back, into the gap its step left, begins a recording of its own, which its first take's
``clock_returned`` note says), and stray
packets (a corrupt or spoofed frame number) that belong to none. Per recording, small steps back of the
phone's clock are undone (``_undo_steps_back``: the frames after one are placed where they arrived),
duplicates (copies of one datagram) are dropped keeping the first arrival, frames sharing a frame time
with other values are spread over it or counted (``_time_ordered``), the rest are ordered by frame time,
cut where the phone's clock stepped forward (``_clock_steps``) and split into segments wherever the
phone's frame time between two frames with a face jumps by more than ``MAX_GAP_S`` (a long pause or a
long time without a face).
Each segment with at least ``MIN_TAKE_FRAMES`` frames with a face becomes a take, from its first to its
last frame with a face; the no-face packets in between become FACE_LOST frames (NaN values, their own
time and arrival, as the app's face-lost CSV rows), gaps in the frame times DROPPED frames
(``csv_take.fill_dropped``, as for CSV takes, on the grid of the declared rate: ``_segment_take``)
within a budget (``MAX_DROPPED_PER_FRAME``) that bounds what a frame clock can make us allocate. A live
stream has no record start or stop, so no-face packets before a take's first face or after its last are
not part of it (``face_lost_outside_takes``).

A stream whose frame clock cannot be trusted (``follow_clock``'s ``problem``: most packets repeat the
frame time of an earlier one with another frame, the clock runs backwards, jumps back far more often
than a phone restarts or advances many frames per packet, as senders built on PyLiveLinkFace do, whose
frame numbers are milliseconds counted as frames, or is no clock at all) is placed by arrival time
instead (``arrival_clock``): packets in arrival order on the declared rate's grid, gaps as DROPPED
frames; the take's ``meta.extra.frame_clock`` and a ``frame_clock`` repair say so.

A stream of CONTROLS records (a MetaHuman Animator subject of the newer app's realtime stream, logged by
``cps_control.PhoneStream``) is read the same way; its takes' channels are the controls its STREAM record
names (``control_0``, ... with a ``controls_unnamed`` repair when the log lost that record) and their
``source_kind`` is ``livelink_realtime``.

Clocks: take time 0 is the segment's first phone frame time. The phone clock is put on the session
clock with ``offset = min(arrival_s - frame_time_s)`` over the segment (the packet that travelled
fastest), so recorder time ``m`` is take time ``m - offset - frame_time_0``. The audio's first sample,
stamped on the session clock, lands at ``audio_first_s - offset - frame_time_0`` and sync events
likewise. A take gets the session's audio from ``AUDIO_MARGIN_S`` plus a frame period before its first
frame to as long after its last frame's period (``_attach_audio_span``; less at the audio's ends),
copied from the log into the take's WAV a block at a time (``SessionAudio.span``), with ``start_s`` moved
by the samples left out before it: each sample keeps its take time.
"""

from __future__ import annotations

import math
import shutil
import struct
import tempfile
from fractions import Fraction
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from . import livelink as ll
from .atomic import write_json_atomic
from .audio_capture import AudioLogChanged, SessionAudio, index_audio_log
from .channels import ARKIT61
from .command import stops_deferred
from .csv_take import detect_fps, fill_dropped, missing_frames, repair
from .errors import InputError, S2AError, strict_names
from .numbers import is_count
from .record_log import INVALID_RECORD, LogReader, RecordType, json_fields
from .recorder import (
    AUDIO_LOG,
    COMPLETE_FILE,
    FRAME_PAYLOAD_BYTES,
    FRAMES_LOG,
    NO_FACE_PAYLOAD_BYTES,
    RATE_CHANGE_PACKETS,
    RATE_JITTER,
    SESSION_SUFFIX,
    close_rates,
)
from .serial_sync import SYNC_HEAD_BYTES, decode_sync_record
from .take import MAX_FPS, FrameStatus, Take, TakeMeta, safe_id, write_take
from .timecode import DAY_S, Timecode

MAX_GAP_S = 5.0
MIN_TAKE_FRAMES = 10
# What a stream's packets add to the counts of the take that holds their frames (``stream_takes``; a copy
# and a frame sharing its frame time that is dropped are counted with the frame kept for them), besides
# its ``packets`` and ``rate_jitter_packets``. The stream's totals stay in its report.
TALLY = ("duplicates", "out_of_order", "same_time_frames", "same_time_dropped")
# The counts each take has of its own, of the stream's report (the stream's totals: ``stream_counts``).
TAKE_COUNTS = ("packets", *TALLY, "clock_steps_back", "rate_jitter_packets")
# The counts of a stream's report a take's metadata holds, in this order: its ``TAKE_COUNTS`` (its own) and
# the stream's (a restart, a clock step forward is between takes).
REPORTED = (
    "packets",
    "duplicates",
    "out_of_order",
    "restarts",
    "rate_changes",
    "stray_packets",
    "same_time_frames",
    "same_time_dropped",
    "clock_steps",
    "clock_steps_back",
    "rate_jitter_packets",
    "senders",
)
# A take's audio reaches this far (plus one frame period) before its first frame and after its last
# frame's period: room for the aligner's default search for the offset between face and audio (align's
# --max-offset-ms 500, looked at 0.25 s beyond that, and a clap there is judged against the 0.5 s of
# sound around it), so the offset it can find is the same as with the whole session's audio.
AUDIO_MARGIN_S = 1.0
# A take's audio starts on a whole multiple of this (s) of the session's audio, the least common multiple of
# the steps align takes from the audio's first sample (its 16 kHz samples, 10 ms energy steps, 30 and 32 ms
# speech-detector windows): they fall where they fell in the whole session's audio, so that align finds
# the same offset and cuts the same samples (off the grid, its content lag moved by up to 4.5 ms).
AUDIO_SPAN_GRID_S = Fraction(12, 25)
# The phone's frame clock, as ``follow_clock`` reads it: the running median of the frame times over
# 2 * CLOCK_HALF_WINDOW + 1 packets (arrival order), which a minority of late or stray packets cannot move.
CLOCK_HALF_WINDOW = MIN_TAKE_FRAMES
# Packets within this of the clock follow it, and the clock jumps (back: a restart or a burst of late
# packets; forward: a pause) where it moves by more. Under heavy jitter the tolerance is JITTER_TOLERANCE
# times the packets' lateness (``_lateness``), if that is more.
RESTART_WINDOW_S = 1.0
JITTER_TOLERANCE = 3.0
LATENESS_WINDOW = 9
LATENESS_QUANTILE = 0.75
# A lateness above this is no network's: the frame times are not a clock (random frame numbers).
MAX_LATENESS_S = 10.0
# A late frame at most this many of a recording's frame steps from one of its frames (a packet or two lost
# between) goes on from it: frames of one take form one run on the phone's clock (``_continuing``).
RUN_STEPS = 3
# A frame this close to one a recording already has (in frame steps) fills no gap of it: it is not a late
# frame of that recording but a frame of another one at the same time.
SLOT_FRACTION = 0.45
# A phone's frame clock moves forward with its packets and restarts rarely: a stream where most packets
# repeat the frame time of an earlier one with another frame, whose clock runs backwards, whose frame
# times mostly follow no clock, or whose clock jumps back at least MIN_CLOCK_JUMPS times and more than
# once per CLOCK_JUMP_S of arrivals, has a frame clock that says nothing about time. (Its speed against
# the arrivals says nothing: a replay at --speed 50 runs 50 times fast.)
MIN_CLOCK_JUMPS = 4
CLOCK_JUMP_S = 10.0
# Nor does a frame number that advances more than MAX_FRAME_ADVANCE times as many frames per packet as
# the packets' spacing in frame periods (and more than MAX_FRAME_ADVANCE): PyLiveLinkFace counts
# milliseconds as frames (1000 / fps per packet, falling back every second), which this tells within a
# second. A phone's advances 1 or 2 (a
# replay sends every frame at any speed; network loss slows the packets down as much as the count).
MAX_FRAME_ADVANCE = 4.0
# A sender that ticks faster than its frame clock counts (a 60 Hz tracker declaring 30 fps without
# sub-frames) sends several frames with one frame time. When at least SHARED_TIME_FRACTION of a
# recording's frames share their frame time with another frame, up to MAX_FRAMES_PER_TIME per frame time,
# they are spread evenly over the frame period in arrival order; a few are kept only first (and counted).
# More frames per frame time is a frozen clock, placed by arrival time.
MAX_FRAMES_PER_TIME = 4
SHARED_TIME_FRACTION = 0.25
# A forward jump of the frame time by more than CLOCK_STEP_S that the arrivals do not show (an NTP
# correction, a clock set forward) is no network loss: the recording is cut there and each part keeps its
# own clock offset. Judged where the frames on each side (STEP_SIDE_S of frame time) came at one pace
# (frame time against arrivals, the same within PACE_TOLERANCE: a replay at --speed 4 keeps its gaps) over
# at least MIN_PACE_S of arrivals (packets sent all at once tell nothing).
CLOCK_STEP_S = 0.5
STEP_SIDE_S = 1.0
PACE_TOLERANCE = 0.25
MIN_PACE_S = 0.1
# A step back of the phone's clock by more than BACK_STEP_S that the arrivals do not show (an NTP or
# Tentacle Sync re-sync), too small for a restart (RESTART_WINDOW_S), is undone: the frames after it are
# placed where they arrived (``_undo_steps_back``).
BACK_STEP_S = 0.1
# Frames that came this many times as fast as their recording's (over a side) are a burst the network held
# back, not a clock that stepped back.
BURST_PACE = 4.0
MAX_STEP_SIDE_PACKETS = 120  # a side of STEP_SIDE_S at most this many packets (a declared 1000 fps)
# A jittering declared rate (``_rate_stretches``): two runs of nearby rates are a change of setting when
# each has at least this many packets.
RATE_HOLD_PACKETS = 2 * MIN_TAKE_FRAMES
# DROPPED frames a take may get per received frame (plus MAX_GAP_S at the stream's rate): past that,
# as only a corrupt or hostile frame clock needs, the gaps are left unfilled.
MAX_DROPPED_PER_FRAME = 4
SPILL_BYTES = 64 << 20
# A take's frames whose frame numbers step by k > 1 (their median step) at least this often (losses make
# multiples of k) come from a sender that sends every k-th frame of its declared rate: a take at rate / k.
STEADY_STRIDE_FRACTION = 0.95


def row_dtype(values: int) -> np.dtype:
    """One logged frame of ``values`` values: arrival ns (little-endian, ours) + the packet's frame block
    (big-endian, the app's)."""
    return np.dtype(
        [
            ("arrival_ns", "<i8"),
            ("frame_number", ">i4"),
            ("sub_frame", ">f4"),
            ("rate_numerator", ">i4"),
            ("rate_denominator", ">i4"),
            ("count", "u1"),
            ("values", ">f4", (values,)),
        ]
    )


ROW_DTYPE = row_dtype(ll.BLENDSHAPE_COUNT)
_STREAM_ID = struct.Struct("<H")
_ARRIVAL_NS = struct.Struct("<q")
_FRAME_AT = 1 + 2  # payload offset of arrival ns (after type and stream id)
# A CONTROLS record (a subject logged with its own controls): its values after the arrival and frame time.
_CONTROLS_AT = _FRAME_AT + 8 + ll.FRAME_TIME_BYTES
# The streams of CONTROLS records have ids of their own: a SessionLog keeps them as this plus their id.
CONTROLS_STREAMS = 0x10000
# What a no-face record's row gets after its frame time: count 0 and NaN values (big-endian like the rest).
_NO_FACE_TAIL = bytes([0]) + np.full(ll.BLENDSHAPE_COUNT, np.nan, dtype=">f4").tobytes()


_INT = (int,)
_TEXT = (str,)
# The JSON records of a frames log: the fields a recorder writes with their types, and the required ones.
_JSON_FIELDS: dict[int, tuple[dict[str, tuple[type, ...]], tuple[str, ...]]] = {
    RecordType.SESSION: ({"session": _TEXT, "clock": (dict,)}, ()),
    RecordType.STREAM: (
        {
            "stream": _INT,
            "device": _TEXT,
            "subject": _TEXT,
            "rate_numerator": _INT,
            "rate_denominator": _INT,
            "source": (str, type(None)),
            "port": (int, type(None)),
            "alongside": _INT,
            "source_kind": _TEXT,
            "controls": (list,),
        },
        ("stream",),
    ),
    RecordType.REJECTS: ({}, ()),
    RecordType.END: ({"datagrams": _INT, "accepted": _INT, "socket_errors": _INT}, ()),
    RecordType.NOTE: ({"kind": _TEXT, "message": _TEXT}, ()),
}


def _plausible_json(kind: int, data: dict[str, Any]) -> bool:
    """What ``json_fields`` does not check: a 16-bit stream id, a clock origin in ns, counts."""
    if kind == RecordType.STREAM:
        controls = data.get("controls")  # the names of a CONTROLS stream's values
        named = controls is None or bool(controls) and all(isinstance(c, str) and c for c in controls)
        return 0 <= data["stream"] <= 0xFFFF and named
    if kind == RecordType.SESSION:
        origin = data.get("clock", {}).get("origin_ns")
        return origin is None or type(origin) is int and -(2**63) <= origin < 2**63  # an int64 of ns
    if kind == RecordType.REJECTS:
        return all(is_count(v) for v in data.values())
    return True


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
        self._row_dtypes: dict[int, np.dtype] = {}  # of the streams of CONTROLS records (ROW_DTYPE else)
        # Rows wait in memory per stream; past SPILL_BYTES in all they go to files, so that building
        # the takes of many long streams needs one stream's rows in memory at a time.
        self._pending: dict[int, bytearray] = {}
        self._pending_bytes = 0
        self._spill_dir: Path | None = None
        first_stamp: int | None = None
        reader = LogReader(self.dir / FRAMES_LOG)
        try:  # a stop (or an error) while the log is read removes the rows spilled so far
            for payload in reader:
                kind = payload[0]
                size = len(payload)
                if (kind == RecordType.FRAME and size == FRAME_PAYLOAD_BYTES) or (
                    kind == RecordType.NO_FACE and size == NO_FACE_PAYLOAD_BYTES
                ):
                    (sid,) = _STREAM_ID.unpack_from(payload, 1)
                    first_stamp = self._counted(sid, payload, first_stamp)
                    self._pending[sid] += payload[_FRAME_AT:]
                    if kind == RecordType.NO_FACE:
                        self._pending[sid] += _NO_FACE_TAIL
                    self._pending_bytes += ROW_DTYPE.itemsize
                    if self._pending_bytes > SPILL_BYTES:
                        self._spill()
                elif kind == RecordType.CONTROLS and size > _CONTROLS_AT and (size - _CONTROLS_AT) % 4 == 0:
                    (sid,) = _STREAM_ID.unpack_from(payload, 1)
                    sid += CONTROLS_STREAMS
                    dtype = self._row_dtypes.setdefault(sid, row_dtype((size - _CONTROLS_AT) // 4))
                    if dtype["values"].shape[0] != (size - _CONTROLS_AT) // 4:
                        reader.reject(INVALID_RECORD)  # a control count its stream's frames do not have
                        continue
                    first_stamp = self._counted(sid, payload, first_stamp)
                    self._pending[sid] += payload[_FRAME_AT:_CONTROLS_AT]
                    self._pending[sid].append(1)  # a face (no-face packets are not logged so)
                    self._pending[sid] += payload[_CONTROLS_AT:]
                    self._pending_bytes += dtype.itemsize
                    if self._pending_bytes > SPILL_BYTES:
                        self._spill()
                elif kind == RecordType.SYNC and size >= SYNC_HEAD_BYTES:
                    self.sync.append(decode_sync_record(payload))
                elif kind in _JSON_FIELDS:
                    data = json_fields(payload, *_JSON_FIELDS[kind])
                    if data is None or not _plausible_json(kind, data):
                        reader.reject(INVALID_RECORD)
                    elif kind == RecordType.SESSION:
                        self.session = data
                    elif kind == RecordType.STREAM:
                        own = "controls" in data  # a stream of CONTROLS records
                        self.streams[data["stream"] + CONTROLS_STREAMS * own] = data
                    elif kind == RecordType.REJECTS:
                        self.rejected = {k: v for k, v in data.items() if v}
                    elif kind == RecordType.END:
                        self.end = data
                    else:
                        self.notes.append(data)
                elif kind in (RecordType.FRAME, RecordType.NO_FACE, RecordType.SYNC, RecordType.CONTROLS):
                    reader.reject(INVALID_RECORD)
            if self._spill_dir is not None:
                self._spill()
            for sid, dtype in self._row_dtypes.items():  # control names of each CONTROLS stream
                info = self.streams.setdefault(sid, {"stream": sid - CONTROLS_STREAMS})
                if len(info.get("controls", ())) != dtype["values"].shape[0]:  # its STREAM record lost
                    info["controls"] = [f"control_{i}" for i in range(dtype["values"].shape[0])]
                    info["controls_unnamed"] = True
            self.torn_tail = reader.torn_tail
            self.damage = reader.skipped
            origin = self.session.get("clock", {}).get("origin_ns")
            if origin is None:
                # Killed before the session record reached the disk: use the first stamp as the origin.
                origin = first_stamp or 0
            self.origin_ns = int(origin)
        except BaseException:
            self.close()
            raise

    def _counted(self, sid: int, payload, first_stamp: int | None) -> int | None:
        """Count a frame record of stream ``sid`` (its rows begun at its first); ``first_stamp`` lowered
        to the arrival of a stream's first frame."""
        if sid not in self.frame_counts:
            self.frame_counts[sid] = 0
            self._pending[sid] = bytearray()
            (stamp,) = _ARRIVAL_NS.unpack_from(payload, _FRAME_AT)
            first_stamp = stamp if first_stamp is None else min(first_stamp, stamp)
        self.frame_counts[sid] += 1
        return first_stamp

    def _spill(self) -> None:
        if self._spill_dir is None:
            # Ctrl-C and SIGTERM wait until the folder is noted here: met as it was made, a stop left it
            with stops_deferred():
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
        packets with ``count`` 0 and NaN values); a stream of CONTROLS records as ``row_dtype`` records
        of its control count (``count`` 1)."""
        dtype = self._row_dtypes.get(sid, ROW_DTYPE)
        if self._spill_dir is None:
            return np.frombuffer(self._pending[sid], dtype=dtype)
        return np.fromfile(self._spill_dir / f"{sid}.rows", dtype=dtype)

    def close(self) -> None:
        """Remove the spilled rows."""
        if self._spill_dir is not None:
            with stops_deferred():  # a second Ctrl-C cuts no removal short
                shutil.rmtree(self._spill_dir, ignore_errors=True)
                self._spill_dir = None

    def seconds(self, ns) -> Any:
        return (np.asarray(ns, dtype=np.int64) - self.origin_ns) / 1e9


def _segments(frame_time: np.ndarray) -> list[slice]:
    breaks = np.flatnonzero(np.diff(frame_time) > MAX_GAP_S) + 1
    bounds = [0, *breaks.tolist(), frame_time.size]
    return [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]


def _window_medians(values: np.ndarray, width: int) -> np.ndarray:
    """Element ``width // 2`` in sorted order of every full window ``values[k : k + width]`` (the median
    for odd widths): ``values.size - width + 1`` of them."""
    kth = width // 2
    out = np.empty(values.size - width + 1)
    for a in range(0, out.size, 1 << 15):  # in chunks: the windows are copied to be partitioned
        b = min(a + (1 << 15), out.size)
        windows = np.lib.stride_tricks.sliding_window_view(values[a : b + width - 1], width)
        out[a:b] = np.partition(windows, kth, axis=1)[:, kth]
    return out


def _running_median(values: np.ndarray, half: int) -> np.ndarray:
    """The median of ``values[i - half : i + half + 1]`` at each ``i`` (the window held inside the array
    at its ends: the first and last ``half`` get the median of the first and last full window)."""
    n = values.size
    width = 2 * half + 1
    if n <= width:
        return np.full(n, np.sort(values)[(n - 1) // 2] if n else 0.0)
    out = np.empty(n)
    out[half : n - half] = _window_medians(values, width)
    out[:half] = out[half]
    out[n - half :] = out[n - half - 1]
    return out


def _lateness(frame_time: np.ndarray) -> float:
    """How late packets typically are: the ``LATENESS_QUANTILE`` quantile of how far each packet's frame
    time is behind the median of the ``LATENESS_WINDOW`` packets before it (0 when ahead). In seconds of
    frame time; 0 for a clock in order however fast it runs; a stray packet now and then does not move it."""
    n = frame_time.size
    if n <= LATENESS_WINDOW:
        return 0.0
    late = _window_medians(frame_time[:-1], LATENESS_WINDOW) - frame_time[LATENESS_WINDOW:]
    return float(np.quantile(np.maximum(late, 0.0), LATENESS_QUANTILE))


def _pieces(level: np.ndarray, tol: float) -> tuple[list[int], list[int]]:
    """Where the clock ``level`` (in arrival order) jumps: starts of the stretches between jumps and how
    each begins (0 the first, -1 a jump back of more than ``tol`` below the highest level of the stretch
    before, +1 a jump forward of more than ``tol``, 0 after a jump back where the clock is back at the
    level it had before it: it went on, past late packets it went back to or from where it restarted)."""
    starts, kinds = [0], [0]
    values = level.tolist()
    top = prev = values[0]
    was = np.inf  # the highest level before the last jump back, until the clock is back there
    for i, v in enumerate(values):
        if v < top - tol:
            starts.append(i)
            kinds.append(-1)
            was = min(was, top)
            top = v
        elif v > prev + tol or v >= was:
            starts.append(i)
            kinds.append(1 if v > prev + tol else 0)
            was = np.inf
            top = v
        elif v > top:
            top = v
        prev = v
    return starts, kinds


def _identical(rows: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Whether rows ``a[k]`` and ``b[k]`` carry the same frame byte for byte (a datagram that arrived
    twice), frame time aside."""
    same = rows["count"][a] == rows["count"][b]
    va = rows["values"][a].view(np.uint32).reshape(a.size, -1)
    vb = rows["values"][b].view(np.uint32).reshape(b.size, -1)
    return same & (va == vb).all(axis=1)


def _repeated_times(rows: np.ndarray, frame_time: np.ndarray) -> int:
    """Packets whose frame time an earlier packet already had, with another frame (copies of a datagram
    are duplicates, not a frozen clock)."""
    order, again, first = _time_repeats(frame_time)
    if not again.size:
        return 0
    return int(np.count_nonzero(~_identical(rows, order[again], order[first])))


def _time_repeats(frame_time: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Packets (arrival order) in frame-time order ``order`` (arrival order within a frame time): the places
    in it of those whose frame time an earlier packet already had, and of that earlier packet each."""
    order = np.argsort(frame_time, kind="stable")
    rank, _ = _rank_in_time(frame_time[order])
    again = np.flatnonzero(rank)
    return order, again, again - rank[again]


class _Recording:
    """Rows of one recording of a stream being collected: parts (row indices and their frame times, in
    frame-time order) and the frame-time range."""

    def __init__(self) -> None:
        self.parts: list[tuple[np.ndarray, np.ndarray]] = []
        self.bounds: list[tuple[float, float]] = []
        self.lo = np.inf
        self.hi = -np.inf

    def add(self, idx: np.ndarray, frame_time: np.ndarray) -> None:
        if idx.size:
            idx = idx[np.argsort(frame_time[idx], kind="stable")]
            times = frame_time[idx]
            self.parts.append((idx, times))
            self.bounds.append((float(times[0]), float(times[-1])))
            self.lo = min(self.lo, self.bounds[-1][0])
            self.hi = max(self.hi, self.bounds[-1][1])

    def rows(self) -> np.ndarray:
        return np.concatenate([idx for idx, _ in self.parts]) if self.parts else np.zeros(0, np.int64)

    def around(self, lo: float, hi: float) -> np.ndarray:
        """The rows with a frame time in [lo, hi] (touching only the parts there)."""
        if not self.parts:
            return np.zeros(0, np.int64)
        bounds = np.asarray(self.bounds)
        found = [
            self.parts[k][0][
                np.searchsorted(self.parts[k][1], lo) : np.searchsorted(self.parts[k][1], hi, "right")
            ]
            for k in np.flatnonzero((bounds[:, 1] >= lo) & (bounds[:, 0] <= hi)).tolist()
        ]
        return np.concatenate(found) if found else np.zeros(0, np.int64)


def _late_frames_of(
    rec: _Recording,
    idx: np.ndarray,
    rows: np.ndarray,
    frame_time: np.ndarray,
    arrival_s: np.ndarray,
    tol: float,
    resumes: bool,
    max_behind: float = MAX_LATENESS_S,
    on_clock: bool = False,
    gap_only: bool = False,
) -> bool:
    """Whether the frames ``idx`` (a stretch the clock jumped back to) are late frames of ``rec``: they lie
    in its frame-time range (or next to it, when the clock then resumes where ``rec`` was), at most
    ``max_behind`` behind its latest frame or in a gap of it no longer than that (``_far_behind``) or,
    when ``rec`` is the recording the clock is on (``on_clock``), going on from its frames
    (``_continuing``), and mostly fill its gaps (all of them, ``gap_only``): a frame on a slot ``rec``
    already has (``_taken_slots``; with ``on_clock``, only of its frames after a small step back of its
    clock when ``idx`` lies in a gap of them, ``_since_step_back``) is a frame of another recording at
    the same time (a restart), not a late packet."""
    ft = frame_time[idx]
    if not ft.size:
        return True
    if max_behind < np.inf:  # no frame is more than infinitely far behind: no recording's rows gathered
        middle = np.median(ft, keepdims=True)
        ends = rec.around(middle[0] - max_behind, middle[0] + max_behind)  # where a gap this long can end
        if _far_behind(middle, rec.hi, frame_time[ends], max_behind)[0]:
            # unless they go on from its frames, all in one gap of them (none of theirs among them), and
            # fill it from end to end when the clock has gone on to another recording (a burst held back
            # over a restart)
            ours = frame_time[rec.around(float(ft.min()) - tol, float(ft.max()) + tol)]
            among = np.any((ours > ft.min()) & (ours < ft.max()))
            if among or not _continuing(ft, ours, ft).all() or not (on_clock or _bridging(ft, ours)):
                return False
    near = (ft >= rec.lo - tol) & (ft <= rec.hi + tol)
    if 2 * np.count_nonzero(near) < ft.size:
        return False
    if not resumes and 2 * np.count_nonzero((ft >= rec.lo) & (ft <= rec.hi)) < ft.size:
        return False
    have = rec.around(float(ft.min()) - tol, float(ft.max()) + tol)
    if on_clock:  # a burst held back just after a step back of the clock: on slots of the clock after it
        have = _since_step_back(ft, have, frame_time, arrival_s)
    taken = _taken_slots(idx[near], have, rows, frame_time, arrival_s)
    return not taken.any() if gap_only else 2 * np.count_nonzero(taken) < ft.size


def _since_step_back(
    ft: np.ndarray, have: np.ndarray, frame_time: np.ndarray, arrival_s: np.ndarray
) -> np.ndarray:
    """Of the frames ``have`` of the recording the clock is on, those that hold their slots against frames
    ``ft`` (a stretch the clock jumped back to): all of them, unless the frames that came after the last
    of them in ``ft``'s range fill no part of it and reach it on both sides (``_bridging``): the phone's
    clock stepped back a little, and ``ft`` is a burst of its frames after the step that the network held
    back, on slots of the frames before it (undone by ``_undo_steps_back``) but in a gap of those after
    it; only those after it count. A restart's frames come on slots the frames that came after them still
    hold."""
    inside = have[(frame_time[have] >= ft.min()) & (frame_time[have] <= ft.max())]
    if not inside.size:
        return have
    since = have[arrival_s[have] > arrival_s[inside].max()]
    return since if _bridging(ft, frame_time[since]) else have


def _far_behind(ft: np.ndarray, clock: np.ndarray | float, have: np.ndarray, limit: float) -> np.ndarray:
    """Which frame times ``ft`` cannot be late frames of a recording whose frame times ``have`` are (any
    order): more than ``limit`` behind its ``clock`` (its latest frame when they came) and in a gap of
    ``have`` longer than ``limit``. A network may hold back a packet, or a burst of them, for longer than
    ``limit``: the gap they left is then as long as the burst, and they fill it. A longer gap far behind
    the clock is one the clock left by stepping forward; frames in it come from the clock stepping back
    into it (a clock corrected twice, a timecode source switched and back), not from the network (unless
    they go on from the frames of the recording the clock is on, ``_continuing``: its callers ask)."""
    times = np.concatenate([[-np.inf], np.sort(have), [np.inf]])
    after = np.searchsorted(times, ft, "right")  # the first of ``have`` after each (ft is finite)
    gap = times[after] - times[after - 1]
    return (np.asarray(clock) - ft > limit) & (gap > limit)


def _continuing(ft: np.ndarray, have: np.ndarray, along: np.ndarray) -> np.ndarray:
    """Which frame times ``ft`` go on from a recording's frame times ``have`` (any order) without a gap:
    in one run with them and the frames ``along`` (each at most ``RUN_STEPS`` of the recording's frame
    steps from the next), as the frames of one take are on the phone's clock. The network may hold back
    the last frames before a pause, or a take's first frames, until after the frames that follow them:
    they go on from the recording's frames before or after them, however long the pause. A clock that
    stepped back into a gap its step forward left lands as far from the frames before the gap as it was
    ahead: it goes on from none."""
    step = _frame_step(np.sort(have))
    if step is None:
        return np.zeros(ft.size, bool)
    times = np.concatenate([have, ft, along])
    order = np.argsort(times, kind="stable")
    run = np.empty(times.size, np.int64)  # each frame's run
    run[order] = np.concatenate([[0], np.cumsum(np.diff(times[order]) > RUN_STEPS * step)])
    ours = np.zeros(int(run.max()) + 1, bool)
    ours[run[: have.size]] = True
    return ours[run[have.size : have.size + ft.size]]


def _bridging(ft: np.ndarray, have: np.ndarray) -> bool:
    """Whether frame times ``ft`` reach a recording's frame times ``have`` (any order) on both sides, each
    end within ``RUN_STEPS`` of its frame steps of one of them: they fill a gap of it from end to end."""
    step = _frame_step(np.sort(have))
    if step is None:
        return False
    reach = RUN_STEPS * step
    below = (have < ft.min()) & (have >= ft.min() - reach)
    above = (have > ft.max()) & (have <= ft.max() + reach)
    return bool(below.any() and above.any())


def _frame_step(times: np.ndarray) -> float | None:
    """The frame step of frame times ``times`` (sorted): the median step between frames of different
    times; None with fewer than two."""
    steps = np.diff(times)
    steps = steps[steps > 0]
    return float(np.median(steps)) if steps.size else None


def _taken_slots(
    idx: np.ndarray,
    have: np.ndarray,
    rows: np.ndarray,
    frame_time: np.ndarray,
    arrival_s: np.ndarray,
    apart: np.ndarray | float = 0.0,
) -> np.ndarray:
    """Which frames ``idx`` land closer than ``SLOT_FRACTION`` of a frame step (the median step of the
    frames ``have``) to one of the frames ``have``, and are not a copy of it that the network delivered
    twice (byte for byte, within ``MAX_GAP_S``; a sender that sends the same frames again later, as a
    replay run twice does, restarted), nor one that arrived after the frame, by less than ``apart`` (s,
    per frame)."""
    have = have[np.argsort(frame_time[have], kind="stable")]
    times = frame_time[have]
    step = _frame_step(times)
    if step is None:
        return np.zeros(idx.size, bool)
    ft = frame_time[idx]
    right = np.clip(np.searchsorted(times, ft), 0, times.size - 1)
    left = np.clip(right - 1, 0, times.size - 1)
    nearest = np.where(np.abs(times[left] - ft) < np.abs(times[right] - ft), left, right)
    dist = np.abs(times[nearest] - ft)
    taken = dist < SLOT_FRACTION * step
    copy = dist == 0
    if copy.any():
        a, b = idx[copy], have[nearest[copy]]
        copy[copy] = _identical(rows, a, b) & (np.abs(arrival_s[a] - arrival_s[b]) <= MAX_GAP_S)
    # the frame came first: the one on its slot, later by less than ``apart``, is what took it from it
    after = arrival_s[have[nearest]] - arrival_s[idx]
    taken &= (after <= 0) | (after >= apart)
    return taken & ~copy


# Where a packet off the clock may belong, in the order tried (recordings by index relative to the one
# current at its moment): behind that clock, a late packet, most likely of its own recording; ahead of
# it, a straggler of a recording before a restart, else an early packet of its own.
BEHIND_ORDER = (0, 1, -1, -2, -3)
AHEAD_ORDER = (-1, -2, -3, 0, 1)


def _place_off_clock(
    off: np.ndarray,
    current: np.ndarray,
    recs: list[_Recording],
    level: np.ndarray,
    clock: np.ndarray,
    tol: float,
    rows: np.ndarray,
    frame_time: np.ndarray,
    arrival_s: np.ndarray,
) -> np.ndarray:
    """The recording each packet ``off`` joins (-1: stray): the first of its candidates whose frame-time
    range holds it on a free slot (``_taken_slots``), not ``_far_behind`` it (behind its ``clock`` at the
    packet's moment, -inf where a burst of strays held the clock; an earlier recording's last frame);
    ``current`` is the recording current at its moment."""
    ft = frame_time[off]
    order = np.where((ft <= level[off] + tol)[:, None], BEHIND_ORDER, AHEAD_ORDER) + current[:, None]
    fits = np.zeros(order.shape, bool)
    for c, rec in enumerate(recs):
        who, rank = np.nonzero(order == c)
        if not who.size:
            continue
        at = ft[who]
        ours = current[who] == c  # the recording the clock was on: late frames going on from it are its
        inside = (at >= rec.lo - tol) & (at <= rec.hi + tol)
        behind = np.where(ours, clock[off[who]], np.where(current[who] > c, rec.hi, -np.inf))
        have = rec.rows()
        had = frame_time[have]
        far = _far_behind(at, behind, had, MAX_LATENESS_S)
        if (back := far & ours).any():
            far[back] = ~_continuing(at[back], had, at[ours])
        inside &= ~far
        who, rank = who[inside], rank[inside]
        # a frame of the recording the clock was on that came less than ``tol`` before the one on its slot:
        # the same clock, which stepped back a little between them (undone by ``_undo_steps_back``), not
        # another recording (a restart's clock went back further); one that came after the frame on its
        # slot is not freed, as a restart's frames amid late packets of the recording before it would be
        mine = current[who] == c
        apart = np.where(mine, tol, 0.0)
        free = ~_taken_slots(off[who], have, rows, frame_time, arrival_s, apart)
        # and a frame of that recording is free when only frames from before a small step back of its clock
        # hold its slot and it lies in a gap of the frames after the step (the first frame of a burst the
        # network held back after the step, ``_since_step_back``)
        for k in np.flatnonzero(~free & mine).tolist():
            one = who[k : k + 1]
            near = rec.around(float(ft[one[0]]) - tol, float(ft[one[0]]) + tol)
            since = _since_step_back(ft[one], near, frame_time, arrival_s)
            if since.size < near.size:  # only the frames after a step back hold their slots against it
                free[k] = not _taken_slots(off[one], since, rows, frame_time, arrival_s)[0]
        fits[who[free], rank[free]] = True
    return np.where(fits.any(1), np.take_along_axis(order, fits.argmax(1)[:, None], 1)[:, 0], -1)


class _Clock:
    """How a stream's packets (one declared rate, arrival order) follow the phone's frame clock: its
    recordings (row indices, arrival order), the packets that fit none (``stray``), and ``problem`` when
    the frame times cannot place the frames."""

    def __init__(
        self,
        recordings: list[np.ndarray],
        stray: np.ndarray,
        problem: str | None,
        returned: dict[int, tuple[float, float]] | None = None,
    ):
        self.recordings = recordings
        self.stray = stray
        self.problem = problem
        # recordings (by index) that began where the clock stepped back into a gap the recording before
        # left, too far behind for late frames: (seconds back, the phone's frame time there)
        self.returned = returned or {}


def follow_clock(rows: np.ndarray, frame_time: np.ndarray, arrival_s: np.ndarray) -> _Clock:
    """Read the phone's frame clock from a stream's packets of one rate (in arrival order).

    The clock is the running median of the frame times over ``2 * CLOCK_HALF_WINDOW + 1`` packets: late,
    reordered, duplicated or stray packets, a minority in any window, do not move it. Packets within a
    tolerance of it (``RESTART_WINDOW_S``, more under heavy jitter) follow it; where it jumps back, the
    packets after the jump are either late frames of a recording (they fill its gaps, see
    ``_late_frames_of``) or a new recording (a restart: the phone's clock went back and went on from
    there); a jump forward (a pause) stays in the recording. A packet off the clock joins a recording
    whose frame-time range holds it on a free slot (a late packet, or a straggler of the recording before
    a restart), or is stray (a corrupt or spoofed frame number). ``problem`` says why a stream's frame
    times are no clock (see ``MIN_CLOCK_JUMPS`` and ``MAX_FRAME_ADVANCE``), judged for streams of
    ``2 * MIN_TAKE_FRAMES`` packets or more.
    """
    n = frame_time.size
    empty = np.zeros(0, np.int64)
    if not n:
        return _Clock([], empty, None)
    judge = n >= 2 * MIN_TAKE_FRAMES
    repeats = _repeated_times(rows, frame_time)
    # A few frames per frame time are a sender ticking faster than its clock (spread by stream_takes).
    if judge and repeats > n / 2 and n > MAX_FRAMES_PER_TIME * np.unique(frame_time).size:
        return _Clock([], empty, f"{repeats} of {n} packets repeat the frame time of an earlier packet")
    if judge:
        period = _declared_period(rows)
        advance = float(np.median(np.diff(frame_time))) / period  # frames per packet
        pace = float(arrival_s[-1] - arrival_s[0]) / (n - 1) / period  # frame periods between packets
        if advance > MAX_FRAME_ADVANCE * max(1.0, pace):
            problem = (
                f"the frame number advances {advance:.0f} frames per packet while packets come every "
                f"{pace:.1f} frames (PyLiveLinkFace counts milliseconds as frames)"
            )
            return _Clock([], empty, problem)
    level = _running_median(frame_time, CLOCK_HALF_WINDOW)
    lateness = _lateness(frame_time)
    if judge and lateness > MAX_LATENESS_S:
        problem = f"the frame time of a packet is typically {lateness:.0f} s behind the packets before it"
        return _Clock([], empty, problem)
    tol = max(RESTART_WINDOW_S, JITTER_TOLERANCE * lateness)
    follows = np.abs(frame_time - level) <= tol
    starts, kinds = _pieces(level, tol)
    bounds = [*starts, n]
    span = float(arrival_s[-1] - arrival_s[0])
    recs: list[_Recording] = []
    piece_current: list[int] = []
    clock = level.copy()  # the clock of the recording current at each packet (``_place_off_clock``)
    current = -1
    restarts = 0
    returned: dict[int, tuple[float, float]] = {}  # as ``_Clock.returned``, by index in ``recs``
    net = 0.0
    for k, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
        net += float(level[b - 1] - level[a])
        idx = a + np.flatnonzero(follows[a:b])
        if idx.size < MIN_TAKE_FRAMES and n > 2 * CLOCK_HALF_WINDOW + 1:
            # Too few packets follow the clock here to be a recording (a burst of strays held it): they
            # are placed one by one below, as the packets off the clock are.
            follows[idx] = False
            piece_current.append(current)
            clock[a:b] = -np.inf  # no recording's clock here
            continue
        target = None
        # A jump back (not after a burst of strays that held the clock, back to where the recording was):
        # late frames of the current or an earlier recording, else a restart. A jump forward: on with the
        # current recording, unless these are late frames of an earlier one (stragglers of a restart).
        back = kinds[k] < 0 and current >= 0 and level[a] < recs[current].hi - tol
        first = current if back else current - 1
        resumes = (
            back
            and k + 1 < len(kinds)
            and kinds[k + 1] >= 0
            and level[bounds[k + 1]] >= recs[current].hi - tol
        )
        # cut where the clock came back up to where it was (``_pieces``): a burst the network held back
        # fills the gap it left, none of its frames on a slot the recording has; a clock that stepped back
        # (a Wi-Fi burst after the step cut short the stretch after it) gives frame times it gave before
        gap_only = k + 1 < len(kinds) and kinds[k + 1] == 0
        for c in range(first, max(current - 3, -1), -1) if kinds[k] else ():
            on_clock = c == current
            if _late_frames_of(
                recs[c],
                idx,
                rows,
                frame_time,
                arrival_s,
                tol,
                resumes and on_clock,
                on_clock=on_clock,
                gap_only=gap_only,
            ):
                target = c
                break
        if target is None and (current < 0 or back):
            if current >= 0:
                restarts += 1
                if judge and restarts >= MIN_CLOCK_JUMPS and restarts > span / CLOCK_JUMP_S:
                    problem = (
                        f"the frame time jumps back {restarts} times or more in {span:.1f} s of arrivals"
                    )
                    return _Clock([], empty, problem)
            if current >= 0 and _late_frames_of(
                recs[current],
                idx,
                rows,
                frame_time,
                arrival_s,
                tol,
                resumes,
                max_behind=np.inf,
                gap_only=gap_only,
            ):  # back into the gap its step forward left (a clock corrected twice): not late frames
                first = float(frame_time[idx[0]])
                returned[len(recs)] = (recs[current].hi - first, first)
            recs.append(_Recording())
            current = target = len(recs) - 1
        elif target is None:
            target = current
        recs[target].add(idx, frame_time)
        piece_current.append(current)
    if judge and net < 0:
        return _Clock([], empty, f"the frame time runs backwards ({-net:.1f} s over {n} packets)")
    # Packets off the clock: late packets of a recording (in its frame-time range, on a free slot of it),
    # or stray.
    piece_of = np.repeat(np.arange(len(kinds)), np.diff(bounds))
    off = np.flatnonzero(~follows)
    choice = _place_off_clock(
        off, np.asarray(piece_current)[piece_of[off]], recs, level, clock, tol, rows, frame_time, arrival_s
    )
    extra = [off[choice == c] for c in range(len(recs))]
    stray = off[choice < 0]
    if judge and 2 * stray.size > n:
        problem = f"the frame times of {stray.size} of {n} packets follow no steady clock"
        return _Clock([], empty, problem)
    recordings = []
    kept_returned = {}
    for k, (rec, more) in enumerate(zip(recs, extra)):
        idx = np.sort(np.concatenate([rec.rows(), more]))
        if idx.size:
            if k in returned:
                kept_returned[len(recordings)] = returned[k]
            recordings.append(idx)
    _restarts_unmixed(recordings, rows, frame_time, arrival_s, tol)
    return _Clock(recordings, stray, None, kept_returned)


def _restarts_unmixed(
    recordings: list[np.ndarray], rows: np.ndarray, frame_time: np.ndarray, arrival_s: np.ndarray, tol: float
) -> None:
    """Sort out the packets of a restart and of the recording before it that jitter mixed: a restart's
    first packets that came among the late ones of the recording before follow its clock, and late packets
    of that recording that came among the restart's first follow the restart's, each on the slot of a frame
    of the other clock with other values (one of the two would be dropped as a frame repeating a frame
    time). Such a packet whose frame time has a free slot in the other recording (in its range,
    ``_free_in``) goes to it: the later of the two on a slot of the recording before, if it came after the
    restart's first packet or less than ``tol`` before it; the earlier on a slot of the restart, if it came
    before that packet or less than ``tol`` after it. Not for a sender ticking faster than its frame
    clock (frames sharing a frame time a quarter of a recording's or more: spread over it)."""
    for k in range(len(recordings) - 1):
        ours, theirs = recordings[k], recordings[k + 1]
        begin = arrival_s[theirs[0]]
        back = _sharing_a_slot(rows, ours, frame_time, later=True)
        back = back[arrival_s[back] >= begin - tol]
        late = _sharing_a_slot(rows, theirs, frame_time, later=False)
        late = late[arrival_s[late] <= begin + tol]
        back = back[_free_in(frame_time[back], frame_time[theirs])]
        late = late[_free_in(frame_time[late], frame_time[ours])]
        if back.size or late.size:
            recordings[k] = np.union1d(np.setdiff1d(ours, back), late)
            recordings[k + 1] = np.union1d(np.setdiff1d(theirs, late), back)


def _sharing_a_slot(rows: np.ndarray, idx: np.ndarray, frame_time: np.ndarray, later: bool) -> np.ndarray:
    """Of rows ``idx`` (arrival order), those sharing their frame time with another of them with other
    values: each that came after the first of its frame time (``later``), else each first; none when they
    are a quarter of them or more (a sender ticking faster than its frame clock)."""
    order, again, first = _time_repeats(frame_time[idx])
    if not again.size or again.size >= SHARED_TIME_FRACTION * idx.size:
        return np.zeros(0, np.int64)
    other = ~_identical(rows, idx[order[again]], idx[order[first]])
    return idx[order[(again if later else first)[other]]]


def _free_in(ft: np.ndarray, have: np.ndarray) -> np.ndarray:
    """Which frame times ``ft`` lie in the range of frame times ``have`` (or up to ``RUN_STEPS`` of their
    frame steps before or after it: a restart's first frame) on a slot none of them has."""
    step = _frame_step(np.sort(have))
    if step is None:
        return np.zeros(ft.size, bool)
    reach = RUN_STEPS * step
    return (ft >= have.min() - reach) & (ft <= have.max() + reach) & ~np.isin(ft, have)


def arrival_clock(arrival_s: np.ndarray, period: float) -> np.ndarray:
    """Frame times from arrival times (in arrival order) on a grid of ``period``: frame ``i`` takes the
    grid slot nearest its arrival, at least one after the frame before (a burst of packets the network
    held back fills consecutive slots; a pause leaves empty slots, later DROPPED frames)."""
    slots = np.rint((arrival_s - arrival_s[0]) / period)
    # k_i = max(k_{i-1} + 1, slot_i): a running maximum of slot_i - i, plus i.
    index = np.arange(slots.size)
    return arrival_s[0] + (np.maximum.accumulate(slots - index) + index) * period


def _rate_runs(num: np.ndarray, den: np.ndarray) -> list[slice]:
    """Stretches (arrival order) of one declared rate: the recorder logs a stream's change of rate (the app
    restarted with another frame-rate setting) once it holds, so each stretch is a recording of its own."""
    change = np.flatnonzero((num[1:] != num[:-1]) | (den[1:] != den[:-1])) + 1
    bounds = [0, *change.tolist(), num.size]
    return [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]


def _rate_stretches(num: np.ndarray, den: np.ndarray) -> list[tuple[slice, tuple[int, int] | None]]:
    """Stretches (arrival order) that each make recordings of their own, with the rate a jittering one is
    read at (None: its one declared rate). Consecutive runs of one rate (``_rate_runs``) whose rates lie
    within ``RATE_JITTER`` of each other are one jittering rate (a sender that declares
    its measured rate) when one of them is short (``RATE_HOLD_PACKETS``); runs that each hold are changes
    of setting (24 -> 25, 30 -> 29.97, and back), as is any larger change (30 -> 60), and so is a short
    steady run that starts the stream before one that holds, or ends it after one (``_steady_edge``). A
    jittering stretch is read at the median packet's declared rate."""
    rate = num / den
    runs = _rate_runs(num, den)
    if not num.size:  # every frame dropped (an implausible rate): one empty stretch, as before
        return [(run, None) for run in runs]
    groups: list[list[slice]] = []
    low = high = 0.0  # the rates of the current group span [low, high]
    for run in runs:
        r = float(rate[run.start])
        if groups and max(high, r) <= (1 + RATE_JITTER) * min(low, r):
            groups[-1].append(run)
            low, high = min(low, r), max(high, r)
        else:
            groups.append([run])
            low = high = r
    stretches: list[tuple[slice, tuple[int, int] | None]] = []
    if _steady_edge(groups[0]):
        stretches.append((groups[0][0], None))
        groups[0] = groups[0][1:]
    steady_end = groups[-1].pop() if _steady_edge(groups[-1][::-1]) else None
    parts = [part for runs in groups for part in _settings_apart(runs, rate)]
    for group, lead in parts:
        if lead:  # the packets mixed at a change of setting: too few for a take, each read at its own rate
            stretches.append((slice(group[0].start, group[lead].start), None))
            group = group[lead:]
        shortest = min(run.stop - run.start for run in group)
        # runs that each hold are settings (read at another's rate, a run's frames would sit elsewhere in
        # the day: 24 <-> 25 fps is 4 % of its timecode)
        if len(group) < 2 or shortest >= RATE_HOLD_PACKETS:
            stretches += [(run, None) for run in group]
            continue
        whole = slice(group[0].start, group[-1].stop)
        middle = whole.start + int(
            np.argsort(rate[whole], kind="stable")[(whole.stop - whole.start - 1) // 2]
        )
        stretches.append((whole, (int(num[middle]), int(den[middle]))))
    if steady_end is not None:
        stretches.append((steady_end, None))
    return stretches


# How many runs of one rate (``_rate_runs``) back a late packet of an old rate is looked for its setting.
LATE_RUNS = 8


def _late_packets_placed(num: np.ndarray, den: np.ndarray) -> np.ndarray | None:
    """An arrival order of a stream's packets (rows) in which those of two settings mixed at a change
    (a late, reordered or twice-sent packet of the old setting among the first of the new) each go to
    their own setting's side, or None when no change mixes them; each packet is read at its own declared
    rate all the same, none moves in time. Left where they came, such packets made a stretch of their own
    too short for a take (its frames lost), or, three or more in a row, made both settings one jittering
    rate (24 <-> 25 fps: one of them placed 4 % of the day off). Two cases, in this order:

    - rates further apart (a change the recorder confirms with ``RATE_CHANGE_PACKETS`` packets in a row,
      and after which it logs a late packet of the old rate, ``recorder.LATE_PACKET_S``): a run shorter
      than that of a rate seen last in a run of that length, with only the new rate between;
    - rates within ``RATE_JITTER`` of each other: between two runs (``_rate_runs``) of the two rates that
      hold (``RATE_HOLD_PACKETS``), runs too short to hold that carry only those two rates."""
    order = np.arange(num.size)

    def old_first(between: slice, a: int) -> None:
        """Put the packets of ``between`` at the rate of row ``a`` (arrival order) before the others."""
        n, d = num[order[between]], den[order[between]]
        is_new = (n != num[order[a]]) | (d != den[order[a]])
        order[between] = order[between][np.argsort(is_new, kind="stable")]

    runs = _rate_runs(num, den)
    if len(runs) > 2:
        first = np.array([run.start for run in runs])
        size = np.diff([*first, num.size])
        rate = num[first] / den[first]
        far = np.abs(rate[1:] - rate[:-1]) > RATE_JITTER * np.minimum(rate[1:], rate[:-1])
        # a short run after a far rate, with a run of the length a change is confirmed with among the
        # LATE_RUNS before it: the only ones that can be late packets (a stream jittering at every packet,
        # or one whose corrupt rates alternate, has none, and costs no walk back)
        long_before = np.zeros(len(runs), bool)
        for k in range(1, LATE_RUNS + 1):
            long_before[k:] |= size[:-k] >= RATE_CHANGE_PACKETS
        late = np.flatnonzero((size < RATE_CHANGE_PACKETS) & np.r_[False, far] & long_before)
    else:
        late = []
    for i in late:
        run = runs[i]
        own = (int(num[run.start]), int(den[run.start]))
        new, confirmed = None, 0  # the one other rate back to the last long run of this one
        for j in range(i - 1, max(i - 1 - LATE_RUNS, -1), -1):
            other = runs[j]
            rate_j = (int(num[other.start]), int(den[other.start]))
            if rate_j == own:
                if other.stop - other.start >= RATE_CHANGE_PACKETS:
                    if new is not None and confirmed >= RATE_CHANGE_PACKETS:
                        old_first(slice(other.stop, run.stop), other.start)
                    break
                continue
            if (new is not None and rate_j != new) or close_rates(*rate_j, *own):
                break
            new, confirmed = rate_j, max(confirmed, other.stop - other.start)
    n, d = num[order], den[order]
    runs = _rate_runs(n, d)
    held = None  # the index of the last run that holds
    for i, run in enumerate(runs):
        if run.stop - run.start < RATE_HOLD_PACKETS:
            continue
        if held is not None and i - held > 1:
            a, b = runs[held].start, run.start
            between = slice(runs[held + 1].start, b)
            rates = {(int(n[k]), int(d[k])) for k in (a, b)}
            if {(int(x), int(y)) for x, y in zip(n[between], d[between])} <= rates and len(rates) == 2:
                old_first(between, a)
        held = i
    return None if (order == np.arange(num.size)).all() else order


def _settings_apart(group: list[slice], rate: np.ndarray) -> list[tuple[list[slice], int]]:
    """A group of ``_rate_stretches`` cut where a run that holds (``RATE_HOLD_PACKETS``) is followed by one
    of another rate that holds, with nothing between them but runs shorter than ``RATE_CHANGE_PACKETS``:
    packets of the two rates mixed at a change of setting (a late or duplicated packet of the old setting
    among the first of the new). Without the cut those few packets made the two settings one jittering
    rate, read at the median (24 -> 25 fps with one late 24 fps packet placed the 25 fps frames 4 % of the
    day off). Each part with the number of short runs it begins with (0 for the first), those mixed ones:
    since ``_late_packets_placed`` puts packets of only the two rates on their own sides first, those
    left mixed carry a third rate too."""
    cuts = []
    held = None  # the index of the last run that holds, while only short runs followed it
    for i, run in enumerate(group):
        n = run.stop - run.start
        if n >= RATE_HOLD_PACKETS:
            if held is not None and rate[run.start] != rate[group[held].start]:
                cuts.append((held + 1, i - held - 1))
            held = i
        elif n >= RATE_CHANGE_PACKETS:
            held = None
    bounds = [(0, 0), *cuts, (len(group), 0)]
    return [(group[a:b], lead) for (a, lead), (b, _) in zip(bounds[:-1], bounds[1:])]


def _steady_edge(group: list[slice]) -> bool:
    """Whether the runs of a stream's rates at its start (a group of ``_rate_stretches``; at its end, the
    last group's runs reversed) begin with a change of setting: a run too short to hold
    (``RATE_HOLD_PACKETS``) but of at least ``RATE_CHANGE_PACKETS`` packets of one rate, as the recorder
    confirms a change, next to a run that holds (the app's setting changed right after the stream began,
    or just before it stopped). A jittering edge differs for a packet or two, or changes again before a
    run holds; read at the next run's rate, a steady edge's frames would sit elsewhere in the day."""
    if len(group) < 2:
        return False
    first, second = (run.stop - run.start for run in group[:2])
    return RATE_CHANGE_PACKETS <= first < RATE_HOLD_PACKETS <= second


def _rate_jitter_note(num: np.ndarray, den: np.ndarray, nominal: tuple[int, int]) -> str:
    """What a take says of a jittering declared rate (``_rate_stretches``)."""
    rate = num / den
    changes = int(np.count_nonzero(rate[1:] != rate[:-1]))
    return (
        f"the sender declared a varying frame rate ({rate.min():g} to {rate.max():g} fps, {changes} "
        f"changes over {rate.size} packets: a measured rate, not a change of setting); the frames are "
        f"placed at the median declared rate, {nominal[0] / nominal[1]:g} fps"
    )


def _declared_rate(rows: np.ndarray) -> tuple[int, int]:
    """The frame rate a recording's sender declares: its first packet's (numerator, denominator)."""
    return int(rows["rate_numerator"][0]), int(ll.rate_denominator(int(rows["rate_denominator"][0])))


def _declared_period(rows: np.ndarray) -> float:
    """One frame period (s) at the rate a recording's sender declares."""
    num, den = _declared_rate(rows)
    return den / num


def _unwrap_midnight(frame_time: np.ndarray, rate: float) -> np.ndarray:
    """Frame times (arrival order, one rate) with the timecode's wraps at midnight undone. Where the clock
    falls back by one day (24 h of frames, or at an NTSC rate 24 h of timecode frames at its nominal
    rate; less the length of packets lost across midnight) it goes on from the next day: each packet is
    put on the day nearest the clock at its moment, so a late packet from before midnight stays on its
    day. Any other jump back stays a restart. A burst of packets from before midnight the network held
    back until after it (its last frames at most ``MAX_LATENESS_S`` late, its first later by its length)
    takes the clock back to the day before for as long as it lasts: its packets stay on their day, and the
    clock comes back to the next day after it."""
    if frame_time.size < 2 or np.ptp(frame_time) < DAY_S / 2:  # nowhere near both ends of a day
        return frame_time
    level = _running_median(frame_time, CLOCK_HALF_WINDOW)
    days = (DAY_S, DAY_S * round(rate) / rate)
    day = np.zeros(level.size - 1)
    on = back = 0  # midnights the clock went on past, and back to the day before of those (a held burst)
    jumps = np.flatnonzero(np.abs(np.diff(level)) > DAY_S / 2).tolist()
    falls = [float(level[j] - level[j + 1]) for j in jumps]
    for k, (j, fall) in enumerate(zip(jumps, falls)):
        # packets lost across midnight shorten the fall by as long as they lasted (up to a gap that splits
        # the take anyway); a held burst is as much less than a day back and forth as it is late, judged
        # by its last frames, with which the clock returns to the next day (its first are later by its
        # length)
        within = (MAX_GAP_S if fall > 0 and not back else MAX_LATENESS_S) + RESTART_WINDOW_S
        returns = fall < 0 and k + 1 < len(falls) and falls[k + 1] > 0
        measured = abs(falls[k + 1] if returns else fall)
        length = next((d for d in days if -RESTART_WINDOW_S <= d - measured <= within), None)
        if length is not None and fall > 0:
            day[j] = length
            on, back = (on, back - 1) if back else (on + 1, 0)
        elif length is not None and on > back:
            day[j] = -length
            back += 1
    if not day.any():
        return frame_time
    clock = level + np.concatenate([[0.0], np.cumsum(day)])
    length = float(day[day > 0][0])
    return frame_time + np.rint((clock - frame_time) / length) * length


def _frame_blocks(rows: np.ndarray) -> np.ndarray:
    """Each row's frame block (frame time, count, values) as one opaque value: equal for copies of one
    datagram."""
    raw = np.ascontiguousarray(rows).view(np.uint8).reshape(rows.size, ROW_DTYPE.itemsize)
    block = np.ascontiguousarray(raw[:, ROW_DTYPE.fields["frame_number"][1] :])
    return block.view(np.dtype((np.void, block.shape[1])))[:, 0]


def _rank_in_time(frame_time: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For frame times in order: each frame's place among the frames of its frame time (0 for the first)
    and how many share it."""
    n = frame_time.size
    new = np.concatenate([[True], frame_time[1:] != frame_time[:-1]])
    starts = np.flatnonzero(new)
    sizes = np.diff(np.append(starts, n))
    return np.arange(n) - np.repeat(starts, sizes), np.repeat(sizes, sizes)


def _first_copies(rows: np.ndarray, idx: np.ndarray, ft: np.ndarray) -> np.ndarray:
    """For frames ``rows[idx]`` with frame times ``ft``: the place of the first of them (in the order
    given) that carries the same frame block byte for byte, a datagram the network delivered more than
    once (its own place when it is no copy)."""
    order = np.argsort(ft, kind="stable")
    _, size = _rank_in_time(ft[order])
    shared = order[size > 1]
    first_of = np.arange(ft.size)
    if shared.size:
        _, first, group = np.unique(_frame_blocks(rows[idx[shared]]), return_index=True, return_inverse=True)
        first_of[shared] = shared[first[group]]
    return first_of


def _pace(frame_time: np.ndarray, arrival_s: np.ndarray) -> float | None:
    """How fast frames' frame time ran against their arrivals (1: real time), None when they arrived
    within ``MIN_PACE_S`` (sent all at once)."""
    took = float(arrival_s.max() - arrival_s.min())
    return float(frame_time[-1] - frame_time[0]) / took if took >= MIN_PACE_S else None


def _clock_steps(frame_time: np.ndarray, arrival_s: np.ndarray) -> list[int]:
    """Where (indices of frames in frame-time order) the phone's clock stepped forward: the frame time
    jumps by more than ``CLOCK_STEP_S`` further than the arrivals do across the jump, and more than twice
    as far; frames the network lost leave a gap in the arrivals too. Each side of the jump
    (``STEP_SIDE_S`` of frame time) gives when its frame next to the jump arrived, from its fastest
    packet at the sides' pace: measured at the jump, an error in the pace (Wi-Fi jitter) counts over a
    side's length, not over the whole gap."""
    steps = []
    for g in (np.flatnonzero(np.diff(frame_time) > CLOCK_STEP_S) + 1).tolist():
        lo = int(np.searchsorted(frame_time, frame_time[g - 1] - STEP_SIDE_S))
        hi = int(np.searchsorted(frame_time, frame_time[g] + STEP_SIDE_S, "right"))
        sides = (slice(lo, g), slice(g, hi))
        if g - lo < MIN_TAKE_FRAMES or hi - g < MIN_TAKE_FRAMES:
            continue
        before, after = (_pace(frame_time[side], arrival_s[side]) for side in sides)
        if not (before and after) or abs(before / after - 1) > PACE_TOLERANCE:
            continue
        speed = (before + after) / 2
        edge = (frame_time[g - 1], frame_time[g])  # each side's frame next to the jump
        arrived = [np.min(arrival_s[side] - (frame_time[side] - at) / speed) for side, at in zip(sides, edge)]
        jump, carried = edge[1] - edge[0], speed * (arrived[1] - arrived[0])
        # the arrivals must carry on far less than the frame time jumps: a side's pace is known only to
        # PACE_TOLERANCE (Wi-Fi jitter), which scales a lost stretch's arrival gap by as much
        if jump - carried > CLOCK_STEP_S and carried < jump / 2:
            steps.append(g)
    return steps


def _floors(behind: np.ndarray, width: int) -> tuple[np.ndarray, np.ndarray]:
    """At each packet ``i``, the least of ``behind`` over the ``width`` packets before it and over the
    ``width`` from it on (the fastest packet's, which late ones do not move); inf where there are none."""
    padded = np.concatenate([np.full(width, np.inf), behind, np.full(width, np.inf)])
    least = np.lib.stride_tricks.sliding_window_view(padded, width).min(axis=1)
    return least[: behind.size], least[width : width + behind.size]


def _side_floors(
    behind: np.ndarray, arrival_s: np.ndarray, at: np.ndarray, width: int
) -> tuple[np.ndarray, np.ndarray]:
    """As ``_floors`` at packets ``at`` (arrival order), each side ``width`` packets or ``STEP_SIDE_S`` of
    arrivals, whichever holds more: a burst the network held back comes within a moment, however many
    packets it holds, so the side of arrivals reaches the packets that came on time after it."""
    n = behind.size
    first = np.minimum(at - width, np.searchsorted(arrival_s, arrival_s[at] - STEP_SIDE_S))
    last = np.maximum(at + width, np.searchsorted(arrival_s, arrival_s[at] + STEP_SIDE_S, "right"))
    first, last = np.maximum(first, 0), np.minimum(last, n)
    return _range_min(behind, first, at), _range_min(behind, at, last)


def _range_min(values: np.ndarray, starts: np.ndarray, stops: np.ndarray) -> np.ndarray:
    """The least of ``values[a:b]`` for each ``a, b`` of ``starts, stops`` (inf where empty), from a table of
    the least of each run of 2**k values (each range the least of two runs that cover it): the time of a
    few passes over ``values``, however long and many the ranges (packets that all came at one moment
    make every side the whole session)."""
    out = np.full(starts.size, np.inf)
    length = stops - starts
    some = np.flatnonzero(length > 0)
    if not some.size:
        return out
    level = np.floor(np.log2(length[some])).astype(np.int64)
    runs = np.asarray(values, np.float64)
    for k in range(int(level.max()) + 1):
        if k:
            runs = np.minimum(runs[: -(1 << (k - 1))], runs[1 << (k - 1) :])  # runs of 2**k values
        mine = some[level == k]
        out[mine] = np.minimum(runs[starts[mine]], runs[stops[mine] - (1 << k)])
    return out


STEP_SIZE_SIDES = 5  # a step's size is measured over up to this many sides of arrivals each way
# from the packet of each side at this fraction of its packets from the fastest, at least the third (a few
# strays, stragglers or packets swapped on the way, early by a frame, are not it)
STEP_SIZE_RANK = 2
STEP_SIZE_FRACTION = 0.02


def _step_size(behind: np.ndarray, arrival_s: np.ndarray, marks: tuple[int, int, int, int]) -> float | None:
    """How far the phone's clock stepped back, from ``behind`` (arrival - frame time, arrival order) of the
    packets on each side of it (None when there are none after it): ``marks`` (the first packet it may use
    before, where it rose, where the side after may begin, the first packet of the next rise) bound up to
    ``STEP_SIZE_SIDES`` of ``STEP_SIDE_S`` of arrivals each way; the side after begins where it rose most,
    at least a side on (packets of the clock before the step that came late, less late than the step, are
    behind it). The lower envelope of each side, as many packets each, by its ``STEP_SIZE_RANK``-th fastest
    packet: over several sides the jitter moves it a fraction of what it moves the fastest packet of one,
    and the rise's most is where the jitter raised it most."""
    first, at, begin, stop = marks
    if begin >= stop:
        return None
    reach = STEP_SIZE_SIDES * STEP_SIDE_S
    before = behind[max(first, int(np.searchsorted(arrival_s, arrival_s[at] - reach))) : at]
    after = behind[begin : min(stop, int(np.searchsorted(arrival_s, arrival_s[begin] + reach, "right")))]
    size = min(before.size, after.size)
    if not size:
        return None
    rank = min(max(STEP_SIZE_RANK, int(STEP_SIZE_FRACTION * size)), size - 1)
    low = np.partition(before[before.size - size :], rank)[rank]
    return float(np.partition(after[:size], rank)[rank] - low)


def _run_through(frame_time: np.ndarray) -> float:
    """How much frame time packets (in any order) span, their first and last tenth left out (a late
    or stray packet among them does not widen it); of their arrivals, how long they took to come."""
    return float(np.quantile(frame_time, 0.9) - np.quantile(frame_time, 0.1))


def _typical_pace(frame_time: np.ndarray, arrival_s: np.ndarray) -> float:
    """How fast a recording's frame time runs against its arrivals (in arrival order; 1: real time, a
    replay at --speed k: k): the median over its ``STEP_SIDE_S`` stretches of arrivals (a burst the network
    held back comes within one, however long, as a step of the clock falls in one)."""
    # each packet's stretch, only those with packets (a grid over the span: one packet logged days late
    # would make it huge)
    stretch = np.floor((arrival_s - arrival_s[0]) / STEP_SIDE_S)
    cuts = np.flatnonzero(np.diff(stretch, prepend=-1.0))
    paces = [
        _run_through(frame_time[a:b]) / float(np.ptp(arrival_s[a:b]))
        for a, b in zip(cuts, [*cuts[1:], arrival_s.size])
        if b - a > 1 and arrival_s[b - 1] > arrival_s[a]
    ]
    return float(np.median(paces)) if paces else 1.0


def _burst(frame_time: np.ndarray, arrival_s: np.ndarray, pace: float) -> bool:
    """Whether packets came ``BURST_PACE`` times as fast as their recording's ``pace`` or more (a burst
    the network held back). Their arrivals' span, as their frame times', leaves out the first and last
    tenth: a packet held back less than the burst, delivered just before it, does not widen it."""
    return _run_through(frame_time) > BURST_PACE * pace * _run_through(arrival_s)


def _sent_in_order(frame_time: np.ndarray, arrival_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The frame times and arrivals of packets (arrival order) but those behind a frame that came before
    them: a burst the network held back comes after frames sent after it, and its own packets, coming at
    once, would make the packets around it look a burst too."""
    keep = frame_time >= np.maximum.accumulate(frame_time)
    return frame_time[keep], arrival_s[keep]


def _undo_steps_back(
    frame_time: np.ndarray, arrival_s: np.ndarray, period: float, copy: np.ndarray | None = None
) -> tuple[np.ndarray, list[tuple[float, float, float]]]:
    """A recording's frame times (arrival order) with the phone's clock's steps back undone: where it
    stepped back by less than a restart (an NTP or Tentacle Sync re-sync while the app keeps sending; never
    more than ``MAX_LATENESS_S``, past which the clock's jump back is a restart: a larger one within a
    recording is a burst the network held back long, or over midnight) the
    frames after the step are moved to where they arrived, by the step in whole frame periods, so that none
    overlaps a frame before it and the audio stays in sync. Returns the new frame times and per step (new
    frame time of the first frame after it, seconds moved, the phone's frame time there). ``copy``: which
    packets are copies of one that came before (``_first_copies``), on its slot with its values: no sign
    of a step of a few frames.

    A step is where ``arrival - frame time`` of the fastest packet over ``STEP_SIDE_S`` of frames after a
    packet exceeds that before it by more than ``BACK_STEP_S`` (late packets, Wi-Fi bursts do not move
    the fastest packet), and where the frame times after it start at least half as much below the latest
    before it, or (a step of a few frames) they land on slots of those before it (``_short_step``), or
    the network held back the frames on both sides of the step and released them together, those after
    it going back over the frame times of those before it (``_held_over_step``): a sender that paused
    with its clock, a slow replay or the network holding packets back for a while moves the arrivals but
    not the frame times back; and where the fastest packet over the
    ``STEP_SIDE_S`` after those is still as late (when the recording goes on that long): a stall the
    network flushed out of order moves both, but the arrivals for the flush only; and where the frames
    after it came at the recording's pace, not ``BURST_PACE`` times as fast: a burst the network held back,
    however long, came at once (unless the packets ``STEP_SIDE_S`` of arrivals later are still as late and
    come at the recording's pace, the burst's own packets among them left out (``_sent_in_order``): a Wi-Fi
    burst right after a step; a second burst held back tells nothing).
    Each side of a rise is also measured over ``STEP_SIDE_S`` of arrivals (``_side_floors``): a burst the
    network held back right after a step fills a side of packets. How far the clock stepped back is measured
    over several sides each way, from the rise before to the next (``_step_size``; the rise itself when
    a side has no packets).
    A packet is of the clock after the step when it arrived after it (next to it: half the step later than
    the fastest before it; a packet of the clock before it as late as that is taken for one after it),
    unless its frame time lies below where the clock after the step resumed (the start of the run of frame
    times its fastest packet is in), or it came in a burst with the frames after the step, before them:
    a frame of the clock before it that the network held back over the step keeps its frame time."""
    n = frame_time.size
    width = min(max(2 * MIN_TAKE_FRAMES, int(STEP_SIDE_S / period)), MAX_STEP_SIDE_PACKETS)
    if n < 2 * width:
        return frame_time, []
    copy = np.zeros(n, bool) if copy is None else copy
    behind = arrival_s - frame_time
    before, after = _floors(behind, width)
    rise = after - before
    moved = frame_time.copy()
    steps: list[tuple[float, float, float]] = []
    done = 0  # packets up to here are placed
    found = np.flatnonzero(rise > BACK_STEP_S)
    pace = None  # the recording's (``_typical_pace``), when a step needs it
    clusters = np.split(found, np.flatnonzero(np.diff(found) > 1) + 1) if found.size else []
    for c, cluster in enumerate(clusters):
        # the clock jumping back further than late frames lie behind it is a restart (``follow_clock``):
        # so large a rise within a recording is a burst the network held back long, or over midnight
        if rise[cluster].max() > MAX_LATENESS_S:
            continue
        # where it rose, each side also over STEP_SIDE_S of arrivals: a side of packets that a burst the
        # network held back fills (just after a step) says how late the burst came, not the clock
        low, high = _side_floors(behind, arrival_s, cluster, width)
        rise[cluster] = high - low
        step = float(rise[cluster].max())
        if step <= BACK_STEP_S:  # no rise left: a burst's lateness alone
            continue
        at = int(cluster[np.argmax(rise[cluster] > step / 2)])  # it rises there, it stays up a side long
        if at < width or at + width > n:  # a side the recording's ends cut short tells too little
            continue
        # the clock went back: the frame times after the step start below the latest before it (the
        # third latest and earliest, which a stray frame number cannot give), or, a step too short for
        # that, they go back over the slots of those before it (``_short_step``)
        latest = np.partition(frame_time[at - width : at], width - 3)[width - 3]
        held = None  # the frames before the step that the network held back with those after it
        sides = frame_time[at - width : at], frame_time[at : at + width]
        # a copy of a packet is on its slot with its values: no frame of a clock that went back
        sent_once = sides[1][~copy[at : at + width]]
        earliest = np.partition(sent_once, 2)[2] if sent_once.size > 2 else np.inf
        if latest - earliest < step / 2 and not _short_step(sides[0], sent_once, step, period):
            # unless the network held back the frames on both sides of the step and released them
            # together, in the order sent: the frames after it then go back over the frame times of
            # those before it (``_held_over_step``)
            held = _held_over_step(frame_time, arrival_s, max(at - width, done), at, step, period, copy)
            if held is None:
                continue
        # and the arrivals stay behind by the step a side further on (until the next step): a stall the
        # network flushed out of order rises for the flush only
        if at + 2 * width <= n and after[at + width] - before[at] < step / 2:
            continue
        # and the frames after it came at the recording's pace (a re-sync does not change it), not many
        # times as fast, or the arrivals stay behind by the step once those have come: a burst the
        # network held back comes all at once, however long it is (a Wi-Fi burst right after a step back
        # comes as fast, and the packets after it are as late)
        side = slice(at, at + width)
        pace = _typical_pace(frame_time, arrival_s) if pace is None else pace
        if _burst(frame_time[side], arrival_s[side], pace):
            # a second of arrivals on, a side of packets coming in the second after (not after a pause), at
            # the recording's pace (not another burst the network held back)
            on = int(np.searchsorted(arrival_s, arrival_s[at] + STEP_SIDE_S))
            if on + width > n or arrival_s[on + width - 1] > arrival_s[at] + 3 * STEP_SIDE_S:
                continue
            still_late = after[on] - before[at] >= step / 2
            next_side = slice(on, on + width)
            if not still_late or _burst(*_sent_in_order(frame_time[next_side], arrival_s[next_side]), pace):
                continue
        zone = slice(max(at - width, done), at + width)
        later = np.zeros(n, bool)
        later[zone] = behind[zone] - before[at] > step / 2
        later[zone.stop :] = True
        if held is not None:
            later[held] = False
        # the clock after the step runs on from where it resumed, the start of the run of frame times (at
        # most RUN_STEPS frame steps apart) of the frames placed after it that holds its fastest packet: a
        # frame below that is a late frame of the clock before it, however late the network delivered it
        # (a burst held back over the step). Those above its fastest packet tell nothing: not sorted (a
        # long recording's every step would sort the rest of it).
        fastest = frame_time[at + int(np.argmin(behind[side]))]
        times = np.sort(frame_time[later & (frame_time <= fastest)])
        if not times.size:  # its fastest packet was held back with the frames before it: no step to place
            continue
        reach = RUN_STEPS * (_frame_step(np.sort(frame_time[zone])) or period)
        breaks = np.flatnonzero(np.diff(times) > reach)
        resumed = times[breaks[-1] + 1 if breaks.size else 0]
        later &= frame_time >= resumed - period / 2
        top = int(cluster[np.argmax(rise[cluster])])
        since, ahead = _between_rises(clusters, c, width, n)
        size = _step_size(behind, arrival_s, (max(done, since), at, max(top, at + width), ahead))
        shift = round((step if size is None else size) / period) * period
        moved[later] += shift
        first = zone.start + int(np.argmax(later[zone]))
        steps.append((float(moved[first]), shift, float(frame_time[first])))
        done = zone.stop
    return moved, steps


def _between_rises(clusters: list[np.ndarray], c: int, width: int, n: int) -> tuple[int, int]:
    """Where the packets around rise ``c`` of ``clusters`` (packet indices, of ``n``) that tell its step's
    size begin and end: from the end of the rise before to the start of the next (a slower route, a
    burst, another step: their lateness is not this step's), passing over one within ``width`` packets of
    it (heavy jitter dips a rise below ``BACK_STEP_S`` a moment); 0 and ``n`` where there is none."""
    cluster = clusters[c]
    since = next(
        (int(clusters[j][-1]) for j in range(c - 1, -1, -1) if clusters[j][-1] < cluster[0] - width), 0
    )
    ahead = next((int(x[0]) for x in clusters[c + 1 :] if x[0] > cluster[-1] + width), n)
    return since, ahead


def _on_slots(times: np.ndarray, had: np.ndarray, period: float) -> int:
    """How many of frame times ``times`` land on the slot of one of frame times ``had`` (sorted, at least
    two): closer to it than ``SLOT_FRACTION`` of a frame ``period``."""
    right = np.clip(np.searchsorted(had, times), 1, had.size - 1)
    dist = np.minimum(np.abs(had[right] - times), np.abs(had[right - 1] - times))
    return int(np.count_nonzero(dist < SLOT_FRACTION * period))


def _short_step(before: np.ndarray, after: np.ndarray, step: float, period: float) -> bool:
    """Whether the frames of a side after a rise of the fastest packet's lateness by ``step`` (frame times
    ``after``, arrival order) went back over the slots of those of the side before it (``before``): at
    least 3 of them, and half the step's frames, and at least half of those not above the latest frame
    before, land on slots of those frames, as only a clock that stepped back gives (late or reordered
    frames fill free slots, a stray frame number or two are too few). A step too short for the sides'
    third frames to tell (``_undo_steps_back``)."""
    over = after[after <= before.max() + period / 2]
    if before.size < 2 or not over.size:
        return False
    taken = _on_slots(over, np.sort(before), period)
    return taken >= max(3, round(step / period) / 2) and 2 * taken >= over.size


def _held_over_step(
    frame_time: np.ndarray,
    arrival_s: np.ndarray,
    lo: int,
    at: int,
    step: float,
    period: float,
    copy: np.ndarray,
) -> np.ndarray | None:
    """Where the network held back the frames on both sides of a step back of the phone's clock (of
    ``step`` s, the fastest packet's lateness rising at packet ``at``) and released them together: the
    frames before the step that came with those after it (packets, arrival order), or None when no
    packet from ``lo`` to ``MAX_LATENESS_S`` of arrivals after ``at`` shows the step. A burst keeps the
    order its packets were sent in (``_sent_run``): where its frame times go back, the frames after that
    land on slots frames that came before have (closer than ``SLOT_FRACTION`` of a frame period), at least
    half of those of the step's length, as only a clock that stepped back gives (late or reordered frames
    fill free slots). The frames before the step are those of the burst that run up to a frame period
    below where the frames after it went back from. Packets ``copy`` (copies of one that came before, on
    its slot) count as none of the frames after the step."""
    hi = int(np.searchsorted(arrival_s, arrival_s[at] + MAX_LATENESS_S, "right"))
    ft = frame_time[lo:hi]
    reach = RUN_STEPS * period
    overlap = max(1, round(step / period))  # frames after the step on slots of frames before it
    for j in (lo + 1 + np.flatnonzero(ft[1:] < ft[:-1] - BACK_STEP_S)).tolist():
        t = frame_time[j]
        went = [j, *_sent_run(frame_time, arrival_s, j, hi, (t + period / 2, t + reach), period, overlap - 1)]
        after = frame_time[[k for k in went if not copy[k]]]  # copies of frames on their slots tell nothing
        if after.size < min(overlap, MIN_TAKE_FRAMES):
            continue
        # the frames before the step that came with them: from a frame period below where they went back
        top = t + step - period
        run = _sent_run(frame_time, arrival_s, j, lo - 1, (top - reach, top + reach), period, hi)
        held = np.array(run, np.int64)
        # and the frames that came before the step (frames before it held back alone fill free slots) and
        # before those that went back: not they themselves, nor those sent with them (a Wi-Fi burst that
        # came just before a rise of the arrivals, a sender ticking faster than its frame clock)
        earlier = int(np.searchsorted(arrival_s, arrival_s[at] - MAX_LATENESS_S))
        had = np.sort(np.concatenate([frame_time[earlier : min(at, j)], frame_time[held]]))
        if had.size >= 2 and 2 * _on_slots(after, had, period) >= after.size:
            return held
    return None


def _sent_run(
    frame_time: np.ndarray,
    arrival_s: np.ndarray,
    anchor: int,
    stop: int,
    want: tuple[float, float],
    period: float,
    most: int,
) -> list[int]:
    """The packets of a burst the network released together in the order they were sent, next to packet
    ``anchor`` towards ``stop`` (arrival order, either way): each less than a frame period over
    ``BURST_PACE`` from the one before (the anchor first), the first with a frame time within ``want``,
    each next a frame step or up to ``RUN_STEPS`` on from the one before (later in arrival order: up;
    earlier: down), past packets on time that came among them; at most ``most``."""
    way = 1 if stop > anchor else -1
    reach = RUN_STEPS * period
    run: list[int] = []
    for k in range(anchor + way, stop, way):
        if (
            len(run) >= most
            or abs(arrival_s[k] - arrival_s[run[-1] if run else anchor]) >= period / BURST_PACE
        ):
            break
        if want[0] <= frame_time[k] <= want[1]:
            run.append(k)
            t = frame_time[k]
            want = (t + period / 2, t + reach) if way > 0 else (t - reach, t - period / 2)
    return run


def _step_back_note(step: tuple[float, float, float], frame_time: np.ndarray) -> tuple[str, str]:
    """A take's note of a step back of the phone's clock (``_undo_steps_back``) within its frames."""
    at, shift, phone = step
    return (
        "clock_step_back",
        f"the phone's clock stepped back {shift:.2f} s at {at - frame_time[0]:.2f} s into the take "
        f"(its timecode went to {Timecode.from_seconds(phone).format()}) while packets kept coming (a "
        "clock re-sync): the frames after it are placed where they arrived, none dropped",
    )


def _returned_note(step: float, phone: float) -> tuple[str, str]:
    """A take's note of its start where the phone's clock stepped back into a gap its step forward left
    (``follow_clock``'s ``returned``)."""
    return (
        "clock_returned",
        f"the phone's clock stepped back {step:.1f} s at the start of the take (its timecode went to "
        f"{Timecode.from_seconds(phone).format()}), into the gap an earlier step forward of it left, while "
        "packets kept coming (a clock corrected twice, or a timecode source switched and back): no network "
        "holds packets back that long, so its frames are no late frames of the take before but a recording "
        "of their own (counted in restarts), placed where they arrived",
    )


def _fold(tally: np.ndarray, gone: np.ndarray, into: np.ndarray, count: str) -> None:
    """Add the tallies of the frames ``gone`` (dropped) to those of the frames ``into`` they are counted
    with, and one ``count`` for each."""
    np.add.at(tally, into, tally[gone])
    np.add.at(tally[:, TALLY.index(count)], into, 1)


def _time_ordered(
    rows: np.ndarray, idx: np.ndarray, ft: np.ndarray, tally: np.ndarray, report: dict[str, Any]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A recording's frames (``rows[idx]``, arrival order) in frame-time order, as indices into ``rows``
    (a recording's rows are not copied), with their ``tally`` rows (``TALLY``). Copies
    of one datagram (the frame block byte for byte) are ``duplicates``: the first arrival is kept. Frames
    that share a frame time with another frame but not its values (``same_time_frames``) are frames of a
    sender ticking faster than its frame clock when they are ``SHARED_TIME_FRACTION`` of the recording or
    more: spread evenly over the frame period in arrival order. A few are kept only first
    (``same_time_dropped``), never silently. A dropped frame's tally goes to the frame kept for it, so that
    the take holding that frame counts it."""
    order = np.argsort(ft, kind="stable")  # arrival order within a frame time
    idx, ft, tally = idx[order], ft[order], tally[order]
    rank, size = _rank_in_time(ft)
    if not rank.any():
        return idx, ft, tally
    kept = _first_copies(rows, idx, ft)  # the frame kept for each (itself when it is no copy)
    copy = np.flatnonzero(kept != np.arange(ft.size))
    _fold(tally, copy, kept[copy], "duplicates")
    report["duplicates"] += copy.size
    keep = np.ones(ft.size, bool)
    keep[copy] = False
    idx, ft, tally = idx[keep], ft[keep], tally[keep]
    rank, size = _rank_in_time(ft)
    same = np.flatnonzero(rank)
    tally[same, TALLY.index("same_time_frames")] += 1
    report["same_time_frames"] += same.size
    if same.size >= SHARED_TIME_FRACTION * ft.size:
        period = _declared_period(rows[idx[:1]])
        return idx, ft + rank / size * period, tally
    _fold(tally, same, same - rank[same], "same_time_dropped")  # counted with the first of its frame time
    report["same_time_dropped"] += same.size
    return idx[rank == 0], ft[rank == 0], tally[rank == 0]


class StreamTake(NamedTuple):
    """A take of a stream (``stream_takes``) before its frames are built: the stream's rows, the take's
    among them (frame-time order) with their frame times, and its own ``counts`` (``TAKE_COUNTS``).
    ``_segment_take`` makes its frames and ``finish_take`` gives it its span of the session's audio and the
    notes on its frame clock, just before it is written: one take's frames in memory at a time."""

    take_id: str
    rows: np.ndarray  # the stream's rows (``ROW_DTYPE``) as ``stream_takes`` read them
    index: np.ndarray  # the take's rows among them, in frame-time order
    frame_time: np.ndarray  # their phone frame times (s)
    counts: dict[str, int]
    placed_by_arrival: str | None = None  # why its frames are placed by arrival time
    notes: tuple[tuple[str, str], ...] = ()  # repairs (kind, message): a jittering rate, steps back


class BuiltTake(NamedTuple):
    """A take's frames (``_segment_take``) and where the session's audio lies on its time line."""

    take: Take
    clock_offset_s: float  # recorder clock minus phone frame time
    first_frame_s: float  # the phone's frame time of the take's first frame
    period: float  # the take's frame period (s)


def finish_take(built: BuiltTake, planned: StreamTake, log: SessionLog, audio: SessionAudio | None) -> None:
    """Give the take its span of the session's ``audio`` (``_attach_audio_span``), then the notes on its
    frame clock: its metadata as when the audio was attached as the take was built (its keys, its repairs
    in that order)."""
    take = built.take
    if audio is not None:
        first_s = float(log.seconds(audio.first_ns)) - built.clock_offset_s - built.first_frame_s  # sample 0
        _attach_audio_span(take, audio, first_s, built.period)
    if planned.placed_by_arrival is not None:
        take.meta.extra["frame_clock"] = {"placed_by": "arrival", "reason": planned.placed_by_arrival}
        message = f"frames placed by arrival time: {planned.placed_by_arrival}"
        repair(take.meta.repairs, None, "frame_clock", message)
    for kind, message in planned.notes:
        repair(take.meta.repairs, None, kind, message)


def stream_takes(log: SessionLog, sid: int, rows: np.ndarray | None = None) -> tuple[list[StreamTake], dict]:
    """The takes of one stream, and a report (packets, duplicates, out-of-order, restarts, rate changes,
    packets of a jittering rate, stray packets and frames, frames sharing a frame time, clock steps forward
    and back, face-lost frames outside the takes,
    frames with an implausible rate). ``rows``: the stream's rows when not
    the log's (a stream merged with its copies from another source, in arrival order). The takes have no
    frames yet (``_segment_take``, then ``finish_take``); each has its own ``TAKE_COUNTS`` of the
    report's: the packets of its frames, with the copies and the dropped frames of its frame times, and the
    steps back of the clock within it."""
    rows = log.stream_rows(sid) if rows is None else rows
    info = log.streams.get(sid, {})
    report: dict[str, Any] = {
        "packets": int(rows.size),
        "duplicates": 0,
        "out_of_order": 0,
        "restarts": 0,
        "rate_changes": 0,
        "stray_packets": 0,
        "same_time_frames": 0,
        "same_time_dropped": 0,
        "clock_steps": 0,
        "clock_steps_back": 0,
    }
    # Logs written before the recorder bounded the rate may hold any rate: such frames make no take.
    plausible = ll.plausible_rate(rows["rate_numerator"].astype(np.int64), rows["rate_denominator"])
    if not plausible.all():
        report["bad_rate_frames"] = int(np.count_nonzero(~plausible))
        rows = rows[plausible]
    num = rows["rate_numerator"].astype(np.int64)
    den = ll.rate_denominator(rows["rate_denominator"].astype(np.int64))
    order = _late_packets_placed(num, den)
    if order is not None:  # a late packet of the old setting among the new one's first: back with its own
        rows, num, den = rows[order], num[order], den[order]
    tally = np.zeros((rows.size, len(TALLY)), np.int32)  # per row: what it adds to its take's counts
    stretches = _rate_stretches(num, den)
    jitter_notes: dict[int, str] = {}  # stretch start -> its note
    for run, nominal in stretches:
        if nominal is not None:
            # A jittering declared rate: read the stretch at one rate (in a copy of the rows, not the log).
            if not jitter_notes:
                rows = rows.copy()
            jitter_notes[run.start] = _rate_jitter_note(num[run], den[run], nominal)
            report["rate_jitter_packets"] = report.get("rate_jitter_packets", 0) + run.stop - run.start
            num[run], den[run] = nominal
            rows["rate_numerator"][run], rows["rate_denominator"][run] = nominal
    frame_time = (rows["frame_number"].astype(np.float64) + rows["sub_frame"].astype(np.float64)) * den / num
    arrival = log.seconds(rows["arrival_ns"])
    # Recordings: (row indices in arrival order, their frame times, why placed by arrival or None, the
    # note of a jittering declared rate or None, the note of its start when the clock stepped back into a
    # gap of the recording before or None).
    recordings: list[tuple[np.ndarray, np.ndarray, str | None, str | None, tuple[str, str] | None]] = []
    problem = None
    stray = []
    report["rate_changes"] = len(stretches) - 1
    for run, _ in stretches:
        base = run.start
        note = jitter_notes.get(base)
        if run.stop > run.start:
            frame_time[run] = _unwrap_midnight(frame_time[run], float(num[base] / den[base]))
        clock = follow_clock(rows[run], frame_time[run], arrival[run])
        if clock.problem is not None:
            problem = clock.problem
            placed = arrival_clock(arrival[run], float(den[base] / num[base]))
            recordings.append((np.arange(run.start, run.stop), placed, problem, note, None))
            continue
        recordings += [
            (
                base + idx,
                frame_time[base + idx],
                None,
                note,
                _returned_note(*clock.returned[k]) if k in clock.returned else None,
            )
            for k, idx in enumerate(clock.recordings)
        ]
        stray.append(base + clock.stray)
    if problem is not None:
        report["frame_clock"] = {"placed_by": "arrival", "reason": problem}
    report["restarts"] = max(len(recordings) - 1, 0)
    stray_rows = np.concatenate(stray) if stray else np.zeros(0, np.int64)
    report["stray_packets"] = int(stray_rows.size)
    stray_faces = int(np.count_nonzero(rows["count"][stray_rows] != 0))
    # Per recording: duplicates dropped, frames put in frame-time order, cut where the phone's clock
    # stepped forward and into segments of the frames with a face; the no-face frames between a segment's
    # first and last face frame belong to it.
    # Segments: (row indices, frame times, why placed by arrival or None, notes for the take, its rows' tally,
    # steps back of the clock within it).
    segments: list[tuple[np.ndarray, np.ndarray, str | None, list[tuple[str, str]], np.ndarray, int]] = []
    face_lost = int(stray_rows.size) - stray_faces
    for idx, ft, placed_by_arrival, rate_note, start_note in recordings:
        backs: list[tuple[float, float, float]] = []
        if placed_by_arrival is None:  # frames after a small step back of the clock: where they arrived
            copy = _first_copies(rows, idx, ft) != np.arange(idx.size)
            ft, backs = _undo_steps_back(ft, arrival[idx], _declared_period(rows[idx[:1]]), copy)
            report["clock_steps_back"] += len(backs)
        prior_max = np.maximum.accumulate(ft)
        late = idx[1:][ft[1:] < prior_max[:-1]]
        tally[late, TALLY.index("out_of_order")] = 1
        report["out_of_order"] += late.size
        idx, ft, t = _time_ordered(rows, idx, ft, tally[idx], report)
        steps = [] if placed_by_arrival is not None else _clock_steps(ft, arrival[idx])
        report["clock_steps"] += len(steps)
        first_segment = len(segments)
        for part in np.split(np.arange(ft.size), steps):
            rp, fp, tp = idx[part], ft[part], t[part]
            face_rows = np.flatnonzero(rows["count"][rp] != 0)
            face_lost += int(rp.size - face_rows.size)
            for s in _segments(fp[face_rows]) if face_rows.size else []:
                seg = slice(int(face_rows[s][0]), int(face_rows[s][-1]) + 1)
                within = [back for back in backs if fp[seg][0] <= back[0] <= fp[seg][-1]]
                notes = [("rate_jitter", rate_note)] if rate_note else []
                if start_note and len(segments) == first_segment:  # where the clock stepped back to
                    notes.append(start_note)
                notes += [_step_back_note(back, fp[seg]) for back in within]
                segments.append((rp[seg], fp[seg], placed_by_arrival, notes, tp[seg], len(within)))
    takes: list[StreamTake] = []
    stray_frames, lost_in_takes = stray_faces, 0
    session = log.session.get("session", log.dir.name.removesuffix(SESSION_SUFFIX))
    base_id = f"{session}_{info.get('subject')}_{(info.get('device') or '')[:8]}"
    for k, (seg_rows, ft, placed_by_arrival, notes, t, backs_within) in enumerate(segments):
        n_lost = int(np.count_nonzero(rows["count"][seg_rows] == 0))
        if seg_rows.size - n_lost < MIN_TAKE_FRAMES:
            stray_frames += seg_rows.size - n_lost
            continue
        take_id = base_id + (f"_{k + 1}" if len(segments) > 1 else "")
        counts = dict(zip(TALLY, t.sum(axis=0).tolist(), strict=True))
        counts["packets"] = seg_rows.size + counts["duplicates"] + counts["same_time_dropped"]
        counts["clock_steps_back"] = backs_within
        if "rate_jitter_packets" in report:  # a recording's packets are all of one stretch of rates
            counts["rate_jitter_packets"] = counts["packets"] if "rate_jitter" in dict(notes) else 0
        takes.append(StreamTake(take_id, rows, seg_rows, ft, counts, placed_by_arrival, tuple(notes)))
        lost_in_takes += n_lost
    report["stray_frames"] = stray_frames
    report["face_lost_outside_takes"] = face_lost - lost_in_takes
    return takes, report


def _segment_take(
    log: SessionLog,
    info: dict[str, Any],
    take_id: str,
    r: np.ndarray,
    ft: np.ndarray,
) -> BuiltTake:
    """The frames of one segment's take: rows ``r`` (frame-time order) with phone frame times ``ft`` (its
    counts are its ``StreamTake``'s; its audio and the notes on its clock come with ``finish_take``)."""
    arr = log.seconds(r["arrival_ns"])
    lost = r["count"] == 0
    values = r["values"].astype(np.float32)
    finite = np.isfinite(values).all(axis=1)
    values[~np.isfinite(values)] = np.nan
    status = np.where(finite, FrameStatus.TRACKED, FrameStatus.BAD_VALUE).astype(np.uint8)
    status[lost] = FrameStatus.FACE_LOST
    finite |= lost  # NaN is what a face-lost frame holds, not a bad value
    t = ft - ft[0]
    # The declared rate (NTSC 30000/1001 named so) is the take's: frame numbers count its frames, so its
    # grid has a slot for every frame and a lost packet is a DROPPED frame. The frames' own rate (median
    # step) only wins when faster (a 60 Hz sender declaring 30: frames share a frame time, spread over
    # it), when the sender steadily sends every k-th frame number (rate / k), or when its frame times do
    # not fall on the declared grid (a sender declaring 60 that sends 24 frames/s with sub-frame times);
    # one slower otherwise (packets lost) gets a note.
    rate_num, rate_den = _declared_rate(r)
    fps, period = rate_num / rate_den, rate_den / rate_num
    measured, step = detect_fps(t)
    raw = np.diff(t) / period  # in declared frames
    steps = np.rint(raw)
    stride = int(np.median(steps)) if steps.size else 1
    on_grid = not steps.size or np.mean(np.abs(raw - steps) < 0.1) >= STEADY_STRIDE_FRACTION
    repairs = []
    if fps + 0.5 < measured <= MAX_FPS or not on_grid:
        fps, period = measured, step
    elif stride > 1 and np.mean(steps % stride == 0) >= STEADY_STRIDE_FRACTION:
        fps, period = fps / stride, period * stride
    elif measured < fps - 0.5:
        repairs.append(
            {
                "line": None,
                "kind": "rate_below_declared",
                "message": f"frames came at {measured:g} fps (median step) where the sender declares "
                f"{fps:g}: the take keeps the declared rate, the gaps are DROPPED frames",
            }
        )
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
    controls = info.get("controls")  # a stream of CONTROLS records: its subject's own controls
    if info.get("controls_unnamed"):
        repairs.append(
            {
                "line": None,
                "kind": "controls_unnamed",
                "message": f"the log lost the names of the stream's {len(controls)} controls: "
                "named control_0, control_1, ...",
            }
        )
    meta = TakeMeta(
        id=safe_id(take_id),
        source_kind="livelink_udp" if controls is None else info.get("source_kind", "livelink_realtime"),
        fps=fps,
        channels=list(ARKIT61) if controls is None else list(controls),
        subject=info.get("subject"),
        device=info.get("device"),
        start_timecode=Timecode.from_seconds(ft[0]).format(),
        timecode_rate=rate_num / rate_den,
        repairs=repairs,
        csv=({"count_name": "BlendShapeCount"} if controls is None else {})
        | {"start_seconds_of_day": float(ft[0] % 86400.0)},
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
    return BuiltTake(take, offset, float(ft[0]), period)


def _attach_audio_span(take: Take, audio: SessionAudio, first_s: float, period: float) -> None:
    """Give ``take`` the span of the session's ``audio`` (sample 0 at take time ``first_s``) from
    ``AUDIO_MARGIN_S`` plus a frame ``period`` (and less than ``AUDIO_SPAN_GRID_S``, to start on that grid)
    before its first frame to as long after its last frame's period, less where the audio begins or ends;
    ``start_s`` moves by the samples left out before it, so that each sample keeps its take time. Where
    the span and the audio do not meet, or the span holds samples a take cannot (NaN), the take is kept
    without audio and a repair says why. Its audio's place in the session's and the gaps it crosses
    (silence) go to ``meta.extra``."""
    rate, margin = audio.sample_rate, AUDIO_MARGIN_S + period
    steps = math.floor((float(take.time[0]) - margin - first_s) / AUDIO_SPAN_GRID_S)
    lo = max(0, math.floor(steps * AUDIO_SPAN_GRID_S * rate))  # exact: a Fraction
    hi = min(audio.frames, math.ceil((float(take.time[-1]) + period + margin - first_s) * rate))
    if hi <= lo:
        where = f"take time {first_s:.3f} s to {first_s + audio.frames / rate:.3f} s"
        message = f"the session's audio ({where}) does not reach this take: it has no audio"
        repair(take.meta.repairs, None, "audio_outside_take", message)
        return
    try:
        take.attach_audio(audio.span(lo, hi), first_s + lo / rate, "recorder_clock")
    except AudioLogChanged:  # the take fails, as when the log changes while it is copied: recover retries
        raise
    except (InputError, OSError, MemoryError) as exc:  # NaN samples, a log that cannot be read: the face
        # is kept without audio (the session's audio log keeps it)
        why = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
        message = f"the take's span of the session's audio is left out: {why}"
        repair(take.meta.repairs, None, "audio_left_out", message)
        return
    take.meta.extra["session_audio"] = {"first_sample": lo, "session_samples": audio.frames}
    gaps = audio.gaps_within(lo, hi)
    if gaps:
        take.meta.extra["audio_gaps"] = gaps


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


def _source(info: dict[str, Any]) -> str:
    """A stream's sender as HOST:PORT (``[IPV6]:PORT``), from its STREAM record."""
    host, port = str(info.get("source")), info.get("port")
    host = f"[{host}]" if ":" in host else host
    return host if port is None else f"{host}:{port}"


def _interleaved(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two streams' packets (rows) came at the same time: each has at least ``MIN_TAKE_FRAMES``
    packets within the other's arrival span (a few stragglers of a sender that stopped are not enough)."""
    ta, tb = a["arrival_ns"], b["arrival_ns"]
    inside_b = np.count_nonzero((ta >= tb.min()) & (ta <= tb.max()))
    inside_a = np.count_nonzero((tb >= ta.min()) & (tb <= ta.max()))
    return min(inside_a, inside_b) >= MIN_TAKE_FRAMES


def _same_sender(log: SessionLog, sid: int, chain: list[int]) -> bool:
    """Whether stream ``sid`` goes on with the streams ``chain`` (one sender): it did not send at the same
    time as them, or sent mostly copies of their frames."""
    rows = log.stream_rows(sid)
    if not any(_interleaved(rows, log.stream_rows(m)) for m in chain):
        return True
    theirs = np.concatenate([_frame_blocks(log.stream_rows(m)) for m in chain])
    return 2 * np.count_nonzero(np.isin(_frame_blocks(rows), theirs)) > rows.size


def _streams_by_sender(log: SessionLog) -> tuple[dict[int, list[int]], dict[int, list[str]]]:
    """The streams takes are built from. The recorder logs each other source of a stream's device id and
    subject as a stream of its own (``alongside`` in its STREAM record). Such a stream joins the stream
    (in arrival order) unless it sent at the same time (``_interleaved``) and not mostly copies of its
    frames: a sender restarted on another port, or the app sending to this computer twice (a socket per
    Live Link target) is one stream; a second sender with the same names is a stream of its own. Returns
    the log's streams each built stream is made of (by its first stream id) and, for names two senders
    shared, every sender's address (HOST:PORT)."""
    groups: dict[int, list[int]] = {}
    for sid in log.stream_ids():
        first = log.streams.get(sid, {}).get("alongside")
        known = isinstance(first, int) and first in log.frame_counts
        groups.setdefault(first if known else sid, []).append(sid)
    members: dict[int, list[int]] = {}
    senders: dict[int, list[str]] = {}
    for group in groups.values():
        chains: list[list[int]] = []
        for sid in group:
            joins = next((chain for chain in chains if _same_sender(log, sid, chain)), None)
            if joins is None:
                chains.append([sid])
            else:
                joins.append(sid)
        members |= {chain[0]: sorted(chain) for chain in chains}
        if len(chains) > 1:
            addresses = [_source(log.streams.get(chain[0], {})) for chain in chains]
            senders |= {chain[0]: addresses for chain in chains}
    return dict(sorted(members.items())), senders


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
    datagram counts by reason), its stream's report with the take's own ``TAKE_COUNTS`` (the stream's
    totals of those in ``stream_counts``; ``packets_outside_takes``: the stream's packets in none of its
    takes), and the take's ``info``
    figures (its frames built and its audio, its own span of the session's, copied from the log a block at
    a time, just before the take is written) with
    ``audio_gaps``, the stretches of silence where the audio log lost chunks, counted in the take's audio
    (the session's with no take). With no take, one summary with ``device``/``subject`` None still
    reports the counts. Each take is built and written on its own:
    one that fails (memory, a full disk) adds a summary with ``path`` None and a one-line ``error``,
    and the others are still written. Marks the session complete afterwards unless a take failed.
    Take folder names are unique in the session (``-2``, ``-3``... when two streams' names collide).
    """
    session_dir = Path(session_dir)
    log = SessionLog(session_dir)
    try:  # the rows it spilled are removed whatever stops the build
        audio, audio_report = index_audio_log(session_dir / AUDIO_LOG)
        common: dict[str, Any] = {
            "session": log.session.get("session", session_dir.name),
            "rejected": dict(log.rejected),
            "datagrams": (log.end or {}).get("datagrams"),
            "accepted": (log.end or {}).get("accepted"),
            "clean_end": log.end is not None,
            "recovered": recovered,
            "sync_events": len(log.sync),
        }
        drops = (log.end or {}).get("receive_queue_drops")
        if is_count(drops) and drops:
            # Datagrams the system dropped before the recorder read them: never logged, counted at its stop (a
            # value of another type is ignored, not the END record: its counts still hold).
            common["receive_queue_drops"] = drops
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
        # (an audio source's failure is noted in both logs: said once)
        errors = list(
            dict.fromkeys(
                n.get("message")
                for n in audio_report.get("notes", []) + log.notes
                if n.get("kind", "").endswith("error")
            )
        )
        if errors:
            common["errors"] = errors
        summaries: list[dict[str, Any]] = []
        failed: list[dict[str, Any]] = []
        stray_streams = stray_frames = 0
        used: set[str] = set()  # take folder names of this session, case-folded
        members, senders = _streams_by_sender(log)
        for sid, member in members.items():
            info = log.streams.get(sid, {})
            who = {"device": info.get("device"), "subject": info.get("subject")}
            try:
                rows = None
                if len(member) > 1:  # one sender from several sources, in arrival order
                    rows = np.concatenate([log.stream_rows(m) for m in member])
                    rows = rows[np.argsort(rows["arrival_ns"], kind="stable")]
                takes, report = stream_takes(log, sid, rows)
            except (MemoryError, ValueError, OverflowError, OSError, S2AError) as exc:
                message = f"the takes of stream {sid} could not be built: {type(exc).__name__}: {exc}"
                failed.append(who | {"error": message})
                continue
            if sid in senders:
                report["senders"] = senders[sid]
            # the stream's totals of the counts each take has its own of
            totals = {"stream_counts": {k: report[k] for k in TAKE_COUNTS if k in report}}
            # what the user sees of the packets in no take (stray, no face outside the takes, too few)
            outside = {"packets_outside_takes": report["packets"] - sum(p.counts["packets"] for p in takes)}
            for planned in takes:
                try:  # its frames built now: one take's in memory at a time
                    built = _segment_take(
                        log, info, planned.take_id, planned.rows[planned.index], planned.frame_time
                    )
                except (MemoryError, ValueError, OverflowError, S2AError) as exc:  # one take, not the session
                    message = (
                        f"take {safe_id(planned.take_id)} could not be built: {type(exc).__name__}: {exc}"
                    )
                    failed.append(who | {"error": message})
                    continue
                take = built.take
                take.meta.id = _unique_id(take.meta.id, used)
                counts = report | planned.counts
                try:
                    # its audio now (copied from the log a block at a time), its metadata in the old order
                    finish_take(built, planned, log, audio)
                    take.meta.extra["rejected"] = dict(log.rejected)
                    take.meta.extra["recovered"] = recovered
                    take.meta.extra |= {k: counts[k] for k in REPORTED if k in counts} | totals
                    if log.torn_tail is not None:
                        take.meta.extra["torn_tail"] = log.torn_tail.to_json()
                    if log.damage:
                        take.meta.extra["log_damage"] = common["log_damage"]
                    folder = write_take(take, out_dir)
                except (OSError, S2AError) as exc:  # a full disk, a read-only folder: this take only
                    where = Path(out_dir) / take.meta.id
                    message = f"{where}: cannot write the take: {getattr(exc, 'strerror', None) or exc}"
                    failed.append(who | {"error": str(exc) if isinstance(exc, S2AError) else message})
                    continue
                finally:
                    take.audio = None  # its span of the session's audio is not held past its writing
                gaps = len(take.meta.extra.get("audio_gaps", []))  # the gaps of the take's own audio
                summaries.append(
                    take.summary()
                    | common
                    | counts  # the stream's report with the take's own counts
                    | totals
                    | outside
                    | {"device": take.meta.device, "subject": take.meta.subject, "path": str(folder)}
                    | ({"audio_gaps": gaps} if gaps else {})
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
        if audio_report["gaps"]:
            summaries[0]["audio_gaps"] = len(audio_report["gaps"])
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
                strict_names({"takes": [s.get("path") for s in summaries], "recovered": recovered}),
            )
        except OSError as exc:
            message = f"{session_dir}: cannot mark the session complete: {exc.strerror or exc}"
            summaries.append(
                summaries[-1] | {"device": None, "subject": None, "path": None, "error": message}
            )
    return summaries
