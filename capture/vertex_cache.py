"""A mesh's animation as DCC tools cache it, read as frames x vertices x 3 (float32).

Maya's geometry cache (nCache): an ``.xml`` description (``cacheType`` ``Type`` ``OneFile`` or
``OneFilePerFrame`` and ``Format`` ``mcc`` or ``mcx``; ``time`` ``Range`` and ``cacheTimePerFrame`` in
ticks, 6000 a second; a ``channel<N>`` per cached object: ``ChannelName``, ``ChannelType``,
``SamplingRate``, ``StartTime``, ``EndTime``) beside its data: ``<name>.mc`` (``.mcx``), or one
``<name>Frame<N>.mc`` a frame. The data is IFF, big-endian: ``FOR4`` groups (32-bit sizes, chunks 4-byte
aligned; ``.mc``) or ``FOR8`` (tags padded to 8 bytes, 64-bit sizes, chunks 8-byte aligned; ``.mcx``).
A ``CACH`` group first (``VRSN``, ``STIM``, ``ETIM``), then a ``MYCH`` group per sample: ``TIME`` (in a
one-file cache), then per channel ``CHNM`` (its name), ``SIZE`` (element count) and ``FVCA``/``DVCA``
(float/double xyz). Blender's and 3ds Max's ``.pc2``: ``POINTCACHE2\\0``, version, point count, start
frame, sample rate (frames a sample), sample count (little-endian), then float32 xyz.

A damaged or lying file is a one-line ``InputError``; nothing is allocated before the file is known to
hold it."""

from __future__ import annotations

import itertools
import os
import re
import struct
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import InputError

TICKS_PER_SECOND = 6000  # Maya's time unit in a cache: 250 a frame at 24 fps
MAX_XML_BYTES = 1 << 20  # a description is a few kB; more is no cache description
PC2_HEADER = struct.Struct("<12siiffi")
PC2_MAGIC = b"POINTCACHE2\0"
# The vector arrays a channel holds positions in: (data tag, type in the .xml, big-endian dtype).
VECTOR_ARRAYS = {b"FVCA": ("FloatVectorArray", ">f4"), b"DVCA": ("DoubleVectorArray", ">f8")}
DATA_SUFFIX = {"mcc": ".mc", "mcx": ".mcx"}


@dataclass
class VertexCache:
    """What a vertex cache holds: its frames, their rate when the file gives one, the file read."""

    frames: np.ndarray  # frames x vertices x 3, float32
    rate: float | None  # frames per second (a Maya cache: 6000 / its channel's ticks a sample)
    path: Path  # the .xml of a Maya cache, the .pc2
    channel: str | None = None  # the Maya channel read
    data: Path | None = None  # a one-file Maya cache's .mc/.mcx


@dataclass
class _Sample:
    """Where one frame's positions lie: file, offset, vertex count, array tag, time in ticks."""

    path: Path
    offset: int
    count: int
    tag: bytes
    tick: int | None


def read_vertex_cache(path: str | Path, vertices: int | None = None) -> VertexCache:
    """The frames of a ``.pc2``, a Maya cache's ``.xml``, or a folder holding one (``<folder>.xml``, else
    its only ``.xml``). ``vertices``: the count a Maya cache's channel must have when it has several."""
    path = Path(path)
    if path.is_dir():
        return read_maya_cache(_description_in(path), vertices)
    suffix = path.suffix.lower()
    if suffix == ".pc2":
        return read_pc2(path)
    if suffix == ".xml":
        return read_maya_cache(path, vertices)
    raise InputError("not a vertex cache this reads (a .pc2, a Maya cache's .xml or its folder)", path)


def read_pc2(path: str | Path) -> VertexCache:
    """A ``.pc2`` point cache: its samples (frames x points x 3). Its sample rate is frames a sample, not a
    frame rate: no rate is given."""
    path = Path(path)
    with _open(path) as f:
        size = os.fstat(f.fileno()).st_size
        head = f.read(PC2_HEADER.size)
        if len(head) < PC2_HEADER.size or not head.startswith(PC2_MAGIC):
            raise InputError("not a .pc2 point cache (no POINTCACHE2 header)", path)
        _, version, points, start, step, samples = PC2_HEADER.unpack(head)
        if version != 1:
            raise InputError(f"a .pc2 of version {version}, not 1", path)
        if points <= 0 or samples <= 0:
            raise InputError(f"a .pc2 of {points} points and {samples} samples: nothing to read", path)
        expected = PC2_HEADER.size + points * samples * 12
        if size != expected:
            raise InputError(
                f"a .pc2 of {size} bytes, its header ({samples} samples of {points} points) says {expected}",
                path,
            )
        frames = np.frombuffer(f.read(expected - PC2_HEADER.size), "<f4").reshape(samples, points, 3)
    return VertexCache(frames.astype(np.float32), None, path)


