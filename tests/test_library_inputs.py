"""The library as trainers call it from Python: what ``write_take`` and ``Take`` accept is what
``read_take`` reads back (and a take read without its audio never loses it), ``train.animate`` takes
audio at any rate, sample format, channel count and container type, ``predict`` takes one path,
``FeatureSettings.from_manifest`` gives a build's settings, ``Normalizer.inverse`` works on tensors and
``train.fit`` completes a partial config. Each test failed before its fix."""

from __future__ import annotations

import copy
import os
from dataclasses import replace

import numpy as np
import pytest
import soundfile as sf
import torch
from dataset_helpers import build_five_take_dataset, speech_like
from live_helpers import synthetic_take
from test_train_pipeline import TINY

from capture import Audio, InputError, TakeMeta, read_take, write_take
from capture.take import Take
from dataset import FeatureSettings, Normalizer, compute_features, read_manifest
from dataset.pitch import PitchSettings
from train import animate, normalize_features, predict
from train.checkpoint import load_system
from train.config import resolve_config
from train.data import InputSpec
from train.fit import fit

QUIET = {"say": lambda _m: None}


# -- 1. a take read without its audio ------------------------------------------------------------------
def test_a_take_read_without_its_audio_is_not_written_over_it(tmp_path):
    folder = write_take(synthetic_take(60, audio=True), tmp_path)
    take = read_take(folder, audio=False)
    meta = copy.deepcopy(take.meta)
    with pytest.raises(InputError, match=r"read_take\(\.\.\., audio=False\)"):
        write_take(take, folder.parent)
    assert take.meta == meta  # the caller's take is as it was
    back = read_take(folder)
    assert back.audio is not None and back.audio.frames == 16000
    # said so, it is written without its audio
    take.meta.audio = None
    write_take(take, tmp_path / "frames-only")
    assert not (tmp_path / "frames-only" / folder.name / "audio.wav").exists()


def test_write_take_leaves_the_callers_take_as_it_was(tmp_path):
    take = synthetic_take(60, audio=True)
    before = copy.deepcopy(take.meta)
    folder = write_take(take, tmp_path)
    assert take.meta == before
    assert read_take(folder).meta == take.meta  # what attach_audio records is what is read back


# -- 2. Take and write_take refuse what read_take refuses ----------------------------------------------
def _meta(channels=("jawOpen",)) -> TakeMeta:
    return TakeMeta(id="t", source_kind="test", fps=60.0, channels=list(channels))


@pytest.mark.parametrize(
    "status, needle",
    [
        (np.full(4, 7), r"unknown value\(s\) \[7\]"),
        (np.full(4, -1), r"unknown value\(s\) \[-1\]"),
        (np.full(4, 256, np.int64), r"unknown value\(s\) \[256\]"),
        (np.full(4, 0.5), "not integer codes"),
        (np.full(4, np.nan), "not integer codes"),
        (np.ones(4, bool), "bool, not integer codes"),
    ],
)
def test_frame_status_of_unknown_codes_or_types_is_refused(status, needle):
    with pytest.raises(InputError, match=needle):
        Take(_meta(), np.arange(4) / 60, np.zeros((4, 1), np.float32), status)


def test_values_that_are_no_float32_numbers_are_refused():
    t = np.arange(3) / 60
    with pytest.raises(InputError, match="beyond the range of float32"):
        Take(_meta(), t, np.full((3, 1), 1e39), np.zeros(3, np.uint8))
    with pytest.raises(InputError, match="must be numbers"):
        Take(_meta(), t, np.array([["0.5"], ["0.1"], ["0"]]), np.zeros(3, np.uint8))
    with pytest.raises(InputError, match="must be numbers"):
        Take(_meta(), np.array(["0", "1", "2"]), np.zeros((3, 1)), np.zeros(3, np.uint8))
    with pytest.raises(InputError, match="NaN or infinite"):
        Take(_meta(), np.array([np.nan]), np.zeros((1, 1)), np.zeros(1, np.uint8))


def test_audio_read_take_would_refuse_is_refused_on_construction_and_on_writing(tmp_path):
    take = synthetic_take(60)
    with pytest.raises(InputError, match="1 NaN or infinite"):
        take.attach_audio(Audio(np.array([0.1, np.nan, 0.2], np.float32), 16000))
    with pytest.raises(InputError, match="no samples"):
        take.attach_audio(Audio(np.zeros((0, 1), np.float32), 16000))
    with pytest.raises(InputError, match="no samples"):
        replace(take, audio=Audio(np.zeros(0, np.int16), 16000, "PCM_16"))
    # arrays replaced after construction: write_take checks again, and writes nothing
    take.frame_status = np.full(take.time.size, 7)
    with pytest.raises(InputError, match="unknown value"):
        write_take(take, tmp_path)
    take = synthetic_take(60, audio=True)
    take.audio.samples[3] = np.inf
    with pytest.raises(InputError, match="NaN or infinite"):
        write_take(take, tmp_path)
    assert os.listdir(tmp_path) == []


