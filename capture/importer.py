"""``s2a-capture import``: every kind of source becomes take folders in the take container."""

from __future__ import annotations

import codecs
import os
import re
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import NamedTuple

from .command import warn
from .csv_take import app_header_separator, read_livelink_csv, split_variant, utf16_csv_error
from .errors import InputError, S2AError
from .paired import bom_codec, emotion_weights, header_names, is_face_cap, read_paired
from .take import Take, is_take_dir, leads_back
from .take_folder import (
    attach_neutral,
    is_take_folder,
    listed_entries,
    listed_files,
    listed_once,
    neutral_named_as,
    nfc,
    once_per_listing,
    preferred_csv,
    read_csv_with_audio,
    read_take_folder,
    reads_as_take,
    spellings,
    takes_side_by_side,
)
from .trainer_data import (
    A2F_PARTS,
    a2f_root,
    a2f_shots,
    is_a2f_dataset,
    neurosync_features,
    read_a2f_shot,
)
from .transfer_litter import (
    Litter,
    icloud_error,
    icloud_original,
    is_appledouble,
    is_litter,
    is_zip,
    not_downloaded,
    zip_error,
)

# How audio given with --audio goes with a CSV's rows (see read_csv_with_audio).
AUDIO_PAIRINGS = ("first-row", "frame-index")
# Audio files ``--pair-audio`` finds beside a CSV or an Audio2Face export.
AUDIO_SUFFIXES = (".wav", ".flac", ".ogg", ".mp3", ".m4a", ".aac", ".aif", ".aiff")
# The keys of an Audio2Face blendshape export, looked for anywhere in a .json (their order is not fixed:
# a writer that puts "facsNames" after the weights has it megabytes in).
_A2F_MARKS = ('"facsNames"', '"weightMat"')
# BEAT's face JSON (``{"names": [...], "frames": [{"time": .., "weights": [...]}]}``): its "names" key,
# and a "frames" list whose first frame holds a "weights" list (each key alone, or the three anywhere in a
# file, is too common to tell a file by: a settings file of "names", "frames" and some "weights").
_BEAT_NAMES = '"names"'
_BEAT_FRAME = re.compile(r'"frames"\s*:\s*\[\s*\{[^{}]*?"weights"\s*:\s*\[')
# Characters of a block kept for the next one: a key, or BEAT's first frame, split across two reads.
_MARK_SPAN = 1 << 12
# What Audio2Face adds to an export's name (``line01_bsweight.json`` goes with ``line01.wav``).
A2F_SUFFIX = "_bsweight"


def warn_skipped(path: Path, why: str) -> None:
    """Say on stderr that a file found in a folder is left out, and why."""
    warn(f"{path}: {why}: skipped")


def find_sources(
    paths: list[str | Path],
    exports: bool = False,
    skipped: Callable[[Path, str], None] = warn_skipped,
    litter: Litter | None = None,
    archives: bool = False,
    variant: str | None = None,
) -> list[Path]:
    """Live Link Face take folders and loose CSV files named by ``paths``, searched recursively (a folder
    of several takes side by side, each CSV named as a ``.mov`` beside it, is one CSV per take, of
    ``variant`` as a take folder chooses it: ``takes_side_by_side``);
    with ``exports``, Audio2Face blendshape exports (``.json``) too, and every other ``.json`` found in a
    folder is reported to ``skipped`` (path, why) rather than left out silently, as are zip archives,
    dangling symbolic links and links back to a folder holding the one searched; with ``archives``, zip
    archives found are sources (``capture.take_archive``). Operating-system and
    transfer litter (``capture.transfer_litter``: ``._*``, ``__MACOSX``, ``$RECYCLE.BIN``, ...) is passed
    over and counted in ``litter``; without one, a warning line per kind is printed here. An iCloud
    placeholder of a CSV (``.X.csv.icloud``) is a source: importing it says to download it. The loose
    CSVs of one calibrated take are one source (``one_per_take``)."""
    tally = Litter() if litter is None else litter
    found: list[Path] = []
    named: set[Path] = set()
    with listed_once():  # a take folder, or one of several takes, looked at for each file in it
        for p in map(Path, paths):
            if tally.skips(p):
                continue
            if p.is_file():
                found.append(p)
                named.add(p)
            elif p.is_dir():
                found.extend(_walk(p, exports, archives, skipped, tally, p.resolve(), variant))
            else:
                raise InputError("no such file or folder", p)
    if litter is None:
        for line in tally.lines():
            warn(line)
    return one_per_take(found, named, variant, skipped)


