"""Zip archives of takes, as they reach a computer: takes shared from the phone (AirDrop, Files, mail),
a take folder compressed by Finder or Windows Explorer, a download of a shared folder. ``s2a-capture
import`` and ``info`` unpack one into a hidden folder (``unpacked``) and read the takes there as any
folder; the takes record their files as ``ARCHIVE.zip/member`` (``Unpacked.rename_files``).

What an archive may hold is checked before a byte is written: no member outside the folder unpacked
into (absolute paths, ``..``, drive letters), no two members of one name, no encryption, and room on
the disk for every member as its header declares it (the reader never writes more than that, so a
"zip bomb" is refused before it is unpacked). Symbolic links are not made; operating-system litter
(``__MACOSX``, ``._X``) is passed over. Names written without the archive's UTF-8 flag (Finder, Windows
Explorer, most tools) are read as UTF-8 when they are that, else as the zip standard's code page 437.

A download of a large folder from Google Drive comes in parts, ``F-20250101T101010Z-001.zip``,
``-002.zip``, ... (each under 2 GB, each holding some of the folder's files under ``F/``; a take's CSV in
one, its ``.mov`` in another): the parts of one download given or found together
(``drive_downloads``) are unpacked into one folder as one archive, each file named after its part; no
file may be in two parts. A part cut short (a download that stopped: no zip directory at its end) is
read as a part missing, with a warning naming it and the files its first bytes show it held (a take
with files in it is read without those).

A zip (a part or not) whose directory alone is cut or damaged, every member's bytes there and the
directory begun after them (a download that stopped in its last kilobytes), is read from its members'
own headers (``_by_headers``: sizes there, in a zip64 field, or in a descriptor after the bytes), each
member checked by its CRC as zipfile checks it, with a warning. A zip stored last in a cut one, whose
end zipfile would find and read as the cut one's, is not taken for it: none of its members starts at
the cut zip's first byte.

A reader that needs a few members only (``s2a-view`` showing one take of an archive of a day's takes,
gigabytes of ``.mov``) picks them from the archive's list (``pick``): the checks of names (outside the
folder, two of one name) still see the whole archive, those of a member's bytes (encryption, a method
not readable here, damage) and the room on the disk see what is unpacked.
"""

from __future__ import annotations

import lzma
import mmap
import os
import re
import shutil
import stat
import tempfile
import zipfile
import zlib
from collections.abc import Callable, Collection, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

from .command import stops_deferred, warn
from .errors import InputError, first_few
from .take import Take
from .transfer_litter import Litter, is_zip

# Hidden folders an import unpacks archives into, inside its output folder; one left by a killed import
# is removed by the next import into that folder (which holds the folder's import lock).
UNPACK_PREFIX = ".unzip-"
# Room kept free on the disk beyond what the members take (the takes imported are written there too).
SPARE_BYTES = 64 << 20
MAX_DEPTH = 2  # archives in an archive are read; archives in those are named and skipped
_UTF8_FLAG = 0x800
_ENCRYPTED_FLAG = 0x1
# Compression methods Python's zipfile cannot read, by number (APPNOTE 4.4.5), for the error.
_METHODS = {
    6: "Implode",
    9: "Deflate64 (Windows Explorer uses it for large files)",
    18: "IBM TERSE",
    19: "IBM LZ77",
    93: "Zstandard",
    95: "XZ",
    97: "WavPack",
    98: "PPMd",
    99: "AES encryption (WinZip)",
}
_DRIVE = re.compile(r"[A-Za-z]:")
# A part of a Google Drive download: the folder's name, the time of the download (UTC), the part's number.
_DRIVE_PART = re.compile(r"(.+-\d{8}T\d{6}Z)-(\d{3,})\.zip", re.IGNORECASE)


