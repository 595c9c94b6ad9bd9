"""What the toolkit writes, as the tools its users feed it to read it: ``predict --count-name`` for
NeuroSync's loader, the metadata an exported ONNX file carries (and its fixed batch dimension), the
viewer's clock for audio paired by frame index, the device id a replayed take folder streams with, and
TensorBoard's ``epoch`` scalar once per step."""

from __future__ import annotations

import json
import re
import socket
from pathlib import Path

import numpy as np
import pytest
from dataset_helpers import build_five_take_dataset
from test_train_pipeline import TINY

from capture import read_audio
from capture.csv_take import COUNT_NAMES
from train.cli import build_parser, main
from train.config import resolve_config
from train.fit import fit

QUIET = {"say": lambda _m: None}
UUID = re.compile(r"^[0-9A-F]{8}-[0-9A-F]{4}-[0-9A-F]{4}-[0-9A-F]{4}-[0-9A-F]{12}$")


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    return build_five_take_dataset(tmp_path_factory.mktemp("interop"))


@pytest.fixture(scope="module")
def run(ds, tmp_path_factory):
    """Transformer-S2A, two steps, a training row and a validation row logged at each."""
    cfg = resolve_config(sets=TINY + ["max_steps=2", "eval_every=1", "log_every=1"])
    out = tmp_path_factory.mktemp("runs") / "s2a"
    fit(ds, out, cfg, **QUIET)
    return out


@pytest.fixture(scope="module")
def wav(ds):
    return next((ds.parent / "takes").rglob("audio.wav"))


# 1. predict writes the count column as NeuroSync's loader names it, on request


def test_predict_writes_the_count_name_asked_for(run, wav, tmp_path, capsys):
    out = tmp_path / "ns.csv"
    assert main(["predict", str(run), str(wav), "-o", str(out), "--count-name", "BlendshapeCount"]) == 0
    assert out.read_text().split("\n", 1)[0].split(",")[:2] == ["Timecode", "BlendshapeCount"]
    plain = tmp_path / "ue.csv"
    assert main(["predict", str(run), str(wav), "-o", str(plain)]) == 0
    assert plain.read_text().split("\n", 1)[0].split(",")[:2] == ["Timecode", "BlendShapeCount"]
    capsys.readouterr()
    # the same choices as s2a-capture export-csv, from the one constant
    predict = build_parser()._subparsers._group_actions[0].choices["predict"]
    option = next(a for a in predict._actions if "--count-name" in a.option_strings)
    assert tuple(option.choices) == COUNT_NAMES


def test_predict_refuses_another_count_name_in_one_line(run, wav, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["predict", str(run), str(wav), "-o", str(tmp_path / "x.csv"), "--count-name", "Count"])
    assert exc.value.code == 2
    assert "Traceback" not in capsys.readouterr().err
    from capture.errors import InputError
    from train.predict import predict

    with pytest.raises(InputError, match="count name must be one of"):
        predict(run, wav, tmp_path / "x.csv", count_name="blendshapecount", say=lambda _m: None)


# 2. the ONNX file carries what a user needs, and its output's batch dimension is 1


def test_onnx_carries_channels_fps_features_and_normalisation(run, wav, tmp_path):
    import onnx
    import onnxruntime as ort

    from dataset import FeatureSettings, Normalizer, compute_features
    from train import animate, load_system, normalize_features
    from train.export import export_onnx
    from train.predict import model_audio

    path = tmp_path / "m.onnx"
    summary = export_onnx(run, path, **QUIET)
    model, payload = load_system(run)
    graph = onnx.load(str(path))
    onnx.checker.check_model(graph, full_check=True)
    meta = {p.key: json.loads(p.value) for p in graph.metadata_props}
    assert sorted(meta) == summary["metadata"]
    info = payload["dataset"]
    assert meta["channels"] == info["channels"] and meta["fps"] == info["fps"]
    assert meta["features"] == info["features"] and meta["normalization"] == info["normalization"]
    assert meta["inputs"] == json.loads(json.dumps(payload["inputs"])) and "animation" in graph.doc_string
    dims = [[d.dim_param or d.dim_value for d in v.type.tensor_type.shape.dim] for v in graph.graph.output]
    assert dims == [[1, "frames", len(info["channels"])]]

    # the metadata alone (no dataset) turns speech into what train.animate gives
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    meta = {k: json.loads(v) for k, v in session.get_modelmeta().custom_metadata_map.items()}
    settings, fps, inputs = FeatureSettings.from_manifest(meta), meta["fps"], meta["inputs"]
    audio = model_audio(read_audio(wav))
    n = round(audio.size / settings.sample_rate * fps)
    feats, _ = compute_features(audio, n, fps, (inputs["content"], *inputs["prosody"]), settings)
    feats = normalize_features(meta, feats)
    feed = {
        "content": feats[inputs["content"]][None],
        "prosody": np.concatenate([feats[f] for f in inputs["prosody"]], axis=1)[None],
        "mask": np.ones((1, n), bool),
    }
    out = session.run(["animation"], feed)[0][0]
    weights = Normalizer.from_json(meta["normalization"]["animation"]).inverse(out)
    np.testing.assert_allclose(weights, animate(model, payload, read_audio(wav)), atol=1e-4)


