"""What a ``TAKE_OR_CSV`` argument of ``s2a-view`` names: exactly one take, read with what went wrong said.

A folder holding several takes is an error (never one of them picked silently); the Live Link Face CSV
variants of one take (``_cal``, ``_raw``, ``_neutral``) count as that one take. What the CSV reader
repaired (rows dropped, cells set to NaN) comes back as warnings. Values no face can take, NaN,
infinite or beyond ±``ABSURD`` (no blendshape weight nor angle in radians is), are bad values.
Blendshape weights outside ``0..1`` (ARKit itself reaches 1.05) are clamped for the face and counted.
A take whose audio was paired by frame index (``s2a-capture import --audio-pairing frame-index``: row i
goes with audio time i/fps) is shown on that clock, as ``s2a-align`` places it, not by its timecodes,
which run 0.16 % slow against it in a Live Link Face CSV (32 ms over 20 s).

A zip archive holding one take (a take folder zipped by Finder or Windows Explorer, a zipped CSV with
its audio) is read as that take unzipped: ``takes.zip``; one take of an archive holding several is named
by its path inside, ``takes.zip/TakeName``. The archive is unpacked by capture's reader
(``capture.take_archive``: the same checks as ``s2a-capture import``) into the system's temporary
folder, never beside the archive, and removed when the command ends (``archives_unpacked``), on an
error, Ctrl-C or SIGTERM too. Of an archive whose member is named, only what that member needs is
unpacked (``members_needed``: an archive of a day's takes holds gigabytes of ``.mov``), and of any
archive, a take's ``.wav`` beside its ``.mov`` only when the ``.mov`` holds no audio track, as the take
reader then reads it (``_wavs_held_back``). Names of one take's files are matched in Unicode NFC, as
the take reader matches them (a Mac writes them decomposed). Messages name the archive's members
(``takes.zip/T/T.csv``), never the temporary copies.
"""

from __future__ import annotations

import atexit
import os
import re
import shutil
import tempfile
from collections.abc import Iterator, Sequence
from contextlib import ExitStack, contextmanager
from pathlib import Path, PurePosixPath

import numpy as np

from capture import Take, find_sources, find_takes, import_source, is_take_folder, read_audio, read_take
from capture.channels import ARKIT52, canonical, is_known
from capture.command import stops_deferred
from capture.csv_take import split_variant
from capture.errors import InputError, S2AError, first_few
from capture.importer import AUDIO_SUFFIXES, audio_beside, audio_stem, is_livelink_csv, warn_skipped
from capture.mov import probe_mov
from capture.paired import NoFrameRate
from capture.take import FrameStatus, is_take_dir
from capture.take_archive import (
    MAX_DEPTH,
    UNPACK_PREFIX,
    DriveDownload,
    Member,
    Unpacked,
    drive_downloads,
    drive_part,
    unpacked,
)
from capture.take_folder import choose_csv, nfc, reads_as_take, takes_side_by_side
from capture.transfer_litter import Litter, icloud_original, is_zip
from capture.workers import process_runs
from dataset.qa import ANIM_LIMIT

ABSURD = ANIM_LIMIT  # |value| above this is no blendshape weight nor angle in radians
# Repairs that change nothing a viewer shows: not worth a warning.
_QUIET_REPAIRS = ("bom", "no_audio")
_BLENDSHAPES = frozenset(ARKIT52)


