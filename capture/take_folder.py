"""Live Link Face take folders, as the app writes them to ``Live Link Face/takes/<take>/``.

``take.json``, ``frame_log.csv``, ``audio_metadata.json``, ``video_metadata.json``, the reference
``<slate>_<take>_<subject>.mov`` (the only place the app keeps audio), and the blendshapes as
``<prefix>.csv`` or the calibrated trio ``<prefix>_cal.csv``, ``_neutral.csv``, ``_raw.csv``.

The audio's start on the take clock follows Epic's own ingest: the first ``A`` row of
``frame_log.csv``, else its first ``V`` row, else the ``.mov`` timecode track; the blendshape rows sit
at their CSV timecodes. Without any of these, audio is assumed to start with the first CSV row.
``frame_log.csv``'s timecodes count at the video's rate: ``video_metadata.json``'s ``FrameRate``, else
the ``.mov``'s own, else 60, unless its own video rows count at another rate (``FrameLog.timecode_rate``).
The app's JSON keys are read in any case (``Subject`` as ``subject``). The names of one take's files
(its CSVs, ``.mov``, ``.wav``, ``_neutral.csv``, the take's names from take.json and its folder) are
matched in Unicode NFC (``nfc``): macOS's HFS+ writes names decomposed (NFD), so a take copied from a
Mac beside files named on Linux spells ``Café_3`` two ways; the names written out stay as found. Two
files of one take named alike in NFC but both present (``_twins_error``) are an error naming both, never
one taken in silence; names equal only in NFKC (``ﬁ`` and ``fi``) are two names.
"""

from __future__ import annotations

import functools
import json
import math
import os
import re
import unicodedata
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .audio_io import Audio, read_audio
from .csv_take import STANDARD_FPS, read_csv_rows, read_livelink_csv, split_variant, text_lines
from .errors import InputError
from .mov import MovInfo, choose_mov_audio, probe_mov
from .paired import bom_codec, note_length_mismatch
from .take import FrameStatus, Take, safe_id, source_file
from .timecode import DAY_S, Timecode
from .transfer_litter import icloud_error, is_litter, not_downloaded

TAKE_FOLDER_MARKERS = ("take.json", "frame_log.csv")
# Seconds of video rows ``frame_log.csv`` must hold before its timecodes tell the rate they count at.
MIN_LOG_SPAN_S = 1.2
# The keys of the app's take.json (formats doc §3).
TAKE_JSON_KEYS = tuple(
    "frames appVersion slate calibrated subject identifier date version take deviceModel".split()
)
_PREFERENCE = ("cal", None, "raw")
# What a copy adds to a file's name: a browser's re-download ``X (1).csv``, Finder's ``X copy.csv`` and
# ``X copy 2.csv``, Windows Explorer's ``X - Copy.csv`` and ``X - Copy (2).csv``.
_COPY_RE = re.compile(r"^(?P<stem>.+?)(?P<copy> \(\d+\)| copy(?: \d+)?| - copy(?: \(\d+\))?)$", re.IGNORECASE)


@dataclass
class FrameLog:
    """``frame_log.csv``: one row per video (V), depth (D) or audio (A) frame the phone recorded."""

    kinds: list[str]
    indices: np.ndarray
    times_s: np.ndarray  # numerator/denominator, seconds on the phone's media clock
    timecodes: list[str]
    dropped: np.ndarray  # bool

    def first(self, kind: str) -> int | None:
        try:
            return self.kinds.index(kind)
        except ValueError:
            return None

    def timecode_rate(self, stated: float) -> float:
        """The rate the log's timecodes count at: ``stated`` (the video's), unless the video rows of its
        first seconds say otherwise: at the rate they count at, each row's timecode minus its media time
        is one constant (within jitter); at another, FF overflows it or the difference saws by up to a
        second. Needs ``MIN_LOG_SPAN_S`` of video rows; a log that fits no standard rate keeps
        ``stated``."""
        video = [i for i, k in enumerate(self.kinds) if k == "V"]
        if not video or self.times_s[video[-1]] - self.times_s[video[0]] < MIN_LOG_SPAN_S:
            return stated
        head = [i for i in video if self.times_s[i] - self.times_s[video[0]] <= 3 * MIN_LOG_SPAN_S]

        def spread(rate: float) -> float:
            try:
                tc = np.array([Timecode.parse(self.timecodes[i], rate).seconds_of_day for i in head])
            except ValueError:
                return math.inf
            lead = tc - self.times_s[head]
            lead[lead < lead[0] - DAY_S / 2] += DAY_S  # past midnight
            return float(np.ptp(lead))

        fits = {rate: spread(rate) for rate in (stated, *STANDARD_FPS)}
        fitting = [rate for rate, s in fits.items() if s <= 2 / rate]
        return stated if not fitting or stated in fitting else min(fitting, key=lambda r: fits[r] * r)


def _app_text(raw: bytes, errors: str = "strict") -> str:
    """The text of one of the app's JSON or log files as a copy may have left it: UTF-8 (the app's), a
    byte-order mark skipped (a Windows editor's "UTF-8 with BOM"), or UTF-16 with its mark (Notepad's
    "Unicode"); a run of NUL bytes ending the file (a power loss: its last blocks never written) left
    out."""
    codec = bom_codec(raw)
    if codec is not None:
        return raw.decode(codec, errors)
    return raw.rstrip(b"\0").decode("utf-8-sig", errors)


