"""Shards: tar files in the WebDataset layout, written deterministically and atomically.

One sample = consecutive members sharing a key (the member name up to its first dot):
``KEY.json``, ``KEY.flac``, ``KEY.anim.npy``, ``KEY.mask.npy``, ``KEY.<feature>.npy`` [, ``KEY.phones.npy``].
Samples are sorted by key and members by name within a sample; every header has mtime 0, uid/gid 0,
empty user/group names and mode 0644, so the same samples always give the same bytes. A shard is
written under a hidden temporary name, fsynced and renamed into place. Readable with the
``webdataset`` library and with plain ``tarfile``.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import os
import tarfile
import tokenize
from collections.abc import Collection, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from capture.atomic import partial_path
from capture.command import stops_deferred
from capture.errors import InputError, loads_names, strict_names

BLOCK = tarfile.BLOCKSIZE
RECORD = tarfile.RECORDSIZE
# A sample's optional member: which channels are usable in which frames, where that differs (dataset.md)
CHANNEL_MASK = "channel_mask.npy"


def channel_mask_problem(
    channel_mask: np.ndarray, mask: np.ndarray, n_channels: int, name: str = "channel_mask"
) -> str | None:
    """Why a sample's ``channel_mask`` (``name`` in the message) is not (frames, ``n_channels``) bool
    whose frames usable in every channel are those ``mask`` (frames,) marks usable, and no other; None
    if it is (the reader's and ``dataset validate``'s check)."""
    shape = (mask.shape[0], n_channels)
    if channel_mask.dtype != np.bool_ or channel_mask.shape != shape:
        return f"{name} is {channel_mask.dtype} of shape {channel_mask.shape}, expected bool of shape {shape}"
    differ = np.flatnonzero(channel_mask.all(axis=1) != mask.astype(bool, copy=False))
    if differ.size:
        return (
            f"{name}: {differ.size} frame(s) usable in every channel here but not in mask.npy, or the "
            f"other way round (first at frame {int(differ[0])})"
        )
    return None


def member_size(nbytes: int) -> int:
    """Bytes a member of ``nbytes`` takes in a tar (header + data padded to 512)."""
    return BLOCK + (nbytes + BLOCK - 1) // BLOCK * BLOCK


def sample_size(members: dict[str, bytes]) -> int:
    return sum(member_size(len(b)) for b in members.values())


def split_key(name: str) -> tuple[str, str]:
    """``("KEY", "ext")`` of a member name ``KEY.ext`` (WebDataset: key up to the first dot)."""
    base = name.rsplit("/", 1)[-1]
    if "." not in base:
        return base, ""
    key, ext = base.split(".", 1)
    prefix = name[: len(name) - len(base)]
    return prefix + key, ext


def npy_bytes(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(array), allow_pickle=False)
    return buf.getvalue()


def json_bytes(data: Any) -> bytes:
    """A sample's JSON member: compact, keys sorted, a name not UTF-8 as messages show it with its bytes
    beside it (``strict_names``: strict JSON, which ``decode_json_object`` reads back as the name)."""
    text = json.dumps(strict_names(data), sort_keys=True, allow_nan=False, separators=(",", ":"))
    return (text + "\n").encode()


class _HashingFile(io.RawIOBase):
    """A file that hashes and counts what passes through it, written or read."""

    def __init__(self, f):
        self.f = f
        self.sha = hashlib.sha256()
        self.bytes = 0

    def writable(self) -> bool:
        return True

    def readable(self) -> bool:
        return True

    def tell(self) -> int:
        return self.bytes

    def _passed(self, b) -> None:
        self.sha.update(b)
        self.bytes += len(b)

    def write(self, b) -> int:
        self.f.write(b)
        self._passed(b)
        return len(b)

    def read(self, size: int = -1) -> bytes:
        b = self.f.read(size)
        self._passed(b)
        return b


@dataclass
class ShardInfo:
    """A written shard: file name, sha256, size in bytes and the keys it holds, in order."""

    name: str
    sha256: str
    bytes: int
    keys: list[str]


class ShardWriter:
    """Writes one shard file from samples ``(key, {ext: bytes})`` given in key order. Its partial file is
    made as ``with`` takes the writer (or at the first ``add`` or ``close`` of a writer used without it),
    not as the writer is made: a stop met between the two left it, with nobody to remove it."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.tmp = partial_path(self.path)
        self._file = None
        self._tar: tarfile.TarFile | None = None
        self._keys: list[str] = []

    def _opened(self) -> tarfile.TarFile:
        """The tar being written into the partial file, both made on first need."""
        if self._tar is None:
            try:
                # Ctrl-C and SIGTERM wait until the file is noted here: met as it was made, a stop left it
                with stops_deferred():
                    self._file = open(self.tmp, "wb")
                self._hash = _HashingFile(self._file)
                self._tar = tarfile.open(fileobj=self._hash, mode="w", format=tarfile.PAX_FORMAT)
            except BaseException:  # before ``with`` holds it: nobody else would remove the file
                self.abort()
                raise
        return self._tar

    def add(self, key: str, members: dict[str, bytes]) -> None:
        if "." in key or "/" in key or not key:
            raise InputError(f"sample key {key!r} may not be empty or contain '.' or '/'")
        if self._keys and key <= self._keys[-1]:
            raise InputError(
                f"sample keys must be written in increasing order ({key!r} after {self._keys[-1]!r})"
            )
        tar = self._opened()
        for ext in sorted(members):
            data = members[ext]
            info = tarfile.TarInfo(f"{key}.{ext}")
            info.size = len(data)
            info.mtime = 0
            info.mode = 0o644
            info.uid = info.gid = 0
            info.uname = info.gname = ""
            tar.addfile(info, io.BytesIO(data))
        self._keys.append(key)

    def close(self) -> ShardInfo:
        """Finish the tar, fsync and rename it into place."""
        self._opened().close()
        self._file.flush()
        os.fsync(self._file.fileno())
        self._file.close()
        os.replace(self.tmp, self.path)
        return ShardInfo(self.path.name, self._hash.sha.hexdigest(), self._hash.bytes, list(self._keys))

    def abort(self) -> None:
        """Remove the partial file this writer made (none yet: nothing to do)."""
        if self._file is None:
            return
        try:
            self._file.close()
        finally:
            with stops_deferred():  # a second Ctrl-C cuts no removal short
                self.tmp.unlink(missing_ok=True)

    def __enter__(self) -> ShardWriter:
        try:
            self._opened()
        except BaseException:  # a stop met as the call returned, outside its own clean-up
            self.abort()
            raise
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self.abort()


