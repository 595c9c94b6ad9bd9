"""``ShardDataset`` as trainers use it: DDP ranks with DataLoader workers started by spawn (the rank
reaches the worker), ranks yielding equal numbers of samples for a loop with a collective per step,
``len()`` as the rank's share, shard order shuffled per epoch (reproducibly, for exact resumes), and
integer-like arguments. Real small datasets: 11 training samples in shards of 3, 3, 3 and 2, and the
same samples in shards of 4, 4 and 3 (``uneven``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import run_gloo_ranks
from dataset_helpers import make_aligned_take

from capture import write_take
from capture.errors import InputError
from dataset import read_manifest
from dataset.build import BuildOptions, build_dataset
from dataset.splits import SplitRule
from dataset.torch_dataset import ShardDataset
from train.data import TakeSubset, endless_batches


@pytest.fixture(scope="module")
def ds(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("ranks")
    for i, seconds in enumerate([2.0, 1.6, 0.8, 1.0, 1.0]):
        write_take(make_aligned_take(f"take{i:02d}", seconds, subject=f"spk{i % 2}", seed=i), root / "takes")
    options = BuildOptions(
        features=("pitch", "energy", "fbank"),
        split=SplitRule("take", 0.1, 0.1, 0, ("take03",), ("take04",)),
        max_sample_s=0.4,
        shard_bytes=100_000,
    )
    build_dataset([root / "takes"], root / "ds", options, say=lambda _m: None)
    m = read_manifest(root / "ds")
    assert [s["samples"] for s in m["shards"] if s["split"] == "train"] == [3, 3, 3, 2]
    return root / "ds"


@pytest.fixture(scope="module")
def uneven(ds) -> Path:
    """The same takes in shards of 4, 4 and 3 training samples: with 2 ranks of 5 samples each, rank 0's
    run is 4 + 1 samples of the first two shards, rank 1's 3 + 2 of the last two."""
    options = BuildOptions(
        features=("pitch", "energy", "fbank"),
        split=SplitRule("take", 0.1, 0.1, 0, ("take03",), ("take04",)),
        max_sample_s=0.4,
        shard_bytes=120_000,
    )
    build_dataset([ds.parent / "takes"], ds.parent / "uneven", options, say=lambda _m: None)
    m = read_manifest(ds.parent / "uneven")
    assert [s["samples"] for s in m["shards"] if s["split"] == "train"] == [4, 4, 3]
    return ds.parent / "uneven"


def _train_keys(ds: Path) -> list[str]:
    return sorted(s["key"] for s in read_manifest(ds)["samples"] if s["split"] == "train")


def _keys(data, workers: int = 0, context: str | None = None) -> list[str]:
    loader = torch.utils.data.DataLoader(
        data, batch_size=None, num_workers=workers, multiprocessing_context=context if workers else None
    )
    return [item["key"] for item in loader]


# ------------------------------------------------------------------------------ 1. ranks in workers


def test_given_ranks_reach_spawned_dataloader_workers(ds):
    """Workers started by spawn have no process group: the rank travels with the pickled dataset."""
    parts = []
    for rank in (0, 1):
        data = ShardDataset(ds, "train", window=12, rank=rank, world_size=2)
        keys = _keys(data, workers=2, context="spawn")
        assert len(keys) == len(data) == len(set(keys))
        parts.append(keys)
    assert not set(parts[0]) & set(parts[1])
    assert sorted(parts[0] + parts[1]) == _train_keys(ds)


DDP_SCRIPT = """
import json, sys
import torch, torch.distributed as dist
from torch.utils.data import ChainDataset, DataLoader
from dataset.torch_dataset import ShardDataset

rank, rendezvous, ds, uneven = int(sys.argv[1]), sys.argv[2], sys.argv[3], sys.argv[4]
early = ShardDataset(ds, "train", window=12)  # made before the process group: resolved when pickled
dist.init_process_group("gloo", init_method="file://" + rendezvous, rank=rank, world_size=2)
late = ShardDataset(ds, "train", window=13)  # its items' length tells them from early's
# both read by one pair of spawned workers (each worker's start-up is an interpreter's and PyTorch's)
both = ChainDataset([early, late])
loader = DataLoader(both, batch_size=None, num_workers=2, multiprocessing_context="spawn")
out = {"early": [], "late": [], "early_len": len(early), "late_len": len(late)}
for item in loader:
    out["early" if len(item["anim"]) == 12 else "late"].append(item["key"])
print(json.dumps(out), flush=True)
out = {}
# an ordinary epoch loop with a collective per step (as DDP's backward): every rank takes as many steps,
# on shards of 4, 4 and 3 where workers given whole shards made 3 batches of 3 on one rank, 2 on the other
even = ShardDataset(uneven, "train", window=12, shuffle_buffer=4, even_ranks=True)
loader = DataLoader(
    even, batch_size=3, num_workers=2, multiprocessing_context="spawn", persistent_workers=True
)
out["epochs"] = []
for epoch in range(2):
    even.set_epoch(epoch)
    keys, steps = [], 0
    for batch in loader:
        total = torch.tensor([float(len(batch["key"]))])
        dist.all_reduce(total)
        keys += batch["key"]
        steps += 1
    out["epochs"].append({"keys": keys, "steps": steps, "len": len(even), "batches": len(loader)})
dist.barrier()
print(json.dumps(out))
dist.destroy_process_group()
"""


