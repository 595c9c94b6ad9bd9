"""``ShardDataset``: a PyTorch ``IterableDataset`` over a split's shards.

Each epoch's samples are the split's shards in an order shuffled by seed and epoch (when shuffling is
on), divided first among DDP ranks, then among each rank's DataLoader workers (``get_worker_info``).
By default a level divides whole shards (the ``i``-th shard holding samples goes to reader
``i % readers``; with fewer shards than readers, every reader reads them all and keeps every
``readers``-th sample); with ``even_ranks``, each rank takes an equal contiguous run of the epoch's
samples instead (the remainder, fewer samples than ranks, is dropped), so every rank yields as many,
and its workers split that run by position (consecutive parts whose sizes depend only on the run's
length and the number of workers), so every rank also makes as many batches.
The rank and world size come from ``torch.distributed`` in the process that makes or iterates the
dataset (or from ``rank``/``world_size``), and travel to DataLoader workers with the dataset: a
spawned worker, where ``torch.distributed`` is not initialised, still reads its rank's share. Samples
pass through a shuffle buffer (seeded by seed, epoch, rank and worker), are normalised with the
manifest's statistics, and are cropped or padded to ``window`` frames. Two per-frame flags come along:
``mask``, the frames whose animation is a target (usable: False on padding and on the frames the build
marked unusable, a lost face or bad values: with ``channels``, bad values in those channels only, where
a sample's ``channel_mask.npy`` says which channels are usable in which frames), for losses and
metrics; and ``present``, the frames of the sample (False on padding only), for a model's input, whose
audio features are real at unusable frames too (at inference every frame is real: a model fed ``mask``
would train on inputs it never sees). With ``values=True`` a per-value flag comes along too:
``values`` (window, channels), the usable values (a training loss's targets: a glitch in one channel
leaves the frame's others).

A shard read to its end is hashed as it streams by and compared with the manifest's sha256: one whose
bytes changed (a flipped bit in a finite value) is an ``InputError`` naming it, after its last sample
(``verify_sha256=False``: not hashed). A process hashes a shard once, while its file stays the same
(inode, size, modification and change times): a shard read in every epoch costs the hashing in the
first only. A reader that leaves a shard early (its end is another reader's) hashes nothing, and a
changed sample is read before the shard's end: so each sample is also checked as it is decoded
(cheaply: on the arrays already in memory): its members are there, its json is an object with a usable
``neutral`` and the manifest's ``speaker`` (whose statistics normalise its pitch), the animation is
(frames, channels) float, the mask (frames,) bool (a channel_mask, where there is one, (frames,
channels) bool whose frames usable in every channel are the mask's) and each feature (frames, dim)
float, with the manifest's frames, channels and dims, and every value is finite (the build writes 0,
never NaN, at unusable values: those of a masked frame, but for the channels a channel_mask keeps
usable in it). A damaged sample is an ``InputError`` naming the shard and the sample key.
"""

from __future__ import annotations

import operator
import random
import tarfile
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import IterableDataset, get_worker_info

from capture.errors import InputError, loads_names
from capture.numbers import is_count

from .manifest import _numbers, dataset_dir, read_manifest, shards_of
from .normalize import FeatureNormalizer, Normalizer
from .shards import CHANNEL_MASK, ShardReader, channel_mask_problem, decode_flac, decode_npy, split_key
from .splits import SPLITS

# The shards this process read to their end with the manifest's sha256, by path, sha256 and file identity
# (device, inode, size, modification and change times): one read in every epoch is hashed in the first
# only, and again once its file changes.
_HASHED: set[tuple[Any, ...]] = set()


def _file_identity(path: Path) -> tuple[int, ...]:
    """(device, inode, size, modification and change times in ns) of ``path``; () when it cannot be read
    (the reader says why). The change time, which no one can set, tells a file rewritten in place or
    replaced with its size and modification time kept (``cp -p``, ``touch -r``) from the one hashed."""
    try:
        st = path.stat()
    except OSError:
        return ()
    return st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns


