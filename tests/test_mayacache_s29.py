"""Vertex caches as Maya and Blender/3ds Max write them (capture/vertex_cache.py): real files written here
from known vertex arrays in each layout (FOR4 .mc and FOR8 .mcx, one file and one file a frame, float and
double vectors, .pc2) read back exactly; damaged and lying files are one-line errors naming the file."""

from __future__ import annotations

import struct
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from capture.errors import InputError
from capture.vertex_cache import read_maya_cache, read_pc2, read_vertex_cache

TPF = 200  # ticks a frame at 30 fps


def _chunk(tag: bytes, payload: bytes, wide: bool) -> bytes:
    """An IFF chunk: FOR4 files a 4-byte tag and size, data padded to 4; FOR8 files the tag padded to 8
    bytes, a 64-bit size, data padded to 8."""
    if wide:
        return tag + b"\0" * 4 + struct.pack(">Q", len(payload)) + payload + b"\0" * (-len(payload) % 8)
    return tag + struct.pack(">I", len(payload)) + payload + b"\0" * (-len(payload) % 4)


def _group_bytes(kind: bytes, children: list[bytes], wide: bool) -> bytes:
    """A FOR4/FOR8 group: its header, its type, its chunks (the size counts the type and chunks)."""
    body = kind + b"".join(children)
    if wide:
        return b"FOR8" + b"\0" * 4 + struct.pack(">Q", len(body)) + body
    return b"FOR4" + struct.pack(">I", len(body)) + body


def _i32(value: int) -> bytes:
    return struct.pack(">i", value)


def _header(start: int, end: int, wide: bool) -> bytes:
    parts = [(b"VRSN", b"0.1\0"), (b"STIM", _i32(start)), (b"ETIM", _i32(end))]
    return _group_bytes(b"CACH", [_chunk(t, p, wide) for t, p in parts], wide)


def _frame(channels: dict[str, np.ndarray], wide: bool, double: bool, tick: int | None) -> bytes:
    children = [] if tick is None else [_chunk(b"TIME", _i32(tick), wide)]
    for name, points in channels.items():
        tag, dtype = (b"DVCA", ">f8") if double else (b"FVCA", ">f4")
        children += [
            _chunk(b"CHNM", name.encode() + b"\0", wide),
            _chunk(b"SIZE", _i32(len(points)), wide),
            _chunk(tag, points.astype(dtype).tobytes(), wide),
        ]
    return _group_bytes(b"MYCH", children, wide)


def _xml(path: Path, kind: str, fmt: str, end: int, channels: dict[str, bool], rate: int = TPF) -> None:
    lines = "".join(
        f'<channel{i} ChannelName="{name}" ChannelType="{"Double" if double else "Float"}VectorArray" '
        f'ChannelInterpretation="positions" SamplingType="Regular" SamplingRate="{rate}" StartTime="0" '
        f'EndTime="{end}"/>\n'
        for i, (name, double) in enumerate(channels.items())
    )
    path.write_text(
        f'<?xml version="1.0"?>\n<Autodesk_Cache_File>\n<cacheType Type="{kind}" Format="{fmt}"/>\n'
        f'<time Range="0-{end}"/>\n<cacheTimePerFrame TimePerFrame="{TPF}"/>\n<cacheVersion Version="2.0"/>\n'
        f"<extra>maya 2024 x64</extra>\n<Channels>\n{lines}</Channels>\n</Autodesk_Cache_File>\n"
    )


def write_maya_cache(
    folder: Path, name: str, frames: np.ndarray, *, wide: bool, double: bool, per_frame: bool, others=None
) -> Path:
    """A Maya geometry cache of ``frames`` (channel ``headShape``, 30 fps) as Maya lays it out: the
    ``.xml`` and one ``.mc``/``.mcx``, or one ``<name>Frame<N>`` file a frame; returns the ``.xml``."""
    folder.mkdir(parents=True, exist_ok=True)
    suffix = ".mcx" if wide else ".mc"
    end = (len(frames) - 1) * TPF
    channels = {"headShape": frames, **(others or {})}
    kind = "OneFilePerFrame" if per_frame else "OneFile"
    _xml(folder / f"{name}.xml", kind, "mcx" if wide else "mcc", end, dict.fromkeys(channels, double))
    if per_frame:
        for i in range(len(frames)):
            data = _header(i * TPF, i * TPF, wide) + _frame(
                {k: v[i] for k, v in channels.items()}, wide, double, None
            )
            (folder / f"{name}Frame{i}{suffix}").write_bytes(data)
    else:
        body = b"".join(
            _frame({k: v[i] for k, v in channels.items()}, wide, double, i * TPF) for i in range(len(frames))
        )
        (folder / f"{name}{suffix}").write_bytes(_header(0, end, wide) + body)
    return folder / f"{name}.xml"


