"""Training on each usable value: in an ``all`` dataset whose head angles glitch (headYaw past ±10) in
frames whose pronunciation channels are fine, the sample's ``channel_mask.npy`` keeps those channels
usable. The reader yields them (``values``), the training loss and the validation loss score them, and
mixup keeps a mixed value only where both windows have it. Before, training left out every frame a
single channel was unusable in (its jawOpen target too)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from dataset_helpers import make_aligned_take
from test_train_pipeline import TINY

from capture import ARKIT61, write_take
from dataset import BuildOptions, build_dataset
from dataset.splits import SplitRule
from dataset.torch_dataset import ShardDataset
from train.augment import augment_frames
from train.config import resolve_config
from train.data import endless_batches, resolve_inputs, to_model_inputs, train_dataset
from train.fit import _train_step, validation_loss
from train.model import masked_mse
from train.systems import build_model

YAW = ARKIT61.index("headYaw")
JAW = ARKIT61.index("jawOpen")
GLITCH = range(20, 80)  # of 120 frames: headYaw jumps to 40 in the training and validation takes
GAP = (100, 105)  # a lost face: every channel unusable
FEATURES = ("pitch", "energy", "fbank")


@pytest.fixture(scope="module")
def glitched(tmp_path_factory):
    """Four ARKit61 takes (2 s at 60 fps): t0, t3 train, t1 val, t2 test; all but the test take glitch in
    headYaw and lose the face for 5 frames. An ``all`` dataset (with channel_mask.npy) and the same
    takes without the glitch (a dataset without the member)."""
    root = tmp_path_factory.mktemp("valuemask")
    for glitch in (True, False):
        for i in range(4):
            take = make_aligned_take(f"t{i}", 2.0, subject="a", seed=i, channels=ARKIT61)
            if i != 2:
                if glitch:
                    take.values[list(GLITCH), YAW] = 40.0
                take.frame_status[GAP[0] : GAP[1]] = 1
            write_take(take, root / f"takes_{glitch}")
        options = BuildOptions(
            channels="all", features=FEATURES, split=SplitRule("take", 0.1, 0.1, 0, ("t1",), ("t2",))
        )
        build_dataset([root / f"takes_{glitch}"], root / f"ds_{glitch}", options, say=lambda _m: None)
    return {"glitch": root / "ds_True", "plain": root / "ds_False"}


def _usable(frames: int) -> np.ndarray:
    usable = np.ones((frames, len(ARKIT61)), bool)
    usable[list(GLITCH), YAW] = False
    usable[GAP[0] : GAP[1]] = False
    return usable


def test_the_reader_yields_each_usable_value_when_asked(glitched):
    counted = {}
    for name, ds in glitched.items():
        items = list(ShardDataset(ds, "train", window=None, features="energy", values=True))
        assert len(items) == 2
        for item in items:
            frame_mask = np.ones(120, bool)
            frame_mask[GAP[0] : GAP[1]] = False
            if name == "glitch":
                frame_mask[list(GLITCH)] = False
            np.testing.assert_array_equal(item["mask"].numpy(), frame_mask)  # the frames as before
            expected = _usable(120) if name == "glitch" else np.repeat(frame_mask[:, None], len(ARKIT61), 1)
            np.testing.assert_array_equal(item["values"].numpy(), expected)
            # the normalised animation keeps the usable values of a glitched frame, 0 at the others
            raw = ShardDataset(ds, "train", window=None, features="energy", normalize=False)
            (whole,) = [i for i in raw if i["key"] == item["key"]]
            normalised = raw.normalizer.forward(whole["anim"].numpy(), None, dtype=np.float32)
            np.testing.assert_allclose(item["anim"].numpy(), np.where(expected, normalised, 0), atol=1e-6)
        # targets per epoch: old (frames usable in every channel × channels) and new (usable values)
        counted[name] = (
            sum(int(i["mask"].sum()) * len(ARKIT61) for i in items),
            sum(int(i["values"].sum()) for i in items),
        )
    assert counted["plain"] == (2 * 115 * 61, 2 * 115 * 61)
    assert counted["glitch"] == (2 * 55 * 61, 2 * (115 * 61 - 60)), counted  # 6710 -> 13910 values
    # not asked: no per-value mask (the reader's items as before)
    assert "values" not in next(iter(ShardDataset(glitched["glitch"], "train", features="energy")))


def _setup(ds, sets=()):
    cfg = resolve_config(sets=[*TINY, *sets])
    manifest = ShardDataset(ds, "train").manifest
    spec = resolve_inputs(manifest, cfg)
    return cfg, manifest, spec


def test_training_learns_jaw_open_from_the_frames_whose_head_yaw_glitched(glitched):
    """The loss depends on jawOpen's target at a frame whose headYaw glitched, never on headYaw's there."""
    cfg, manifest, spec = _setup(glitched["glitch"])
    _, _, batch = next(endless_batches(train_dataset(glitched["glitch"], spec, cfg, manifest), 4))
    window_glitch = batch["present"] & ~batch["mask"]  # glitched frames (the lost face's too) in the windows
    losses = {}
    for name, channel, value in (("as read", JAW, None), ("jaw", JAW, 1e3), ("yaw", YAW, 1e3)):
        b = dict(batch)
        if value is not None:
            b["anim"] = batch["anim"].clone()
            b["anim"][..., channel] = torch.where(window_glitch, value, batch["anim"][..., channel])
        torch.manual_seed(0)
        model, _ = build_model("s2a", spec, cfg)
        losses[name] = float(_train_step(model, model, b, spec, cfg, None, torch.device("cpu"))[0].detach())
    assert losses["jaw"] > 100 * losses["as read"]  # before: equal, the frame was left out
    assert losses["yaw"] == losses["as read"]  # the glitched value itself is never a target


def test_a_frame_mask_and_its_values_give_the_same_loss_and_gradient():
    torch.manual_seed(1)
    pred = torch.randn(3, 7, 5, requires_grad=True)
    target = torch.randn(3, 7, 5)
    mask = torch.rand(3, 7) > 0.4
    weights = torch.rand(5)
    grads = []
    for m in (mask, mask.unsqueeze(-1).expand(-1, -1, 5)):
        loss = masked_mse(pred, target, m, weights)
        (grad,) = torch.autograd.grad(loss, pred)
        grads.append((loss, grad))
    assert torch.equal(grads[0][0], grads[1][0]) and torch.equal(grads[0][1], grads[1][1])
    values = torch.rand(3, 7, 5) > 0.5
    values[0] = False  # a row without a usable value counts nothing
    expected = ((pred - target) ** 2 * weights)[values].sum() / values.sum()
    assert float(masked_mse(pred, target, values, weights).detach()) == pytest.approx(
        float(expected.detach()), rel=1e-6
    )


def test_mixup_keeps_a_value_where_both_windows_have_it(glitched):
    cfg, manifest, spec = _setup(glitched["glitch"], ["aug_mixup=0.4"])
    _, _, batch = next(endless_batches(train_dataset(glitched["glitch"], spec, cfg, manifest), 4))
    content = batch["energy"]
    torch.manual_seed(3)
    *_, values, present = augment_frames(content, None, batch["anim"], batch["values"], batch["present"], cfg)
    torch.manual_seed(3)
    *_, mask, _ = augment_frames(content, None, batch["anim"], batch["mask"], batch["present"], cfg)
    assert values.shape == batch["values"].shape
    assert bool((values <= present.unsqueeze(-1)).all())
    np.testing.assert_array_equal(values.all(dim=-1).numpy(), mask.numpy())  # every channel's: as before
    assert int(values.sum()) > int(mask.sum()) * len(ARKIT61)


def test_validation_scores_each_usable_value(glitched):
    cfg, manifest, spec = _setup(glitched["glitch"])
    torch.manual_seed(0)
    model, _ = build_model("s2a", spec, cfg)
    got = validation_loss(model, glitched["glitch"], spec, torch.device("cpu"), None, cfg, manifest)
    (item,) = ShardDataset(glitched["glitch"], "val", window=None, features=list(spec.features), values=True)
    batch = {k: (v.unsqueeze(0) if isinstance(v, torch.Tensor) else v) for k, v in item.items()}
    content, prosody = to_model_inputs(batch, spec)
    model.eval()
    with torch.no_grad():
        pred = model(content, prosody, batch["present"])
    values = batch["values"]
    expected = float(((pred - batch["anim"]) ** 2)[values].sum()) / int(values.sum())
    assert int(values.sum()) == 115 * 61 - 60  # the glitched frames' other 60 channels are scored
    assert got == pytest.approx(expected, rel=1e-5)