def read_frame_log(path: str | Path, repairs: list[dict[str, Any]]) -> FrameLog:
    """Parse ``frame_log.csv`` (no header): ``type,index,num,den,timecode[,dropped]``."""
    path = Path(path)
    kinds, idx, times, tcs, dropped = [], [], [], [], []
    text = _app_text(path.read_bytes(), errors="replace")
    for number, line in enumerate(text_lines(text), start=1):
        if not line.strip():
            continue
        f = [x.strip() for x in line.split(",")]
        try:
            if len(f) < 5 or f[0] not in ("V", "D", "A"):
                raise ValueError("expected type,index,num,den,timecode[,dropped]")
            if not line.isascii():  # int() reads other scripts' digits too; the app writes ASCII
                raise ValueError("non-ASCII characters")
            index, num, den = int(f[1]), int(f[2]), int(f[3])
            if den == 0:
                raise ValueError("zero time denominator")
            time_s = num / den
        except (ValueError, OverflowError) as exc:  # OverflowError: num/den beyond a float
            message = str(exc) if isinstance(exc, ValueError) else "time num/den out of range"
            repairs.append(
                {
                    "line": number,
                    "kind": "frame_log_row",
                    "message": f"{path.name}: {message[:200]}: row skipped",
                }
            )
            continue
        # appended only once the whole row parsed: the lists stay one entry per row
        kinds.append(f[0])
        idx.append(index)
        times.append(time_s)
        tcs.append(f[4])
        dropped.append(len(f) > 5 and f[5] not in ("", "0"))
    return FrameLog(kinds, np.asarray(idx), np.asarray(times), tcs, np.asarray(dropped, bool))


class Listing:
    """What was found in folders while ``listed_once`` holds it: (what, folder, its arguments) -> result."""

    def __init__(self) -> None:
        self.found: dict[tuple[Any, ...], Any] = {}

    @property
    def folders(self) -> list[Path]:
        """The folders listed, each once."""
        return [key[1] for key in self.found if key[0] == "_listed"]


_listing: Listing | None = None  # while ``listed_once`` holds


@contextmanager
def listed_once() -> Iterator[Listing]:
    """Within it each folder is listed once (``listed_entries``, ``listed_files``), and what is found in
    it (its CSVs, ``.mov`` files, app files, placeholders) found once, however many sources in it look at
    it: for one import, which writes no file in the folders it reads (files added to them meanwhile go
    unseen). Nested: the outer one's listing."""
    global _listing
    if _listing is not None:
        yield _listing
        return
    _listing = Listing()
    try:
        yield _listing
    finally:
        _listing = None


def once_per_listing(find: Callable[..., Any]) -> Callable[..., Any]:
    """``find(folder, *args)``, called once per listing within ``listed_once`` (its result only read)."""

    @functools.wraps(find)
    def found(folder: Path, *args: Any) -> Any:
        if _listing is None:
            return find(folder, *args)
        key = (find.__name__, folder, *args)
        if key not in _listing.found:
            _listing.found[key] = find(folder, *args)
        return _listing.found[key]

    return found


def _is_file(entry: os.DirEntry) -> bool:
    try:
        return entry.is_file()
    except OSError:  # as ``Path.is_file``: not a file it can tell is one
        return False


@once_per_listing
def _listed(folder: Path) -> tuple[list[Path], list[Path]]:
    """(the entries of ``folder``, in ``iterdir``'s order, those of them that are files)."""
    with os.scandir(folder) as scan:
        found = [(folder / entry.name, _is_file(entry)) for entry in scan]
    return [p for p, _ in found], [p for p, is_file in found if is_file]


def listed_entries(folder: Path) -> list[Path]:
    """``folder.iterdir()``, listed once within ``listed_once``."""
    return _listed(folder)[0]


def listed_files(folder: Path) -> list[Path]:
    """The entries of ``folder`` that are files (``Path.is_file``), listed once within ``listed_once``."""
    return _listed(folder)[1]


def is_take_folder(folder: str | Path) -> bool:
    """A Live Link Face take folder: has take.json or frame_log.csv, or a .mov beside a CSV (any of them
    perhaps an iCloud placeholder: reading the take then says to download it)."""
    folder = Path(folder)
    if not folder.is_dir():
        return False
    waiting = _placeholders(folder)
    if any(app_file_in(folder, m) is not None or m in waiting for m in TAKE_FOLDER_MARKERS):
        return True
    return bool(_files_ending(folder, ".mov") or _waiting_ending(waiting, ".mov")) and bool(
        _blendshape_csvs(folder) or _waiting_ending(waiting, ".csv")
    )


