"""``s2a-capture``: import takes, record them live from the phone (listen, recover, remote, replay),
simulate them, inspect them, write them back as Live Link Face CSV."""

from __future__ import annotations

import argparse
import collections
import sys
from pathlib import Path

from .atomic import batch_of_writes
from .audio_io import audio_left_in_files
from .channels import is_known
from .command import (
    StageParser,
    add_version,
    emit_json,
    emit_line,
    handle_stoppable,
    progress,
    run,
    sigterm_stops,
    warn,
)
from .csv_take import COUNT_NAMES, nonfinite_frames, split_variant, write_livelink_csv
from .errors import InputError, S2AError, printable
from .file_lock import another_writer, holding
from .import_guard import imports_done
from .importer import (
    AUDIO_PAIRINGS,
    audio_beside,
    find_sources,
    import_source,
    is_livelink_csv,
    warn_skipped,
)
from .live_cli import register as register_live
from .paired import read_paired
from .recorder import SESSION_SUFFIX
from .simulate.cli import register as register_simulate
from .take import (
    FrameStatus,
    Take,
    find_takes,
    is_take_dir,
    make_out_dir,
    read_meta,
    read_take,
    safe_id,
    write_take,
)
from .take_archive import (
    UNPACK_PREFIX,
    DriveDownload,
    Unpacked,
    clear_unpacked,
    drive_downloads,
    drive_part,
    unpacked,
)
from .take_folder import listed_once
from .timecode import CSV_TIMECODE_RATE, OTHER_TIMECODE_RATES
from .transfer_litter import Litter, is_zip

# The command's imports are done: Ctrl-C is its own from here (capture.import_guard).
_guard = imports_done("capture")

IMPORT_LOCK = ".import.lock"  # hidden: held (flock) by the one import writing into a folder

PROG = "s2a-capture"
TIMECODE_RATE_CHOICES = ("auto", *(f"{r:g}" for r in (*OTHER_TIMECODE_RATES, CSV_TIMECODE_RATE)))
# Repairs and notes that ask the user to act, printed as warnings by import (the others are counted in
# the summary and listed in meta.json): a timecode rate guessed or named, audio and frames of different
# lengths (a wrong --fps, or the audio of another take), a WAV cut short, a take folder without audio, a
# time column read as frame numbers or in a unit its name does not give, frame numbers read as counting
# from 1, weights on a 0..100 scale, --first-frame given for a file of a batch without a frame-number
# column, a CSV's last row cut short, most of a CSV's frames without values or many of its rows without
# a timecode (a file read wrongly), a column named like a channel the CSV lacks (a typo), channel values
# no face makes (a typing slip), a channel left out for having no value on any row; and what may move the
# sound against the face or changed what is heard: damaged audio mended (silence in place of lost MP3
# frames, perhaps shifting the sound after it), an encoder delay the file does not record, a channel
# count changing mid-stream (files joined).
WARN_REPAIRS = (
    "timecode_rate",
    "length_mismatch",
    "truncated_audio",
    "unfinished_audio",
    "no_audio",
    "frame_numbers",
    "time_unit",
    "frame_numbers_from_1",
    "percent_scale",
    "first_frame_ignored",
    "truncated_row",
    "bad_values_widespread",
    "bad_timecodes_widespread",
    "channel_typo",
    "channel_affix",
    "value_range",
    "empty_channel",
    "bad_audio",
    "encoder_delay_unknown",
    "channels_changed",
)
# What a warning adds to a repair's message: what the user may have to do about it.
WARN_HINTS = {"truncated_row": "an incomplete copy or download? Copy or download the file again"}


