"""The dataset manifest: one JSON file (``manifest.json``) that says what every shard holds.

Fields (docs/dataset.md has the full list): ``format``/``schema_version``; ``fps``, ``sample_rate``;
``channels`` and how they were selected; ``features`` (names, dims, the one analysis setting, PPG
backend and library versions); ``normalization`` (animation offset/scale, feature mean/std, per-speaker
log-F0); ``splits`` (rule, takes and speakers per split); ``shards`` (name, split, sha256, bytes,
samples, frames, duration); ``samples`` (key, take, speaker, split, shard, frames, duration);
``sources`` (every source take with its sha256); ``stats``; ``warnings``; ``build`` (fingerprint).
It is written last and atomically, so a manifest always describes finished shards. A name whose bytes
are not UTF-8 (a speaker) is written as messages show it, its bytes in base64 beside it
(``capture.errors.strict_names``): strict JSON, which jq reads; one written before as a lone surrogate
(``"\\udce9"``) reads back as the same name.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

from capture.atomic import write_json_atomic
from capture.errors import InputError, loads_names, strict_names
from capture.file_lock import held_elsewhere, lock_holder
from capture.numbers import is_count as _count
from capture.numbers import is_finite_number

from .splits import SPLITS

FORMAT = "s2a-dataset"
SCHEMA_VERSION = 1
MANIFEST_FILE = "manifest.json"
WORK = ".work"  # a build's working folder inside the dataset folder
# In .work: each take's record (its statistics and samples' sha256) and statistics, kept after a build so
# that a rebuild processes only the takes that changed; a cache, not a leftover (safe to delete).
TAKE_RECORDS = "takes"
LOCK_FILE = ".build.lock"  # held (flock) by the one build writing into a dataset folder
# the least feature or log-F0 std a manifest may hold (1e-6, less float32 rounding): the build stores 1 for
# a smaller one, and a smaller one (hand-edited or damaged) would turn the features into infinities
SMALLEST_STD = 1e-6 * (1 - 2**-23)
REQUIRED = ("fps", "sample_rate", "channels", "features", "normalization", "splits", "shards", "samples")


def manifest_path(ds: str | Path) -> Path:
    ds = Path(ds)
    return ds if ds.suffix == ".json" else ds / MANIFEST_FILE


def dataset_dir(ds: str | Path) -> Path:
    """The dataset folder of ``ds``, a dataset folder or its manifest file."""
    return manifest_path(ds).parent


def build_running(ds: str | Path) -> str | None:
    """What to say when a live build holds the lock of dataset ``ds`` (a folder or its manifest) right
    now, else None. A build replaces the dataset in a swap at its end: a reader that went on reading
    meanwhile (validate decodes every shard) could see some shards of the old dataset and some of the
    new, so the commands that read a whole dataset wait for it instead."""
    folder = dataset_dir(ds)
    if not held_elsewhere(folder / LOCK_FILE):
        return None
    return f"a build{lock_holder(folder / LOCK_FILE)} is writing into {folder}: wait for it to finish"


def dataset_folder(ds: str | Path) -> Path:
    """The dataset folder ``ds`` (``--data``) names: the folder itself or its manifest.json. Any other
    file is refused, naming it: taking its folder instead would quietly read the whole dataset a shard
    lies in (``eval --data DS/train-000000.tar`` scored the test split) or name ``.`` for a file in the
    current folder."""
    ds = Path(ds)
    if not ds.exists() or ds.is_dir():
        return ds  # a folder, or nothing: read_manifest says it is not a dataset
    if ds.name == MANIFEST_FILE:
        return ds.parent
    if (ds.parent / MANIFEST_FILE).is_file():
        folder = ds.parent if str(ds.parent) != "." else Path.cwd()
        raise InputError(
            f"--data takes the dataset folder, not a file in it: give the dataset folder {folder}", ds
        )
    raise InputError("--data takes a dataset folder (as s2a-dataset build writes it), not a file", ds)


# ------------------------------------------------------------------------------------------ schema
# The types of every field a reader (stats, report, training, validate) relies on, checked on reading so
# that nothing downstream trips over a hand-edited manifest. One set of checks: read_manifest refuses a
# manifest that fails any; qa.validate_manifest reports every failure.


def _fields(obj: dict, at: str, kinds: dict[str, tuple[Callable[[Any], bool], str]], optional=()):
    """(location, message) for each field of ``obj`` that is missing (unless optional) or fails its test."""
    for name, (ok, what) in kinds.items():
        if name not in obj:
            if name not in optional:
                yield f"{at}.{name}", f"missing (expected {what})"
        elif not ok(obj[name]):
            yield f"{at}.{name}", f"must be {what}, not {obj[name]!r:.40}"


def _is_str(v: Any) -> bool:
    return isinstance(v, str)


def _numbers(v: Any) -> bool:
    return isinstance(v, list) and all(is_finite_number(x) for x in v)


STR = (_is_str, "a string")
COUNT = (_count, "a non-negative integer")
SECONDS = (lambda v: is_finite_number(v) and v >= 0, "a non-negative number")
SHARD = {"name": STR, "split": STR, "sha256": STR, "bytes": COUNT, "samples": COUNT, "frames": COUNT}
SHARD |= {"duration_s": SECONDS}
SAMPLE = {"key": STR, "take": STR, "speaker": STR, "split": STR, "shard": STR, "frames": COUNT}
SAMPLE |= {"usable_frames": COUNT, "usable_values": COUNT, "duration_s": SECONDS}
SPLIT_STATS = {"takes": COUNT, "samples": COUNT, "hours": SECONDS, "usable_frames": COUNT}
SPLIT_STATS |= {
    "hours_per_speaker": (
        lambda v: isinstance(v, dict) and all(is_finite_number(h) for h in v.values()),
        "{speaker: hours}",
    ),
    "channels": (
        lambda v: (
            isinstance(v, dict)
            and all(
                isinstance(d, dict) and all(x is None or is_finite_number(x) for x in d.values())
                for d in v.values()
            )
        ),
        "{channel: {statistic: number}}",
    ),
    "phone_frames": (lambda v: isinstance(v, dict) and all(_count(n) for n in v.values()), "{phone: frames}"),
}


def _objects(value: Any, at: str, kinds: dict, optional=()):
    if not isinstance(value, list):
        yield at, "must be a list of objects"
        return
    for i, obj in enumerate(value):
        if isinstance(obj, dict):
            yield from _fields(obj, f"{at}[{i}]", kinds, optional)
        else:
            yield f"{at}[{i}]", "must be an object"


def _dicts(value: Any) -> list[dict]:
    return [v for v in value if isinstance(v, dict)] if isinstance(value, list) else []


def features_problems(features: Any) -> list[tuple[str, str]]:
    """(field, message) for ``features.names`` and ``features.dims`` of a manifest (or of the copy of
    them a training checkpoint keeps)."""
    features = features if isinstance(features, dict) else {}
    out = []
    names = features.get("names")
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        out.append(("features.names", "must be a list of feature names"))
        names = []
    dims = features.get("dims")
    if not isinstance(dims, dict) or not all(_count(d) and d > 0 for d in dims.values()):
        out.append(("features.dims", "must be a JSON object {feature: dimension, a positive integer}"))
    elif lacking := [n for n in names if n not in dims]:
        out.append(("features.dims", f"lacks feature(s) {', '.join(lacking)}"))
    return out


def normalization_problems(norm: Any, channels: list[str], features: Any) -> list[tuple[str, str]]:
    """(field, message) for each problem of ``normalization`` (a manifest's, or the copy a training
    checkpoint keeps) whose ``channels`` and ``features`` passed their checks: the animation offset and
    scale per channel, each feature's mean and std per dimension, with a pitch feature each speaker's
    log-F0 mean and std (the reader would otherwise pass raw log-F0 through); a std is at least
    ``SMALLEST_STD``, as the build writes it (it divides)."""
    if not isinstance(norm, dict):
        return [("normalization", "must be a JSON object")]
    out = []
    anim = norm.get("animation")
    anim = anim if isinstance(anim, dict) else {}
    for field in ("offset", "scale"):
        v = anim.get(field)
        if not _numbers(v) or len(v) != len(channels) or (field == "scale" and min(v, default=1) <= 0):
            out.append(
                (
                    f"normalization.animation.{field}",
                    f"must list one finite number per channel ({len(channels)})"
                    + (", each positive" if field == "scale" else ""),
                )
            )
    named = anim.get("channels")
    if named is not None and named != channels:
        out.append(("normalization.animation.channels", "must equal channels (the columns it normalises)"))
    dims = features.get("dims") if isinstance(features, dict) else None
    dims = dims if isinstance(dims, dict) else {}
    feature_norm = norm.get("features")
    if not isinstance(feature_norm, dict):
        out.append(("normalization.features", "must be a JSON object ({feature: {mean, std}})"))
        feature_norm = {}
    for name, st in feature_norm.items():
        if not isinstance(st, dict) or not _numbers(st.get("mean")) or not _numbers(st.get("std")):
            out.append((f"normalization.features.{name}", "must hold lists of numbers mean and std"))
        elif len(st["mean"]) != len(st["std"]) or (name in dims and len(st["mean"]) != dims[name]):
            out.append((f"normalization.features.{name}", f"mean and std must have {dims.get(name)} values"))
        elif min(st["std"], default=1) < SMALLEST_STD:
            out.append((f"normalization.features.{name}.std", "must be at least 1e-6 (it divides)"))
    pitch = norm.get("pitch", {})
    if not isinstance(pitch, dict):
        return out + [("normalization.pitch", "must be a JSON object")]
    speakers = pitch.get("speakers")
    names = features.get("names") if isinstance(features, dict) else None
    if speakers is None and isinstance(names, list) and "pitch" in names:
        return out + [("normalization.pitch.speakers", "missing (the dataset has a pitch feature)")]
    if not isinstance(speakers, dict | None):
        return out + [("normalization.pitch.speakers", "must be a JSON object {speaker: {mean, std}}")]
    for name, st in (speakers or {}).items():
        if (
            not isinstance(st, dict)
            or not is_finite_number(st.get("mean"))
            or not is_finite_number(st.get("std"))
            or st["std"] < SMALLEST_STD
        ):
            out.append(
                (
                    f"normalization.pitch.speakers.{name}",
                    "must hold a number mean and a std of at least 1e-6 (it divides)",
                )
            )
    return out


def _repeated_keys(samples: Any) -> list[tuple[str, str]]:
    """(field, message) for each sample key listed again: readers look samples up by key, so a second
    entry (a hand-merged manifest) would count its hours twice in stats and, pointing at another shard
    or another length, make the reader expect the sample where it is not."""
    first: dict[str, int] = {}
    out = []
    for i, s in enumerate(samples if isinstance(samples, list) else []):
        key = s.get("key") if isinstance(s, dict) else None
        if not isinstance(key, str):
            continue
        if key in first:
            out.append((f"samples[{i}].key", f"{key!r} is listed twice (also samples[{first[key]}])"))
        else:
            first[key] = i
    return out


def manifest_problems(data: dict[str, Any]) -> list[tuple[str, str]]:
    """(field, message) for each field of a manifest that readers rely on and that is missing or has
    the wrong type or value; empty for a usable manifest."""
    out = [(k, "missing") for k in REQUIRED if k not in data]
    if out:
        return out
    fps, rate, channels = data["fps"], data["sample_rate"], data["channels"]
    if not is_finite_number(fps) or fps <= 0:
        out.append(("fps", f"must be a positive number, not {fps!r:.40}"))
    if not _count(rate) or rate == 0:
        out.append(("sample_rate", f"must be a positive integer, not {rate!r:.40}"))
    if not isinstance(channels, list) or not channels or not all(isinstance(c, str) for c in channels):
        out.append(("channels", "must be a non-empty list of channel names"))
        channels = []
    for key in ("features", "splits"):
        if not isinstance(data[key], dict):
            out.append((key, "must be a JSON object"))
    out += features_problems(data["features"])
    out += normalization_problems(data["normalization"], channels, data["features"])
    speakers = data["normalization"].get("pitch", {}) if isinstance(data["normalization"], dict) else {}
    speakers = speakers.get("speakers") if isinstance(speakers, dict) else None
    names = data["features"].get("names") if isinstance(data["features"], dict) else None
    if isinstance(speakers, dict) and isinstance(names, list) and "pitch" in names:
        needed = sorted({str(s.get("speaker")) for s in _dicts(data["samples"])} - set(speakers))
        if needed:
            out.append(
                ("normalization.pitch.speakers", f"lacks the samples' speaker(s) {', '.join(needed[:3])}")
            )
    splits = data["splits"] if isinstance(data["splits"], dict) else {}
    for split in SPLITS:  # every split, empty or not: readers look each one up
        takes = splits[split].get("takes") if isinstance(splits.get(split), dict) else None
        if split not in splits and isinstance(data["splits"], dict):
            out.append((f"splits.{split}", "missing (expected an object whose takes list take ids)"))
        elif not isinstance(takes, list) or not all(isinstance(t, str) for t in takes):
            out.append((f"splits.{split}", "must be an object whose takes are a list of take ids"))
    if not isinstance(splits.get("rule", {}), dict):
        out.append(("splits.rule", "must be a JSON object"))
    out += _objects(data["shards"], "shards", SHARD, optional=("frames",))
    for i, s in enumerate(data["shards"] if isinstance(data["shards"], list) else []):
        if isinstance(s, dict) and isinstance(s.get("split"), str) and s["split"] not in SPLITS:
            out.append((f"shards[{i}].split", f"unknown split {s['split']!r}"))
        name = s.get("name") if isinstance(s, dict) else None
        if isinstance(name, str) and ("/" in name or "\\" in name or name.startswith(".")):
            out.append((f"shards[{i}].name", f"shard name {name!r} is not a plain file name"))
    out += _objects(data["samples"], "samples", SAMPLE, optional=("usable_frames", "usable_values"))
    out += _repeated_keys(data["samples"])
    stats = data.get("stats", {})
    if not isinstance(stats, dict):
        out.append(("stats", "must be a JSON object"))
    else:
        for split in sorted({sh["split"] for sh in _dicts(data["shards"]) if sh.get("split") in SPLITS}):
            if split not in stats:
                out.append((f"stats.{split}", "missing (the split has shards)"))
        for split, entry in stats.items():
            if split not in SPLITS or not isinstance(entry, dict):
                out.append((f"stats.{split}", "must be an object under train, val or test"))
            else:
                out += _fields(entry, f"stats.{split}", SPLIT_STATS, optional=("phone_frames",))
    for key in ("warnings", "speakers_assumed", "members"):
        v = data.get(key, [])
        if not isinstance(v, list) or not all(isinstance(w, str) for w in v):
            out.append((key, "must be a list of strings"))
    sources = data.get("sources", [])
    if not isinstance(sources, list) or not all(isinstance(s, dict) for s in sources):
        out.append(("sources", "must be a list of objects"))
    return out


def load_manifest(ds: str | Path) -> dict[str, Any]:
    """The JSON of the manifest of dataset folder ``ds`` (or of a manifest file), its format and schema
    version checked but not its fields (``read_manifest`` checks those)."""
    path = manifest_path(ds)
    try:
        data = loads_names(path.read_text(encoding="utf-8"))
    except (FileNotFoundError, NotADirectoryError, IsADirectoryError):
        raise InputError("not a dataset (no manifest.json)", path.parent) from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"manifest is not valid JSON: {exc}", path) from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise InputError(f'not a dataset manifest (expected "format": "{FORMAT}")', path)
    version = data.get("schema_version")
    if not _count(version) or version != SCHEMA_VERSION:
        if _count(version) and version > SCHEMA_VERSION:
            why = "a newer toolkit wrote it: read it with that version"
        else:
            why = "rebuild it with s2a-dataset build"
        raise InputError(
            f"manifest schema version {version!r}, this toolkit reads version {SCHEMA_VERSION} ({why})", path
        )
    return data


def read_manifest(ds: str | Path) -> dict[str, Any]:
    """The manifest of dataset folder ``ds`` (or of a manifest file), every field readers use checked."""
    data = load_manifest(ds)
    problems = manifest_problems(data)
    if problems:
        field, message = problems[0]
        more = len(problems) - 1
        also = f" (and {more} more problem(s): s2a-dataset validate lists them)" if more else ""
        raise InputError(f"manifest field {field} {message}{also}", manifest_path(ds))
    return data


def write_manifest(ds: str | Path, data: dict[str, Any]) -> Path:
    path = manifest_path(ds)
    write_json_atomic(path, strict_names({"format": FORMAT, "schema_version": SCHEMA_VERSION} | data))
    os.chmod(path, 0o644)  # readable like the shards (the atomic writer creates 0600 files)
    return path


SEGMENT_ID = re.compile(r"^(.+)\.seg\d+$")  # align names the segments it cuts from TAKE TAKE.seg01, ...


def take_recordings(manifest: dict[str, Any]) -> dict[str, str]:
    """``{take id: recording id}`` for every take of the manifest: the build's ``sources[].recording``
    (the raw take align cut it from), else, in datasets built before that was recorded, the take id
    less align's ``.segNN`` suffix."""

    def guess(take: str) -> str:
        m = SEGMENT_ID.match(take)
        return m.group(1) if m else take

    out: dict[str, str] = {}
    for src in manifest.get("sources", []):
        if isinstance(src, dict) and isinstance(src.get("take"), str):
            rec = src.get("recording")
            out[src["take"]] = rec if isinstance(rec, str) and rec else guess(src["take"])
    for sample in manifest.get("samples", []):
        if isinstance(sample, dict) and isinstance(sample.get("take"), str):
            out.setdefault(sample["take"], guess(sample["take"]))
    return out


def takes_by_recording(manifest: dict[str, Any]) -> dict[str, list[str]]:
    """``{recording id: its take ids, sorted}`` (``take_recordings`` turned around)."""
    groups: dict[str, list[str]] = {}
    for take, recording in take_recordings(manifest).items():
        groups.setdefault(recording, []).append(take)
    return {recording: sorted(takes) for recording, takes in groups.items()}


def shards_of(manifest: dict[str, Any], split: str | None = None) -> list[dict[str, Any]]:
    """Shard entries of one split (all when ``split`` is None), in manifest order."""
    return [s for s in manifest["shards"] if split is None or s.get("split") == split]
