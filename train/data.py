"""Model inputs from a dataset: which features feed content and prosody, and batches of tensors.

Content is the PPG when the dataset has one (``input = "auto"`` or ``"ppg"``), else log-mel filter banks
(``fbank``) or MFCC (``mfcc``); prosody is pitch (per-speaker z-scored log-F0, voicing flag) and
energy, followed by the speaker's style vector with ``speaker_style`` (train/style.py). Everything is
at the animation frame rate; targets are normalised animation channels.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import DataLoader

from capture.errors import InputError
from dataset.manifest import (
    read_manifest,
    take_recordings,
    takes_by_recording,
)
from dataset.normalize import FeatureNormalizer
from dataset.torch_dataset import ShardDataset

from .style import MEAN, style_rows

PROSODY_FEATURES = ("pitch", "energy")


@dataclass(frozen=True)
class InputSpec:
    """Features feeding the model: ``content`` (a feature name) of ``content_dim`` dims, and the
    ``prosody`` features (empty for the no-prosody ablation) and one column per speaker of ``styles``
    (empty without ``speaker_style``) concatenated into ``prosody_dim`` dims."""

    content: str
    content_dim: int
    prosody: tuple[str, ...]
    prosody_dim: int
    out_dim: int
    note: str | None = None
    styles: tuple[str, ...] = ()

    @property
    def features(self) -> list[str]:
        return [self.content, *self.prosody]

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> InputSpec:
        return cls(**{**d, "prosody": tuple(d["prosody"]), "styles": tuple(d.get("styles", ()))})


def resolve_inputs(manifest: dict[str, Any], cfg: dict[str, Any], where: str = "manifest.json") -> InputSpec:
    """The input choice of ``cfg`` (``input``, ``prosody``, ``speaker_style``) checked against the
    dataset's features; the styles are the speakers of the training samples (``val_takes`` and
    ``drop_takes`` applied)."""
    dims = manifest["features"]["dims"]
    want, note = cfg["input"], None
    if want == "auto":
        for name in ("ppg", "fbank", "mfcc"):
            if name in dims:
                want = name
                break
        else:
            raise InputError("dataset has none of ppg, fbank, mfcc for the content input", where)
        if want != "ppg":
            note = f"dataset has no PPG: content input falls back to {want}"
    if want not in dims:
        raise InputError(
            f"input={want!r} but the dataset has no {want} feature (it has {', '.join(dims)}); "
            f"rebuild it with --features ...,{want} or choose another input",
            where,
        )
    prosody: tuple[str, ...] = ()
    if cfg["prosody"]:
        missing = [p for p in PROSODY_FEATURES if p not in dims]
        if missing:
            raise InputError(
                f"prosody=true needs features {missing} that the dataset lacks (or use --set prosody=false)",
                where,
            )
        prosody = PROSODY_FEATURES
    styles = training_speakers(manifest, cfg, where) if cfg.get("speaker_style") else ()
    dim = sum(int(dims[p]) for p in prosody) + len(styles)
    return InputSpec(want, int(dims[want]), prosody, dim, len(manifest["channels"]), note, styles)


def training_speakers(manifest: dict[str, Any], cfg: dict[str, Any], where: str) -> tuple[str, ...]:
    """The speakers of the samples that train under ``cfg`` (sorted)."""
    keys = split_keys(manifest, cfg)
    trains = (lambda s: s["key"] in keys[0]) if keys is not None else (lambda s: s["split"] == "train")
    speakers = sorted({str(s.get("speaker") or "") for s in manifest["samples"] if trains(s)})
    if not speakers:
        raise InputError("speaker_style: no training samples to take speakers from", where)
    if MEAN in speakers:
        raise InputError(
            f"speaker_style: a training speaker is named {MEAN!r}, the name --style keeps for the mean "
            "style: rename it (meta.subject) and rebuild",
            where,
        )
    return tuple(speakers)


def to_model_inputs(
    item: dict[str, Any], spec: InputSpec, style: str | None = None, style_dropout: float = 0.0
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """(content, prosody) tensors from a (batched) ShardDataset item; prosody None when not used. With
    styles, each row's speaker style follows the features (``style``: a speaker or ``"mean"`` for every
    row instead of the item's own ``speaker``; ``style_dropout``: see train/style.py)."""
    content = item[spec.content]
    parts = [item[p] for p in spec.prosody]
    if spec.styles:
        speakers = item.get("speaker", "")
        speakers = [speakers] * content.shape[0] if isinstance(speakers, str) else list(speakers)
        rows = style_rows(speakers, spec.styles, style, style_dropout).to(content)
        parts.append(rows.unsqueeze(1).expand(-1, content.shape[1], -1))
    prosody = torch.cat(parts, dim=-1) if parts else None
    return content, prosody