def build_parser() -> argparse.ArgumentParser:
    parser = StageParser(prog=PROG, description=__doc__)
    add_version(parser)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser(
        "import",
        help="Live Link Face CSVs, take folders or generic paired data -> take folders",
        description="Import Live Link Face CSV files and take folders (folders are searched "
        "recursively), or one generic paired take (--matrix with --audio, --names, --fps).",
    )
    p.add_argument("sources", nargs="*", type=Path, help="CSV files, take folders, or folders of them")
    p.add_argument("-o", "--out", type=Path, required=True, help="folder to write the takes into")
    p.add_argument(
        "--audio", metavar="FILE", type=Path, help="audio recorded elsewhere (WAV/FLAC/MP3/M4A) for one CSV"
    )
    p.add_argument(
        "--pair-audio",
        action="store_true",
        help="pair each CSV found (and each Audio2Face .json export) with the audio beside it: the file "
        "of the same stem, else the only audio file in its folder (batches of paired data, e.g. NeuroSync's "
        "folders of audio.wav + CSV: add --audio-pairing frame-index; CSVs of other generators: their "
        "header names the channels, a time column or --fps the rate)",
    )
    p.add_argument(
        "--matrix",
        metavar="FILE",
        type=Path,
        help="generic import: frames x channels weights (.npy, .npz, .csv, or an Audio2Face or BEAT .json)",
    )
    p.add_argument(
        "--names",
        metavar="FILE",
        type=Path,
        help="generic import: channel names (.txt one per line, a .json list, or .npy)",
    )
    p.add_argument("--fps", type=float, help="generic import: frame rate (a .json gives its own)")
    p.add_argument(
        "--first-frame",
        type=int,
        help="generic import: the number, in a frame-number column, of the frame at the audio's start "
        "(default: 1 when the column starts at 1, as timelines of Maya, Blender or iClone do, else 0)",
    )
    p.add_argument(
        "--value-scale",
        type=float,
        help="generic import: multiply the weights by this (0.01 for weights on a 0..100 scale)",
    )
    p.add_argument("--id", metavar="ID", dest="take_id", help="take id (default: from the source's name)")
    p.add_argument(
        "--variant",
        choices=("cal", "raw", "plain"),
        help="which CSV of a calibrated take (its folder, or its loose CSVs) to import (default: cal, else "
        "plain, else raw)",
    )
    p.add_argument(
        "--audio-pairing",
        choices=AUDIO_PAIRINGS,
        default="first-row",
        help="how --audio goes with a CSV's rows: first-row (default: the audio starts with the first row; "
        "s2a-align measures the real offset and places frames by their timecodes) or frame-index (row i "
        "goes with audio time i/fps, as in data sets built that way, e.g. NeuroSync's; s2a-align then "
        "places frames by index)",
    )
    p.add_argument(
        "--timecode-rate",
        choices=TIMECODE_RATE_CHOICES,
        default="auto",
        help="the rate a Live Link Face CSV's timecode frames (FF) count at: 60 for the app; auto (default) "
        "also recognises other writers of the format counting at 24/25/30/48/50 fps (with a warning)",
    )
    p.add_argument("--swap-lr", action="store_true", help="exchange JawLeft/Right and MouthLeft/Right labels")
    p.add_argument(
        "--strict",
        action="store_true",
        help="refuse files that need any repair (and archives read short: a Drive part missing or cut, "
        "a zip whose directory is damaged)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON summary line per take")
    p.set_defaults(handler=cmd_import)

    p = sub.add_parser("info", help="frames, rate, drops, face-lost frames and audio of takes")
    p.add_argument(
        "takes",
        nargs="+",
        type=Path,
        help="take folders (ours or the app's), CSV files, or folders or zip archives of them",
    )
    p.add_argument("--json", action="store_true", help="one JSON object per take")
    p.set_defaults(handler=cmd_info)

    p = sub.add_parser(
        "export-csv",
        help="write a take's Live Link channels in the Live Link Face CSV format (a rig's own controls are "
        "left out, with a warning; a take holding none of the 61 channels is refused)",
    )
    p.add_argument("take", type=Path, help="a take folder")
    p.add_argument("-o", "--out", type=Path, required=True, help="CSV file to write (folders are created)")
    p.add_argument(
        "--count-name",
        choices=COUNT_NAMES,
        help="spelling of the second header column (default: as in the source)",
    )
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(handler=cmd_export_csv)
    # Subcommands of other capture modules register themselves here: module.register(sub).
    register_live(sub)
    register_simulate(sub)
    return parser


