"""Training-time augmentation of the model inputs, for small datasets (minutes of speech).

Applied to a batch of normalised inputs (features z-scored by the reader, so 0 is the mean frame)
after the reader's random window crop, on the training batches only:

- ``aug_noise``: Gaussian noise of this standard deviation added to the content features;
- ``aug_time_masks`` × up to ``aug_time_mask_width`` frames: SpecAugment time masks, spans of frames
  whose content features are set to 0 (the mean), per window; with ``aug_mask_prosody`` the spans
  also blank pitch and energy;
- ``aug_feature_masks`` × up to ``aug_feature_mask_width`` dims: SpecAugment feature masks, bands of
  content dimensions set to 0 for the whole window;
- ``aug_mixup``: mixup (Zhang et al. 2018) with a Beta(a, a) weight per window: a window's inputs and
  targets are blended with those of another window of the batch, frame by frame; the flags are
  combined (a frame is a target when it is usable in both, and a model input when it is present in
  both: a frame blended with padding is neither).

Both flags travel through: ``mask`` (usable frames, the loss's) stays inside ``present`` (the sample's
frames, the model's input), whatever the augmentation.

Random numbers come from the global torch generator, which the checkpoint saves, so a resumed run
draws the same masks as an uninterrupted one. Targets are untouched except by mixup.
"""

from __future__ import annotations

from typing import Any

import torch


def enabled(cfg: dict[str, Any]) -> bool:
    return bool(
        cfg["aug_noise"] > 0
        or (cfg["aug_time_masks"] and cfg["aug_time_mask_width"])
        or (cfg["aug_feature_masks"] and cfg["aug_feature_mask_width"])
        or cfg["aug_mixup"] > 0
    )


def _span_mask(n_masks: int, max_width: int, batch: int, length: int) -> torch.Tensor:
    """(batch, length) bool, True inside ``n_masks`` spans per row, each of a width drawn uniformly
    from 0..max_width at a uniform start (SpecAugment's masking)."""
    out = torch.zeros(batch, length, dtype=torch.bool)
    if n_masks <= 0 or max_width <= 0 or length == 0:
        return out
    width = torch.randint(0, min(max_width, length) + 1, (batch, n_masks))
    start = (torch.rand(batch, n_masks) * (length - width + 1).float()).long()
    pos = torch.arange(length).view(1, 1, length)
    inside = (pos >= start.unsqueeze(-1)) & (pos < (start + width).unsqueeze(-1))
    return inside.any(dim=1)


def augment(
    content: torch.Tensor,
    prosody: torch.Tensor | None,
    target: torch.Tensor,
    mask: torch.Tensor,
    cfg: dict[str, Any],
) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor, torch.Tensor]:
    """Augmented (content, prosody, target, mask) of a batch with one flag for both uses (``mask``
    (B, T) bool); ``augment_frames`` keeps the reader's two apart."""
    content, prosody, target, mask, _ = augment_frames(content, prosody, target, mask, mask, cfg)
    return content, prosody, target, mask


def augment_frames(
    content: torch.Tensor,
    prosody: torch.Tensor | None,
    target: torch.Tensor,
    mask: torch.Tensor,
    present: torch.Tensor,
    cfg: dict[str, Any],
) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Augmented (content, prosody, target, mask, present) of one training batch: content (B, T, C),
    prosody (B, T, P) or None, target (B, T, channels), ``mask`` (B, T) bool (usable frames: the
    loss's) or (B, T, channels) bool (usable values), ``present`` (B, T) bool (the frames that are not
    padding: the model's). Inputs are not modified in place."""
    b, t, c = content.shape
    mask = mask & (present if mask.dim() == 2 else present.unsqueeze(-1))  # a target is always an input frame
    if cfg["aug_noise"] > 0:
        content = content + cfg["aug_noise"] * torch.randn(content.shape).to(content)
    if cfg["aug_time_masks"] and cfg["aug_time_mask_width"]:
        spans = _span_mask(cfg["aug_time_masks"], cfg["aug_time_mask_width"], b, t).to(content.device)
        keep = (~spans).unsqueeze(-1).to(content.dtype)
        content = content * keep
        if prosody is not None and cfg["aug_mask_prosody"]:
            prosody = prosody * keep.to(prosody.dtype)
    if cfg["aug_feature_masks"] and cfg["aug_feature_mask_width"]:
        bands = _span_mask(cfg["aug_feature_masks"], cfg["aug_feature_mask_width"], b, c).to(content.device)
        content = content * (~bands).unsqueeze(1).to(content.dtype)
    if cfg["aug_mixup"] > 0 and b > 1:
        lam = torch.distributions.Beta(cfg["aug_mixup"], cfg["aug_mixup"]).sample((b,))
        lam = torch.maximum(lam, 1 - lam).to(content)  # the window keeps the larger share
        perm = torch.randperm(b).to(content.device)
        w = lam.view(b, 1, 1)
        content = w * content + (1 - w) * content[perm]
        if prosody is not None:
            prosody = w.to(prosody) * prosody + (1 - w.to(prosody)) * prosody[perm]
        target = w.to(target) * target + (1 - w.to(target)) * target[perm]
        mask = mask & mask[perm]  # a mixed target value is usable in both windows
        present = present & present[perm]
    return content, prosody, target, mask, present