def present_frames(item: dict[str, Any]) -> torch.Tensor:
    """The (batched) item's frames that exist (the reader's ``present``: False on padding only), what a
    model takes as its ``mask``; an item without it (made by other code) falls back to its ``mask``.
    The loss and the metrics take ``item["mask"]`` (usable frames) instead."""
    present = item.get("present")
    return item["mask"] if present is None else present


def target_values(item: dict[str, Any]) -> torch.Tensor:
    """The targets a loss scores of a (batched) item: its ``values`` (B, T, channels), the usable values
    (a reader's with ``values=True``: a glitch in one channel leaves the frame's others); an item
    without them falls back to its ``mask`` (B, T), the frames usable in every channel."""
    values = item.get("values")
    return item["mask"] if values is None else values


class TakeSubset(ShardDataset):
    """The samples of ``keys`` (sample keys) read from the shards of ``splits``; otherwise a
    ShardDataset (``random_crop`` as given, default: crop at random)."""

    # every reader scans all the shards and takes every n-th kept sample: dividing the shards instead
    # could leave a DDP rank with few of the kept takes (with even_ranks: an equal run of them each)
    divide_shards = False

    def __init__(self, ds: str | Path, splits: tuple[str, ...], keys: set[str], **kwargs: Any):
        kwargs.setdefault("random_crop", True)  # manifest=...: as ShardDataset
        super().__init__(ds, splits[0], **kwargs)
        self.shards = [sh["name"] for sh in self.manifest["shards"] if sh["split"] in splits]
        self.keys = set(keys)

    def _keep(self, key: str) -> bool:
        return key in self.keys


def split_keys(manifest: dict[str, Any], cfg: dict[str, Any], where: str = "config:val_takes"):
    """(training sample keys, validation sample keys) when ``cfg["val_takes"]`` or ``cfg["drop_takes"]``
    name takes: the val_takes' samples validate, every other train- or val-split sample trains (with no
    val_takes, the dataset's own train and val splits), and the drop_takes' samples do neither; None
    with neither set (the dataset's own splits). A name may be a take or the recording align cut takes
    from; either way every take of that recording goes (segments of one recording never end up on both
    sides). Test takes and unknown takes are errors."""
    named_val = list(cfg.get("val_takes") or [])
    named_dropped = list(cfg.get("drop_takes") or [])
    if not named_val and not named_dropped:
        return None
    split_of = {s["take"]: s["split"] for s in manifest["samples"]}
    recording_of, members = take_recordings(manifest), takes_by_recording(manifest)
    chosen: dict[str, set[str]] = {}
    for key, named in (("val_takes", named_val), ("drop_takes", named_dropped)):
        chosen[key] = set()
        for name in named:  # a take brings the other segments of its recording along
            takes_of = {t for t in members.get(recording_of.get(name, name), ()) if t in split_of}
            if not takes_of:
                raise InputError(
                    f"{key}: no take {name!r} in the dataset (it has {sorted(split_of)})", f"config:{key}"
                )
            for take in sorted(takes_of):
                if split_of[take] not in ("train", "val"):
                    raise InputError(
                        f"{key}: take {take!r} is in the {split_of[take]} split", f"config:{key}"
                    )
            chosen[key] |= takes_of
    takes, dropped = chosen["val_takes"], chosen["drop_takes"]
    if dropped & set(takes):
        raise InputError(f"takes both validate and are dropped: {sorted(dropped & set(takes))}", "config")
    usable = [s for s in manifest["samples"] if s["split"] in ("train", "val") and s["take"] not in dropped]
    if takes:
        val = {s["key"] for s in usable if s["take"] in takes}
        train = {s["key"] for s in usable if s["take"] not in takes}
    else:
        val = {s["key"] for s in usable if s["split"] == "val"}
        train = {s["key"] for s in usable if s["split"] == "train"}
    if not train:
        raise InputError("val_takes and drop_takes leave no training take", where)
    return train, val