def _print_summary(summary: dict, as_json: bool) -> None:
    if as_json:
        emit_json(summary)
        return
    lines = [f"{summary['id']}:"]
    for key, value in summary.items():
        if key != "id" and value is not None:
            lines.append(f"  {key:18s} {value}")
    emit_line("\n".join(lines))


def _of_variant(sources: list[Path], variant: str, box: Unpacked | None = None) -> list[Path]:
    """``--variant`` among loose Live Link Face CSVs (take folders choose their own CSV; generic paired
    data has no variants): one of another variant of its take, by its name (``X_cal.csv`` for
    ``--variant raw``; ``X.csv`` is the plain one), is left out with a warning. ``box``: the archive
    the sources were unpacked from, to name them by."""
    kept = []
    for src in sources:
        own = split_variant(src.stem)[1] or "plain"  # what the name says; read the file only if it differs
        if own == variant or src.suffix.lower() != ".csv" or not is_livelink_csv(src):
            kept.append(src)
        else:
            shown = box.shown(src) if box else src
            warn(f"{shown}: the {own} CSV of its take, not --variant {variant}: skipped")
    if sources and not kept:
        raise InputError(f"no {variant} CSV among the sources (--variant {variant})")
    return kept


def cmd_import(args: argparse.Namespace) -> int:
    if args.pair_audio and (args.audio is not None or args.matrix is not None):
        raise InputError("--pair-audio finds each source's audio: give neither --audio nor --matrix with it")
    if (
        args.audio_pairing != "first-row"
        and not args.pair_audio
        and (args.audio is None or args.matrix is not None)
    ):
        raise InputError("--audio-pairing goes with a CSV and its --audio (or --pair-audio)")
    timecode_rate = None if args.timecode_rate == "auto" else float(args.timecode_rate)
    litter = Litter()  # what the folders and archives held that is no take, said once at the end
    try:
        # SIGTERM stops it as Ctrl-C does (exit 143): the audio decoded into the output folder, what was
        # unpacked there and the folder's lock go with it, not left until the next import
        with sigterm_stops(), listed_once():  # each folder listed once for the run
            return _import_jobs(args, timecode_rate, litter)
    finally:
        for line in litter.lines():
            warn(line)