def test_ddp_ranks_with_spawned_workers_read_their_share_and_step_together(ds, uneven, tmp_path):
    args = [str(tmp_path / "rendezvous"), str(ds), str(uneven)]
    lines = run_gloo_ranks(DDP_SCRIPT, args)
    shares = [json.loads(found[0]) for found in lines]
    everything = _train_keys(ds)
    for name in ("early", "late"):
        a, b = (r[name] for r in shares)
        assert a and b and not set(a) & set(b), name  # not the whole split on every rank
        assert sorted(a + b) == everything, name
        assert [r[name + "_len"] for r in shares] == [len(a), len(b)]  # len(): the rank's share
    results = [json.loads(found[-1]) for found in lines]
    for epoch in range(2):
        a, b = (r["epochs"][epoch] for r in results)
        # 11 samples: 5 per rank, one dropped; each rank's 2 workers read 3 and 2 of them: 2 batches
        assert a["steps"] == b["steps"] == a["batches"] == b["batches"] == 2
        assert len(a["keys"]) == len(b["keys"]) == a["len"] == b["len"] == 5
        assert not set(a["keys"]) & set(b["keys"]) and len(set(a["keys"] + b["keys"])) == 10
    assert results[0]["epochs"][0]["keys"] != results[0]["epochs"][1]["keys"]


# ------------------------------------------------------------------------------ 2. equal shares


