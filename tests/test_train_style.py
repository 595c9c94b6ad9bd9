"""Speaker styles (``speaker_style``, train/style.py): a one-hot of the speaker appended to the prosody
input, the mean style for speakers a run did not train on, ensembles of members that trained on
different speakers, and the eval/predict ``--style`` choice, on a dataset whose two speakers differ
in how far they open the jaw."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from conftest import run_here
from dataset_helpers import make_aligned_take
from test_train_pipeline import TINY

from capture import read_livelink_csv, write_take
from dataset import BuildOptions, build_dataset
from dataset.splits import SplitRule
from train.ensemble import Ensemble
from train.style import MEAN, member_style_map, style_rows

JAW_OFFSET = 0.3  # spk1 rests with the jaw this much more open than spk0


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    root = tmp_path_factory.mktemp("style")
    for i in range(8):
        speaker = f"spk{i % 2}"
        take = make_aligned_take(f"take{i:02d}", 3.0, subject=speaker, seed=i)
        if speaker == "spk1":
            take.values[:, take.meta.channels.index("jawOpen")] += JAW_OFFSET
        write_take(take, root / "takes")
    options = BuildOptions(
        features=("pitch", "energy", "fbank"),
        split=SplitRule("take", 0.1, 0.1, 0, ("take05",), ("take06", "take07")),
        shard_bytes=200_000,
    )
    build_dataset([root / "takes"], root / "ds", options, say=lambda _m: None)
    return root / "ds"


def _cli(*args):
    return run_here("train", *map(str, args))


def _eval(run, ds, *extra):
    proc = _cli("eval", run, "--data", ds, "--json", *extra)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def _eval_here(run, ds, style):
    """In this process (the CLI's own path is covered above): one torch start-up less per call."""
    from train.evaluate import evaluate

    return evaluate(run, ds, "test", say=lambda _m: None, style=style)


def test_style_rows_one_hot_mean_override_and_dropout():
    styles = ("a", "b", "c")
    third = torch.full((3,), 1 / 3)
    rows = style_rows(["b", "zz", ""], styles)
    assert rows[0].tolist() == [0, 1, 0] and torch.equal(rows[1], third) and torch.equal(rows[2], third)
    assert style_rows(["a", "b"], styles, override="c").tolist() == [[0, 0, 1], [0, 0, 1]]
    assert torch.equal(style_rows(["a"], styles, override=MEAN)[0], third)
    torch.manual_seed(0)
    dropped = style_rows(["a"] * 2000, styles, dropout=0.25)
    share = float((dropped[:, 0] < 1).float().mean())
    assert 0.2 < share < 0.3  # about a quarter of the rows get the mean style
    assert torch.allclose(dropped.sum(1), torch.ones(2000))


def test_member_style_map_keeps_known_speakers_and_the_mean():
    union, member = ("a", "b", "c", "d"), ("b", "d")
    m = member_style_map(union, member)
    assert m.shape == (4, 2)
    assert m[1].tolist() == [1, 0] and m[3].tolist() == [0, 1]  # known speakers keep their one-hot
    assert m[0].tolist() == [0.5, 0.5]  # a speaker the member never saw: its mean style
    mean = torch.full((1, 4), 0.25)
    assert torch.allclose(mean @ m, torch.full((1, 2), 0.5))  # the union's mean is the member's mean


class _StyleReader(torch.nn.Module):
    """A member whose output is its style input times a fixed matrix (one output channel per speaker)."""

    def __init__(self, n: int, seed: int):
        super().__init__()
        self.n = n
        self.w = torch.randn(n, 3, generator=torch.Generator().manual_seed(seed))

    def forward(self, content, prosody, mask):
        return prosody[..., -self.n :] @ self.w + prosody[..., :1]


def test_ensemble_gives_each_member_its_own_styles():
    union = ("a", "b", "c")
    members = [("a", "b"), ("b", "c")]
    readers = [_StyleReader(len(m), i) for i, m in enumerate(members)]
    ens = Ensemble(readers, [member_style_map(union, m) for m in members])
    base = torch.randn(1, 5, 2)
    for name in ("a", "b", "c", MEAN):
        full = torch.cat([base, style_rows([name], union).expand(1, 5, 3)[:1]], -1)
        want = sum(
            r(None, torch.cat([base, style_rows([name], m).expand(1, 5, len(m))], -1), None)
            for r, m in zip(readers, members)
        )
        torch.testing.assert_close(ens(None, full, None), want / 2)


def test_ridge_with_speaker_style_learns_each_speakers_jaw(ds, tmp_path):
    """Without styles the jaw offset of spk1 is unpredictable from speech; with them ridge learns it.
    ``--style`` picks the mean style or another speaker's for every utterance."""
    plain, styled = tmp_path / "plain", tmp_path / "styled"
    assert _cli("fit", "--data", ds, "--model", "ridge", "-o", plain).returncode == 0
    proc = _cli("fit", "--data", ds, "--model", "ridge", "-o", styled, "--set", "speaker_style=true")
    assert proc.returncode == 0, proc.stderr
    config = json.loads((styled / "config.json").read_text())
    assert config["inputs"]["styles"] == ["spk0", "spk1"]  # take05 (spk1) validates, both speakers train

    r_plain, r_own = _eval(plain, ds), _eval(styled, ds)
    jaw_plain, jaw_own = r_plain["per_channel"]["jawOpen"], r_own["per_channel"]["jawOpen"]
    assert jaw_plain > 100 * JAW_OFFSET / 2 * 0.8  # half the offset missed on every frame, roughly
    assert jaw_own < 0.6 * jaw_plain  # what is left is the speech-driven part both speakers share
    assert r_own["rmse_entire"]["mean"] < r_plain["rmse_entire"]["mean"]
    assert "style" not in r_plain
    style = r_own["style"]
    assert style["chosen"] == "own" and style["styles"] == ["spk0", "spk1"]
    assert style["utterances_in_own_style"] == r_own["utterances"] and style["utterances_in_mean_style"] == 0

    r_mean = _eval_here(styled, ds, "mean")
    assert r_mean["style"]["chosen"] == "mean"
    assert r_mean["style"]["utterances_in_mean_style"] == r_mean["utterances"]
    assert r_mean["per_channel"]["jawOpen"] > 1.5 * jaw_own  # the mean style misses half the offset again
    r_wrong = _eval_here(styled, ds, "spk1")  # every test utterance with spk1's jaw
    assert r_wrong["style"]["utterances_in_chosen_style"] == r_wrong["utterances"]
    assert r_wrong["per_channel"]["jawOpen"] > 2 * jaw_own

    bad = _cli("eval", styled, "--data", ds, "--style", "spk9")
    assert bad.returncode == 1 and "unknown style 'spk9'" in bad.stderr and "Traceback" not in bad.stderr
    bad = _cli("eval", plain, "--data", ds, "--style", "spk0")
    assert bad.returncode == 1 and "no speaker styles" in bad.stderr

    # predict: --speaker chooses the style too, --style overrides it; the jaw follows the speaker
    wav = next((ds.parent / "takes").rglob("audio.wav"))
    jaw = {}
    for name, extra in (("spk0", ["--speaker", "spk0"]), ("spk1", ["--speaker", "spk1"]), ("mean", [])):
        out = tmp_path / f"{name}.csv"
        proc = _cli("predict", styled, wav, "-o", out, "--json", *extra)
        assert proc.returncode == 0, proc.stderr
        assert json.loads(proc.stdout)["style"] == name
        take = read_livelink_csv(out)
        jaw[name] = float(np.mean(take.values[:, take.meta.channels.index("jawOpen")]))
    # the ridge's penalty shrinks the per-speaker weights somewhat: most of the offset, not all of it
    assert 0.6 * JAW_OFFSET < jaw["spk1"] - jaw["spk0"] < 1.1 * JAW_OFFSET
    assert jaw["mean"] == pytest.approx((jaw["spk0"] + jaw["spk1"]) / 2, abs=0.02)
    out = tmp_path / "override.csv"
    proc = _cli("predict", styled, wav, "-o", out, "--speaker", "spk0", "--style", "spk1", "--json")
    assert json.loads(proc.stdout)["style"] == "spk1"


def test_network_with_styles_only_trains_evaluates_and_exports(ds, tmp_path):
    """A Transformer-S2A with no prosody but speaker styles: its prosody input is the style alone; the
    ONNX export lists the styles and matches PyTorch; a cross-validation ensemble of it evaluates."""
    sets = ["speaker_style=true", "prosody=false", *TINY, "eval_every=5"]
    args = [a for s in sets for a in ("--set", s)]
    run = tmp_path / "s2a"
    proc = _cli("fit", "--data", ds, "--model", "s2a", "-o", run, "--max-steps", 10, *args)
    assert proc.returncode == 0, proc.stderr
    assert json.loads((run / "config.json").read_text())["inputs"]["prosody_dim"] == 2
    assert _eval(run, ds)["style"]["utterances_in_own_style"] > 0
    proc = _cli("export", run, "-o", tmp_path / "s.onnx", "--json")
    assert proc.returncode == 0, proc.stderr
    exported = json.loads(proc.stdout)
    assert exported["styles"] == ["spk0", "spk1"] and exported["max_abs_diff"] < 1e-4

    cv = tmp_path / "cv"
    proc = _cli("fit", "--data", ds, "--model", "ridge", "-o", cv, "--set", "cv_folds=3", *args[:4])
    assert proc.returncode == 0, proc.stderr
    assert _eval(cv, ds)["style"]["styles"] == ["spk0", "spk1"]


@pytest.mark.parametrize(
    "value, needle",
    [("speaker_style=1", "speaker_style must be true or false"), ("style_dropout=1.0", "style_dropout")],
)
def test_bad_style_settings_are_one_line_errors(ds, tmp_path, value, needle):
    proc = _cli("fit", "--data", ds, "--model", "ridge", "-o", tmp_path / "r", "--set", value)
    assert proc.returncode == 1 and needle in proc.stderr and "Traceback" not in proc.stderr, proc.stderr


def test_a_speaker_named_mean_is_refused():
    from capture.errors import InputError
    from train.data import training_speakers

    manifest = {"samples": [{"key": "k", "take": "t", "speaker": "mean", "split": "train"}]}
    with pytest.raises(InputError, match="named 'mean'"):
        training_speakers(manifest, {}, "manifest.json")