def _loose_csv(source: Path) -> tuple[str, str | None] | None:
    """The take name (its prefix, in NFC) and variant (cal, raw, neutral or None: plain) of a source that
    is a loose Live Link Face CSV (or its iCloud placeholder), by its name; None for any other source."""
    name = icloud_original(source) or source.name
    if Path(name).suffix.lower() != ".csv" or source.is_dir():
        return None
    prefix, variant = split_variant(Path(name).stem)
    return nfc(prefix), variant


def one_per_take(
    sources: list[Path],
    named: set[Path],
    variant: str | None = None,
    skipped: Callable[[Path, str], None] = warn_skipped,
) -> list[Path]:
    """``sources`` with the loose Live Link Face CSVs of one calibrated take (``X_cal.csv``, ``X_raw.csv``,
    ``X_neutral.csv`` in one folder) read as their take folder reads them: one of them, ``variant``'s
    when the take has it, else cal, plain, raw; the others reported to ``skipped``. ``X_neutral.csv`` is
    no take of its own but the pose ``import_source`` keeps as the take's ``neutral``; a lone one is
    skipped too, unless ``named`` (given by name: the user asked for it, and it is read as a take). A take
    with two CSVs of one variant (a copy, one name spelled two ways) and CSVs of other writers (generic
    paired data) are left as they are."""
    takes: dict[tuple[Path, str], dict[str | None, list[Path]]] = {}
    for p in sources:
        if (csv := _loose_csv(p)) is not None:
            takes.setdefault((p.parent.resolve(), csv[0]), {}).setdefault(csv[1], []).append(p)
    dropped: set[Path] = set()
    for files in takes.values():
        if (len(files) == 1 and "neutral" not in files) or any(len(ps) > 1 for ps in files.values()):
            continue  # one CSV, or a take whose CSVs no name tells apart: as they were
        of_take = {v: p for v, (p,) in files.items() if icloud_original(p) is not None or is_livelink_csv(p)}
        neutral = of_take.pop("neutral", None)
        chosen = preferred_csv(of_take, variant)
        if chosen is not None:  # its import reads the neutral pose beside it (a damaged one too: said once)
            dropped.update(files.get("neutral", []))
        elif neutral is not None and neutral not in named:
            dropped.add(neutral)
            skipped(
                neutral,
                "the neutral pose of a calibrated take (a still face) with no other CSV of its take beside "
                "it, not a take of its own (name it to import it as one)",
            )
        for own, p in of_take.items():
            if p != chosen:
                dropped.add(p)
                why = (
                    f"not --variant {variant}"
                    if variant
                    else f"{icloud_original(chosen) or chosen.name} read instead"
                )
                skipped(p, f"the {own or 'plain'} CSV of its take, {why}")
    return [p for p in sources if p not in dropped]


def _walk(
    folder: Path,
    exports: bool,
    archives: bool,
    skipped: Callable[[Path, str], None],
    litter: Litter,
    root: Path,
    variant: str | None,
    seen: set[Path] | None = None,
) -> Iterator[Path]:
    seen = set() if seen is None else seen
    real = folder.resolve()
    if real in seen:  # a folder reached again through a symbolic link (a loop, or two links to it)
        return
    seen.add(real)
    if is_take_folder(folder):
        for p in listed_entries(folder):  # counted: what the take folder reader passes over in it
            litter.skips(p)
        # several takes' CSVs and .movs gathered into one folder: each CSV is read as its take
        yield from takes_side_by_side(folder, variant) or [folder]
        return
    if is_take_dir(folder) or folder.name.startswith("."):
        return  # an imported take of ours, or a hidden/temporary folder
    dataset_parts: tuple[str, ...] = ()
    if is_a2f_dataset(folder):  # an actor's Audio2Face-3D training data: a take per shot of cache/skin
        yield from a2f_shots(folder)
        dataset_parts = A2F_PARTS
    for p in sorted(listed_entries(folder)):
        if p.name in dataset_parts or litter.skips(p):
            continue
        if p.is_symlink():
            if not p.exists():  # dangling (or a loop of links)
                skipped(p, f"a symbolic link to {os.readlink(p)}, which does not exist")
                continue
            target = p.resolve()
            if p.is_dir() and leads_back(target, root):
                skipped(p, f"a symbolic link to {target}, which holds the folder searched (a loop)")
                continue
        if p.is_dir():
            yield from _walk(p, exports, archives, skipped, litter, root, variant, seen)
        elif p.suffix.lower() == ".csv":
            why = not_a_face_take(p.name, _head(p))
            if why is None:
                yield p
            else:
                skipped(p, why)
        elif exports and is_face_cap_text(p):
            yield p  # Face Cap's text export
        elif exports and p.suffix.lower() == ".json":
            if is_weights_json(p):
                yield p
            else:
                skipped(
                    p,
                    'not an Audio2Face blendshape export or BEAT face JSON (no "facsNames"/"weightMat", '
                    'nor "names" and "frames" of "weights")',
                )
        elif is_zip(p):
            if archives:
                yield p
            else:
                skipped(p, "a zip archive: unzip it to import the takes it holds")
        elif (original := not_downloaded(p)) is not None and Path(original).suffix.lower() in (
            (".csv", ".json") if exports else (".csv",)
        ):
            yield p  # a source of this import, not downloaded


