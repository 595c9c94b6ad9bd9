"""Per-channel usable frames: a take whose head angles glitch (a value past ±10, a NaN) while its
pronunciation channels are fine. The build keeps which channels are usable in which frames
(``channel_mask.npy``, written only for samples with such frames), ``ShardDataset(channels=...)`` and
``s2a-train eval`` use the frames usable in the run's channels, and ``s2a-dataset validate`` checks the
member. Before, a pronunciation32 run scored on an ``all`` dataset left those frames out."""

from __future__ import annotations

import hashlib
import io
import json
import tarfile
from pathlib import Path

import numpy as np
import pytest
from conftest import run_cli
from dataset_helpers import make_aligned_take
from test_train_pipeline import TINY

from capture import ARKIT61, write_take
from capture.channels import PRONUNCIATION32
from capture.errors import InputError
from dataset import BuildOptions, build_dataset
from dataset.shards import ShardReader, npy_bytes
from dataset.splits import SplitRule
from dataset.torch_dataset import ShardDataset
from train.cli import main

SETS = [a for s in TINY for a in ("--set", s)]
GLITCH_TAKE = "t2"  # the test split's take
YAW_FRAMES = range(30, 46)  # HeadYaw jumps to 40 (degrees in a weight channel: a tracker glitch)
PITCH_NAN = 70  # HeadPitch NaN
GAP = (90, 95)  # a lost face: every channel unusable


def _build(takes: Path, out: Path, channels: str) -> Path:
    options = BuildOptions(
        channels=channels,
        features=("pitch", "energy", "fbank"),
        split=SplitRule("take", 0.1, 0.1, 0, ("t1",), (GLITCH_TAKE,)),
    )
    build_dataset([takes], out, options, say=lambda _m: None)
    return out


@pytest.fixture(scope="module")
def glitched(tmp_path_factory):
    """Four ARKit61 takes (2 s at 60 fps); the test take's head angles glitch in 17 frames and its face
    is lost in 5; datasets of ``all`` channels and of pronunciation32, and a tiny pronunciation32 run."""
    root = tmp_path_factory.mktemp("channelmask")
    for i in range(4):
        take = make_aligned_take(f"t{i}", 2.0, subject="a", seed=i, channels=ARKIT61)
        if take.meta.id == GLITCH_TAKE:
            take.values[list(YAW_FRAMES), ARKIT61.index("headYaw")] = 40.0
            take.values[PITCH_NAN, ARKIT61.index("headPitch")] = np.nan
            take.frame_status[GAP[0] : GAP[1]] = 1
            take.values[GAP[0] : GAP[1]] = np.nan
        write_take(take, root / "takes")
    wide = _build(root / "takes", root / "all", "all")
    own = _build(root / "takes", root / "p32", "pronunciation32")
    args = ["fit", "--data", own, "--model", "s2a", "-o", root / "run", "--max-steps", 2, *SETS]
    assert main([str(a) for a in args]) == 0
    return {"root": root, "all": wide, "p32": own, "run": root / "run"}


def _members(ds: Path) -> dict[str, dict[str, bytes]]:
    """Every sample's members, by key."""
    manifest = json.loads((ds / "manifest.json").read_text())
    return {key: m for s in manifest["shards"] for key, m in ShardReader(ds / s["name"])}


def _usable(channels: list[str], frames: int) -> np.ndarray:
    """Which channels of the glitched take are usable in which frames."""
    usable = np.ones((frames, len(channels)), bool)
    usable[list(YAW_FRAMES), channels.index("headYaw")] = False
    usable[PITCH_NAN, channels.index("headPitch")] = False
    usable[GAP[0] : GAP[1]] = False
    return usable


def _npy(data: bytes) -> np.ndarray:
    return np.load(io.BytesIO(data), allow_pickle=False)


def test_the_build_keeps_which_channels_are_usable_where_they_differ(glitched):
    samples = _members(glitched["all"])
    with_member = sorted(k for k, m in samples.items() if "channel_mask.npy" in m)
    assert with_member == [k for k in sorted(samples) if k.startswith(GLITCH_TAKE + "_")], with_member
    members = samples[with_member[0]]
    channels = json.loads((glitched["all"] / "manifest.json").read_text())["channels"]
    usable, mask, anim = (_npy(members[m]) for m in ("channel_mask.npy", "mask.npy", "anim.npy"))
    assert usable.dtype == np.bool_ and usable.shape == (mask.size, len(channels))
    assert np.array_equal(usable.all(axis=1), mask)  # mask.npy: usable in every channel, as before
    assert np.array_equal(usable, _usable(channels, mask.size))
    yaw, pitch = channels.index("headYaw"), channels.index("headPitch")
    # the frames usable in some channels keep those values; unusable values are 0
    jaw = channels.index("jawOpen")
    assert anim[YAW_FRAMES[0], jaw] > 0 and anim[YAW_FRAMES[0], yaw] == 0 and anim[PITCH_NAN, pitch] == 0
    # a lost face alone (all channels at once) writes no member: the pronunciation32 dataset has none
    assert not any("channel_mask.npy" in m for m in _members(glitched["p32"]).values())


