"""The take container: one folder per take, metadata as JSON, frames as arrays, the audio beside them.

```
<take id>/
  meta.json     TakeMeta (format "s2a-take", schema_version)
  frames.npz    time (float64, s), values (float32, frames x channels), frame_status (uint8)[, neutral]
                [, arrival_s (float64, s on the recorder's monotonic clock, NaN where no packet; live takes)]
  audio.wav     the take's audio at its recorded rate and sample format (optional)
```

Folders are written under a temporary name and renamed into place, so a reader never sees half a
take. See docs/take-format.md for the full description.
"""

from __future__ import annotations

import copy
import hashlib
import json
import os
import tokenize
import unicodedata
from collections import Counter
from collections.abc import Iterable
from dataclasses import asdict, dataclass, field, fields, replace
from enum import IntEnum
from pathlib import Path
from typing import Any

import numpy as np

from .atomic import folder_in_place, write_json_atomic
from .audio_io import Audio, FileAudio, read_audio, write_audio
from .errors import InputError, loads_names, strict_names
from .npz import NPZ_ERRORS, npz_array, npz_headers, open_npz
from .numbers import is_finite_number, number_array
from .transfer_litter import litter_kind

FORMAT = "s2a-take"
SCHEMA_VERSION = 1
META_FILE = "meta.json"
FRAMES_FILE = "frames.npz"
FRAMES_ARRAYS = ("time", "values", "frame_status", "neutral", "arrival_s")  # what write_take stores
AUDIO_FILE = "audio.wav"
MAX_FPS = 1000.0  # the highest frame rate a take may declare (the app records 30 or 60)


class FrameStatus(IntEnum):
    """Why a frame is or is not usable. Only ``TRACKED`` frames are valid."""

    TRACKED = 0
    FACE_LOST = 1  # the app saw no face: values are NaN
    DROPPED = 2  # no row/packet arrived for this slot of the frame grid: values are NaN
    BAD_VALUE = 3  # the row held a non-numeric or non-finite value (repaired to NaN, see meta.repairs)
    INTERPOLATED = 4  # aligned takes: filled by interpolation across a short gap (usable, but not measured)


@dataclass
class AudioInfo:
    """Where a take's audio is and how it sits on the take's clock."""

    file: str
    sample_rate: int
    channels: int
    samples: int
    subtype: str
    start_s: float = 0.0  # take time (s) of the first audio sample; frame times share this clock
    start_source: str = "assumed"  # what start_s comes from: frame_log_audio, frame_log_video, ...


@dataclass
class SourceFile:
    """A file the take was made from, with its checksum so provenance can be checked later."""

    path: str
    role: str
    sha256: str
    bytes: int


@dataclass
class TakeMeta:
    """Everything about a take but its arrays. Times are seconds on the take clock."""

    id: str
    source_kind: str
    fps: float
    channels: list[str]
    slate: str | None = None
    take_number: int | None = None
    subject: str | None = None
    device: str | None = None
    start_timecode: str | None = None  # timecode of take time 0, HH:MM:SS:FF.fff
    timecode_rate: float | None = None
    audio: AudioInfo | None = None
    sources: list[SourceFile] = field(default_factory=list)
    repairs: list[dict[str, Any]] = field(default_factory=list)
    csv: dict[str, Any] = field(default_factory=dict)  # details needed to write the CSV back
    extra: dict[str, Any] = field(default_factory=dict)
    schema_version: int = SCHEMA_VERSION
    format: str = FORMAT

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, data: dict[str, Any], path: Path | None = None) -> TakeMeta:
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise InputError(f'not a take\'s metadata (expected "format": "{FORMAT}")', path)
        version = data.get("schema_version")
        if version != SCHEMA_VERSION:
            raise InputError(
                f"take schema version {version!r}; this toolkit reads version {SCHEMA_VERSION}", path
            )
        known = {f.name for f in fields(cls)}
        missing = [n for n in ("id", "source_kind", "fps", "channels") if n not in data]
        if missing:
            raise InputError(f"metadata lacks field(s) {', '.join(missing)}", path)
        fps = data["fps"]
        if not isinstance(fps, (int, float)) or isinstance(fps, bool) or not 0 < fps <= MAX_FPS:
            raise InputError(f"fps must be a frame rate between 0 and {MAX_FPS:g}, not {fps!r:.40}", path)
        check_meta_fields(data, path)
        kwargs = {k: v for k, v in data.items() if k in known}
        try:
            if kwargs.get("audio") is not None:
                kwargs["audio"] = AudioInfo(**kwargs["audio"])
            kwargs["sources"] = [SourceFile(**s) for s in kwargs.get("sources", [])]
            return cls(**kwargs)
        except TypeError as exc:
            raise InputError(f"malformed metadata: {exc}", path) from None


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_text(v: Any) -> bool:
    return isinstance(v, str) and v.strip() != ""