@once_per_listing
def app_file_in(folder: Path, name: str) -> Path | None:
    """The app's file ``name`` (lower case, as the app writes it) in ``folder``, spelled in any case
    (``TAKE.JSON``, ``Frame_Log.csv`` from a copy that changed the case, as the take's ``.CSV`` and ``.MOV``
    are found), else its one copy (``take (1).json``, ``without_copy``), or None. Of several spellings the
    app's own wins; several others are none of them."""
    if (folder / name).is_file():
        return folder / name
    found = [p for p in listed_files(folder) if not is_litter(p)]
    alike = [p for p in found if p.name.lower() == name]
    if not alike:  # a take folder whose every file a transfer renamed (``take (1).json``)
        alike = [p for p in found if without_copy(p.name).lower() == name]
    return alike[0] if len(alike) == 1 else None


def without_copy(name: str) -> str:
    """``name`` less what a copy added to it (``_COPY_RE``): ``take (1).json`` -> ``take.json``; AirDrop
    and Finder so rename every file of a take folder received where one of its names is taken."""
    path = Path(name)
    m = _COPY_RE.match(path.stem)
    return m.group("stem") + path.suffix if m else name


@once_per_listing
def _files_ending(folder: Path, suffix: str) -> list[Path]:
    """Files of ``folder`` with the suffix in any case (``X.MOV`` as well as ``X.mov``), sorted;
    operating-system and transfer litter (``._X.mov``, ``~$X.csv``) left out."""
    return sorted(p for p in listed_files(folder) if p.suffix.lower() == suffix and not is_litter(p))


def _is_frame_log(name: str) -> bool:
    """Whether ``name`` is the app's frame log (``frame_log.csv``), in any case or copy's name."""
    return without_copy(name).lower() == "frame_log.csv"


def _blendshape_csvs(folder: Path) -> list[Path]:
    return [p for p in _files_ending(folder, ".csv") if not _is_frame_log(p.name)]


@once_per_listing
def _placeholders(folder: Path) -> dict[str, Path]:
    """The files of ``folder`` iCloud has not downloaded: their names -> their placeholders
    (``.X.mov.icloud``)."""
    return {original: p for p in listed_entries(folder) if (original := not_downloaded(p)) is not None}


def _waiting_ending(waiting: dict[str, Path], suffix: str) -> list[str]:
    """The names among ``waiting`` (``_placeholders``) with the suffix in any case (``frame_log.csv``
    left out)."""
    return [n for n in waiting if Path(n).suffix.lower() == suffix and not _is_frame_log(n)]


# The app's files a take is read from besides its CSVs and media (``read_take_folder``).
APP_FILES = ("take.json", "video_metadata.json", "audio_metadata.json", "frame_log.csv")


def refuse_placeholders(folder: Path, audio_given: bool = False, variant: str | None = None) -> None:
    """Refuse a take folder holding an iCloud placeholder of a file the take is read from rather than
    import it without its audio or timing: ``APP_FILES``, the CSVs ``choose_csv`` takes (``variant`` as
    there), and the ``.mov`` and ``.wav`` the take would use (``_media``: a placeholder counts as the file
    it stands for when choosing them); ``audio_given``: its audio comes from elsewhere (``--audio``).
    Placeholders of files the take never reads (a second ``.mov``, a ``.wav`` beside a ``.mov`` with
    audio, other JSON) are left alone."""
    _refuse_app_placeholders(folder)
    csv_path, _ = choose_csv(folder, variant)
    _media(folder, split_variant(csv_path.stem)[0], audio_given)


def _refuse_app_placeholders(folder: Path) -> None:
    """Refuse a take folder holding an iCloud placeholder of one of ``APP_FILES``."""
    for name, placeholder in sorted(_placeholders(folder).items()):
        if without_copy(name).lower() in APP_FILES:
            raise icloud_error(placeholder, folder)


def nfc(name: str) -> str:
    """``name`` in Unicode NFC, as the names of one take's files are compared: macOS's HFS+ stores
    names decomposed (NFD: ``e`` + combining accent), Linux and Windows keep them as typed (NFC), so a
    copied ``Café.wav`` may be spelled otherwise than ``Café.csv``."""
    return unicodedata.normalize("NFC", name)


def spellings(names: list[str]) -> str:
    """Names equal in NFC, each told by its Unicode spelling, for a message: ``Café.mov (composed, NFC)
    and Café.mov (decomposed, NFD, as a Mac writes names)``."""
    return " and ".join(
        f"{n} ({'composed, NFC' if n == nfc(n) else 'decomposed, NFD, as a Mac writes names'})"
        for n in sorted(names)
    )


def _twins_error(names: list[str], folder: Path) -> InputError:
    """The error for two files of one take named alike but for their Unicode spelling (``nfc``): which
    one is the take's, no name tells; neither is taken in silence."""
    return InputError(
        f"holds {spellings(names)}: one name spelled two ways in Unicode (a file copied from a Mac beside "
        "one named here); keep the take's own and remove or rename the other",
        folder,
    )


def _refuse_twins(names: list[str], name: str, folder: Path) -> None:
    """``_twins_error`` when ``names`` hold ``name`` in two spellings (equal in ``nfc``)."""
    twins = sorted({n for n in names if nfc(n) == nfc(name)})
    if len(twins) > 1:
        raise _twins_error(twins, folder)