@dataclass(frozen=True)
class DriveDownload:
    """Two or more parts of one Google Drive download (``F-20250101T101010Z-001.zip``, ``-002.zip``, ...)
    in one folder, read as one archive by ``unpacked``: ``stem`` is ``F-20250101T101010Z``."""

    stem: str
    parts: tuple[Path, ...]  # in the order of their numbers

    def __str__(self) -> str:
        first, *others = self.parts
        if len(others) > 2:  # a thousand parts named each time would be a line of 30 000 characters
            return f"{first} + ... + {others[-1].name} ({len(self.parts)} parts)"
        return " + ".join([str(first), *(p.name for p in others)])

    def missing(self) -> list[str]:
        """The numbers of the parts before the last one given that are not given, a run of them as one
        (``002`` of 001 and 003, ``002-004`` of 001 and 005: never one string per part, a part named
        ``-999999999.zip`` is no list of a billion; parts after the last cannot be known)."""
        given = sorted({int(drive_part(p)[1]) for p in self.parts})
        gaps = [(before + 1, after - 1) for before, after in zip([0, *given], given) if after - before > 1]
        return [f"{first:03d}" if first == last else f"{first:03d}-{last:03d}" for first, last in gaps]


def drive_part(path: Path) -> tuple[str, str] | None:
    """The stem of the download and the part's number, for a part of a Google Drive download by its name."""
    match = _DRIVE_PART.fullmatch(path.name)
    return (match[1], match[2]) if match else None


def drive_downloads(sources: list[Path]) -> list[Path | DriveDownload]:
    """``sources`` with the parts of each Google Drive download among them (same folder, same
    ``F-<time>Z`` stem) gathered into one ``DriveDownload``, in the place of its first part; a part
    alone stays an archive of its own."""
    keys = [_download_key(src) for src in sources]  # each name matched and each file looked at once
    groups: dict[tuple[Path, str], list[Path]] = {}
    for src, key in zip(sources, keys):
        if key is not None:
            groups.setdefault(key, []).append(src)
    downloads = {key: sorted(set(g), key=lambda p: int(drive_part(p)[1])) for key, g in groups.items()}
    out: list[Path | DriveDownload] = []
    done = set()
    for src, key in zip(sources, keys):
        parts = downloads[key] if key is not None else []
        if len(parts) < 2:
            out.append(src)
        elif key not in done:  # the parts of a download given twice are read once
            done.add(key)
            out.append(DriveDownload(drive_part(parts[0])[0], tuple(parts)))
    return out


def _download_key(src: Path) -> tuple[Path, str] | None:
    """The download a part belongs to (its folder and case-folded stem), None for any other source."""
    part = drive_part(src)
    return (src.parent, part[0].casefold()) if part is not None and is_zip(src) else None


@dataclass
class Unpacked:
    """An archive unpacked: ``folder`` holds its members (named after the archive, ``takes.zip`` ->
    ``.../takes``, so a take folder zipped without its folder keeps a name). Of a ``DriveDownload``,
    ``archive``, ``name`` and ``real`` are its first part's, and ``parts`` says which part each member
    unpacked came from (relative path -> the part's name and real path; a folder: the first part
    holding something in it)."""

    archive: Path
    folder: Path
    name: str  # what the archive is called in messages: as given, or a member of another archive's
    real: str  # and in the takes' records: its real path (symbolic links resolved), as a loose file's
    depth: int = 1  # 1 for an archive given or found in a folder, 2 for one in an archive
    parts: dict[str, tuple[str, str]] = field(default_factory=dict)

    @property
    def unpacks_archives(self) -> bool:
        """Whether the archives found in this one are read too (one level down, not further)."""
        return self.depth < MAX_DEPTH

    def shown(self, text: object) -> str:
        """``text`` (a path of a file unpacked, or a message naming one) with the archive's member in its
        place: ``takes.zip/T/T.csv``."""
        return self._named(text, 0)

    def recorded(self, text: object) -> str:
        """``text`` (a path of a file unpacked) as the takes record it: the archive by its real path."""
        return self._named(text, 1)

    def _named(self, text: object, which: int) -> str:
        pieces = str(text).split(str(self.folder))
        if not self.parts:
            return (self.name, self.real)[which].join(pieces)
        named = [pieces[0]]
        for rest in pieces[1:]:  # each path named after the part its longest known beginning is from
            member = max((k for k in self.parts if rest.startswith(f"/{k}")), key=len, default="")
            named.append(self.parts[member][which] + rest)
        return "".join(named)

    def rename_files(self, take: Take) -> None:
        """Record ``take``'s files as the archive's members (``/dl/takes.zip/T/T.csv``, the archive by its
        real path: a re-import through another spelling replaces them; the unpacked copies are gone after
        the import), in its sources and repair messages."""
        for source in take.meta.sources:
            source.path = self.recorded(source.path)
        for repair in take.meta.repairs:
            if isinstance(repair.get("message"), str):
                repair["message"] = self.shown(repair["message"])