def read_maya_cache(xml: str | Path, vertices: int | None = None) -> VertexCache:
    """A Maya geometry cache from its ``.xml`` and the ``.mc``/``.mcx`` data beside it: the frames of its
    one channel of vector arrays (of several, the one of ``vertices`` vertices)."""
    xml = Path(xml)
    desc = _description(xml)
    suffix = DATA_SUFFIX[desc["format"]]
    if desc["type"] == "OneFile":
        data = xml.with_suffix(suffix)
        if not data.is_file():
            raise InputError(f"no {data.name} beside this Maya cache description", xml)
        frames = _one_file_samples(data)
    else:
        data, frames = None, _per_frame_samples(xml, desc, suffix)
    name = _channel(xml, desc["channels"], frames[0], vertices)
    samples = [_sample_of(f, name) for f in frames]
    ticks = [s.tick for s in samples]
    if any(b is not None and a is not None and b <= a for a, b in zip(ticks, ticks[1:])):
        raise InputError(f"the frames of {samples[0].path.name} are not in time order", xml)
    step, end = desc["channels"][name]
    if ticks[-1] is not None and ticks[-1] < end - step / 2:
        raise InputError(
            f"{samples[-1].path.name} ends at tick {ticks[-1]}, the description's range at {end}: cut short",
            xml,
        )
    count = samples[0].count
    for s in samples:
        if s.count != count:
            raise InputError(f"a frame of {s.count} vertices after frames of {count}", s.path)
    out = np.empty((len(samples), count, 3), np.float32)
    i = 0
    for file, group in itertools.groupby(samples, lambda s: s.path):  # a one-file cache: opened once
        with _open(file) as f:
            for s in group:
                dtype = np.dtype(VECTOR_ARRAYS[s.tag][1])
                f.seek(s.offset)
                out[i] = np.frombuffer(f.read(count * 3 * dtype.itemsize), dtype).reshape(count, 3)
                i += 1
    return VertexCache(out, TICKS_PER_SECOND / step, xml, name, data)


def _open(path: Path):
    try:
        return open(path, "rb")
    except OSError as exc:
        raise InputError(f"cannot be read ({exc.strerror or exc})", path) from None


def _description_in(folder: Path) -> Path:
    """The ``.xml`` of the Maya cache a folder holds: ``<folder>.xml``, else its only one."""
    named = folder / f"{folder.name}.xml"
    if named.is_file():
        return named
    found = sorted(p for p in folder.glob("*.xml") if p.is_file() and not p.name.startswith("."))
    if len(found) != 1:
        held = "no .xml" if not found else f"{len(found)} .xml files and none named {named.name}"
        raise InputError(f"a Maya cache's folder holding {held}", folder)
    return found[0]