def take_source(path: str | Path, one_take: str, shown: str | None = None) -> Path:
    """The take folder, Live Link Face take folder, folder of one take's CSVs or CSV file ``path``
    names. ``one_take`` opens the error for a folder holding several takes (``"render shows one take
    per input"``), which lists them and says how to name one; ``shown``: what the user called ``path``
    when that is not its name here (``takes.zip`` for the folder an archive was unpacked into)."""
    path = Path(path)
    if is_take_dir(path) or path.is_file():
        return path
    if not path.is_dir():
        raise InputError(_missing_take(path), path)
    if is_take_folder(path) and not takes_side_by_side(path):  # several takes side by side: listed below
        return path
    found = [(f"{p.relative_to(path)}/", p) for p in find_takes([path])]
    groups: dict[tuple[Path, str], tuple[str, Path]] = {}
    archives: list[str] = []  # zip archives in the folder, which are takes only when named
    skipped = warn_skipped if shown is None else lambda p, why: archives.append(str(p.relative_to(path)))
    for src in find_sources([path], skipped=skipped):  # Live Link Face take folders and CSVs, not ours
        if src.is_dir():
            groups[(src, "")] = (f"{src.relative_to(path)}/", src)
            continue
        prefix, variant = split_variant(src.stem)
        if variant != "neutral":  # a neutral pose goes with its take: no take of its own
            # The folder, not the file: the take folder reader picks the variant and the audio beside it.
            groups.setdefault((src.parent, prefix.lower()), (str(src.relative_to(path)), src.parent))
    found += groups.values()
    names = [name for name, _ in found] or [a for a in archives if a.lower().endswith(".zip")]
    if not found and not names:
        raise InputError("holds no take folder or Live Link Face CSV", path)
    if len(found) == 1:
        return found[0][1]
    shown_names = first_few(names)
    if not found:  # archives in an archive: each is named as a path into the outer one
        raise InputError(
            f"holds no take of its own, but {len(names)} zip archive(s) ({shown_names}): name one "
            f"as {shown}/{names[0]}",
            path,
        )
    how = "name one of them" + (f" as {shown}/{names[0].rstrip('/')}" if shown else "")
    raise InputError(f"{one_take}; found {len(found)} takes under it ({shown_names}): {how}", path)


def _missing_take(path: Path) -> str:
    """Why ``path``, which does not exist, names no take: a take align cut into segments is only its
    segments (``ID.seg01``, ``ID.seg02``), which are named."""
    from align.batch import SEGMENT_SUFFIX  # align's imports only for this message

    try:
        segment = re.compile(re.escape(path.name) + SEGMENT_SUFFIX)
        segments = sorted(p.name for p in path.parent.iterdir() if segment.fullmatch(p.name))
    except OSError:  # no such parent folder either
        segments = []
    if not segments:
        return "no such take folder or CSV file"
    shown = first_few(segments, 3)
    return f"no such take folder: align cut this take into {len(segments)} segment(s) ({shown}): name one"


def read_input(
    path: str | Path, one_take: str, audio: str | Path | None = None, audio_flag: str | None = "--audio"
) -> tuple[Take, list[str], Path | None]:
    """The one take ``path`` names (see ``take_source``; a zip archive of one take, or
    ``ARCHIVE.zip/member`` naming one take in it, as that take unzipped: ``unpacked_input``), with
    ``audio`` as its speech, warnings about what reading it repaired (one line each), and the file its
    speech was read from (None: silent). ``audio_flag`` is the option that gives a CSV its audio here
    (``None``: none does), for the message about a CSV that needs it. A CSV named without ``audio``
    brings the audio beside it (``csv_with_its_audio``), as naming its folder does.

    Audio holding NaN or infinite samples is an ``InputError`` (as ``s2a-train predict`` refuses it),
    never silence in its place. Called outside ``archives_unpacked``, an archive is unpacked for this
    call only: the take returned holds its values and audio, but no file of it remains to be read."""
    if not _sessions:
        with archives_unpacked():
            return read_input(path, one_take, audio, audio_flag)
    place = unpacked_input(path)
    if place is None:
        return _read_source(path, take_source(path, one_take), audio, audio_flag)
    folder, name = place
    try:
        take, warnings, speech = _read_source(folder, take_source(folder, one_take, name), audio, audio_flag)
    except S2AError as exc:
        raise InputError(shown(exc)) from None
    return take, [shown(w) for w in warnings], Path(shown(speech)) if speech is not None else None


def _read_source(
    path: str | Path, src: Path, audio: str | Path | None, audio_flag: str | None
) -> tuple[Take, list[str], Path | None]:
    """``read_input`` of ``src``, the take source ``path`` names."""
    if is_take_dir(src):
        take = read_take(src, audio=audio is None)
        if audio is not None:
            # without a repair list, NaN samples are an error
            take.attach_audio(read_audio(audio), *replaced_speech_start(take))
            return on_audio_clock(take), [], Path(audio)
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


class _Session:
    """The archives one command unpacked, removed together when it ends."""

    def __init__(self) -> None:
        self.stack = ExitStack()
        self.boxes: list[Unpacked] = []
        self.pid = os.getpid()  # a forked child inherits the session, not what it unpacked


_sessions: list[_Session] = []  # innermost last; the CLI holds one open while a command runs


