"""What a ``TAKE_OR_CSV`` argument of ``s2a-view`` names: exactly one take, read with what went wrong said.

A folder holding several takes is an error (never one of them picked silently); the Live Link Face CSV
variants of one take (``_cal``, ``_raw``, ``_neutral``) count as that one take. What the CSV reader
repaired (rows dropped, cells set to NaN) comes back as warnings. Values no face can take, NaN,
infinite or beyond ±``ABSURD`` (no blendshape weight nor angle in radians is), are bad values.
Blendshape weights outside ``0..1`` (ARKit itself reaches 1.05) are clamped for the face and counted.
A take whose audio was paired by frame index (``s2a-capture import --audio-pairing frame-index``: row i
goes with audio time i/fps) is shown on that clock, as ``s2a-align`` places it, not by its timecodes,
which run 0.16 % slow against it in a Live Link Face CSV (32 ms over 20 s).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from capture import Take, find_sources, find_takes, import_source, is_take_folder, read_audio, read_take
from capture.channels import ARKIT52, canonical, is_known
from capture.csv_take import split_variant
from capture.errors import InputError
from capture.importer import audio_beside, is_livelink_csv
from capture.paired import NoFrameRate
from capture.take import FrameStatus, is_take_dir
from capture.take_folder import choose_csv
from dataset.qa import ANIM_LIMIT

ABSURD = ANIM_LIMIT  # |value| above this is no blendshape weight nor angle in radians
# Repairs that change nothing a viewer shows: not worth a warning.
_QUIET_REPAIRS = ("bom", "no_audio")
_BLENDSHAPES = frozenset(ARKIT52)


def take_source(path: str | Path, one_take: str) -> Path:
    """The take folder, Live Link Face take folder, folder of one take's CSVs or CSV file ``path``
    names. ``one_take`` opens the error for a folder holding several takes (``"render shows one take
    per input"``), which lists them."""
    path = Path(path)
    if is_take_dir(path) or path.is_file():
        return path
    if not path.is_dir():
        raise InputError("no such take folder or CSV file", path)
    if is_take_folder(path):
        return path
    found = [(f"{p.relative_to(path)}/", p) for p in find_takes([path])]
    groups: dict[tuple[Path, str], tuple[str, Path]] = {}
    for src in find_sources([path]):  # Live Link Face take folders and CSVs, not take folders of ours
        if src.is_dir():
            groups[(src, "")] = (f"{src.relative_to(path)}/", src)
            continue
        prefix, variant = split_variant(src.stem)
        if variant != "neutral":  # a neutral pose goes with its take: no take of its own
            # The folder, not the file: the take folder reader picks the variant and the audio beside it.
            groups.setdefault((src.parent, prefix.lower()), (str(src.relative_to(path)), src.parent))
    found += groups.values()
    if not found:
        raise InputError("holds no take folder or Live Link Face CSV", path)
    if len(found) > 1:
        names = [name for name, _ in found]
        shown = ", ".join(names[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")
        raise InputError(f"{one_take}; found {len(found)} takes under it ({shown}): name one of them", path)
    return found[0][1]


def read_input(
    path: str | Path, one_take: str, audio: str | Path | None = None, audio_flag: str | None = "--audio"
) -> tuple[Take, list[str], Path | None]:
    """The one take ``path`` names (see ``take_source``), with ``audio`` as its speech, warnings about
    what reading it repaired (one line each), and the file its speech was read from (None: silent).
    ``audio_flag`` is the option that gives a CSV its audio here (``None``: none does), for the message
    about a CSV that needs it. A CSV named without ``audio`` brings the audio beside it
    (``csv_with_its_audio``), as naming its folder does.

    Audio holding NaN or infinite samples is an ``InputError`` (as ``s2a-train predict`` refuses it),
    never silence in its place."""
    src = take_source(path, one_take)
    if is_take_dir(src):
        take = read_take(src)
        if audio is not None:
            take.attach_audio(read_audio(audio))  # without a repair list, NaN samples are an error
            return take, [], Path(audio)
        # The file meta.json names, as read_take read it (a folder written elsewhere may name another).
        return on_audio_clock(take), [], src / take.meta.audio.file if take.meta.audio is not None else None
    warnings: list[str] = []
    variant = None
    if src.is_file():
        if src.stat().st_size == 0:
            raise InputError("file is empty: no Live Link Face CSV", src)
        if src.suffix.lower() == ".csv" and audio is None:
            src, variant, audio, why = csv_with_its_audio(src)
            if why:
                warnings.append(f"{path}: {why}: shown without audio")
        if src.suffix.lower() == ".csv" and audio is None and not is_livelink_csv(src):
            how = f"give its speech with {audio_flag}" if audio_flag else "it cannot be shown here"
            raise InputError(
                "not a Live Link Face CSV (its header does not start with Timecode,BlendShapeCount); as "
                f"other paired data (a column per channel) it needs its audio: {how}",
                src,
            )
    try:
        take = import_source(src, audio, variant)
    except NoFrameRate as exc:  # the viewer has no --fps: such a matrix is imported first, with one
        raise InputError(
            f"{exc}; the viewer takes no --fps: import it first (s2a-capture import --matrix {src} "
            "--audio AUDIO --fps RATE -o takes) and view the take folder"
        ) from None
    for r in take.meta.repairs:
        if r.get("kind") == "bad_audio":
            what = r["message"].removesuffix(" set to 0")
            raise InputError(
                f"the audio holds NaN or infinite samples ({what}): give clean speech", audio or path
            )
    return on_audio_clock(take), warnings + repair_warnings(take, src), audio_source(take, audio)


def on_audio_clock(take: Take) -> Take:
    """``take`` with its frames where its audio placement puts them, by ``s2a-align``'s own rule
    (``align.aligner.frame_clock``, ``auto``): audio paired by frame index places frame i at i/fps from
    the first frame (dropped-frame placeholders counted); any other placement keeps the timecodes."""
    from align.aligner import frame_clock  # align's imports (SciPy) only for a viewer that reads a take

    return frame_clock(take, "auto")[0]


def csv_with_its_audio(csv: Path) -> tuple[Path, str | None, Path | None, str | None]:
    """What to read for a CSV named without audio, so that naming it shows what naming its folder
    shows: the Live Link Face take folder it sits in when that folder reads this very CSV (the speech
    from its .mov or WAV, on the folder's timing), else the CSV with the audio file beside it (the one
    of the same stem, else the only one: capture's ``audio_beside``, as ``s2a-capture import
    --pair-audio`` pairs them). Returns (source, CSV variant to read, audio or None, why no audio was
    taken when that is worth a warning)."""
    variant = split_variant(csv.stem)[1]
    if variant != "neutral" and is_take_folder(csv.parent):
        try:
            if choose_csv(csv.parent, variant or "plain")[0] == csv:
                return csv.parent, variant or "plain", None, None
        except InputError:  # the folder does not read this CSV: the CSV alone, as named
            pass
    audio, why = audio_beside(csv)
    return csv, None, audio, why


def audio_source(take: Take, audio: str | Path | None) -> Path | None:
    """The file ``take``'s speech was read from: ``audio`` when given, else the WAV or the .mov its
    reader took it from (None: the take has no audio)."""
    if take.audio is None:
        return None
    if audio is not None:
        return Path(audio)
    roles = {s.role: Path(s.path) for s in take.meta.sources}
    return roles.get("audio") or roles.get("external_audio") or roles.get("reference_video")


def repair_warnings(take: Take, path: Path) -> list[str]:
    """One line per kind of repair the reader made (rows dropped, cells set to NaN, ...): the first one
    with its file and line, and how many more of the kind there were."""
    by_kind: dict[str, list[dict]] = {}
    for r in take.meta.repairs:
        if r.get("kind") not in _QUIET_REPAIRS:
            by_kind.setdefault(str(r.get("kind")), []).append(r)
    csv = next((s.path for s in take.meta.sources if s.role == "blendshapes_csv"), path)
    out = []
    for rs in by_kind.values():
        first = rs[0]
        where = f"{csv}:{first['line']}" if first.get("line") is not None else str(path)
        more = f" (and {len(rs) - 1} more like it)" if len(rs) > 1 else ""
        out.append(f"{where}: {first['message']}{more}")
    return out


def bad_frames(values: np.ndarray, channels: Sequence[str]) -> np.ndarray:
    """Frames (boolean mask) where a known channel is NaN, infinite or beyond ±``ABSURD``."""
    cols = [j for j, c in enumerate(channels) if is_known(c)]
    v = np.asarray(values, dtype=np.float64)[:, cols]
    return ~np.all(np.abs(v) <= ABSURD, axis=1)  # NaN compares False


def livelink_coverage(take: Take, path: str | Path, what: str) -> list[str]:
    """``what`` (a render, a stream) shows the 61 Live Link Face channels only: a take holding none of
    them (a rig's own controls, as FACEGOOD's takes and predictions of runs trained on them) is an
    ``InputError`` that says how to look at it instead; for a take holding some others, a warning that
    those are left out."""
    other = [c for c in take.meta.channels if not is_known(c)]
    if not other:
        return []
    shown = ", ".join(other[:3]) + (", ..." if len(other) > 3 else "")
    if len(other) == len(take.meta.channels):
        raise InputError(
            f"take {take.meta.id} holds none of the 61 Live Link Face channels (its {len(other)} channels "
            f"are a rig's own controls: {shown}): {what} shows Live Link channels only; draw its curves "
            f"with s2a-view plot --channels {','.join(most_varying(take))}",
            path,
        )
    return [f"{path}: {len(other)} channel(s) not of Live Link Face ({shown}) are left out of the {what}"]


def most_varying(take: Take, count: int = 2) -> list[str]:
    """The ``count`` channels of ``take`` whose values spread widest: worth a plot (the first channel of
    a rig often stays flat)."""
    values = np.where(np.abs(take.values) <= ABSURD, take.values, np.nan).astype(np.float64)
    usable = np.isfinite(values)
    # Reduced without nanmax/nanmin: their "All-NaN slice" warning would precede the one-line error.
    highest = np.where(usable, values, -np.inf).max(axis=0, initial=-np.inf)
    lowest = np.where(usable, values, np.inf).min(axis=0, initial=np.inf)
    spread = np.where(usable.any(axis=0), highest - lowest, -1.0)  # a channel of no value plots last
    order = np.argsort(-spread, kind="stable")  # ties (all flat) keep the take's own channel order
    return [take.meta.channels[j] for j in order[:count]]


def missing_face_channels(take: Take, path: str | Path) -> list[str]:
    """A warning naming the ARKit blendshapes ``take`` lacks (a CSV without a column, paired data of a
    few channels): the face shows them at 0, which looks like a closed mouth, not a gap. The head and
    eye angles are left out: a take of the 52 blendshapes (no head tracking) is whole, not lacking."""
    held = {canonical(c) for c in take.meta.channels if is_known(c)}
    missing = [c for c in ARKIT52 if c not in held]
    if not missing or not held:  # a take of no Live Link channel is refused (livelink_coverage)
        return []
    shown = ", ".join(missing[:5]) + (f" and {len(missing) - 5} more" if len(missing) > 5 else "")
    return [f"{path}: {len(missing)} face channel(s) not in the take, shown at 0: {shown}"]


def blendshape_columns(channels: Sequence[str]) -> list[int]:
    """Columns of ``channels`` that are ARKit blendshapes (weights 0..1), not head or eye angles."""
    return [j for j, c in enumerate(channels) if is_known(c) and canonical(c) in _BLENDSHAPES]


def clamp_blendshapes(
    values: np.ndarray, channels: Sequence[str], rows: np.ndarray | None = None, clamp: bool = True
) -> int:
    """How many blendshape weights of ``values`` (frames, channels) lie outside 0..1, in ``rows`` only
    (a boolean mask; default all); with ``clamp`` they are clamped to 0..1 in place. Angles are left
    alone."""
    cols = blendshape_columns(channels)
    if not cols:
        return 0
    sel = np.ix_(np.flatnonzero(rows) if rows is not None else np.arange(values.shape[0]), cols)
    block = values[sel]
    count = int(np.count_nonzero((block < 0) | (block > 1)))
    if count and clamp:
        values[sel] = np.clip(block, 0.0, 1.0)
    return count


def prepared_for_stream(take: Take) -> tuple[Take, int]:
    """``take`` as it may be sent to Unreal: frames with bad values marked BAD_VALUE (sent as no-face
    packets, counted in ``bad_values``). Returns it and how many blendshape weights of the frames sent
    with values lie outside 0..1: those are sent as they are, as the phone sends them (ARKit reaches
    1.05), and the caller warns about them."""
    bad = bad_frames(take.values, take.meta.channels)
    sent = (take.frame_status != FrameStatus.DROPPED) & (take.frame_status != FrameStatus.FACE_LOST)
    status = take.frame_status.copy()
    status[bad & sent] = FrameStatus.BAD_VALUE
    take.frame_status = status
    return take, clamp_blendshapes(take.values, take.meta.channels, sent & ~bad, clamp=False)
