"""Training configuration: defaults, TOML files and ``--set key=value`` overrides.

Keys are flat (``lr``, ``batch_size``...) plus the table ``arch`` whose keys override the fields of the
model config dataclasses (``arch.d_model = 128`` applies to S2AConfig, ``arch.hidden`` to BLSTM and NVP,
``arch.dropout`` to all; ``arch.blstm.hidden = 64`` to one system only). Units: steps
are optimizer updates, ``window`` is animation frames, ``max_minutes`` wall-clock minutes.
"""

from __future__ import annotations

import copy
import sys
from pathlib import Path
from typing import Any

from capture.errors import RAW_BYTES, InputError, loads_names
from capture.numbers import is_finite_number
from capture.paired import read_text

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

MODELS = ("s2a", "s2a-nomoe", "blstm", "nvp3", "nvp9", "ridge")
MAX_RIDGE_CONTEXT = 60  # ± frames: (2·60 + 1) stacked frames is already far beyond useful
# PyTorch's generators take seeds below 2**64, and the reader seeds one with seed + epoch: a seed past
# 2**63 - 1 failed with a traceback at torch.manual_seed, or in a later epoch (as s2a-train ppg's --seed)
MAX_SEED = 2**63 - 1
# aug_mixup's Beta(a, a) drawn in float32: below 0.01 a growing share of the draws come out as exactly 0.5
# (a quarter at 0.001; every window mixed half and half where nearly none should be), under 1e-45 the
# draw fails with a traceback, past 1e38 (inf in float32) every weight is 1; from 1000 on the weights are
# 0.5 within 2 %, so larger values change nothing
MIXUP_RANGE = (0.01, 1000.0)
INPUTS = ("auto", "ppg", "fbank", "mfcc")

DEFAULTS: dict[str, Any] = {
    "model": "s2a",
    "input": "auto",  # content features: auto = ppg when the dataset has it, else fbank
    "prosody": True,  # pitch (log-F0, voicing) + energy
    # the speaker's style as a one-hot input (train/style.py): the training samples' speakers, the
    # mean style for any other speaker
    "speaker_style": False,
    "style_dropout": 0.1,  # probability that a training window gets the mean style instead of its own
    "seed": 0,
    "window": 240,  # frames per training window (4 s at 60 fps)
    "batch_size": 16,
    "lr": 5e-4,  # peak learning rate (AdamW)
    "weight_decay": 0.01,
    "betas": [0.9, 0.98],
    "warmup_steps": 200,
    "min_lr_ratio": 0.1,  # cosine decay from lr to lr * min_lr_ratio at max_steps
    "max_steps": 4000,
    "max_minutes": 0.0,  # 0 = no wall-clock limit
    "grad_clip": 1.0,  # max global gradient norm
    "aux_weight": 0.01,  # MoE load-balancing loss weight
    "amp": "auto",  # auto (bf16 on CUDA when supported), bf16 (also on CPU), none
    "shuffle_buffer": 64,
    "eval_every": 200,  # steps between validations and checkpoints
    "patience": 10,  # validations without improvement before early stopping (0 = never stop early)
    "log_every": 20,
    "ridge_context": 7,  # ridge: ± frames stacked
    "ridge_alpha": 0.0,  # ridge: L2 penalty per frame on standardised inputs; 0 = best on val of a grid
    # takes that validate instead of the dataset's val split (they leave training; the val split's
    # takes then train); [] = the dataset's splits. Test takes are refused.
    "val_takes": [],
    # > 0: a cross-validation ensemble (train/ensemble.py): the train and val takes dealt into this many
    # folds, one member per fold validating on it and training on the rest; predictions average them
    "cv_folds": 0,
    # takes that neither train nor validate (e.g. takes whose animation uses the rig differently from
    # the rest); test takes are refused
    "drop_takes": [],
    # channel weights of the loss (and of the validation score that early stopping and best.pt follow):
    # "normalised" = every normalised channel alike; "raw" = squared error in 0..1 coefficient units,
    # what rmse_entire measures (weights scale² of the manifest's normalisation, mean 1)
    "loss_weights": "normalised",
    # augmentation of the training batches (train/augment.py); all off by default
    "aug_noise": 0.0,  # std of Gaussian noise added to the normalised content features
    "aug_time_masks": 0,  # SpecAugment time masks per window ...
    "aug_time_mask_width": 0,  # ... each up to this many frames wide (content set to its mean, 0)
    "aug_feature_masks": 0,  # SpecAugment feature masks per window ...
    "aug_feature_mask_width": 0,  # ... each up to this many content dims wide
    "aug_mask_prosody": False,  # time masks also blank pitch and energy
    "aug_mixup": 0.0,  # mixup Beta(a, a) parameter; 0 = off
    "arch": {},
}


