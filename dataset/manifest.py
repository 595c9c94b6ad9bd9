"""The dataset manifest: one JSON file (``manifest.json``) that says what every shard holds.

Fields (docs/dataset.md has the full list): ``format``/``schema_version``; ``fps``, ``sample_rate``;
``channels`` and how they were selected; ``features`` (names, dims, the one analysis setting, PPG
backend and library versions); ``normalization`` (animation offset/scale, feature mean/std, per-speaker
log-F0); ``splits`` (rule, takes and speakers per split); ``shards`` (name, split, sha256, bytes,
samples, frames, duration); ``samples`` (key, take, speaker, split, shard, frames, duration);
``sources`` (every source take with its sha256); ``stats``; ``warnings``; ``build`` (fingerprint).
It is written last and atomically, so a manifest always describes finished shards.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from capture.atomic import write_json_atomic
from capture.errors import InputError

FORMAT = "s2a-dataset"
SCHEMA_VERSION = 1
MANIFEST_FILE = "manifest.json"
# field: (type, element type or None, description) - checked on reading, so that nothing downstream
# trips over a hand-edited manifest; finer checks are qa.validate_manifest's.
TYPES = {
    "channels": (list, str, "list of channel names"),
    "features": (dict, None, "JSON object"),
    "normalization": (dict, None, "JSON object"),
    "splits": (dict, None, "JSON object"),
    "shards": (list, dict, "list of shard objects"),
    "samples": (list, dict, "list of sample objects"),
}
REQUIRED = ("fps", "sample_rate", "channels", "features", "normalization", "splits", "shards", "samples")


def manifest_path(ds: str | Path) -> Path:
    ds = Path(ds)
    return ds if ds.suffix == ".json" else ds / MANIFEST_FILE


def read_manifest(ds: str | Path) -> dict[str, Any]:
    """The manifest of dataset folder ``ds`` (or of a manifest file), format-checked."""
    path = manifest_path(ds)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError("not a dataset (no manifest.json)", path.parent) from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"manifest is not valid JSON: {exc}", path) from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise InputError(f'not a dataset manifest (expected "format": "{FORMAT}")', path)
    if data.get("schema_version") != SCHEMA_VERSION:
        raise InputError(
            f"manifest schema version {data.get('schema_version')!r}; this reads {SCHEMA_VERSION}", path
        )
    missing = [k for k in REQUIRED if k not in data]
    if missing:
        raise InputError(f"manifest lacks field(s) {', '.join(missing)}", path)
    for key, kind in TYPES.items():
        value = data[key]
        if not isinstance(value, kind[0]) or (
            kind[1] is not None and not all(isinstance(v, kind[1]) for v in value)
        ):
            raise InputError(f"manifest field {key!r} must be a {kind[2]}", path)
    return data


def write_manifest(ds: str | Path, data: dict[str, Any]) -> Path:
    path = manifest_path(ds)
    write_json_atomic(path, {"format": FORMAT, "schema_version": SCHEMA_VERSION} | data)
    os.chmod(path, 0o644)  # readable like the shards (the atomic writer creates 0600 files)
    return path


def shards_of(manifest: dict[str, Any], split: str | None = None) -> list[dict[str, Any]]:
    """Shard entries of one split (all when ``split`` is None), in manifest order."""
    return [s for s in manifest["shards"] if split is None or s.get("split") == split]