def _import_jobs(args: argparse.Namespace, timecode_rate: float | None, litter: Litter) -> int:
    # the options of generic paired data given, and why a Live Link Face take ignores each
    generic = {
        flag: why
        for flag, value, why in (
            ("--fps", args.fps, "has its own timecodes"),
            ("--first-frame", args.first_frame, "has its own timecodes"),
            ("--value-scale", args.value_scale, "holds weights on the app's 0..1 scale"),
        )
        if value is not None
    }
    if args.matrix is not None:
        if args.sources:
            raise InputError("give either sources or --matrix, not both")
        if timecode_rate is not None:
            raise InputError("--timecode-rate applies to Live Link Face CSVs, not to --matrix")
        if args.audio is None:
            raise InputError(
                "--matrix needs --audio, and --fps and --names unless the file gives them (a CSV header "
                "with a time column, an Audio2Face .json export)"
            )
        jobs = [("matrix", args.matrix)]
    else:
        if not args.sources:
            raise InputError("nothing to import: name CSV files or take folders, or use --matrix")
        if args.names is not None:
            raise InputError("--names only applies to a generic import with --matrix")
        if generic and not (args.pair_audio or args.audio is not None):
            raise InputError(
                f"{next(iter(generic))} only applies to generic paired data (--matrix, or CSVs with audio)"
            )
        sources = find_sources(
            args.sources, exports=args.pair_audio, litter=litter, archives=True, variant=args.variant
        )
        if args.variant is not None:
            sources = _of_variant(sources, args.variant)
        if not sources:
            raise InputError(
                f"no Live Link Face CSV or take folder under {', '.join(map(str, args.sources))}"
            )
        sources = drive_downloads(sources)  # the parts of a Google Drive download: one archive
        if args.audio is not None and len(sources) != 1:
            raise InputError(f"--audio pairs with one source, but {len(sources)} were found")
        if args.audio is not None and _is_archive(sources[0]):
            raise InputError("--audio pairs with a CSV or take folder, not a zip archive", sources[0])
        if args.take_id and len(sources) != 1:
            raise InputError("--id names one take, but several sources were found")
        jobs = [("archive" if _is_archive(s) else "source", s) for s in sources]
    out = make_out_dir(args.out)
    if (out / "manifest.json").exists():  # the dataset stage's (which capture may not import)
        raise InputError(
            "is a dataset folder (it holds manifest.json): import takes into a folder of their own", out
        )

    # One import at a time into a folder (two at once each took the same free ids and overwrote each
    # other's takes); the folder is listed once for leftovers of killed writes, not once per take.
    with (
        holding(out / IMPORT_LOCK, another_writer("s2a-capture import", out), optional=True) as alone,
        batch_of_writes(out),
    ):
        if alone:  # without the lock, another import may be reading what it unpacked
            clear_unpacked(out)  # archives a killed import left unpacked
        importer = _Importer(args, generic, timecode_rate, litter)
        failures = sum(
            importer.archive(src) if kind == "archive" else not importer.one(kind, src) for kind, src in jobs
        )
        if failures > 1:  # a batch's errors, one per file, may be one mistake (no --fps for 200 CSVs)
            reason, count = importer.reasons.most_common(1)[0]
            common = f"; {count} of them: {reason}" if count > 1 else ""
            print(printable(f"{PROG}: {failures} sources failed{common}"), file=sys.stderr)
        return 1 if failures else 0


def _is_archive(source: Path | DriveDownload) -> bool:
    return isinstance(source, DriveDownload) or is_zip(source)


def _lone_part(source: Path | DriveDownload) -> str:
    """Why an archive holds no take, if it is one part of a Google Drive download given alone."""
    lone = isinstance(source, Path) and is_zip(source) and drive_part(source)
    return " (one part of a Google Drive download: give it with its other parts)" if lone else ""