def _is_file_name(v: Any) -> bool:
    """A plain file name inside the take folder (no folder part: the audio never lies elsewhere)."""
    return _is_text(v) and "/" not in v and "\\" not in v and v not in (".", "..")


# What each meta.json field must hold (docs/take-format.md): (field, test, what the test asks for).
# ``None`` passes for the optional fields (those whose default is None or empty).
_META_FIELDS: tuple[tuple[str, Any, str], ...] = (
    ("id", _is_text, "non-empty text"),
    ("source_kind", _is_text, "non-empty text"),
    ("slate", lambda v: v is None or isinstance(v, str), "text or null"),
    ("take_number", lambda v: v is None or _is_int(v), "a whole number or null"),
    ("subject", lambda v: v is None or isinstance(v, str), "text or null"),
    ("device", lambda v: v is None or isinstance(v, str), "text or null"),
    ("start_timecode", lambda v: v is None or isinstance(v, str), "text or null"),
    ("timecode_rate", lambda v: v is None or (is_finite_number(v) and v > 0), "a positive number or null"),
    ("repairs", lambda v: isinstance(v, list) and all(isinstance(r, dict) for r in v), "a list of objects"),
    ("csv", lambda v: isinstance(v, dict), "an object"),
    ("extra", lambda v: isinstance(v, dict), "an object"),
)
_AUDIO_FIELDS: tuple[tuple[str, Any, str], ...] = (
    ("file", _is_file_name, "a file name in the take folder"),
    ("sample_rate", lambda v: _is_int(v) and v > 0, "a positive whole number (Hz)"),
    ("channels", lambda v: _is_int(v) and v >= 1, "a whole number of at least 1"),
    ("samples", lambda v: _is_int(v) and v >= 1, "a positive whole number"),
    ("subtype", _is_text, "text (PCM_16, PCM_24, PCM_32, FLOAT)"),
    ("start_s", is_finite_number, "a finite number of seconds"),
    ("start_source", lambda v: isinstance(v, str), "text"),
)
_SOURCE_FIELDS: tuple[tuple[str, Any, str], ...] = (
    ("path", lambda v: isinstance(v, str), "text"),
    ("role", lambda v: isinstance(v, str), "text"),
    ("sha256", lambda v: isinstance(v, str), "text"),
    ("bytes", lambda v: _is_int(v) and v >= 0, "a whole number"),
)


def _check_object(data: dict[str, Any], checks, prefix: str, path: Path | None) -> None:
    for name, test, what in checks:
        if name in data and not test(data[name]):
            value = data[name]
            raise InputError(f"malformed metadata: {prefix}{name} must be {what}, not {value!r:.60}", path)


def check_meta_fields(data: dict[str, Any], path: Path | None = None) -> None:
    """Refuse a meta.json field of the wrong type or range with a one-line ``InputError`` naming it
    (``fps`` is checked by ``TakeMeta.from_json``; fields left out take their defaults)."""
    _check_object(data, _META_FIELDS, "", path)
    channels = data.get("channels")
    if not isinstance(channels, list):
        raise InputError(f"malformed metadata: channels must be a list of names, not {channels!r:.60}", path)
    for i, name in enumerate(channels):
        if not _is_text(name):
            what = f"channels[{i}] must be a non-empty name, not {name!r:.60}"
            raise InputError(f"malformed metadata: {what}", path)
    counts = Counter(c.lower() for c in channels)
    twice = sorted(c for c in channels if counts[c.lower()] > 1)
    if twice:  # channels are looked up case-insensitively: a second jawOpen/JAWOPEN is ambiguous
        names = ", ".join(twice)[:80]
        raise InputError(
            f"malformed metadata: channels name one channel twice ({names}; case is ignored)", path
        )
    audio = data.get("audio")
    if audio is not None:
        if not isinstance(audio, dict):
            raise InputError(f"malformed metadata: audio must be an object or null, not {audio!r:.60}", path)
        _check_object(audio, _AUDIO_FIELDS, "audio.", path)
    sources = data.get("sources", [])
    if not isinstance(sources, list) or not all(isinstance(s, dict) for s in sources):
        raise InputError(f"malformed metadata: sources must be a list of objects, not {sources!r:.60}", path)
    for i, source in enumerate(sources):
        _check_object(source, _SOURCE_FIELDS, f"sources[{i}].", path)


