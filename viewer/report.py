"""``s2a-view report``: one self-contained HTML page per dataset (or folder of takes).

The page holds the statistics of ``s2a-dataset stats``, the align report of every take (offset,
where it came from, confidence, drift, flags), a thumbnail of each take's mouth curves and the
outliers, with the reason each was flagged. Everything is inline (CSS, a few lines of script to sort
the tables, thumbnails as base64 PNG): no external URL, so it opens anywhere, offline.

Dataset mode reads the manifest through the dataset stage's API (``read_manifest``,
``dataset_stats``) and the curves from the shards themselves; an aligned take folder named in the
manifest's sources (or found under ``--takes``) supplies its align report. Take mode (a folder
without ``manifest.json``) reports over the take folders found in it, aligned or not.
"""

from __future__ import annotations

import base64
import html
import io
import math
from pathlib import Path
from typing import Any

import numpy as np

from capture import InputError, find_sources, find_takes, read_meta, read_take
from capture.atomic import atomic_write
from capture.channels import canonical, is_known
from capture.errors import loads_names, printable, shown_against
from capture.take import FrameStatus

from .output import writing

THUMB_CHANNELS = ("jawOpen", "mouthClose", "mouthFunnel")
MIN_CONFIDENCE = 0.5  # align offset confidence below this is flagged
MAX_OFFSET_S = 0.25  # |audio-face offset| above this is flagged
MIN_USABLE = 0.9  # share of usable frames below this is flagged
ROBUST_Z = 3.5  # per-take channel level this many robust deviations from the median is flagged
MIN_LEVEL_GAP = (
    0.05  # ... and at least this far from it in weight units (near-identical takes have tiny MADs)
)

CSS = """
body{font:14px/1.45 system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:24px;color:#1d2127;
  background:#fafbfc}
h1{font-size:22px;margin:0 0 4px}h2{font-size:17px;margin:28px 0 8px;border-bottom:1px solid #d8dde3}
.muted{color:#667}.cards{display:flex;flex-wrap:wrap;gap:12px;margin:12px 0}
.card{background:#fff;border:1px solid #d8dde3;border-radius:6px;padding:8px 14px;min-width:110px}
.card b{display:block;font-size:20px}
table{border-collapse:collapse;background:#fff;margin:6px 0}
th,td{border:1px solid #d8dde3;padding:3px 8px;text-align:right;vertical-align:middle}
th{background:#eef1f4;cursor:pointer;user-select:none}td.l,th.l{text-align:left}
tr.flag td{background:#fff4e5}.warn{color:#a15c00}.bad{color:#b00020}
img.thumb{display:block;height:54px}
"""

SCRIPT = """
document.querySelectorAll('table.sortable').forEach(function (t) {
  t.querySelectorAll('th').forEach(function (th, i) {
    th.addEventListener('click', function () {
      var rows = Array.from(t.tBodies[0].rows), asc = th.dataset.asc !== '1';
      rows.sort(function (a, b) {
        var x = a.cells[i].dataset.v || a.cells[i].textContent;
        var y = b.cells[i].dataset.v || b.cells[i].textContent;
        var nx = parseFloat(x), ny = parseFloat(y);
        var c = (isNaN(nx) || isNaN(ny)) ? x.localeCompare(y) : nx - ny;
        return asc ? c : -c;
      });
      th.dataset.asc = asc ? '1' : '0';
      rows.forEach(function (r) { t.tBodies[0].appendChild(r); });
    });
  });
});
document.body.dataset.ready = '1';
"""


