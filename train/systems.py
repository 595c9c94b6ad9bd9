"""The trainable systems by name: Transformer-S2A (and its no-MoE ablation), BLSTM, NVP (3 or 9
frames of context) and ridge regression, built from an ``InputSpec`` and ``arch`` overrides."""

from __future__ import annotations

import difflib
from dataclasses import asdict, fields
from typing import Any

from torch import nn

from capture.errors import InputError

from .config import DEFAULTS
from .data import InputSpec
from .model import BLSTM, NVP, BLSTMConfig, NVPConfig, S2AConfig, TransformerS2A
from .ridge import Ridge

FROM_DATASET = ("content_dim", "prosody_dim", "out_dim")  # sizes the InputSpec gives

ARCH_TABLES = {
    "s2a": S2AConfig,
    "s2a-nomoe": S2AConfig,
    "blstm": BLSTMConfig,
    "nvp3": NVPConfig,
    "nvp9": NVPConfig,
}


# settings a system's name fixes: (system, arch key) -> what to say instead of ignoring the key
FIXED = {
    ("nvp3", "window"): "nvp3's window is fixed at 3 frames: train nvp9 for 9 frames, and drop arch.window",
    ("nvp9", "window"): "nvp9's window is fixed at 9 frames: train nvp3 for 3 frames, and drop arch.window",
    ("s2a", "moe"): "s2a always decodes with the MoE experts: train s2a-nomoe for the dense decoder, "
    "and drop arch.moe",
    ("s2a-nomoe", "moe"): "s2a-nomoe never has MoE experts: train s2a for them, and drop arch.moe",
}