# what a run's config.json holds besides its config (fit writes them): ignored when it is read as a config
RUN_RECORD_KEYS = ("data", f"data{RAW_BYTES}", "world_size", "inputs", "model_config")


def _hint(key: str) -> str:
    """`` (did you mean 'lr'?)`` for the closest known key; an arch field's name points to ``arch.``."""
    from .systems import ARCH_TABLES, did_you_mean  # only on this error path: it imports the models (torch)

    if any(key in cls.__dataclass_fields__ for cls in ARCH_TABLES.values()):
        return f" (did you mean 'arch.{key}'? model settings are arch keys)"
    return did_you_mean(key, DEFAULTS)


def _merge(base: dict[str, Any], extra: dict[str, Any], where: str) -> None:
    for key, value in extra.items():
        if key not in DEFAULTS:
            raise InputError(
                f"unknown config key {key!r}{_hint(key)} (known: {', '.join(sorted(DEFAULTS))})", where
            )
        if key == "arch":
            if not isinstance(value, dict):
                raise InputError("'arch' must be a table", where)
            base["arch"].update(value)
        else:
            base[key] = value


def parse_set(item: str) -> tuple[str, Any]:
    """``key=value`` → (key, value); value read as a TOML literal, else kept as a string."""
    if "=" not in item:
        raise InputError(f"--set expects key=value, got {item!r}")
    key, raw = (s.strip() for s in item.split("=", 1))
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except ValueError:  # TOMLDecodeError, or an integer of more digits than Python converts
        value = raw
    return key, value


def resolve_config(
    file: str | Path | None = None,
    sets: list[str] | None = None,
    base: dict[str, Any] | None = None,
    check: bool = True,
) -> dict[str, Any]:
    """Defaults (or ``base``) ← TOML ``file`` ← ``--set`` items; checked unless ``check`` is false
    (``base={}, check=False`` gives only the keys the user set)."""
    cfg = copy.deepcopy(base if base is not None else DEFAULTS)
    cfg.setdefault("arch", {})
    if file is not None:
        path = Path(file)
        data = read_config_file(path)
        _merge(cfg, data, str(path))
        if check and isinstance(data.get("arch"), dict):  # name the file, not config:arch, for its typos
            from .systems import check_arch

            check_arch(data["arch"], f"{path}: [arch]")
    for item in sets or []:
        key, value = parse_set(item)
        if key.startswith("arch."):
            table, *rest = key[5:].split(".", 1)
            if rest:  # arch.<system>.<key>
                cfg["arch"].setdefault(table, {})[rest[0]] = value
            else:
                cfg["arch"][table] = value
        else:
            _merge(cfg, {key: value}, "--set")
    if check:
        check_config(cfg)
    return cfg


