"""Evaluation on the paper's scale and real-time factor.

``rmse`` = root mean square error of DE-normalised coefficients (0..1 blendshape units) × 100, over the
usable frames of an utterance (the dataset's raw samples, normalised and de-normalised with the RUN's
statistics, so that a dataset built with other statistics gives the same numbers; the model reads
every frame, unusable ones included, as ``s2a-train predict`` does, and only the usable ones are
scored; usable in the run's channels: a glitch in a channel of the dataset's that the run lacks, which
its ``channel_mask.npy`` keeps apart, leaves a frame scored): ``entire`` over every channel of the run
(picked by name from the dataset's), ``crucial`` over jawOpen and mouthClose (paper Table 1). Reported
as mean ± std over utterances, plus per-channel RMSE pooled over all usable frames of the split. The
floor predicts every frame as the training split's per-channel mean (from the manifest). On a dataset
that stores frame phones (built with a PPG), ``per_phone_class`` gives the model's and the floor's RMSE
pooled over the frames of each articulatory class of phone, ``bilabial_closure`` the share of the
recorded lip closures on bilabials that each keeps and ``open_vowel_opening`` the share of the recorded
openings on open vowels (train/lipsync.py). ``rtf`` = seconds of model compute per second of animation,
on a ~12 s utterance, batch 1, no gradient (median of repeated runs).
"""

from __future__ import annotations

import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from capture.command import progress, warn
from capture.errors import InputError, first_few, loads_names
from dataset.manifest import dataset_folder, read_manifest
from dataset.normalize import Normalizer
from dataset.torch_dataset import ShardDataset

from .checkpoint import NOT_FINITE, checkpoint_path, load_for_inference
from .data import InputSpec, TakeSubset, normalize_features, split_keys, to_model_inputs
from .lipsync import LipSyncTally, aperture_columns
from .precision import infer
from .run_dataset import leaked_takes, recorded_takes
from .style import MEAN
from .systems import check_sample_frames, max_frames

PHONES = "phones.npy"
LIP_FIGURES = ("per_phone_class", "bilabial_closure", "open_vowel_opening")  # by phone (train/lipsync.py)
NO_PHONES = (
    "the dataset stores no frame phones (built without a phone-aware PPG, or before frame phones were "
    "stored: build it with --ppg pocketsphinx or bottleneck)"
)


def crucial_columns(channels: list[str]) -> list[int] | None:
    """Columns of jawOpen and mouthClose (paper Table 1; the lip aperture's ``JAW``), or None when the
    rig lacks either."""
    columns = aperture_columns(channels)
    return None if columns is None else columns[0]


class ErrorTally:
    """Per-utterance and per-channel squared errors (paper scale: values × 100)."""

    def __init__(self, channels: list[str]):
        self.channels = channels
        self.crucial = crucial_columns(channels)
        self.entire: list[float] = []
        self.crucial_rmse: list[float] = []
        self.se = np.zeros(len(channels))
        self.frames = 0

    def add(self, pred: np.ndarray, true: np.ndarray, mask: np.ndarray) -> None:
        """``pred``, ``true`` (frames, channels) de-normalised; ``mask`` (frames,) usable frames."""
        if not mask.any():
            return
        d = (np.asarray(pred, np.float64)[mask] - np.asarray(true, np.float64)[mask]) * 100.0
        self.entire.append(float(np.sqrt(np.mean(d**2))))
        if self.crucial is not None:
            self.crucial_rmse.append(float(np.sqrt(np.mean(d[:, self.crucial] ** 2))))
        self.se += (d**2).sum(0)
        self.frames += d.shape[0]

    def summary(self) -> dict[str, Any]:
        def ms(v):
            return {"mean": float(np.mean(v)), "std": float(np.std(v))} if v else None

        per_channel = np.sqrt(self.se / max(self.frames, 1))
        return {
            "rmse_entire": ms(self.entire),
            "rmse_crucial": ms(self.crucial_rmse),
            "rmse_pooled": float(np.sqrt(self.se.sum() / max(self.frames * len(self.channels), 1))),
            "per_channel": dict(zip(self.channels, per_channel.round(6).tolist())),
            "utterances": len(self.entire),
            "frames": self.frames,
        }