def _description(xml: Path) -> dict:
    """The facts of a cache's ``.xml`` read here: type, format, ticks a frame, and per channel of vector
    arrays its ticks a sample and end tick."""
    with _open(xml) as f:
        text = f.read(MAX_XML_BYTES + 1)
    if len(text) > MAX_XML_BYTES:
        raise InputError(f"over {MAX_XML_BYTES >> 10} kB: no Maya cache description", xml)
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise InputError(f"not readable XML ({exc})", xml) from None
    if root.tag != "Autodesk_Cache_File":
        raise InputError(f"XML whose root is <{root.tag}>, not a Maya cache's <Autodesk_Cache_File>", xml)
    kind = root.find("cacheType")
    kind = {} if kind is None else kind.attrib
    cache_type, cache_format = kind.get("Type", ""), kind.get("Format", "mcc").lower()
    if cache_type not in ("OneFile", "OneFilePerFrame"):
        raise InputError(
            f"a Maya cache of type {cache_type or 'none'!r}, not OneFile or OneFilePerFrame", xml
        )
    if cache_format not in DATA_SUFFIX:
        raise InputError(f"a Maya cache of format {cache_format!r}, not mcc or mcx", xml)
    per_frame = _ticks(xml, root.find("cacheTimePerFrame"), "TimePerFrame", positive=True)
    span = root.find("time")
    found = re.fullmatch(r"\s*(-?\d+)\s*-\s*(-?\d+)\s*", "" if span is None else span.get("Range", ""))
    if found is None or int(found[1]) > int(found[2]):
        raise InputError("a Maya cache description without a time Range (start-end ticks)", xml)
    channels = {}
    types = [t for t, _ in VECTOR_ARRAYS.values()]
    for element in root.iterfind("Channels/*"):
        if element.tag.startswith("channel") and element.get("ChannelType") in types:
            step = _ticks(xml, element, "SamplingRate", positive=True, default=per_frame)
            end = _ticks(xml, element, "EndTime", default=int(found[2]))
            channels[element.get("ChannelName", "")] = (step, end)
    if not channels:
        raise InputError(
            "a Maya cache description with no channel of FloatVectorArray/DoubleVectorArray", xml
        )
    return {
        "type": cache_type,
        "format": cache_format,
        "per_frame": per_frame,
        "range": (int(found[1]), int(found[2])),
        "channels": channels,
    }


def _ticks(xml: Path, element, name: str, positive: bool = False, default: int | None = None) -> int:
    """An attribute of ``element`` in ticks (an integer; ``default`` when absent)."""
    value = None if element is None else element.get(name)
    if value is None and default is not None:
        return default
    try:
        ticks = int(value)
    except (TypeError, ValueError):
        raise InputError(f"a Maya cache description whose {name} is {value!r}, not ticks", xml) from None
    if positive and ticks <= 0:
        raise InputError(f"a Maya cache description whose {name} is {ticks}", xml)
    return ticks


def _channel(xml: Path, channels: dict, first: dict, vertices: int | None) -> str:
    """The channel read: the one vector-array channel, else the one of ``vertices`` vertices."""
    names = list(channels)
    if len(names) > 1 and vertices is not None:
        names = [n for n in names if n in first and first[n][2] == vertices]
    if len(names) != 1:
        which = ", ".join(repr(n) for n in channels)
        more = f" and {'none' if not names else 'several'} of {vertices} vertices" if vertices else ""
        raise InputError(f"a Maya cache of channels {which}{more}: which one to read is not known", xml)
    return names[0]


def _sample_of(frame: dict, name: str) -> _Sample:
    if name not in frame:
        raise InputError(f"a frame (tick {frame['']}) without channel {name!r}", frame["path"])
    offset, tag, count = frame[name]
    return _Sample(frame["path"], offset, count, tag, frame[""])


class _Chunks:
    """The chunks of one ``.mc``/``.mcx`` file, each checked to lie inside its group and the file."""

    def __init__(self, f, path: Path):
        self.f, self.path = f, path
        self.size = os.fstat(f.fileno()).st_size
        magic = self.read(0, 4)
        if magic not in (b"FOR4", b"FOR8"):
            raise InputError(f"not a Maya cache's data (starts {magic!r}, not FOR4 or FOR8)", path)
        self.form = magic
        wide = magic == b"FOR8"
        self.tag_bytes, self.size_format, self.align = (8, ">Q", 8) if wide else (4, ">I", 4)
        self.header = self.tag_bytes + struct.calcsize(self.size_format)

    def read(self, offset: int, n: int) -> bytes:
        self.f.seek(offset)
        data = self.f.read(n)
        if len(data) != n:
            raise InputError(
                f"cut short: {n} bytes wanted at byte {offset}, the file ends at {self.size}", self.path
            )
        return data

    def chunk(self, offset: int, end: int) -> tuple[bytes, int, int]:
        """(tag, data offset, data size) of the chunk at ``offset`` of a group ending at ``end``."""
        if offset + self.header > end:
            raise InputError(
                f"cut short: a chunk at byte {offset} runs past its group's end ({end})", self.path
            )
        head = self.read(offset, self.header)
        tag = head[:4]
        (size,) = struct.unpack(self.size_format, head[self.tag_bytes :])
        if offset + self.header + size > end:
            where = "the file's end" if end == self.size else "its group's end"
            raise InputError(
                f"cut short: chunk {tag.decode('latin-1')!r} at byte {offset} claims {size} bytes, past "
                f"{where} ({end})",
                self.path,
            )
        return tag, offset + self.header, size

    def groups(self):
        """(type, first child offset, end) of each top-level group, in order."""
        offset = 0
        while offset < self.size:
            tag, data, size = self.chunk(offset, self.size)
            if tag != self.form:
                raise InputError(
                    f"a chunk {tag!r} at byte {offset} where a {self.form.decode()} group was", self.path
                )
            if size < 4:
                raise InputError(f"an empty group at byte {offset}", self.path)
            yield self.read(data, 4), data + 4, data + size
            offset = data + size
            if offset % self.align and offset < self.size and self.read(offset, 4) != self.form:  # padding
                offset += -offset % self.align

    def children(self, offset: int, end: int):
        """(tag, data offset, size) of each chunk of a group, padding skipped."""
        while offset < end:
            tag, data, size = self.chunk(offset, end)
            yield tag, data, size
            offset = data + size + (-size % self.align)

    def integer(self, data: int, size: int, tag: bytes) -> int:
        if size != 4:
            raise InputError(f"a {tag.decode()} chunk of {size} bytes, not 4", self.path)
        return struct.unpack(">i", self.read(data, 4))[0]