def member_name(info: zipfile.ZipInfo) -> str:
    """A member's name as its writer meant it: without the UTF-8 flag, zipfile reads names as code page
    437, but Finder, Windows Explorer (since Windows 10) and Info-ZIP write UTF-8 without setting it."""
    name = info.filename
    if not info.flag_bits & _UTF8_FLAG:
        try:
            name = name.encode("cp437").decode("utf-8")
        except (UnicodeEncodeError, UnicodeDecodeError):
            pass
    return name.replace("\\", "/")  # some Windows writers separate folders so, against the standard


def member_parts(info: zipfile.ZipInfo, archive: Path) -> tuple[str, ...]:
    """The folders and file name a member unpacks to, relative to the folder unpacked into; an
    ``InputError`` for a member whose name would put it elsewhere."""
    name = member_name(info)
    parts = tuple(p for p in PurePosixPath(name).parts if p not in ("", "."))
    if name.startswith("/") or ".." in parts or (parts and _DRIVE.match(parts[0])):
        raise InputError(
            f"member {name!r} would be written outside the folder unpacked into: an archive not made by "
            "the app or a file manager; unpack it yourself after checking it",
            archive,
        )
    return parts


def is_folder(info: zipfile.ZipInfo) -> bool:
    """Whether a member is a folder: its name ends with a separator, ``/`` or, from some Windows writers,
    ``\\`` (zipfile's ``is_dir`` sees only ``/``)."""
    return member_name(info).endswith("/")


def _is_link(info: zipfile.ZipInfo) -> bool:
    return stat.S_ISLNK(info.external_attr >> 16)


_READABLE = (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED, zipfile.ZIP_BZIP2, zipfile.ZIP_LZMA)
Plan = list[tuple[zipfile.ZipInfo, tuple[str, ...]]]  # the members to unpack, each with its parts


@dataclass(frozen=True)
class Member:
    """A member an archive would unpack, as ``pick`` sees it: its folders and file name (``parts``)."""

    parts: tuple[str, ...]
    is_dir: bool


# Given the members an archive holds (litter and links left out), the parts of those to unpack.
Pick = Callable[[list[Member]], Collection[tuple[str, ...]]]


def _plan(zf: zipfile.ZipFile, archive: Path, litter: Litter, readable: bool = True) -> Plan:
    """The members to unpack with their relative parts, after every check that needs no writing
    (``readable``: with those of their bytes, ``_check_readable``, else left to the caller)."""
    plan, seen = [], {}
    for info in zf.infolist():
        parts = member_parts(info, archive)
        if not parts or any(litter.skips(archive.joinpath(*parts[: i + 1])) for i in range(len(parts))):
            continue
        if readable:
            _check_readable(info, parts, archive)
        if _is_link(info):
            continue  # a link is no take file; following one could reach outside the folder
        key = "/".join(parts)
        if key in seen and not is_folder(info):
            raise InputError(f"holds two members named {key}: unzip it and keep the right one", archive)
        seen[key] = info
        plan.append((info, parts))
    return plan