def _named_as(files: list[tuple[str, Path]], prefix: str, exact: bool = False) -> Path | None:
    """Of several files (their names, paths) of one kind, the take's: the one named as its CSV
    (``prefix``, compared in NFC), else (unless ``exact``) the first by name; None for none. Two files
    whose names are equal in NFC, the chosen one among them, are an error (``_twins_error``)."""
    files = sorted(files)
    named = [(name, p) for name, p in files if nfc(Path(name).stem) == nfc(prefix)]
    chosen = named[0] if named else None if exact or not files else files[0]
    if chosen is None:
        return None
    _refuse_twins([name for name, _ in files], chosen[0], chosen[1].parent)
    return chosen[1]


def _media(
    folder: Path, prefix: str, audio_given: bool, exact: bool = False
) -> tuple[Path | None, MovInfo | None, Path | None]:
    """The take's ``.mov`` (with its facts, ``_probe``) and the ``.wav`` that stands in for its audio
    (None unless the take has no ``.mov`` or its ``.mov`` holds no audio track), each the one named as
    the CSV (``prefix``), else (unless ``exact``: a folder of several takes) the first by name. Unless
    ``audio_given``, a file iCloud has not downloaded counts as there when choosing, and one chosen so
    is an error (``icloud_error``)."""
    waiting = {} if audio_given else _placeholders(folder)

    def pick(suffix: str) -> Path | None:
        real = [(p.name, p) for p in _files_ending(folder, suffix)]
        named = real + [(n, waiting[n]) for n in _waiting_ending(waiting, suffix)]
        chosen = _named_as(named, prefix, exact)
        if chosen is not None and chosen in waiting.values():
            raise icloud_error(chosen, folder)
        return chosen

    mov = pick(".mov")
    info = _probe(mov)
    mov_audio = mov is not None and (info is None or info.audio_tracks > 0)  # unknown: decoding tells
    return mov, info, None if mov_audio else pick(".wav")


def _bad_json(repairs: list[dict[str, Any]], message: str) -> None:
    repairs.append({"line": None, "kind": "bad_json", "message": message})


def _load_json(path: Path, repairs: list[dict[str, Any]]) -> dict[str, Any]:
    if not path.is_file():
        return {}
    try:
        data = json.loads(_app_text(path.read_bytes()))
        if not isinstance(data, dict):
            raise ValueError("not a JSON object")
        bad: list[str] = []
        data = _finite_json(data, "", bad)
    except (ValueError, UnicodeDecodeError, RecursionError) as exc:
        _bad_json(repairs, f"{path.name}: {str(exc)[:200]}: ignored")
        return {}
    if bad:
        more = f" and {len(bad) - 5} more" if len(bad) > 5 else ""
        _bad_json(repairs, f"{path.name}: NaN or infinite number in {', '.join(bad[:5])}{more}: set to null")
    return data


def _finite_json(value: Any, where: str, bad: list[str]) -> Any:
    """``value`` with the NaN and infinite numbers Python's json accepts replaced by ``None``; the
    path of each is appended to ``bad``."""
    if isinstance(value, float) and not math.isfinite(value):
        bad.append(where)
        return None
    if isinstance(value, dict):
        return {k: _finite_json(v, f"{where}.{k}" if where else k, bad) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite_json(v, f"{where}[{i}]", bad) for i, v in enumerate(value)]
    return value


def _field(data: dict[str, Any], key: str) -> Any:
    """A field of the app's JSON, its key in any case (``Subject`` for ``subject``): Epic's ingest reads
    these files with UE's FJsonObject, whose FString keys compare case-insensitively (inferred), so a
    file of another app version that spells them so is read there too."""
    if key in data:
        return data[key]
    return next((v for k, v in data.items() if k.lower() == key.lower()), None)


def _unknown_take_json(app_take: dict[str, Any], repairs: list[dict[str, Any]]) -> None:
    """Note a take.json none of whose keys is one the app writes (another tool's file, or a renamed
    layout): its slate, take and subject then come from the file name, which may be wrong."""
    known = {k.lower() for k in TAKE_JSON_KEYS}
    if app_take and not any(k.lower() in known for k in app_take):
        keys = ", ".join(list(app_take)[:5]) + (", ..." if len(app_take) > 5 else "")
        _bad_json(
            repairs,
            f"take.json: none of its keys ({keys}) is one the app writes ({', '.join(TAKE_JSON_KEYS)}): "
            "ignored: slate, take and subject come from the file name",
        )


def _json_number(data: dict[str, Any], key: str, file: str, repairs: list[dict[str, Any]]) -> float | None:
    """A positive number field of the app's JSON; another value is ignored (repair ``bad_json``)."""
    value = _field(data, key)
    if value is None:
        return None
    try:
        if isinstance(value, (int, float)) and not isinstance(value, bool) and 0 < float(value) < math.inf:
            return float(value)
    except OverflowError:
        pass
    _bad_json(repairs, f"{file}: {key} {repr(value)[:40]} is not a positive number: ignored")
    return None