class ShardReader:
    """Iterates the samples of a shard with plain ``tarfile`` (streaming, constant memory).

    Yields ``(key, {ext: bytes})`` for each run of consecutive members sharing a key; with ``exts``,
    only the members of those extensions (the others are skipped unread, so a reader that does not use
    the audio does not hold it). Raises ``InputError`` naming the shard when the tar is damaged, a
    member appears twice in a sample (whether read or skipped) or, with ``sha256`` (the manifest's), when
    the shard read to its end hashes otherwise (after its last sample: the bytes are hashed as they
    stream by; a reader that stops early checks nothing). ``digest`` is then the shard's sha256."""

    def __init__(self, path: str | Path, exts: Collection[str] | None = None, sha256: str | None = None):
        self.path = Path(path)
        self.exts = None if exts is None else frozenset(exts)
        self.sha256 = sha256
        self.digest: str | None = None

    def __iter__(self) -> Iterator[tuple[str, dict[str, bytes]]]:
        key: str | None = None
        members: dict[str, bytes] = {}
        seen: set[str] = set()  # the extensions of the sample's members, read or skipped
        try:
            with open(self.path, "rb") as raw:
                stream = _HashingFile(raw) if self.sha256 is not None else raw
                with tarfile.open(fileobj=stream, mode="r|") as tar:
                    for info in tar:
                        if not info.isfile():
                            continue
                        k, ext = split_key(info.name)
                        if k != key:
                            if key is not None:
                                yield key, members
                            key, members, seen = k, {}, set()
                        if ext in seen:
                            raise InputError(f"member {info.name} appears twice in a row", self.path)
                        seen.add(ext)
                        if self.exts is not None and ext not in self.exts:
                            continue
                        f = tar.extractfile(info)
                        data = f.read() if f is not None else b""
                        if len(data) != info.size:
                            raise InputError(f"member {info.name} is truncated", self.path)
                        members[ext] = data
                if isinstance(stream, _HashingFile):
                    while stream.read(1 << 20):  # the end-of-archive blocks and padding tarfile left unread
                        pass
                    self.digest = stream.sha.hexdigest()
        except FileNotFoundError:
            raise InputError("shard not found", self.path) from None
        except (tarfile.TarError, EOFError, OSError) as exc:
            raise InputError(f"shard is not a readable tar ({exc})", self.path) from None
        if key is not None:
            yield key, members
        if self.digest is not None and self.digest != self.sha256:
            raise InputError(
                f"sha256 {self.digest[:16]}... differs from the manifest's {self.sha256[:16]}...: its bytes "
                f"changed since the build (a damaged shard? s2a-dataset validate {self.path.parent})",
                self.path,
            )


