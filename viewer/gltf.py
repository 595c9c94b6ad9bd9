"""glTF 2.0 / GLB heads with ARKit morph targets → ``FaceModel``; and the built-in head written as GLB.

Read with numpy from the glTF JSON and its binary buffers (GLB chunk, external ``.bin`` or base64 data
URI): triangle primitives, their POSITION, COLOR_0, indices and morph-target POSITION deltas (dense or
sparse accessors, any component type, normalised or not), node transforms (matrix or TRS) through the
default scene. Skins, textures and animations are ignored: the mesh is shown in its bind pose with the
material's base colour.

Target names come from ``mesh.extras.targetNames`` (the common export convention) or a primitive's
``extras.targetNames``, and map to ARKit channels whatever the spelling (``arkit_channel``). Triangle
strips and fans are drawn as triangles; points and lines are not drawn.

A damaged file is an ``InputError`` naming it: indices, types and counts are checked where they are
read, and ``load_gltf`` turns any other structural failure while parsing (``KeyError``, ``IndexError``,
``TypeError``, ``ValueError``, ``AttributeError``, ``struct.error``) into one.
"""

from __future__ import annotations

import base64
import binascii
import json
import re
import struct
from pathlib import Path
from urllib.parse import unquote

import numpy as np

from capture.atomic import atomic_write
from capture.channels import ARKIT52, ARKIT61
from capture.errors import InputError

from .face import FaceModel, Part
from .output import writing

GLB_MAGIC = 0x46546C67  # "glTF"
CHUNK_JSON = 0x4E4F534A
CHUNK_BIN = 0x004E4942
_COMPONENT = {
    5120: np.int8,
    5121: np.uint8,
    5122: np.int16,
    5123: np.uint16,
    5125: np.uint32,
    5126: np.float32,
}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_NORM = {np.int8: 127.0, np.uint8: 255.0, np.int16: 32767.0, np.uint16: 65535.0}
_LOOKUP = {n.lower(): n for n in ARKIT52}
_INDEX = {n: i for i, n in enumerate(ARKIT61)}
MAX_TARGET_REACH = 100.0  # a morph target may move a vertex at most this many times the head's size
# a buffer URI that is no relative reference: one with a scheme (file:, http:, C: too), read as written (a
# colon percent-encoded, "head%3A1.bin", is part of a file name), or a path, once decoded, that is absolute
# (POSIX, Windows, UNC: "%2Fetc%2Fhostname" too)
_SCHEME = re.compile(r"[A-Za-z][A-Za-z0-9+.-]*:")
_ABSOLUTE = re.compile(r"[/\\]|[A-Za-z]:")
_PREFIXES = ("arkit", "blendshape", "blendshapes", "bs", "shape", "morph", "target")


def _segments(name: str) -> list[str]:
    """A morph target name's parts between namespace and side separators (``.``, ``:``, ``|``, ``/``)."""
    return [s for s in re.split(r"[.:|/]", name.strip()) if s]


def _blender_copy(name: str) -> bool:
    """Whether ``name`` ends in the number Blender gives a copy (``jawOpen.001``), which ``arkit_channel``
    drops: beside the target it copies (or an earlier copy), the copy is the one left unread."""
    seg = _segments(name)
    return len(seg) >= 2 and seg[-1].isdigit()