def _check_readable(info: zipfile.ZipInfo, parts: tuple[str, ...], archive: Path) -> None:
    """Refuse a member whose bytes cannot be read here: encrypted, or compressed by another method."""
    if info.flag_bits & _ENCRYPTED_FLAG:
        raise InputError(f"member {'/'.join(parts)} is encrypted: unzip it with its password", archive)
    if info.compress_type not in _READABLE:
        method = _METHODS.get(info.compress_type, f"method {info.compress_type}")
        raise InputError(
            f"member {'/'.join(parts)} is compressed with {method}, which cannot be read here: "
            "unzip it with your system's tool (or 7-Zip) and import the folder",
            archive,
        )


def _picked(plan: Plan, wanted: set[tuple[str, ...]], archive: Path) -> Plan:
    """The members of ``plan`` that are ``wanted``, their bytes checked (``_check_readable``)."""
    plan = [(info, parts) for info, parts in plan if parts in wanted]
    for info, parts in plan:
        _check_readable(info, parts, archive)
    return plan


def _size(nbytes: int) -> str:
    """A size as a message says it: GB from 1 GB up, else MB."""
    return f"{nbytes / 1e9:.2f} GB" if nbytes >= 1e9 else f"{nbytes / 1e6:.1f} MB"


def _check_room(plan: Plan, into: Path, archive: Path) -> None:
    need = sum(info.file_size for info, _ in plan if not is_folder(info))
    free = shutil.disk_usage(into).free
    if need + SPARE_BYTES > free:
        raise InputError(
            f"no space left on the disk to unpack it: unpacking it needs {_size(need + SPARE_BYTES)} "
            f"({_size(SPARE_BYTES)} of it to spare) and {into} has {_size(free)} free: free some "
            "space, or unzip it elsewhere and import the folder",
            archive,
        )


def _parts_of(plans: list[Plan], names: list[str]) -> dict[str, int]:
    """Which part of a download each member and folder to unpack comes from, by index (a folder: the
    first part holding something in it; "": the folder unpacked into); an ``InputError`` naming both
    parts for a file in two of them."""
    owner, files = {"": 0}, {}
    for i, plan in enumerate(plans):
        for info, parts in plan:
            key = "/".join(parts)
            if not is_folder(info):
                if key in files:
                    raise InputError(
                        f"holds {key}, as {names[files[key]]} does: parts of two downloads? Unzip them "
                        "and keep the right one",
                        names[i],
                    )
                files[key] = owner[key] = i
            for j in range(1, len(parts)):
                owner.setdefault("/".join(parts[:j]), i)
            owner.setdefault(key, i)
    return owner


_LOCAL_HEADER = b"PK\x03\x04"
# What follows a zip's last member: its directory's first record (a file's entry; a zip64 end; the end).
_DIRECTORY = re.compile(b"PK\x01\x02|PK\x06\x06|PK\x05\x06")
_NEXT_RECORD = re.compile(b"PK\x03\x04|PK\x01\x02|PK\x06\x06|PK\x05\x06")
_ZIP64_EXTRA = 0x0001


@dataclass
class _Headers:
    """A zip as its members' local headers show it, read from its first byte: the members whose bytes end
    before the file does, each with where its bytes start; the files all its headers name (a member cut
    too); and whether the zip's directory begins after its last member (``whole``: every member there,
    only the directory at its end cut or damaged)."""

    members: list[tuple[zipfile.ZipInfo, int]]
    names: list[str]
    whole: bool


def _by_headers(part: Path) -> _Headers | None:
    """``part`` read from its members' local headers (APPNOTE 4.3.7) when zipfile cannot read its directory
    (cut short, damaged) or finds a zip stored in one of its members instead (a cut part whose last bytes
    are a zip it holds): no member of that one starts at the first byte, where this one's does; None for a
    file zipfile reads (also one whose zip begins past this one's members: two zips joined, a copy resumed
    over a cut one, which zipfile reads as the last), or one starting with no member's header (no zip:
    zipfile says why)."""
    inner = None  # where the first member of a zip zipfile finds, not at the first byte, starts
    try:
        with open(part, "rb") as f:
            if f.read(4) != _LOCAL_HEADER:
                return None
            try:
                with zipfile.ZipFile(f) as zf:
                    starts = [info.header_offset for info in zf.infolist()]
                if 0 in starts:
                    return None
                inner = min(starts, default=None)
            except (zipfile.BadZipFile, NotImplementedError):  # e.g. a version no zip has: damaged
                pass
            data = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
    except (OSError, ValueError):
        return None
    with data:
        headers = _read_headers(data)
    if inner is not None and not any(
        info.compress_type == zipfile.ZIP_STORED and start <= inner < start + info.compress_size
        for info, start in headers.members
    ):
        return None
    return headers