def _thumb(curves: dict[str, np.ndarray], fps: float) -> str:
    """A small PNG of the curves as a data URI."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(3.2, 0.6), dpi=90)
    for name, y in curves.items():
        ax.plot(np.arange(y.size) / fps, y, lw=0.8, label=name)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_ylim(-0.02, max(0.3, float(np.nanmax([np.nanmax(v) for v in curves.values()] + [0])) * 1.05))
    for s in ax.spines.values():
        s.set_visible(False)
    fig.subplots_adjust(0, 0, 1, 1)
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _legend_thumb() -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    return " ".join(
        f'<span style="color:{colors[i]}">&#9644; {html.escape(n)}</span>'
        for i, n in enumerate(THUMB_CHANNELS)
    )


def _fmt(v: Any, digits: int = 3) -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        if not math.isfinite(v):
            return "–"
        return f"{v:.{digits}f}"
    return html.escape(str(v))


def _cell(v: Any, digits: int = 3, cls: str = "") -> str:
    sort = f' data-v="{v}"' if isinstance(v, (int, float)) and v is not None else ""
    c = f' class="{cls}"' if cls else ""
    return f"<td{c}{sort}>{_fmt(v, digits)}</td>"


def _table(headers: list[str], rows: list[str], sortable: bool = True) -> str:
    head = "".join(
        f'<th class="l">{html.escape(h)}</th>' if i == 0 else f"<th>{html.escape(h)}</th>"
        for i, h in enumerate(headers)
    )
    cls = ' class="sortable"' if sortable else ""
    return f"<table{cls}><thead><tr>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table>"


# -- gathering what the report shows ---------------------------------------------------------------
def _take_entry(folder: Path, curves: bool = True) -> dict[str, Any]:
    """Figures, align report and (with ``curves``) the thumbnail curves of one take folder."""
    take = read_take(folder, audio=False)
    ok = (take.frame_status == FrameStatus.TRACKED) | (take.frame_status == 4)
    entry: dict[str, Any] = {
        "take": take.meta.id,
        "path": str(folder),
        "speaker": take.meta.subject,
        "split": None,
        "fps": take.meta.fps,
        "duration_s": take.duration_s,
        "frames": int(take.time.size),
        "usable": float(ok.mean()) if take.time.size else 0.0,
        "align": take.meta.extra.get("align"),
        "source_kind": take.meta.source_kind,
    }
    found = _curves(take.values, take.meta.channels, ok)
    entry["p95"] = _levels(found)
    entry["curves"] = found if curves else {}
    return entry


def _levels(curves: dict[str, np.ndarray]) -> dict[str, float | None]:
    """Each thumbnail channel's 95th percentile over the usable frames (what ``_outliers`` compares)."""
    return {
        n: float(np.nanpercentile(y, 95))
        if (y := curves.get(n)) is not None and np.isfinite(y).any()
        else None
        for n in THUMB_CHANNELS
    }


def _curves(values: np.ndarray, channels: list[str], ok: np.ndarray | None = None) -> dict[str, np.ndarray]:
    index = {canonical(c): j for j, c in enumerate(channels) if is_known(c)}
    out = {}
    for name in THUMB_CHANNELS:
        if name in index:
            y = values[:, index[name]].astype(np.float64)
            if ok is not None:
                y = np.where(ok, y, np.nan)
            out[name] = y
    return out


def _dataset_curves(
    ds: Path, manifest: dict[str, Any], limit: int
) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, dict[str, float | None]]]:
    """Per take, concatenated over its samples from the shards: the thumbnail curves of the first
    ``limit`` takes by id, and the levels (``_levels``) of every take."""
    from dataset import ShardReader

    channels = manifest["channels"]
    thumbs = set(sorted({s["take"] for s in manifest["samples"]})[:limit])
    chunks: dict[str, list[tuple[str, dict[str, np.ndarray]]]] = {}
    for shard in manifest["shards"]:
        for key, members in ShardReader(ds / shard["name"], ("json", "anim.npy", "mask.npy")):  # no audio
            info = loads_names(members["json"])
            anim = np.load(io.BytesIO(members["anim.npy"]), allow_pickle=False)
            mask = np.load(io.BytesIO(members["mask.npy"]), allow_pickle=False).astype(bool)
            # only the thumbnail channels are kept, so a large dataset's report stays small
            chunks.setdefault(info["take"], []).append((key, _curves(anim, channels, mask)))
    curves, levels = {}, {}
    for tid, parts in chunks.items():
        parts.sort(key=lambda p: p[0])
        joined = {n: np.concatenate([p[1][n] for p in parts]) for n in parts[0][1]}
        levels[tid] = _levels(joined)
        if tid in thumbs:
            curves[tid] = joined
    return curves, levels


def _not_aligned(folder: Path) -> str:
    return f"{folder}: --takes names aligned take folders (s2a-align output); this one has no align report"


def _find_aligned(sources: list[dict[str, Any]], extra: list[Path], warnings: list[str]) -> dict[str, Path]:
    """Aligned take folders by take id: those the manifest names, then any found under ``extra`` (one
    that is not aligned is left out, with a line in ``warnings``)."""
    found: dict[str, Path] = {}
    for folder in find_takes(extra) if extra else []:
        try:
            meta = read_meta(folder)
        except InputError as exc:
            warnings.append(f"{exc}: left out")
            continue
        if meta.extra.get("align"):
            found.setdefault(meta.id, folder)
        else:
            warnings.append(_not_aligned(folder))
    for s in sources:
        p = Path(s.get("path", ""))
        if s.get("source_kind") == "aligned" and (p / "meta.json").is_file():
            found[s["take"]] = p
    return found