# NumPy reads version 3.0 (2.0 with a UTF-8 header, for non-latin-1 field names) only privately
_read_npy_header = getattr(np.lib, "_format_impl", np.lib.format)._read_array_header
NPY_HEADER_READERS = {
    (1, 0): np.lib.format.read_array_header_1_0,
    (2, 0): np.lib.format.read_array_header_2_0,
    (3, 0): lambda f: _read_npy_header(f, (3, 0)),
}


def decode_npy(data: bytes, what: str = "array") -> np.ndarray:
    """An array from ``.npy`` bytes, for any untrusted ``.npy`` (a shard member, a take's file): the
    header is parsed and checked first (a dtype without Python objects, so nothing is unpickled; a
    shape whose data the bytes hold), so a damaged header is an ``InputError`` naming ``what`` and a
    header declaring a huge shape allocates nothing."""
    f = io.BytesIO(data)
    try:
        version = np.lib.format.read_magic(f)
        if version not in NPY_HEADER_READERS:
            raise ValueError(f"unsupported .npy version {version[0]}.{version[1]}")
        shape, fortran_order, dtype = NPY_HEADER_READERS[version](f)
    except (ValueError, SyntaxError, EOFError, OSError) as exc:
        raise InputError(f"{what} is not a readable .npy ({exc})") from None
    except tokenize.TokenError as exc:  # NumPy's header parser on an unclosed bracket
        raise InputError(f"{what} is not a readable .npy (its header is cut short: {exc.args[0]})") from None
    if dtype.hasobject:
        raise InputError(f"{what} holds Python objects (dtype {dtype}), which are never unpickled")
    if dtype.itemsize == 0:
        raise InputError(f"{what} is not a readable .npy (dtype {dtype} has no size)")
    if any(d < 0 for d in shape):
        raise InputError(
            f"{what} is not a readable .npy (its header declares shape {shape}: a negative size)"
        )
    count = math.prod(shape)
    held = len(data) - f.tell()
    if count * dtype.itemsize > held:
        raise InputError(
            f"{what} is not a readable .npy (its header declares shape {shape} of {dtype}, "
            f"{count * dtype.itemsize} bytes; the file holds {held})"
        )
    flat = np.frombuffer(data, dtype, count, offset=f.tell())
    array = flat.reshape(shape[::-1]).T if fortran_order else flat.reshape(shape)
    return array.copy(order="K")  # writable and owning its memory, as np.load's


def decode_json_object(data: bytes, what: str = "metadata") -> dict[str, Any]:
    """A JSON object from bytes, each name not UTF-8 as Python holds it (``loads_names``); anything
    else (not UTF-8, not JSON, nested past Python's limits, not an object) is an ``InputError`` naming
    ``what``."""
    try:
        value = loads_names(data)
    except (ValueError, RecursionError) as exc:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        reason = "nested too deeply" if isinstance(exc, RecursionError) else str(exc)
        raise InputError(f"{what} is not a JSON object ({reason})") from None
    if not isinstance(value, dict):
        raise InputError(f"{what} is not a JSON object")
    return value


def decode_flac(data: bytes) -> tuple[np.ndarray, int]:
    """Mono float32 samples and the sample rate (Hz) of FLAC bytes."""
    import soundfile as sf

    try:
        x, rate = sf.read(io.BytesIO(data), dtype="float32", always_2d=False)
    except (sf.LibsndfileError, RuntimeError, TypeError) as exc:
        raise InputError(f"audio is not readable FLAC ({str(exc).split(': ', 1)[-1]})") from None
    return x, int(rate)


def flac_bytes(samples: np.ndarray, sample_rate: int, subtype: str = "PCM_24") -> bytes:
    """FLAC bytes of mono float samples in [-1, 1) (24-bit by default)."""
    import soundfile as sf

    buf = io.BytesIO()
    sf.write(buf, np.clip(samples, -1.0, 1.0 - 2**-23), int(sample_rate), format="FLAC", subtype=subtype)
    return buf.getvalue()