def arkit_channel(name: str) -> str | None:
    """The ARKit channel (camelCase) a morph target name means, or None.

    Case-insensitive; camelCase or PascalCase; ``_L``/``_R``, ``.L``, ``Left``/``Right`` sides;
    namespaces (``blendShape1.jawOpen``, ``Face:JawOpen``) and prefixes (``ARKit_``, ``bs_``, and one
    numbered as Maya numbers its blendShape nodes: ``blendShape1_jawOpen``) dropped, as is the number
    Blender gives a duplicate (``jawOpen.001``).
    """
    seg = _segments(name)
    while len(seg) >= 2 and seg[-1].isdigit():  # "jawOpen.001"
        seg.pop()
    if not seg:
        return None
    last = seg[-1]
    side = ""
    if len(seg) >= 2 and seg[-1].upper() in ("L", "R"):  # "mouthSmile.L"
        last, side = seg[-2], "left" if seg[-1].upper() == "L" else "right"
    else:
        m = re.match(r"^(.*?)[_\- ]([LR])$", last, re.IGNORECASE)
        if m:
            last, side = m.group(1), "left" if m.group(2).upper() == "L" else "right"
    key = re.sub(r"[^a-z0-9]", "", last.lower()) + side
    candidates = [key] + [key[len(p) :].lstrip("0123456789") for p in _PREFIXES if key.startswith(p)]
    for k in candidates:
        if k in _LOOKUP:
            return _LOOKUP[k]
    for k in candidates:  # eyeBlinkL / eyeBlinkR
        if k.endswith(("l", "r")):
            k2 = k[:-1] + ("left" if k.endswith("l") else "right")
            if k2 in _LOOKUP:
                return _LOOKUP[k2]
    return None