def device_name(device: torch.device) -> str:
    if device.type == "cuda":
        return torch.cuda.get_device_name(device)
    name = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                name = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"cpu ({name}, {torch.get_num_threads()} threads)"


@torch.inference_mode()
def real_time_factor(
    model,
    spec: InputSpec,
    item: dict[str, Any],
    fps: float,
    frames: int,
    style: str | None = None,
    repeats: int = 5,
) -> float:
    """Seconds of compute per second of animation for one utterance of ``frames`` frames (batch 1): the
    utterance ``item``'s inputs tiled or cut to that length."""
    n = int(frames)
    seconds = n / fps
    content, prosody = to_model_inputs(item, spec, style)
    reps = -(-n // content.shape[1])
    content = content.repeat(1, reps, 1)[:, :n]
    prosody = None if prosody is None else prosody.repeat(1, reps, 1)[:, :n]
    mask = torch.ones(1, n, dtype=torch.bool)
    infer(model, content, prosody, mask)  # warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        infer(model, content, prosody, mask)
        times.append(time.perf_counter() - t0)
    return float(np.median(times)) / seconds


class RawSamples(ShardDataset):
    """Un-normalised samples with their sample json's ``speaker`` and calibrated ``neutral`` (or None),
    and their frame ``phones`` (ids into ``manifest_phones``) when the dataset stores them (else None)."""

    def members_read(self) -> list[str]:
        return [*super().members_read(), *([PHONES] if manifest_phones(self.manifest) else [])]

    def _decode(self, key: str, members: dict[str, bytes], rng) -> dict[str, Any]:
        item = super()._decode(key, members, rng)
        meta = loads_names(members["json"])  # an object with a usable neutral: ShardDataset checked it
        neutral = meta.get("neutral")
        item["speaker"] = meta.get("speaker")
        item["neutral"] = None if neutral is None else np.asarray(neutral, np.float32)
        item["phones"] = self._phones(key, members, item["mask"].shape[0]) if PHONES in members else None
        return item

    def _phones(self, key: str, members: dict[str, bytes], frames: int) -> np.ndarray:
        phones = self._array(key, members, "phones")
        known = len(manifest_phones(self.manifest))
        if phones.dtype.kind not in "iu" or phones.shape != (frames,):
            raise self.damaged(
                key, f"phones.npy is {phones.dtype} of shape {phones.shape}, expected {frames} ids"
            )
        if phones.size and not (-1 <= phones.min() and phones.max() < known):
            raise self.damaged(key, f"phones.npy holds ids outside -1..{known - 1} (the manifest's phones)")
        return phones


def manifest_phones(manifest: dict[str, Any]) -> list[str] | None:
    """The phone names a dataset's ``phones.npy`` ids index (its PPG's: pocketsphinx's, or the
    bottleneck model's config), or None when its samples store no phones."""
    if PHONES not in (manifest.get("members") or []):
        return None
    ppg = manifest["features"].get("ppg")
    ppg = ppg if isinstance(ppg, dict) else {}
    config = ppg.get("config") if isinstance(ppg.get("config"), dict) else {}
    phones = ppg.get("phones", config.get("phones"))
    return phones if isinstance(phones, list) and phones and all(isinstance(p, str) for p in phones) else None


class RawTakeSubset(TakeSubset, RawSamples):
    """``RawSamples`` of chosen sample keys from the train and val shards (a run's own train or
    validation takes when it trained with ``val_takes`` or ``drop_takes``)."""


def run_split_keys(payload: dict[str, Any], manifest: dict[str, Any], split: str, where: Path):
    """The sample keys that ``split`` means for this run, or None for the dataset's own split. A run
    trained with ``val_takes`` or ``drop_takes`` validated on its own takes and trained on the others
    (the dataset's val split may have trained it): its "train" and "val" are those."""
    if split not in ("train", "val"):
        return None
    if "ensemble" in payload:  # every train/val take trained some member
        if split == "val":
            raise InputError(
                "a cross-validation ensemble trained on every train and val take (each member validates on "
                "its own fold; ensemble.json's cv_score): evaluate the test split, or one member's folder "
                "(RUN/fold-i) on its val split",
                where,
            )
        return None
    cfg = payload.get("config") or {}
    try:
        keys = split_keys(manifest, cfg)
    except InputError as exc:
        raise InputError(f"the run's val_takes/drop_takes do not fit this dataset ({exc})", where) from None
    if keys is None:
        return None
    chosen = keys[0] if split == "train" else keys[1]
    if not chosen:
        raise InputError(f"the run has no {split} takes (its drop_takes leave none)", where)
    return chosen


def run_channel_columns(channels: list[str], run_channels: list[str], where: Path) -> list[int]:
    """The dataset's columns (``channels``) of the run's channels, in the run's order: a dataset built
    with more channels than the run (arkit52 for a pronunciation32 run), or with the run's in another
    order, is scored on the run's. One that lacks any of the run's channels is refused, naming them."""
    column = {c: j for j, c in enumerate(channels)}
    missing = [c for c in run_channels if c not in column]
    if missing:
        raise InputError(
            f"dataset lacks {len(missing)} of the {len(run_channels)} channels the run was trained on "
            f"({first_few(missing)}): build it with the run's channels (s2a-dataset build --channels)",
            where,
        )
    return [column[c] for c in run_channels]


def check_dataset_fits_run(
    manifest: dict[str, Any], info: dict[str, Any], spec: InputSpec, where: Path
) -> list[int]:
    """Refuse a dataset whose frame rate or input features are not the run's, or that lacks some of the
    run's channels (``info``: the checkpoint's ``dataset``); returns the dataset's columns of the run's
    channels (``run_channel_columns``). Its normalisation may differ: evaluation uses the run's."""
    columns = run_channel_columns(manifest["channels"], info["channels"], where)
    if manifest["fps"] != info["fps"]:
        raise InputError(f"dataset is at {manifest['fps']:g} fps, the run at {info['fps']:g} fps", where)
    features = manifest.get("features")
    dims = features.get("dims") if isinstance(features, dict) else None
    if not isinstance(dims, dict):
        raise InputError("manifest lacks the features' dims", where)
    for name in spec.features:
        if name not in dims:
            raise InputError(f"dataset has no {name} feature, the run needs it", where)
        if dims[name] != info["features"].get("dims", {}).get(name):
            raise InputError(f"dataset's {name} has {dims[name]!r} dims, not the run's", where)
    if features.get("settings") != info["features"].get("settings"):
        raise InputError("dataset's feature settings differ from the run's: features would not match", where)
    if "ppg" in spec.features:
        ours, theirs = (_ppg_model(f) for f in (features, info["features"]))
        if ours != theirs:
            raise InputError(
                f"dataset's PPG comes from {_show_model(ours)}, the run's from {_show_model(theirs)}: "
                "features would not match (build the dataset with the run's --ppg-model)",
                where,
            )
    return columns


def _ppg_model(features: dict[str, Any]) -> tuple[Any, Any]:
    """The PPG backend and model checksum a dataset's features were computed with."""
    ppg = features.get("ppg") if isinstance(features.get("ppg"), dict) else {}
    return ppg.get("backend"), ppg.get("model_sha256")


def _show_model(model: tuple[Any, Any]) -> str:
    backend, sha = model
    return f"{backend} model sha256 {sha[:12]}..." if isinstance(sha, str) else f"{backend} (no model file)"


@torch.no_grad()
def evaluate(
    run: str | Path,
    ds: str | Path,
    split: str = "test",
    rtf_seconds: float = 12.0,
    say: Callable[[str], None] = progress,
    precision: str = "fp32",
    style: str | None = None,
) -> dict[str, Any]:
    """Metrics of a run on a dataset split (see module doc), computed at ``precision``
    (train/precision.py). A run with speaker styles animates each utterance in its own speaker's style
    (the mean style for a speaker it did not train on), or every utterance in ``style`` (a speaker of
    the run or ``"mean"``). Notes go to ``say``; a leak (``leaked_takes``) is also a warning on stderr
    (``warn``)."""
    model, payload, spec = load_for_inference(run, precision, style, say)
    info = payload["dataset"]
    ds = dataset_folder(ds)  # the folder or its manifest.json; another file is named, not taken for it
    manifest = read_manifest(ds)
    columns = check_dataset_fits_run(manifest, info, spec, ds / "manifest.json")
    channels = list(info["channels"])  # scored: the run's, picked from the dataset's by name
    picked = None if columns == list(range(len(manifest["channels"]))) else columns
    if picked is not None:
        say(
            f"note: the dataset holds {len(manifest['channels'])} channels, the run {len(channels)}"
            f"{' in another order' if len(columns) == len(manifest['channels']) else ''}: "
            "the run's channels are scored"
        )
    own_keys = run_split_keys(payload, manifest, split, ds / "manifest.json")
    if own_keys is None and split not in {s["split"] for s in manifest["shards"]}:
        raise InputError(f"dataset has no {split!r} split", ds / "manifest.json")
    model_config = payload.get("model_config") or {}
    check_sample_frames(manifest, (split,), model_config, ds / "manifest.json", own_keys)
    leaked = _leaks(payload, manifest, split, own_keys)
    try:
        train_mean = np.asarray(
            [manifest["stats"]["train"]["channels"][c]["mean"] for c in channels], np.float64
        )
    except (KeyError, TypeError, ValueError):
        raise InputError("manifest lacks the training split's channel means", ds / "manifest.json") from None
    # the run's normalisation, not the dataset's: the model only knows the statistics it trained with
    animation = Normalizer.from_json(info["normalization"]["animation"])
    run_norm = {"normalization": info["normalization"]}
    tally, floor = ErrorTally(channels), ErrorTally(channels)
    phones = manifest_phones(manifest)
    lipsync = None if phones is None else LipSyncTally(channels, phones, info["fps"])
    longest, own_style, seen = None, 0, 0
    # a frame is scored when usable in the run's channels (a glitch in one the run lacks leaves it in)
    read = {"window": None, "features": spec.features, "normalize": False, "channels": channels}
    if own_keys is None:
        samples = RawSamples(ds, split, **read)
    else:
        samples = RawTakeSubset(ds, ("train", "val"), own_keys, random_crop=False, **read)
    for item in samples:
        raw_feats = {f: item[f].numpy() for f in spec.features}
        feats = normalize_features(run_norm, raw_feats, item["speaker"])
        batch = {f: torch.from_numpy(x).unsqueeze(0) for f, x in feats.items()}
        batch["mask"] = item["mask"].unsqueeze(0)  # the frames scored
        batch["present"] = item["present"].unsqueeze(0)  # the frames the model sees: all of the sample
        batch["speaker"] = item["speaker"] or ""
        own_style += style is None and batch["speaker"] in spec.styles
        seen += 1
        content, prosody = to_model_inputs(batch, spec, style)
        mask = item["mask"].numpy()
        pred_norm = infer(model, content, prosody, batch["present"])[0].double().numpy()
        if not np.all(np.isfinite(pred_norm)):
            raise InputError(NOT_FINITE, checkpoint_path(run))
        true = item["anim"].numpy().astype(np.float64)
        neutral = item["neutral"]
        if picked is not None:
            true = true[:, picked]
            neutral = None if neutral is None else neutral[picked]
        pred = animation.inverse(pred_norm, neutral)
        tally.add(pred, true, mask)
        floor_pred = np.broadcast_to(train_mean, true.shape)
        floor.add(floor_pred, true, mask)
        if lipsync is not None:  # every sample has its phones (RawSamples reads them)
            lipsync.add(item["phones"], pred, floor_pred, true, mask)
        if longest is None or mask.shape[0] > longest["mask"].shape[1]:
            longest = batch
    if not tally.frames:
        raise InputError(
            f"the {split} split has no usable frames (face lost throughout?): nothing to score",
            ds / "manifest.json",
        )
    result = {
        "run": str(run),
        "dataset": str(ds),
        "split": split,
        "model": payload["system"],
        "step": payload["step"],
        "precision": precision,
    }
    if own_keys is not None:
        takes = sorted({s["take"] for s in manifest["samples"] if s["key"] in own_keys})
        result["split_source"] = "run"  # the dataset's split otherwise
        result["split_takes"] = takes
        cfg = payload.get("config") or {}
        given = "val_takes" if cfg.get("val_takes") else "drop_takes"
        result["split_note"] = (
            f"{split}: the run's own {'validation' if split == 'val' else 'training'} takes "
            f"(it trained with {given}), not the dataset's {split} split"
        )
        say(f"note: {result['split_note']}: {', '.join(takes)}")
    # the takes of this dataset that trained or validated the run (None: its checkpoint records none)
    result["leaked_takes"] = leaked
    if leaked:
        result["leak_note"] = (
            f"{len(leaked)} evaluated take(s) trained or validated this run: these {split} scores are not "
            "held out"
        )
        warn(f"{result['leak_note']}: {', '.join(leaked)}")
    result.update(tally.summary())
    fl = floor.summary()
    result["floor"] = {k: fl[k] for k in ("rmse_entire", "rmse_crucial", "rmse_pooled", "per_channel")}
    if tally.crucial is None:
        result["note"] = "the run's channels lack jawOpen or mouthClose: no crucial RMSE"
    result["per_phone_class"] = None if lipsync is None else lipsync.per_phone_class()
    result["bilabial_closure"] = None if lipsync is None else lipsync.bilabial_closure()
    result["open_vowel_opening"] = None if lipsync is None else lipsync.open_vowel_opening()
    for key in LIP_FIGURES:
        if lipsync is None:
            result[f"{key}_note"] = NO_PHONES
        elif key != "per_phone_class" and result[key] is None:
            result[f"{key}_note"] = "the run's channels lack jawOpen or mouthClose: no lip aperture"
    if spec.styles:
        result["style"] = {
            "styles": list(spec.styles),
            "chosen": style or "own",
            "utterances_in_own_style": own_style,
            "utterances_in_mean_style": seen - own_style if style in (None, MEAN) else 0,
            "utterances_in_chosen_style": seen if style not in (None, MEAN) else 0,
        }
    if longest is not None:
        frames = int(round(rtf_seconds * info["fps"]))
        limit = max_frames(model_config)
        if limit is not None and limit < frames:
            frames = limit  # the model takes no more in one pass
            result["rtf_note"] = (
                f"rtf timed on {limit} frames ({limit / info['fps']:g} s, the model's max_frames), "
                f"not {rtf_seconds:g} s"
            )
            say(f"note: {result['rtf_note']}")
        result["rtf"] = real_time_factor(model, spec, longest, info["fps"], style=style, frames=frames)
        result["rtf_seconds"] = frames / info["fps"]
        result["rtf_frames"] = frames
    result["device"] = device_name(torch.device("cpu"))
    say(
        f"{payload['system']} on {split}: rmse entire {_fmt(result['rmse_entire'])}, "
        f"crucial {_fmt(result['rmse_crucial'])}; floor {_fmt(result['floor']['rmse_entire'])}"
    )
    return result


def _leaks(
    payload: dict[str, Any], manifest: dict[str, Any], split: str, own_keys: set[str] | None
) -> list[str] | None:
    """The takes of the samples evaluated (the dataset's ``split``, or the run's own takes) that trained
    or validated the run (``run_dataset.leaked_takes``); None for a run whose checkpoint records no takes. An
    ensemble's first member trained on or validated every take the ensemble used."""
    record = recorded_takes(payload.get("dataset"))
    if record is None:
        return None
    if own_keys is not None:  # the run's own training or validation takes (its val_takes, drop_takes)
        return []
    evaluated = {s["take"] for s in manifest["samples"] if s["split"] == split}
    return leaked_takes(record, manifest, sorted(evaluated), split)


def _fmt(ms: dict[str, float] | None) -> str:
    return "n/a" if ms is None else f"{ms['mean']:.3f} ± {ms['std']:.3f}"


def format_result(r: dict[str, Any]) -> str:
    """Human-readable summary of ``evaluate``'s result."""
    lines = [
        f"{r['model']} (step {r['step']}) on {r['split']}: "
        f"{r['utterances']} utterances, {r['frames']} frames",
        f"  rmse entire  {_fmt(r['rmse_entire'])}   floor (train mean) {_fmt(r['floor']['rmse_entire'])}",
        f"  rmse crucial {_fmt(r['rmse_crucial'])}   floor (train mean) {_fmt(r['floor']['rmse_crucial'])}",
    ]
    lines += _lipsync_lines(r)
    if "split_note" in r:
        lines.append(f"  {r['split_note']}: {', '.join(r['split_takes'])}")
    if r.get("leaked_takes"):
        lines.append(f"  warning: {r['leak_note']}: {', '.join(r['leaked_takes'])}")
    if "rtf" in r:
        where = f"{r['rtf_seconds']:g} s utterance, {r['device']}, {r.get('precision', 'fp32')}"
        lines.append(f"  rtf {r['rtf']:.5f} ({where})")
        if "rtf_note" in r:
            lines.append(f"  {r['rtf_note']}")
    worst = sorted(r["per_channel"].items(), key=lambda kv: -kv[1])[:5]
    lines.append("  worst channels: " + ", ".join(f"{k} {v:.2f}" for k, v in worst))
    return "\n".join(lines)


def _lipsync_lines(r: dict[str, Any]) -> list[str]:
    """``format_result``'s lines on errors by phone class, bilabial closures and open-vowel openings
    (absent from a result of an older eval)."""
    if "per_phone_class" not in r:
        return []
    if r["per_phone_class"] is None:
        return [f"  by phone class: n/a ({r['per_phone_class_note']})"]
    shown = [
        f"{name} {c['rmse']:.2f}/{c['floor']:.2f} ({c['frames']})"
        for name, c in r["per_phone_class"]["classes"].items()
        if c["frames"]
    ]
    lines = ["  by phone class, rmse/floor (frames): " + (", ".join(shown) or "no frame's phone in a class")]
    for key, label, done, segments, recorded in (
        ("bilabial_closure", "bilabial closures", "kept", "bilabial", "recorded_closures"),
        ("open_vowel_opening", "open-vowel openings", "made", "open-vowel", "recorded_openings"),
    ):
        figure = r[key]
        if figure is None:
            lines.append(f"  {label}: n/a ({r[f'{key}_note']})")
        elif not figure[recorded]:
            lines.append(f"  {label}: none recorded in {figure['segments']} {segments} segments")
        else:
            model, floor, n = figure["model"], figure["floor"], figure[recorded]
            lines.append(
                f"  {label} {done}: {model['hits']}/{n} ({model['hit_rate']:.0%}), floor "
                f"{floor['hits']}/{n} ({floor['hit_rate']:.0%}); {figure['segments']} {segments} segments"
            )
    return lines