def _numbers(take_id: str, name: str, data: Any, dtype: Any) -> np.ndarray:
    """``data`` as an array of ``dtype``: numbers only (integers or floats, as ``read_take`` accepts:
    never text such as "0.5", bools or objects), and no finite value that the conversion would make
    infinite (beyond float32's range)."""
    raw = number_array(data, f"take {take_id}: {name}")
    with np.errstate(over="ignore"):
        out = np.asarray(raw, dtype=dtype)
    if raw.dtype.kind == "f" and raw.dtype.itemsize > out.dtype.itemsize:
        beyond = np.isinf(out) & np.isfinite(raw)
        if beyond.any():
            first = float(raw[beyond].flat[0])
            raise InputError(
                f"take {take_id}: {name} holds {int(beyond.sum())} value(s) beyond the range of {out.dtype} "
                f"(e.g. {first:.3g})"
            )
    return out


def _status_codes(take_id: str, data: Any) -> np.ndarray:
    """``frame_status`` as uint8 codes: an array holding only ``FrameStatus`` codes. A code such as 7,
    -1 or 256 (that uint8 would wrap), a bool array (True is no code) and a float array holding anything
    but whole codes (0.5, NaN: ``np.zeros(n)`` is fine) are an ``InputError``."""
    try:
        raw = np.asarray(data)
    except (ValueError, TypeError) as exc:
        raise InputError(f"take {take_id}: frame_status is not an array of codes ({exc})") from None
    if raw.dtype.kind == "f" and raw.size:
        whole = np.isfinite(raw) & (raw == np.round(raw))
        if not whole.all():
            bad = raw[~whole][:5].tolist()
            raise InputError(f"take {take_id}: frame_status holds {bad}, not integer codes (FrameStatus)")
    elif raw.dtype.kind not in "iu" and raw.size:
        raise InputError(f"take {take_id}: frame_status is {raw.dtype}, not integer codes (FrameStatus)")
    unknown = np.setdiff1d(raw, [int(s) for s in FrameStatus]) if raw.size else raw
    if unknown.size:
        raise InputError(
            f"take {take_id}: frame_status holds unknown value(s) {unknown[:5].tolist()} "
            f"(known: {', '.join(f'{int(s)} {s.name}' for s in FrameStatus)})"
        )
    return raw.astype(np.uint8)


def check_take_audio(take_id: str, audio: Any) -> None:
    """A take's audio as ``read_take`` accepts it: an ``Audio`` of at least one sample, none of them NaN
    or infinite; else an ``InputError``."""
    if not isinstance(audio, Audio):
        raise InputError(f"take {take_id}: audio must be a capture.Audio, not {type(audio).__name__}")
    if audio.frames < 1 or audio.channels < 1:
        raise InputError(f"take {take_id}: audio holds no samples")
    if isinstance(audio, FileAudio) and not audio.held:
        return  # left in its file: checked a block at a time as it was read, NaN read as 0 (read_audio)
    if audio.samples.dtype.kind == "f":
        bad = _non_finite(audio.samples)
        if bad:
            raise InputError(f"take {take_id}: audio holds {bad} NaN or infinite sample(s)")


_CHECK_FRAMES = 1 << 16  # frames of audio checked at a time


def _non_finite(samples: np.ndarray) -> int:
    """How many of the float ``samples`` are NaN or infinite, ``_CHECK_FRAMES`` frames at a time: the
    boolean mask of all of them took 58 MB on an hour of 16 kHz audio (each segment align writes)."""
    bad = 0
    for lo in range(0, samples.shape[0], _CHECK_FRAMES):
        block = samples[lo : lo + _CHECK_FRAMES]
        if not np.isfinite(block).all():
            bad += int(np.count_nonzero(~np.isfinite(block)))
    return bad