@pytest.mark.parametrize("world", [2, 3])
def test_len_is_the_ranks_share_and_even_ranks_yield_equal_numbers(ds, world):
    everything = _train_keys(ds)
    for epoch in range(3):
        uneven, even = [], []
        for rank in range(world):
            for out, flag in ((uneven, False), (even, True)):
                data = ShardDataset(
                    ds, "train", window=12, shuffle_buffer=4, rank=rank, world_size=world, even_ranks=flag
                )
                data.set_epoch(epoch)
                keys = _keys(data)
                assert len(keys) == len(data) == len(set(keys))
                assert sorted(_keys(data, workers=2)) == sorted(keys)  # a rank's share, whatever its workers
                out.append(keys)
        assert sorted(sum(uneven, [])) == everything  # whole shards: every sample once, unequal shares
        assert len({len(k) for k in uneven}) > 1
        assert [len(k) for k in even] == [len(everything) // world] * world  # the remainder dropped
        assert len(set(sum(even, []))) == len(everything) // world * world


def _batch_sizes(data, batch_size: int, workers: int) -> list[int]:
    loader = torch.utils.data.DataLoader(data, batch_size=batch_size, num_workers=workers)
    return [len(batch["key"]) for batch in loader]


def test_even_ranks_take_as_many_batches_with_dataloader_workers(uneven):
    """Each DataLoader worker makes its own batches (its last one partial): the workers split a rank's
    run by position, so the batch count does not depend on where shard boundaries fall in it. Split by
    whole shards, rank 0's workers read 4 and 1 samples (batches of 3: 2 + 1), rank 1's 3 and 2 (1 + 1),
    and a loop with a collective per step hung."""
    for shuffle, epochs in ((0, 1), (4, 4)):  # storage order, then shards shuffled per epoch
        for epoch in range(epochs):
            for batch_size in (2, 3):
                sizes = []
                for rank in (0, 1):
                    data = ShardDataset(
                        uneven,
                        "train",
                        window=12,
                        shuffle_buffer=shuffle,
                        rank=rank,
                        world_size=2,
                        even_ranks=True,
                    )
                    data.set_epoch(epoch)
                    sizes.append(_batch_sizes(data, batch_size, workers=2))
                    assert sum(sizes[-1]) == len(data) == 5
                # 3 and 2 samples per worker on both ranks
                assert sorted(sizes[0]) == sorted(sizes[1]), (shuffle, epoch, batch_size, sizes)


def test_even_ranks_of_a_take_subset(ds):
    """A run's training takes chosen by val_takes (TakeSubset): equal shares of the kept samples only."""
    m = read_manifest(ds)
    keys = {s["key"] for s in m["samples"] if s["take"] in ("take00", "take02", "take03")}  # 5 + 2 + 3
    parts = []
    for rank in (0, 1):
        data = TakeSubset(ds, ("train", "val"), keys, window=12, shuffle_buffer=4, rank=rank, world_size=2)
        even = TakeSubset(
            ds, ("train", "val"), keys, window=12, shuffle_buffer=4, rank=rank, world_size=2, even_ranks=True
        )
        got, got_even = _keys(data), _keys(even)
        assert len(got) == len(data) and len(got_even) == len(even) == 5
        assert set(got) <= keys and set(got_even) <= keys
        parts.append((got, got_even))
    assert sorted(parts[0][0] + parts[1][0]) == sorted(keys)
    assert sorted(parts[0][1] + parts[1][1]) == sorted(keys)


# ------------------------------------------------------------------------------ 3. shard order


def test_shard_order_is_shuffled_per_epoch_reproducibly_and_stays_disjoint(ds):
    shard_of = {s["key"]: s["shard"] for s in read_manifest(ds)["samples"]}
    everything = _train_keys(ds)
    data = ShardDataset(ds, "train", window=12, shuffle_buffer=2, seed=5)
    firsts = set()
    for epoch in range(8):
        data.set_epoch(epoch)
        keys = _keys(data)
        assert sorted(keys) == everything
        firsts.add(shard_of[keys[0]])
    assert len(firsts) > 1  # an epoch does not always start at the first shard
    assert len({tuple(data.shard_order(epoch)) for epoch in range(8)}) > 1
    for epoch in range(3):  # every rank and worker reads its part of the same order: disjoint, complete
        split = []
        for rank in (0, 1):
            part = ShardDataset(ds, "train", window=12, shuffle_buffer=2, seed=5, rank=rank, world_size=2)
            part.set_epoch(epoch)
            split += _keys(part, workers=2)
        assert sorted(split) == everything
    # no shuffling: the manifest's order, every epoch
    plain = ShardDataset(ds, "train", window=12)
    assert {tuple(plain.shard_order(e)) for e in range(4)} == {tuple(plain.shards)}


def test_resumed_epoch_sees_the_same_batches(ds):
    """train/fit.py resumes at (epoch, batch) with endless_batches: the order depends on seed and epoch
    only, so a fresh dataset skipping the batches already seen continues exactly."""

    def batches(epoch, skip, n):
        data = ShardDataset(ds, "train", window=12, shuffle_buffer=4, seed=3)
        it = endless_batches(data, 2, epoch=epoch, skip=skip, seed=3)
        out = []
        for _ in range(n):
            e, i, b = next(it)
            out.append((e, i, tuple(b["key"]), b["anim"].numpy().tobytes()))
        return out

    whole = batches(0, 0, 14)  # 6 batches an epoch: into the third epoch
    assert whole[8:] == batches(1, 2, 6)
    assert whole[0][2] != whole[6][2]


# ------------------------------------------------------------------------------ 4. arguments


def test_integer_like_window_and_one_feature_name(ds):
    item = next(iter(ShardDataset(ds, "train", window=np.int64(12), features="fbank")))
    assert item["anim"].shape[0] == 12 and item["fbank"].shape == (12, 40)
    assert not {"pitch", "energy"} & set(item)
    assert len(ShardDataset(ds, "train", window=torch.tensor(8), rank=np.int64(1), world_size=np.int32(2)))
    for kw, needle in [
        ({"window": 2.5}, "window must be a positive"),
        ({"window": True}, "window must be a positive"),
        ({"features": "mfcc"}, "'mfcc' not in this dataset"),
        ({"features": ["fbank", 3]}, "features must be a list of feature names"),
        ({"features": 3}, "features must be a list of feature names"),
        ({"rank": 1}, "rank and world_size go together"),
        ({"rank": 2, "world_size": 2}, "rank must be below world_size"),
        ({"rank": 0, "world_size": 0}, "world_size must be a positive"),
    ]:
        with pytest.raises(InputError, match=needle):
            ShardDataset(ds, "train", **kw)
