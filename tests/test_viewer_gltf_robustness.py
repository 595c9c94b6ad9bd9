"""Damaged or unusual glTF heads are a one-line error naming the file, never a traceback or a blank
image; strips and fans are drawn; the report lists a take once; audio outside the video is warned of."""

from __future__ import annotations

import base64
import json
from pathlib import Path

import numpy as np
import pytest
from conftest import run_here

from capture import Audio, read_livelink_csv, write_take
from capture.errors import InputError
from viewer.gltf import load_gltf
from viewer.report import gather

CAL = "livelinkface/neurosync_MySlate_166/MySlate_166_iPhone_cal.csv"
POS = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float32)
IDX = np.array([0, 1, 2, 0, 0, 0], np.uint16)  # one triangle, padded to 4 bytes
DELTA = np.array([[0, 0, 0], [0, -0.5, 0], [0, 0, 0], [0, 0, 0]], np.float32)


def _doc(**edit) -> dict:
    """One triangle (of a 4-vertex buffer) with a jawOpen target; ``edit`` maps dotted paths to values."""
    blob = POS.tobytes() + IDX.tobytes() + DELTA.tobytes()
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [
            {
                "primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "targets": [{"POSITION": 2}]}],
                "extras": {"targetNames": ["jawOpen"]},
            }
        ],
        "buffers": [{"byteLength": len(blob), "uri": "data:;base64," + base64.b64encode(blob).decode()}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 48},
            {"buffer": 0, "byteOffset": 48, "byteLength": 12},
            {"buffer": 0, "byteOffset": 60, "byteLength": 48},
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3"},
            {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"},
            {"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC3"},
        ],
    }
    for key, value in edit.items():
        *head, last = key.split(".")
        obj = doc
        for k in head:
            obj = obj[int(k)] if isinstance(obj, list) else obj[k]
        obj[int(last) if isinstance(obj, list) else last] = value
    return doc


def _write(path: Path, doc) -> Path:
    path.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    return path


def _blob_uri(data: bytes) -> str:
    return "data:;base64," + base64.b64encode(data).decode()


DAMAGED = {
    "top_list": ("[1, 2, 3]", "not a glTF file"),
    "asset_str": ('{"asset": "2.0"}', "not a glTF file"),
    "bad_base64": (_doc(**{"buffers.0.uri": "data:;base64,!!!"}), "not base64"),
    "no_comma": (_doc(**{"buffers.0.uri": "data:application/octet-stream"}), "no comma"),
    "negative_offset": (_doc(**{"bufferViews.0.byteOffset": -8}), "negative byte offset"),
    "unknown_type": (_doc(**{"accessors.0.type": "VEC7"}), "unknown type 'VEC7'"),
    "negative_count": (_doc(**{"accessors.0.count": -5}), "count -5"),
    "scene_oob": (_doc(scene=5), "scenes index 5"),
    "node_oob": (_doc(**{"scenes.0.nodes": [7]}), "nodes index 7"),
    "mesh_oob": (_doc(**{"nodes.0.mesh": 3}), "meshes index 3"),
    "accessor_oob": (_doc(**{"meshes.0.primitives.0.attributes.POSITION": 9}), "accessors index 9"),
    "material_oob": (_doc(**{"meshes.0.primitives.0.material": 4}), "materials index 4"),
    "matrix_short": (_doc(**{"nodes.0.matrix": [1, 0, 0]}), "3 numbers, not 16"),
    "indices_not_triangles": (_doc(**{"accessors.1.count": 2}), "not whole triangles"),
    "index_beyond_vertices": (_doc(**{"accessors.0.count": 2}), "beyond its 2 vertices"),
    "target_count": (_doc(**{"accessors.2.count": 3}), "moves 3 of 4 vertices"),
    "stride_small": (_doc(**{"bufferViews.0.byteStride": 4}), "byteStride 4"),
    "names_string": (_doc(**{"meshes.0.extras.targetNames": "jawOpen"}), "targetNames is str"),
    "zero_scale": (_doc(**{"nodes.0.scale": [0, 0, 0]}), "no size"),
    "missing_field": (_doc(**{"bufferViews.0": {"byteLength": 48}}), "a field is missing"),
}


@pytest.mark.parametrize("name", sorted(DAMAGED))
def test_a_damaged_gltf_is_an_input_error_naming_the_file(tmp_path, name):
    doc, needle = DAMAGED[name]
    path = _write(tmp_path / f"{name}.gltf", doc)
    with pytest.raises(InputError) as err:
        load_gltf(path)
    assert str(err.value).startswith(f"{path}: ") and needle in str(err.value)


