"""Data laid out for the trainers users migrate from, imported as it is: NVIDIA's Audio2Face-3D training
framework (an actor's ``audio/`` and ``cache/skin/`` vertex caches, with ``bs_data/bs_skin.npz``) and
NeuroSync's trainer (a folder per take: ``*_iPhone_cal.csv``, ``audio.wav``, ``audio_features.csv``)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import soundfile as sf
from conftest import SAMPLES, run_cli

from capture import read_take
from capture.channels import ARKIT52

SPEECH = SAMPLES / "speech" / "pocketsphinx-testdata-librivox"
NEUROSYNC = SAMPLES / "paired" / "neurosync-trainer-lite-testset"
# Shots named as the Claire dataset names them (``cp<N>_<emotion>``), one a real speech file each.
SHOTS = ("cp1_neutral", "cp2_neutral", "cp33_anger", "cp40_joy", "cp41_sadness")
FPS = 30.0
VERTICES, FRONTAL = 900, 600


def _envelope(audio: np.ndarray, rate: int, frames: int) -> np.ndarray:
    """The audio's loudness at each frame, 0..1: what drives the jaw of the generated performance."""
    hop = len(audio) / frames
    rms = np.array(
        [np.sqrt(np.mean(audio[int(i * hop) : int((i + 1) * hop)] ** 2) + 1e-12) for i in range(frames)]
    )
    return np.clip(rms / np.percentile(rms, 95), 0, 1)