def read_config_file(path: Path) -> dict[str, Any]:
    """The keys of a TOML config file, or of a JSON one such as a run's ``config.json`` (whose
    ``data``, ``world_size`` and ``inputs`` records are not config keys and are ignored)."""
    if path.is_dir():
        raise InputError("config path is a folder, not a TOML file (or a run's config.json)", path)
    try:
        text = read_text(path)  # UTF-8 with or without a byte-order mark (Notepad), UTF-16/32 with one
    except FileNotFoundError:
        raise InputError("config file not found", path) from None
    except OSError as exc:
        raise InputError(f"cannot read config file: {exc.strerror}", path) from None
    if path.suffix.lower() == ".json":
        try:
            data = loads_names(text)
        except (ValueError, RecursionError) as exc:  # JSONDecodeError, or numbers/nesting past limits
            raise InputError(f"not valid JSON: {exc}", path) from None
        if not isinstance(data, dict):
            raise InputError("a JSON config must be an object of config keys (as config.json is)", path)
        return {k: v for k, v in data.items() if k not in RUN_RECORD_KEYS}
    try:
        return tomllib.loads(text)
    except (ValueError, RecursionError) as exc:  # TOMLDecodeError, or numbers/nesting past limits
        raise InputError(f"not valid TOML: {exc}", path) from None


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def check_config(cfg: dict[str, Any]) -> None:
    if cfg["model"] not in MODELS:
        raise InputError(f"model must be one of {', '.join(MODELS)}, got {cfg['model']!r}", "config:model")
    if cfg["input"] not in INPUTS:
        raise InputError(f"input must be one of {', '.join(INPUTS)}, got {cfg['input']!r}", "config:input")
    if not isinstance(cfg["prosody"], bool):
        raise InputError(f"prosody must be true or false, got {cfg['prosody']!r}", "config:prosody")
    if not isinstance(cfg["speaker_style"], bool):
        raise InputError(
            f"speaker_style must be true or false, got {cfg['speaker_style']!r}", "config:speaker_style"
        )
    if not is_finite_number(cfg["style_dropout"]) or not 0 <= cfg["style_dropout"] < 1:
        raise InputError(
            f"style_dropout must be a number in [0, 1), got {cfg['style_dropout']!r}", "config:style_dropout"
        )
    for key in ("val_takes", "drop_takes"):
        if not isinstance(cfg[key], list) or not all(isinstance(t, str) for t in cfg[key]):
            raise InputError(f"{key} must be a list of take ids, got {cfg[key]!r}", f"config:{key}")
    folds = cfg["cv_folds"]
    if not isinstance(folds, int) or isinstance(folds, bool) or folds < 0 or folds == 1:
        raise InputError(f"cv_folds must be 0 (off) or an integer >= 2, got {folds!r}", "config:cv_folds")
    if folds and cfg["val_takes"]:
        raise InputError("cv_folds and val_takes exclude each other: every fold validates in turn", "config")
    if cfg["loss_weights"] not in ("normalised", "raw"):
        raise InputError(
            f"loss_weights must be normalised or raw, got {cfg['loss_weights']!r}", "config:loss_weights"
        )
    if cfg["amp"] not in ("auto", "bf16", "none"):
        raise InputError(f"amp must be auto, bf16 or none, got {cfg['amp']!r}", "config:amp")
    for key in ("window", "batch_size", "max_steps", "eval_every", "log_every"):
        if not _is_int(cfg[key]) or cfg[key] < 1:
            raise InputError(f"{key} must be a positive integer, got {cfg[key]!r}", f"config:{key}")
    if not _is_int(cfg["seed"]) or not 0 <= cfg["seed"] <= MAX_SEED:
        raise InputError(f"seed must be an integer in 0..2**63 - 1, got {cfg['seed']!r}", "config:seed")
    for key in (
        "warmup_steps",
        "patience",
        "shuffle_buffer",
        "aug_time_masks",
        "aug_time_mask_width",
        "aug_feature_masks",
        "aug_feature_mask_width",
    ):
        if not _is_int(cfg[key]) or cfg[key] < 0:
            raise InputError(f"{key} must be a non-negative integer, got {cfg[key]!r}", f"config:{key}")
    # a mask's draws take (windows x masks x frames) bytes: 10**12 time masks ran out of memory only once
    # training had started (its run folder written), 10**7 would ask for 38 GB; more masks than a
    # window's frames mask nothing more
    if cfg["aug_time_masks"] > cfg["window"]:
        raise InputError(
            f"aug_time_masks must be at most window ({cfg['window']}): more masks than frames mask nothing "
            f"more, got {cfg['aug_time_masks']!r}",
            "config:aug_time_masks",
        )
    context = cfg["ridge_context"]
    if not _is_int(context) or not 0 <= context <= MAX_RIDGE_CONTEXT:
        raise InputError(
            f"ridge_context must be an integer in 0..{MAX_RIDGE_CONTEXT}, got {context!r}",
            "config:ridge_context",
        )
    if not isinstance(cfg["aug_mask_prosody"], bool):
        raise InputError(
            f"aug_mask_prosody must be true or false, got {cfg['aug_mask_prosody']!r}",
            "config:aug_mask_prosody",
        )
    if not is_finite_number(cfg["lr"]) or cfg["lr"] <= 0:
        raise InputError(f"lr must be a positive finite number, got {cfg['lr']!r}", "config:lr")
    for key in (
        "weight_decay",
        "grad_clip",
        "aux_weight",
        "max_minutes",
        "ridge_alpha",
        "aug_noise",
        "aug_mixup",
    ):
        if not is_finite_number(cfg[key]) or cfg[key] < 0:
            raise InputError(
                f"{key} must be a non-negative number (finite), got {cfg[key]!r}", f"config:{key}"
            )
    low, high = MIXUP_RANGE
    if cfg["aug_mixup"] and not low <= cfg["aug_mixup"] <= high:
        raise InputError(
            f"aug_mixup must be 0 (off) or in [{low:g}, {high:g}] (Beta(a, a) in float32 is wrong outside), "
            f"got {cfg['aug_mixup']!r}",
            "config:aug_mixup",
        )
    if not is_finite_number(cfg["min_lr_ratio"]) or not 0 <= cfg["min_lr_ratio"] <= 1:
        raise InputError(
            f"min_lr_ratio must be a number in [0, 1], got {cfg['min_lr_ratio']!r}", "config:min_lr_ratio"
        )
    betas = cfg["betas"]
    if not (
        isinstance(betas, list) and len(betas) == 2 and all(is_finite_number(b) and 0 <= b < 1 for b in betas)
    ):
        raise InputError(f"betas must be two numbers in [0, 1), got {betas!r}", "config:betas")
