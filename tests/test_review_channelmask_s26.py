"""Review of the per-channel masks (``channel_mask.npy``, ``ShardDataset(channels=...)``): a reader asked
for no channel at all, and the normalised animation of a frame usable in the channels asked for but not in
others. Five ARKit61 takes (2 s at 60 fps, 1 s samples); the test take's face is lost in some frames and
its head yaw glitches (a value past ±10) in others."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from dataset_helpers import build_take_split, make_aligned_take

from capture import ARKIT61, write_take
from capture.channels import PRONUNCIATION32
from capture.errors import InputError
from dataset.torch_dataset import ShardDataset

GAP = (10, 20)  # face lost: no channel usable
YAW_GLITCH = range(30, 34)  # headYaw at 40: every other channel usable


@pytest.fixture(scope="module")
def glitched(tmp_path_factory):
    root = tmp_path_factory.mktemp("review_channelmask")
    for i in range(5):
        take = make_aligned_take(f"take{i:02d}", 2.0, subject=f"spk{i % 2}", seed=i, channels=ARKIT61)
        if i == 4:  # the test split's
            take.frame_status[GAP[0] : GAP[1]] = 1
            take.values[GAP[0] : GAP[1]] = np.nan
            take.values[list(YAW_GLITCH), ARKIT61.index("headYaw")] = 40.0
        write_take(take, root / "takes" / take.meta.id)
    return build_take_split(root / "takes", root / "ds", channels="all")


def test_a_reader_asked_for_no_channel_is_refused(glitched):
    """No channel to be usable in would make every frame a target, lost faces included (it did, in the
    samples with a channel_mask.npy, while the others kept mask.npy's)."""
    with pytest.raises(InputError, match="channels must name at least one channel"):
        ShardDataset(glitched, "test", window=None, features="energy", channels=[])


def test_values_outside_the_channels_asked_for_are_zero_where_unusable(glitched):
    whole = {i["key"]: i for i in ShardDataset(glitched, "test", window=None, features="energy")}
    picked = ShardDataset(
        glitched, "test", window=None, features="energy", channels=list(reversed(PRONUNCIATION32))
    )
    first = "take04_c000"
    item = next(i for i in picked if i["key"] == first)
    channels = picked.manifest["channels"]
    yaw, jaw = channels.index("headYaw"), channels.index("jawOpen")
    glitch = list(YAW_GLITCH)
    assert item["mask"][glitch].all() and not whole[first]["mask"][glitch].any()
    assert not item["mask"][GAP[0] : GAP[1]].any()  # a lost face stays out, whatever the channels
    # the glitched value is 0 (the training mean, normalised); the usable ones are normalised as elsewhere
    assert (item["anim"][glitch, yaw] == 0).all()
    assert (item["anim"][glitch, jaw] != 0).all()
    usable = item["mask"] & whole[first]["mask"]
    assert torch.equal(item["anim"][usable], whole[first]["anim"][usable])
