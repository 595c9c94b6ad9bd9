"""The training loop of every system: one straight loop (``_fit``) over the pieces above it (the resume
checks, the restore, one training step, the metrics log).

AdamW with linear warm-up and cosine decay, global gradient-norm clipping, optional bf16 autocast,
validation every ``eval_every`` steps with early stopping, checkpoints that resume exactly (model,
optimizer, step, RNG state, data position), metrics as JSON lines and TensorBoard events, DDP when
started by ``torchrun`` (WORLD_SIZE > 1; gloo on CPU, nccl on CUDA). Ridge regression is solved in closed
form instead.
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import json
import math
import os
import threading
import time
from collections.abc import Callable
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import torch
import torch.distributed as dist

from capture.command import json_safe, progress, warn
from capture.errors import InputError, strict_names
from dataset.manifest import MANIFEST_FILE, dataset_folder
from dataset.torch_dataset import check_shards

from .augment import augment_frames
from .augment import enabled as augmenting
from .checkpoint import (
    BEST,
    CONFIG,
    DATA_ORDER,
    LAST,
    METRICS,
    load_checkpoint,
    read_run_config,
    refuse_other_world,
    run_lock,
    save_checkpoint,
    write_atomically,
    write_error,
    write_json,
)
from .config import DEFAULTS, RUN_RECORD_KEYS, check_config
from .data import (
    endless_batches,
    present_frames,
    resolve_inputs,
    split_keys,
    target_values,
    to_model_inputs,
    train_dataset,
    utterances,
)
from .ensemble import check_ensemble_run, fit_ensemble, refuse_beside_ensemble
from .model import masked_mse
from .ridge import ALPHAS, NormalEquations
from .run_dataset import (
    DIFFERS,
    RUN_DATASET,
    DatasetWatch,
    agreed_failure,
    recorded_takes,
    run_takes,
    take_changes,
)
from .systems import build_model, check_sample_frames


def learning_rate(step: int, cfg: dict[str, Any]) -> float:
    """Linear warm-up over ``warmup_steps``, then cosine decay to ``lr · min_lr_ratio`` at ``max_steps``."""
    peak, warm, total = cfg["lr"], cfg["warmup_steps"], cfg["max_steps"]
    if warm > 0 and step < warm:
        return peak * (step + 1) / warm
    progress_ = min(1.0, (step - warm) / max(1, total - warm))
    floor = peak * cfg["min_lr_ratio"]
    return floor + (peak - floor) * 0.5 * (1 + math.cos(math.pi * progress_))


def _distributed() -> tuple[int, int, torch.device]:
    world = int(os.environ.get("WORLD_SIZE", "1"))
    cuda = torch.cuda.is_available()
    if world > 1 and not dist.is_initialized():
        dist.init_process_group("nccl" if cuda else "gloo")
    rank = dist.get_rank() if dist.is_initialized() else 0
    if cuda:
        local = int(os.environ.get("LOCAL_RANK", "0"))
        torch.cuda.set_device(local)
        return rank, world, torch.device("cuda", local)
    return rank, world, torch.device("cpu")


def _all_sum(values: list[float], device: torch.device) -> list[float]:
    t = torch.tensor(values, dtype=torch.float64, device=device)
    if dist.is_initialized():
        dist.all_reduce(t)
    return t.tolist()


def _autocast(cfg: dict[str, Any], device: torch.device):
    if device.type == "cuda":
        on = cfg["amp"] in ("auto", "bf16") and torch.cuda.is_bf16_supported()
    else:
        on = cfg["amp"] == "bf16"
    return torch.autocast(device.type, dtype=torch.bfloat16, enabled=on)


def channel_weights(
    manifest: dict[str, Any], cfg: dict[str, Any], device: torch.device | str = "cpu"
) -> torch.Tensor | None:
    """Per-channel loss weights: None for ``loss_weights = "normalised"``; for ``"raw"`` the squared
    normalisation scales divided by their mean, so that the weighted normalised error is proportional to
    the error in coefficient units (the metric's), at the normalised loss's overall size."""
    if cfg.get("loss_weights", "normalised") == "normalised":
        return None
    scale = torch.tensor(manifest["normalization"]["animation"]["scale"], dtype=torch.float64) ** 2
    return (scale / scale.mean()).float().to(device)


@torch.no_grad()
def validation_loss(
    model,
    ds: Path,
    spec,
    device: torch.device,
    weights: torch.Tensor | None = None,
    cfg: dict[str, Any] | None = None,
    manifest: dict[str, Any] | None = None,
) -> float:
    """MSE over every usable value (frame and channel) of the validation split (this rank's share,
    summed over ranks), normalised units, channels weighted by ``weights`` when given. ``manifest``:
    the dataset's as the run read it when it started (default: read here)."""
    model.eval()
    se, n = 0.0, 0.0
    error = None
    try:
        for item in utterances(ds, "val", spec, cfg, manifest, values=True):
            content, prosody = to_model_inputs(item, spec)
            m = item["values"].to(device).float()  # the values scored; the model sees every frame
            present = present_frames(item).to(device)
            pred = model(content.to(device), None if prosody is None else prosody.to(device), present)
            err = (pred.float() - item["anim"].to(device)) ** 2
            se += float(((err if weights is None else err * weights) * m).sum())
            n += float(m.sum())
    except (InputError, OSError) as exc:  # under DDP: decided with the other ranks below
        if not dist.is_initialized():
            raise
        error = exc
    finally:
        model.train()
    error = agreed_failure(error, device)  # every rank read its share, or every rank stops
    if error is not None:
        raise error
    se, n = _all_sum([se, n], device)
    return se / n if n else float("nan")


def _no_validation(ds: Path, manifest: dict[str, Any], cfg: dict[str, Any]) -> str | None:
    """Why the run cannot validate (no val split, or one without a usable value), else None."""
    keys = split_keys(manifest, cfg)
    val = [
        s for s in manifest["samples"] if (s["key"] in keys[1] if keys is not None else s["split"] == "val")
    ]
    if not val:
        return "the dataset has no val split"
    if any(s.get("usable_frames", s["frames"]) for s in val) or _val_has_values(ds, manifest, cfg, val):
        return None
    return "the val split has no usable frames (face lost throughout?)"


def _val_has_values(
    ds: Path, manifest: dict[str, Any], cfg: dict[str, Any], val: list[dict[str, Any]]
) -> bool:
    """Whether the val split (its manifest entries ``val``) holds a usable value: a channel NaN
    throughout a take leaves no frame usable in every channel (``usable_frames`` 0), and its other
    channels as targets (``values``). Told by the entries' ``usable_values``; a manifest without them
    (a build before it) has the samples read, whole on every rank, so that the ranks decide alike."""
    if all("usable_values" in s for s in val):
        return any(s["usable_values"] for s in val)
    items = utterances(ds, "val", None, cfg, manifest, values=True, whole=True)
    return any(bool(item["values"].any()) for item in items)


def _fit_ridge(
    ds: Path, run: Path, cfg, spec, watch: DatasetWatch, say
) -> tuple[dict[str, Any], torch.nn.Module]:
    """Solve the ridge regression; (summary entries, the fitted model)."""
    manifest = watch.manifest
    torch.manual_seed(cfg["seed"])  # the random state its checkpoint keeps: the same run, the same bytes
    model, model_config = build_model("ridge", spec, cfg)
    eq = NormalEquations(model.linear.in_features, spec.out_dim)
    t0 = time.perf_counter()
    with watch.reading():
        # each usable value: a glitch in one channel leaves the frame's others (their own solution)
        for item in utterances(ds, "train", spec, cfg, manifest, values=True):
            content, prosody = to_model_inputs(item, spec)
            eq.add(model.inputs(content, prosody, present_frames(item)), item["anim"], item["values"])
        no_val = _no_validation(ds, manifest, cfg)
    frames = eq.n  # usable in some channel
    alpha, val = _choose_alpha(eq, model, ds, spec, watch, cfg, no_val, say)
    cfg = {**cfg, "ridge_alpha": alpha}
    eq.solve(model, alpha)
    best_val = None if math.isnan(val) else val
    dataset = dataset_entry(ds, watch, cfg)
    payload = _payload(model, None, cfg, spec, model_config, dataset, step=0, epoch=0, batch=0)
    payload.update(best_val=best_val, finished=True)
    watch.check()  # solved on the build it started on
    save_checkpoint(payload, run / LAST)
    elapsed = time.perf_counter() - t0
    scored = "" if best_val is None else f", val mse {best_val:.4f}"
    say(f"ridge: solved on {frames} frames in {elapsed:.1f} s, alpha {alpha:g}{scored}")
    try:  # a new file: the run is solved once (a resumed ridge run is not solved again)
        with open(run / METRICS, "w") as f:
            f.write(json.dumps({"step": 0, "val_mse": best_val, "train_frames": frames}) + "\n")
    except OSError as exc:
        raise write_error(exc, run / METRICS) from None
    return {
        "steps": 0,
        "best_val": best_val,
        "stopped": "closed_form",
        "train_frames_per_s": frames / elapsed,
    }, model


def _choose_alpha(
    eq: NormalEquations, model, ds: Path, spec, watch: DatasetWatch, cfg, no_val: str | None, say
) -> tuple[float, float]:
    """(alpha, its validation loss) of the ridge: ``ridge_alpha``, or with 0 the one of ``ALPHAS`` val
    scores best. Without a val split to score on (``no_val``: why), ``ridge_alpha`` or else 1, loss NaN."""
    if no_val is not None:  # nothing to score on
        if cfg["ridge_alpha"] > 0:
            return cfg["ridge_alpha"], math.nan
        say(f"note: {no_val}: ridge uses alpha 1")
        return 1.0, math.nan
    alphas = [cfg["ridge_alpha"]] if cfg["ridge_alpha"] > 0 else ALPHAS
    weights = channel_weights(watch.manifest, cfg)
    cpu = torch.device("cpu")
    scores = []
    with watch.reading():
        for alpha in alphas:
            eq.solve(model, alpha)
            scores.append(validation_loss(model, ds, spec, cpu, weights, cfg, watch.manifest))
    if len(alphas) > 1 and all(math.isnan(s) for s in scores):  # counted usable values it does not hold
        say(
            "note: the val split has no usable value (its manifest's usable_values say otherwise: see "
            "s2a-dataset validate): ridge uses alpha 1"
        )
        return 1.0, math.nan
    best = min(range(len(alphas)), key=lambda i: scores[i])
    return alphas[best], scores[best]


def _summary(
    run: Path,
    cfg: dict[str, Any],
    steps: int,
    epochs: int | None,
    best_val: float | None,
    stopped: str | None,
    world: int,
    rank: int,
    checksums: list[Any],
    parameters: int | None,
    session_s: float,
    **extra: Any,
) -> dict[str, Any]:
    """``fit``'s summary: the same keys for every system (ridge and ensembles add their own)."""
    return {
        "run": str(run),
        "model": cfg["model"],
        "steps": steps,
        "epochs": epochs,  # passes over the training split begun (the last may be partial)
        "best_val": best_val,
        "stopped": stopped,
        "world_size": world,
        "rank": rank,
        "params_checksums": checksums,  # sha256 of every rank's parameters: DDP keeps them identical
        "ranks_in_sync": len(set(checksums)) <= 1,
        "parameters": parameters,
        "session_s": session_s,
        **extra,
    }


def _show(value: float) -> str:
    return "none" if math.isinf(value) or math.isnan(value) else f"{value:.4f}"


def _checksum(model) -> str:
    h = hashlib.sha256()
    for p in model.parameters():
        h.update(p.detach().cpu().numpy().tobytes())
    return h.hexdigest()


def dataset_record(ds: Path) -> dict[str, str]:
    """config.json's ``data``: the dataset folder, as strict JSON readers take it (``strict_names``: a name
    not UTF-8 as ``\\xff``, its bytes in ``data_b64``)."""
    return strict_names({"data": str(ds)})


def dataset_entry(ds: Path, watch: DatasetWatch, cfg: dict[str, Any]) -> dict[str, Any]:
    """A checkpoint's ``dataset``: where the run's dataset is, what a resumed run and inference must
    match (channels, fps, features with their settings, normalization), the build it was (manifest.json's
    sha256) and the takes that train and validate the run (``run_takes``: resume and eval compare them)."""
    manifest = watch.manifest
    return {
        "path": str(ds),
        "channels": manifest["channels"],
        "fps": manifest["fps"],
        "features": manifest["features"],  # settings of the feature pipeline, for predict
        "normalization": manifest["normalization"],
        "manifest_sha256": watch.sha,
        "takes": run_takes(manifest, cfg),
    }


def _payload(
    model, optimizer, cfg, spec, model_config, dataset, step, epoch, batch, data_order: int = DATA_ORDER
) -> dict[str, Any]:
    module = model.module if hasattr(model, "module") else model
    return {
        "system": cfg["model"],
        "config": cfg,
        "model_config": model_config,
        "inputs": spec.to_json(),
        "dataset": dataset,
        "state_dict": {k: v.detach().cpu() for k, v in module.state_dict().items()},
        "optimizer": optimizer.state_dict() if optimizer is not None else {},
        "step": step,
        "epoch": epoch,
        "batch": batch,
        "data_order": data_order,  # the order the training data is read in (see _data_order)
        "rng": {"torch": torch.get_rng_state()},
        "best_val": None,
        "bad_evals": 0,
        "finished": False,
    }


def check_outside_dataset(out: Path, ds: Path, what: str = "run folder") -> None:
    """Refuse an output folder ``out`` that is the dataset folder ``ds`` or lies inside it: run files
    would be mixed into the dataset (and a dataset rebuilt or copied would carry them along)."""
    if not (ds / MANIFEST_FILE).is_file():
        return  # not a dataset: reading it says so
    try:
        inside, folder = out.resolve(), ds.resolve()
    except (OSError, RuntimeError):  # a symlink loop: the write names it
        return
    if inside == folder or folder in inside.parents:
        where = "is the dataset folder" if inside == folder else f"is inside the dataset folder {ds}"
        raise InputError(f"{what} {where}: give -o outside the dataset", out)


def check_feature_masks(cfg: dict[str, Any], spec) -> None:
    """No more feature masks than the content input has dims, as no more time masks than the window has
    frames (config.py): more mask nothing more, and the draws grow with their number."""
    if cfg["aug_feature_masks"] > spec.content_dim:
        raise InputError(
            f"aug_feature_masks must be at most the content input's {spec.content_dim} dims: more masks than "
            f"dims mask nothing more, got {cfg['aug_feature_masks']!r}",
            "config:aug_feature_masks",
        )


def checked_model(name: str, manifest: dict[str, Any], cfg: dict[str, Any], where: str = "manifest.json"):
    """``(inputs, (model, model_config))`` a config makes of a dataset, with what it asks of the inputs
    checked (``check_feature_masks``): every caller that refuses a config before training (fit, compare)."""
    spec = resolve_inputs(manifest, cfg, where)
    check_feature_masks(cfg, spec)
    return spec, build_model(name, spec, cfg)


def _check_before_writing(
    ds: Path, manifest: dict[str, Any], cfg: dict[str, Any], world: int, shards: bool = True
):
    """``(inputs, model_config)`` of a run, after everything that can refuse it short of training: the
    inputs, the arch keys, the samples against ``max_frames``, ridge under torchrun, the shards (missing,
    truncated, foreign; not when the caller checked them: ``shards`` False), so that a refused run writes
    nothing."""
    spec, (_, model_config) = checked_model(cfg["model"], manifest, cfg, str(ds / "manifest.json"))
    check_sample_frames(manifest, ("train", "val"), model_config, ds / "manifest.json")
    if cfg["model"] == "ridge" and world > 1:
        raise InputError("ridge is solved in closed form: run it without torchrun", "config:model")
    if shards:
        check_shards(ds, manifest, ("train", "val"))
    return spec, model_config


def _diverged(cfg: dict[str, Any], last_saved: int | None) -> str:
    """What a diverged run says after its step: the likely cause, and which checkpoint is left, if any
    (a run diverging before its first checkpoint has none: there is nothing to resume)."""
    cause = "the loss or its gradient is not finite"
    cause += " (lower lr?)" if not cfg["aug_noise"] else " (lower lr or aug_noise?)"
    if last_saved is None:
        first = min(cfg["eval_every"], cfg["max_steps"])
        return f"{cause}; no checkpoint was written before it (the first comes at step {first})"
    return f"{cause}; {LAST} keeps the checkpoint of step {last_saved}, before it"


def complete_config(cfg: Any) -> dict[str, Any]:
    """``cfg`` with the keys it leaves out taken from ``DEFAULTS`` (``{"model": "s2a", "max_steps": 1}``
    from code), checked as ``resolve_config`` checks a config; a complete config is returned as it is.
    Not a dict, or an unknown key, is an ``InputError``."""
    if not isinstance(cfg, dict):
        raise InputError(
            f"the config must be a dict of config keys (train.resolve_config() makes one), not "
            f"{type(cfg).__name__}"
        )
    if all(k in cfg for k in DEFAULTS):
        return cfg
    unknown = sorted(str(k) for k in cfg if k not in DEFAULTS and k not in RUN_RECORD_KEYS)
    if unknown:
        raise InputError(
            f"unknown config key(s) {', '.join(unknown)} (known: {', '.join(sorted(DEFAULTS))}; "
            "train.resolve_config() makes a complete config)"
        )
    full = copy.deepcopy(DEFAULTS)
    full.update({k: copy.deepcopy(v) for k, v in cfg.items() if k in DEFAULTS})
    check_config(full)
    return full


def fit(
    ds: str | Path,
    run: str | Path,
    cfg: dict[str, Any],
    resume: bool = False,
    say: Callable[[str], None] = progress,
    stop_after_steps: int | None = None,
    given: dict[str, Any] | None = None,
    shards_checked: bool = False,
) -> dict[str, Any]:
    """Train system ``cfg["model"]`` on dataset ``ds`` (a folder or its manifest.json) into run folder
    ``run``; returns a summary.

    ``resume`` continues from ``run/last.pt`` with the run's saved config (``max_steps`` and
    ``max_minutes`` from ``cfg``) on the dataset it was trained on; ``given`` (the config keys the user
    set) must then agree with the saved config. ``stop_after_steps`` ends this session after that many
    steps with a checkpoint, as if the process had been stopped (the run is then resumable).
    ``shards_checked``: the caller has checked the dataset's shards (``compare``), not done again.
    Progress and notes go to ``say``, warnings to stderr through ``warn`` (named by the running command).

    Under torchrun the process group is created here and destroyed on the way out: a process that
    exits with gloo's worker threads still alive is aborted by the C++ runtime."""
    cfg = complete_config(cfg)
    owns_group = int(os.environ.get("WORLD_SIZE", "1")) > 1 and not dist.is_initialized()
    ds, run = dataset_folder(ds), Path(run)  # the folder, or its manifest as validate and stats accept it
    if run.exists() and not run.is_dir():
        raise InputError("run folder path is a file: give a folder with -o", run)
    check_outside_dataset(run, ds)
    locks = ExitStack()
    writer = int(os.environ.get("RANK", "0")) == 0  # under torchrun, rank 0 writes and holds the lock
    held = False

    def claim() -> None:
        """Lock the run folder (once it exists) for the rest of this fit."""
        nonlocal held
        if writer and not held:
            locks.enter_context(run_lock(run))
            held = True

    try:
        if run.is_dir():  # before reading its checkpoint: another fit may be about to rewrite it
            claim()
        if resume and (run / CONFIG).is_file() and not (run / LAST).is_file():
            saved = read_run_config(run / CONFIG)
            if saved.get("cv_folds"):  # an ensemble: its own config, this session's limits
                _refuse_changes(given, saved, run / CONFIG)
                cfg = _resumed_config(saved, cfg, given)
        if cfg.get("cv_folds") and not (resume and (run / LAST).is_file()):
            return _fit_ensemble(ds, run, cfg, resume, say, stop_after_steps, claim, shards_checked)
        # (a resumed single run given cv_folds is refused by its resume: its config keeps cv_folds 0)
        refuse_beside_ensemble(run, resume)  # whatever this fit's config: never beside an ensemble
        return _fit(ds, run, cfg, resume, say, stop_after_steps, given, claim, shards_checked)
    finally:
        locks.close()
        if owns_group and dist.is_initialized():
            dist.destroy_process_group()


def _flat(cfg: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"arch": {"s2a": {"d_model": 8}}}`` → ``{"arch.s2a.d_model": 8}``."""
    out: dict[str, Any] = {}
    for k, v in cfg.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[prefix + k] = v
    return out


def _refuse_changes(
    given: dict[str, Any] | None, saved: dict[str, Any], where: Path, who: str = "--resume"
) -> None:
    """Resuming keeps the run's config: a key the user set to another value than the run's is an error
    (the limits ``max_steps`` and ``max_minutes`` may change)."""
    old = _flat({**DEFAULTS, **saved})
    changed = [
        k for k, v in _flat(given or {}).items() if k not in ("max_steps", "max_minutes") and old.get(k) != v
    ]
    if changed:
        runs = ", ".join(f"{k} = {json.dumps(old.get(k))}" for k in changed)
        raise InputError(
            f"{who} keeps the run's config, but {', '.join(changed)} differ(s) from it (the run's: {runs}); "
            "only --max-steps and --max-minutes may change (train another run with -o)",
            where,
        )


def check_resumable(run: Path, given: dict[str, Any] | None, who: str = "--resume") -> None:
    """Refuse, before anything trains, to resume ``run`` (a run or ensemble folder with a saved
    config.json) with ``given`` config keys other than the run's."""
    if (run / CONFIG).is_file():
        _refuse_changes(given, read_run_config(run / CONFIG), run / CONFIG, who)


def _same_dataset(state: dict[str, Any], manifest: dict[str, Any], ds: Path, where: Path) -> None:
    """A resumed run's dataset has the channels, fps, features and normalization it trained with; the
    refusal says what changed, and whether the run's own dataset folder was rebuilt or another one given."""
    trained = state.get("dataset")
    trained = trained if isinstance(trained, dict) else {}
    differ = [k for k in RUN_DATASET if trained.get(k) != manifest[k]]
    if not differ:
        return
    words = "; ".join(DIFFERS[k] for k in differ)
    was = trained.get("path")
    if isinstance(was, str) and _same_folder(Path(was), ds):
        raise InputError(
            f"the dataset at {ds} was rebuilt since this run trained on it: {words} (a run resumes on the "
            "dataset it trained on: train a new run on this build, or rebuild the dataset as it was)",
            where,
        )
    raise InputError(
        f"the run was trained on another dataset ({was if isinstance(was, str) else 'not recorded'}), "
        f"not {ds}: {words}; resume it with its own dataset",
        where,
    )


def _same_folder(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve()
    except (OSError, RuntimeError):
        return a == b


def _takes_since(state: dict[str, Any], manifest: dict[str, Any], cfg: dict[str, Any]):
    """(how the run's train takes, how its val takes changed since the checkpoint ``state``), in words;
    nothing for a checkpoint that records no takes (written before runs recorded them)."""
    before = recorded_takes(state.get("dataset"))
    if before is None:
        return [], []
    now = run_takes(manifest, cfg)
    return take_changes(before, now, "train"), take_changes(before, now, "val")


def _resumed_config(
    saved: dict[str, Any], cfg: dict[str, Any], given: dict[str, Any] | None = None
) -> dict[str, Any]:
    """A run's saved config with this session's limits (``max_steps``, ``max_minutes``): those the user
    set (``given``, from the command line), else the saved ones; without ``given`` (a call from code),
    ``cfg``'s. Keys added after the run was saved take their defaults (augmentation off)."""
    source = cfg if given is None else {**saved, **given}
    limits = {k: source.get(k, DEFAULTS[k]) for k in ("max_steps", "max_minutes")}
    return {**DEFAULTS, **{k: v for k, v in saved.items() if k in DEFAULTS}, **limits}


def _trim_metrics(path: Path, step: int) -> None:
    """Keep the lines of ``metrics.jsonl`` up to ``step``. A torn last line (a crash while writing it)
    is dropped; an unreadable line elsewhere is an error."""
    lines = path.read_text(errors="replace").splitlines(keepends=True)
    kept = []
    for i, line in enumerate(lines):
        try:
            record = json.loads(line)
            at = record.get("step", 0) if isinstance(record, dict) else None
        except json.JSONDecodeError:
            at = None
        if at is None and i == len(lines) - 1 and not line.endswith("\n"):
            break
        if not isinstance(at, (int, float)):
            raise InputError("not a metrics record (a JSON object with a step)", path, i + 1)
        if at <= step:
            kept.append(line)
    write_atomically(path, lambda tmp: tmp.write_text("".join(kept)))  # a kill here keeps the old lines


def _fit_ensemble(
    ds: Path,
    run: Path,
    cfg: dict[str, Any],
    resume: bool,
    say: Callable[[str], None],
    stop_after_steps: int | None,
    claim: Callable[[], None] = lambda: None,
    shards_checked: bool = False,
) -> dict[str, Any]:
    """A cross-validation ensemble (train/ensemble.py): one ordinary run per fold, all on the build of
    the dataset the ensemble started on."""
    watch = DatasetWatch.read(ds, cfg)
    rank, world, _device = _distributed()
    watch.agree()  # every rank on one build, or every rank stops (after _distributed: the group exists)
    manifest = watch.manifest
    say = say if rank == 0 else (lambda _m: None)
    split_keys(manifest, cfg)  # checks drop_takes against the dataset
    folds = check_ensemble_run(manifest, run, cfg, resume, world=world)
    # the members' own checks, before writing (the members then skip the shards)
    spec, _ = _check_before_writing(ds, manifest, cfg, world, not shards_checked)
    run.mkdir(parents=True, exist_ok=True)
    claim()
    if rank == 0:
        write_json(run / CONFIG, {**dataset_record(ds), "world_size": world, "inputs": spec.to_json(), **cfg})
    t0 = time.perf_counter()

    def fit_member(folder: Path, member_cfg: dict[str, Any], member_resume: bool) -> dict[str, Any]:
        return _fit(
            ds, folder, member_cfg, member_resume, say, stop_after_steps, shards_checked=True, watch=watch
        )

    summary = fit_ensemble(fit_member, folds, run, cfg, resume, rank == 0, say)
    checksums = [c for m in summary["members"] for c in m["params_checksums"] or []]
    sizes = [m.get("parameters") for m in summary["members"]]
    return {
        "run": str(run),
        "model": cfg["model"],
        "epochs": None,
        "world_size": world,
        "rank": rank,
        "params_checksums": checksums,
        "parameters": sum(sizes) if all(isinstance(n, int) for n in sizes) else None,  # all members'
        "session_s": time.perf_counter() - t0,
        **summary,
        "ranks_in_sync": all(m["ranks_in_sync"] is not False for m in summary["members"]),
    }


def _start_afresh(run: Path) -> None:
    """A run folder without ``last.pt`` holds at most what an attempt stopped before its first
    checkpoint left (Ctrl-C, a crash): its metrics lines, a ``best.pt`` written just before the
    ``last.pt`` that never came, its tensorboard events. A new run starts without them."""
    (run / BEST).unlink(missing_ok=True)
    (run / METRICS).unlink(missing_ok=True)
    for events in (run / "tensorboard").glob("events.out.tfevents.*"):
        events.unlink(missing_ok=True)


def _begin_run_files(run: Path, config_record: dict[str, Any], resumed_at: int | None) -> None:
    """Write the run's config.json; a new run (``resumed_at`` None) starts without what an attempt
    before it left (``_start_afresh``), a resumed one drops the metrics lines logged after its
    checkpoint's step ``resumed_at``."""
    write_json(run / CONFIG, config_record)
    if resumed_at is None:
        _start_afresh(run)
    elif (run / METRICS).exists():
        _trim_metrics(run / METRICS, resumed_at)


def _after_take_changes(
    train_changed: list[str], val_changed: list[str], best_val: float, bad_evals: int, warning
) -> tuple[float, int]:
    """Warn of the takes that train or validate a resumed run changed since its checkpoint (in words:
    ``_takes_since``); (best validation loss, bad evaluations) to go on with: restarted when the val
    takes changed, as scores of two validation sets do not compare."""
    if train_changed:
        warning(
            f"the dataset's takes that train this run changed since {LAST} "
            f"({'; '.join(train_changed)}): training goes on with them as they are now"
        )
    if not val_changed:
        return best_val, bad_evals
    warning(
        f"the takes that validate this run changed since {LAST} "
        f"({'; '.join(val_changed)}): best_val restarts (was {_show(best_val)}), and the next "
        f"validation writes {BEST}; patience counts afresh"
    )
    return math.inf, 0


def _ridge_chose_alpha(run: Path, state: dict[str, Any]) -> bool:
    """Whether ``run`` is a ridge that chose its alpha on val: its config.json asked for ``ridge_alpha``
    0 (a run given an alpha keeps that one; an unreadable config.json tells nothing)."""
    if state["config"].get("model") != "ridge" or not (run / CONFIG).is_file():
        return False
    try:
        return read_run_config(run / CONFIG).get("ridge_alpha") == 0
    except InputError:
        return False


def _load_resume_state(
    run: Path,
    manifest: dict[str, Any],
    ds: Path,
    cfg: dict[str, Any],
    given: dict[str, Any] | None,
    world: int,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """(checkpoint, config) of a run to resume, after every check that it can be: its checkpoint, its
    dataset (channels, fps, features, normalization), the config keys the user set, its number of
    processes."""
    if not (run / LAST).is_file():
        raise InputError(f"nothing to resume: no {LAST}", run)
    state = load_checkpoint(run / LAST)
    if not isinstance(state.get("config"), dict):
        raise InputError("checkpoint lacks its config", run / LAST)
    _same_dataset(state, manifest, ds, run / LAST)
    if (given or {}).get("ridge_alpha") == 0 and _ridge_chose_alpha(run, state):
        # 0 asks for the alpha val chooses: the checkpoint's config holds the one chosen (config.json the 0)
        given = {k: v for k, v in given.items() if k != "ridge_alpha"}
    _refuse_changes(given, state["config"], run / LAST)
    cfg = _resumed_config(state["config"], cfg, given)
    check_config(cfg)
    refuse_other_world(len(_positions(state)), world, "run", run / LAST)
    _data_order(state, run / LAST)
    return state, cfg


def _data_order(state: dict[str, Any], where: Path) -> int:
    """The order a checkpoint's run reads its training data in: ``DATA_ORDER`` (2: shards shuffled per
    epoch when ``shuffle_buffer`` > 1), or 1 for a checkpoint that records none (written before shard
    order was shuffled: shards in storage order every epoch), which then resumes in that order."""
    order = state.get("data_order", 1)
    if isinstance(order, bool) or order not in (1, DATA_ORDER):
        raise InputError(
            f"checkpoint reads its data in order {order!r}; this version knows 1 and {DATA_ORDER}", where
        )
    return order


def _positions(state: dict[str, Any]) -> list[Any]:
    """Every rank's data position ``[epoch, next batch]`` in a checkpoint (older ones hold one)."""
    return state.get("positions") or [[state.get("epoch"), state.get("batch")]]


def _restore(
    state: dict[str, Any], model, optimizer, rank: int, world: int, where: Path
) -> tuple[int, int, int, float, int]:
    """Load a checkpoint into the model, the optimizer and this rank's random generator; returns where
    training stands: (step, this rank's epoch and next batch, best validation loss, bad evaluations)."""
    try:
        model.load_state_dict(state["state_dict"])
        optimizer.load_state_dict(state["optimizer"])
        epoch, batch = _positions(state)[rank]  # checked against the world size by _load_resume_state
        ranks = state["rng"].get("ranks")  # each rank's generator (absent in older checkpoints)
        torch.set_rng_state(
            ranks[rank] if isinstance(ranks, list) and len(ranks) == world else state["rng"]["torch"]
        )
        best_val = state["best_val"] if state["best_val"] is not None else math.inf
        return state["step"], epoch, batch, best_val, state["bad_evals"]
    except (RuntimeError, KeyError, TypeError, ValueError, AttributeError) as exc:
        first = " ".join(str(exc).strip().splitlines()[:1]) or type(exc).__name__
        raise InputError(f"checkpoint cannot be resumed ({first})", where) from None


class MetricsLog:
    """``metrics.jsonl`` and the same figures as TensorBoard events (unless the tensorboard package is
    missing: a dependency, but an install without dependencies runs without it); only
    the main process ``writes``. ``resumed_at``: the step of the checkpoint a resumed session starts
    from, after which TensorBoard drops what an interrupted session logged."""

    def __init__(self, run: Path, writes: bool, resumed_at: int | None):
        self.path, self.lines, self.tb = run / METRICS, None, None
        self._tb_step: int | None = None  # the step of the last scalars written, and their tags
        self._tb_tags: set[str] = set()
        if not writes:
            return
        self.events = run / "tensorboard"
        self._hook = threading.excepthook
        threading.excepthook = self._events_thread_failed
        try:
            from torch.utils.tensorboard import SummaryWriter

            purge = None if resumed_at is None else resumed_at + 1
            self.tb = SummaryWriter(str(self.events), purge_step=purge)
        except ImportError:  # installed without its dependencies: metrics.jsonl only
            self.tb = None
        except UnicodeEncodeError:  # TensorBoard writes its file's name as UTF-8: a folder's bytes may not be
            warn(
                f"{self.events}: TensorBoard cannot write in a folder whose name is not UTF-8: {METRICS} only"
            )
            self.tb = None
        except OSError as exc:
            self.close()
            raise write_error(exc, self.events, "TensorBoard events") from None
        try:
            self.lines = open(self.path, "a")  # noqa: SIM115 - closed by close()
        except OSError as exc:
            self.close()
            raise write_error(exc, self.path) from None

    def emit(self, record: dict[str, Any]) -> None:
        if self.lines is None:
            return
        try:  # strict JSON for jq and browsers: a NaN or infinite figure (a diverged run) is null
            self.lines.write(json.dumps(json_safe(record)) + "\n")
            self.lines.flush()
        except OSError as exc:
            raise write_error(exc, self.path) from None
        if self.tb is not None:
            step = record["step"]
            if step != self._tb_step:
                self._tb_step, self._tb_tags = step, set()
            try:
                for k, v in record.items():
                    # a figure two records of one step share (the epoch of a training row and of the
                    # validation row after it) is one scalar event, not two of the same step
                    if k != "step" and k not in self._tb_tags and isinstance(v, (int, float)):
                        self.tb.add_scalar(k, v, step)
                        self._tb_tags.add(k)
            except OSError as exc:  # raised again here from its writer thread (a full disk)
                raise write_error(exc, self.events, "TensorBoard events") from None

    def _events_thread_failed(self, args: threading.ExceptHookArgs) -> None:
        """TensorBoard writes events on a thread of its own. A write that fails there (a full disk) is one
        line, not that thread's traceback; the next call here raises it again and ends the run."""
        if issubclass(args.exc_type, OSError) and type(args.thread).__module__.startswith("tensorboard"):
            error = write_error(args.exc_value, self.events, "TensorBoard events")
            with contextlib.suppress(OSError, ValueError):  # stderr closed by a caller: still no traceback
                warn(str(error))
        else:
            self._hook(args)

    def close(self) -> None:
        if self.lines is not None:
            self.lines.close()
        try:
            if self.tb is not None:
                tb, self.tb = self.tb, None
                tb.close()
        except OSError as exc:
            raise write_error(exc, self.events, "TensorBoard events") from None
        finally:
            if threading.excepthook == self._events_thread_failed:
                threading.excepthook = self._hook


def _stop_reason(step: int, cfg: dict[str, Any], early: bool, over: bool) -> str | None:
    """Why training stops after a validation at ``step`` (None: it goes on); ``early``: patience has run
    out, ``over``: the session's minutes have."""
    if step >= cfg["max_steps"]:
        return "max_steps"
    if early:
        return "early_stopping"
    return "max_minutes" if over else None


def _read_together(batches, world: int, device: torch.device):
    """``next(batches)``; under DDP every rank's read succeeded, or every rank raises (its own error, or
    the line of the rank that failed): a rank stopping alone would leave the others at the gradients'
    all-reduce until the process group times out. One all-reduce of a flag per step."""
    if world == 1:
        return next(batches)
    try:
        got, error = next(batches), None
    except (InputError, OSError) as exc:
        got, error = None, exc
    error = agreed_failure(error, device)
    if error is not None:
        raise error
    return got


def _train_step(net, model, batch, spec, cfg, weights, device):
    """Forward and backward of one batch (augmented as configured), gradients clipped; (mse, aux loss,
    gradient norm before clipping, usable values (B, T, channels)). The caller steps the optimizer once
    the norm is finite. The model sees the batch's ``present`` frames, the loss scores its ``values``
    (usable ones: a glitch in one channel leaves the frame's others)."""
    content, prosody = to_model_inputs(batch, spec, style_dropout=cfg["style_dropout"])
    content = content.to(device)
    prosody = None if prosody is None else prosody.to(device)
    mask = target_values(batch).to(device)  # usable values: the loss's
    present = present_frames(batch).to(device)  # frames that are not padding: the model's input
    target = batch["anim"].to(device)
    if augmenting(cfg):
        content, prosody, target, mask, present = augment_frames(content, prosody, target, mask, present, cfg)
    with _autocast(cfg, device):
        pred = net(content, prosody, present)
    mse = masked_mse(pred.float(), target, mask, weights)
    aux = model.aux_loss().to(device) if hasattr(model, "aux_loss") else torch.zeros((), device=device)
    model.zero_grad(set_to_none=True)
    (mse + cfg["aux_weight"] * aux).backward()
    grad_norm = torch.nn.utils.clip_grad_norm_(model.parameters(), cfg["grad_clip"] or math.inf)
    return mse, aux, grad_norm, mask


def _ridge_run(ds: Path, run: Path, cfg, spec, watch, state, config_record, say) -> dict[str, Any]:
    """A ridge run: solved in closed form; resumed, solved already (nothing to train, nor to append)."""
    t0 = time.perf_counter()
    if state is None:
        _begin_run_files(run, config_record, None)
        solved, ridge = _fit_ridge(ds, run, cfg, spec, watch, say)
    else:
        ridge, _ = build_model("ridge", spec, cfg)
        try:
            ridge.load_state_dict(state["state_dict"])
        except (RuntimeError, TypeError, KeyError) as exc:
            reason = type(exc).__name__
            raise InputError(f"checkpoint has a malformed state_dict ({reason})", run / LAST) from None
        say(
            "ridge is solved in closed form and this run already holds its solution "
            f"(alpha {cfg['ridge_alpha']:g}): nothing to do"
        )
        solved = {"steps": 0, "best_val": state.get("best_val"), "stopped": "closed_form"}
    return _summary(
        run,
        cfg,
        steps=solved.pop("steps"),
        epochs=0,
        best_val=solved.pop("best_val"),
        stopped=solved.pop("stopped"),
        world=1,
        rank=0,
        checksums=[_checksum(ridge)],
        parameters=sum(p.numel() for p in ridge.parameters()),
        session_s=time.perf_counter() - t0,
        **solved,
    )


def _fit(
    ds: Path,
    run: Path,
    cfg: dict[str, Any],
    resume: bool,
    say: Callable[[str], None],
    stop_after_steps: int | None,
    given: dict[str, Any] | None = None,
    claim: Callable[[], None] = lambda: None,
    shards_checked: bool = False,
    watch: DatasetWatch | None = None,
) -> dict[str, Any]:
    given_watch = watch is not None
    # the build the run starts on (an ensemble's members: the ensemble's); refuses a manifest whose fps
    # or normalisation is malformed
    if watch is None:
        watch = DatasetWatch.read(ds, cfg)
    rank, world, device = _distributed()
    if given_watch:
        watch.check_together(device)  # every rank together (DDP): one rank stopping alone hangs the rest
    else:
        watch.agree()  # every rank on one build, or every rank stops
    manifest = watch.manifest
    main = rank == 0
    say = say if main else (lambda _m: None)
    warning = warn if main else (lambda _m: None)  # said once, by the rank that speaks
    state = None
    # every check before anything is written: a refused run leaves its folder (and config.json) as it was
    if resume:
        state, cfg = _load_resume_state(run, manifest, ds, cfg, given, world)
    elif (run / LAST).exists():
        raise InputError(f"run folder already holds {LAST}: use --resume or another -o", run)
    split_keys(manifest, cfg)  # checks val_takes and drop_takes against the dataset
    watch = DatasetWatch(ds, manifest, watch.sha, cfg)  # the run's config (a resumed run's own)
    train_changed, val_changed = _takes_since(state, manifest, cfg) if state is not None else ([], [])
    spec, model_config = _check_before_writing(ds, manifest, cfg, world, not shards_checked)
    run.mkdir(parents=True, exist_ok=True)  # only now: a refused run leaves no empty folder behind
    claim()
    if spec.note:
        say(f"note: {spec.note}")
    if not spec.styles and cfg["style_dropout"] != DEFAULTS["style_dropout"]:
        say("note: style_dropout applies with speaker_style = true only: ignored")
    config_record = {**dataset_record(ds), "world_size": world, "inputs": spec.to_json(), **cfg}
    if cfg["model"] == "ridge":
        return _ridge_run(ds, run, cfg, spec, watch, state, config_record, say)

    torch.manual_seed(cfg["seed"])
    model, model_config = build_model(cfg["model"], spec, cfg)
    config_record["model_config"] = model_config  # every size of the model, defaults filled in
    model.to(device)
    optimizer = torch.optim.AdamW(
        model.parameters(), lr=cfg["lr"], betas=tuple(cfg["betas"]), weight_decay=cfg["weight_decay"]
    )
    step, epoch, batch_pos, best_val, bad_evals = 0, 0, 0, math.inf, 0
    if state is not None:
        step, epoch, batch_pos, best_val, bad_evals = _restore(
            state, model, optimizer, rank, world, run / LAST
        )
        best_val, bad_evals = _after_take_changes(train_changed, val_changed, best_val, bad_evals, warning)
    if main:  # written only now that every check has passed
        _begin_run_files(run, config_record, None if state is None else step)
    if state is not None and state.get("stopped") == "early_stopping":
        say(f"run stopped early at step {step}; nothing to resume")
    weights = channel_weights(manifest, cfg, device)
    with watch.reading():
        no_val = _no_validation(ds, manifest, cfg)
    has_val = no_val is None
    if not has_val:
        say(f"note: {no_val}: no validation, no early stopping, no best.pt")
    n_params = sum(p.numel() for p in model.parameters())
    say(f"{cfg['model']}: {n_params / 1e6:.2f} M parameters, {world} process(es) on {device}")
    # the only buffers are constant positional encodings: nothing to broadcast before each forward. Validation
    # runs the bare model: ranks hold different numbers of validation utterances, so a DDP forward there
    # could wait on a collective the other rank never joins.
    net = torch.nn.parallel.DistributedDataParallel(model, forward_sync_buffers=False) if world > 1 else model
    log = MetricsLog(run, main, None if state is None else step)
    dataset = dataset_entry(ds, watch, cfg)

    last_saved = step if state is not None else None  # the step of the run's last.pt, None before the first

    def save(name: str) -> None:
        # a checkpoint holds training on the build the run started on, never a newer one; under DDP the
        # ranks decide together (a rank that stopped alone would leave the others at the gather below)
        nonlocal last_saved
        watch.check_together(device)
        positions: list[Any] = [[epoch, batch_pos]]
        rngs: list[Any] = [torch.get_rng_state()]
        if world > 1:  # every rank reads its own shards and draws its own masks: keep each one's
            positions, rngs = [None] * world, [None] * world
            dist.all_gather_object(positions, [epoch, batch_pos])
            dist.all_gather_object(rngs, torch.get_rng_state())
        if main:
            p = _payload(model, optimizer, cfg, spec, model_config, dataset, step, epoch, batch_pos, order)
            p["positions"] = positions
            p["rng"]["ranks"] = rngs
            p.update(best_val=None if math.isinf(best_val) else best_val, bad_evals=bad_evals)
            p["finished"] = stopped in ("max_steps", "early_stopping")
            p["stopped"] = stopped
            save_checkpoint(p, run / name)
        if name == LAST:
            last_saved = step

    stopped = None
    t_start = t_log = time.perf_counter()
    frames_since, session_steps = 0.0, 0
    # a run checkpointed before shard order was shuffled per epoch resumes in its own (storage) order
    order = DATA_ORDER if state is None else _data_order(state, run / LAST)
    data = train_dataset(ds, spec, cfg, manifest, shuffle_shards=None if order >= 2 else False)
    net.train()
    try:
        if state is not None and state.get("stopped") == "early_stopping":
            stopped = "early_stopping"
        elif step >= cfg["max_steps"]:
            stopped = "max_steps"
            say(f"run already finished at step {step} (max_steps {cfg['max_steps']}); nothing to train")
        # each epoch checks manifest.json with one process; under DDP, ranks start their epochs at steps
        # of their own, so only the checks all ranks make together (validation, checkpoints) stop a run
        check = watch.check if world == 1 else None
        batches = endless_batches(data, cfg["batch_size"], epoch, batch_pos, cfg["seed"], check)
        while stopped is None:
            with watch.reading():  # a failed read checks manifest.json again
                # under DDP the ranks read their own shards: one failing alone stops them all
                epoch, i, batch = _read_together(batches, world, device)
            lr = learning_rate(step, cfg)
            for g in optimizer.param_groups:
                g["lr"] = lr
            mse, aux, grad_norm, mask = _train_step(net, model, batch, spec, cfg, weights, device)
            if not math.isfinite(float(grad_norm)):  # the same on every rank: gradients are all-reduced
                raise InputError(f"training diverged at step {step + 1}: {_diverged(cfg, last_saved)}", run)
            optimizer.step()
            step, batch_pos, session_steps = step + 1, i + 1, session_steps + 1
            # frames with a target; a tensor: no device sync per step
            frames_since += (mask.any(dim=-1) if mask.dim() == 3 else mask).sum()
            if step % cfg["log_every"] == 0:
                fr, ls = _all_sum([float(frames_since), mse.item()], device)
                now = time.perf_counter()
                rec = {"step": step, "epoch": epoch, "lr": lr, "mse": ls / world, "aux": float(aux.detach())}
                rec.update(grad_norm=float(grad_norm), frames_per_s=fr / (now - t_log))
                log.emit(rec)
                say(f"step {step}: mse {rec['mse']:.4f} lr {lr:.2e} {rec['frames_per_s']:.0f} frames/s")
                frames_since, t_log = 0.0, now
            minutes = (time.perf_counter() - t_start) / 60
            over = cfg["max_minutes"] > 0 and minutes >= cfg["max_minutes"]
            if world > 1 and cfg["max_minutes"] > 0:  # ranks stop together on rank-local clocks
                over = _all_sum([float(over)], device)[0] > 0
            # Validation only on the run's own schedule: a session cut short by the clock (or by
            # stop_after_steps) saves last.pt and nothing else, so that sessions reproduce one
            # uninterrupted run (no extra validations counting toward patience, writing best.pt or
            # adding metrics lines at steps the uninterrupted run never validates at).
            if step % cfg["eval_every"] == 0 or step >= cfg["max_steps"]:
                if has_val:  # on the build the run started on: checked before and after (by all ranks)
                    with watch.reading():
                        watch.check_together(device)
                        val = validation_loss(model, ds, spec, device, weights, cfg, manifest)
                        watch.check_together(device)
                else:
                    val = math.nan
                improved = has_val and val < best_val
                if improved:
                    best_val, bad_evals = val, 0
                else:
                    bad_evals += 1
                if has_val:
                    since = time.perf_counter() - t_start  # seconds into this session
                    log.emit(
                        {
                            "step": step,
                            "epoch": epoch,
                            "val_mse": val,
                            "best_val_mse": best_val,
                            "time_s": since,
                        }
                    )
                    say(f"step {step}: val mse {val:.4f} (best {best_val:.4f})")
                early = bool(has_val and cfg["patience"] and bad_evals >= cfg["patience"])
                stopped = _stop_reason(step, cfg, early, over)
                if improved:
                    save(BEST)
                save(LAST)
            elif over:
                stopped = "max_minutes"
                save(LAST)
            if stopped == "max_minutes":
                say(f"step {step}: max_minutes ({cfg['max_minutes']:g}) reached; --resume continues the run")
            if stopped is None and stop_after_steps is not None and session_steps >= stop_after_steps:
                stopped = "stopped"
                save(LAST)
    finally:
        log.close()
    elapsed = time.perf_counter() - t_start
    checksums = [_checksum(model)]
    if dist.is_initialized():
        gathered: list[Any] = [None] * world
        dist.all_gather_object(gathered, checksums[0])
        checksums = gathered
        dist.barrier()
    return _summary(
        run,
        cfg,
        step,
        epoch + 1 if step else 0,
        None if math.isinf(best_val) else best_val,
        stopped,
        world,
        rank,
        checksums,
        n_params,
        elapsed,
    )