class _Importer:
    """Imports jobs into ``args.out``, each source given a take id no other of the run has."""

    def __init__(
        self, args: argparse.Namespace, generic: dict[str, str], timecode_rate: float | None, litter: Litter
    ) -> None:
        self.args, self.generic, self.timecode_rate, self.litter = args, generic, timecode_rate, litter
        self.written: dict[str, Path] = {}  # folder name (case-folded) -> source, for this run
        self.reasons: collections.Counter[str] = collections.Counter()  # of the sources that failed

    def _failed(self, src: Path | str, exc: S2AError, box: Unpacked | None = None) -> None:
        shown = box.shown(exc) if box else str(exc)
        print(printable(f"{PROG}: error: {shown}"), file=sys.stderr)
        self.reasons[getattr(exc, "reason", None) or str(exc)] += 1
        if self.args.json:
            emit_json({"source": str(src), "error": shown})

    def archive(self, archive: Path | DriveDownload, outer: Unpacked | None = None) -> int:
        """Import the takes a zip archive (or the parts of a Google Drive download) holds (and those of
        the archives in it, one level down: a download of a folder of zipped takes), unpacked into the
        output folder meanwhile; the number that failed (1 when the archive itself cannot be read).
        ``outer``: the archive it is in."""
        args = self.args
        name = outer.shown(archive) if outer else str(archive)
        if isinstance(archive, DriveDownload) and (missing := archive.missing()):
            some = len(missing) > 1 or "-" in missing[0]
            absent = (
                f"part{'s' if some else ''} {', '.join(missing)} of this Google Drive download "
                f"{'are' if some else 'is'} not beside them"
            )
            if args.strict:
                self._failed(name, InputError(f"{absent}; --strict refuses an archive read short", name))
                return 1
            warn(
                f"{name}: {absent}: a take with files in {'them' if some else 'it'} is imported without "
                f"those (download {'them' if some else 'it'} and import all the parts again)"
            )
        try:
            with unpacked(archive, args.out, self.litter, outer, strict=args.strict) as box:
                sources = find_sources(
                    [box.folder],
                    exports=args.pair_audio,
                    litter=self.litter,
                    skipped=lambda path, why: warn_skipped(Path(box.shown(path)), why),
                    archives=box.unpacks_archives,
                    variant=args.variant,
                )
                if args.variant is not None:
                    sources = _of_variant(sources, args.variant, box)
                if not sources:
                    ours = find_takes([box.folder])
                    why = " (it holds takes imported already: unzip it where you keep takes)" if ours else ""
                    why = why or _lone_part(archive)
                    raise InputError(f"holds no Live Link Face CSV or take folder{why}", name)
                if args.take_id and len(sources) != 1:
                    raise InputError(f"--id names one take, but the archive holds {len(sources)}", name)
                progress(f"{name}: {len(sources)} source{'s' if len(sources) > 1 else ''} unpacked")
                return sum(
                    self.archive(src, box) if _is_archive(src) else not self.one("source", src, box)
                    for src in drive_downloads(sources)
                )
        except S2AError as exc:
            self._failed(name, exc)
            return 1

    def one(self, kind: str, src: Path, box: Unpacked | None = None) -> bool:
        """Import one job (a source, or the matrix of a generic import); whether it was written. ``box``:
        the archive ``src`` was unpacked from, to name it and its files by."""
        args, generic, timecode_rate = self.args, self.generic, self.timecode_rate
        shown = box.shown(src) if box else src
        try:
            # recorded audio that libsndfile reads cleanly stays in its file until write_take copies it;
            # what FFmpeg decodes waits in a scratch file in the output folder (where the take is written:
            # room for it, not a small /tmp), removed when this block ends, however it ends; a kill
            # leaves it to the next import's clear_unpacked, as an archive unpacked there
            with audio_left_in_files(args.out, f"{UNPACK_PREFIX}audio-"):
                if kind == "matrix":
                    take = read_paired(
                        args.audio,
                        args.matrix,
                        args.fps,
                        args.names,
                        args.take_id,
                        first_frame=args.first_frame,
                        value_scale=args.value_scale,
                    )
                else:
                    audio, pairing = args.audio, args.audio_pairing
                    if args.pair_audio:  # loose files get the audio beside them; take folders have their own
                        audio, why = audio_beside(src) if src.is_file() else (None, None)
                        pairing = args.audio_pairing if audio is not None else "first-row"
                        if why:
                            warn(f"{shown}: {why}: imported without audio")
                    take = import_source(
                        src,
                        audio,
                        args.variant,
                        args.strict,
                        args.swap_lr,
                        pairing,
                        args.fps,
                        timecode_rate,
                        first_frame=args.first_frame,
                        value_scale=args.value_scale,
                        first_frame_strict=not args.pair_audio,
                    )
                    for flag, why in generic.items() if take.meta.source_kind != "paired_matrix" else ():
                        warn(f"{shown}: {flag} ignored: a Live Link Face take {why}")
                    if not args.pair_audio and audio is None and take.audio is None and src.is_file():
                        _say_audio_not_paired(src, shown)
                    if args.take_id:
                        take.meta.id = args.take_id
                if box:
                    box.rename_files(take)
                _unique_id(take, shown, self.written, args.out)
                folder = write_take(take, args.out)
        except S2AError as exc:
            self._failed(shown, exc, box)
            return False
        for repair in take.meta.repairs:
            if repair["kind"] in WARN_REPAIRS:
                hint = f" ({WARN_HINTS[repair['kind']]})" if repair["kind"] in WARN_HINTS else ""
                warn(f"{shown}: {repair['message']}{hint}")
        summary = take.summary() | {"path": str(folder), "source": str(shown)}
        if args.json:
            emit_json(summary)
        else:
            progress(
                f"{shown} -> {folder}: {summary['frames']} frames at {summary['fps']:g} fps: "
                f"{summary['valid_frames']} valid, {summary['bad_value_frames']} bad-value, "
                f"{summary['dropped_frames']} dropped, {summary['face_lost_frames']} face-lost; "
                f"{summary['repairs']} repairs"
            )
        return True


