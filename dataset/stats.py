"""``s2a-dataset stats``: hours per speaker and split, phone coverage (with a phone-aware PPG), and
per-channel distributions, from the statistics the build stored in the manifest."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .manifest import dataset_dir, read_manifest
from .splits import SPLITS


def dataset_stats(ds: str | Path) -> dict[str, Any]:
    """Summary of dataset ``ds``: durations in hours, frame counts, per-channel distributions."""
    m = read_manifest(ds)
    stats = m.get("stats", {})
    out: dict[str, Any] = {
        "dataset": str(dataset_dir(ds)),
        "fps": m["fps"],
        "channels": len(m["channels"]),
        "features": m["features"]["names"],
        "ppg": (m["features"].get("ppg") or {}).get("backend"),
        "hours": round(sum(s["duration_s"] for s in m["shards"]) / 3600.0, 6),
        "splits": {},
        "hours_per_speaker": {},
        "phone_coverage": None,
        "channel_distributions": {},
        "warnings": m.get("warnings", []),
    }
    all_phones: dict[str, int] = {}
    for split in SPLITS:
        s = stats.get(split)
        if not s:
            continue
        out["splits"][split] = {
            "takes": s["takes"],
            "samples": s["samples"],
            "hours": round(s["hours"], 6),
            "usable_frames": s["usable_frames"],
            "speakers": len(s["hours_per_speaker"]),
        }
        for spk, h in s["hours_per_speaker"].items():
            out["hours_per_speaker"].setdefault(spk, {})[split] = round(h, 6)
        out["channel_distributions"][split] = {name: _measured(d) for name, d in s["channels"].items()}
        for p, n in s.get("phone_frames", {}).items():
            all_phones[p] = all_phones.get(p, 0) + n
    if all_phones:
        total = sum(all_phones.values())
        covered = sorted(p for p, n in all_phones.items() if n > 0)
        out["phone_coverage"] = {
            "phones": len(all_phones),
            "covered": len(covered),
            "missing": sorted(p for p, n in all_phones.items() if n == 0),
            "frames": {p: n for p, n in sorted(all_phones.items(), key=lambda kv: -kv[1])},
            "share": {p: round(n / total, 6) for p, n in all_phones.items()} if total else {},
        }
    return out


def _measured(d: dict[str, Any]) -> dict[str, Any]:
    """A channel's distribution, its statistics null when no frame was measured (a split whose takes
    lost the face throughout: older builds stored 0 there, which reads as a still channel)."""
    if d.get("frames") == 0:
        return {k: (v if k == "frames" else None) for k, v in d.items()}
    return dict(d)


def _num(v: Any) -> str:
    return f"{v:7.3f}" if isinstance(v, (int, float)) else f"{'-':>7s}"


def format_stats(s: dict[str, Any]) -> str:
    """A short human-readable table of ``dataset_stats``."""
    lines = [
        f"{s['dataset']}: {s['hours'] * 60:.2f} min, {s['channels']} channels at {s['fps']} fps, "
        f"features {', '.join(s['features'])}"
    ]
    for split, v in s["splits"].items():
        lines.append(
            f"  {split:5s} {v['hours'] * 60:8.2f} min  {v['takes']:4d} takes  {v['samples']:5d} samples  "
            f"{v['speakers']:3d} speakers"
        )
    lines.append("  minutes per speaker:")
    for spk, per in s["hours_per_speaker"].items():
        lines.append("    " + spk + ": " + ", ".join(f"{k} {h * 60:.2f}" for k, h in per.items()))
    cov = s.get("phone_coverage")
    if cov:
        lines.append(
            f"  phones covered: {cov['covered']}/{cov['phones']}"
            + (f" (missing {' '.join(cov['missing'])})" if cov["missing"] else "")
        )
    train = s["channel_distributions"].get("train", {})
    if train:
        lines.append("  train channel distributions (mean / std / p05 / p95 / max):")
        for name, d in train.items():
            values = " ".join(_num(d.get(k)) for k in ("mean", "std", "p05", "p95", "max"))
            lines.append(f"    {name:22s} {values}")
    for w in s["warnings"]:
        lines.append(f"  warning: {w}")
    return "\n".join(lines)
