"""Generic paired data from other rigs: an audio file, a frames x channels matrix, channel names, a rate.

Frame ``i`` covers ``[i/F, (i+1)/F)`` seconds from the start of the audio, so its time is ``i/F``.
Channel names are kept as given (a rig's own controls, e.g. FACEGOOD's 116); names of Live Link
channels in any spelling are mapped to the toolkit's canonical ARKit names.

The matrix is a ``.npy`` array, a CSV (optional header row of names) or the blendshape JSON that
NVIDIA Audio2Face exports (``exportFps``, ``numFrames``, ``numPoses``, ``facsNames``, ``weightMat``;
its joint tracks are not face weights and are left out), which carries its own names and rate.
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np

from . import channels as ch
from .audio_io import read_audio
from .csv_take import MAX_GAP_S, detect_fps, fill_dropped
from .errors import InputError
from .take import MAX_FPS, FrameStatus, Take, TakeMeta, safe_id, source_file


def load_npy(path: Path) -> np.ndarray:
    """A ``.npy`` array, never unpickled (object arrays are refused)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # Python 2 era .npy headers are harmless
            return np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise InputError(f"not a numeric or string .npy array ({exc})", path) from None


def read_names(path: str | Path) -> list[str]:
    """Channel names: a text file (one per line, or comma-separated) or a ``.npy`` array of strings."""
    path = Path(path)
    if not path.is_file():
        raise InputError("channel-name file not found", path)
    if path.suffix.lower() == ".npy":
        arr = load_npy(path)
        if arr.dtype.kind not in "US":
            raise InputError(f"names array holds {arr.dtype}, not strings", path)
        names = [str(x.decode() if isinstance(x, bytes) else x).strip() for x in arr.ravel()]
    else:
        text = path.read_text(encoding="utf-8-sig", errors="replace")
        names = [n.strip() for line in text.splitlines() for n in line.split(",")]
        names = [n for n in names if n]
    if not names:
        raise InputError("no channel names", path)
    twice = repeated_name(names)
    if twice is not None:
        raise InputError(f"channel name {twice[1]!r} appears twice", path)
    return names


def repeated_name(names: list[str]) -> tuple[str, str] | None:
    """The first two names that are one name in any case and spacing (first, second), or None."""
    seen: dict[str, str] = {}
    for n in names:
        key = n.strip().lower()
        if key in seen:
            return seen[key], n
        seen[key] = n
    return None