def test_audio_needs_numbers_a_whole_rate_and_samples_first():
    assert Audio([0.0, 0.5, -0.5], 16000).samples.shape == (3, 1)  # a list is one channel
    assert Audio(np.zeros(4, np.float32), 44100.0).sample_rate == 44100
    with pytest.raises(InputError, match="whole positive number"):
        Audio(np.zeros(4, np.float32), 44100.7)
    with pytest.raises(InputError, match="whole positive number"):
        Audio(np.zeros(4, np.float32), float("nan"))
    with pytest.raises(InputError, match=r"\(channels, samples\)"):
        Audio(np.zeros((2, 16000), np.float32), 16000)
    with pytest.raises(InputError, match="must be numbers"):
        Audio(np.array(["0.1", "0.2"]), 16000)


# -- 3. animate, predict and compute_features take audio as it comes -----------------------------------
@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A one-step Transformer-S2A run (dropout on) on five 2 s takes at 60 fps."""
    root = tmp_path_factory.mktemp("library")
    ds = build_five_take_dataset(root)
    cfg = resolve_config(sets=[*TINY, "arch.dropout=0.3", "max_steps=1", "eval_every=1"])
    fit(ds, root / "run", cfg, **QUIET)
    return ds, root / "run"


@pytest.fixture(scope="module")
def speech() -> np.ndarray:
    return (0.5 * speech_like(2.0, np.random.default_rng(11))[0]).astype(np.float32)


def test_animate_takes_the_rate_format_channels_and_type_of_the_audio(run, speech):
    import soxr

    model, payload = load_system(run[1])
    fps = payload["dataset"]["fps"]
    base = animate(model, payload, speech)
    assert base.shape[0] == round(2.0 * fps)
    at44 = soxr.resample(speech, 16000, 44100, quality="VHQ").astype(np.float32)
    assert animate(model, payload, at44, sample_rate=44100).shape[0] == round(2.0 * fps)
    assert animate(model, payload, Audio(at44, 44100)).shape[0] == round(2.0 * fps)
    pcm = np.round(speech * 32767).astype(np.int16)
    np.testing.assert_allclose(animate(model, payload, pcm), base, atol=2e-3)
    stereo = np.stack([speech, speech], axis=1)
    np.testing.assert_allclose(animate(model, payload, stereo), base, atol=1e-5)
    np.testing.assert_allclose(animate(model, payload, torch.from_numpy(speech)), base, atol=1e-6)
    np.testing.assert_allclose(animate(model, payload, speech.tolist()), base, atol=1e-6)
    with pytest.raises(InputError, match=r"\(channels, samples\)"):
        animate(model, payload, stereo.T.copy())
    with pytest.raises(InputError, match="not str"):
        animate(model, payload, "speech.wav")
    bad = speech.copy()
    bad[100] = np.nan
    with pytest.raises(InputError, match="1 NaN or infinite sample") as caught:
        animate(model, payload, bad)
    assert "model" not in str(caught.value).split("(")[0]


def test_animate_runs_the_model_in_eval_mode_and_restores_its_mode(run, speech):
    model, payload = load_system(run[1])
    model.train()
    first = animate(model, payload, speech)
    assert model.training
    second = animate(model, payload, speech)
    np.testing.assert_array_equal(first, second)
    model.eval()
    np.testing.assert_array_equal(animate(model, payload, speech), first)
    assert not model.training


def test_predict_takes_one_path_as_one_file(run, speech, tmp_path):
    wav = tmp_path / "one.wav"
    sf.write(wav, speech, 16000, subtype="FLOAT")
    results = predict(run[1], str(wav), tmp_path / "one.csv", **QUIET)
    assert [r["csv"] for r in results] == [str(tmp_path / "one.csv")]
    results = predict(run[1], wav, tmp_path / "out", **QUIET)
    assert [r["csv"] for r in results] == [str(tmp_path / "out" / "one.csv")]
    with pytest.raises(InputError, match="audio file not found"):
        predict(run[1], str(tmp_path / "missing.wav"), tmp_path / "missing.csv", **QUIET)


def test_compute_features_refuses_audio_of_another_rate_or_nan(speech):
    settings = FeatureSettings()
    names = ("energy", "fbank")
    feats, _ = compute_features(speech, 120, 60.0, names, settings)
    assert feats["fbank"].shape == (120, 40)
    at44 = np.zeros(88200, np.float32)
    with pytest.raises(InputError, match="another sample rate"):
        compute_features(at44, 120, 60.0, names, settings)
    with pytest.raises(InputError, match="44100 Hz"):
        compute_features(speech, 120, 60.0, names, settings, sample_rate=44100)
    bad = speech.copy()
    bad[5] = np.nan
    with pytest.raises(InputError, match="NaN or infinite"):
        compute_features(bad, 120, 60.0, names, settings)
    with pytest.raises(InputError, match="float samples"):
        compute_features(np.round(speech * 32767).astype(np.int16), 120, 60.0, names, settings)


# -- 4. the feature settings of a build, and the ONNX recipe's chain -----------------------------------
def test_feature_settings_from_a_manifest_are_the_builds(run):
    ds, _ = run
    manifest = read_manifest(ds)
    settings = FeatureSettings.from_manifest(manifest)
    assert isinstance(settings.pitch, PitchSettings)
    assert settings.level == manifest["features"]["settings"]["level"] == "speech -26 dBFS"
    assert settings.to_json() == manifest["features"]["settings"]
    assert FeatureSettings.from_manifest(ds) == settings  # the folder, read with read_manifest
    legacy = {k: v for k, v in manifest["features"]["settings"].items() if k != "level"}
    assert FeatureSettings.from_json(legacy).level == "none"
    for broken, needle in (
        ({**legacy, "pitch": "praat"}, "pitch must be a JSON object"),
        ({**legacy, "n_mels": "40"}, "n_mels must be a positive whole number"),
        ({**legacy, "sampel_rate": 16000}, "unknown field"),
        ({**legacy, "level": "loud"}, "level"),
    ):
        with pytest.raises(InputError, match=needle):
            FeatureSettings.from_json(broken)
    with pytest.raises(InputError, match="no feature settings"):
        FeatureSettings.from_manifest({"features": {"names": []}})


def test_the_onnx_recipes_feature_chain_gives_what_animate_gives(run, speech):
    """docs/guide-training.md §10, with the PyTorch model in onnxruntime's place."""
    from align.resample import to_16k_mono

    ds, run_dir = run
    model, payload = load_system(run_dir)
    manifest = read_manifest(ds)
    settings = FeatureSettings.from_manifest(manifest)
    fps = manifest["fps"]
    audio = to_16k_mono(Audio(speech, 16000))
    n = round(audio.size / settings.sample_rate * fps)
    span = round(n * settings.sample_rate / fps)
    audio = np.pad(audio, (0, max(span - audio.size, 0)))[:span]
    feats, _ = compute_features(audio, n, fps, ("fbank", "pitch", "energy"), settings)
    feats = normalize_features(manifest, feats)
    content = feats["fbank"][None]
    prosody = np.concatenate([feats["pitch"], feats["energy"]], axis=1)[None]
    assert InputSpec.from_json(payload["inputs"]).features == ["fbank", "pitch", "energy"]
    with torch.no_grad():
        out = model.eval()(torch.from_numpy(content), torch.from_numpy(prosody), torch.ones(1, n, dtype=bool))
    out = out[0] if isinstance(out, tuple) else out
    weights = Normalizer.from_json(manifest["normalization"]["animation"]).inverse(out[0].numpy())
    np.testing.assert_allclose(weights, animate(model, payload, speech), atol=1e-4)