def make_a2f_dataset(root: Path, *, config: bool = True, setup: bool = True) -> tuple[Path, dict]:
    """An Audio2Face-3D training dataset as the framework's docs lay it out, for actor ``mark``:
    ``audio/<shot>.wav`` (real speech, 16 kHz), ``cache/skin/<shot>.npy`` (frames x vertices x 3 float32
    at 30 fps, the mesh an ARKit blendshape performance driven by the speech deforms), ``geom/``,
    ``xform/``, ``bs_data/bs_skin.npz`` (``poseNames`` with the neutral, ``neutral``, a delta per pose,
    ``frontalMask``) and its config, ``config_dataset.py`` at the dataset's root (``CACHE_FPS``).
    Returns the actor's folder and the weights each shot was made from."""
    rng = np.random.default_rng(29)
    actor = root / "Audio2Face-3D-Dataset-v1.0.0-mark" / "data" / "mark"
    for part in ("audio/aug/voice1", "cache/skin", "geom/skin", "xform", "bs_data"):
        (actor / part).mkdir(parents=True, exist_ok=True)
    neutral = rng.normal(size=(VERTICES, 3)).astype(np.float32)
    deltas = np.zeros((len(ARKIT52), VERTICES, 3), np.float32)
    for k in range(len(ARKIT52)):  # each pose moves a patch of the face
        patch = rng.choice(VERTICES, 80, replace=False)
        deltas[k, patch] = rng.normal(scale=0.2, size=(80, 3))
    frontal = np.sort(rng.choice(VERTICES, FRONTAL, replace=False)).astype(np.int32)
    if setup:
        poses = {name: deltas[k] for k, name in enumerate(ARKIT52)}
        np.savez(
            actor / "bs_data" / "bs_skin.npz",
            poseNames=np.array(["neutral", *ARKIT52]),
            neutral=neutral,
            frontalMask=frontal,
            rig_version="1.0",
            **poses,
        )
        params = {"strengthL2regularization": 0.1, "numPoses": len(ARKIT52), "templateBBSize": 45.0}
        (actor / "bs_data" / "bs_skin_config.json").write_text(json.dumps({"blendshape_params": params}))
    np.save(actor / "geom" / "skin" / "neutral_pose.npy", neutral)
    np.save(actor / "geom" / "skin" / "lip_open_pose_delta.npy", deltas[ARKIT52.index("jawOpen")])
    (actor / "geom" / "skin" / "lip_dist_vertex_list.json").write_text(
        json.dumps({"upper": [1, 2], "lower": [3, 4]})
    )
    wavs = sorted(SPEECH.glob("*.wav"))
    made, jaw_eyes = {}, {}
    jaw = ARKIT52.index("jawOpen")
    for shot, wav in zip(SHOTS, wavs):
        audio, rate = sf.read(wav)
        frames = int(round(len(audio) / rate * FPS))
        weights = np.clip(rng.normal(0.1, 0.05, size=(frames, len(ARKIT52))), 0, 1)
        weights[:, jaw] = 0.9 * _envelope(audio, rate, frames)
        blink = np.zeros(frames)
        blink[frames // 3 : frames // 3 + 4] = [0.5, 1.0, 1.0, 0.5]
        weights[:, ARKIT52.index("eyeBlinkLeft")] = weights[:, ARKIT52.index("eyeBlinkRight")] = blink
        mesh = neutral + np.einsum("fk,kvc->fvc", weights, deltas)
        np.save(actor / "cache" / "skin" / f"{shot}.npy", mesh.astype(np.float32))
        sf.write(actor / "audio" / f"{shot}.wav", audio, rate, subtype="PCM_16")
        made[shot] = weights
        jaw_eyes[shot] = rng.normal(size=(frames, 5, 3)).astype(np.float32)
    shutil.copy(actor / "audio" / f"{SHOTS[0]}.wav", actor / "audio" / "aug" / "voice1")  # augmented voice
    np.savez(actor / "xform" / "jaw_keypoints_cache_all.npz", **jaw_eyes)
    if config:
        (actor.parents[1] / "config_dataset.py").write_text(
            "# Paths to various parts of the Audio2Face dataset (per actor)\n"
            'AUDIO_ROOT = {"mark": "/datasets/mark/audio"}\n'
            'SHOT_EMOTION_NAMES = ["neutral", "anger", "joy", "sadness"]\n'
            'CACHE_FPS = {"mark": 30.0}\nACTOR_NAMES = ["mark"]\n'
            'TRANSFORM_SCALE = {"mark": {"skin": 1.0}}\n'
            "SKIN_CACHE_ROOT = {k: v for k, v in AUDIO_ROOT.items()}\n"  # no literal: passed over
        )
    return actor, made


def _meta(take: Path) -> dict:
    return json.loads((take / "meta.json").read_text())


def test_an_audio2face_3d_training_dataset_imports_aligns_and_builds(samples, tmp_path):
    """The whole dataset folder imports as a take per shot (52 ARKit channels solved from the vertex
    caches, 30 fps from its config, each shot with its audio), aligns and builds. Old: no source found."""
    actor, made = make_a2f_dataset(tmp_path / "a2f")
    proc = run_cli("capture", "import", actor.parents[1], "-o", tmp_path / "takes", "--json")
    assert proc.returncode == 0, proc.stderr
    takes = sorted(p for p in (tmp_path / "takes").iterdir() if p.is_dir())
    assert [t.name for t in takes] == sorted(SHOTS)
    for take in takes:
        meta = _meta(take)
        assert meta["fps"] == FPS and meta["channels"] == list(ARKIT52)
        assert meta["audio"]["start_s"] == 0.0 and meta["audio"]["sample_rate"] == 16000
        assert meta["extra"]["audio2face_shot"] == {"actor": "mark", "emotion": take.name.split("_")[1]}
        assert "blendshape_solve" in [r["kind"] for r in meta["repairs"]]
        assert np.abs(read_take(take).values - made[take.name]).max() < 1e-3
    proc = run_cli("capture", "info", takes[2], "--json")
    assert proc.returncode == 0, proc.stderr
    aligned = tmp_path / "aligned"
    proc = run_cli("align", tmp_path / "takes", "-o", aligned, "--vad", "none", "--json")
    assert proc.returncode == 0, proc.stderr
    proc = run_cli("dataset", "build", aligned, "-o", tmp_path / "ds", "--json")
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "ds" / "manifest.json").is_file()


