"""``ShardDataset``: a PyTorch ``IterableDataset`` over a split's shards.

Shards are divided among DDP ranks (``torch.distributed``, when initialised) and DataLoader workers
(``get_worker_info``): shard ``i`` goes to consumer ``i % consumers``; with fewer shards than consumers,
every consumer reads every shard and keeps every ``consumers``-th sample instead. Samples pass through
a shuffle buffer (seeded by seed, epoch and consumer), are normalised with the manifest's statistics,
and are cropped or padded to ``window`` frames with a mask (padding frames are masked out).

Each sample is checked as it is decoded (cheaply: on the arrays already in memory), since the readers
compare only a shard's size with the manifest, not its sha256: its members are there, its json is an
object with a usable ``neutral`` and ``speaker``, the animation is (frames, channels) float, the mask
(frames,) bool and each feature (frames, dim) float, with the manifest's frames, channels and dims, and
every value is finite (the build writes 0, never NaN, at masked frames). A damaged sample is an
``InputError`` naming the shard and the sample key.
"""

from __future__ import annotations

import json
import random
import tarfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import IterableDataset, get_worker_info

from capture.errors import InputError

from .manifest import _numbers, dataset_dir, read_manifest, shards_of
from .normalize import FeatureNormalizer, Normalizer
from .shards import ShardReader, decode_flac, decode_npy, split_key
from .splits import SPLITS


def _rank_world() -> tuple[int, int]:
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        return torch.distributed.get_rank(), torch.distributed.get_world_size()
    return 0, 1


