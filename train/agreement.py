"""Cross-take agreement (``s2a-train agreement``): how well the takes of a dataset predict each other.

A take whose animation was labelled differently from the rest (another animator's style, a rig mapped
differently, a tracking fault) is predicted badly by a model of the other takes, however good the
model. The ridge regression of the model table (train/ridge.py, closed form, seconds) measures this:

- **leave one take out**: for each take, a ridge fitted on every other take, scored on it;
- **take by take** (up to ``MATRIX_TAKES`` takes): a ridge fitted on each single take, scored on
  every take (the diagonal is the take's fit to itself, an optimistic bound).

Scores are RMSE of de-normalised coefficients × 100 (the paper's scale, pooled over the take's usable
values: a glitch in one channel leaves the frame's others) and their ratio to the floor of the same fit
(its training takes' mean): near 1, the other takes tell nothing about this one. The normal equations
of each take are summed once; leaving a take out subtracts its sums from the total. Only the train and
val splits by default: scoring the test takes too is for studying a dataset, not for choosing a model.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch

from capture.command import progress
from capture.errors import InputError
from dataset.manifest import dataset_folder, read_manifest, take_recordings

from .data import present_frames, resolve_inputs, to_model_inputs, utterances
from .ridge import Memory, NormalEquations, Ridge

MATRIX_TAKES = 30  # the take-by-take table is takes² scores: skipped above this many takes
DEFAULT_ALPHA = 0.1  # ridge_alpha 0 means "choose on val" in fit; here there is no val to choose on


def _items(ds: Path, splits: tuple[str, ...], spec, take_of: dict[str, str]) -> Iterator[tuple[str, dict]]:
    for split in splits:
        for item in utterances(ds, split, spec, values=True):
            yield take_of[item["key"]], item


def _take_of_samples(manifest: dict[str, Any]) -> dict[str, str]:
    """``{sample key: the take it counts in}``: the segments align cut from one recording count as one
    take, left out together and named by the recording (a recording of one sampled take keeps the
    take's name)."""
    recording_of = take_recordings(manifest)
    parts: dict[str, set[str]] = {}
    for sample in manifest["samples"]:
        parts.setdefault(recording_of.get(sample["take"], sample["take"]), set()).add(sample["take"])
    name = {rec: next(iter(takes)) if len(takes) == 1 else rec for rec, takes in parts.items()}
    return {s["key"]: name[recording_of.get(s["take"], s["take"])] for s in manifest["samples"]}


def take_agreement(
    ds: str | Path,
    cfg: dict[str, Any],
    splits: tuple[str, ...] = ("train", "val"),
    say: Callable[[str], None] = progress,
    memory: Memory | None = None,
) -> dict[str, Any]:
    """Leave-one-take-out and take-by-take ridge scores of ``ds`` (see module doc); ``cfg`` gives the
    inputs (``input``, ``prosody``) and the ridge's ``ridge_context`` and ``ridge_alpha``. The sums of
    every take are held at once, in ``memory`` (default: the machine's): past it, an ``InputError``
    before reading (a set per take, their total and a take left out) or on finding a glitched channel."""
    ds = dataset_folder(ds)
    manifest = read_manifest(ds)
    where = ds / "manifest.json"
    present = {s["split"] for s in manifest["shards"]}
    unknown = [s for s in splits if s not in ("train", "val", "test")]
    if unknown:
        raise InputError(f"unknown split(s) {', '.join(unknown)}: choose from train, val, test", where)
    asked = tuple(dict.fromkeys(splits))  # a split named twice is read once (its takes counted once)
    splits = tuple(s for s in asked if s in present)
    # a take left out is a speaker the fit never saw: style columns would only add unfitted weights
    if cfg.get("speaker_style"):
        say("note: agreement ignores speaker_style (a take left out is a speaker its fit never saw)")
    spec = resolve_inputs(manifest, {**cfg, "speaker_style": False}, str(where))
    take_of = _take_of_samples(manifest)
    alpha = float(cfg["ridge_alpha"]) or DEFAULT_ALPHA
    model = Ridge(spec.content_dim, spec.prosody_dim, spec.out_dim, cfg["ridge_context"])
    n_in = model.linear.in_features
    memory = Memory() if memory is None else memory
    read = {take_of[s["key"]] for s in manifest["samples"] if s["split"] in splits}
    what = (
        "agreement's sums of {} takes ({} channels glitched in some frames), their total and a take left out"
    )
    memory.check(n_in, len(read) + 2, what.format(len(read), 0))

    sums: dict[str, NormalEquations] = {}
    for take, item in _items(ds, splits, spec, take_of):
        content, prosody = to_model_inputs(item, spec)
        if take not in sums:
            sums[take] = NormalEquations(n_in, spec.out_dim, memory)
        sums[take].add(model.inputs(content, prosody, present_frames(item)), item["anim"], item["values"])
    takes = sorted(t for t, eq in sums.items() if eq.n > 0)
    if len(takes) < 2:
        lacking = [s for s in asked if s not in present]
        lacks = f" (the dataset has no {' or '.join(lacking)} split)" if lacking else ""
        raise InputError(
            f"agreement needs at least 2 takes with usable frames in {', '.join(asked)}{lacks}", where
        )
    say(f"agreement: {len(takes)} takes, {sum(sums[t].n for t in takes)} frames")
    glitched = len({c for t in takes for c in sums[t].gaps})
    memory.check(n_in, 2 * (1 + glitched), what.format(len(sums), glitched))
    total = NormalEquations.total([sums[t] for t in takes])

    def fitted(eq: NormalEquations) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(weight, bias, training mean) of the ridge solved on ``eq``."""
        eq.solve(model, alpha)
        mean = eq.means().float()
        return model.linear.weight.detach().clone(), model.linear.bias.detach().clone(), mean

    loto = {t: fitted(total.minus(sums[t])) for t in takes}
    single = {t: fitted(sums[t]) for t in takes} if len(takes) <= MATRIX_TAKES else {}
    scale = torch.as_tensor(np.asarray(manifest["normalization"]["animation"]["scale"], np.float32))
    # squared errors (coefficient units) per (fit, scored take), of the fit and of its floor, over the
    # usable values of the frames usable in some channel
    se: dict[tuple[str, str], list[float]] = {}
    frames: dict[str, int] = {}
    values: dict[str, int] = {}
    for take, item in _items(ds, splits, spec, take_of):
        if take not in loto:
            continue
        content, prosody = to_model_inputs(item, spec)
        usable = item["values"][0]
        rows = usable.any(dim=1)
        x = model.inputs(content, prosody, present_frames(item))[0][rows]
        y, usable = item["anim"][0][rows], usable[rows].float()
        frames[take] = frames.get(take, 0) + int(rows.sum())
        values[take] = values.get(take, 0) + int(usable.sum())
        fits = {("loo", take): loto[take], **{("single", t): f for t, f in single.items()}}
        for (kind, source), (w, b, mean) in fits.items():
            err = float(((((x @ w.T + b) - y) * scale).square() * usable).sum())
            floor = float((((mean - y) * scale).square() * usable).sum())
            acc = se.setdefault((f"{kind}:{source}", take), [0.0, 0.0])
            acc[0] += err
            acc[1] += floor

    def score(key: str, take: str) -> dict[str, float]:
        err, floor = se[(key, take)]
        n = max(values[take], 1)
        rmse, floor_rmse = 100.0 * (err / n) ** 0.5, 100.0 * (floor / n) ** 0.5
        return {"rmse": rmse, "floor": floor_rmse, "ratio": rmse / floor_rmse if floor_rmse else float("nan")}

    return {
        "dataset": str(ds),
        "splits": list(splits),
        "input": spec.content,
        "prosody": list(spec.prosody),
        "context": cfg["ridge_context"],
        "alpha": alpha,
        "takes": takes,
        "frames": frames,
        "leave_one_out": {t: score(f"loo:{t}", t) for t in takes},
        "matrix": {s: {t: score(f"single:{s}", t)["ratio"] for t in takes} for s in single} or None,
    }


def format_agreement(r: dict[str, Any]) -> str:
    """Leave-one-take-out scores, the least agreeing take first, then the take-by-take table."""
    loo = r["leave_one_out"]
    inputs = " + ".join([r["input"], *r["prosody"]])
    lines = [
        f"{r['dataset']}: {len(r['takes'])} takes of {', '.join(r['splits'])}; ridge on {inputs}, "
        f"±{r['context']} frames, alpha {r['alpha']:g}",
        "leave one take out (RMSE x 100 of a ridge fitted on the other takes; ratio to their mean):",
    ]
    width = max(len(t) for t in r["takes"])
    for t in sorted(loo, key=lambda t: -loo[t]["ratio"]):
        s = loo[t]
        lines.append(f"  {t:{width}s}  {s['rmse']:7.3f}  floor {s['floor']:7.3f}  ratio {s['ratio']:.3f}")
    if r["matrix"]:
        lines.append("fitted on one take (rows) and scored on each take (columns), ratio to the floor:")
        common = len(os.path.commonprefix(r["takes"]))
        short = [t[common:][-8:] or t[-8:] for t in r["takes"]]
        lines.append(" " * (width + 2) + " ".join(f"{s:>8s}" for s in short))
        for src in r["takes"]:
            row = r["matrix"][src]
            lines.append(f"  {src:{width}s}" + " ".join(f"{row[t]:8.2f}" for t in r["takes"]))
    else:
        lines.append(f"(take-by-take table left out: more than {MATRIX_TAKES} takes)")
    return "\n".join(lines)