def _read_headers(data: mmap.mmap) -> _Headers:
    """The members of the zip ``data`` as their local headers, from the first, show them (``_Headers``)."""
    members, names, at = [], [], 0
    while data[at : at + 4] == _LOCAL_HEADER and at + 30 <= len(data):
        flags, method, crc, size, file_size, length, extra = (
            _number(data, at + i, width)
            for i, width in ((6, 2), (8, 2), (14, 4), (18, 4), (22, 4), (26, 2), (28, 2))
        )
        raw = data[at + 30 : at + 30 + length]  # decoded as zipfile decodes a name
        info = zipfile.ZipInfo(raw.decode("utf-8" if flags & _UTF8_FLAG else "cp437", "replace"))
        info.flag_bits, info.compress_type, info.header_offset = flags, method, at
        if raw and not is_folder(info) and at + 30 + length <= len(data):  # a name cut short: no file's
            names.append(member_name(info))
        start = at + 30 + length + extra  # the member's bytes
        if 0xFFFFFFFF in (size, file_size):  # a zip64's sizes, in its extra field: the size, then packed
            file_size, size = _zip64_sizes(data[at + 30 + length : start], file_size, size)
        if flags & 8:  # sizes written after the bytes: the next record is the one past a descriptor giving
            # their size (the signature met in a member's bytes, a zip stored in this one, starts none)
            found = (
                d for m in _NEXT_RECORD.finditer(data, start) if (d := _descriptor(data, start, m.start()))
            )
            crc, size, file_size, end = next(found, (crc, size, file_size, len(data) + 1))
        else:
            end = start + size
        if start > len(data) or end > len(data):
            break  # cut in it
        info.CRC, info.compress_size, info.file_size = crc, size, file_size
        members.append((info, start))
        at = end
    return _Headers(members, names, bool(_DIRECTORY.match(data, at)))


def _zip64_sizes(extra: bytes, file_size: int, size: int) -> tuple[int, int]:
    """The sizes a zip64 local header's extra field gives (APPNOTE 4.5.3: the size, then the packed size)."""
    at = 0
    while at + 4 <= len(extra):  # blocks of a kind and a length
        kind, length = _number(extra, at, 2), _number(extra, at + 2, 2)
        if kind == _ZIP64_EXTRA and length >= 16:
            return _number(extra, at + 4, 8), _number(extra, at + 12, 8)
        at += 4 + length
    return file_size, size


def _number(data: bytes | mmap.mmap, at: int, width: int) -> int:
    """The number of ``width`` bytes at ``at`` (a zip's numbers are little-endian)."""
    return int.from_bytes(data[at : at + width], "little")


def _descriptor(data: mmap.mmap, start: int, at: int) -> tuple[int, int, int, int] | None:
    """The CRC and sizes of a member whose bytes from ``start`` end at ``at`` with its data descriptor
    (APPNOTE 4.3.9: perhaps its signature, a CRC, the sizes in 4 bytes or, in a zip64, 8) saying how many
    they are, and ``at``; None when no descriptor before ``at`` says so."""
    for signature, width in ((b"PK\x07\x08", 4), (b"PK\x07\x08", 8), (b"", 4), (b"", 8)):
        descriptor = at - len(signature) - 4 - 2 * width
        fields = descriptor + len(signature)
        crc, size, file_size = (
            _number(data, fields, 4),
            *(_number(data, fields + 4 + i * width, width) for i in (0, 1)),
        )
        if descriptor >= start and data[descriptor:fields] == signature and size == descriptor - start:
            return crc, size, file_size, at
    return None