def read_a2f_json(path: Path) -> tuple[np.ndarray, list[str], float]:
    """Weights, pose names and frame rate of an Audio2Face blendshape export (JSON)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8-sig"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"not a JSON file ({exc})", path) from None
    except RecursionError:
        raise InputError("not a JSON file (nested too deeply)", path) from None
    if not isinstance(data, dict) or "weightMat" not in data or "facsNames" not in data:
        raise InputError("not an Audio2Face blendshape export (no weightMat and facsNames)", path)
    names, rows, fps = data["facsNames"], data["weightMat"], data.get("exportFps")
    if not isinstance(names, list) or not names or not all(isinstance(n, str) and n.strip() for n in names):
        raise InputError("facsNames must be a non-empty list of names", path)
    if not isinstance(rows, list) or not rows:
        raise InputError("weightMat must be a non-empty list of frames", path)
    for i, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != len(names):
            got = f"{len(row)} values" if isinstance(row, list) else type(row).__name__
            raise InputError(f"weightMat[{i}] holds {got}, facsNames {len(names)} names", path)
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in row):
            raise InputError(f"weightMat[{i}] holds a value that is not a number", path)
    for key, want in (("numFrames", len(rows)), ("numPoses", len(names))):
        got = data.get(key)
        if got is not None and (isinstance(got, bool) or got != want):
            raise InputError(f"{key} is {_show(got)} but the file holds {want}", path)
    if fps is not None:
        if isinstance(fps, bool) or not isinstance(fps, (int, float)):
            raise InputError(f"exportFps must be a number, not {_show(fps)}", path)
        try:
            fps = float(fps)
        except OverflowError:
            raise InputError(f"exportFps must be a frame rate, not {_show(fps)}", path) from None
    try:
        matrix = np.array(rows, dtype=np.float64)
    except OverflowError:
        raise InputError("weightMat holds a number too large for a float", path) from None
    return matrix, [n.strip() for n in names], fps


def _show(value: object, limit: int = 40) -> str:
    """A value for an error message, cut short (a 400-digit number stays readable)."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def read_matrix(path: str | Path) -> tuple[np.ndarray, list[str] | None, float | None]:
    """Frames x channels weights from ``.npy`` (never unpickled), ``.csv`` (optional header row) or an
    Audio2Face ``.json`` export; with the names and frame rate the file gives (else None)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("matrix file not found", path)
    header = fps = None
    if path.suffix.lower() == ".npy":
        m = load_npy(path)
    elif path.suffix.lower() == ".json":
        m, header, fps = read_a2f_json(path)
    else:
        rows: list[list[float]] = []
        text = path.read_text(encoding="utf-8-sig", errors="replace")
        for number, line in enumerate(text.splitlines(), start=1):
            if not line.strip():
                continue
            cells = [c.strip() for c in line.split(",")]
            try:
                if any("_" in c for c in cells):  # Python's float() reads "1_0" as 10
                    raise ValueError
                rows.append([float(c) for c in cells])
            except ValueError:
                if header is None and not rows:
                    header = cells
                    if not all(header):
                        raise InputError("the header leaves a column without a name", path, number) from None
                    continue
                raise InputError("non-numeric value in the matrix", path, number) from None
            if len(rows[-1]) != len(rows[0]):
                raise InputError(
                    f"row has {len(rows[-1])} values, the first row {len(rows[0])}", path, number
                )
        if not rows:
            raise InputError("matrix has no frames", path)
        m = np.array(rows, dtype=np.float64)
    if m.dtype.kind not in "fiu" or m.ndim != 2:
        raise InputError(f"expected a 2-D numeric frames x channels matrix, got {m.dtype} {m.shape}", path)
    if m.shape[0] == 0:
        raise InputError("matrix has no frames", path)
    return m, header, fps


# Paired data below this rate is a misread time column (milliseconds taken for seconds), not a capture.
MIN_FPS = 1.0
# Audio longer or shorter than the frames by more than this (s) is noted as repair ``length_mismatch``.
LENGTH_MISMATCH_S = 1.0
# Header names of a column that holds each frame's time rather than a channel (compared lower-case).
SECONDS_COLUMNS = ("time", "time_s", "times", "seconds", "timestamp", "timecode", "t")
FRAME_COLUMNS = ("frame", "frames", "frame_index", "frameindex", "frame_number", "framenumber")


def channel_name(name: str) -> str:
    """A channel's name as the take keeps it: Live Link/ARKit names in canonical spelling, also under a
    dotted prefix (``blendShapes.JawOpen``); a rig's own names as given."""
    if ch.is_known(name):
        return ch.canonical(name)
    last = name.rsplit(".", 1)[-1]
    return ch.canonical(last) if "." in name and ch.is_known(last) else name


def _frame_clock(names: list[str], matrix: np.ndarray, path) -> tuple[str | None, np.ndarray | None, int]:
    """The time column, if the header has one: (kind "seconds"/"frames", its values, its index)."""
    found = [(i, n) for i, n in enumerate(names) if n.strip().lower() in SECONDS_COLUMNS + FRAME_COLUMNS]
    if not found:
        return None, None, -1
    if len(found) > 1:
        raise InputError(f"several time columns: {', '.join(n for _, n in found)}", path)
    i, name = found[0]
    clock = matrix[:, i].astype(np.float64)
    if not np.isfinite(clock).all() or (clock.size > 1 and not (np.diff(clock) > 0).all()):
        raise InputError(f"time column {name!r} must be finite and increase from row to row", path)
    kind = "seconds" if name.strip().lower() in SECONDS_COLUMNS else "frames"
    if kind == "frames" and not np.array_equal(clock, np.round(clock)):
        raise InputError(f"frame column {name!r} holds values that are not whole numbers", path)
    return kind, clock, i


def _frame_times(kind: str | None, clock: np.ndarray | None, frames: int, fps: float, path) -> np.ndarray:
    """Frame times (s from the audio's start): ``i / fps``, or from the time column, whose median step
    must match ``fps`` and which may not jump by more than ``MAX_GAP_S``."""
    if kind is None:
        return np.arange(frames, dtype=np.float64) / fps
    time = clock if kind == "seconds" else clock / fps
    step = np.diff(time)
    median = float(np.median(step)) if step.size else 1 / fps
    if abs(median * fps - 1) > 0.03:
        raise InputError(
            f"the time column's step ({median:.5g} s) does not match {fps:g} frames per second", path
        )
    if step.size and step.max() > MAX_GAP_S:
        at = int(np.argmax(step))
        raise InputError(
            f"the time column jumps by {step[at]:.6g} s after frame {at + 1} (more than "
            f"{MAX_GAP_S:g} s: two recordings joined, or a corrupt clock)",
            path,
        )
    return time


