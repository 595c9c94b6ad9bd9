"""Units of the training stage: config resolution, the metrics on a hand-computed example, the
learning-rate schedule and the closed-form ridge solution."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from capture.errors import InputError
from train.config import DEFAULTS, parse_set, resolve_config
from train.evaluate import ErrorTally, crucial_columns
from train.fit import learning_rate
from train.ridge import NormalEquations, Ridge, stack_frames


def test_config_layers_toml_then_set(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text('model = "blstm"\nlr = 0.002\n[arch]\nhidden = 64\n[arch.s2a]\nd_model = 128\n')
    cfg = resolve_config(
        f, ["lr=1e-4", "prosody=false", "arch.layers=3", "arch.blstm.hidden=32", "input=mfcc"]
    )
    assert (
        cfg["model"] == "blstm" and cfg["lr"] == 1e-4 and cfg["prosody"] is False and cfg["input"] == "mfcc"
    )
    assert cfg["arch"] == {"hidden": 64, "s2a": {"d_model": 128}, "layers": 3, "blstm": {"hidden": 32}}
    assert DEFAULTS["arch"] == {}  # defaults are never mutated
    assert parse_set("note=hello world") == ("note", "hello world")


@pytest.mark.parametrize(
    "text, sets, needle",
    [
        ("lr = [", [], "not valid TOML"),
        ("", ["batch_size=0"], "batch_size must be a positive integer"),
        ("", ["model=gpt"], "model must be one of"),
        ("", ["prosody=maybe"], "prosody must be true or false"),
        ("", ["lr"], "--set expects key=value"),
        ("speed = 3", [], "unknown config key 'speed'"),
        ("lr = 1" + "0" * 5000, [], "not valid TOML: Exceeds the limit"),
    ],
)
def test_config_errors_name_the_field(tmp_path, text, sets, needle):
    f = tmp_path / "c.toml"
    f.write_text(text)
    with pytest.raises(InputError, match=needle):
        resolve_config(f, sets)


def test_config_files_saved_by_windows_editors_are_read(tmp_path):
    """Notepad's UTF-8 with a byte-order mark, and "Unicode" (UTF-16), for TOML and a JSON config."""
    for name, raw in (
        ("bom.toml", "\ufefflr = 0.002\n".encode("utf-8")),
        ("u16.toml", "lr = 0.002\n".encode("utf-16")),
        ("bom.json", '\ufeff{"lr": 0.002}'.encode("utf-8")),
    ):
        (tmp_path / name).write_bytes(raw)
        assert resolve_config(tmp_path / name, [])["lr"] == 0.002, name


def test_error_tally_matches_hand_computation():
    channels = ["jawOpen", "mouthClose", "mouthFunnel"]
    true = np.zeros((4, 3))
    pred = np.array([[0.01, 0.02, 0.0], [0.01, 0.02, 0.0], [0.0, 0.0, 0.03], [9.0, 9.0, 9.0]])
    mask = np.array([True, True, True, False])  # the last frame is not usable
    t = ErrorTally(channels)
    t.add(pred, true, mask)
    t.add(true[:2] + 0.04, true[:2], np.ones(2, bool))
    s = t.summary()
    # utterance 1: squared errors (×100)² = 1,4,0, 1,4,0, 0,0,9 → mean 19/9; utterance 2: 16 everywhere
    u1, u2 = np.sqrt(19 / 9), 4.0
    assert s["rmse_entire"]["mean"] == pytest.approx((u1 + u2) / 2)
    assert s["rmse_entire"]["std"] == pytest.approx(abs(u1 - u2) / 2)
    c1 = np.sqrt((1 + 4 + 1 + 4) / 6)
    assert s["rmse_crucial"]["mean"] == pytest.approx((c1 + 4.0) / 2)
    assert s["per_channel"]["jawOpen"] == pytest.approx(np.sqrt((1 + 1 + 16 + 16) / 5), abs=1e-6)
    assert s["frames"] == 5 and s["utterances"] == 2
    assert crucial_columns(["JawOpen", "x"]) is None


def test_learning_rate_warms_up_then_decays():
    cfg = {"lr": 1.0, "warmup_steps": 10, "max_steps": 110, "min_lr_ratio": 0.1}
    assert learning_rate(0, cfg) == pytest.approx(0.1)
    assert learning_rate(9, cfg) == pytest.approx(1.0)
    assert learning_rate(60, cfg) == pytest.approx(0.55)
    assert learning_rate(110, cfg) == pytest.approx(0.1) == learning_rate(500, cfg)


def test_ridge_closed_form_matches_least_squares():
    g = torch.Generator().manual_seed(0)
    content, prosody = torch.randn(2, 50, 3, generator=g), torch.randn(2, 50, 1, generator=g)
    mask = torch.ones(2, 50, dtype=torch.bool)
    mask[1, 40:] = False
    model = Ridge(3, 1, 2, context=1)
    x = model.inputs(content, prosody, mask)
    assert x.shape == (2, 50, 12) and torch.equal(stack_frames(content, 1)[0, 0, :3], torch.zeros(3))
    y = x @ torch.randn(12, 2, generator=g) + 0.5
    eq = NormalEquations(12, 2)
    eq.add(x, y, mask)
    eq.solve(model, alpha=1e-12)
    with torch.no_grad():
        pred = model(content, prosody, mask)
    np.testing.assert_allclose(pred[mask].numpy(), y[mask].numpy(), atol=1e-4)