class _FromHeaders:
    """A zip whose directory is cut or damaged, every member whole, read as zipfile reads one (its
    members' CRCs checked) from what their local headers say (``_Headers``)."""

    def __init__(self, archive: Path, headers: _Headers) -> None:
        self.file = open(archive, "rb")
        self.members = headers.members
        self.starts = {info.header_offset: start for info, start in headers.members}

    def __enter__(self) -> _FromHeaders:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.file.close()

    def infolist(self) -> list[zipfile.ZipInfo]:
        return [info for info, _ in self.members]

    def open(self, info: zipfile.ZipInfo) -> zipfile.ZipExtFile:
        self.file.seek(self.starts[info.header_offset])
        return zipfile.ZipExtFile(self.file, "r", info)


def _open(archive: Path, name: str, headers: _Headers | None = None) -> zipfile.ZipFile | _FromHeaders:
    """``archive`` opened; by its members' ``headers`` when those are all there (its directory cut or
    damaged)."""
    try:
        if headers is not None and headers.whole:
            return _FromHeaders(archive, headers)
        if headers is not None:  # cut in its members (zipfile fails, or reads a zip stored in it as it)
            raise zipfile.BadZipFile("File is not a zip file")
        return zipfile.ZipFile(archive)
    except (zipfile.BadZipFile, NotImplementedError) as exc:
        raise InputError(
            f"not a readable zip archive ({exc}): a download or copy cut short? Copy it again", name
        ) from None
    except OSError as exc:
        raise InputError(f"cannot read it: {exc.strerror or exc}", name) from None


@contextmanager
def unpacked(
    archive: Path | DriveDownload,
    into: Path | None = None,
    litter: Litter | None = None,
    outer: Unpacked | None = None,
    prefix: str = UNPACK_PREFIX,
    pick: Pick | None = None,
    strict: bool = False,
) -> Iterator[Unpacked]:
    """``archive`` (or the parts of a Google Drive download, as one archive) unpacked into a hidden
    folder made in ``into`` (default: the system's temporary folder), removed on leaving; ``outer``: the
    archive it was unpacked from, if any, to name it as a member of; ``prefix``: how the hidden folder's
    name starts (one command's own, to find what a killed run of it left); ``pick``: the members to
    unpack (default all; of a download, of each part). Litter passed over is counted in ``litter``. An
    ``InputError`` (naming it, or the part) names what is wrong: not a zip archive (or cut short), a
    member outside the folder, encrypted, compressed with a method not readable here, damaged (its
    checksum), too large for the disk, a file in two parts of a download; with ``strict``, also a part
    cut short or a directory damaged, which are otherwise warnings (a part read as missing; the members
    read from their own headers)."""
    tally = Litter() if litter is None else litter
    archives = archive.parts if isinstance(archive, DriveDownload) else (archive,)
    names = [outer.shown(a) if outer else str(a) for a in archives]
    headers = [_by_headers(part) for part in archives]
    said = []  # (a part, how it was read short or repaired)
    if len(archives) > 1 and any(h is None or h.whole for h in headers):
        # a part cut short is read as a part missing when another part reads
        said += [(n, _read_as_missing(h)) for n, h in zip(names, headers) if h is not None and not h.whole]
        kept = [i for i, held in enumerate(headers) if held is None or held.whole]
        archives, names, headers = ([seq[i] for i in kept] for seq in (archives, names, headers))
    said += [(n, _read_by_headers(h)) for n, h in zip(names, headers) if h is not None and h.whole]
    if strict and said:
        raise InputError(f"{said[0][1]}; --strict refuses an archive read short or repaired", said[0][0])
    for name, what in said:
        warn(f"{name}: {what}")
    reals = [outer.recorded(a) if outer else str(Path(a).resolve()) for a in archives]
    plans = []
    for part, name, held in zip(archives, names, headers):  # one part open at a time: a download of a
        with _open(part, name, held) as zf:  # thousand parts is past a system's limit of open files
            plans.append(_plan(zf, Path(name), tally, readable=pick is None))
    if pick is not None:  # a download's members picked as one archive's
        wanted = set(pick([Member(parts, is_folder(info)) for plan in plans for info, parts in plan]))
        plans = [_picked(plan, wanted, Path(n)) for plan, n in zip(plans, names)]
    owners = _parts_of(plans, names) if len(archives) > 1 else {}
    where = Path(tempfile.gettempdir() if into is None else into)
    _check_room([m for plan in plans for m in plan], where, Path(names[0]))
    work = None
    pid = os.getpid()
    try:
        # Ctrl-C and SIGTERM wait until the folder is noted here: met as it was made, a stop left it
        with stops_deferred():
            work = Path(tempfile.mkdtemp(prefix=prefix, dir=where)).resolve()  # as source paths are
        # named as the archive (a take folder zipped without its folder keeps a name), never "." or ".."
        folder = work / (archive.stem.strip(".") and archive.stem or "archive")
        try:
            folder.mkdir()
        except OSError as exc:
            raise InputError(f"cannot unpack it into {where}: {exc.strerror or exc}", names[0]) from None
        for part, plan, name, held in zip(archives, plans, names, headers):
            with _open(part, name, held) as zf:
                for info, parts in plan:
                    _unpack_member(zf, info, folder.joinpath(*parts), name)
        owned = {member: (names[i], reals[i]) for member, i in owners.items()}
        yield Unpacked(archives[0], folder, names[0], reals[0], outer.depth + 1 if outer else 1, owned)
    finally:
        # a forked child that inherited this (its generator closed as the child ends) leaves it: the
        # files are the parent's, still being read
        if work is not None and os.getpid() == pid:
            with stops_deferred():  # a second Ctrl-C cuts no removal short
                shutil.rmtree(work, ignore_errors=True)