def train_dataset(
    ds: str | Path,
    spec: InputSpec,
    cfg: dict[str, Any],
    manifest: dict[str, Any] | None = None,
    shuffle_shards: bool | None = None,
) -> ShardDataset:
    """The training samples of ``cfg`` (``manifest``: the dataset's as the run read it; default: read).
    ``shuffle_shards``: as ``ShardDataset``'s (default: shuffled per epoch when ``shuffle_buffer`` > 1;
    False: storage order, that of runs checkpointed before shards were shuffled)."""
    manifest = read_manifest(ds) if manifest is None else manifest
    kwargs = dict(
        window=cfg["window"],
        features=spec.features,
        shuffle_buffer=cfg["shuffle_buffer"],
        seed=cfg["seed"],
        manifest=manifest,
        shuffle_shards=shuffle_shards,
        values=True,  # the loss's targets: each usable value (a glitch in one channel leaves the others)
    )
    keys = split_keys(manifest, cfg)
    if keys is None:
        return ShardDataset(ds, "train", **kwargs)
    return TakeSubset(ds, ("train", "val"), keys[0], **kwargs)


def endless_batches(
    data: ShardDataset,
    batch_size: int,
    epoch: int = 0,
    skip: int = 0,
    seed: int = 0,
    check: Callable[[], None] | None = None,
) -> Iterator[tuple[int, int, dict[str, Any]]]:
    """(epoch, batch index within the epoch, batch) forever, starting at ``epoch`` after ``skip`` batches
    of it: the data position a checkpoint records, so that a resumed run sees the same batches. The
    loader gets its own generator so that starting an epoch leaves the global torch RNG alone.
    ``check`` runs before every epoch (``DatasetWatch.check``: the dataset is the build the run began
    on; one process only: under DDP each rank would check alone, at a step of its own, and a rank
    stopping alone leaves the others waiting at their next collective)."""
    while True:
        if check is not None:
            check()
        data.set_epoch(epoch)
        loader = DataLoader(
            data, batch_size=batch_size, num_workers=0, generator=torch.Generator().manual_seed(seed + epoch)
        )
        n = 0
        for i, batch in enumerate(loader):
            n += 1
            if i < skip:
                continue
            yield epoch, i, batch
        if n == 0:
            raise InputError(
                "the training split yields no samples for this process", data.ds / "manifest.json"
            )
        epoch, skip = epoch + 1, 0


def utterances(
    ds: str | Path,
    split: str,
    spec: InputSpec | None = None,
    cfg: dict[str, Any] | None = None,
    manifest: dict[str, Any] | None = None,
    values: bool = False,
    whole: bool = False,
) -> Iterator[dict[str, Any]]:
    """Whole samples of a split, one at a time, with a batch dimension of 1 (normalised). With a
    ``cfg`` that sets ``val_takes`` or ``drop_takes``, "train" and "val" mean its training and
    validation takes. ``manifest``: the dataset's as the caller read it (a run: the build it started
    on, never a newer one read here); default: read here. ``values``: as ``ShardDataset``'s (each
    item's usable values, a loss's targets). ``whole``: every sample of the split, on every rank
    (default: this rank's share under DDP)."""
    manifest = read_manifest(ds) if manifest is None else manifest
    features = spec.features if spec is not None else None
    read = {"window": None, "features": features, "manifest": manifest, "values": values}
    if whole:
        read.update(rank=0, world_size=1)
    keys = split_keys(manifest, cfg) if cfg is not None and split in ("train", "val") else None
    if keys is not None:
        chosen = keys[0] if split == "train" else keys[1]
        reader: ShardDataset = TakeSubset(ds, ("train", "val"), chosen, **read)
    elif split not in {s["split"] for s in manifest["shards"]}:
        raise InputError(f"dataset has no {split!r} split", Path(ds) / "manifest.json")
    else:
        reader = ShardDataset(ds, split, **read)
    for item in reader:
        yield {k: (v.unsqueeze(0) if isinstance(v, torch.Tensor) else v) for k, v in item.items()}


def normalize_features(
    manifest: dict[str, Any], feats: dict[str, np.ndarray], speaker: str | None = None
) -> dict[str, np.ndarray]:
    """The reader's feature normalisation (dataset.normalize.FeatureNormalizer, as ShardDataset applies
    it) for features computed outside a dataset. Pitch of a speaker the dataset does not know is
    z-scored with the utterance's own voiced log-F0."""
    normalizer = FeatureNormalizer(manifest["normalization"])
    return {
        name: normalizer.apply(name, x, speaker, unknown_speaker="utterance").astype(np.float32)
        for name, x in feats.items()
    }
