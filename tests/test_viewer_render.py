"""Real offscreen renders of the built-in face and of glTF heads: pixels, reference images (SSIM), the
GL probe. Reference images: tests/data/viewer/*.png, regenerated with
``python tests/test_viewer_render.py --regenerate`` (after a deliberate change to the face)."""

from __future__ import annotations

import base64
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from skimage.metrics import structural_similarity

from capture.channels import ARKIT61
from viewer.face import MOUTH_EL, MOUTH_HALF, B, builtin_face
from viewer.gltf import arkit_channel, load_gltf, write_glb
from viewer.render import FaceRenderer

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = Path(__file__).parent / "data" / "viewer"
SIZE = (256, 256)
# SSIM over the head's bounding box (the background would make any two faces look alike): the same
# render scores 1.0; the closest two different poses below score 0.95.
SSIM_MIN = 0.98
POSES: dict[str, dict[str, float]] = {
    "neutral": {},
    "jaw_open": {"jawOpen": 1.0},
    "smile_funnel": {"mouthSmileLeft": 0.8, "mouthSmileRight": 0.8, "jawOpen": 0.25, "mouthFunnel": 0.4},
    "blink_brow_yaw": {
        "eyeBlinkLeft": 1.0,
        "browInnerUp": 0.8,
        "cheekPuff": 0.6,
        "headYaw": 0.3,
        "jawOpen": 0.4,
    },
}


def weights(**named: float) -> np.ndarray:
    w = np.zeros(len(ARKIT61))
    for name, value in named.items():
        w[ARKIT61.index(name)] = value
    return w


@pytest.fixture(scope="module")
def renderer():
    with FaceRenderer(builtin_face(), SIZE) as r:
        yield r


def ssim(a: np.ndarray, ref: np.ndarray) -> float:
    """Structural similarity of two renders within the bounding box of the reference's head."""
    fg = np.any(np.abs(ref.astype(int) - ref[0, 0]) > 3, axis=2)
    rows, cols = np.flatnonzero(fg.any(axis=1)), np.flatnonzero(fg.any(axis=0))
    box = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
    return float(structural_similarity(a[box], ref[box], channel_axis=2))


def read_png(path: Path) -> np.ndarray:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert img is not None, path
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def mouth_box(r: FaceRenderer) -> tuple[slice, slice]:
    """Pixel rows/columns around the lips, from the projected lip line."""
    theta = np.linspace(-MOUTH_HALF, MOUTH_HALF, 9)
    from viewer.face import _surface

    pts = _surface(theta, np.full_like(theta, MOUTH_EL))
    px = r.project(pts)
    c0, c1 = int(px[:, 0].min()), int(px[:, 0].max())
    row = int(px[:, 1].mean())
    return slice(row - 8, row + 40), slice(c0, c1 + 1)


def test_jaw_open_moves_the_mouth_and_nothing_above_it(renderer):
    closed = renderer.render(weights())
    opened = renderer.render(weights(jawOpen=1.0))
    for img in (closed, opened):
        assert img.shape == (*SIZE[::-1], 3) and img.dtype == np.uint8
        assert img.std() > 20  # not a blank frame
        background = np.all(np.abs(img.astype(int) - img[0, 0]) < 3, axis=2).mean()
        assert 0.3 < background < 0.8  # the head fills a good part of the frame
    rows, cols = mouth_box(renderer)
    diff = np.abs(opened.astype(int) - closed.astype(int)).sum(axis=2)
    assert diff[rows, cols].mean() > 40
    # The open mouth shows the dark cavity where the closed lips were skin-coloured.
    dark = lambda im: (im[rows, cols].max(axis=2) < 70).sum()  # noqa: E731
    assert dark(opened) > dark(closed) + 150
    # Forehead and eyes (above the nose) do not move with the jaw.
    eye_row = int(renderer.project(np.array([[0.0, B * np.sin(0.05), 0.9]]))[0, 1])
    assert diff[:eye_row].max() == 0