def _json_text(data: dict[str, Any], key: str, file: str, repairs: list[dict[str, Any]]) -> str | None:
    """A non-empty text field of the app's JSON; another value is ignored (repair ``bad_json``)."""
    value = _field(data, key)
    if value is None or value == "":
        return None
    if isinstance(value, str):
        return value
    _bad_json(repairs, f"{file}: {key} {repr(value)[:40]} is not text: ignored")
    return None


def _json_whole(data: dict[str, Any], key: str, file: str, repairs: list[dict[str, Any]]) -> int | None:
    """A whole-number field of the app's JSON (0 or more), also written as text (``"7"``); another value
    is ignored (repair ``bad_json``)."""
    value = _field(data, key)
    if value is None or (type(value) is int and value >= 0):
        return value
    if isinstance(value, str) and re.fullmatch(r"[0-9]{1,9}", value.strip()):
        return int(value)
    _bad_json(repairs, f"{file}: {key} {repr(value)[:40]} is not a whole number: ignored")
    return None


@dataclass
class _CsvFile:
    """A blendshape CSV of a take folder, or its iCloud placeholder, and what its name says."""

    path: Path  # the file, or its placeholder
    name: str  # the file's own name
    prefix: str  # the take's name part, in NFC (``nfc``): ``MySlate_166_iPhone``
    variant: str | None  # cal, raw, neutral or None (plain)
    copy: str  # what a copy added to the name (``" (1)"``, ``" copy"``), or ""


@once_per_listing
def _csv_files(folder: Path) -> list[_CsvFile]:
    found = [(p, p.name) for p in _blendshape_csvs(folder)]
    waiting = _placeholders(folder)
    found += [(waiting[n], n) for n in _waiting_ending(waiting, ".csv")]
    files = []
    for path, name in sorted(found, key=lambda f: f[1]):
        stem = Path(name).stem
        m = _COPY_RE.match(stem)
        base, copy = (m.group("stem"), m.group("copy")) if m else (stem, "")
        prefix, variant = split_variant(base)
        files.append(_CsvFile(path, name, nfc(prefix), variant, copy))
    return files


def folder_name(folder: Path) -> str:
    """The name of ``folder`` as the user sees it, also when given as ``.``, ``./`` or ``..``."""
    return Path(os.path.abspath(folder)).name


def _take_names(folder: Path) -> set[str]:
    """What a take folder's CSV is named after: the ``.mov``'s stem, the app's ``{slate}_{take}_{subject}``
    and ``identifier`` from take.json, and the folder's name; in NFC (``nfc``)."""
    names = {folder_name(folder), *(p.stem for p in _files_ending(folder, ".mov"))}
    names |= {Path(n).stem for n in _waiting_ending(_placeholders(folder), ".mov")}
    take_json = app_file_in(folder, "take.json")
    app_take = {} if take_json is None else _load_json(take_json, [])
    identifier = _field(app_take, "identifier")
    if isinstance(identifier, str):
        names.add(identifier)
    parts = [_field(app_take, key) for key in ("slate", "take", "subject")]
    if all(isinstance(v, (str, int)) and not isinstance(v, bool) for v in parts):
        names.add("_".join(map(str, parts)))
    return {nfc(n) for n in names}


def _the_one(folder: Path, files: list[_CsvFile]) -> _CsvFile:
    """The CSV of one variant to import: the only one, else the one named after the take
    (``_take_names``, without a copy's addition; else so in any case); several are an error."""
    if len(files) == 1:
        return files[0]
    names = _take_names(folder)
    exact = [f for f in files if not f.copy and f.prefix in names]
    if len(exact) != 1:
        # lower(), not casefold(): casefold() also merges what only NFKC equates (``ﬁ`` and ``fi``)
        folded = {n.lower() for n in names}
        exact = [f for f in files if not f.copy and f.prefix.lower() in folded] or exact
    if len(exact) == 1:
        return exact[0]
    twins = [f.name for f in files if any(g.name != f.name and nfc(g.name) == nfc(f.name) for g in files)]
    if twins:  # two spellings of one name look alike in a list of names: said so
        raise _twins_error(twins, folder)
    variant = files[0].variant or "plain"
    raise InputError(
        f"take folder holds {len(files)} {variant} CSVs ({', '.join(f.name for f in files)}) and "
        f"{'none' if not exact else 'more than one'} is named after the take "
        f"({' or '.join(sorted(names))}): keep the take's own and remove the others (a copy or a "
        "re-download such as 'X (1).csv' or 'X copy.csv'), or import the right CSV alone",
        folder,
    )