@contextmanager
def archives_unpacked() -> Iterator[None]:
    """While the block runs, archives named as inputs (``read_input``, ``unpacked_input``) stay
    unpacked (a render reads a take's reference video frame by frame); on leaving, also by an error,
    Ctrl-C or SIGTERM, their unpacked files are removed, with Ctrl-C and SIGTERM held off meanwhile
    (a second Ctrl-C would otherwise leave them half removed)."""
    session = _Session()
    _sessions.append(session)
    _clear_orphans()
    try:
        yield
    finally:
        _sessions.remove(session)
        if session.pid == os.getpid():  # a forked child leaving the block: the files are its parent's
            with stops_deferred():
                session.stack.close()


_PREFIX = f"{UNPACK_PREFIX}view-"  # .unzip-view-PID-xxxx: which process unpacked it


def _own_prefix() -> str:
    return f"{_PREFIX}{os.getpid()}-"


def _clear_orphans() -> None:
    """Remove what viewer processes killed by SIGKILL (no ``finally`` runs) left unpacked in the
    temporary folder: folders of a process that no longer runs. Those of a process alive (another
    command, or one that took a dead one's PID) are left."""
    try:
        leftovers = [p for p in Path(tempfile.gettempdir()).iterdir() if p.name.startswith(_PREFIX)]
    except OSError:
        return
    for p in leftovers:
        pid = p.name[len(_PREFIX) :].split("-", 1)[0]
        if pid.isdigit() and int(pid) != os.getpid() and not process_runs(int(pid)):
            shutil.rmtree(p, ignore_errors=True)


@atexit.register
def _remove_at_exit() -> None:
    """Remove what sessions still open unpacked when the interpreter ends without leaving them: VTK
    ends it itself (``Py_Exit``, exit status 1) on a Ctrl-C met while it calls a Python observer, from
    inside that call, and no ``finally`` of the command runs then. A forked child that ends normally
    leaves its parent's sessions alone: their files are the parent's, still being read."""
    while _sessions:
        session = _sessions.pop()
        if session.pid != os.getpid():
            continue
        with stops_deferred(redeliver=False):
            session.stack.close()


def shown(text: object) -> str:
    """``text`` (a path, a message) with the folders archives were unpacked into named as the archives'
    members (``takes.zip/T/T.csv``), as the user knows them."""
    out = str(text)
    for box in _boxes():
        out = box.shown(out)
    return out


def _boxes() -> Iterator[Unpacked]:
    """The archives unpacked, an archive in an archive before the one holding it (its folder lies in the
    outer one's)."""
    for session in _sessions:
        yield from reversed(session.boxes)


def archive_member(path: Path) -> tuple[Path, PurePosixPath] | None:
    """The zip archive ``path`` is or lies in, and the member it names (``takes.zip/T`` -> takes.zip,
    ``T``; ``.`` for the archive itself); None when ``path`` is no archive nor in one (a path that
    exists and is not a ``.zip`` file, or one under no ``.zip`` file)."""
    if is_zip(path):
        return path, PurePosixPath(".")
    if path.exists():
        return None
    for parent in path.parents:
        if is_zip(parent):
            return parent, PurePosixPath(path.relative_to(parent).as_posix())
        if parent.exists():
            return None
    return None