class _Gltf:
    def __init__(self, path: Path):
        self.path = path
        data = path.read_bytes()
        if not data:
            raise InputError("file is empty: no glTF or GLB", path)
        self.bin: bytes | None = None
        if data[:4] == b"glTF":
            if len(data) < 12:
                raise InputError(f"GLB header is cut short: {len(data)} of its 12 bytes", path)
            magic, version, length = struct.unpack_from("<III", data, 0)
            if version != 2:
                raise InputError(f"GLB version {version}; only glTF 2.0 is read", path)
            if len(data) < length:  # cut short (a copy or download that stopped): say so, not a JSON error
                raise InputError(
                    f"GLB is truncated: its header says {length} bytes, the file holds {len(data)}", path
                )
            off, doc, k = 12, None, 0
            while off + 8 <= min(length, len(data)):
                clen, ctype = struct.unpack_from("<II", data, off)
                if off + 8 + clen > length:  # what fits of it is not the chunk: refused, not read in part
                    raise InputError(
                        f"GLB chunk {k} says {clen} bytes, but only {length - off - 8} follow its header "
                        f"in the file's {length}: the file is damaged",
                        path,
                    )
                chunk = data[off + 8 : off + 8 + clen]
                if ctype == CHUNK_JSON:
                    doc = chunk
                elif ctype == CHUNK_BIN and self.bin is None:
                    self.bin = chunk
                off, k = off + 8 + clen, k + 1
            if doc is None:
                raise InputError("GLB has no JSON chunk", path)
        else:
            doc = data
        try:
            self.doc = json.loads(doc.decode("utf-8").rstrip("\x00 "))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InputError(f"not a glTF file ({exc})", path) from None
        if not isinstance(self.doc, dict) or not isinstance(self.doc.get("asset"), dict):
            raise InputError("not a glTF file (no JSON object with an asset object at the top)", path)
        if not str(self.doc["asset"].get("version", "")).startswith("2"):
            raise InputError("only glTF 2.0 is read (asset.version)", path)
        self.buffers: dict[int, bytes] = {}

    def item(self, kind: str, i) -> dict:
        """``doc[kind][i]``; an ``InputError`` when ``i`` is not one of its indices."""
        items = self.doc.get(kind) or []
        if type(i) is not int or not 0 <= i < len(items) or not isinstance(items[i], dict):
            raise InputError(f"{kind} index {i!r} is out of range (the file has {len(items)})", self.path)
        return items[i]

    def buffer(self, i: int) -> bytes:
        if i not in self.buffers:
            b = self.item("buffers", i)
            uri = b.get("uri")
            if uri is None:
                if self.bin is None:
                    raise InputError(f"buffer {i} has no data", self.path)
                self.buffers[i] = self.bin
            elif uri.startswith("data:"):
                if "," not in uri:
                    raise InputError(f"buffer {i}: data URI has no data (no comma)", self.path)
                try:
                    self.buffers[i] = base64.b64decode(uri.split(",", 1)[1], validate=True)
                except binascii.Error as exc:
                    raise InputError(f"buffer {i}: data URI is not base64 ({exc})", self.path) from None
            else:
                written, uri = uri, unquote(uri)  # a URI: "my%20head.bin" is the file "my head.bin"
                if _SCHEME.match(written) or _ABSOLUTE.match(uri):
                    # glTF 2.0 buffers are data URIs or references relative to the .gltf: an absolute path
                    # or another scheme (file:, http:) would read whatever file it names, or nothing
                    raise InputError(
                        f"buffer {i}: {uri!r} is not a file beside the .gltf (glTF takes a data: URI or a "
                        "relative path)",
                        self.path,
                    )
                f = self.path.parent / uri
                if not f.is_file():
                    raise InputError(f"buffer file {uri} not found", self.path)
                self.buffers[i] = f.read_bytes()
        return self.buffers[i]

    def _view(self, index: int, dtype, width: int, count: int, offset: int) -> np.ndarray:
        bv = self.item("bufferViews", index)
        buf = self.buffer(bv["buffer"])
        item = np.dtype(dtype).itemsize * width
        stride = bv.get("byteStride") or item
        start = bv.get("byteOffset", 0) + offset
        if stride < item:
            raise InputError(
                f"bufferView {index}: byteStride {stride} is less than its {item}-byte element", self.path
            )
        if start < 0:
            raise InputError(f"bufferView {index}: negative byte offset {start}", self.path)
        if count == 0:
            return np.zeros((0, width), dtype)
        need = start + stride * (count - 1) + item
        if need > len(buf):
            raise InputError(f"bufferView {index} runs past its buffer", self.path)
        raw = np.frombuffer(buf, np.uint8, stride * (count - 1) + item, start)
        if stride == item:
            return raw.view(dtype).reshape(count, width).copy()
        rows = np.lib.stride_tricks.as_strided(raw, (count, item), (stride, 1))
        return np.ascontiguousarray(rows).view(dtype).reshape(count, width)

    def accessor(self, index: int) -> np.ndarray:
        """Accessor ``index`` as float64 (count, width) (normalised integers scaled to [0, 1]/[-1, 1])."""
        acc = self.item("accessors", index)
        dtype = _COMPONENT.get(acc["componentType"])
        if dtype is None:
            raise InputError(f"accessor {index}: unknown component type {acc['componentType']}", self.path)
        if acc["type"] not in _WIDTH:
            raise InputError(f"accessor {index}: unknown type {acc['type']!r}", self.path)
        width = _WIDTH[acc["type"]]
        count = acc["count"]
        if type(count) is not int or count < 0:
            raise InputError(f"accessor {index}: count {count!r} is not a count", self.path)
        if "bufferView" in acc:
            out = self._view(acc["bufferView"], dtype, width, count, acc.get("byteOffset", 0)).astype(
                np.float64
            )
        else:
            out = np.zeros((count, width))
        if acc.get("normalized") and dtype in _NORM:
            out = np.maximum(out / _NORM[dtype], -1.0)
        sparse = acc.get("sparse")
        if sparse:
            n = sparse["count"]
            ix = sparse["indices"]
            idx = self._view(ix["bufferView"], _COMPONENT[ix["componentType"]], 1, n, ix.get("byteOffset", 0))
            vs = sparse["values"]
            vals = self._view(vs["bufferView"], dtype, width, n, vs.get("byteOffset", 0)).astype(np.float64)
            if acc.get("normalized") and dtype in _NORM:
                vals = np.maximum(vals / _NORM[dtype], -1.0)
            idx = idx[:, 0].astype(np.int64)
            if n and not 0 <= idx.min() <= idx.max() < count:
                raise InputError(f"accessor {index}: sparse index beyond its {count} elements", self.path)
            out[idx] = vals
        return out


def _node_matrix(node: dict) -> np.ndarray:
    if "matrix" in node:
        if len(node["matrix"]) != 16:
            raise ValueError(f"a node's matrix has {len(node['matrix'])} numbers, not 16")
        return np.array(node["matrix"], dtype=np.float64).reshape(4, 4).T  # column-major in glTF
    t = np.array(node.get("translation", [0, 0, 0]), dtype=np.float64)
    x, y, z, w = node.get("rotation", [0, 0, 0, 1])
    s = np.array(node.get("scale", [1, 1, 1]), dtype=np.float64)
    r = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    m = np.eye(4)
    m[:3, :3] = r * s
    m[:3, 3] = t
    return m