def _outliers(entries: list[dict[str, Any]]) -> None:
    """Sets ``entry["reasons"]``: why a take deserves a look."""
    levels: dict[str, list[float]] = {n: [] for n in THUMB_CHANNELS}
    for e in entries:
        e["reasons"] = []
        for n, v in e["p95"].items():
            if v is not None:
                levels[n].append(v)
    for n, vals in levels.items():
        if len(vals) < 4:
            continue
        med = float(np.median(vals))
        mad = float(np.median(np.abs(np.array(vals) - med))) * 1.4826
        if mad <= 1e-9:
            continue
        for e in entries:
            v = e["p95"].get(n)
            if v is not None and abs(v - med) / mad > ROBUST_Z and abs(v - med) > MIN_LEVEL_GAP:
                e["reasons"].append(f"{n} p95 {v:.3f} far from the median {med:.3f}")
    for e in entries:
        a = e.get("align") or {}
        conf = a.get("offset_confidence")
        if conf is not None and conf < MIN_CONFIDENCE:
            shown = shown_against(conf, MIN_CONFIDENCE)
            e["reasons"].append(f"offset confidence {shown} < {MIN_CONFIDENCE:g}")
        off = a.get("offset_s")
        if off is not None and abs(off) > MAX_OFFSET_S:
            e["reasons"].append(f"offset {off * 1000:.0f} ms")
        if a.get("flags"):
            e["reasons"].append("align flags: " + ", ".join(map(str, a["flags"])))
        if e.get("usable") is not None and e["usable"] < MIN_USABLE:
            e["reasons"].append(f"only {e['usable'] * 100:.0f}% usable frames")


def gather(path: str | Path, takes: list[Path] | None = None, limit: int = 500) -> dict[str, Any]:
    """Everything the page shows, as plain data (also what ``--json`` summarises). At most ``limit``
    takes (the first by id in a dataset, by path in a folder of takes) get curve thumbnails; 0: none."""
    if not (isinstance(limit, int) and limit >= 0):
        raise InputError(f"--limit must be 0 or more (0: no curve thumbnails), not {limit}")
    path = Path(path)
    extra = list(takes or [])
    warnings: list[str] = []
    unreadable: list[dict[str, str]] = []
    if (path / "manifest.json").is_file() or path.suffix == ".json":
        from dataset import dataset_stats, read_manifest

        ds = path if path.is_dir() else path.parent
        manifest = read_manifest(ds)
        stats = dataset_stats(ds)
        curves, levels = _dataset_curves(ds, manifest, limit)
        aligned = _find_aligned(manifest.get("sources", []), extra, warnings)
        missing = sorted(
            {s.get("take") for s in manifest.get("sources", []) if s.get("source_kind") == "aligned"}
            - set(aligned)
        )
        if missing:
            named = ", ".join(map(str, missing[:3])) + (", ..." if len(missing) > 3 else "")
            warnings.append(
                f"the align reports of {len(missing)} take(s) were not found where the manifest says the "
                f"aligned takes are ({named}): give their folder with --takes"
            )
        per_take: dict[str, dict[str, Any]] = {}
        for s in manifest["samples"]:
            e = per_take.setdefault(
                s["take"],
                {
                    "take": s["take"],
                    "speaker": s["speaker"],
                    "split": s["split"],
                    "duration_s": 0.0,
                    "frames": 0,
                    "usable_frames": 0,
                    "fps": manifest["fps"],
                },
            )
            e["duration_s"] += s["duration_s"]
            e["frames"] += s["frames"]
            e["usable_frames"] += s.get("usable_frames", s["frames"])
        entries = []
        for tid in sorted(per_take):
            e = per_take[tid]
            e["usable"] = e["usable_frames"] / e["frames"] if e["frames"] else 0.0
            e["curves"] = curves.get(tid, {})
            e["p95"] = levels.get(tid) or _levels({})
            e["align"] = None
            if tid in aligned:
                try:
                    e["align"] = read_meta(aligned[tid]).extra.get("align")
                except InputError:
                    pass
            entries.append(e)
        kind, title = "dataset", ds.name
    else:
        named = find_takes(extra) if extra else []  # walked once: the --takes folders are listed too
        # A --takes folder inside FOLDER (or FOLDER itself) is one take, listed once.
        folders = list({f.resolve(): f for f in [*find_takes([path]), *named]}.values())
        if not folders:
            if find_sources([path], skipped=lambda _path, _why: None):  # no notes before the error
                raise InputError(
                    "holds Live Link Face recordings, not take folders: import them first "
                    f"(s2a-capture import {path} -o TAKES) and report on TAKES",
                    path,
                )
            raise InputError("neither a dataset (manifest.json) nor a folder of takes", path)
        stats, manifest = None, None
        given = set(named)
        # Every take is listed; ``limit`` only bounds the thumbnails, as in dataset mode. A take folder
        # that cannot be read is listed apart with its error, and the others are reported.
        entries = []
        for f in folders:
            try:
                entries.append(_take_entry(f, len(entries) < limit))
            except InputError as exc:
                unreadable.append({"path": str(f), "error": str(exc)})
                continue
            if f in given and not entries[-1]["align"]:
                warnings.append(_not_aligned(f))
        kind, title = "takes", path.name
    _outliers(entries)
    return {
        "kind": kind,
        "title": title,
        "path": str(path),
        "stats": stats,
        "manifest": manifest,
        "takes": entries,
        "unreadable": unreadable,  # take folders that could not be read: path, error
        "warnings": warnings,
    }