def unpacked_input(path: str | Path, litter: Litter | None = None) -> tuple[Path, str] | None:
    """Where the archive ``path`` is or names a member of is unpacked (inside ``archives_unpacked``),
    the folder or file ``path`` names there and ``path`` as the user wrote it, for messages; None for
    a path in no archive. An archive in the archive is entered when the path names it
    (``download.zip/T.zip/T``), as ``s2a-capture import`` reads one level of them. Of an archive whose
    member is named, only what that member needs is unpacked (``members_needed``): a day's takes hold
    gigabytes of ``.mov``. A take's ``.wav`` beside its ``.mov`` is unpacked after it, and only when the
    reader reads it (``_wavs_read``). The archive is checked and unpacked by
    ``capture.take_archive.unpacked``, its ``InputError`` naming what is wrong; what it passed over
    (``__MACOSX``, ``._X``) is counted in ``litter``."""
    if not _sessions:
        raise RuntimeError("unpacked_input is called inside archives_unpacked()")
    found = archive_member(Path(path))
    if found is None:
        return None
    archive, member = found
    archive = download_of(archive)
    session, outer = _sessions[-1], None
    tally = Litter() if litter is None else litter
    while True:
        route = _Route(member, enter_archives=(outer.depth + 1 if outer else 1) < MAX_DEPTH)
        box = session.stack.enter_context(
            unpacked(archive, litter=tally, outer=outer, prefix=_own_prefix(), pick=route.pick)
        )
        session.boxes.append(box)
        member = PurePosixPath(*route.parts) if route.parts else member  # as the archive spells it
        target = box.folder.joinpath(*member.parts)
        if route.inner is None:
            break
        # a path through an archive in this one: that archive unpacked in turn
        parts = member.parts
        archive, member, outer = (
            box.folder.joinpath(*parts[: route.inner]),
            PurePosixPath(*parts[route.inner :]),
            box,
        )
    if not target.exists():
        held = sorted({m.parts[0] + ("/" if m.is_dir or len(m.parts) > 1 else "") for m in route.listed})
        listed = first_few(held)
        raise InputError(f"holds no {member} (it holds {listed or 'nothing'})", box.name)
    folders = {b[:-1] for b in route.held_back}  # each folder's .movs probed once, however many .wavs
    reading = {f for f in folders if _wavs_read(target, box.folder.joinpath(*f))}
    read = {b for b in route.held_back if b[:-1] in reading}
    if read:  # unpacked apart, then moved beside the take's other files
        later = session.stack.enter_context(
            unpacked(archive, litter=Litter(), outer=outer, prefix=_own_prefix(), pick=lambda _: read)
        )
        for parts in read:
            later.folder.joinpath(*parts).replace(box.folder.joinpath(*parts))
    return target, box.shown(target)


def download_of(archive: Path) -> Path | DriveDownload:
    """A part of a Google Drive download (``F-<time>Z-001.zip``) with other parts of it beside it: the
    download, read as one archive as ``s2a-capture import`` reads it (a take's CSV in one part, its
    ``.mov`` in another); any other archive as it is."""
    if drive_part(archive) is None:
        return archive
    try:  # drive_downloads gathers the parts of the archive's download, in its place (the first)
        beside = sorted(p for p in archive.parent.iterdir() if p != archive and drive_part(p))
    except OSError:
        return archive
    download = drive_downloads([archive, *beside])[0]
    return download if isinstance(download, DriveDownload) else archive


class _Route:
    """Which members of an archive a path into it (``member``; ``.`` for the whole archive) needs: the
    ``pick`` given to ``unpacked``, which keeps the archive's list (``listed``) for messages and notes
    whether the path goes through an archive in this one (``inner``: how many of its parts name it),
    and the ``.wav`` files it holds back until the ``.mov`` beside them is seen (``held_back``)."""

    def __init__(self, member: PurePosixPath, enter_archives: bool) -> None:
        self.parts = member.parts  # () for "."; as the archive spells them once ``pick`` has seen it
        self.enter_archives = enter_archives
        self.listed: list[Member] = []
        self.inner: int | None = None
        self.held_back: set[tuple[str, ...]] = set()  # unpacked only if read (``_wavs_held_back``)

    def pick(self, members: list[Member]) -> set[tuple[str, ...]]:
        self.listed = members
        self.parts = _as_spelled(self.parts, members)
        files = {m.parts for m in members if not m.is_dir}
        if self.enter_archives:
            for i in range(1, len(self.parts) + 1):
                if self.parts[:i] in files and self.parts[i - 1].lower().endswith(".zip"):
                    self.inner = i
                    return {self.parts[:i]}  # only that archive: its own members are picked in turn
        needed = members_needed(members, self.parts)
        self.held_back = _wavs_held_back(needed & files)
        return needed - self.held_back


# Files beside a named file that no take reader looks at, and large: videos other than the take's .mov,
# archives (other takes). A take folder's .mov is its audio and reference video: the one it reads is kept.
_NOT_READ_BESIDE = (".mov", ".mp4", ".m4v", ".avi", ".mkv", ".zip")