def test_vertex_caches_without_a_blendshape_setup_say_what_is_missing(samples, tmp_path):
    """Shots with no blendshape setup to solve weights from, a Maya cache's too, are each one line saying
    what is missing (old: "no Live Link Face CSV or take folder" for the whole folder)."""
    actor, _ = make_a2f_dataset(tmp_path / "a2f", setup=False)
    maya = actor / "cache" / "skin" / "cp50_fear"
    maya.mkdir()
    (maya / "cp50_fear.xml").write_text("<Autodesk_Cache_File/>")
    (maya / "cp50_fear.mc").write_bytes(b"FOR4")
    proc = run_cli("capture", "import", actor, "-o", tmp_path / "takes")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    errors = [line for line in proc.stderr.splitlines() if ": error: " in line]
    assert len(errors) == len(SHOTS) + 1
    assert all("no blendshape setup (bs_data/bs_skin.npz)" in line for line in errors if ".npy:" in line)
    (maya_error,) = [line for line in errors if "cp50_fear:" in line]
    assert "no blendshape setup (bs_data/bs_skin.npz)" in maya_error
    assert not any((tmp_path / "takes").iterdir())


def test_without_its_config_the_rate_is_the_one_that_fills_the_audio(samples, tmp_path):
    """No config_dataset.py: the framework's rule that a shot lasts as long as its audio gives 30 fps
    (repair ``fps_from_audio``); ``--fps`` with ``--pair-audio`` gives it too."""
    actor, made = make_a2f_dataset(tmp_path / "a2f", config=False)
    proc = run_cli("capture", "import", actor, "-o", tmp_path / "takes")
    assert proc.returncode == 0, proc.stderr
    meta = _meta(tmp_path / "takes" / SHOTS[0])
    assert meta["fps"] == FPS and "fps_from_audio" in [r["kind"] for r in meta["repairs"]]
    proc = run_cli("capture", "import", actor, "--pair-audio", "--fps", 30, "-o", tmp_path / "given")
    assert proc.returncode == 0, proc.stderr
    take = read_take(tmp_path / "given" / SHOTS[2])
    assert take.meta.fps == FPS and np.abs(take.values - made[SHOTS[2]]).max() < 1e-3


def make_neurosync_data(root: Path) -> Path:
    """NeuroSync's ``dataset/data`` after a training run: a folder per take of the app's calibrated CSV,
    ``audio.wav`` and the trainer's ``audio_features.csv`` (header 0..68, pandas' default), and its
    ``info.txt``. Test_1 is NeuroSync's own test pair (frame i at audio i/60 s)."""
    data = root / "dataset" / "data"
    slate, test = data / "20241204_MySlate_166", data / "20250131_Test_1"
    slate.mkdir(parents=True)
    test.mkdir()
    (data / "info.txt").write_text("Put all your (extracted) iPhone data folders in here (ARKit).\n")
    shutil.copy(SAMPLES / "livelinkface" / "neurosync_MySlate_166" / "MySlate_166_iPhone_cal.csv", slate)
    shutil.copy(NEUROSYNC / "testset.csv", test / "Test_1_iPhone_cal.csv")
    shutil.copy(NEUROSYNC / "audio.wav", test / "audio.wav")
    speech = np.concatenate([sf.read(p)[0] for p in sorted(SPEECH.glob("*.wav"))])  # 24.7 s at 16 kHz
    sf.write(slate / "audio.wav", np.tile(speech, 2)[: int(1848 / 60 * 16000)], 16000)
    rng = np.random.default_rng(1)
    for folder, frames in ((slate, 1848), (test, 1218)):
        rows = [",".join(map(str, range(69)))]
        rows += [",".join(f"{v:.6g}" for v in row) for row in rng.normal(size=(frames, 69))]
        (folder / "audio_features.csv").write_text("\n".join(rows) + "\n")
    return data


