"""Training on simulated speech: throughput (frames per second) and the time to reach a validation RMSE
target, Transformer-S2A against BLSTM trained on the same data with the same batches and budget.

Data: simulated speakers (``s2a-capture simulate`` → import → ``s2a-align``), built into a dataset with
pitch, energy and filter banks (split by take). Both systems use ``benchmarks/configs/simulated.toml``
(the settings of ``make results``) with filter-bank input. The validation RMSE is that of the training
loop's validation score: with ``loss_weights = "raw"`` the validation MSE is the raw squared error
divided by the mean squared normalisation scale, so RMSE × 100 = 100 · sqrt(val_mse · mean(scale²)),
pooled over the validation split's frames and channels. The target is a fraction of the validation
split's train-mean floor on the same scale (from the manifest's statistics)."""

from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.bench_dataset import simulated_aligned_takes
from benchmarks.figure import Figure

CONFIG = Path(__file__).resolve().parent / "configs" / "simulated.toml"
TARGET = 0.8  # of the validation floor


def val_floor(manifest: dict) -> float:
    """RMSE × 100 over the val split of predicting the training mean, pooled over frames and channels."""
    train, val = manifest["stats"]["train"]["channels"], manifest["stats"]["val"]["channels"]
    sq = [val[c]["std"] ** 2 + (val[c]["mean"] - train[c]["mean"]) ** 2 for c in manifest["channels"]]
    return 100.0 * math.sqrt(float(np.mean(sq)))


def trained(ds: Path, run: Path, model: str, steps: int) -> tuple[float, list[tuple[float, float]], float]:
    """(mean training frames per second, [(seconds, val RMSE × 100)], seconds of the whole fit)."""
    from dataset.manifest import read_manifest
    from train.config import resolve_config
    from train.fit import fit

    cfg = resolve_config(CONFIG, ["input=fbank", f"max_steps={steps}", "eval_every=25", "log_every=25"])
    cfg["model"] = model
    summary = fit(ds, run, cfg, say=lambda _m: None)
    scale2 = float(np.mean(np.square(read_manifest(ds)["normalization"]["animation"]["scale"])))
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    fps = [r["frames_per_s"] for r in rows if "frames_per_s" in r][1:]  # the first window includes start-up
    curve = [(r["time_s"], 100.0 * math.sqrt(r["val_mse"] * scale2)) for r in rows if "val_mse" in r]
    return float(np.mean(fps)), curve, summary["session_s"]


def time_to(curve: list[tuple[float, float]], target: float) -> float | None:
    return next((t for t, rmse in curve if rmse <= target), None)


def run(quick: bool = False) -> list[Figure]:
    import torch

    from dataset import BuildOptions, SplitRule, build_dataset, read_manifest

    torch.set_num_threads(2)
    takes, seconds, steps = (8, 12.0, 60) if quick else (12, 20.0, 200)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        aligned, _origin = simulated_aligned_takes(tmp / "takes", takes, seconds)
        options = BuildOptions(features=("pitch", "energy", "fbank"), split=SplitRule("take", 0.15, 0.15, 0))
        build_dataset([aligned], tmp / "ds", options)
        floor = val_floor(read_manifest(tmp / "ds"))
        target = TARGET * floor
        results = {m: trained(tmp / "ds", tmp / m, m, steps) for m in ("s2a", "blstm")}
    (s2a_fps, s2a_curve, s2a_s), (blstm_fps, blstm_curve, blstm_s) = results["s2a"], results["blstm"]
    note = f"{takes} simulated takes of {seconds:g} s, {steps} steps, batch 8 x 240 frames, 2 threads"
    figures = [
        Figure("S2A training throughput", s2a_fps, "frames/s", "BLSTM", blstm_fps, True, None, note),
    ]
    reached = {m: time_to(c, target) for m, c in (("s2a", s2a_curve), ("blstm", blstm_curve))}
    best = {m: min(r for _t, r in c) for m, c in (("s2a", s2a_curve), ("blstm", blstm_curve))}
    goal = f"val RMSE x100 <= {target:.2f} ({TARGET:g} x the val floor {floor:.2f})"
    if reached["s2a"] is not None and reached["blstm"] is not None:
        figures.append(
            Figure("S2A time to " + goal, reached["s2a"], "s", "BLSTM", reached["blstm"], False, None, note)
        )
    else:
        missed = ", ".join(m for m, t in reached.items() if t is None)
        figures.append(
            Figure(
                f"S2A best val RMSE x100 ({goal} not reached by {missed})",
                best["s2a"],
                "",
                "BLSTM",
                best["blstm"],
                False,
                None,
                note,
            )
        )
    figures.append(
        Figure("S2A best val RMSE x100 vs the val floor", best["s2a"], "", "floor", floor, False, None, note)
    )
    figures.append(Figure("S2A fit wall time", s2a_s, "s", "BLSTM", blstm_s, False, None, note))
    return figures