@pytest.mark.parametrize("pose", list(POSES))
def test_render_matches_reference_image(renderer, pose):
    img = renderer.render(weights(**POSES[pose]))
    ref = read_png(REFERENCE / f"{pose}.png")
    assert ssim(img, ref) >= SSIM_MIN


def test_reference_comparison_tells_poses_apart(renderer):
    neutral = renderer.render(weights())
    assert ssim(neutral, read_png(REFERENCE / "neutral.png")) >= SSIM_MIN
    assert ssim(neutral, read_png(REFERENCE / "jaw_open.png")) < SSIM_MIN


@pytest.mark.parametrize("style", ["arkit", "pascal", "suffix"])
def test_glb_round_trip_renders_like_the_builtin_face(tmp_path, renderer, style):
    face = builtin_face()
    path = write_glb(face, tmp_path / "face.glb", style)
    model = load_gltf(path)
    assert model.extra["unmapped"] == [] and len(model.extra["mapped"]) == 52
    model.camera_position, model.camera_focus = face.camera_position, face.camera_focus
    model.pivot = face.pivot
    pose = weights(**POSES["smile_funnel"])
    with FaceRenderer(model, SIZE) as r:
        got = r.render(pose)
    assert ssim(got, renderer.render(pose)) >= 0.99


@pytest.mark.parametrize(
    ("name", "channel"),
    [
        ("jawOpen", "jawOpen"),
        ("JawOpen", "jawOpen"),
        ("eyeBlink_L", "eyeBlinkLeft"),
        ("EyeBlink_R", "eyeBlinkRight"),
        ("mouthSmile.L", "mouthSmileLeft"),
        ("blendShape1.MouthPucker", "mouthPucker"),
        ("ARKit_cheekPuff", "cheekPuff"),
        ("eyeBlinkL", "eyeBlinkLeft"),
        ("MOUTHFUNNEL", "mouthFunnel"),
        ("smile", None),
        ("headYaw", None),  # a rotation, not a morph target
    ],
)
def test_target_names_map_to_arkit_channels(name, channel):
    assert arkit_channel(name) == channel


def _hand_made_gltf(path: Path) -> None:
    """A quad with a node translation and scale, indices as uint16 and a sparse morph target."""
    pos = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)
    idx = np.array([0, 1, 2, 0, 2, 3], np.uint16)
    sparse_idx = np.array([2], np.uint8)
    sparse_val = np.array([[0, 0.5, 0]], np.float32)
    blob = pos.tobytes() + idx.tobytes() + sparse_idx.tobytes() + b"\0\0\0" + sparse_val.tobytes()
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"children": [1], "translation": [0, 0, 5]}, {"mesh": 0, "scale": [2, 2, 2]}],
        "meshes": [
            {
                "primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "targets": [{"POSITION": 2}]}],
                "extras": {"targetNames": ["Face.JawOpen"]},
            }
        ],
        "buffers": [
            {
                "byteLength": len(blob),
                "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode(),
            }
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 48},
            {"buffer": 0, "byteOffset": 48, "byteLength": 12},
            {"buffer": 0, "byteOffset": 60, "byteLength": 1},
            {"buffer": 0, "byteOffset": 64, "byteLength": 12},
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3"},
            {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"},
            {
                "componentType": 5126,
                "count": 4,
                "type": "VEC3",
                "sparse": {
                    "count": 1,
                    "indices": {"bufferView": 2, "componentType": 5121},
                    "values": {"bufferView": 3},
                },
            },
        ],
    }
    path.write_text(json.dumps(doc))