def _say_audio_not_paired(src: Path, shown: Path | str) -> None:
    """Warn that a CSV imported without audio has an audio file beside it that ``--pair-audio`` would
    pair with it (``audio_beside``): a take without audio cannot be aligned, and nothing said why."""
    try:
        beside, _ = audio_beside(src)
    except S2AError:  # an iCloud placeholder of it: --pair-audio says so
        return
    if beside is not None:
        warn(f"{shown}: {beside.name} beside it is not used: add --pair-audio to import it with its audio")


def _unique_id(take: Take, src: Path, written: dict[str, Path], out: Path) -> None:
    """Give ``take`` an id no other source of this run has (folder names compared case-insensitively,
    as on macOS and Windows) and no folder in ``out`` holds but an earlier import of the same source
    (which is replaced): ``<id>-2``, ``<id>-3``, ... recorded as repair ``renamed_id``."""
    base = safe_id(take.meta.id)
    name, n = base, 1
    while name.casefold() in written or _occupant(out / name, take):
        n += 1
        name = safe_id(f"{base}-{n}")
    if name != base:
        other = written.get(base.casefold())
        holder = (
            f"the id of {other} in this import"
            if other
            else f"taken in {out} by {_occupant(out / base, take)}"
        )
        message = f"take id {base!r} is {holder}: written as {name!r}"
        take.meta.repairs.append({"line": None, "kind": "renamed_id", "message": message})
        warn(f"{src}: {message}")
        take.meta.id = name
    _say_if_replaced(out / name, take, src)
    written[name.casefold()] = src


def _say_if_replaced(folder: Path, take: Take, src: Path) -> None:
    """Warn when ``take`` replaces an earlier import of the same source whose contents have changed
    since (an identical re-import replaces it without a word: the same bytes)."""
    try:
        before = read_meta(folder).sources if folder.exists() else []
    except S2AError:
        return
    now = take.meta.sources
    if before and now and before[0].path == now[0].path and before[0].sha256 != now[0].sha256:
        warn(f"{src}: replaces {folder}, imported from it before its contents changed")


def _occupant(folder: Path, take: Take) -> str | None:
    """What ``folder`` holds that importing ``take`` must not replace: a take imported from another
    source, or anything that is not a take. None when ``folder`` is free or holds an earlier import of
    the same source (compared by their first source file: the CSV or matrix)."""
    if not folder.exists():
        return None
    try:
        meta = read_meta(folder)
    except S2AError:
        return "something that is not a take"
    if meta.source_kind == "aligned":  # made by s2a-align from such an import: never replaced by one
        return "an aligned take"
    sources = meta.sources
    before = sources[0].path if sources else None
    if take.meta.sources and take.meta.sources[0].path == before:
        return None
    return f"the take imported from {before}" if before else "a take of unknown source"


def _load_for_info(path: Path | DriveDownload, litter: Litter, outer: Unpacked | None = None) -> list[Take]:
    """The takes ``path`` holds: a take of ours, a folder of them, recordings to import, zip archives of
    any of these (and the archives in them, as import reads them; the parts of a Google Drive download
    as one); ``outer``: the archive ``path`` was unpacked from."""
    if not _is_archive(path):
        return _takes_in(path, litter, outer)
    with unpacked(path, litter=litter, outer=outer) as box:
        try:
            return _takes_in(box.folder, litter, box)
        except S2AError as exc:
            raise InputError(box.shown(exc)) from None