def test_precision_refuses_emulated_bf16_and_unknown_names(monkeypatch):
    import train.precision as precision

    model = torch.nn.Linear(4, 4)
    assert precision.for_inference(model, "fp32") is model
    with pytest.raises(InputError, match="must be one of fp32, bf16"):
        precision.for_inference(model, "fp8")
    monkeypatch.setattr(precision, "bf16_is_native", lambda: False)
    with pytest.raises(InputError, match="no native bfloat16"):
        precision.for_inference(model, "bf16")


def test_folds_balance_takes_by_duration():
    from train.ensemble import fold_takes

    durations = {"a": 50.0, "b": 40.0, "c": 30.0, "d": 20.0, "e": 10.0, "t": 99.0}
    manifest = {
        "samples": [
            {"take": t, "split": "test" if t == "t" else "train", "duration_s": d / 2}
            for t, d in durations.items()
            for _half in range(2)
        ]
    }
    folds = fold_takes(manifest, 2)
    assert folds == [["a", "d", "e"], ["b", "c"]]  # 80 s and 70 s; the test take is in neither
    with pytest.raises(InputError, match="needs as many train/val recordings"):
        fold_takes(manifest, 6)


def test_folds_and_val_takes_keep_the_segments_of_a_recording_together():
    from train.data import split_keys
    from train.ensemble import fold_takes

    takes = ["long.seg01", "long.seg02", "long.seg03", "b", "c", "d"]
    manifest = {
        "samples": [{"key": t, "take": t, "split": "train", "duration_s": 10.0} for t in takes],
        "sources": [{"take": t} for t in takes],  # no recording recorded: align's .segNN names are used
    }
    for k in (2, 3):
        folds = fold_takes(manifest, k)
        home = [i for i, f in enumerate(folds) if "long.seg01" in f]
        assert len(home) == 1 and {"long.seg02", "long.seg03"} <= set(folds[home[0]])
    train, val = split_keys(manifest, {"val_takes": ["long.seg02"]})
    assert val == {"long.seg01", "long.seg02", "long.seg03"} and train == {"b", "c", "d"}
    manifest["sources"] = [{"take": t, "recording": "rec" if t in ("b", "c") else t} for t in takes]
    train, val = split_keys(manifest, {"val_takes": ["rec"]})  # a recording id names its takes
    assert val == {"b", "c"}
    with pytest.raises(InputError, match="no take 'nope'"):
        split_keys(manifest, {"val_takes": ["nope"]})


# -- windowed inference (train/windowed.py) ---------------------------------------------------------------
class _FrameLocal(torch.nn.Module):
    """Each output frame depends on its own input frame only: windows must change nothing."""

    def __init__(self):
        super().__init__()
        self.proj = torch.nn.Linear(5, 3)

    def forward(self, content, prosody, mask):
        return self.proj(content) + prosody.sum(-1, keepdim=True)


@pytest.mark.parametrize("frames, window", [(100, 100), (101, 100), (260, 100), (1799, 240), (5000, 7)])
def test_windowed_inference_covers_every_frame_with_weights_summing_to_one(frames, window):
    from train.windowed import infer_windowed, window_starts

    starts = window_starts(frames, window)
    assert starts[0] == 0 and starts[-1] == max(0, frames - window)
    assert all(0 < b - a <= max(1, window // 2) for a, b in zip(starts, starts[1:]))
    torch.manual_seed(0)
    model = _FrameLocal().eval()
    content, prosody = torch.randn(1, frames, 5), torch.randn(1, frames, 2)
    mask = torch.ones(1, frames, dtype=torch.bool)
    with torch.no_grad():
        whole = model(content, prosody, mask)
        got = infer_windowed(model, content, prosody, mask, window)
    torch.testing.assert_close(got, whole, atol=1e-5, rtol=1e-5)


def test_windowed_inference_blends_without_steps():
    """Windows that disagree (each adds its own offset) meet in ramps, never in a jump."""
    from train.windowed import infer_windowed

    class Offset(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.w = torch.nn.Parameter(torch.zeros(1))
            self.calls = 0

        def forward(self, content, prosody, mask):
            self.calls += 1
            return torch.full((1, content.shape[1], 1), float(self.calls))

    model = Offset()
    frames = 1000
    out = infer_windowed(model, torch.zeros(1, frames, 1), None, torch.ones(1, frames, dtype=torch.bool), 200)
    steps = out[0, 1:, 0] - out[0, :-1, 0]
    assert model.calls == 9 and out[0, 0, 0] == 1 and out[0, -1, 0] == model.calls
    assert steps.abs().max() <= 1 / 50 + 1e-6  # at most one offset unit over a 50-frame ramp
