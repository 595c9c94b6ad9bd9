"""What operating systems, sync services and downloads leave among takes a user copies, zips or
downloads: never a take, never part of one.

- macOS AppleDouble files ``._X`` (magic ``00 05 16 07``): Finder writes one beside every file it copies
  to a volume without extended attributes (exFAT, FAT, SMB shares) and into every zip it makes, under
  ``__MACOSX/``. Known by name: only Finder writes ``._`` names.
- Windows' ``$RECYCLE.BIN`` (deleted files, takes among them) and ``System Volume Information`` at a
  drive's root.
- Excel's owner files ``~$X.csv`` (a file open in Excel).
- Unfinished downloads: Firefox's ``X.part``, Chrome's and Edge's ``X.crdownload``, Safari's
  ``X.download`` folder holding the file as far as it came.

iCloud Drive's placeholders ``.X.mov.icloud`` (a file not downloaded yet) and zip archives are not
litter: they stand for a take's files, and importing without them would lose the take's data, so the
importer refuses them with the errors here.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from .errors import InputError

APPLEDOUBLE_MAGIC = b"\x00\x05\x16\x07"
# What a command says it passed over: (noun, what it is), counted once per path.
_APPLEDOUBLE = ("macOS metadata file", "(._*)")
_FOLDERS = {  # compared case-insensitively, as the volumes they come from compare names
    "__macosx": ("macOS metadata folder", "(__MACOSX)"),
    "$recycle.bin": ("Windows recycle bin", "($RECYCLE.BIN)"),
    "system volume information": ("Windows system folder", "(System Volume Information)"),
}
_OFFICE_OWNER = ("Office owner file", "(~$*)")
PARTIAL_SUFFIXES = (".part", ".crdownload", ".download")  # Firefox, Chrome and Edge, Safari (a folder)
_PARTIAL = ("unfinished download", "(.part, .crdownload, .download: finish the download to import it)")
ICLOUD_SUFFIX = ".icloud"


def litter_kind(name: str) -> tuple[str, str] | None:
    """What a file or folder of this name is when it is operating-system or transfer litter (noun,
    what it is), else None."""
    if name.startswith("._"):
        return _APPLEDOUBLE
    folder = _FOLDERS.get(name.casefold())
    if folder is not None:
        return folder
    if name.startswith("~$"):
        return _OFFICE_OWNER
    if name.lower().endswith(PARTIAL_SUFFIXES):
        return _PARTIAL
    return None


def is_litter(path: Path) -> bool:
    """Whether ``path`` is operating-system or transfer litter (``litter_kind`` of its name)."""
    return litter_kind(path.name) is not None


def without_litter(paths: Iterable[Path]) -> list[Path]:
    """``paths`` less the litter among them, in their order."""
    return [p for p in paths if not is_litter(p)]


def is_appledouble(path: Path) -> bool:
    """Whether a file holds AppleDouble data (its first bytes are the format's magic), whatever its
    name."""
    try:
        with open(path, "rb") as f:
            return f.read(len(APPLEDOUBLE_MAGIC)) == APPLEDOUBLE_MAGIC
    except OSError:
        return False


class Litter:
    """The litter one command passed over, for one warning line per kind (``lines``)."""

    def __init__(self) -> None:
        self._seen: dict[tuple[str, str], set[Path]] = {}

    def skips(self, path: Path) -> bool:
        """Whether ``path`` is litter; if so it is counted (once, however often it is met)."""
        kind = litter_kind(path.name)
        if kind is not None:
            self._seen.setdefault(kind, set()).add(path)
        return kind is not None

    def lines(self) -> list[str]:
        """``skipped 14 macOS metadata files (._*)``, one line per kind met."""
        return [
            f"skipped {len(paths)} {noun}{'' if len(paths) == 1 else 's'} {what}"
            for (noun, what), paths in self._seen.items()
        ]


def icloud_original(path: Path) -> str | None:
    """The name of the file an iCloud Drive placeholder stands for (``.X.mov.icloud`` -> ``X.mov``),
    else None. iCloud leaves such a hidden file (a binary property list) where a file it has not
    downloaded yet belongs."""
    name = path.name
    if name.startswith(".") and name.lower().endswith(ICLOUD_SUFFIX) and len(name) > len(ICLOUD_SUFFIX) + 1:
        return name[1 : -len(ICLOUD_SUFFIX)]
    return None


def not_downloaded(path: Path) -> str | None:
    """The name of the file an iCloud placeholder stands for when that file is not beside it (not
    downloaded yet), else None (not a placeholder, or one iCloud left beside the downloaded file)."""
    original = icloud_original(path)
    return original if original is not None and not (path.parent / original).exists() else None


def icloud_error(placeholder: Path, where: Path | None = None) -> InputError:
    """The error for a file of a take that iCloud has not downloaded (``placeholder``: its
    ``.X.icloud`` file), naming ``where`` (default: the placeholder)."""
    return InputError(
        f"{icloud_original(placeholder)} is an iCloud placeholder, not downloaded: download it first "
        "(Finder: Download Now; or open it once), then import again",
        placeholder if where is None else where,
    )


def is_zip(path: Path) -> bool:
    """Whether ``path`` is a zip archive: a file named ``X.zip`` (what a download or Finder's Compress
    makes; a folder so named, such as a take folder, is none)."""
    return path.suffix.lower() == ".zip" and path.is_file()


def zip_error(path: Path) -> InputError:
    """The error for a zip archive given where takes are expected: archives are not read."""
    return InputError(
        f"{path} is a zip archive: unzip it first (then import the folder it holds; archives are not read)"
    )
