"""Several systems on one dataset: train each, evaluate each, and tabulate like the paper's Table 1
(RMSE entire / crucial, paper scale, with the train-mean floor) and Table 2 (RTF, speed-up vs BLSTM)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from capture.command import progress
from capture.errors import InputError
from dataset.manifest import dataset_folder, read_manifest
from dataset.torch_dataset import check_shards

from .checkpoint import LAST, write_json
from .ensemble import has_members
from .evaluate import evaluate
from .fit import check_outside_dataset, check_resumable, checked_model, fit


def compare(
    ds: str | Path,
    out: str | Path,
    models: list[str],
    config_for: Callable[[str], dict[str, Any]],
    split: str = "test",
    say: Callable[[str], None] = progress,
    given_for: Callable[[str], dict[str, Any]] | None = None,
) -> list[dict[str, Any]]:
    """Train (or resume) ``out/<model>`` for each model and evaluate it; one row per system. A system
    that fails while training or evaluating (it diverges, meets a damaged sample) gets a row holding its
    ``error`` and the others go on, so that ``compare.json`` keeps every result computed: one failing
    system used to stop the command before ``compare.json`` was written, losing the rows of the systems
    already trained and evaluated.

    ``given_for(model)``: the config keys the user set (command line); a run that already exists is
    resumed with its own config and limits, and a given key whose value differs from the run's is
    refused, as ``fit --resume`` refuses it (``max_steps`` and ``max_minutes`` may change). Without
    ``given_for`` (a call from code), ``config_for``'s limits apply to the resumed runs."""
    out = Path(out)
    ds = dataset_folder(ds)  # the folder, or its manifest.json
    repeated = sorted({name for name in models if models.count(name) > 1})
    if repeated:  # trained once, tabulated twice: never what was meant
        raise InputError(f"--models names {', '.join(repeated)} more than once: give each system once")
    if out.exists() and not out.is_dir():
        raise InputError("output folder path is a file: give a folder with -o", out)
    check_outside_dataset(out, ds, "output folder")
    manifest = read_manifest(ds)
    if split not in {s["split"] for s in manifest["shards"]}:  # before hours of training, not after
        raise InputError(f"dataset has no {split!r} split to compare on", ds / "manifest.json")
    # training reads train and val, evaluation then the split compared on
    check_shards(ds, manifest, tuple(dict.fromkeys(("train", "val", split))))
    for name in models:  # every system's settings checked before the first one trains
        cfg = config_for(name)
        checked_model(name, manifest, cfg)
        run = out / name
        if given_for is not None and _resumable(run):
            check_resumable(run, given_for(name), f"compare resumes {run}, which")
    rows = []
    for name in models:
        run = out / name
        say(f"compare: {name}")
        resumable = _resumable(run)
        if resumable:
            say(f"compare: {run} exists: resuming it with its own config")
        given = given_for(name) if given_for is not None else None
        try:
            summary = fit(
                ds, run, config_for(name), resume=resumable, say=say, given=given, shards_checked=True
            )
            r = evaluate(run, ds, split, say=say)
        except InputError as exc:
            say(f"compare: {name} failed: {exc}")
            rows.append({"model": name, "error": str(exc)})
            continue
        rows.append(
            {
                "model": name,
                "steps": summary["steps"],
                "rmse_entire": r["rmse_entire"],
                "rmse_crucial": r["rmse_crucial"],
                "floor": {
                    "rmse_entire": r["floor"]["rmse_entire"],
                    "rmse_crucial": r["floor"]["rmse_crucial"],
                },
                "rtf": r.get("rtf"),
                "device": r["device"],
                **({"style": r["style"]} if "style" in r else {}),
            }
        )
    blstm = next((r["rtf"] for r in rows if r["model"] == "blstm" and r.get("rtf")), None)
    for r in rows:
        if "error" not in r:
            r["speedup_vs_blstm"] = blstm / r["rtf"] if blstm and r["rtf"] else None
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "compare.json", rows)  # names not UTF-8 kept by write_json
    return rows


def _resumable(run: Path) -> bool:
    return (run / LAST).is_file() or has_members(run)


def _ms(v: dict[str, float] | None) -> str:
    return "n/a" if v is None else f"{v['mean']:.3f} ± {v['std']:.3f}"


def format_tables(rows: list[dict[str, Any]]) -> str:
    """Table 1 (RMSE ×100 of de-normalised coefficients) and Table 2 (RTF)."""
    lines = [
        "Table 1: RMSE (paper scale, mean ± std over utterances)",
        f"{'system':<12} {'entire':>17} {'crucial':>17}",
    ]
    scored = [r for r in rows if "error" not in r]
    for r in rows:
        if "error" in r:
            lines.append(f"{r['model']:<12} {'failed':>17} {'failed':>17}")
        else:
            lines.append(f"{r['model']:<12} {_ms(r['rmse_entire']):>17} {_ms(r['rmse_crucial']):>17}")
    if scored:
        f = scored[0]["floor"]
        lines.append(f"{'train mean':<12} {_ms(f['rmse_entire']):>17} {_ms(f['rmse_crucial']):>17}")
        lines += [
            "",
            f"Table 2: real-time factor ({scored[0]['device']})",
            f"{'system':<12} {'RTF':>10} {'speed-up':>9}",
        ]
    for r in scored:
        rtf = f"{r['rtf']:.5f}" if r["rtf"] is not None else "n/a"
        sp = f"{r['speedup_vs_blstm']:.2f}x" if r["speedup_vs_blstm"] else "n/a"
        lines.append(f"{r['model']:<12} {rtf:>10} {sp:>9}")
    return "\n".join(lines)