# -- the page --------------------------------------------------------------------------------------
def _stats_html(stats: dict[str, Any]) -> tuple[str, str]:
    """The summary (cards, splits, speakers) and the details (channels, phones, warnings) of the stats."""
    parts = ['<div class="cards">']
    cards = [
        ("hours", f"{stats['hours']:.3f}"),
        ("fps", _fmt(stats["fps"], 1)),
        ("channels", stats["channels"]),
        ("speakers", len(stats["hours_per_speaker"])),
        ("features", ", ".join(stats["features"])),
    ]
    if stats.get("ppg"):
        cards.append(("PPG", stats["ppg"]))
    for k, v in cards:
        parts.append(f'<div class="card"><span class="muted">{k}</span><b>{html.escape(str(v))}</b></div>')
    parts.append("</div>")
    rows = [
        f'<tr><td class="l">{s}</td>'
        + _cell(v["takes"])
        + _cell(v["samples"])
        + _cell(v["hours"], 4)
        + _cell(v["usable_frames"])
        + _cell(v["speakers"])
        + "</tr>"
        for s, v in stats["splits"].items()
    ]
    parts.append(
        "<h2>Splits</h2>" + _table(["split", "takes", "samples", "hours", "usable frames", "speakers"], rows)
    )
    rows = []
    for spk, per in sorted(stats["hours_per_speaker"].items()):
        rows.append(
            f'<tr><td class="l">{html.escape(spk)}</td>'
            + "".join(_cell(per.get(s), 4) for s in ("train", "val", "test"))
            + "</tr>"
        )
    parts.append("<h2>Hours per speaker</h2>" + _table(["speaker", "train", "val", "test"], rows))
    top, parts = "".join(parts), []
    dist = stats.get("channel_distributions", {}).get("train") or next(
        iter(stats.get("channel_distributions", {}).values()), None
    )
    if dist:
        keys = ("mean", "std", "min", "p05", "p50", "p95", "max")
        rows = [
            f'<tr><td class="l">{html.escape(ch)}</td>' + "".join(_cell(d.get(k)) for k in keys) + "</tr>"
            for ch, d in (dist.items() if isinstance(dist, dict) else [])
        ]
        parts.append("<h2>Channel distributions (train split)</h2>" + _table(["channel", *keys], rows))
    cov = stats.get("phone_coverage")
    if cov:
        parts.append(
            f"<h2>Phone coverage</h2><p>{cov['covered']} of {cov['phones']} phones seen"
            + (f"; missing: {html.escape(', '.join(cov['missing']))}" if cov["missing"] else "")
            + "</p>"
        )
    if stats.get("warnings"):
        parts.append(
            "<h2>Warnings</h2><ul>"
            + "".join(f'<li class="warn">{html.escape(w)}</li>' for w in stats["warnings"])
            + "</ul>"
        )
    return top, "".join(parts)