def _distributed() -> tuple[int, int] | None:
    """(rank, world size) of this process's default process group; None when there is none (never in a
    DataLoader worker that was spawned or started by a fork server)."""
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        return torch.distributed.get_rank(), torch.distributed.get_world_size()
    return None


def _count(value: Any, what: str, where: Path, least: int | None, none: bool = False) -> int | None:
    """``value`` as an int of at least ``least`` (any integer-like number: int, numpy or torch integer);
    None only with ``none``. Anything else (a bool, a float, a string) is an ``InputError``."""
    if value is None and none:
        return None
    try:  # an int from any integer-like number; is_count then says whether it counts (never a bool)
        n = operator.index(value) if not isinstance(value, bool) else None
    except TypeError:
        n = None
    if n is None or (least is not None and not (is_count(n) and n >= least)):
        kind = {None: "an", 0: "a non-negative", 1: "a positive"}[least]
        raise InputError(f"{what} must be {kind} integer{' or None' if none else ''}, not {value!r}", where)
    return n


class ShardDataset(IterableDataset):
    """Samples of one split as dicts of tensors.

    ``window``: frames per item (crop at a random start in training, pad with frames False in both
    flags when short); None yields whole samples. ``features``: which features to load (a list of
    names, or one name; default: all in the manifest). Each item: ``anim`` (window, channels) float32
    (normalised when ``normalize``), ``mask`` (window,) bool, True on usable frames (the loss's and the
    metrics': False on padding and on unusable frames), ``present`` (window,) bool, True on the
    sample's frames (the model's input: False on padding only; ``mask`` implies it), one (window, dim)
    float32 tensor per feature (pitch: per-speaker z-scored log-F0 and voicing; others z-scored),
    optionally ``audio`` (samples,) float32 at 16 kHz, ``key`` and ``speaker`` (the sample's, "" if
    none). ``manifest``: the dataset's manifest as the caller read it (default: read here).
    ``channels``: the names of the dataset's channels that a frame must be usable in for ``mask``
    (default: all; a run scored on fewer channels than the dataset holds, from samples whose
    ``channel_mask.npy`` keeps a glitch in one channel out of the others). ``values``: each item also
    has ``values`` (window, channels) bool, True on the usable values (a training loss's targets: the
    sample's ``channel_mask.npy`` where it has one, else ``mask`` in every channel; False on padding).

    ``shuffle_buffer``: samples mixed at a time (0 or 1: none); ``shuffle_shards``: read the shards in
    an order shuffled by ``seed`` and the epoch (default: when ``shuffle_buffer`` > 1). ``rank`` and
    ``world_size``: this process's share of the data (default: ``torch.distributed``'s, when it is
    initialised where the dataset is made or iterated). ``even_ranks``: every rank yields the same
    number of samples per epoch (the epoch's samples divided into equal contiguous runs, the remainder
    dropped; a rank's DataLoader workers split its run by position, so with one ``batch_size`` every
    rank also makes as many batches), for a loop with a collective per step; default: ranks read whole
    shards, and may yield different numbers. ``verify_sha256``: compare each shard read to its end
    with the manifest's sha256 (default: on; see the module doc). An ``IterableDataset``: no random
    access (``__getitem__``); ``len()`` is this rank's number of samples in the current epoch.
    """

    # a level (ranks, a rank's workers) divides whole shards among its readers (else sample by sample)
    divide_shards = True

    def __init__(
        self,
        ds: str | Path,
        split: str = "train",
        window: int | None = None,
        features: list[str] | str | None = None,
        shuffle_buffer: int = 0,
        seed: int = 0,
        normalize: bool = True,
        audio: bool = False,
        random_crop: bool | None = None,
        manifest: dict[str, Any] | None = None,
        shuffle_shards: bool | None = None,
        rank: int | None = None,
        world_size: int | None = None,
        even_ranks: bool = False,
        verify_sha256: bool = True,
        channels: list[str] | None = None,
        values: bool = False,
    ):
        super().__init__()
        self.ds = dataset_dir(ds)
        # a caller that read the manifest already (a training run: the build it started on) passes it
        self.manifest = read_manifest(self.ds) if manifest is None else manifest
        if split not in SPLITS:
            raise InputError(f"split must be one of {', '.join(SPLITS)}, not {split!r}", self.ds)
        window = _count(window, "window", self.ds, 1, none=True)
        names = list(self.manifest["features"]["names"])
        if isinstance(features, str):  # one feature by name, never its letters
            features = [features]
        elif features is not None:
            given = features
            try:
                features = list(features)
            except TypeError:
                features = [None]
            if not all(isinstance(f, str) for f in features):
                raise InputError(f"features must be a list of feature names, not {given!r}", self.ds)
        unknown = [f for f in features or () if f not in names]
        if unknown:
            raise InputError(
                f"feature(s) {', '.join(map(repr, unknown))} not in this dataset (it has "
                f"{', '.join(names) or 'none'})",
                self.ds,
            )
        if (rank is None) != (world_size is None):
            raise InputError("rank and world_size go together: give both or neither", self.ds)
        self._given: tuple[int, int] | None = None  # the caller's rank and world size
        if world_size is not None:
            world = _count(world_size, "world_size", self.ds, 1)
            r = _count(rank, "rank", self.ds, 0)
            if r >= world:
                raise InputError(f"rank must be below world_size ({world}), not {rank!r}", self.ds)
            self._given = (r, world)
        # torch.distributed's, resolved where it is initialised (here, in __iter__, __len__ or when the
        # dataset is pickled for a DataLoader worker) and kept for workers where it is not
        self._ranks: tuple[int, int] | None = _distributed()
        self.split = split
        self.shards = [s["name"] for s in shards_of(self.manifest, split)]
        self.check_shards()
        self.listed: dict[str, set[str]] = {}  # sample keys by shard, as the manifest lists them
        self.sha256_of = {s["name"]: s["sha256"] for s in self.manifest["shards"]}
        self.frames: dict[str, int] = {}  # frames of each sample, as the manifest lists them
        self.shard_of: dict[str, str] = {}
        self.speaker_of: dict[str, str] = {}  # whose log-F0 statistics normalise each sample's pitch
        for sample in self.manifest["samples"]:
            self.listed.setdefault(sample["shard"], set()).add(sample["key"])
            self.frames[sample["key"]] = sample["frames"]
            self.shard_of[sample["key"]] = sample["shard"]
            self.speaker_of[sample["key"]] = sample["speaker"]
        self.window = window
        self.features = list(features) if features is not None else names
        self.shuffle_buffer = _count(shuffle_buffer, "shuffle_buffer", self.ds, 0)
        self.seed = _count(seed, "seed", self.ds, None)
        self.shuffle_shards = self.shuffle_buffer > 1 if shuffle_shards is None else bool(shuffle_shards)
        self.even_ranks = bool(even_ranks)
        self.verify_sha256 = bool(verify_sha256)
        # the epoch in shared memory: DataLoader workers (persistent ones too, forked or spawned) hold
        # copies of this object but read the one value, at the start of each pass
        self._epoch = torch.zeros(1, dtype=torch.int64).share_memory_()
        self.normalize = normalize
        self.audio = audio
        self.random_crop = (split == "train") if random_crop is None else random_crop
        self.columns = scored_columns(self.manifest["channels"], channels, self.ds)
        self.values = bool(values)
        norm = self.manifest["normalization"]
        self.normalizer = Normalizer.from_json(norm["animation"])
        self.feature_normalizer = FeatureNormalizer(norm)

    def rank_world(self) -> tuple[int, int]:
        """(rank, world size) this process reads for: the ones given, else ``torch.distributed``'s here
        (when initialised), else the ones resolved where the dataset was made or pickled, else (0, 1)."""
        if self._given is not None:
            return self._given
        here = _distributed()
        if here is not None:
            self._ranks = here
        return self._ranks or (0, 1)

    def __getstate__(self) -> dict[str, Any]:
        # pickled for a spawned (or fork-server) DataLoader worker: the rank travels along, resolved in
        # this process, where torch.distributed may be initialised (it never is in the worker)
        self.rank_world()
        return self.__dict__.copy()

    def check_shards(self) -> None:
        """Each shard to read is there with the manifest's size (a stat per shard): a shard copied from
        another build, truncated or missing is an error, never silently other samples."""
        check_shard_files(self.ds, self.manifest, self.shards)

    def members_read(self) -> list[str]:
        """The members of a sample this dataset decodes: the others are skipped unread (a shuffle buffer
        would otherwise hold every sample's audio, most of its bytes, also with ``audio=False``)."""
        members = ["json", "anim.npy", "mask.npy", *(f"{name}.npy" for name in self.features)]
        return [*members, CHANNEL_MASK, *(["flac"] if self.audio else [])]

    def _read(self, name: str) -> Iterator[tuple[str, dict[str, bytes]]]:
        """The samples of shard ``name``; a key the manifest does not list for it, or a listed key it
        lacks, is an error."""
        path = self.ds / name
        listed = set(self.listed.get(name, ()))
        sha256 = self.sha256_of[name] if self.verify_sha256 else None
        hashed = (str(path), sha256, *_file_identity(path))
        reader = ShardReader(path, self.members_read(), None if hashed in _HASHED else sha256)
        for key, members in reader:
            if key not in listed:
                raise _unlisted(self.ds, path, {key})
            listed.discard(key)
            yield key, members
        if listed:
            raise _lacking(self.ds, path, listed)
        if reader.digest is not None:  # read to its end, its sha256 the manifest's
            _HASHED.add(hashed)

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
        """Samples this process's rank yields in the current epoch (with its DataLoader workers
        together): the whole split with one process."""
        rank, world = self.rank_world()
        return int(self._rank_share(self.epoch, rank, world)[0].size)

    def _keep(self, key: str) -> bool:
        """Whether the sample ``key`` of the shards read is one of this dataset's (a subset: not all)."""
        return True

    def shard_order(self, epoch: int) -> list[str]:
        """The shards in the order epoch ``epoch`` reads them: shuffled by seed and epoch (the same in
        every rank and worker, and again when a run resumes) when ``shuffle_shards``."""
        order = list(self.shards)
        if self.shuffle_shards:
            random.Random(f"{self.seed}:{epoch}:shards").shuffle(order)
        return order

    def _rank_share(self, epoch: int, rank: int, world: int) -> tuple[np.ndarray, np.ndarray, list[str]]:
        """(the epoch's sample indices that ``rank`` of ``world`` reads, the first index of each shard
        and one past the last, the shards in the epoch's order). The epoch's samples are numbered in
        shard order, each shard's in the order it holds them (the ones ``_keep`` keeps)."""
        order = self.shard_order(epoch)
        counts = [sum(1 for key in self.listed.get(name, ()) if self._keep(key)) for name in order]
        starts = np.concatenate([[0], np.cumsum(counts, dtype=np.int64)])
        index = np.arange(starts[-1], dtype=np.int64)
        return self._divide(index, starts, rank, world, self.even_ranks), starts, order

    def _divide(
        self, index: np.ndarray, starts: np.ndarray, k: int, n: int, even: bool, by_position: bool = False
    ) -> np.ndarray:
        """Reader ``k``'s part of the sample indices ``index`` (ascending) among ``n`` readers: an equal
        contiguous run (``even``: ``len(index) // n`` each, the rest dropped; ``by_position``: the first
        ``len(index) % n`` runs one longer, nothing dropped), else whole shards when ``divide_shards``
        and there are at least ``n`` shards holding some, else every ``n``-th one."""
        if n == 1:
            return index
        if by_position:  # sizes from len(index) and n alone, wherever the shard boundaries fall
            return np.array_split(index, n)[k]
        if even:
            q = index.size // n
            return index[k * q : (k + 1) * q]
        if self.divide_shards:
            shard = np.searchsorted(starts, index, side="right") - 1
            held = np.unique(shard)
            if held.size >= n:
                return index[np.isin(shard, held[k::n])]
        return index[k::n]

    def _plan(self) -> tuple[int, int, int, list[tuple[str, np.ndarray, bool]]]:
        """(epoch, rank, worker, [(shard, positions among its kept samples to yield, whether to leave it
        after the last of them)]): what this reader (a rank's DataLoader worker, or the rank itself)
        reads this pass. A shard is left early only when other readers read its end: a reader of its
        end reads all of it, so the listed keys it lacks are found."""
        rank, world = self.rank_world()
        info = get_worker_info()
        wid, nworkers = (info.id, info.num_workers) if info is not None else (0, 1)
        epoch = self.epoch  # read once per pass: set_epoch of the main process, even in a worker
        index, starts, order = self._rank_share(epoch, rank, world)
        # even_ranks: the workers split the rank's run by position, so that each one's number of samples
        # (and of batches, its last one partial) is the same on every rank; whole shards would make a
        # rank's batch count depend on where the shard boundaries fall in its run
        index = self._divide(index, starts, wid, nworkers, even=False, by_position=self.even_ranks)
        shard = np.searchsorted(starts, index, side="right") - 1
        plan = []
        for i in np.unique(shard):
            positions = index[shard == i] - starts[i]
            plan.append((order[i], positions, bool(positions[-1] + 1 < starts[i + 1] - starts[i])))
        return epoch, rank, wid, plan

    def _samples(self, plan: list[tuple[str, np.ndarray, bool]]) -> Iterator[tuple[str, dict[str, bytes]]]:
        for name, positions, leave in plan:
            wanted = set(positions.tolist())
            last = int(positions[-1])
            kept = 0
            for key, members in self._read(name):
                if not self._keep(key):
                    continue
                if kept in wanted:
                    yield key, members
                kept += 1
                if leave and kept > last:  # the rest is other readers'
                    break

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
        missing = [m for m in self.members_read() if m not in members and m != CHANNEL_MASK]
        if missing:
            raise self.damaged(key, f"lacks the member(s) {', '.join(missing)}")
        try:
            meta = loads_names(members["json"])
        except (ValueError, RecursionError):  # JSONDecodeError and UnicodeDecodeError are ValueErrors
            raise self.damaged(key, "its json member is not valid JSON") from None
        if not isinstance(meta, dict):
            raise self.damaged(key, "its json member is not a JSON object")
        n_channels = len(self.manifest["channels"])
        neutral = meta.get("neutral")
        if neutral is not None and not (_numbers(neutral) and len(neutral) == n_channels):
            raise self.damaged(key, f"its json's neutral is not null or {n_channels} finite numbers")
        speaker = self.speaker_of.get(key)
        if meta.get("speaker") != speaker:  # its pitch would be raw log-F0, or another speaker's z-score
            raise self.damaged(
                key, f"its json's speaker {meta.get('speaker')!r:.40} is not the manifest's {speaker!r}"
            )
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
        if CHANNEL_MASK in members:
            arrays["channel_mask"] = self._channel_mask(key, members, mask)
            if not isinstance(self.columns, slice):  # all channels: the mask's frames, as just checked
                mask = arrays["channel_mask"][:, self.columns].all(axis=1)
        return meta, anim, mask, arrays

    def _channel_mask(self, key: str, members: dict[str, bytes], mask: np.ndarray) -> np.ndarray:
        """The sample's channel_mask.npy, checked (``channel_mask_problem``) against its ``mask``."""
        usable = self._array(key, members, "channel_mask")
        problem = channel_mask_problem(usable, mask, len(self.manifest["channels"]), CHANNEL_MASK)
        if problem is not None:
            raise self.damaged(key, problem)
        return usable

    def _array(self, key: str, members: dict[str, bytes], name: str) -> np.ndarray:
        try:
            return decode_npy(members[f"{name}.npy"], f"{name}.npy")
        except InputError as exc:
            raise self.damaged(key, str(exc)) from None

    def _decode(self, key: str, members: dict[str, bytes], rng: random.Random) -> dict[str, Any]:
        meta, anim, mask, feats = self.check_sample(key, members)
        channel_mask = feats.pop("channel_mask", None)
        # the usable values: a glitch in one channel leaves the frame's others (targets)
        usable = mask[:, None] if channel_mask is None else channel_mask
        if self.normalize:
            neutral = np.asarray(meta["neutral"], np.float32) if meta.get("neutral") is not None else None
            anim = self.normalizer.forward(anim, neutral, dtype=np.float32) * usable  # 0 at the unusable
        present = np.ones(mask.shape, bool)  # every frame of the sample; False only on padding below
        item: dict[str, Any] = {"key": key, "anim": anim.astype(np.float32), "mask": mask, "present": present}
        if self.values:
            # a broadcast view is read-only: a channel_mask is the sample's own (writable) array
            item["values"] = usable if channel_mask is not None else np.broadcast_to(usable, anim.shape)
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
            for k in ("anim", "mask", "present", *(["values"] if self.values else []), *self.features):
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
        epoch, rank, wid, plan = self._plan()
        rng = random.Random(f"{self.seed}:{epoch}:{rank}:{wid}")
        buffer: list[tuple[str, dict[str, bytes]]] = []
        self.check_shards()  # again: a subclass may read other shards, and files change between epochs
        for sample in self._samples(plan):
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