def test_gltf_loader_reads_sparse_targets_and_node_transforms(tmp_path):
    _hand_made_gltf(tmp_path / "quad.gltf")
    model = load_gltf(tmp_path / "quad.gltf")
    assert model.extra["mapped"] == ["jawOpen"]
    rest = model.pose(weights())[0]
    assert np.allclose(rest, [[0, 0, 5], [2, 0, 5], [2, 2, 5], [0, 2, 5]])
    posed = model.pose(weights(jawOpen=0.5))[0]
    assert np.allclose(posed - rest, [[0, 0, 0], [0, 0, 0], [0, 0.5, 0], [0, 0, 0]])  # 0.5 * 0.5 * scale 2
    assert model.parts[0].triangles.tolist() == [[0, 1, 2], [0, 2, 3]]


def test_gltf_without_arkit_targets_is_a_clear_error(tmp_path):
    _hand_made_gltf(tmp_path / "quad.gltf")
    doc = json.loads((tmp_path / "quad.gltf").read_text())
    doc["meshes"][0]["extras"]["targetNames"] = ["Smile"]
    (tmp_path / "quad.gltf").write_text(json.dumps(doc))
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "viewer",
            "render",
            str(tmp_path / "x.csv"),
            "-o",
            str(tmp_path / "a.png"),
            "--face",
            str(tmp_path / "quad.gltf"),
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    assert proc.returncode == 1 and "Traceback" not in proc.stderr


def test_without_gl_the_command_says_what_to_install(tmp_path):
    # A machine without an EGL driver: glvnd finds no vendor library, there is no X display either.
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("DISPLAY", "WAYLAND_DISPLAY", "VTK_DEFAULT_OPENGL_WINDOW")
    }
    env["__EGL_VENDOR_LIBRARY_FILENAMES"] = str(tmp_path / "no-such-vendor.json")
    proc = subprocess.run(
        [sys.executable, "-m", "viewer", "probe"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=env,
        timeout=120,
    )
    assert proc.returncode == 1
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert lines[-1].startswith("s2a-view: error: offscreen rendering is not available")
    assert "libegl1 libgl1-mesa-dri" in lines[-1]


def regenerate() -> None:
    """Write the reference images from the current face (run after a deliberate change)."""
    from viewer.render import write_image

    REFERENCE.mkdir(parents=True, exist_ok=True)
    with FaceRenderer(builtin_face(), SIZE) as r:
        for name, pose in POSES.items():
            write_image(REFERENCE / f"{name}.png", r.render(weights(**pose)))
            print(REFERENCE / f"{name}.png")


if __name__ == "__main__":
    if sys.argv[1:] == ["--regenerate"]:
        regenerate()
    else:
        print(f"usage: {sys.argv[0]} --regenerate")


def test_face_lost_frames_are_bridged_between_tracked_poses(samples):
    from viewer.render import load_animation

    path = next((samples / "livelinkface").rglob("S88-001.csv"))
    anim = load_animation(path)
    lost = anim.take.frame_status == 1
    assert lost.sum() > 200 and np.all(np.isfinite(anim.weights))
    k = int(np.flatnonzero(lost)[0])
    end = k + int(np.argmin(lost[k:]))  # first tracked frame after the gap
    before, after = anim.weights[k - 1], anim.weights[end]
    for j in range(k, end):  # linear between the tracked frames around the gap, not a neutral face
        assert np.all(anim.weights[j] >= np.minimum(before, after) - 1e-9)
        assert np.all(anim.weights[j] <= np.maximum(before, after) + 1e-9)
    assert np.abs(anim.weights[k:end]).sum() > 0


def test_an_aligned_segment_starts_at_its_place_on_the_parent_clock(samples):
    from viewer.render import load_animation, place_on_parent_clock

    src = samples / "paired" / "neurosync-trainer-lite-testset" / "testset.csv"
    raw, seg, other = load_animation(src), load_animation(src), load_animation(src)
    seg.take.meta.extra["align"] = {"parent": {"id": raw.take.meta.id}, "segment_start_s": 1.34}
    other.take.meta.extra["align"] = {"parent": {"id": "another_take"}, "segment_start_s": 1.34}
    assert place_on_parent_clock(raw, seg) == pytest.approx(1.34)
    assert place_on_parent_clock(raw, other) == 0.0