class ShardDataset(IterableDataset):
    """Samples of one split as dicts of tensors.

    ``window``: frames per item (crop at a random start in training, pad with a zero mask when short);
    None yields whole samples. ``features``: which features to load (default: all in the manifest).
    Each item: ``anim`` (window, channels) float32 (normalised when ``normalize``), ``mask`` (window,)
    bool, one (window, dim) float32 tensor per feature (pitch: per-speaker z-scored log-F0 and voicing;
    others z-scored), optionally ``audio`` (samples,) float32 at 16 kHz, ``key`` and ``speaker`` (the
    sample's, "" if none). ``manifest``: the dataset's manifest as the caller read it (default: read
    here).
    """

    def __init__(
        self,
        ds: str | Path,
        split: str = "train",
        window: int | None = None,
        features: list[str] | None = None,
        shuffle_buffer: int = 0,
        seed: int = 0,
        normalize: bool = True,
        audio: bool = False,
        random_crop: bool | None = None,
        manifest: dict[str, Any] | None = None,
    ):
        super().__init__()
        self.ds = dataset_dir(ds)
        # a caller that read the manifest already (a training run: the build it started on) passes it
        self.manifest = read_manifest(self.ds) if manifest is None else manifest
        if split not in SPLITS:
            raise InputError(f"split must be one of {', '.join(SPLITS)}, not {split!r}", self.ds)
        if window is not None and (isinstance(window, bool) or not isinstance(window, int) or window < 1):
            raise InputError(f"window must be a positive number of frames or None, not {window!r}", self.ds)
        names = list(self.manifest["features"]["names"])
        unknown = [f for f in features or () if f not in names]
        if unknown:
            raise InputError(
                f"feature(s) {', '.join(map(repr, unknown))} not in this dataset (it has "
                f"{', '.join(names) or 'none'})",
                self.ds,
            )
        self.split = split
        self.shards = [s["name"] for s in shards_of(self.manifest, split)]
        self.check_shards()
        self.listed: dict[str, set[str]] = {}  # sample keys by shard, as the manifest lists them
        self.frames: dict[str, int] = {}  # frames of each sample, as the manifest lists them
        self.shard_of: dict[str, str] = {}
        for sample in self.manifest["samples"]:
            self.listed.setdefault(sample["shard"], set()).add(sample["key"])
            self.frames[sample["key"]] = sample["frames"]
            self.shard_of[sample["key"]] = sample["shard"]
        self.window = window
        self.features = list(features) if features is not None else names
        self.shuffle_buffer = shuffle_buffer
        self.seed = seed
        # the epoch in shared memory: DataLoader workers (persistent ones too, forked or spawned) hold
        # copies of this object but read the one value, at the start of each pass
        self._epoch = torch.zeros(1, dtype=torch.int64).share_memory_()
        self.normalize = normalize
        self.audio = audio
        self.random_crop = (split == "train") if random_crop is None else random_crop
        norm = self.manifest["normalization"]
        self.normalizer = Normalizer.from_json(norm["animation"])
        self.feature_normalizer = FeatureNormalizer(norm)

    def check_shards(self) -> None:
        """Each shard to read is there with the manifest's size (a stat per shard): a shard copied from
        another build, truncated or missing is an error, never silently other samples."""
        check_shard_files(self.ds, self.manifest, self.shards)

    def _read(self, name: str) -> Iterator[tuple[str, dict[str, bytes]]]:
        """The samples of shard ``name``; a key the manifest does not list for it, or a listed key it
        lacks, is an error."""
        path = self.ds / name
        listed = set(self.listed.get(name, ()))
        for key, members in ShardReader(path):
            if key not in listed:
                raise _unlisted(self.ds, path, {key})
            listed.discard(key)
            yield key, members
        if listed:
            raise _lacking(self.ds, path, listed)

    @property
    def epoch(self) -> int:
        return int(self._epoch[0])

    @epoch.setter
    def epoch(self, epoch: int) -> None:
        self._epoch[0] = int(epoch)

    def set_epoch(self, epoch: int) -> None:
        """Reshuffle differently in each epoch (call before iterating the DataLoader; its workers,
        persistent or not, see the new epoch)."""
        self.epoch = epoch

    def __len__(self) -> int:
        return sum(s["samples"] for s in shards_of(self.manifest, self.split))

    def _consumer(self) -> tuple[int, int]:
        """(this reader's index, number of readers) over DDP ranks × DataLoader workers."""
        rank, world = _rank_world()
        info = get_worker_info()
        wid, nworkers = (info.id, info.num_workers) if info is not None else (0, 1)
        return rank * nworkers + wid, world * nworkers

    def _assignment(self) -> tuple[list[str], int, int]:
        consumer, consumers = self._consumer()
        if len(self.shards) >= consumers:
            return self.shards[consumer::consumers], 0, 1
        return self.shards, consumer, consumers

    def _samples(self) -> Iterator[tuple[str, dict[str, bytes]]]:
        shards, offset, stride = self._assignment()
        i = 0
        for name in shards:
            for key, members in self._read(name):
                if i % stride == offset:
                    yield key, members
                i += 1

    def damaged(self, key: str, what: str) -> InputError:
        """The error for sample ``key`` whose contents are not what the manifest promises."""
        shard = self.shard_of.get(key)
        return InputError(
            f"sample {key}: {what} (a damaged shard? s2a-dataset validate {self.ds})",
            self.ds / shard if shard is not None else self.ds,
        )

    def check_sample(
        self, key: str, members: dict[str, bytes]
    ) -> tuple[dict[str, Any], np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """(metadata, animation, mask, {feature: array}) of a sample, checked (see the module doc): a
        shard damaged without changing its size is an error here, never NaN losses, crashes deep in
        training or silently wrong scores."""
        need = ["json", "anim.npy", "mask.npy", *(f"{name}.npy" for name in self.features)]
        missing = [m for m in need + (["flac"] if self.audio else []) if m not in members]
        if missing:
            raise self.damaged(key, f"lacks the member(s) {', '.join(missing)}")
        try:
            meta = json.loads(members["json"])
        except (ValueError, RecursionError):  # JSONDecodeError and UnicodeDecodeError are ValueErrors
            raise self.damaged(key, "its json member is not valid JSON") from None
        if not isinstance(meta, dict):
            raise self.damaged(key, "its json member is not a JSON object")
        n_channels = len(self.manifest["channels"])
        neutral = meta.get("neutral")
        if neutral is not None and not (_numbers(neutral) and len(neutral) == n_channels):
            raise self.damaged(key, f"its json's neutral is not null or {n_channels} finite numbers")
        if meta.get("speaker") is not None and not isinstance(meta["speaker"], str):
            raise self.damaged(key, "its json's speaker is not a string")
        frames = self.frames.get(key)
        dims = self.manifest["features"]["dims"]
        arrays = {}
        for name, shape in (
            ("anim", (frames, n_channels)),
            ("mask", (frames,)),
            *((name, (frames, dims[name])) for name in self.features),
        ):
            x = self._array(key, members, name)
            kind = "b" if name == "mask" else "f"
            if x.dtype.kind != kind or x.shape != shape:
                want = "bool" if kind == "b" else "float"
                raise self.damaged(
                    key,
                    f"{name}.npy is {x.dtype} of shape {_shape(x.shape)}, "
                    f"expected {want} of shape {_shape(shape)}",
                )
            if kind == "f" and not np.isfinite(x).all():
                bad = ~np.isfinite(x)
                raise self.damaged(
                    key,
                    f"{name}.npy holds {int(bad.sum())} NaN or infinite value(s) "
                    f"(first at frame {int(np.argwhere(bad)[0][0])})",
                )
            arrays[name] = x
        anim, mask = arrays.pop("anim"), arrays.pop("mask")
        return meta, anim, mask, arrays

    def _array(self, key: str, members: dict[str, bytes], name: str) -> np.ndarray:
        try:
            return decode_npy(members[f"{name}.npy"], f"{name}.npy")
        except InputError as exc:
            raise self.damaged(key, str(exc)) from None

    def _decode(self, key: str, members: dict[str, bytes], rng: random.Random) -> dict[str, Any]:
        meta, anim, mask, feats = self.check_sample(key, members)
        if self.normalize:
            neutral = np.asarray(meta["neutral"], np.float32) if meta.get("neutral") is not None else None
            anim = self.normalizer.forward(anim, neutral, dtype=np.float32) * mask[:, None]
        item: dict[str, Any] = {"key": key, "anim": anim.astype(np.float32), "mask": mask}
        item["speaker"] = str(meta.get("speaker") or "")
        for name in self.features:
            x = feats[name].astype(np.float32)
            if self.normalize:
                x = self.feature_normalizer.apply(name, x, meta.get("speaker"))
            item[name] = x
        n = anim.shape[0]
        start = 0
        if self.window is not None:
            w = self.window
            if n > w:
                start = rng.randrange(n - w + 1) if self.random_crop else 0
            for k in ("anim", "mask", *self.features):
                v = item[k][start : start + w]
                if v.shape[0] < w:
                    pad = np.zeros((w - v.shape[0], *v.shape[1:]), v.dtype)
                    v = np.concatenate([v, pad])
                item[k] = v
        if self.audio:
            try:
                x, rate = decode_flac(members["flac"])
            except InputError as exc:
                raise self.damaged(key, str(exc)) from None
            if self.window is not None:
                fps = self.manifest["fps"]  # every sample's (s2a-dataset validate checks)
                s0 = int(round(start * rate / fps))
                n_s = int(round(self.window * rate / fps))
                x = np.pad(x[s0 : s0 + n_s], (0, max(0, n_s - x[s0 : s0 + n_s].shape[0])))
            item["audio"] = x.astype(np.float32)
        return {
            k: (torch.from_numpy(np.ascontiguousarray(v)) if isinstance(v, np.ndarray) else v)
            for k, v in item.items()
        }

    def __iter__(self) -> Iterator[dict[str, Any]]:
        rank, _ = _rank_world()
        info = get_worker_info()
        wid = info.id if info is not None else 0
        epoch = self.epoch  # read once per pass: set_epoch of the main process, even in a worker
        rng = random.Random(f"{self.seed}:{epoch}:{rank}:{wid}")
        buffer: list[tuple[str, dict[str, bytes]]] = []
        self.check_shards()  # again: a subclass may read other shards, and files change between epochs
        for sample in self._samples():
            if self.shuffle_buffer <= 1:
                yield self._decode(*sample, rng)
                continue
            buffer.append(sample)
            if len(buffer) >= self.shuffle_buffer:
                j = rng.randrange(len(buffer))
                buffer[j], buffer[-1] = buffer[-1], buffer[j]
                yield self._decode(*buffer.pop(), rng)
        rng.shuffle(buffer)
        for sample in buffer:
            yield self._decode(*sample, rng)


def check_shard_files(ds: Path, manifest: dict[str, Any], names: list[str]) -> None:
    """Each of the shards ``names`` is there with the manifest's size (a stat per shard)."""
    size = {s["name"]: s["bytes"] for s in manifest["shards"]}
    for name in names:
        path = ds / name
        if not path.is_file():
            raise InputError(f"shard listed in the manifest is missing: s2a-dataset validate {ds}", path)
        if path.stat().st_size != size[name]:
            raise InputError(f"shard size differs from the manifest: s2a-dataset validate {ds}", path)


def check_shards(ds: Path, manifest: dict[str, Any], splits: tuple[str, ...]) -> None:
    """The shards of ``splits`` are there with the manifest's size and hold the samples it lists for
    them, from their tar headers alone (the members' data are skipped): what the reader would find at
    the first batch or validation, found before a run writes anything."""
    names = [s["name"] for split in splits for s in shards_of(manifest, split)]
    check_shard_files(ds, manifest, names)
    listed: dict[str, set[str]] = {}
    for sample in manifest["samples"]:
        listed.setdefault(sample["shard"], set()).add(sample["key"])
    for name in names:
        path = ds / name
        try:
            with tarfile.open(path, mode="r:") as tar:
                found = {split_key(member.name)[0] for member in tar if member.isfile()}
        except (tarfile.TarError, EOFError, OSError) as exc:
            raise InputError(
                f"shard is not a readable tar ({exc}): s2a-dataset validate {ds}", path
            ) from None
        wanted = listed.get(name, set())
        if found - wanted:
            raise _unlisted(ds, path, found - wanted)
        if wanted - found:
            raise _lacking(ds, path, wanted - found)


def _unlisted(ds: Path, path: Path, keys: set[str]) -> InputError:
    return InputError(
        f"sample {min(keys)} is not listed in the manifest for this shard: s2a-dataset validate {ds}", path
    )


def _lacking(ds: Path, path: Path, keys: set[str]) -> InputError:
    return InputError(
        f"shard lacks {len(keys)} sample(s) the manifest lists ({min(keys)}): s2a-dataset validate {ds}", path
    )


def _shape(shape: tuple[Any, ...]) -> str:
    return "(" + ", ".join(map(str, shape)) + ")"