def read_paired(
    audio_path: str | Path,
    matrix_path: str | Path,
    fps: float | None,
    names_path: str | Path | None = None,
    take_id: str | None = None,
) -> Take:
    """A take from audio + weight matrix + names at ``fps`` frames per second (None: the rate the
    matrix file gives, as an Audio2Face export does, or its time column's step), named ``take_id``
    (default: the matrix file's stem).

    A header column named like a time (``time``, ``timestamp``, ... in seconds from the audio's start) or
    a frame index (``frame``, ``frame_index``, ...) places the frames instead of the row index and is
    not a channel; gaps in it become DROPPED frames."""
    if fps is not None and not 0 < fps < math.inf:  # also NaN
        raise InputError(f"--fps must be a positive frame rate, not {fps}")
    matrix, header, file_fps = read_matrix(matrix_path)
    if file_fps is not None and fps is not None and not math.isclose(file_fps, fps, rel_tol=1e-6):
        raise InputError(f"--fps {fps:g} but the file says {file_fps:g} frames per second", matrix_path)
    if names_path is not None:
        names = read_names(names_path)
    elif header is not None:
        names = header
    else:
        raise InputError("no channel names: give --names or a header row in the matrix CSV", matrix_path)
    if len(names) != matrix.shape[1]:
        raise InputError(f"{len(names)} channel names for a matrix of {matrix.shape[1]} columns", matrix_path)
    kind, clock, column = _frame_clock(names, matrix, matrix_path)
    if column >= 0:
        names = names[:column] + names[column + 1 :]
        matrix = np.delete(matrix, column, axis=1)
        if not names:
            raise InputError("no channel columns besides the time column", matrix_path)
    fps = fps if fps is not None else file_fps
    if fps is None and kind == "seconds" and clock.size > 1:
        fps = detect_fps(clock, ntsc=True)[0]
    if fps is None:
        raise InputError("no frame rate: give --fps", matrix_path)
    if not MIN_FPS <= fps <= MAX_FPS:
        hint = " (is the time column in milliseconds?)" if kind == "seconds" else ""
        raise InputError(
            f"the frame rate must be in [{MIN_FPS:g}, {MAX_FPS:g}], not {fps:g}{hint}", matrix_path
        )
    names = [channel_name(n) for n in names]
    twice = repeated_name(names)
    if twice is not None:
        raise InputError(f"channels {twice[0]!r} and {twice[1]!r} are the same channel", matrix_path)
    with np.errstate(over="ignore"):  # beyond float32: inf, a BAD_VALUE frame
        values = matrix.astype(np.float32)
    status = np.where(np.isfinite(values).all(axis=1), FrameStatus.TRACKED, FrameStatus.BAD_VALUE).astype(
        np.uint8
    )
    time = _frame_times(kind, clock, matrix.shape[0], fps, matrix_path)
    meta = TakeMeta(
        id=safe_id(take_id or Path(matrix_path).stem),
        source_kind="paired_matrix",
        fps=float(fps),
        channels=names,
        sources=[source_file(matrix_path, "matrix")],
    )
    if names_path is not None:
        meta.sources.append(source_file(names_path, "channel_names"))
    bad = int((status != FrameStatus.TRACKED).sum())
    if bad:
        meta.repairs.append(
            {"line": None, "kind": "bad_value", "message": f"{bad} frames hold NaN/inf: marked invalid"}
        )
    if kind is not None:
        time, values, status, inserted = fill_dropped(time, values, status, 1 / fps)
        if inserted:
            meta.repairs.append(
                {
                    "line": None,
                    "kind": "dropped_frames",
                    "message": f"{inserted} frames missing from the time column",
                }
            )
    take = Take(meta, time, values, status)
    audio = read_audio(audio_path, meta.repairs)
    if time[-1] < 0 or time[0] >= audio.duration_s:
        raise InputError(
            f"the frames ({time[0]:.6g}..{time[-1]:.6g} s) lie outside the audio "
            f"(0..{audio.duration_s:.3f} s)",
            matrix_path,
        )
    take.attach_audio(audio, 0.0, "paired_frame_convention")
    meta.sources.append(source_file(audio_path, "audio"))
    note_length_mismatch(take, "check --fps")
    return take


def note_length_mismatch(take: Take, hint: str) -> None:
    """Note audio more than ``LENGTH_MISMATCH_S`` longer or shorter than the frames it was paired with
    (repair ``length_mismatch``; ``hint`` says what to check). The frames end one frame period after the
    last; both are measured from the audio's start."""
    frames_end = float(take.time[-1]) + 1 / take.meta.fps - take.meta.audio.start_s
    mismatch = take.audio.duration_s - frames_end
    if abs(mismatch) > LENGTH_MISMATCH_S:
        take.meta.repairs.append(
            {
                "line": None,
                "kind": "length_mismatch",
                "message": f"audio is {abs(mismatch):.3f} s {'longer' if mismatch > 0 else 'shorter'} than "
                f"the frames: {hint}",
            }
        )