def test_the_reader_masks_frames_by_the_channels_asked_for(glitched):
    ds = glitched["all"]
    everything = {i["key"]: i for i in ShardDataset(ds, "test", window=None, features="energy")}
    picked = ShardDataset(ds, "test", window=None, features="energy", channels=list(PRONUNCIATION32))
    items = list(picked)
    assert [i["key"] for i in items] == list(everything) == [f"{GLITCH_TAKE}_c000"]
    for item in items:
        whole = everything[item["key"]]  # default: usable in every channel, mask.npy as before
        assert int(whole["mask"].sum()) == 120 - len(YAW_FRAMES) - 1 - (GAP[1] - GAP[0])
        assert int(item["mask"].sum()) == 120 - (GAP[1] - GAP[0])
    with pytest.raises(InputError, match="'jawopen' not in this dataset"):
        ShardDataset(ds, "test", channels=["jawopen"])


def test_eval_scores_the_frames_usable_in_the_runs_channels(glitched):
    frames = {}
    for name in ("p32", "all"):
        proc = run_cli(
            "train", "eval", glitched["run"], "--data", glitched[name], "--split", "test", "--json"
        )
        assert proc.returncode == 0, proc.stderr
        frames[name] = json.loads(proc.stdout)["frames"]
    # the head-angle glitch is in channels the run lacks: its frames are scored (were 98 of 115)
    assert frames == {"p32": 115, "all": 115}, frames


def _copy_with(ds: Path, out: Path, key: str, member: str, data: bytes) -> Path:
    """A copy of dataset ``ds`` whose sample ``key`` has ``member`` replaced (the manifest's shard size
    and sha256 updated, as if the build had written it)."""
    out.mkdir()
    manifest = json.loads((ds / "manifest.json").read_text())
    for shard in manifest["shards"]:
        entries = list(ShardReader(ds / shard["name"]))
        buf = io.BytesIO()
        with tarfile.open(fileobj=buf, mode="w", format=tarfile.USTAR_FORMAT) as tar:
            for k, members in entries:
                if k == key:
                    members[member] = data
                for ext in sorted(members):
                    info = tarfile.TarInfo(f"{k}.{ext}")
                    info.size = len(members[ext])
                    tar.addfile(info, io.BytesIO(members[ext]))
        (out / shard["name"]).write_bytes(buf.getvalue())
        shard["bytes"] = len(buf.getvalue())
        shard["sha256"] = hashlib.sha256(buf.getvalue()).hexdigest()
    (out / "manifest.json").write_text(json.dumps(manifest))
    return out


def test_validate_checks_the_channel_mask(glitched, tmp_path):
    ds = glitched["all"]
    proc = run_cli("dataset", "validate", ds, "--deep", "--json")  # statistics from mask.npy's frames
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert json.loads(proc.stdout)["problems"] == []  # the member is known: no "unexpected member" warning
    key = f"{GLITCH_TAKE}_c000"
    channels = json.loads((ds / "manifest.json").read_text())["channels"]
    usable = _usable(channels, 120)
    for name, damaged, needle in (
        ("dtype", usable.astype(np.uint8), "channel_mask is uint8"),
        ("shape", usable[:, :-1], f"expected bool of shape ({usable.shape[0]}, {usable.shape[1]})"),
        ("mask", np.logical_not(usable), "usable in every channel here but not in mask.npy"),
    ):
        copy = _copy_with(ds, tmp_path / name, key, "channel_mask.npy", npy_bytes(damaged))
        proc = run_cli("dataset", "validate", copy, "--json")
        assert proc.returncode == 1, proc.stdout + proc.stderr
        problems = json.loads(proc.stdout)["problems"]
        assert [p["code"] for p in problems] == ["channel_mask"], problems
        assert needle in problems[0]["message"] and problems[0]["location"].endswith(
            f"{key}.channel_mask.npy"
        )
        # the reader refuses it too, naming the sample: never a mask out of step with the animation
        with pytest.raises(InputError, match=f"sample {key}: channel_mask.npy"):
            list(ShardDataset(copy, "test", window=None, features="energy"))