def render_html(data: dict[str, Any]) -> str:
    """The page for ``gather``'s data: a complete HTML document, nothing loaded from elsewhere."""
    entries = data["takes"]
    title = f"s2a report: {data['title']}"
    body = [
        f"<h1>{html.escape(title)}</h1>",
        f'<p class="muted">{html.escape(data["kind"])} at {html.escape(data["path"])} · '
        f"{len(entries)} takes</p>",
    ]
    details = ""
    if data["stats"] is not None:
        top, details = _stats_html(data["stats"])
        body.append(top)
    else:
        body.append(
            '<p class="warn">Not a built dataset (no manifest.json): the report covers the take '
            "folders found, with their align reports where they are aligned.</p>"
        )
    flagged = [e for e in entries if e["reasons"]]
    body.append(f"<h2>Outliers ({len(flagged)})</h2>")
    if flagged:
        rows = [
            f'<tr class="flag"><td class="l">{html.escape(e["take"])}</td><td class="l">'
            + html.escape("; ".join(e["reasons"]))
            + "</td></tr>"
            for e in flagged
        ]
        body.append(_table(["take", "why"], rows))
    else:
        body.append(
            '<p class="muted">No take stands out (align confidence, offset, usable frames, '
            "mouth-curve levels).</p>"
        )
    if data["unreadable"]:
        rows = [
            f'<tr class="flag"><td class="l">{html.escape(u["path"])}</td>'
            f'<td class="l bad">{html.escape(u["error"])}</td></tr>'
            for u in data["unreadable"]
        ]
        body.append(f"<h2>Unreadable take folders ({len(rows)})</h2>" + _table(["folder", "error"], rows))
    body.append(f'<h2>Takes</h2><p class="muted">Thumbnails: {_legend_thumb()}</p>')
    rows = []
    for e in entries:
        a = e.get("align") or {}
        thumb = _thumb(e["curves"], e.get("fps") or 60.0) if e.get("curves") else ""
        img = f'<img class="thumb" alt="curves of {html.escape(e["take"])}" src="{thumb}">' if thumb else "–"
        conf = a.get("offset_confidence")
        cls = "bad" if conf is not None and conf < MIN_CONFIDENCE else ""
        off = a.get("offset_s")
        rows.append(
            f'<tr{" class=flag" if e["reasons"] else ""}><td class="l">{html.escape(e["take"])}</td>'
            f'<td class="l">{_fmt(e.get("split"))}</td><td class="l">{_fmt(e.get("speaker"))}</td>'
            + _cell(round(e["duration_s"], 3), 2)
            + _cell(e["frames"])
            + _cell(round(e["usable"] * 100, 1), 1)
            + _cell(round(off * 1000, 1) if off is not None else None, 1)
            + f'<td class="l">{_fmt(a.get("offset_source"))}</td>'
            + _cell(conf, 2, cls)
            + _cell(a.get("drift_ppm"), 1)
            + f'<td class="l">{html.escape(", ".join(map(str, a.get("flags") or [])) or "–")}</td>'
            + f"<td>{img}</td></tr>"
        )
    body.append(
        _table(
            [
                "take",
                "split",
                "speaker",
                "seconds",
                "frames",
                "usable %",
                "offset ms",
                "offset from",
                "confidence",
                "drift ppm",
                "flags",
                "curves",
            ],
            rows,
        )
    )
    if not any(e.get("align") for e in entries):
        body.append(
            '<p class="muted">No align report was found for these takes (align reports live in aligned '
            "take folders: give them with --takes).</p>"
        )
    body.append(details)
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width,initial-scale=1">'
        f"<title>{html.escape(title)}</title>"
        f"<style>{CSS}</style></head><body>{''.join(body)}<script>{SCRIPT}</script></body></html>\n"
    )


def write_report(
    path: str | Path, out: str | Path, takes: list[Path] | None = None, limit: int = 500
) -> dict:
    """Write the report page of dataset (or take folder) ``path`` to ``out``; returns a summary."""
    data = gather(path, takes, limit)
    out = Path(out)
    page = printable(render_html(data))  # a name not UTF-8 as \xff: the page is UTF-8
    with writing(out, "report"), atomic_write(out, "w", encoding="utf-8") as f:
        f.write(page)
    return {
        "output": str(out),
        "kind": data["kind"],
        "takes": len(data["takes"]),
        "with_align_report": sum(1 for e in data["takes"] if e.get("align")),
        "thumbnails": sum(1 for e in data["takes"] if e.get("curves")),
        "outliers": [{"take": e["take"], "reasons": e["reasons"]} for e in data["takes"] if e["reasons"]],
        "unreadable": data["unreadable"],
        "warnings": data["warnings"],
        "bytes": out.stat().st_size,
    }