# 3. the viewer places audio paired by frame index as s2a-align does


def test_render_places_a_frame_index_pairing_by_index(samples, tmp_path):
    from capture import write_take
    from capture.take_folder import read_csv_with_audio
    from viewer.render import load_animation

    pair = samples / "paired" / "neurosync-trainer-lite-testset"
    for by_index in (True, False):
        take = read_csv_with_audio(pair / "testset.csv", pair / "audio.wav", by_frame_index=by_index)
        write_take(take, tmp_path / str(by_index))
    by_index = load_animation(tmp_path / "True" / "testset")
    n, fps = by_index.time.size, by_index.fps
    assert by_index.take.meta.audio.start_source == "paired_frame_convention"
    np.testing.assert_allclose(by_index.time, np.arange(n) / fps, atol=1e-9)  # row i at audio i/fps
    # a first-row pairing keeps the CSV's timecodes, which run about 0.16 % slow: 32 ms by the end
    by_timecode = load_animation(tmp_path / "False" / "testset")
    assert 0.025 < by_timecode.time[-1] - by_index.time[-1] < 0.04


# 4. a replayed take folder streams a device id like the app's, not its device model


def test_replayed_take_folders_stream_uuids_not_the_device_model(tmp_path):
    from capture import import_source
    from capture.livelink import decode_packet
    from capture.replay import replay_take
    from capture.simulate.session import TakeSpec, simulate_take, write_take_folder

    devices = []
    for speaker in (0, 1):
        sim = simulate_take(TakeSpec(seed=3, speaker=speaker, take=1, seconds=2.0))
        folder = write_take_folder(sim, tmp_path)
        take = import_source(folder)
        assert take.meta.device == "iPhone13,3"  # take.json's deviceModel: kept as the take's metadata
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.bind(("127.0.0.1", 0))
            sock.settimeout(5)
            report = replay_take(take, "127.0.0.1", sock.getsockname()[1], speed=1000)
            frame = decode_packet(sock.recv(2048))
        assert UUID.match(frame.device) and frame.device == report.device
        devices.append(frame.device)
    assert devices[0] != devices[1]


def test_a_streamed_device_id_is_replayed_as_it_was(tmp_path):
    from dataset_helpers import make_aligned_take

    from capture.replay import default_device

    take = make_aligned_take("take00", 2.0)
    take.meta.device = "4E1B1D2C-0000-4000-8000-00000000ABCD"
    assert default_device(take) == take.meta.device
    take.meta.device = None
    assert UUID.match(default_device(take))


# 5. TensorBoard's epoch scalar once per step


def test_tensorboard_writes_each_scalar_once_per_step(run):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert sum("val_mse" in r for r in rows) == 2 and sum("mse" in r for r in rows) == 2
    folders = {p.parent for p in Path(run, "tensorboard").rglob("events.out.tfevents.*")}
    steps: dict[str, list[int]] = {}
    for folder in folders:
        events = EventAccumulator(str(folder))
        events.Reload()
        for tag in events.Tags()["scalars"]:
            steps.setdefault(tag, []).extend(e.step for e in events.Scalars(tag))
    assert sorted(steps["epoch"]) == [1, 2]
    assert sorted(steps["val_mse"]) == [1, 2] and sorted(steps["mse"]) == [1, 2]