def no_takes_found(paths: list[str | Path], stage: str) -> InputError:
    """The error of a ``stage`` (align, the dataset build) that found no take folder of ours under
    ``paths``: when they hold what ``s2a-capture import`` reads (the app's take folders, CSVs), it says
    to import them first."""
    where = ", ".join(map(str, paths))
    try:
        recordings = find_sources(paths, skipped=lambda _path, _why: None, litter=Litter(), archives=True)
    except (S2AError, OSError):
        recordings = []
    if not recordings:
        return InputError(f"no takes found under {where}")
    return InputError(
        f"no takes found under {where}, only {len(recordings)} recording(s) not imported yet (Live Link Face "
        f"take folders or CSVs): run s2a-capture import {where} -o TAKES first, then {stage} TAKES"
    )


def is_weights_json(path: Path) -> bool:
    """Whether a JSON file looks like blendshape weights ``read_json_matrix`` reads: an Audio2Face
    export (the key ``"facsNames"`` or ``"weightMat"`` anywhere) or BEAT's face JSON (``"names"``, and
    ``"frames"`` whose first frame holds a list of ``"weights"``); reading it then says what else is
    wrong with it. The file is read a block at a time as UTF-8, or as UTF-16/UTF-32 when it starts with
    their byte-order mark (Windows' "Unicode" text, as ``read_json_matrix`` reads it)."""
    names = frame = False  # BEAT's marks met so far
    try:
        with open(path, "rb") as f:
            codec = bom_codec(f.read(4)) or "utf-8"
            f.seek(0)
            text = codecs.getincrementaldecoder(codec)(errors="replace")  # a character split across reads
            tail = ""
            while chunk := f.read(1 << 20):
                block = tail + text.decode(chunk)
                names = names or _BEAT_NAMES in block
                frame = frame or _BEAT_FRAME.search(block) is not None
                if any(mark in block for mark in _A2F_MARKS) or (names and frame):
                    return True
                tail = block[-_MARK_SPAN:]
    except OSError:
        return False
    return False


def folder_files(folder: Path) -> list[Path]:
    """The files of a folder, sorted (what ``audio_beside`` looks among), operating-system and transfer
    litter left out (a ``._X.wav`` is no audio), iCloud placeholders (``.X.wav.icloud``) kept."""
    return sorted(p for p in listed_files(folder) if not is_litter(p))


def audio_stem(source: Path) -> str:
    """The stem of the audio file that goes with a CSV or export: its own, less Audio2Face's
    ``_bsweight`` (``line01_bsweight.json`` goes with ``line01.wav``)."""
    return source.stem.removesuffix(A2F_SUFFIX) if source.suffix.lower() == ".json" else source.stem


def is_face_cap_text(path: Path) -> bool:
    """Whether a file is Face Cap's text export: a ``.txt`` whose first lines are its (``is_face_cap``).
    Only a file is read: a named pipe (``mkfifo notes.txt``) would wait for a writer for ever."""
    return path.suffix.lower() == ".txt" and path.is_file() and is_face_cap(_text_start(_head(path)))