def scored_columns(names: list[str], channels: list[str] | None, ds: Path) -> list[int] | slice:
    """The columns of ``channels`` (channel names) among the dataset's ``names``: the channels whose
    usable frames make an item's ``mask`` (None: all of them). An unknown name, or none (every frame,
    a lost face's too, would be a target), is an ``InputError``."""
    if channels is None:
        return slice(None)
    if not isinstance(channels, (list, tuple)) or not all(isinstance(c, str) for c in channels):
        raise InputError(f"channels must be a list of channel names, not {channels!r:.80}", ds)
    if not channels:
        raise InputError("channels must name at least one channel (None: all of them)", ds)
    unknown = [c for c in channels if c not in names]
    if unknown:
        raise InputError(f"channel(s) {', '.join(map(repr, unknown[:5]))} not in this dataset", ds)
    return [names.index(c) for c in channels]


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
    them, each member once, from their tar headers alone (the members' data are skipped): what the
    reader would find at the first batch or validation, found before a run writes anything."""
    names = [s["name"] for split in splits for s in shards_of(manifest, split)]
    check_shard_files(ds, manifest, names)
    listed: dict[str, set[str]] = {}
    for sample in manifest["samples"]:
        listed.setdefault(sample["shard"], set()).add(sample["key"])
    for name in names:
        path = ds / name
        try:
            with tarfile.open(path, mode="r:") as tar:
                members = [member.name for member in tar if member.isfile()]
        except (tarfile.TarError, EOFError, OSError) as exc:
            raise InputError(
                f"shard is not a readable tar ({exc}): s2a-dataset validate {ds}", path
            ) from None
        twice = sorted(member for member, n in Counter(members).items() if n > 1)
        if twice:
            raise InputError(f"member {twice[0]} appears twice: s2a-dataset validate {ds}", path)
        found = {split_key(member)[0] for member in members}
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