def write_pc2(path: Path, frames: np.ndarray, start: float = 1.0, step: float = 1.0) -> Path:
    header = struct.pack("<12siiffi", b"POINTCACHE2\0", 1, frames.shape[1], start, step, frames.shape[0])
    path.write_bytes(header + frames.astype("<f4").tobytes())
    return path


def _mesh(frames: int = 7, vertices: int = 11, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(frames, vertices, 3)).astype(np.float32)


def _error(call, *args, **kwargs) -> str:
    with pytest.raises(InputError) as caught:
        call(*args, **kwargs)
    text = str(caught.value)
    assert "\n" not in text and "Traceback" not in text
    return text


@pytest.mark.parametrize("per_frame", [False, True], ids=["OneFile", "OneFilePerFrame"])
@pytest.mark.parametrize("double", [False, True], ids=["float", "double"])
@pytest.mark.parametrize("wide", [False, True], ids=["FOR4", "FOR8"])
def test_maya_cache_reads_back_exactly(tmp_path, wide, double, per_frame):
    frames = _mesh()
    xml = write_maya_cache(tmp_path / "cp1_neutral", "cp1_neutral", frames, wide=wide, double=double,
                           per_frame=per_frame)  # fmt: skip
    cache = read_maya_cache(xml)
    assert cache.frames.dtype == np.float32 and cache.frames.shape == frames.shape
    np.testing.assert_array_equal(cache.frames, frames)
    assert cache.rate == 30.0 and cache.channel == "headShape" and cache.path == xml
    assert cache.data == (None if per_frame else xml.with_suffix(".mcx" if wide else ".mc"))
    # the shot's folder, as the Audio2Face-3D dataset lays it out (cache/skin/<shot>/<shot>.xml)
    np.testing.assert_array_equal(read_vertex_cache(xml.parent).frames, frames)


def test_documented_for4_bytes(tmp_path):
    """A one-file-per-frame data file spelled out byte by byte as public notes on the format show one
    (FOR4, 'CACH' with VRSN '0.1', STIM and ETIM 250: frame 1 at 24 fps; a MYCH without TIME)."""
    points = np.array([[1.0, 2.0, 3.0], [-4.5, 0.25, 8.0]], np.float32)
    data = (
        bytes.fromhex("464f5234 00000028 43414348 5652534e 00000004 302e3100 5354494d 00000004")
        + bytes.fromhex("000000fa 4554494d 00000004 000000fa")
        + b"FOR4" + struct.pack(">I", 4 + 8 + 8 + 8 + 4 + 8 + 24) + b"MYCH"
        + b"CHNM" + struct.pack(">I", 5) + b"skin\0\0\0\0"
        + b"SIZE" + struct.pack(">I", 4) + struct.pack(">i", 2)
        + b"FVCA" + struct.pack(">I", 24) + points.astype(">f4").tobytes()
    )  # fmt: skip
    (tmp_path / "shotFrame1.mc").write_bytes(data)
    (tmp_path / "shot.xml").write_text(
        '<Autodesk_Cache_File><cacheType Type="OneFilePerFrame" Format="mcc"/><time Range="250-250"/>'
        '<cacheTimePerFrame TimePerFrame="250"/><Channels><channel0 ChannelName="skin" '
        'ChannelType="FloatVectorArray" SamplingRate="250" StartTime="250" EndTime="250"/></Channels>'
        "</Autodesk_Cache_File>"
    )
    cache = read_vertex_cache(tmp_path / "shot.xml")
    np.testing.assert_array_equal(cache.frames, points[None])
    assert cache.rate == 24.0


def test_several_channels_chosen_by_vertex_count(tmp_path):
    frames, teeth = _mesh(), _mesh(vertices=4, seed=1)
    xml = write_maya_cache(tmp_path, "s", frames, wide=False, double=False, per_frame=False,
                           others={"teethShape": teeth})  # fmt: skip
    np.testing.assert_array_equal(read_maya_cache(xml, vertices=4).frames, teeth)
    np.testing.assert_array_equal(read_maya_cache(xml, vertices=11).frames, frames)
    assert "which one to read" in _error(read_maya_cache, xml)
    assert "none of 5 vertices" in _error(read_maya_cache, xml, vertices=5)


def test_pc2_reads_back_exactly(tmp_path):
    frames = _mesh(frames=5, vertices=9)
    cache = read_vertex_cache(write_pc2(tmp_path / "cp2_neutral.pc2", frames))
    np.testing.assert_array_equal(cache.frames, frames)
    assert cache.frames.dtype == np.float32 and cache.rate is None  # its sample rate is frames a sample


