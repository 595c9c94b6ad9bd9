"""Cross-validation ensembles (``cv_folds = K``): the small-data protocol without a chosen val take.

The takes of the dataset's train and val splits are dealt into K folds of about equal duration (longest
take first, each to the fold with the least audio so far; ties by take id). Member ``i`` trains on every
other fold and validates on fold ``i``: its early stopping and ``best.pt`` follow takes it never trained
on, and every take validates exactly once, so nothing has to be chosen by looking at the test takes.
The ensemble predicts the mean of its members' outputs (their best checkpoints), which also averages
away much of the variance a network trained on minutes of speech has.

Run folder: ``RUN/config.json`` (the ensemble's config), ``RUN/fold-<i>/`` (ordinary run folders, each
config naming its ``val_takes``) and ``RUN/ensemble.json`` (members and their takes, written once every
member has finished). ``s2a-train eval``, ``predict`` and ``export`` take the ensemble's run folder like
any other; the cross-validation score (``cv_score``) is the mean of the members' best validation losses.
"""

from __future__ import annotations

from collections.abc import Callable, Collection
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch
from torch import nn

from capture.errors import InputError, loads_names
from dataset.manifest import take_recordings

from .checkpoint import CONFIG, LAST, read_run_config, refuse_other_world, write_json
from .data import InputSpec
from .style import member_style_map

ENSEMBLE = "ensemble.json"


def fold_takes(manifest: dict[str, Any], folds: int, dropped: Collection[str] = ()) -> list[list[str]]:
    """The train and val takes, less ``dropped`` (and the other segments of their recordings), dealt
    into ``folds`` groups of about equal duration, a recording at a time: the segments align cut from
    one recording validate together, never against each other."""
    recording_of = take_recordings(manifest)
    gone = {recording_of.get(t, t) for t in dropped}
    duration: dict[str, float] = {}
    members: dict[str, set[str]] = {}
    for s in manifest["samples"]:
        recording = recording_of.get(s["take"], s["take"])
        if s["split"] in ("train", "val") and recording not in gone:
            duration[recording] = duration.get(recording, 0.0) + float(s["duration_s"])
            members.setdefault(recording, set()).add(s["take"])
    if folds < 2:
        raise InputError(f"cv_folds must be 0 (off) or at least 2, got {folds}", "config:cv_folds")
    if len(duration) < folds:
        raise InputError(
            f"cv_folds = {folds} needs as many train/val recordings; the dataset has {len(duration)}",
            "config:cv_folds",
        )
    groups: list[list[str]] = [[] for _ in range(folds)]
    load = [0.0] * folds
    for recording in sorted(duration, key=lambda r: (-duration[r], r)):
        i = min(range(folds), key=lambda j: (load[j], j))
        groups[i] += members[recording]
        load[i] += duration[recording]
    return [sorted(g) for g in groups]


def member_dir(run: Path, i: int) -> Path:
    return run / f"fold-{i + 1}"


def has_members(run: Path) -> bool:
    """Whether an ensemble run folder holds any member checkpoint (so that it can be resumed)."""
    return any((p / LAST).is_file() for p in run.glob("fold-*"))


def refuse_beside_ensemble(run: Path, resume: bool) -> None:
    """Refuse a fit without ``--resume`` into a folder holding a cross-validation ensemble (its
    ensemble.json, or a member checkpoint), whatever the fit's own config."""
    if not resume and ((run / ENSEMBLE).exists() or has_members(run)):
        raise InputError(
            "run folder already holds an ensemble (ensemble.json, fold-*): use --resume or another -o", run
        )


class Ensemble(nn.Module):
    """The mean of several models' outputs (same inputs, same output channels). With ``style_maps``
    (members trained on different speakers), the last columns of the prosody input are a style over
    the union of the members' speakers, taken to each member's own by its map (train/style.py)."""

    def __init__(self, members: list[nn.Module], style_maps: list[torch.Tensor] | None = None):
        super().__init__()
        self.members = nn.ModuleList(members)
        self.n_styles = 0 if style_maps is None else style_maps[0].shape[0]
        for i, m in enumerate(style_maps or []):
            self.register_buffer(f"style_map_{i}", m)

    def _member_prosody(self, prosody: torch.Tensor | None, i: int) -> torch.Tensor | None:
        if not self.n_styles or prosody is None:
            return prosody
        own = prosody[..., -self.n_styles :] @ getattr(self, f"style_map_{i}").to(prosody)
        return torch.cat([prosody[..., : -self.n_styles], own], dim=-1)

    def forward(self, content: torch.Tensor, prosody: torch.Tensor | None, mask: torch.Tensor):
        total = self.members[0](content, self._member_prosody(prosody, 0), mask)
        for i, m in enumerate(self.members[1:], 1):
            total = total + m(content, self._member_prosody(prosody, i), mask)
        return total / len(self.members)