def choose_csv(folder: Path, variant: str | None) -> tuple[Path, Path | None]:
    """The blendshape CSV to import (``variant`` cal/raw/plain, default cal, then plain, then raw),
    and the ``_neutral.csv`` beside it if any. Of two CSVs of one variant (``X.csv`` and a copy
    ``X (1).csv``, or ``X.CSV`` beside ``x.csv``) the one named after the take is taken, else it is an
    error naming them; a CSV that iCloud has not downloaded (``.X.csv.icloud``) is an error."""
    by_variant: dict[str | None, list[_CsvFile]] = {}
    for f in _csv_files(folder):
        by_variant.setdefault(f.variant, []).append(f)
    neutrals = by_variant.pop("neutral", None)
    if not by_variant:
        hint = " (a MetaHuman Animator depth take has none)" if app_file_in(folder, "depth_data.bin") else ""
        raise InputError(f"take folder holds no blendshape CSV{hint}", folder)
    if variant is not None:
        key = None if variant == "plain" else variant
        if key not in by_variant:
            raise InputError(
                f"take folder has no {variant} CSV (has: {[k or 'plain' for k in by_variant]})", folder
            )
    else:
        key = next(k for k in _PREFERENCE if k in by_variant)
    chosen = [_the_one(folder, by_variant[key])]
    if neutrals:
        chosen.append(_the_one(folder, neutrals))
    for f in chosen:
        if f.path.name != f.name:
            raise icloud_error(f.path, folder)
    return chosen[0].path, chosen[1].path if neutrals else None


def _mov_names(folder: Path) -> set[str]:
    """The stems of the ``.mov`` files of ``folder``, iCloud placeholders of them included, in NFC."""
    names = {p.stem for p in _files_ending(folder, ".mov")}
    return {nfc(n) for n in names | {Path(n).stem for n in _waiting_ending(_placeholders(folder), ".mov")}}


def _is_its_folder(csv: Path) -> bool:
    """Whether the folder ``csv`` sits in is its take's own folder: a take folder that reads this very
    CSV (``choose_csv`` of its variant), so that its take.json, metadata and frame_log.csv are this
    take's. A folder of several takes, where they are nobody's in particular, is not."""
    variant = split_variant(csv.stem)[1]
    if variant == "neutral" or not is_take_folder(csv.parent):
        return False
    try:
        return nfc(choose_csv(csv.parent, variant or "plain")[0].name) == nfc(csv.name)
    except InputError:  # the folder does not read this CSV (several takes, or it is a copy)
        return False


def reads_as_take(csv: str | Path) -> bool:
    """Whether a Live Link Face CSV named alone is read as its take (``read_take_folder`` with
    ``csv``): its folder reads it as its take, or the ``.mov`` named as its take (its stem without
    ``_cal``/``_raw``, compared in NFC) sits beside it, perhaps not yet downloaded from iCloud (reading
    then says so). A ``_neutral.csv`` is no take."""
    csv = Path(csv)
    prefix, variant = split_variant(csv.stem)
    if variant == "neutral" or not csv.parent.is_dir():
        return False
    return _is_its_folder(csv) or nfc(prefix) in _mov_names(csv.parent)


def takes_side_by_side(folder: str | Path, variant: str | None = None) -> list[Path]:
    """The CSVs of a folder holding several takes side by side (each take's ``X.csv`` and ``X.mov``
    gathered into one folder), one per take, to import on its own; [] for any other folder. Every
    blendshape CSV must be named as a ``.mov`` beside it (less ``_cal``/``_raw``/``_neutral``; names
    compared in NFC, so a take's files of two spellings are one take's), none a copy (``X (1).csv``: a
    take folder's copies stay its error or choice), of two takes or more. Of a take's variants,
    ``variant``'s (cal, raw, plain) when it has one, else the one a take folder prefers (cal, plain,
    raw): its cal and raw CSVs are one performance, not two takes."""
    folder = Path(folder)
    files = _csv_files(folder)
    movs = _mov_names(folder)
    if any(f.copy or f.prefix not in movs for f in files) or len({f.prefix for f in files}) < 2:
        return []
    if len({(f.prefix, f.variant) for f in files}) < len(files):  # one CSV spelled two ways (``nfc``)
        return []  # read as one take folder, whose ``choose_csv`` names them
    chosen = []
    for prefix in dict.fromkeys(f.prefix for f in files):
        csv = preferred_csv({f.variant: f.path for f in files if f.prefix == prefix}, variant)
        if csv is not None:
            chosen.append(csv)
    return chosen


def preferred_csv(of_take: dict[str | None, Path], variant: str | None = None) -> Path | None:
    """Of the CSVs of one take by variant (cal, raw, None: plain; a ``neutral`` one is never chosen),
    the one its take folder reads: ``variant``'s (cal, raw, plain) when the take has it, else cal, plain,
    raw; None when it has none of them."""
    wanted = ((None if variant == "plain" else variant),) if variant is not None else ()
    return next((of_take[k] for k in (*wanted, *_PREFERENCE) if k in of_take), None)


def neutral_named_as(folder: Path, prefix: str) -> Path | None:
    """The ``_neutral.csv`` of the take ``prefix`` in a folder of several takes, or None; one iCloud
    has not downloaded is an error."""
    found = [
        f for f in _csv_files(folder) if f.variant == "neutral" and f.prefix == nfc(prefix) and not f.copy
    ]
    if not found:
        return None
    if len(found) > 1:  # spelled two ways (``nfc``)
        raise _twins_error([f.name for f in found], folder)
    if found[0].path.name != found[0].name:
        raise icloud_error(found[0].path, folder)
    return found[0].path


def _signed_day_diff(a: float, b: float) -> float:
    d = (a - b) % DAY_S
    return d - DAY_S if d > DAY_S / 2 else d


