"""Reading ``.npz`` archives from other hands: array headers first, only the arrays wanted, each refused
when its header declares more values than any take holds (a few compressed bytes can declare gigabytes).
Never unpickles."""

from __future__ import annotations

import contextlib
import math
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from .errors import InputError

# The most values one array may hold (an hour at 120 fps of 200 channels is 86 million): its header says
# how many before it is read, so a compressed array of zeros cannot take gigabytes.
NPZ_MAX_VALUES = 200_000_000
# What reading a damaged .npz raises: a truncated file, a member whose data is cut or corrupt.
NPZ_ERRORS = (ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error)

Header = tuple[str, tuple[int, ...], np.dtype]


@contextlib.contextmanager
def open_npz(path: Path) -> Iterator[np.lib.npyio.NpzFile | np.ndarray]:
    """``np.load`` (never unpickling) of a file this opens and closes, whatever is in it: NumPy's own
    open leaves the file open when an archive that starts like a zip is damaged. Yields the open
    ``.npz``, or the array of a ``.npy`` given instead; raises what ``NPZ_ERRORS`` names."""
    with open(path, "rb") as f:
        loaded = np.load(f, allow_pickle=False)
        if isinstance(loaded, np.lib.npyio.NpzFile):
            with loaded:
                yield loaded
        else:
            yield loaded


def npz_headers(npz: np.lib.npyio.NpzFile, only: tuple[str, ...] | None = None) -> dict[str, Header]:
    """The ``.npy`` arrays of an open ``.npz`` (those named in ``only``, when given) by name in lower
    case: (key, shape, dtype), from their headers alone (nothing is read)."""
    arrays = {}
    for member in npz.zip.namelist():
        if not member.endswith(".npy") or (only is not None and member.removesuffix(".npy") not in only):
            continue
        with npz.zip.open(member) as f:
            version = np.lib.format.read_magic(f)
            read = (
                np.lib.format.read_array_header_1_0
                if version == (1, 0)
                else np.lib.format.read_array_header_2_0
            )
            shape, _, dtype = read(f)
        arrays[member.removesuffix(".npy").lower()] = (member.removesuffix(".npy"), shape, dtype)
    return arrays


def npz_array(npz: np.lib.npyio.NpzFile, header: Header, path: Path) -> np.ndarray:
    """One array of an open ``.npz`` (``header``: its ``npz_headers`` entry), refused when it holds more
    than ``NPZ_MAX_VALUES`` values."""
    key, shape, _ = header
    if math.prod(shape) > NPZ_MAX_VALUES:
        raise InputError(f"array {key!r} holds {math.prod(shape)} values (more than {NPZ_MAX_VALUES})", path)
    return npz[key]