@dataclass
class Take:
    """One recorded (or simulated) take: frames on the take clock plus optional audio.

    ``time`` is float64 seconds (strictly increasing), ``values`` float32 (frames x channels, never
    clamped; NaN where a frame has no data), ``frame_status`` uint8 ``FrameStatus`` codes.
    ``neutral`` is the calibrated rest pose (channels,) when the app recorded one.
    ``arrival_s`` (frames,) float64 is, for live-recorded takes, when each frame's packet arrived in
    seconds on the recorder's monotonic session clock (NaN for frames no packet arrived for).
    """

    meta: TakeMeta
    time: np.ndarray
    values: np.ndarray
    frame_status: np.ndarray
    audio: Audio | None = None
    neutral: np.ndarray | None = None
    arrival_s: np.ndarray | None = None

    def __post_init__(self) -> None:
        # the checks read_take applies to a take folder, so that write_take never writes what it refuses
        tid = self.meta.id
        self.time = _numbers(tid, "time", self.time, np.float64)
        self.values = _numbers(tid, "values", self.values, np.float32)  # row- or column-major, both fine
        self.frame_status = _status_codes(tid, self.frame_status)
        n = self.time.shape[0] if self.time.ndim else 0
        if self.time.ndim != 1 or self.values.shape != (n, len(self.meta.channels)):
            raise InputError(
                f"take {tid}: values {self.values.shape} do not match "
                f"{n} frames x {len(self.meta.channels)} channels"
            )
        if not np.all(np.isfinite(self.time)):
            raise InputError(f"take {tid}: frame times hold NaN or infinite values")
        if self.frame_status.shape != (n,):
            raise InputError(f"take {tid}: frame_status has the wrong length")
        if n > 1 and not np.all(np.diff(self.time) > 0):
            raise InputError(f"take {tid}: frame times are not strictly increasing")
        if self.neutral is not None:
            self.neutral = _numbers(tid, "neutral", self.neutral, np.float32)
            if self.neutral.shape != (len(self.meta.channels),):
                raise InputError(f"take {tid}: neutral has the wrong length")
        if self.arrival_s is not None:
            self.arrival_s = np.ascontiguousarray(_numbers(tid, "arrival_s", self.arrival_s, np.float64))
            if self.arrival_s.shape != (n,):
                raise InputError(f"take {tid}: arrival_s has the wrong length")
        if self.audio is not None:
            check_take_audio(tid, self.audio)

    def attach_audio(self, audio: Audio, start_s: float = 0.0, start_source: str = "assumed") -> None:
        """Give the take its audio; ``start_s`` is the take time of the first sample. ``meta.audio``
        names the file ``write_take`` writes it to. Audio without a sample or holding NaN or infinite
        samples is an ``InputError`` (``check_take_audio``)."""
        check_take_audio(self.meta.id, audio)
        self.audio = audio
        self.meta.audio = AudioInfo(
            AUDIO_FILE, audio.sample_rate, audio.channels, audio.frames, audio.subtype, start_s, start_source
        )

    @property
    def valid(self) -> np.ndarray:
        """Per-frame mask: True where the frame was tracked and every value is usable."""
        return self.frame_status == FrameStatus.TRACKED

    @property
    def duration_s(self) -> float:
        """Span of the frames in seconds, counting the last frame's own period."""
        if self.time.size == 0:
            return 0.0
        return float(self.time[-1] - self.time[0]) + 1.0 / self.meta.fps

    def channel_index(self, name: str) -> int:
        """Column of a channel, case-insensitive."""
        lowered = [c.lower() for c in self.meta.channels]
        try:
            return lowered.index(name.strip().lower())
        except ValueError:
            raise InputError(f"take {self.meta.id} has no channel {name!r}") from None

    def channel(self, name: str) -> np.ndarray:
        """Values of one channel over all frames."""
        return self.values[:, self.channel_index(name)]

    def count(self, status: FrameStatus) -> int:
        return int(np.count_nonzero(self.frame_status == status))

    def summary(self) -> dict[str, Any]:
        """What ``s2a-capture info`` reports (times in seconds)."""
        m = self.meta
        out: dict[str, Any] = {
            "id": m.id,
            "source_kind": m.source_kind,
            "frames": int(self.time.size),
            "fps": m.fps,
            "duration_s": round(self.duration_s, 6),
            "valid_frames": int(self.valid.sum()),
            "dropped_frames": self.count(FrameStatus.DROPPED),
            "face_lost_frames": self.count(FrameStatus.FACE_LOST),
            "bad_value_frames": self.count(FrameStatus.BAD_VALUE),
            "channels": len(m.channels),
            "start_timecode": m.start_timecode,
            "slate": m.slate,
            "take_number": m.take_number,
            "subject": m.subject,
            "audio_sample_rate": m.audio.sample_rate if m.audio else None,
            "audio_duration_s": round(m.audio.samples / m.audio.sample_rate, 6) if m.audio else None,
            "audio_start_s": m.audio.start_s if m.audio else None,
            "repairs": len(m.repairs),
        }
        return out