def _read_as_missing(held: _Headers) -> str:
    what = (
        f"{first_few(held.names)} and what followed were in it" if held.names else "what it held is unknown"
    )
    return (
        f"cut short (not a whole zip: a download that stopped?), read as a part missing ({what}): a take "
        "with files in it is read without those (download it again and give all the parts)"
    )


def _read_by_headers(held: _Headers) -> str:
    return (
        "its zip directory (the list of its files, at its end) is cut or damaged: read from its members' "
        f"own headers ({len(held.members)} found whole, each checked by its CRC; copy it again if it was "
        "cut short)"
    )


def _unpack_member(zf: zipfile.ZipFile, info: zipfile.ZipInfo, target: Path, archive: str) -> None:
    name = member_name(info)
    try:
        if is_folder(info):
            target.mkdir(parents=True, exist_ok=True)
            return
        target.parent.mkdir(parents=True, exist_ok=True)
        with zf.open(info) as src, open(target, "xb") as dst:
            shutil.copyfileobj(src, dst, 1 << 20)
    except FileExistsError:  # a file and a folder of one name (``T`` and ``T/x``), or names equal here
        raise InputError(f"member {name} clashes with another member of that name", archive) from None
    # NotImplementedError: a flag no writer sets (5, patched data), as damage sets it
    except (zipfile.BadZipFile, zlib.error, lzma.LZMAError, EOFError, NotImplementedError, OSError) as exc:
        # bz2 refuses bytes it cannot decode with an OSError of no errno ("Invalid data stream"); the disk's
        # errors carry one
        if isinstance(exc, OSError) and (exc.errno is not None or info.compress_type != zipfile.ZIP_BZIP2):
            raise InputError(f"cannot unpack member {name}: {exc.strerror or exc}", archive) from None
        raise InputError(f"member {name} is damaged ({exc}): copy the archive again", archive) from None


def clear_unpacked(folder: Path) -> None:
    """Remove what killed imports left unpacked in ``folder`` (call it holding the folder's import lock)."""
    try:
        leftovers = [p for p in folder.iterdir() if p.name.startswith(UNPACK_PREFIX) and p.is_dir()]
    except OSError:
        return
    for p in leftovers:
        shutil.rmtree(p, ignore_errors=True)