def _takes_in(path: Path, litter: Litter, box: Unpacked | None) -> list[Take]:
    if is_take_dir(path):
        return [read_take(path)]
    if path.is_dir():
        takes = find_takes([path])
        if takes:
            return [read_take(t) for t in takes]
    sources = find_sources(
        [path],
        litter=litter,
        archives=box is None or box.unpacks_archives,
        skipped=lambda p, why: warn_skipped(Path(box.shown(p) if box else p), why),
    )
    return [
        t
        for s in drive_downloads(sources)
        for t in (_load_for_info(s, litter, box) if _is_archive(s) else [import_source(s)])
    ]


def cmd_info(args: argparse.Namespace) -> int:
    litter = Litter()  # what the folders held that is no take, said once at the end
    try:
        for path in drive_downloads(args.takes):  # the parts of a Google Drive download: one archive
            # ``info live/*`` meets the logs
            if isinstance(path, Path) and path.is_dir() and path.name.endswith(SESSION_SUFFIX):
                why = "is a listen session's log folder, not a take: its takes are written beside it"
                if len(args.takes) == 1:
                    raise InputError(f"{why} (s2a-capture recover {path} rebuilds them)", path)
                warn_skipped(path, why)
                continue
            takes = _load_for_info(path, litter)
            if not takes:
                raise InputError(f"no takes found{_lone_part(path)}", path)
            for take in takes:
                _print_summary(take.summary() | {"path": str(path)}, args.json)
    finally:
        for line in litter.lines():
            warn(line)
    return 0


def cmd_export_csv(args: argparse.Namespace) -> int:
    if args.take.is_file():
        raise InputError("is a file, not a take folder (import it first: s2a-capture import)", args.take)
    take = read_take(args.take, audio=False)
    if args.out.is_dir():
        raise InputError("is a folder: give the name of the CSV file to write", args.out)
    into = (
        next((p for p in args.out.resolve().parents if is_take_dir(p)), None) if args.out.is_file() else None
    )
    if into is not None:  # its audio (or frames) replaced by the CSV
        raise InputError(f"is a file of the take {into}: give -o outside any take", args.out)
    others = [c for c in take.meta.channels if not is_known(c)]
    shown = ", ".join(others[:3]) + (", ..." if len(others) > 3 else "")
    if len(others) == len(take.meta.channels):
        raise InputError(
            f"take {take.meta.id} holds none of the 61 Live Link Face channels (its {len(others)} channels "
            f"are a rig's own controls: {shown}): a Live Link Face CSV of it would hold only zeros",
            args.take,
        )
    try:
        make_out_dir(args.out.parent)
        out = write_livelink_csv(take, args.out, count_name=args.count_name)
    except OSError as exc:
        raise InputError(f"cannot write the CSV: {exc.strerror or exc}", args.out) from None
    rows = int((take.frame_status != FrameStatus.DROPPED).sum())
    bad = int(nonfinite_frames(take).sum())
    if bad:
        warn(f"{take.meta.id}: {bad} frames with NaN/inf values written as face-lost rows")
    if others:
        warn(
            f"{take.meta.id}: {len(others)} of its {len(take.meta.channels)} channels are not Live "
            f"Link Face channels and are left out of the CSV ({shown})"
        )
    summary = {
        "id": take.meta.id,
        "path": str(out),
        "rows": rows,
        "nonfinite_rows": bad,
        "channels_left_out": len(others),
    }
    if args.json:
        emit_json(summary)
    else:
        progress(f"{take.meta.id} -> {out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run(PROG, build_parser, handle_stoppable, argv)


if __name__ == "__main__":
    sys.exit(main())