# -- 5. Normalizer on tensors; fit with a partial config -----------------------------------------------
def test_normalizer_inverse_keeps_a_tensor_a_tensor_and_differentiable():
    norm = Normalizer("zscore", ["a", "b"], np.array([0.25, -1.0]), np.array([0.5, 2.0]))
    y = torch.tensor([[1.0, 2.0], [-1.0, 0.5]], requires_grad=True)
    x = norm.inverse(y)
    assert isinstance(x, torch.Tensor) and x.dtype == torch.float32 and x.device == y.device
    np.testing.assert_array_equal(x.detach().numpy(), norm.inverse(y.detach().numpy()))
    x.sum().backward()
    np.testing.assert_array_equal(y.grad.numpy(), [[0.5, 2.0], [0.5, 2.0]])
    assert norm.inverse(y.detach().double()).dtype == torch.float64
    neutral = Normalizer("neutral", ["a", "b"], np.zeros(2), np.ones(2))
    pose = torch.tensor([0.1, 0.2])
    np.testing.assert_allclose(neutral.inverse(torch.zeros(1, 2), pose).numpy(), [[0.1, 0.2]])


def test_fit_fills_a_partial_config_from_the_defaults(run, tmp_path):
    ds, _ = run
    summary = fit(ds, tmp_path / "ridge", {"model": "ridge", "ridge_context": 1}, **QUIET)
    assert summary["model"] == "ridge" and (tmp_path / "ridge" / "last.pt").is_file()
    with pytest.raises(InputError, match="unknown config key"):
        fit(ds, tmp_path / "typo", {"model": "ridge", "learning_rate": 1e-3}, **QUIET)
    with pytest.raises(InputError, match="model must be one of"):
        fit(ds, tmp_path / "bad", {"model": "s3a"}, **QUIET)
