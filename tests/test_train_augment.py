"""Small-data training options: input augmentation (train/augment.py) and the loss's channel weights."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from capture.errors import InputError
from train.augment import _span_mask, augment, enabled
from train.config import DEFAULTS, resolve_config
from train.fit import channel_weights
from train.model import masked_mse

OFF = {k: v for k, v in DEFAULTS.items() if k.startswith("aug_")}


def _batch(b=4, t=50, c=6, p=3, ch=5):
    g = torch.Generator().manual_seed(0)
    content = torch.randn(b, t, c, generator=g) + 3.0  # away from 0 so that masked values stand out
    prosody = torch.randn(b, t, p, generator=g) + 3.0
    target = torch.randn(b, t, ch, generator=g)
    mask = torch.ones(b, t, dtype=torch.bool)
    mask[1, 40:] = False
    return content, prosody, target, mask


def test_defaults_are_off_and_change_nothing():
    assert not enabled(DEFAULTS)
    batch = _batch()
    out = augment(*batch, {**DEFAULTS})
    for a, b in zip(batch, out):
        assert torch.equal(a, b)


def test_span_mask_widths_and_counts():
    torch.manual_seed(3)
    m = _span_mask(2, 7, 200, 60)
    assert m.shape == (200, 60)
    runs = []
    for row in m.int().numpy():
        edges = np.flatnonzero(np.diff(np.r_[0, row, 0]))
        runs += list(edges[1::2] - edges[::2])
    assert max(runs) <= 14 and sum(m.sum(1) > 14) == 0  # two spans of at most 7 frames
    assert 0.05 < m.float().mean() < 0.2  # about 2 × 3.5 / 60 of the frames
    assert not _span_mask(0, 7, 3, 10).any() and not _span_mask(2, 0, 3, 10).any()


def test_time_and_feature_masks_zero_the_content_only():
    batch = _batch()
    content, prosody, target, mask = batch
    before = [x.clone() for x in batch]
    cfg = {**OFF, "aug_time_masks": 2, "aug_time_mask_width": 8}
    torch.manual_seed(0)
    c2, p2, t2, m2 = augment(*batch, cfg)
    for a, b in zip(before, batch):  # nothing modified in place
        assert torch.equal(a, b)
    blank = (c2 == 0).all(-1)
    assert blank.any() and ((c2 == content) | (c2 == 0)).all()
    assert torch.equal(p2, prosody) and torch.equal(t2, target) and torch.equal(m2, mask)
    torch.manual_seed(0)
    c3, p3, _, _ = augment(*batch, {**cfg, "aug_mask_prosody": True})
    assert torch.equal(c3, c2) and torch.equal((p3 == 0).all(-1), blank)  # same spans, prosody too
    torch.manual_seed(1)
    c4, _, _, _ = augment(*batch, {**OFF, "aug_feature_masks": 1, "aug_feature_mask_width": 3})
    zero_cols = (c4 == 0).all(1)  # (B, C): whole bands over the window
    assert zero_cols.any() and zero_cols.sum(1).max() <= 3
    assert torch.equal(c4[~(c4 == 0)], content[~(c4 == 0)])


def test_noise_is_seeded_and_of_the_asked_size():
    batch = _batch(b=8, t=200)
    torch.manual_seed(5)
    a = augment(*batch, {**OFF, "aug_noise": 0.3})[0]
    torch.manual_seed(5)
    b = augment(*batch, {**OFF, "aug_noise": 0.3})[0]
    assert torch.equal(a, b)
    assert float((a - batch[0]).std()) == pytest.approx(0.3, rel=0.05)


def test_mixup_blends_inputs_and_targets_with_one_weight():
    content, prosody, target, mask = _batch(b=6)
    torch.manual_seed(2)
    c2, p2, t2, m2 = augment(content, prosody, target, mask, {**OFF, "aug_mixup": 0.4})
    for i in range(6):
        found = False
        for j in range(6):
            # content = lam c_i + (1 - lam) c_j for one lam in [0.5, 1], the same for prosody and target
            d = (content[i] - content[j]).flatten()
            if i == j:
                found |= torch.allclose(c2[i], content[i]) and torch.allclose(t2[i], target[i])
                continue
            lam = float(((c2[i] - content[j]).flatten() @ d) / (d @ d))
            if 0.5 - 1e-5 <= lam <= 1 + 1e-5 and torch.allclose(
                c2[i], lam * content[i] + (1 - lam) * content[j], atol=1e-5
            ):
                assert torch.allclose(p2[i], lam * prosody[i] + (1 - lam) * prosody[j], atol=1e-5)
                assert torch.allclose(t2[i], lam * target[i] + (1 - lam) * target[j], atol=1e-5)
                assert torch.equal(m2[i], mask[i] & mask[j])
                found = True
        assert found, i
    assert not torch.allclose(t2, target)


def test_raw_loss_weights_measure_the_error_in_coefficient_units():
    scale = [0.5, 0.125, 0.01]
    manifest = {"normalization": {"animation": {"scale": scale}}}
    assert channel_weights(manifest, {"loss_weights": "normalised"}) is None
    w = channel_weights(manifest, {"loss_weights": "raw"})
    assert float(w.mean()) == pytest.approx(1.0)
    g = torch.Generator().manual_seed(0)
    pred, true = torch.randn(2, 10, 3, generator=g), torch.randn(2, 10, 3, generator=g)
    mask = torch.ones(2, 10, dtype=torch.bool)
    mask[0, 7:] = False
    s = torch.tensor(scale)
    raw = (((pred - true) * s) ** 2)[mask].mean()  # squared error of de-normalised values
    mean_sq = float((s**2).mean())
    assert float(masked_mse(pred, true, mask, w)) == pytest.approx(float(raw) / mean_sq, rel=1e-5)
    assert float(masked_mse(pred, true, mask)) == pytest.approx(float(((pred - true) ** 2)[mask].mean()))


@pytest.mark.parametrize(
    "sets, needle",
    [
        (["aug_noise=-1"], "aug_noise must be a non-negative number"),
        (["aug_time_masks=1.5"], "aug_time_masks must be a non-negative integer"),
        (["aug_mask_prosody=2"], "aug_mask_prosody must be true or false"),
        (["loss_weights='metric'"], "loss_weights must be normalised or raw"),
    ],
)
def test_new_config_keys_are_checked(sets, needle):
    with pytest.raises(InputError, match=needle):
        resolve_config(None, sets)