def load_gltf(path: str | Path) -> FaceModel:
    """A glTF/GLB head as a ``FaceModel``; its morph targets drive the ARKit channels they name.

    ``InputError`` naming the file when it is not glTF 2.0, is damaged (an index out of range, a count
    or type that does not fit, non-finite positions or target offsets, a target that moves a vertex
    over ``MAX_TARGET_REACH`` times the head's size, a head of no size), or when no morph target maps
    to an ARKit channel.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("no such glTF/GLB file", path)
    try:
        return _load(_Gltf(path))
    except (KeyError, IndexError, TypeError, ValueError, AttributeError, struct.error) as exc:
        # What the checks along the way do not name: one line naming the file, not a traceback.
        what = "a field is missing" if isinstance(exc, KeyError) else type(exc).__name__
        raise InputError(f"damaged glTF ({what}: {exc})", path) from None


def _triangles(g: _Gltf, prim: dict, n: int, where: str) -> np.ndarray:
    """(F, 3) vertex indices of a triangle list (mode 4), strip (5) or fan (6), checked against ``n``."""
    mode = prim.get("mode", 4)
    if "indices" in prim:
        seq = g.accessor(prim["indices"])[:, 0].astype(np.int64)
    else:
        seq = np.arange(n)
    if mode == 4:
        if seq.size % 3:
            raise InputError(f"{where}: {seq.size} indices are not whole triangles", g.path)
        tris = seq.reshape(-1, 3)
    else:
        k = np.arange(max(seq.size - 2, 0))
        if mode == 5:  # strip: triangle k is (k, k+1, k+2), every other one turned to keep the winding
            tris = np.stack([seq[k], seq[k + 1 + k % 2], seq[k + 2 - k % 2]], axis=1)
        else:  # fan about the first vertex
            tris = np.stack([seq[k + 1], seq[k + 2], np.zeros_like(k) + seq[:1]], axis=1)
    if tris.size and not 0 <= tris.min() <= tris.max() < n:
        raise InputError(f"{where}: a vertex index is beyond its {n} vertices", g.path)
    return tris


def _load(g: _Gltf) -> FaceModel:
    path, doc = g.path, g.doc
    nodes = doc.get("nodes", [])
    if doc.get("scenes"):
        roots = g.item("scenes", doc.get("scene", 0)).get("nodes", [])
    else:
        children = {c for n in nodes for c in n.get("children", [])}
        roots = [i for i in range(len(nodes)) if i not in children]
    parts: list[Part] = []
    mapped: set[str] = set()
    unmapped: set[str] = set()
    reach: list[tuple[str, float]] = []  # how far each morph target moves a vertex
    stack = [(i, np.eye(4)) for i in roots]
    seen = 0
    while stack:
        i, parent = stack.pop()
        seen += 1
        if seen > 100000:
            raise InputError("node hierarchy has a cycle", path)
        node = g.item("nodes", i)
        m = parent @ _node_matrix(node)
        stack += [(c, m) for c in node.get("children", [])]
        if "mesh" not in node:
            continue
        mesh = g.item("meshes", node["mesh"])
        names = (mesh.get("extras") or {}).get("targetNames")
        for k, prim in enumerate(mesh.get("primitives", [])):
            if prim.get("mode", 4) not in (4, 5, 6) or "POSITION" not in prim.get("attributes", {}):
                continue  # points and lines are not drawn
            where = f"mesh {node['mesh']} primitive {k}"
            pos = g.accessor(prim["attributes"]["POSITION"])[:, :3]
            tris = _triangles(g, prim, len(pos), where)
            pnames = names or (prim.get("extras") or {}).get("targetNames") or []
            if not isinstance(pnames, list):
                raise InputError(
                    f"{where}: targetNames is {type(pnames).__name__}, not a list of names", path
                )
            deltas: dict[int, np.ndarray] = {}
            named: dict[int, str] = {}
            targets = prim.get("targets", [])
            tnames = [str(pnames[t]) if t < len(pnames) else f"target{t}" for t in range(len(targets))]
            # copies last, in the order of their numbers: one that names the channel another target does
            # (its original, or an earlier copy) is left unread, not refused
            copies = [_blender_copy(name) for name in tnames]
            for t in sorted(
                range(len(targets)), key=lambda t: (copies[t], tnames[t] if copies[t] else "", t)
            ):
                target, tname = targets[t], tnames[t]
                ch = arkit_channel(tname)
                if ch is None or "POSITION" not in target:
                    unmapped.add(tname)
                    continue
                idx = _INDEX[ch]
                if idx in named and copies[t]:
                    unmapped.add(tname)
                    continue
                if idx in named:
                    raise InputError(f"{where}: morph targets {named[idx]} and {tname} both name {ch}", path)
                d = g.accessor(target["POSITION"])[:, :3]
                if d.shape[0] != len(pos):
                    raise InputError(
                        f"{where}: morph target {tname} moves {d.shape[0]} of {len(pos)} vertices", path
                    )
                if not np.isfinite(d).all():
                    raise InputError(
                        f"{where}: morph target {tname} moves vertices by numbers that are not finite", path
                    )
                mapped.add(ch)
                named[idx] = tname
                deltas[idx] = d @ m[:3, :3].T
                reach.append((f"{where}: morph target {tname}", float(np.abs(deltas[idx]).max(initial=0.0))))
            colors = _part_colors(g, prim, len(pos))
            world = pos @ m[:3, :3].T + m[:3, 3]
            if not np.isfinite(world).all():
                raise InputError(f"{where}: vertex positions that are not finite numbers", path)
            if np.linalg.det(m[:3, :3]) < 0:
                tris = tris[:, ::-1]
            parts.append(Part(f"{mesh.get('name', 'mesh')}.{k}", world, tris, colors, deltas))
    if not parts:
        raise InputError("glTF has no triangle mesh", path)
    if not mapped:
        hint = ", ".join(sorted(unmapped)[:5]) or "none"
        raise InputError(f"no morph target names an ARKit blendshape (targets: {hint})", path)
    allv = np.vstack([p.vertices for p in parts])
    lo, hi = allv.min(axis=0), allv.max(axis=0)
    if not (hi - lo).max() > 0:
        raise InputError("the head has no size: all its vertices are at one point", path)
    for what, far in reach:
        # A target that throws a vertex this far is damage, not a pose: the camera's depth range then
        # spans it, and the head vanishes from every frame it moves in (a blank image, no error).
        if far > MAX_TARGET_REACH * (hi - lo).max():
            raise InputError(
                f"{what} moves a vertex by {far:.3g}, over {MAX_TARGET_REACH:g} times the head's size "
                f"({(hi - lo).max():.3g}): the file is damaged",
                path,
            )
    center = (lo + hi) / 2
    height = hi[1] - lo[1] or (hi - lo).max()  # a head flat in y is framed by its largest extent
    # Frame the head: 30 degree view, the head's height filling about 80% of the image, from the front.
    dist = height / 0.8 / (2 * np.tan(np.radians(15))) + (hi[2] - lo[2]) / 2
    model = FaceModel(
        name=path.name,
        parts=parts,
        pivot=np.array([center[0], lo[1], center[2]]),
        camera_position=(float(center[0]), float(center[1]), float(center[2] + dist)),
        camera_focus=tuple(float(c) for c in center),
        view_angle=30.0,
    )
    model.extra = {"mapped": sorted(mapped), "unmapped": sorted(unmapped)}
    return model


def _part_colors(g: _Gltf, prim: dict, n: int) -> np.ndarray:
    attrs = prim.get("attributes", {})
    if "COLOR_0" in attrs:
        c = g.accessor(attrs["COLOR_0"])[:, :3]
        if c.max() > 1.0:
            c = c / 255.0
        return np.clip(np.rint(c * 255), 0, 255).astype(np.uint8)
    base = [0.85, 0.68, 0.58]
    if "material" in prim:
        mat = g.item("materials", prim["material"])
        base = (mat.get("pbrMetallicRoughness") or {}).get("baseColorFactor", base + [1])[:3]
    return np.tile(np.clip(np.rint(np.array(base) * 255), 0, 255).astype(np.uint8), (n, 1))


def target_name(channel: str, style: str) -> str:
    """How an exporter might spell an ARKit channel: ``arkit`` (jawOpen), ``pascal`` (JawOpen),
    ``suffix`` (eyeBlink_L, as several avatar tools write the sides)."""
    if style == "pascal":
        return channel[0].upper() + channel[1:]
    if style == "suffix":
        for side, s in (("Left", "_L"), ("Right", "_R")):
            if channel.endswith(side):
                return channel[: -len(side)] + s
    return channel


def write_glb(model: FaceModel, path: str | Path, style: str = "arkit") -> Path:
    """``model`` as a GLB: one mesh per part with POSITION, COLOR_0, indices and one morph target per
    channel that moves it (names in ``mesh.extras.targetNames``). ``path`` must end in ``.glb``: the
    file is binary glTF, which a ``.gltf`` (JSON) or ``.obj`` name would misdescribe."""
    path = Path(path)
    if path.suffix.lower() != ".glb":
        raise InputError("the face is written as binary glTF: give a file name ending in .glb", path)
    blob = bytearray()
    views: list[dict] = []
    accessors: list[dict] = []

    def add(arr: np.ndarray, ctype: int, atype: str, target: int | None, minmax: bool = False) -> int:
        while len(blob) % 4:
            blob.append(0)
        data = np.ascontiguousarray(arr).tobytes()
        view = {"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        views.append(view)
        blob.extend(data)
        acc = {
            "bufferView": len(views) - 1,
            "componentType": ctype,
            "count": int(arr.shape[0]),
            "type": atype,
        }
        if minmax:
            acc["min"] = [float(x) for x in arr.min(axis=0)]
            acc["max"] = [float(x) for x in arr.max(axis=0)]
        if ctype == 5121:
            acc["normalized"] = True
        accessors.append(acc)
        return len(accessors) - 1

    meshes, nodes = [], []
    for part in model.parts:
        attrs = {
            "POSITION": add(part.vertices.astype(np.float32), 5126, "VEC3", 34962, True),
            "COLOR_0": add(
                np.hstack([part.colors, np.full((len(part.colors), 1), 255, np.uint8)]), 5121, "VEC4", 34962
            ),
        }
        idx = add(part.triangles.astype(np.uint32).ravel(), 5125, "SCALAR", 34963)
        targets, names = [], []
        for k in sorted(part.deltas):
            targets.append({"POSITION": add(part.deltas[k].astype(np.float32), 5126, "VEC3", 34962, True)})
            names.append(target_name(ARKIT61[k], style))
        prim = {"attributes": attrs, "indices": idx, "mode": 4}
        mesh = {"name": part.name, "primitives": [prim]}
        if targets:
            prim["targets"] = targets
            mesh["extras"] = {"targetNames": names}
            mesh["weights"] = [0.0] * len(targets)
        meshes.append(mesh)
        nodes.append({"mesh": len(meshes) - 1, "name": part.name})
    doc = {
        "asset": {"version": "2.0", "generator": "s2a-toolkit viewer"},
        "scene": 0,
        "scenes": [{"nodes": list(range(len(nodes)))}],
        "nodes": nodes,
        "meshes": meshes,
        "buffers": [{"byteLength": len(blob)}],
        "bufferViews": views,
        "accessors": accessors,
    }
    js = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    js += b" " * (-len(js) % 4)
    while len(blob) % 4:
        blob.append(0)
    out = struct.pack("<III", GLB_MAGIC, 2, 12 + 8 + len(js) + 8 + len(blob))
    out += (
        struct.pack("<II", len(js), CHUNK_JSON) + js + struct.pack("<II", len(blob), CHUNK_BIN) + bytes(blob)
    )
    with writing(path, "GLB"), atomic_write(path) as f:
        f.write(out)
    return path