def check_ensemble_run(
    manifest: dict[str, Any], run: Path, cfg: dict[str, Any], resume: bool, *, world: int
) -> list[list[str]]:
    """The folds' takes; refuses a dataset or run folder an ensemble cannot use, before anything is
    written (the config itself is checked by ``train.config.check_config``): ``world`` processes resume
    only members trained with as many."""
    if (run / LAST).exists():  # a single run's folder (its resume keeps cv_folds 0)
        raise InputError(
            f"run folder already holds a single run ({LAST}), not an ensemble: train the ensemble into "
            "another -o",
            run,
        )
    refuse_beside_ensemble(run, resume)
    if resume and not has_members(run):
        raise InputError(f"nothing to resume: no fold-*/{LAST}", run)
    for member in sorted(run.glob("fold-*")) if resume else ():
        if not (member / LAST).is_file():
            continue  # trained afresh on resume, under any number of processes
        try:
            trained = read_run_config(member / CONFIG).get("world_size", 1)
        except InputError:
            continue  # the member's own resume names what is wrong with it
        refuse_other_world(trained, world, "ensemble", member / CONFIG)
    return fold_takes(manifest, cfg["cv_folds"], cfg["drop_takes"])


def fit_ensemble(
    fit_member: Callable[[Path, dict[str, Any], bool], dict[str, Any]],
    folds: list[list[str]],
    run: Path,
    cfg: dict[str, Any],
    resume: bool,
    main: bool,
    say: Callable[[str], None],
) -> dict[str, Any]:
    """Train (or resume) one member per fold with ``fit_member(folder, config, resume)``, then write
    ``ensemble.json``; returns the ensemble's summary."""
    members = []
    for i, takes in enumerate(folds):
        folder = member_dir(run, i)
        say(f"fold {i + 1}/{len(folds)}: validating on {', '.join(takes)}")
        member_cfg = {**cfg, "cv_folds": 0, "val_takes": takes}
        summary = fit_member(folder, member_cfg, resume and (folder / LAST).is_file())
        members.append({"folder": folder.name, "val_takes": takes, **_member_summary(summary)})
    scores = [m["best_val"] for m in members if m["best_val"] is not None]
    cv_score = sum(scores) / len(scores) if len(scores) == len(members) else None
    if main:
        write_json(run / ENSEMBLE, {"members": members, "cv_score": cv_score})
    return {
        "steps": sum(m["steps"] for m in members),
        "best_val": cv_score,
        "cv_score": cv_score,
        "stopped": "cv_folds",
        "members": members,
    }


def _member_summary(s: dict[str, Any]) -> dict[str, Any]:
    keys = ("steps", "best_val", "stopped", "params_checksums", "ranks_in_sync", "parameters")
    return {k: s.get(k) for k in keys}


def load_ensemble(run: Path, load_member: Callable[[Path], tuple[nn.Module, dict[str, Any]]]):
    """(Ensemble in eval mode, payload of the first member with ``ensemble`` added) of a finished
    ensemble run folder."""
    try:
        record = loads_names((run / ENSEMBLE).read_text())
        folders = [run / m["folder"] for m in record["members"]]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"unreadable ensemble record ({type(exc).__name__})", run / ENSEMBLE) from None
    loaded = [load_member(f) for f in folders]
    first = loaded[0][1]
    specs = [InputSpec.from_json(p["inputs"]) for _m, p in loaded]
    union = tuple(sorted({s for spec in specs for s in spec.styles}))
    for folder, (_m, p), spec in zip(folders, loaded, specs):
        if replace(spec, styles=(), prosody_dim=0) != replace(specs[0], styles=(), prosody_dim=0):
            raise InputError("ensemble members differ in inputs", folder)
        if p["dataset"]["channels"] != first["dataset"]["channels"]:
            raise InputError("ensemble members differ in channels", folder)
        if bool(spec.styles) != bool(union):
            raise InputError("ensemble members differ in speaker styles", folder)
    maps = [member_style_map(union, spec.styles) for spec in specs] if union else None
    inputs = replace(
        specs[0], styles=union, prosody_dim=specs[0].prosody_dim - len(specs[0].styles) + len(union)
    )
    payload = {
        **first,
        "inputs": inputs.to_json(),
        "step": sum(p["step"] for _m, p in loaded),
        "ensemble": record,
    }
    return Ensemble([m for m, _p in loaded], maps).eval(), payload