def members_needed(members: list[Member], parts: tuple[str, ...]) -> set[tuple[str, ...]]:
    """The members of an archive (``members``) that showing its member ``parts`` needs: all for the
    archive itself (``()``), a folder's own members for a folder, and for a file (a CSV) the files its
    reader may look at beside it: for a CSV read alone (``_read_alone``: one take's of a flat folder of
    several), the audio files ``audio_beside`` may pair with it (``_read_alone_needs``); else those of
    its folder, less other takes' videos and archives (of the ``.mov`` files, those the take folder
    reader may take: ``_movs_read``); none when it holds no ``parts``. A take's files' names are compared
    in Unicode NFC, as the take folder reader compares them (a Mac writes them decomposed)."""
    if not parts:
        return {m.parts for m in members}
    n = len(parts)
    if any(m.parts == parts and not m.is_dir for m in members):
        beside = [
            m.parts for m in members if not m.is_dir and len(m.parts) == n and m.parts[:-1] == parts[:-1]
        ]
        if _read_alone(beside, parts[-1]):
            return _read_alone_needs(beside, parts[-1]) | {parts}
        kept = {b for b in beside if PurePosixPath(b[-1]).suffix.lower() not in _NOT_READ_BESIDE}
        return kept | _movs_read(beside, parts[-1]) | {parts}
    return {m.parts for m in members if m.parts[:n] == parts}


def _wavs_held_back(files: set[tuple[str, ...]]) -> set[tuple[str, ...]]:
    """Of the files an archive's member needs, the ``.wav`` files (and iCloud placeholders of them) in a
    folder where a ``.mov`` is unpacked too: a take folder's reader takes its speech from the ``.mov``
    and reads a ``.wav`` only where the ``.mov`` holds no audio track (``capture.take_folder``), which
    only the ``.mov`` unpacked tells (``_wavs_read``). A ``.wav`` is as large as the ``.mov``'s audio."""
    movs = {b[:-1] for b in files if PurePosixPath(b[-1]).suffix.lower() == ".mov"}
    return {
        b for b in files if b[:-1] in movs and PurePosixPath(_original_name(b[-1])).suffix.lower() == ".wav"
    }


def _wavs_read(target: Path, folder: Path) -> bool:
    """Whether showing ``target`` (the folder or file named, unpacked) may read a ``.wav`` held back in
    ``folder`` (``_wavs_held_back``), as it would on the folder unzipped: unless every ``.mov`` of the
    folder holds an audio track and ``target`` is a folder (its take folders read as such) or a CSV read
    as its take (``reads_as_take``): the take folder's reader then takes its speech from the ``.mov`` it
    chooses. A CSV read alone takes the audio beside it (``csv_with_its_audio``); a ``.mov`` iCloud has
    not downloaded, or one that does not open, leaves the choice to the reader."""
    if target.is_file() and not (target.suffix.lower() == ".csv" and reads_as_take(target)):
        return True
    movs = [p for p in folder.iterdir() if Path(_original_name(p.name)).suffix.lower() == ".mov"]
    return not movs or not all(p.is_file() and p.suffix.lower() == ".mov" and _holds_audio(p) for p in movs)


def _holds_audio(mov: Path) -> bool:
    """Whether the ``.mov`` holds an audio track (False for one that does not open)."""
    try:
        return probe_mov(mov).audio_tracks > 0
    except InputError:
        return False


def _spelling(name: str) -> str:
    """``name`` in NFC and lower case; not ``casefold()``, which also equates what only NFKC does
    (``ﬁ`` and ``fi``): names that differ so are two names."""
    return nfc(name).lower()


def _as_spelled(parts: tuple[str, ...], members: list[Member]) -> tuple[str, ...]:
    """``parts`` as the archive spells them: a name typed in another case or Unicode normalisation
    (macOS writes names decomposed, NFD; a shell types them composed) is the member's own where one
    member only is so named, as the whole archive unpacked on macOS's file system found it; else as
    typed."""
    known = {m.parts[:i] for m in members for i in range(1, len(m.parts) + 1)}
    for i in range(len(parts)):
        if parts[: i + 1] in known:
            continue
        same = {k[i] for k in known if len(k) == i + 1 and k[:i] == parts[:i]}
        same = {name for name in same if _spelling(name) == _spelling(parts[i])}
        if len(same) != 1:
            return parts
        parts = (*parts[:i], same.pop(), *parts[i + 1 :])
    return parts