def read_take_folder(
    folder: str | Path,
    variant: str | None = None,
    audio_file: str | Path | None = None,
    strict: bool = False,
    swap_lr: bool = False,
    timecode_rate: float | None = None,
    csv: str | Path | None = None,
) -> Take:
    """Import a Live Link Face take folder (blendshapes, audio from the ``.mov``, timing, metadata);
    ``timecode_rate``: the rate its CSV's FF counts at (None: detected, see ``read_livelink_csv``).
    ``csv``: a CSV named alone, read as its take (``folder`` is then its folder, ``variant`` unused):
    with the ``.mov`` (else ``.wav``) and ``_neutral.csv`` named as it, and the folder's app files only
    when the folder is its take's own (``_is_its_folder``); in a folder of several takes the ``.mov``'s
    own timecode places the audio."""
    if csv is not None:
        csv_path, folder = Path(csv), Path(csv).parent
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("take folder not found", folder)
    own = csv is None or _is_its_folder(csv_path)
    if not own:  # its folder's own take, but for a twin of its name: not read without take.json in silence
        _refuse_twins([f.name for f in _csv_files(folder)], csv_path.name, folder)
    if own:
        _refuse_app_placeholders(folder)
        # named alone, the CSV's own variant (``choose_csv`` of it is this CSV, as ``_is_its_folder`` found)
        own_variant = variant if csv is None else split_variant(csv_path.stem)[1] or "plain"
        csv_path, neutral_path = choose_csv(folder, own_variant)
    prefix = split_variant(csv_path.stem)[0]
    if not own:
        neutral_path = neutral_named_as(folder, prefix)
    # of several, the .mov (or .wav) named as the CSV is the take's (in a folder of several takes, only it)
    mov, info, wav = _media(folder, prefix, audio_given=audio_file is not None, exact=not own)
    take = read_livelink_csv(csv_path, strict=strict, swap_lr=swap_lr, timecode_rate=timecode_rate)
    meta = take.meta
    repairs = meta.repairs

    def app_file(name: str) -> Path | None:
        """One of the app's files of this take; none in a folder of several takes."""
        return app_file_in(folder, name) if own else None

    def app_json(name: str) -> dict[str, Any]:
        path = app_file(name)
        return {} if path is None else _load_json(path, repairs)

    app_take = app_json("take.json")
    _unknown_take_json(app_take, repairs)
    video_meta = app_json("video_metadata.json")
    audio_meta = app_json("audio_metadata.json")
    meta.source_kind = "livelink_take_folder"
    if own:
        meta.id = safe_id(_json_text(app_take, "identifier", "take.json", repairs) or folder_name(folder))
    meta.slate = _json_text(app_take, "slate", "take.json", repairs) or meta.slate
    take_number = _json_whole(app_take, "take", "take.json", repairs)
    meta.take_number = meta.take_number if take_number is None else take_number
    meta.subject = _json_text(app_take, "subject", "take.json", repairs) or meta.subject
    meta.device = _json_text(app_take, "deviceModel", "take.json", repairs)
    meta.extra.update({"take_json": app_take, "video_metadata": video_meta, "audio_metadata": audio_meta})
    # A simulated take (s2a-capture simulate) carries its ground truth beside the app's files.
    if (simulation := app_file("simulation.json")) is not None:
        meta.extra["simulation"] = _load_json(simulation, repairs)
        meta.sources.append(source_file(simulation, "simulation.json"))
    for name in ("take.json", "video_metadata.json", "audio_metadata.json", "frame_log.csv"):
        if (path := app_file(name)) is not None:
            meta.sources.append(source_file(path, name))
    if neutral_path is not None:
        attach_neutral(take, neutral_path)

    # frame_log.csv's timecodes count at the video's rate: an app version that writes no
    # video_metadata.json still states it in the .mov
    video_rate = (
        _json_number(video_meta, "FrameRate", "video_metadata.json", repairs)
        or (info.timecode_rate if info else None)
        or 60.0
    )
    log = None
    if (frame_log := app_file("frame_log.csv")) is not None:
        log = read_frame_log(frame_log, repairs)
        meta.extra["frame_log"] = {
            "video_frames": log.kinds.count("V"),
            "audio_rows": log.kinds.count("A"),
            "dropped_video_frames": int(log.dropped[[k == "V" for k in log.kinds]].sum()) if log.kinds else 0,
        }
        log_rate = log.timecode_rate(video_rate)
        if log_rate != video_rate:
            repairs.append(
                {
                    "line": None,
                    "kind": "frame_log_rate",
                    "message": f"frame_log.csv's timecodes count at {log_rate:g} fps, not at the video's "
                    f"{video_rate:g}: read at {log_rate:g}",
                }
            )
            video_rate = log_rate
    mov_audio = mov is not None and (info is None or info.audio_tracks > 0)  # unknown: decoding tells
    if mov is not None:
        meta.sources.append(source_file(mov, "reference_video"))
        meta.extra["reference_video"] = mov.name
    audio: Audio | None = None
    start_s, start_source = 0.0, "assumed_first_csv_row"
    if audio_file is not None:
        audio = read_audio(audio_file, repairs)
        meta.sources.append(source_file(audio_file, "external_audio"))
    elif not mov_audio and wav is None:
        why = "has no .mov or .wav" if mov is None else f"has no .wav, and {mov.name} holds no audio track"
        repairs.append(
            {"line": None, "kind": "no_audio", "message": f"take folder {why}: imported without audio"}
        )
    else:
        if mov_audio:
            audio, track = choose_mov_audio(mov, repairs, info.audio_tracks if info else 1)  # probed once
            if track is not None:
                meta.extra["mov_audio_track"] = track
        else:
            audio = read_audio(wav, repairs)
            meta.sources.append(source_file(wav, "audio"))
            if mov is not None:
                repairs.append(
                    {
                        "line": None,
                        "kind": "audio_track",
                        "message": f"{mov.name} holds no audio track: the audio is {wav.name} beside it",
                    }
                )
        csv_t0 = meta.csv["start_seconds_of_day"]
        for kind, source in (("A", "frame_log_audio"), ("V", "frame_log_video")):
            i = log.first(kind) if log else None
            if i is None or log is None:
                continue
            try:
                tod = Timecode.parse(log.timecodes[i], video_rate).seconds_of_day
            except ValueError as exc:
                repairs.append({"line": i + 1, "kind": "frame_log_row", "message": str(exc)})
                continue
            start_s, start_source = _signed_day_diff(tod, csv_t0), source
            break
        else:
            if info is None and mov is not None:
                info = probe_mov(mov)
            if info is not None and info.timecode:
                try:
                    rate = info.timecode_rate or round(video_rate)
                    tod = Timecode.parse(info.timecode, rate).seconds_of_day
                    # a stand-in .wav starts with the video, as the .mov's audio would
                    start_s = _signed_day_diff(tod, csv_t0) + (info.audio_start_s if mov_audio else 0.0)
                    start_source = "mov_timecode"
                except ValueError:
                    pass
        expected = _json_number(audio_meta, "SampleRate", "audio_metadata.json", repairs)
        if expected and expected != audio.sample_rate:
            repairs.append(
                {
                    "line": None,
                    "kind": "audio_rate_mismatch",
                    "message": f"audio_metadata.json says {expected:g} Hz, the audio holds "
                    f"{audio.sample_rate} Hz: the file's own rate is used",
                }
            )
    if audio is not None:
        take.attach_audio(audio, start_s, start_source)
    return take