class _AudioIn(NamedTuple):
    """What ``audio_beside`` looks at in a folder (``_audio_in``)."""

    audio: list[Path]  # the audio files (no iCloud placeholder)
    waiting: dict[Path, str]  # the placeholders of audio iCloud has not downloaded -> the file each is
    stems: dict[Path, str]  # each of these two -> the stem (``_stem``) of the file it is
    alike: dict[str, list[Path]]  # ``stems``' paths by their stem in lower case, in the folder's order
    sources: dict[str, list[Path]]  # the CSVs and exports, by the ``audio_stem`` of each (NFC) in lower case
    no_file: dict[str, list[Path]]  # entries named as audio that are no file (a link to nothing, a folder),
    # by their stem (``_stem``) in lower case


@once_per_listing
def _audio_in(folder: Path) -> _AudioIn:
    """What ``audio_beside`` looks at among the files of ``folder`` (``folder_files``), found once
    within ``listed_once``: each source or audio file's stem is read there once, not once per source
    beside it (1,000 CSVs beside their audio took 2.3 s)."""
    files = folder_files(folder)
    waiting = {}
    for p in files:
        original = not_downloaded(p)
        if original is not None and Path(original).suffix.lower() in AUDIO_SUFFIXES:
            waiting[p] = original
    audio = [p for p in files if p.suffix.lower() in AUDIO_SUFFIXES and icloud_original(p) is None]
    stems = {p: _stem(p.name) for p in audio} | {p: _stem(name) for p, name in waiting.items()}
    alike: dict[str, list[Path]] = {}
    for p, stem in stems.items():
        alike.setdefault(stem.lower(), []).append(p)
    sources: dict[str, list[Path]] = {}
    for p in files:
        if p.suffix.lower() in (".csv", ".json") or is_face_cap_text(p):
            sources.setdefault(nfc(audio_stem(p)).lower(), []).append(p)
    listed = set(files)
    no_file: dict[str, list[Path]] = {}
    for p in listed_entries(folder):
        if p.suffix.lower() in AUDIO_SUFFIXES and p not in listed and not is_litter(p):
            no_file.setdefault(_stem(p.name).lower(), []).append(p)
    return _AudioIn(audio, waiting, stems, alike, sources, no_file)


def _stem(name: str) -> str:
    """The stem of a file name, in NFC (``nfc``): as the names of a source and its audio are compared."""
    return nfc(Path(name).stem)


def audio_beside(source: Path) -> tuple[Path | None, str | None]:
    """The audio file that goes with a CSV or export: the one of the same stem (an Audio2Face export's
    without ``_bsweight``; stems compared in Unicode NFC, and in another case when none is alike: a copy
    that changed it), else the only audio file in its folder (``folder_files`` of it, listed once within
    ``listed_once``; litter such as ``._X.wav`` is never audio). An audio file named for another CSV or
    export beside it (in any case; a Face Cap text export too) is not this one's, nor is a hidden one
    (``.X.wav``, a program's temporary file) the only one; an entry of its stem that is no file (a
    symbolic link to nothing) is not passed over for another. Returns (path or None, why none was taken
    when that is worth a warning). An iCloud placeholder of the audio (``.X.wav.icloud``) is an
    ``InputError``: the pair is never imported without its audio. A placeholder counts as the file it
    stands for: the one of the same stem, the only audio beside the source, or, when all the audio
    beside it is placeholders, any of them is that error."""
    beside = _audio_in(source.parent)
    waiting = beside.waiting
    stems = {nfc(source.stem), nfc(audio_stem(source))}
    folded = {s.lower() for s in stems}  # lower(), as the take folder reader: not casefold() (see _the_one)

    def owner(stem: str) -> Path | None:
        """The other CSV or export beside the source that an audio file of this stem is named for (in
        another case when none is named so exactly)."""
        named = [p for p in beside.sources.get(stem.lower(), []) if p.name != source.name]
        exact = [p for p in named if nfc(audio_stem(p)) == stem]
        return (exact or named or [None])[0]

    # in the folder's order (``stems``'): the audio files, then the placeholders, each sorted
    alike = sorted({p for s in folded for p in beside.alike.get(s, [])}, key=lambda p: (p in waiting, p))
    same = [p for p in alike if beside.stems[p] in stems]
    if not same:  # named so in another case (a copy that changed it), and for no other file beside it
        same = [p for p in alike if owner(beside.stems[p]) is None]
    for p in same:
        if p in waiting:
            raise icloud_error(p, source)
    if len(same) > 1:
        names = [p.name for p in same]
        listed = spellings(names) if len({nfc(n) for n in names}) == 1 else ", ".join(names)
        return None, f"several audio files named {source.stem}.*: {listed}"
    if same:
        return same[0], None
    unreadable = sorted(p for s in folded for p in beside.no_file.get(s, []))
    if unreadable:
        return None, f"{unreadable[0].name} beside it is no file (a symbolic link to nothing, or a folder)"
    if len(beside.stems) == 1:
        ((only, stem),) = beside.stems.items()
        name = waiting.get(only, only.name)
        if (other := owner(stem)) is not None:
            return None, f"the only audio file beside it, {name}, is named for {other.name}"
        if name.startswith("."):
            return None, f"the only audio file beside it, {name}, is hidden (a program's temporary file?)"
        if only in waiting:
            raise icloud_error(only, source)
        return only, None
    if not beside.audio:  # all placeholders: whichever of them is this source's audio is not downloaded
        free = sorted((name, p) for p, name in waiting.items() if owner(beside.stems[p]) is None)
        if free:
            raise icloud_error(free[0][1], source)
    if beside.stems:
        return None, f"{len(beside.stems)} audio files beside it and none named {source.stem}.*"
    return None, None