def test_damaged_pc2(tmp_path):
    good = write_pc2(tmp_path / "a.pc2", _mesh(frames=3, vertices=4))
    raw = good.read_bytes()
    (tmp_path / "magic.pc2").write_bytes(b"POINTCACHE3\0" + raw[12:])
    assert "magic.pc2: not a .pc2" in _error(read_pc2, tmp_path / "magic.pc2")
    (tmp_path / "short.pc2").write_bytes(raw[:-5])
    assert "says" in _error(read_pc2, tmp_path / "short.pc2")
    (tmp_path / "tiny.pc2").write_bytes(raw[:20])
    assert "tiny.pc2" in _error(read_pc2, tmp_path / "tiny.pc2")
    lying = struct.pack("<12siiffi", b"POINTCACHE2\0", 1, 2**30, 0.0, 1.0, 2**30) + raw[32:]
    (tmp_path / "lying.pc2").write_bytes(lying)
    tracemalloc.start()
    try:
        assert "lying.pc2" in _error(read_pc2, tmp_path / "lying.pc2")
        assert tracemalloc.get_traced_memory()[1] < 10 << 20  # the header's 2**60 points never allocated
    finally:
        tracemalloc.stop()
    (tmp_path / "neg.pc2").write_bytes(struct.pack("<12siiffi", b"POINTCACHE2\0", 1, -3, 0.0, 1.0, 2))
    assert "nothing to read" in _error(read_pc2, tmp_path / "neg.pc2")


@pytest.mark.parametrize("wide", [False, True], ids=["FOR4", "FOR8"])
def test_damaged_maya_data(tmp_path, wide):
    frames = _mesh(frames=4, vertices=5)
    xml = write_maya_cache(tmp_path, "s", frames, wide=wide, double=False, per_frame=False)
    data = xml.with_suffix(".mcx" if wide else ".mc")
    raw = data.read_bytes()

    data.write_bytes(b"RIFF" + raw[4:])
    assert f"{data.name}: not a Maya cache's data" in _error(read_maya_cache, xml)
    data.write_bytes(raw[:-7])  # cut inside the last frame
    assert "cut short" in _error(read_maya_cache, xml)
    last = raw.rindex(b"FOR8" if wide else b"FOR4")
    data.write_bytes(raw[:last])  # cut at a frame's start: the range says one more
    assert "cut short" in _error(read_maya_cache, xml)

    size = raw.index(b"SIZE") + (16 if wide else 8)
    data.write_bytes(raw[:size] + _i32(10**9) + raw[size + 4 :])  # a lying element count
    assert "SIZE 1000000000 vectors" in _error(read_maya_cache, xml)
    vectors = raw.index(b"FVCA") + (8 if wide else 4)
    huge = struct.pack(">Q", 2**62) if wide else struct.pack(">I", 2**31)
    data.write_bytes(raw[:vectors] + huge + raw[vectors + len(huge) :])  # a size past the end
    tracemalloc.start()
    try:
        assert "past" in _error(read_maya_cache, xml)
        assert tracemalloc.get_traced_memory()[1] < 10 << 20
    finally:
        tracemalloc.stop()
    data.write_bytes(raw.replace(b"headShape\0", b"neckShape\0"))  # the .xml's channel absent
    assert "without channel 'headShape'" in _error(read_maya_cache, xml)
    data.unlink()
    assert f"no {data.name} beside" in _error(read_maya_cache, xml)


def test_damaged_maya_description(tmp_path):
    xml = write_maya_cache(tmp_path, "s", _mesh(), wide=False, double=False, per_frame=True)
    text = xml.read_text()
    (tmp_path / "s3.xml").write_text(text[:-40])
    assert "s3.xml: not readable XML" in _error(read_maya_cache, tmp_path / "s3.xml")
    xml.write_text(text.replace('Type="OneFilePerFrame"', 'Type="Twice"'))
    assert "type 'Twice'" in _error(read_maya_cache, xml)
    xml.write_text(text.replace("FloatVectorArray", "FloatArray"))
    assert "no channel of" in _error(read_maya_cache, xml)
    xml.write_text(text.replace('TimePerFrame="200"', 'TimePerFrame="0"'))
    assert "TimePerFrame is 0" in _error(read_maya_cache, xml)
    xml.write_text(text.replace('Range="0-1200"', 'Range="0-600000000000"'))
    assert "folder holds" in _error(read_maya_cache, xml)  # a lying range: no file looked for each tick
    xml.write_text(text)
    (tmp_path / "sFrame3.mc").unlink()
    assert "no sFrame3.mc (tick 600" in _error(read_maya_cache, xml)
    (tmp_path / "a.txt").write_text("x")
    assert "not a vertex cache" in _error(read_vertex_cache, tmp_path / "a.txt")
    empty = tmp_path / "empty"
    empty.mkdir()
    assert "holding no .xml" in _error(read_vertex_cache, empty)