def _probe(mov: Path | None) -> MovInfo | None:
    """The ``.mov``'s facts, or None without one or for a file that does not open (reading its audio
    then says what is wrong with it)."""
    if mov is None:
        return None
    try:
        return probe_mov(mov)
    except InputError:
        return None


def attach_neutral(take: Take, path: Path) -> None:
    """Keep the ``_neutral.csv`` at ``path`` as the take's calibrated rest pose (``take.neutral``) and
    name it among its sources."""
    take.neutral = _neutral_pose(path, take)
    take.meta.sources.append(source_file(path, "neutral_csv"))


def _neutral_pose(path: Path, take: Take) -> np.ndarray:
    """The calibrated rest pose: mean of the tracked rows of ``_neutral.csv``, in the take's channels."""
    neutral = read_livelink_csv(path, swap_lr=bool(take.meta.csv.get("swapped_left_right")))
    rows = neutral.values[neutral.frame_status == FrameStatus.TRACKED]
    if rows.size == 0:
        raise InputError("neutral CSV has no tracked rows", path)
    mean = rows.mean(axis=0)
    out = np.full(len(take.meta.channels), np.nan, dtype=np.float32)
    for j, name in enumerate(take.meta.channels):
        if name in neutral.meta.channels:
            out[j] = mean[neutral.meta.channels.index(name)]
    return out


def read_csv_with_audio(
    csv_path: str | Path,
    audio_file: str | Path,
    strict: bool = False,
    swap_lr: bool = False,
    by_frame_index: bool = False,
    timecode_rate: float | None = None,
) -> Take:
    """A CSV paired with audio recorded elsewhere; the audio is assumed to start with the first row
    (``s2a-align`` measures the real offset). ``by_frame_index``: the pair was made so that row i goes
    with audio time i/fps whatever the timecodes say (start source ``paired_frame_convention``, which
    ``s2a-align`` places by frame index). Audio of another length than the rows is noted
    (``length_mismatch``); ``timecode_rate`` as for ``read_livelink_csv``."""
    take = read_livelink_csv(csv_path, strict=strict, swap_lr=swap_lr, timecode_rate=timecode_rate)
    source = "paired_frame_convention" if by_frame_index else "assumed_first_csv_row"
    take.attach_audio(read_audio(audio_file, take.meta.repairs), 0.0, source)
    take.meta.sources.append(source_file(audio_file, "external_audio"))
    note_length_mismatch(take, "check that the audio is this CSV's")
    return take


__all__ = [
    "FrameLog",
    "attach_neutral",
    "choose_csv",
    "is_take_folder",
    "neutral_named_as",
    "preferred_csv",
    "read_csv_rows",
    "read_csv_with_audio",
    "read_frame_log",
    "read_take_folder",
    "reads_as_take",
    "refuse_placeholders",
    "takes_side_by_side",
]