def _movs_read(beside: list[tuple[str, ...]], named: str) -> set[tuple[str, ...]]:
    """Of the ``.mov`` files in the folder of the CSV ``named`` (``beside``: the folder's files), those
    the take folder reader may read (``capture.take_folder``): the one named as the CSV and the first
    by name, its fallback, and one an iCloud placeholder stands beside (without it, the placeholder
    would count as not downloaded); all of them unless the folder's CSVs are one take's (one prefix,
    one of each variant): between several, the reader picks by the take's names, ``.mov`` stems among
    them (a flat folder of several takes whose CSV is not read alone, ``_read_alone``, keeps them all)."""
    movs = sorted((b for b in beside if PurePosixPath(b[-1]).suffix.lower() == ".mov"), key=lambda b: b[-1])
    names = [nfc(_original_name(b[-1])) for b in beside]
    csvs = [n for n in names if n.lower().endswith(".csv") and n.lower() != "frame_log.csv"]
    split = [split_variant(PurePosixPath(n).stem) for n in csvs]  # a copy "X (1)" is a prefix of its own
    if len({prefix for prefix, _ in split}) > 1 or len({variant for _, variant in split}) < len(split):
        return set(movs)
    prefix = split_variant(nfc(PurePosixPath(named).stem))[0]
    placeheld = {icloud_original(Path(b[-1])) for b in beside}
    named_as = {b for b in movs if nfc(PurePosixPath(b[-1]).stem) == prefix or b[-1] in placeheld}
    return named_as | set(movs[:1])


def _read_alone(beside: list[tuple[str, ...]], named: str) -> bool:
    """Whether the CSV ``named`` is read alone with the audio beside it (``csv_with_its_audio``), its
    folder's files as ``beside`` lists them, whatever else the folder holds: a neutral pose, or a CSV of
    a flat folder of several takes (``MySlate_1_iPhone.csv``, ``.mov``, ``MySlate_2_iPhone.csv``, ...,
    as people zip an export), where two CSVs or more of its variant are named as ``.mov`` files beside
    them: the take folder reader then reads none of them (``choose_csv`` refuses to choose, whatever
    take.json says). CSVs whose names may be a copy's (``X (1)``, ``X copy``) are not counted: the
    reader sets those aside."""
    if PurePosixPath(named).suffix.lower() != ".csv":
        return False
    variant = split_variant(PurePosixPath(named).stem)[1]
    if variant == "neutral":
        return True
    names = [PurePosixPath(nfc(_original_name(b[-1]))) for b in beside]
    movs = {n.stem for n in names if n.suffix.lower() == ".mov"}
    named_as_movs = [
        n
        for n in names
        if n.suffix.lower() == ".csv"
        and not _maybe_a_copy(n.stem)
        and split_variant(n.stem) in {(mov, variant) for mov in movs}
    ]
    return len(named_as_movs) > 1


def _maybe_a_copy(stem: str) -> bool:
    """Whether ``stem`` may be a copy's (a browser's ``X (1)``, Finder's ``X copy``, Windows Explorer's
    ``X - Copy (2)``): wider than the take folder reader's own test, so that a doubt keeps every .mov."""
    return stem.endswith(")") or " copy" in stem.casefold()


# What an audio file beside a CSV read alone may be named for instead (``audio_beside``): a CSV, a JSON
# export, a Face Cap text export (a .txt: unpacked, ``audio_beside`` reads whether it is one)
_NAMED_FOR = (".csv", ".json", ".txt")


def _read_alone_needs(beside: list[tuple[str, ...]], named: str) -> set[tuple[str, ...]]:
    """What ``audio_beside`` looks at for the CSV ``named`` read alone (``beside``: its folder's files):
    the audio files of its stem, else every audio file beside it with the CSVs and exports they may be
    named for (``_NAMED_FOR``; an only one, or an iCloud placeholder, named for another is not this
    CSV's); each with the iCloud placeholder standing for it, or standing beside it (a placeholder
    without the file it stands for counts as not downloaded). No .mov, nor the app's files: the folder
    unpacked is then no take folder, and the CSV is read alone there too."""
    by_name: dict[str, set[tuple[str, ...]]] = {}  # a file's name, in NFC -> it and its placeholder
    for b in beside:
        by_name.setdefault(nfc(_original_name(b[-1])), set()).add(b)
    named = nfc(named)
    prefix, variant = split_variant(PurePosixPath(named).stem)
    if variant != "neutral" and f"{prefix}.mov" in by_name:  # read as its take (``reads_as_take``)
        own = (named, f"{prefix}.mov", f"{prefix}.wav", f"{prefix}_neutral.csv")  # the .wav: a silent .mov's
        return {b for n in own for b in by_name.get(n, ())}
    stem = PurePosixPath(named).stem
    audio = [n for n in by_name if PurePosixPath(n).suffix.lower() in AUDIO_SUFFIXES]
    same = [n for n in audio if PurePosixPath(n).stem == stem]
    wanted = {named, *(same or audio)}
    if not same:
        owners = {PurePosixPath(n).stem.lower() for n in audio}  # by_name's names are NFC already
        wanted |= {
            n
            for n in by_name
            if PurePosixPath(n).suffix.lower() in _NAMED_FOR and audio_stem(Path(n)).lower() in owners
        }
    return {b for n in wanted for b in by_name.get(n, ())}