def test_a_neurosync_training_folder_imports_as_it_is(samples, tmp_path):
    """``import dataset/data --pair-audio``: both takes with their audio.wav (61 channels, 60 fps, all
    frames), the trainer's audio features skipped with a warning (old: an error for each, exit 1); paired
    as NeuroSync pairs them (``--audio-pairing frame-index``), the real take aligns within a frame."""
    data = make_neurosync_data(tmp_path)
    proc = run_cli("capture", "import", data, "--pair-audio", "-o", tmp_path / "takes")
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.count("NeuroSync's audio features (69 a frame") == 2
    for take, frames in (("MySlate_166_iPhone_cal", 1848), ("Test_1_iPhone_cal", 1218)):
        meta = _meta(tmp_path / "takes" / take)
        assert (meta["fps"], len(meta["channels"]), meta["audio"]["file"]) == (60.0, 61, "audio.wav")
        assert read_take(tmp_path / "takes" / take).values.shape == (frames, 61)
    test = data / "20250131_Test_1"
    args = ["--pair-audio", "--audio-pairing", "frame-index", "-o", tmp_path / "indexed"]
    proc = run_cli("capture", "import", test, *args)
    assert proc.returncode == 0, proc.stderr
    proc = run_cli("align", tmp_path / "indexed", "-o", tmp_path / "aligned", "--vad", "none", "--json")
    assert proc.returncode == 0, proc.stderr
    (report,) = [json.loads(line) for line in proc.stdout.splitlines() if line.startswith("{")]
    assert abs(report["offset_s"]) < 1 / 60


def test_neurosync_audio_features_named_alone_is_a_one_line_error(samples, tmp_path):
    data = make_neurosync_data(tmp_path)
    features = data / "20250131_Test_1" / "audio_features.csv"
    proc = run_cli(
        "capture", "import", features, "--audio", features.with_name("audio.wav"), "-o", tmp_path / "t"
    )
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().endswith(
        "NeuroSync's audio features (69 a frame, its trainer's cache of the audio), not face weights"
    )


def test_maya_and_pc2_skin_caches_import_as_the_npy_ones(samples, tmp_path):
    """The Claire dataset's layout (``cache/skin/<shot>/<shot>.xml`` + ``.mc``), a Maya cache of a file a
    frame in doubles (``.mcx``), and a ``.pc2``: the same weights as the ``.npy`` they were made from (was:
    one line saying to export ``.npy``); a cut ``.mc`` is one line naming it."""
    from test_mayacache_s29 import write_maya_cache, write_pc2

    actor, made = make_a2f_dataset(tmp_path / "a2f")
    skin = actor / "cache" / "skin"
    layouts = {SHOTS[0]: (False, False, False), SHOTS[2]: (True, True, True)}
    for shot, (wide, double, per_frame) in layouts.items():
        frames = np.load(skin / f"{shot}.npy")
        (skin / f"{shot}.npy").unlink()
        write_maya_cache(skin / shot, shot, frames, wide=wide, double=double, per_frame=per_frame)
    write_pc2(skin / f"{SHOTS[3]}.pc2", np.load(skin / f"{SHOTS[3]}.npy"))
    (skin / f"{SHOTS[3]}.npy").unlink()
    proc = run_cli("capture", "import", actor, "-o", tmp_path / "takes")
    assert proc.returncode == 0, proc.stderr
    for shot in (SHOTS[0], SHOTS[2], SHOTS[3]):
        take = read_take(tmp_path / "takes" / shot)
        assert take.meta.fps == FPS and np.abs(take.values - made[shot]).max() < 1e-3
    names = [Path(f["path"]).name for f in _meta(tmp_path / "takes" / SHOTS[0])["sources"]]
    assert f"{SHOTS[0]}.xml" in names and f"{SHOTS[0]}.mc" in names
    data = skin / SHOTS[0] / f"{SHOTS[0]}.mc"
    data.write_bytes(data.read_bytes()[:-100])
    proc = run_cli("capture", "import", actor, "-o", tmp_path / "again")
    errors = [line for line in proc.stderr.splitlines() if ": error: " in line]
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert len(errors) == 1 and f"{SHOTS[0]}.mc" in errors[0], errors