def is_livelink_csv(path: Path, head: bytes | None = None) -> bool:
    """Whether a CSV's first non-blank line starts like the app's header (``Timecode,BlendShapeCount``,
    any case; in UTF-8, or UTF-16 with its byte-order mark; also as a spreadsheet re-saves it: quoted,
    or with ';' or tabs between the fields); the Live Link Face reader then reads it or says what is
    wrong with it. ``head``: the file's ``_head``, when the caller has read it."""
    raw = _head(path) if head is None else head
    if raw is None:
        return True  # let the Live Link Face reader report it
    return app_header_separator(_first_line(raw)) is not None


def _text_start(raw: bytes | None) -> str:
    """A text file's first bytes (``_head``) as text, in UTF-8 or the codec its byte-order mark says."""
    return (raw or b"").decode(bom_codec(raw or b"") or "utf-8-sig", "replace")


def _first_line(raw: bytes | None) -> str:
    """The first non-blank line of a text file's first bytes (``_head``) ("" for none)."""
    return next((line for line in _text_start(raw).splitlines() if line.strip()), "")


def not_a_face_take(name: str, head: bytes | None) -> str | None:
    """Why a CSV named ``name`` whose first bytes (``_head``) are ``head`` is no face take (emotion
    weights: ``emotion_weights``; NeuroSync's audio features: ``neurosync_features``), or None."""
    header = header_names(_first_line(head))
    return emotion_weights(header) or neurosync_features(name, header)


def _head(path: Path, size: int = 1 << 16) -> bytes | None:
    """The first ``size`` bytes of a file, or None when it cannot be read."""
    try:
        with open(path, "rb") as f:
            return f.read(size)
    except OSError:
        return None