def _original_name(name: str) -> str:
    """The name of the file an iCloud placeholder (``.X.csv.icloud``) stands for, else ``name``."""
    return icloud_original(Path(name)) or name


def unpacked_folder(path: str | Path) -> tuple[Path, str] | None:
    """``unpacked_input`` for a folder of takes or a dataset (``s2a-view report``): the folder the
    archive or its member ``path`` names, entered when it holds nothing but one folder (a folder zipped
    by Finder or Windows Explorer holds itself), and its name for messages; None for a path in no
    archive."""
    place = unpacked_input(path)
    if place is None:
        return None
    folder, name = place
    inside = list(folder.iterdir()) if folder.is_dir() else []
    if len(inside) == 1 and inside[0].is_dir() and not (folder / "manifest.json").exists():
        return inside[0], shown(inside[0])
    return folder, name


def shown_in_page(page: str) -> str:
    """``shown`` for an HTML page, whose paths are escaped."""
    import html

    for box in _boxes():
        page = page.replace(html.escape(str(box.folder)), html.escape(box.name))
    return page


def replaced_speech_start(take: Take) -> tuple[float, str]:
    """Where speech given for a take folder of ours (``--audio``) starts: (take time in seconds,
    start source). Where the take's own speech started, on its clock (the same file given again shows
    the same: a take paired by frame index stays on that clock, one placed by frame_log.csv keeps that
    offset); a take without speech gets it at its first frame, as a CSV given with ``--audio`` does."""
    if take.meta.audio is not None:
        return float(take.meta.audio.start_s), take.meta.audio.start_source
    return (float(take.time[0]) if take.time.size else 0.0), "assumed_first_csv_row"


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
    if reads_as_take(csv):  # the .mov of its take beside it (takes side by side): read as import reads it
        return csv, None, None, None
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
    good = np.ones(len(values), dtype=bool)
    for j, c in enumerate(channels):  # a column at a time: a copy of a 2-hour take's values took 1 GB
        if is_known(c):
            good &= np.abs(values[:, j]) <= ABSURD  # NaN compares False
    return ~good


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
    shown = first_few(missing)
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
    count = 0
    for j in blendshape_columns(channels):  # a column at a time: a copy of them took 180 MB for 2 hours
        col = values[:, j]
        outside = (col < 0) | (col > 1)
        if rows is not None:
            outside &= rows
        count += int(np.count_nonzero(outside))
        if clamp:
            np.clip(col, 0.0, 1.0, out=col, where=outside)
    return count


def with_face(take: Take) -> np.ndarray:
    """Per frame: whether it holds a face (not dropped, not face lost)."""
    return (take.frame_status != FrameStatus.DROPPED) & (take.frame_status != FrameStatus.FACE_LOST)


def prepared_for_stream(take: Take) -> tuple[Take, int]:
    """``take`` as it may be sent to Unreal: frames with bad values marked BAD_VALUE (sent as no-face
    packets, counted in ``bad_values``). Returns it and how many blendshape weights of the frames sent
    with values lie outside 0..1: those are sent as they are, as the phone sends them (ARKit reaches
    1.05), and the caller warns about them."""
    bad = bad_frames(take.values, take.meta.channels)
    sent = with_face(take)
    status = take.frame_status.copy()
    status[bad & sent] = FrameStatus.BAD_VALUE
    take.frame_status = status
    return take, clamp_blendshapes(take.values, take.meta.channels, sent & ~bad, clamp=False)