def test_a_sparse_index_beyond_the_accessor_is_an_input_error(tmp_path):
    doc = _doc()
    doc["accessors"][2]["sparse"] = {
        "count": 1,
        "indices": {"bufferView": 1, "componentType": 5123, "byteOffset": 6},  # in the padding
        "values": {"bufferView": 2},
    }
    blob = POS.tobytes() + IDX.tobytes() + DELTA.tobytes()
    blob = blob[:54] + np.uint16(9).tobytes() + blob[56:]  # sparse index 9 of 4 elements
    doc["buffers"][0]["uri"] = _blob_uri(blob)
    with pytest.raises(InputError, match="sparse index beyond its 4 elements"):
        load_gltf(_write(tmp_path / "sparse.gltf", doc))


def test_a_cut_short_glb_header_is_an_input_error(tmp_path):
    path = tmp_path / "head.glb"
    path.write_bytes(b"glTF")
    with pytest.raises(InputError, match="GLB header is cut short"):
        load_gltf(path)


def test_a_nan_vertex_position_is_refused_not_rendered_blank(tmp_path):
    doc = _doc()
    pos = POS.copy()
    pos[1, 0] = np.nan
    doc["buffers"][0]["uri"] = _blob_uri(pos.tobytes() + IDX.tobytes() + DELTA.tobytes())
    with pytest.raises(InputError, match="not finite"):
        load_gltf(_write(tmp_path / "nan.gltf", doc))


def test_morph_targets_naming_one_channel_twice_are_refused(tmp_path):
    doc = _doc(**{"meshes.0.extras.targetNames": ["jawOpen", "JawOpen"]})
    doc["meshes"][0]["primitives"][0]["targets"] *= 2
    with pytest.raises(InputError, match="jawOpen and JawOpen both name jawOpen"):
        load_gltf(_write(tmp_path / "dup.gltf", doc))


def test_a_percent_encoded_buffer_uri_is_decoded(tmp_path):
    (tmp_path / "my head.bin").write_bytes(POS.tobytes() + IDX.tobytes() + DELTA.tobytes())
    model = load_gltf(_write(tmp_path / "head.gltf", _doc(**{"buffers.0.uri": "my%20head.bin"})))
    assert model.extra["mapped"] == ["jawOpen"]


@pytest.mark.parametrize(("mode", "tris"), [(5, [[0, 1, 2], [1, 3, 2]]), (6, [[1, 2, 0], [2, 3, 0]])])
def test_strips_and_fans_are_drawn_as_triangles(tmp_path, mode, tris):
    doc = _doc()
    strip = {"attributes": {"POSITION": 0}, "mode": mode, "targets": [{"POSITION": 2}]}  # all 4 vertices
    doc["meshes"][0]["primitives"].append(strip)
    model = load_gltf(_write(tmp_path / "mixed.gltf", doc))
    assert len(model.parts) == 2
    assert model.parts[1].triangles.tolist() == tris


def test_render_with_a_damaged_face_is_a_one_line_error(samples, tmp_path):
    csv = tmp_path / "take.csv"
    with open(samples / CAL, encoding="utf-8") as f:
        csv.write_text("".join(next(f) for _ in range(6)), encoding="utf-8")
    face = _write(tmp_path / "face.gltf", _doc(**{"accessors.0.type": "VEC7"}))
    out = tmp_path / "o.png"
    proc = run_here("viewer", "render", csv, "--face", face, "-o", out, "--size", 32)
    assert proc.returncode == 1, proc.stderr
    assert proc.stderr.strip() == f"s2a-view: error: {face}: accessor 0: unknown type 'VEC7'"
    assert not out.exists()


def _take(samples: Path, tmp_path: Path, rows: int = 30):
    csv = tmp_path / "src" / "take.csv"
    csv.parent.mkdir(parents=True, exist_ok=True)
    with open(samples / CAL, encoding="utf-8") as f:
        csv.write_text("".join(next(f) for _ in range(rows + 1)), encoding="utf-8")
    return read_livelink_csv(csv)


def test_report_lists_a_take_named_by_takes_and_found_in_the_folder_once(samples, tmp_path):
    folder = write_take(_take(samples, tmp_path), tmp_path / "takes")
    data = gather(tmp_path / "takes", [tmp_path / "takes"])
    assert [e["path"] for e in data["takes"]] == [str(folder)]


def test_mp4_audio_wholly_outside_the_video_is_warned_about(samples, tmp_path):
    take = _take(samples, tmp_path)  # 0.5 s of face
    rate = 16000
    take.attach_audio(Audio(np.zeros(rate, np.float32), rate), start_s=float(take.time[0]) + 100.0)
    folder = write_take(take, tmp_path / "takes")
    out = tmp_path / "o.mp4"
    proc = run_here("viewer", "render", folder, "-o", out, "--size", 32)
    assert proc.returncode == 0, proc.stderr
    assert "(audio) spans 100.000..101.000 s, outside the rendered" in proc.stderr, proc.stderr
    assert "the video is silent" in proc.stderr