def import_source(
    source: Path,
    audio: str | Path | None = None,
    variant: str | None = None,
    strict: bool = False,
    swap_lr: bool = False,
    audio_pairing: str = "first-row",
    fps: float | None = None,
    timecode_rate: float | None = None,
    first_frame: int | None = None,
    value_scale: float | None = None,
    first_frame_strict: bool = True,
) -> Take:
    """One source (take folder or CSV file) as a take. ``audio_pairing`` (one of ``AUDIO_PAIRINGS``)
    says how external ``audio`` goes with a CSV's rows. ``timecode_rate``: the rate a Live Link Face
    CSV's FF field counts at (None: detected, see ``read_livelink_csv``). A CSV with audio whose header
    is not the app's is generic paired data (``read_paired``: a header of channel names, perhaps a time
    column; ``fps`` unless the file gives the rate; ``first_frame``, ``value_scale`` and
    ``first_frame_strict`` as there). A Live Link Face CSV without ``audio`` is read as its take when
    its folder reads it so or the ``.mov`` named as its take is beside it (``reads_as_take``): a take
    is never imported without the audio beside it. Under ``audio_left_in_files`` (``s2a-capture
    import``), recorded audio that libsndfile reads cleanly (WAV, FLAC, ...) is checked a block at a
    time and left in its file until ``write_take`` copies it."""
    if audio_pairing not in AUDIO_PAIRINGS:
        raise InputError(f"unknown audio pairing {audio_pairing!r} (known: {', '.join(AUDIO_PAIRINGS)})")
    if is_zip(source):
        raise zip_error(source)
    if a2f_root(source) is not None:  # a shot of an Audio2Face-3D training dataset, with the dataset's audio
        return read_a2f_shot(source, fps, audio)
    if icloud_original(source) is not None:
        raise icloud_error(source)
    if source.is_dir():
        if audio_pairing != "first-row":
            raise InputError(
                "--audio-pairing frame-index applies to a CSV with --audio, not a take folder", source
            )
        return read_take_folder(source, variant, audio, strict, swap_lr, timecode_rate)
    if source.suffix.lower() == ".json" and audio is not None:  # the export reader names a non-export
        return read_paired(
            audio, source, fps, None, source.stem, False, first_frame, value_scale, first_frame_strict
        )
    if source.suffix.lower() == ".json" and is_weights_json(source):
        raise InputError("blendshape weights in JSON need their audio (--audio, or --pair-audio)", source)
    head = _head(source)
    if source.suffix.lower() == ".txt" and is_face_cap(_text_start(head)):  # Face Cap's text export
        if audio is None:
            raise InputError("a Face Cap text export needs its audio (--audio, or --pair-audio)", source)
        return read_paired(
            audio, source, fps, None, source.stem, False, first_frame, value_scale, first_frame_strict
        )
    # named directly, a file of another suffix is read when its header is the app's (a .tsv, or Excel's
    # "Unicode Text" .txt: the reader then says what is wrong with it, as for a .csv)
    if source.suffix.lower() != ".csv" and (head is None or not is_livelink_csv(source, head)):
        raise InputError("not a Live Link Face CSV or take folder", source)
    if is_appledouble(source):
        raise InputError(
            "a macOS metadata file (AppleDouble, as Finder leaves as ._X beside copied files), not a take: "
            + (
                "import the file without the ._ in its name"
                if source.name.startswith("._")
                else "it was perhaps renamed from ._X or copied over X: import the CSV itself"
            ),
            source,
        )
    if (utf16 := utf16_csv_error(head or b"", source)) is not None:  # also without its byte-order mark
        raise utf16
    livelink = is_livelink_csv(source, head)
    if livelink and bom_codec(head or b""):
        raise InputError(  # utf16_csv_error (above) found no message of its own for it
            "a Live Link Face CSV saved as UTF-16 text: save it as UTF-8 (as the app writes it)", source
        )
    if not livelink:
        if head is not None and not head.strip():
            raise InputError("file is empty", source)
        why = not_a_face_take(source.name, head)
        if why is not None:
            raise InputError(why, source)
        if audio is None:
            raise InputError(
                "not a Live Link Face CSV (its header does not start with Timecode,BlendShapeCount), and "
                "as generic paired data it needs its audio (--audio, or --pair-audio)",
                source,
            )
        return read_paired(
            audio, source, fps, None, source.stem, False, first_frame, value_scale, first_frame_strict
        )
    with listed_once():  # its folder, looked at for its take's .mov and neutral pose, listed once
        if audio is not None:
            take = read_csv_with_audio(
                source, audio, strict, swap_lr, audio_pairing == "frame-index", timecode_rate
            )
        elif reads_as_take(source):  # named alone, as its take folder reads it: with the audio of its .mov
            return read_take_folder(source.parent, None, None, strict, swap_lr, timecode_rate, csv=source)
        else:
            take = read_livelink_csv(source, strict=strict, swap_lr=swap_lr, timecode_rate=timecode_rate)
        return with_neutral_beside(take, source)


def with_neutral_beside(take: Take, csv: Path) -> Take:
    """The take of a loose Live Link Face CSV with the calibrated rest pose of its take (``neutral``), as
    its take folder keeps it: the ``_neutral.csv`` named as its take beside it, if any (one iCloud has not
    downloaded is an error). A ``_neutral.csv`` read as a take has none."""
    prefix, variant = split_variant(csv.stem)
    neutral = None if variant == "neutral" else neutral_named_as(csv.parent, prefix)
    if neutral is not None:
        attach_neutral(take, neutral)
    return take