def _frames_in(path: Path) -> tuple[list[dict], int | None]:
    """Each ``MYCH`` group of a data file as ``{channel: (data offset, tag, count), "": tick, "path":
    path}`` (its ``TIME``, else None), and the ``STIM`` of its header."""
    with _open(path) as f:
        chunks = _Chunks(f, path)
        frames, start = [], None
        for n, (kind, offset, end) in enumerate(chunks.groups()):
            if n == 0:
                if kind != b"CACH":
                    raise InputError(f"a first group {kind!r}, not the CACH header", path)
                for tag, data, size in chunks.children(offset, end):
                    if tag == b"STIM":
                        start = chunks.integer(data, size, tag)
                continue
            if kind != b"MYCH":
                continue  # a group this reader has no use for
            frame: dict = {"": None, "path": path}
            name = count = None
            for tag, data, size in chunks.children(offset, end):
                if tag == b"TIME":
                    frame[""] = chunks.integer(data, size, tag)
                elif tag == b"CHNM":
                    name, count = chunks.read(data, size).split(b"\0")[0].decode("utf-8", "replace"), None
                elif tag == b"SIZE":
                    count = chunks.integer(data, size, tag)
                elif name is not None:
                    if tag in VECTOR_ARRAYS:
                        width = np.dtype(VECTOR_ARRAYS[tag][1]).itemsize * 3
                        if count is None or count < 0 or count * width != size:
                            raise InputError(
                                f"channel {name!r}: SIZE {count} vectors, its {tag.decode()} {size} bytes",
                                path,
                            )
                        frame[name] = (data, tag, count)
                    name = None
            frames.append(frame)
    return frames, start


def _one_file_samples(data: Path) -> list[dict]:
    frames, _ = _frames_in(data)
    if not frames:
        raise InputError("a Maya cache's data with no frame (no MYCH group)", data)
    if any(f[""] is None for f in frames):
        raise InputError("a one-file Maya cache with a frame without its TIME", data)
    return frames


def _per_frame_samples(xml: Path, desc: dict, suffix: str) -> list[dict]:
    """The frames of a one-file-per-frame cache: ``<name>Frame<N>[Tick<T>]<suffix>`` for each sample of
    its range, each a data file whose header's ``STIM`` is its time."""
    (start, end), per_frame = desc["range"], desc["per_frame"]
    step = min(s for s, _ in desc["channels"].values())
    wanted = (end - start) // step + 1
    held = sum(1 for _ in xml.parent.iterdir())
    if wanted > held:
        raise InputError(
            f"a range of {wanted} frames ({start}-{end} ticks), and its folder holds {held} files", xml
        )
    frames = []
    for tick in range(start, end + 1, step):
        frame, sub = divmod(tick, per_frame)
        name = f"{xml.stem}Frame{frame}{f'Tick{sub}' if sub else ''}{suffix}"
        if not (xml.parent / name).is_file():
            raise InputError(f"no {name} (tick {tick} of its range {start}-{end})", xml)
        found, stim = _frames_in(xml.parent / name)
        if len(found) != 1:
            raise InputError(f"a frame's file holding {len(found)} frames, not 1", xml.parent / name)
        if found[0][""] is None:
            found[0][""] = stim
        frames.append(found[0])
    return frames
