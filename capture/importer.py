"""``s2a-capture import``: every kind of source becomes take folders in the take container."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from .csv_take import read_livelink_csv
from .errors import InputError
from .take import Take, is_take_dir
from .take_folder import is_take_folder, read_csv_with_audio, read_take_folder

# How audio given with --audio goes with a CSV's rows (see read_csv_with_audio).
AUDIO_PAIRINGS = ("first-row", "frame-index")


def find_sources(paths: list[str | Path]) -> list[Path]:
    """Live Link Face take folders and loose CSV files named by ``paths``, searched recursively."""
    found: list[Path] = []
    for p in map(Path, paths):
        if p.is_file():
            found.append(p)
        elif p.is_dir():
            found.extend(_walk(p))
        else:
            raise InputError("no such file or folder", p)
    return found


def _walk(folder: Path) -> Iterator[Path]:
    if is_take_folder(folder):
        yield folder
        return
    if is_take_dir(folder) or folder.name.startswith("."):
        return  # an imported take of ours, or a hidden/temporary folder
    for p in sorted(folder.iterdir()):
        if p.is_dir():
            yield from _walk(p)
        elif p.suffix.lower() == ".csv":
            yield p


def import_source(
    source: Path,
    audio: str | Path | None = None,
    variant: str | None = None,
    strict: bool = False,
    swap_lr: bool = False,
    audio_pairing: str = "first-row",
) -> Take:
    """One source (take folder or CSV file) as a take. ``audio_pairing`` (one of ``AUDIO_PAIRINGS``)
    says how external ``audio`` goes with a CSV's rows."""
    if audio_pairing not in AUDIO_PAIRINGS:
        raise InputError(f"unknown audio pairing {audio_pairing!r} (known: {', '.join(AUDIO_PAIRINGS)})")
    if source.is_dir():
        if audio_pairing != "first-row":
            raise InputError(
                "--audio-pairing frame-index applies to a CSV with --audio, not a take folder", source
            )
        return read_take_folder(source, variant, audio, strict, swap_lr)
    if source.suffix.lower() != ".csv":
        raise InputError("not a Live Link Face CSV or take folder", source)
    if audio is not None:
        return read_csv_with_audio(
            source, audio, strict, swap_lr, by_frame_index=audio_pairing == "frame-index"
        )
    return read_livelink_csv(source, strict=strict, swap_lr=swap_lr)