def sha256_file(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def source_file(path: str | Path, role: str) -> SourceFile:
    """Provenance record of an input file: absolute path, role, sha256 and size."""
    p = Path(path)
    return SourceFile(str(p.resolve()), role, sha256_file(p), p.stat().st_size)


MAX_ID_BYTES = 120  # folder names are limited to 255 bytes; temporary names add a prefix and suffix


# Names Windows keeps for devices, with any extension (``AUX.seg01`` too), in any case.
WINDOWS_DEVICES = {"CON", "PRN", "AUX", "NUL"} | {f"{d}{i}" for d in ("COM", "LPT") for i in range(1, 10)}


def safe_id(text: str) -> str:
    """A take id usable as a folder name on every platform: letters, digits, ``-_.``, at most
    ``MAX_ID_BYTES`` bytes of UTF-8 (a longer id is cut and ends in a hash of the whole, so that two
    long ids stay apart). Unicode in its composed form (NFC: macOS names files decomposed, and
    ``Café`` must be one id however it came); never starting with ``-`` (a command-line option) or
    ``.`` (hidden), never a Windows device name (``AUX``, ``com1``: ``AUX_``)."""
    text = unicodedata.normalize("NFC", text)
    keep = "".join(c if c.isalnum() or c in "-_." else "_" for c in text.strip())
    keep = keep.lstrip("-.").rstrip(".") or "take"
    if keep.split(".")[0].upper() in WINDOWS_DEVICES:
        head, dot, rest = keep.partition(".")
        keep = f"{head}_{dot}{rest}"
    if len(keep.encode()) <= MAX_ID_BYTES:
        return keep
    digest = hashlib.sha256(text.encode("utf-8", "surrogatepass")).hexdigest()[:12]
    cut = keep.encode()[: MAX_ID_BYTES - len(digest) - 1].decode("utf-8", "ignore")
    return f"{cut}-{digest}"


def make_out_dir(out_dir: str | Path) -> Path:
    """The output folder ``out_dir``, created with its parents if missing; an ``InputError`` when it
    is a file or cannot be created."""
    out_dir = Path(out_dir)
    if out_dir.is_symlink() and not out_dir.exists():
        raise InputError(
            f"cannot create the output's folder: a symbolic link to {os.readlink(out_dir)}, which does not "
            "exist, is in the way",
            out_dir,
        )
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(
            "cannot create the output's folder: the output folder is a file, not a folder", out_dir
        )
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create the output's folder ({exc.strerror or exc})", out_dir) from None
    return out_dir


def write_take(take: Take, out_dir: str | Path, overwrite: bool = True) -> Path:
    """Write ``take`` as ``out_dir/<id>/`` atomically; returns the folder.

    The folder is assembled under a hidden temporary name in ``out_dir`` and renamed into place.
    Metadata holding NaN or infinity (not JSON), fields or a frame rate ``read_meta`` would refuse, arrays
    or audio ``read_take`` would refuse (the checks of ``Take``'s construction, applied again) and
    folders that cannot be written are ``InputError``s. So is a take whose ``meta.audio`` names audio it
    does not hold (read with ``read_take(..., audio=False)``): writing it would replace the folder by one
    without its audio. ``take`` itself is never modified (the audio record written is a copy's).
    """
    if take.audio is None and take.meta.audio is not None:
        raise InputError(
            f"take {take.meta.id}: its metadata names audio ({take.meta.audio.file or 'attached'}) that the "
            "take does not hold (was it read without its audio, read_take(..., audio=False)?): read it "
            "with audio to write it, or set meta.audio = None to write it without audio",
            Path(out_dir) / safe_id(take.meta.id),
        )
    # the checks of construction again (arrays may have been replaced since), on a copy: the metadata
    # written (its audio record) is the copy's, and the caller's take is never modified
    try:
        take = replace(take, meta=copy.deepcopy(take.meta))
    except InputError as exc:
        if exc.path is not None:
            raise
        raise InputError(str(exc), Path(out_dir) / safe_id(take.meta.id)) from None
    out_dir = make_out_dir(out_dir)
    target = out_dir / safe_id(take.meta.id)
    if not 0 < take.meta.fps <= MAX_FPS:  # also NaN: never write a take that cannot be read back
        raise InputError(
            f"take {take.meta.id}: frame rate {take.meta.fps:g} is not in (0, {MAX_FPS:g}]", target
        )
    # never a field read_take would refuse (the audio record is completed when its file is written)
    check_meta_fields({k: v for k, v in take.meta.to_json().items() if k != "audio"}, target)
    if target.exists() and not overwrite:
        raise InputError("take exists already (use overwrite)", target)
    try:
        _write_take_folder(take, target)
    except OSError as exc:
        raise InputError(f"cannot write the take: {exc.strerror or exc}", target) from None
    return target


def _write_take_folder(take: Take, target: Path) -> None:
    with folder_in_place(target) as tmp:
        arrays = {"time": take.time, "values": take.values, "frame_status": take.frame_status}
        if take.neutral is not None:
            arrays["neutral"] = take.neutral
        if take.arrival_s is not None:
            arrays["arrival_s"] = take.arrival_s
        with open(tmp / FRAMES_FILE, "wb") as f:
            np.savez(f, **arrays)
            f.flush()
            os.fsync(f.fileno())
        meta = take.meta
        if take.audio is not None:
            write_audio(tmp / AUDIO_FILE, take.audio)
            start = meta.audio.start_s if meta.audio else 0.0
            source = meta.audio.start_source if meta.audio else "assumed"
            meta.audio = AudioInfo(
                AUDIO_FILE,
                take.audio.sample_rate,
                take.audio.channels,
                take.audio.frames,
                take.audio.subtype,
                start,
                source,
            )
        else:
            meta.audio = None
        try:
            write_json_atomic(tmp / META_FILE, strict_names(meta.to_json()))
        except ValueError as exc:  # NaN or infinity, which JSON cannot hold
            raise InputError(f"take {meta.id}: metadata cannot be written: {exc}", target) from None


def is_take_dir(path: str | Path) -> bool:
    return (Path(path) / META_FILE).is_file() and (Path(path) / FRAMES_FILE).is_file()


def read_meta(folder: str | Path) -> TakeMeta:
    """Only the metadata of a take folder (cheap)."""
    path = Path(folder) / META_FILE
    try:
        data = loads_names(path.read_text(encoding="utf-8"))
    except (FileNotFoundError, NotADirectoryError):
        raise InputError("not a take folder (no meta.json)", folder) from None
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise InputError(f"metadata is not valid JSON: {str(exc)[:200]}", path) from None
    except OSError as exc:  # unreadable (permissions, a folder named meta.json, I/O error)
        raise InputError(f"metadata cannot be read: {exc.strerror or exc}", path) from None
    return TakeMeta.from_json(data, path)


def read_take(folder: str | Path, audio: bool = True) -> Take:
    """Read a take folder written by ``write_take``. Never unpickles anything."""
    folder = Path(folder)
    meta = read_meta(folder)
    frames_path = folder / FRAMES_FILE
    try:
        with open_npz(frames_path) as z:
            if not isinstance(z, np.lib.npyio.NpzFile):
                raise InputError("frames are unreadable (a .npy array, not a .npz archive)", frames_path)
            # only the arrays a take has, each checked for its size before it is read (others are ignored)
            held = {header[0]: header for header in npz_headers(z, FRAMES_ARRAYS).values()}
            arrays = {k: npz_array(z, held[k], frames_path) for k in FRAMES_ARRAYS if k in held}
    except FileNotFoundError:
        raise InputError("take folder has no frames.npz", folder) from None
    except (*NPZ_ERRORS, SyntaxError, tokenize.TokenError) as exc:
        # SyntaxError, TokenError: a member's .npy header NumPy cannot parse (an unclosed bracket)
        raise InputError(f"frames are unreadable ({exc})", frames_path) from None
    for key in ("time", "values", "frame_status"):
        if key not in arrays:
            raise InputError(f"frames lack the array {key!r}", frames_path)
    if arrays["time"].dtype.kind != "f":
        raise InputError(f"time is {arrays['time'].dtype}, not float seconds", frames_path)
    if not np.all(np.isfinite(arrays["time"])):
        raise InputError("time holds NaN or infinite values", frames_path)
    for key in ("values", "neutral", "arrival_s"):  # numbers, not text that would convert or fail
        if key in arrays and arrays[key].dtype.kind not in "fiu":
            raise InputError(f"{key} is {arrays[key].dtype}, not numbers", frames_path)
    status = arrays["frame_status"]
    if status.dtype.kind not in "iu":
        raise InputError(f"frame_status is {status.dtype}, not integer codes", frames_path)
    unknown = np.setdiff1d(status, [int(s) for s in FrameStatus])
    if unknown.size:
        raise InputError(f"frame_status holds unknown value(s) {unknown[:5].tolist()}", frames_path)
    take_audio = None
    if audio and meta.audio is not None:
        take_audio = read_audio(folder / meta.audio.file)
        for what, held, said in (
            ("holds {} samples", take_audio.frames, meta.audio.samples),
            ("has {} channel(s)", take_audio.channels, meta.audio.channels),
            ("is at {} Hz", take_audio.sample_rate, meta.audio.sample_rate),
        ):
            if held != said:
                raise InputError(
                    f"audio {what.format(held)}, meta.json says {said} (damaged?)", folder / meta.audio.file
                )
    try:
        return Take(
            meta,
            arrays["time"],
            arrays["values"],
            arrays["frame_status"],
            take_audio,
            arrays.get("neutral"),
            arrays.get("arrival_s"),
        )
    except InputError as exc:  # the take's own checks (shapes, times) name the take, not its file
        if exc.path is not None:
            raise
        raise InputError(str(exc), frames_path) from None


def find_takes(paths: Iterable[str | Path]) -> list[Path]:
    """Take folders named by ``paths``; a folder that is not a take is searched recursively, skipping
    takes in or below a hidden folder (a take being written in place, ``folder_in_place``) under it: a
    folder named in ``paths`` counts even when hidden; what systems leave among copied files
    (``__MACOSX``, ``$RECYCLE.BIN``: ``transfer_litter``) is not searched. Symbolic links to folders
    are followed, each real folder once (no loops), and never to the folder searched or one above it."""
    found: list[Path] = []
    for p in map(Path, paths):
        if is_take_dir(p):
            found.append(p)
        elif p.is_dir():
            found.extend(_takes_below(p))
        else:
            raise InputError("no such take folder", p)
    return found


def leads_back(real: str | Path, top: str | Path) -> bool:
    """Whether the folder of real path ``real`` is the folder searched (real path ``top``) or one holding
    it: a symbolic link there would walk the search again (or everything above it)."""
    real, top = os.fspath(real), os.fspath(top)
    return top == real or top.startswith(real.rstrip(os.sep) + os.sep)


def _takes_below(root: Path) -> list[Path]:
    top = os.path.realpath(root)
    seen: set[str] = set()
    takes = []
    for here, folders, files in os.walk(root, followlinks=True):
        real = os.path.realpath(here)
        # a folder reached again, or a link back up to the folder searched or above it
        if real in seen or (here != str(root) and leads_back(real, top)):
            folders[:] = []
            continue
        seen.add(real)
        # not what systems leave (a take folder of ours named like a download, `x.part`, is a take)
        folders[:] = sorted(
            f
            for f in folders
            if not f.startswith(".") and (litter_kind(f) is None or is_take_dir(os.path.join(here, f)))
        )
        if here != str(root) and META_FILE in files and is_take_dir(here):
            takes.append(Path(here))
    return sorted(takes)