def did_you_mean(word: str, known) -> str:
    """`` (did you mean 'x'?)`` for the known name closest to a mistyped one, else ``""``."""
    close = difflib.get_close_matches(word, sorted(known), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _arch_hint(key: str, known) -> str:
    """The hint for an unknown arch key: a top-level config key (``lr``) written below ``[arch]`` in a
    TOML file, where every key belongs to the table, is said so; else the closest arch key."""
    if key in DEFAULTS:
        return (
            f" ({key!r} is a config key, not a model setting: in a TOML file every key after an [arch] "
            "header belongs to that table, so put it above the first table)"
        )
    return did_you_mean(key, known)


def check_arch(arch: dict[str, Any], where: str = "config:arch") -> None:
    """Refuse ``arch`` keys that no system has and keys of a system's table (``arch.blstm``) that
    system does not have, whichever system is built: a typo shows at once, with the closest key."""
    shared = {k for k, v in arch.items() if not isinstance(v, dict)}
    everywhere = set().union(*({f.name for f in fields(c)} for c in ARCH_TABLES.values()))
    unknown = sorted(shared - everywhere)
    tables = [t for t in arch if isinstance(arch[t], dict)]
    bad = unknown + sorted(set(tables) - set(ARCH_TABLES))
    if bad:
        hint = _arch_hint(bad[0], everywhere if bad[0] in unknown else ARCH_TABLES)
        raise InputError(
            f"unknown arch keys {bad}{hint} (known: {sorted(everywhere)} and tables {sorted(ARCH_TABLES)})",
            where,
        )
    for table in tables:
        known = sorted(f.name for f in fields(ARCH_TABLES[table]))
        if set(arch[table]) - set(known):
            wrong = sorted(set(arch[table]) - set(known))
            raise InputError(
                f"unknown arch keys {wrong} for {table}{_arch_hint(wrong[0], known)} (known: {known})",
                where,
            )


def _config(cls, spec: InputSpec, fixed: dict[str, Any], arch: dict[str, Any], name: str):
    """``arch`` keys apply to every system whose config has them (a key no system has is an error);
    the sub-table ``arch.<name>`` (``arch.s2a`` also for s2a-nomoe) applies to that system only."""
    known = {f.name for f in fields(cls)}
    shared = {k: v for k, v in arch.items() if not isinstance(v, dict)}
    own = dict(arch.get("s2a", {})) if name == "s2a-nomoe" else {}
    own.update(arch.get(name, {}))
    from_data = sorted((set(shared) | set(own)) & set(FROM_DATASET))
    if from_data:
        raise InputError(
            f"arch.{from_data[0]} is set from the dataset (its features and channels), not in the config",
            "config:arch",
        )
    for key, value in fixed.items():  # set by the system's name: a different value would be ignored
        for given in (shared.get(key, value), own.get(key, value)):
            if given != value:
                raise InputError(f"arch.{key} = {given!r}: {FIXED[name, key]}", "config:arch")
    base = {"content_dim": spec.content_dim, "prosody_dim": spec.prosody_dim, "out_dim": spec.out_dim}
    base.update({k: v for k, v in shared.items() if k in known})
    chosen = {**base, **own, **fixed}
    for f in fields(cls):  # sizes the modules would divide by or allocate with
        value = chosen.get(f.name, f.default)
        if f.name == "dropout":
            if not isinstance(value, (int, float)) or not 0 <= value < 1:
                raise InputError(f"arch.dropout must be in [0, 1), got {value!r}", "config:arch")
        elif f.type in ("int", int) and f.name != "prosody_dim":
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise InputError(f"arch.{f.name} must be a positive integer, got {value!r}", "config:arch")
    return cls(**chosen)


def build_model(name: str, spec: InputSpec, cfg: dict[str, Any]) -> tuple[nn.Module, dict[str, Any]]:
    """(module, its config as a dict) for system ``name``; sizes the modules refuse are config errors."""
    try:
        return _build(name, spec, cfg)
    except (ValueError, TypeError, OverflowError) as exc:  # the modules check their own sizes (int(inf))
        raise InputError(f"arch settings for {name}: {exc}", "config:arch") from None


def _build(name: str, spec: InputSpec, cfg: dict[str, Any]) -> tuple[nn.Module, dict[str, Any]]:
    arch = dict(cfg.get("arch", {}))
    check_arch(arch)
    if name in ("s2a", "s2a-nomoe"):
        c = _config(S2AConfig, spec, {"moe": name == "s2a"}, arch, name)
        window = cfg.get("window", 0)
        if window > c.max_frames:
            raise InputError(
                f"window ({window} frames) exceeds arch.max_frames ({c.max_frames})", "config:window"
            )
        return TransformerS2A(c), asdict(c)
    if name == "blstm":
        c = _config(BLSTMConfig, spec, {}, arch, name)
        return BLSTM(c), asdict(c)
    if name in ("nvp3", "nvp9"):
        c = _config(NVPConfig, spec, {"window": int(name[3:])}, arch, name)
        return NVP(c), asdict(c)
    if name == "ridge":
        context = int(cfg["ridge_context"])
        return Ridge(spec.content_dim, spec.prosody_dim, spec.out_dim, context), {"context": context}
    raise InputError(f"unknown model {name!r}", "config:model")


def max_frames(model_config: dict[str, Any] | None) -> int | None:
    """The most frames the model takes in one pass (Transformer-S2A's ``max_frames``), None without one."""
    limit = (model_config or {}).get("max_frames")
    return limit if isinstance(limit, int) and not isinstance(limit, bool) and limit > 0 else None


def check_sample_frames(
    manifest: dict[str, Any],
    splits: tuple[str, ...],
    model_config: dict[str, Any],
    where,
    keys: set[str] | None = None,
) -> None:
    """Whole samples of ``splits`` (validation and evaluation read them unwindowed), or those of the
    sample ``keys`` when given, must fit the model's ``max_frames``."""
    limit = max_frames(model_config)
    chosen = (lambda s: s.get("key") in keys) if keys is not None else (lambda s: s.get("split") in splits)
    frames = [s.get("frames") for s in manifest["samples"] if chosen(s)]
    longest = max((f for f in frames if isinstance(f, int)), default=0)
    if limit is not None and longest > limit:
        raise InputError(
            f"the longest {'/'.join(splits)} sample has {longest} frames, more than max_frames ({limit})",
            where,
        )
