"""``s2a-dataset validate``: checks as data, one function per kind of object, one ``validate`` on top.

``CHECKS`` lists every check (code, what it applies to, whether it needs ``--deep``, what it means);
``VALIDATORS`` maps each kind of object (manifest, shard, sample, splits) to its function. Each function
returns ``Problem`` records naming the location (``manifest.json:shards[2].sha256``,
``train-000000.tar:KEY.anim.npy``, ...). The default run decodes every sample and reads each FLAC
header, hashing each shard as it reads it (its sha256); ``deep`` also decodes every FLAC in full and
recomputes, with the build's own accumulators, the channel distributions and normalisation statistics
the manifest holds.
"""

from __future__ import annotations

import io
import math
from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from capture.errors import InputError
from capture.file_lock import held_elsewhere
from capture.numbers import is_finite_number
from capture.transfer_litter import is_litter

from .manifest import (
    LOCK_FILE,
    MANIFEST_FILE,
    STR,
    TAKE_RECORDS,
    WORK,
    _count,
    _fields,
    load_manifest,
    manifest_problems,
    take_recordings,
)
from .normalize import (
    ANIM_LIMIT,
    KINDS,
    ChannelAccumulator,
    FeatureAccumulator,
    animation_statistics,
    histogram_resolution,
    is_power_of_two,
    power_of_two,
    usable_neutral,
    voiced_log_f0_sums,
)
from .shards import (
    CHANNEL_MASK,
    ShardReader,
    channel_mask_problem,
    decode_flac,
    decode_json_object,
    decode_npy,
)
from .splits import SPLITS

MIDPOINT_EPS = 1e-9  # in octaves: a recomputed spread this near a midpoint may round either way
LOG_F0_RANGE = (math.log(20.0), math.log(2000.0))
# still_channel: a channel counts as animated when the median over takes of its per-take std reaches
# MOVING_STD (blendshape units); a take whose std is under STILL_RATIO of that median leaves it still
MOVING_STD = 0.03
STILL_RATIO = 0.25
MIN_TAKES = 3  # fewer takes give no majority to compare with
# shorter takes are not judged: a channel that moves on a few phones only (mouthRollLower on m, b, p) can
# rest through a short one
MIN_TAKE_S = 30.0


@dataclass(frozen=True)
class Check:
    code: str
    applies_to: str
    deep: bool
    description: str


CHECKS: tuple[Check, ...] = (
    Check("manifest_schema", "manifest", False, "required fields present, with the right types and lengths"),
    Check("shard_missing", "shard", False, "a shard listed in the manifest is not on disk"),
    Check("shard_size", "shard", False, "a shard's size differs from the manifest (truncated or appended)"),
    Check("shard_checksum", "shard", False, "a shard's sha256 differs from the manifest"),
    Check("shard_unreadable", "shard", False, "a shard is not a readable tar"),
    Check("shard_contents", "shard", False, "samples, frames or keys in a shard differ from the manifest"),
    Check("shard_unlisted", "shard", False, "a shard file in the folder is not in the manifest (warning)"),
    Check(
        "sample_members",
        "sample",
        False,
        "a sample lacks a member the manifest promises, or has unknown ones",
    ),
    Check("sample_decode", "sample", False, "a member cannot be decoded (.npy, .json, .flac)"),
    Check("dtype", "sample", False, "animation, features float32; mask bool"),
    Check("channel_count", "sample", False, "animation columns differ from the manifest's channels"),
    Check(
        "length_mismatch", "sample", False, "mask/features/metadata frame counts differ from the animation"
    ),
    Check("feature_dim", "sample", False, "a feature's dimension differs from the manifest"),
    Check(
        "channel_mask",
        "sample",
        False,
        "the optional channel_mask.npy is not bool of shape (frames, channels), or the frames usable in "
        "all its channels differ from mask.npy",
    ),
    Check("nonfinite", "sample", False, "NaN or infinity in animation or features"),
    Check(
        "value_range",
        "sample",
        False,
        "animation beyond +-10, voicing flag not 0/1, voiced log-F0 outside 20-2000 Hz",
    ),
    Check("sample_rate", "sample", False, "audio sample rate differs from the manifest"),
    Check(
        "frame_rate",
        "sample",
        False,
        "sample fps differs from the manifest, or audio length from frames / fps",
    ),
    Check("duplicate_key", "splits", False, "the same sample key occurs twice"),
    Check("duplicate_take", "splits", False, "the same take content appears under two take ids"),
    Check(
        "split_leakage", "splits", False, "a take (or, split by speaker, a speaker) is in more than one split"
    ),
    Check("manifest_mismatch", "splits", False, "samples listed in the manifest and found in shards differ"),
    Check(
        "split_listing",
        "manifest",
        False,
        "a take's samples sit in another split than splits.SPLIT.takes (or sources[].split) lists it under, "
        "or in no split's list",
    ),
    Check(
        "stats_mismatch",
        "manifest",
        False,
        "stats.SPLIT (takes, samples, hours, usable frames, hours per speaker) or a shard's duration_s "
        "differ from the takes and samples the manifest lists; with --deep, a channel distribution "
        "(stats.SPLIT.channels) from the one recomputed from the split's samples",
    ),
    Check(
        "feature_names",
        "manifest",
        False,
        "features.names, features.dims, members and normalization.features name different features",
    ),
    Check(
        "normalization_scale",
        "manifest",
        False,
        "an animation scale (normalization.animation.scale) that is not a power of two, as the build "
        "makes every one",
    ),
    Check(
        "normalization_mismatch",
        "dataset",
        True,
        "normalization (animation offset and scale, feature mean and std, per-speaker log-F0) differs "
        "from what the build computes from the training split's samples",
    ),
    Check(
        "split_empty",
        "manifest",
        False,
        "a val or test split that its fraction asked for holds no take, or a split holds no usable frame "
        "(warning)",
    ),
    Check(
        "build_leftover",
        "dataset",
        False,
        "a build's .work folder, lock or .partial files in the dataset folder: a build is running or was "
        "interrupted (warning)",
    ),
    Check(
        "still_channel",
        "takes",
        False,
        f"a take of at least {MIN_TAKE_S:g} s leaves still a channel that the other takes animate: its "
        f"std is under {STILL_RATIO:g} x the median of the takes' stds, which is at least {MOVING_STD:g} "
        "(warning; a tracking or calibration fault, or a rig mapped differently)",
    ),
)
CHECK_CODES = {c.code for c in CHECKS}


@dataclass(frozen=True)
class Problem:
    """One finding: which check, where, and what is wrong."""

    code: str
    location: str
    message: str
    severity: str = "error"

    def to_json(self) -> dict[str, str]:
        return asdict(self)


def _p(code: str, location: str, message: str, severity: str = "error") -> Problem:
    assert code in CHECK_CODES, code
    return Problem(code, location, message, severity)


# ------------------------------------------------------------------------------------------ manifest


def validate_manifest(manifest: dict[str, Any], **_: Any) -> list[Problem]:
    """Types and values of the manifest's fields: every problem ``read_manifest`` would refuse."""
    return [
        _p("manifest_schema", f"{MANIFEST_FILE}:{field}", message)
        for field, message in manifest_problems(manifest)
    ]


# ------------------------------------------------------------------------------------------ shard


def decode_metadata(members: dict[str, bytes]) -> dict[str, Any] | InputError | None:
    """A sample's metadata, decoded from its ``json`` member once for every check that reads it: None
    when the sample has no such member, the ``InputError`` saying why when it does not decode."""
    if "json" not in members:
        return None
    try:
        return decode_json_object(members["json"])
    except InputError as exc:
        return exc


def validate_shard(
    entry: dict[str, Any],
    ds: Path,
    manifest: dict[str, Any],
    deep: bool = False,
    on_sample: Callable[[str, dict[str, bytes], dict[str, Any] | InputError | None], None] | None = None,
    **_: Any,
) -> list[Problem]:
    """File, size, checksum and readability of one shard; hands each sample to ``on_sample`` with its
    metadata as ``decode_metadata`` returns it."""
    out: list[Problem] = []
    name = entry.get("name", "?")
    path = ds / name
    if not path.is_file():
        return [_p("shard_missing", name, "listed in the manifest but not found")]
    size = path.stat().st_size
    if isinstance(entry.get("bytes"), int) and size != entry["bytes"]:
        out.append(_p("shard_size", name, f"{size} bytes; the manifest says {entry['bytes']}"))
    count = frames = 0
    reader = ShardReader(path, sha256=entry.get("sha256"))  # hashed as it is read: no --deep needed
    try:
        for key, members in reader:
            count += 1
            metadata = decode_metadata(members)
            # metadata that does not decode is validate_sample's to report
            said = metadata.get("frames") if isinstance(metadata, dict) else None
            frames += said if _count(said) else 0
            if on_sample is not None:
                on_sample(key, members, metadata)
    except InputError as exc:
        if reader.digest is None or reader.digest == reader.sha256:
            out.append(_p("shard_unreadable", name, str(exc).split(": ", 1)[-1]))
            return out
        # read to its end, every sample handed on, its bytes not the manifest's
        said = f"sha256 {reader.digest[:16]}... differs from the manifest's {reader.sha256[:16]}..."
        out.append(_p("shard_checksum", name, said))
    if count != entry.get("samples"):
        out.append(_p("shard_contents", name, f"{count} samples; the manifest says {entry.get('samples')}"))
    elif "frames" in entry and frames != entry["frames"]:
        out.append(_p("shard_contents", name, f"{frames} frames; the manifest says {entry['frames']}"))
    return out


# ------------------------------------------------------------------------------------------ sample


def _check_anim(anim: np.ndarray, at: str, n_channels: int) -> tuple[list[Problem], int | None]:
    """Problems of a sample's animation (dtype, shape, values) and its number of frames (None when it
    is not a (frames, channels) array)."""
    out: list[Problem] = []
    frames = None
    if anim.dtype != np.float32:
        out.append(_p("dtype", f"{at}.anim.npy", f"animation is {anim.dtype}, expected float32"))
    if anim.ndim != 2:
        out.append(
            _p(
                "channel_count",
                f"{at}.anim.npy",
                f"animation has shape {anim.shape}, expected (frames, channels)",
            )
        )
    else:
        frames = anim.shape[0]
        if anim.shape[1] != n_channels:
            out.append(
                _p(
                    "channel_count",
                    f"{at}.anim.npy",
                    f"{anim.shape[1]} channels; the manifest lists {n_channels}",
                )
            )
        if anim.dtype.kind == "f":
            bad = ~np.isfinite(anim)
            if bad.any():
                r, c = np.argwhere(bad)[0]
                out.append(
                    _p(
                        "nonfinite",
                        f"{at}.anim.npy",
                        f"{int(bad.sum())} NaN/inf values (first at frame {r}, column {c})",
                    )
                )
            big = np.abs(np.where(bad, 0, anim)) > ANIM_LIMIT
            if big.any():
                out.append(
                    _p(
                        "value_range",
                        f"{at}.anim.npy",
                        f"{int(big.sum())} values beyond +-{ANIM_LIMIT:g}",
                    )
                )
    return out, frames


def usable_values(arrays: dict[str, np.ndarray], n_channels: int) -> int:
    """How many values of a decoded sample are usable (a training loss's targets, the reader's
    ``values``): its channel_mask's where it has one, else its mask's frames in every channel. Only for
    a sample whose channel_mask ``validate_sample`` found sound: ``validate`` counts none of a damaged one."""
    mask, channel_mask = arrays["mask"], arrays.get("channel_mask")
    if channel_mask is None:
        return int(np.count_nonzero(mask)) * n_channels
    return int(np.count_nonzero(channel_mask))


def _check_features(
    arrays: dict[str, np.ndarray], at: str, manifest: dict[str, Any], frames: int | None
) -> list[Problem]:
    """Problems of a sample's feature arrays: dtype, shape, length against the animation's, dimension
    against the manifest's, values (finite; the voicing flag and log-F0 of pitch in range)."""
    out: list[Problem] = []
    dims = manifest.get("features", {}).get("dims", {})
    for name in manifest.get("features", {}).get("names", []):
        arr = arrays.get(name)
        if arr is None:
            continue
        loc = f"{at}.{name}.npy"
        if arr.dtype != np.float32:
            out.append(_p("dtype", loc, f"{name} is {arr.dtype}, expected float32"))
        if arr.ndim != 2:
            out.append(_p("feature_dim", loc, f"{name} has shape {arr.shape}, expected (frames, dim)"))
            continue
        if frames is not None and arr.shape[0] != frames:
            out.append(_p("length_mismatch", loc, f"{name} has {arr.shape[0]} frames, animation {frames}"))
        if name in dims and arr.shape[1] != dims[name]:
            out.append(
                _p("feature_dim", loc, f"{name} has dimension {arr.shape[1]}; the manifest says {dims[name]}")
            )
        if arr.dtype.kind == "f":
            bad = ~np.isfinite(arr)
            if bad.any():
                out.append(
                    _p(
                        "nonfinite",
                        loc,
                        f"{int(bad.sum())} NaN/inf values (first at frame {np.argwhere(bad)[0][0]})",
                    )
                )
            elif name == "pitch" and arr.shape[1] == 2:
                flag = arr[:, 1]
                if not np.all((flag == 0) | (flag == 1)):
                    out.append(_p("value_range", loc, "voicing flag holds values other than 0 and 1"))
                voiced = arr[flag == 1, 0]
                lo, hi = LOG_F0_RANGE
                if voiced.size and (voiced.min() < lo or voiced.max() > hi):
                    out.append(_p("value_range", loc, "voiced log-F0 outside 20-2000 Hz"))
    return out


def _check_metadata(
    meta: dict[str, Any], key: str, at: str, manifest: dict[str, Any], frames: int | None
) -> list[Problem]:
    """Problems of a sample's metadata against its key, its animation and the manifest's rates."""
    out: list[Problem] = []
    fps = manifest.get("fps")
    if meta.get("key") != key:
        out.append(_p("sample_members", f"{at}.json", f"metadata names key {meta.get('key')!r}"))
    if frames is not None and meta.get("frames") != frames:
        out.append(
            _p(
                "length_mismatch",
                f"{at}.json",
                f"metadata says {meta.get('frames')} frames, animation has {frames}",
            )
        )
    if isinstance(fps, (int, float)) and meta.get("fps") != fps:
        out.append(
            _p("frame_rate", f"{at}.json", f"sample at {meta.get('fps')} fps; the dataset is {fps} fps")
        )
    if meta.get("sample_rate") != manifest.get("sample_rate"):
        out.append(
            _p(
                "sample_rate",
                f"{at}.json",
                f"metadata says {meta.get('sample_rate')} Hz; the dataset is "
                f"{manifest.get('sample_rate')} Hz",
            )
        )
    return out


def _str_or_null(v: Any) -> bool:
    return v is None or isinstance(v, str)


# the sample metadata fields validate groups, sorts and compares by: a field of another type is reported
# and left out, so that the checks after see only these types
SAMPLE_META = {"key": STR, "take": STR, "split": STR}
SAMPLE_META |= {k: (_str_or_null, "a string or null") for k in ("speaker", "content_sha256", "take_sha256")}


def validate_sample(
    key: str,
    members: dict[str, bytes],
    shard: str,
    manifest: dict[str, Any],
    deep: bool = False,
    on_arrays: Callable[[dict[str, np.ndarray], np.ndarray], None] | None = None,
    metadata: dict[str, Any] | InputError | None = None,
    **_: Any,
) -> tuple[list[Problem], dict[str, Any] | None]:
    """Decode one sample and check members, dtypes, shapes, values and rates; returns its metadata.
    ``on_arrays`` receives the decoded arrays (by member name less ``.npy``) and the usable frames (mask
    true, every animation value finite), when the animation and mask have the manifest's shape.
    ``metadata`` is the ``json`` member as ``decode_metadata`` returned it, when the caller decoded it
    already (None: decoded here)."""
    out: list[Problem] = []
    at = f"{shard}:{key}"
    expected = set(manifest.get("members", BASE_MEMBERS))
    missing = sorted(expected - set(members))
    if missing:
        out.append(_p("sample_members", at, f"missing member(s) {', '.join(missing)}"))
    extra = sorted(set(members) - expected - set(OPTIONAL_MEMBERS))
    if extra:
        out.append(_p("sample_members", at, f"unexpected member(s) {', '.join(extra)}", "warning"))
    meta = None
    if "json" in members:
        decoded = metadata if metadata is not None else decode_metadata(members)
        if isinstance(decoded, InputError):
            out.append(_p("sample_decode", f"{at}.json", str(decoded)))
        else:
            meta = decoded
            bad = list(_fields(meta, "metadata", SAMPLE_META, optional=SAMPLE_META))
            out += [_p("sample_decode", f"{at}.json", f"{field} {message}") for field, message in bad]
            if bad:
                wrong = {field for field, _ in bad}
                meta = {k: v for k, v in meta.items() if f"metadata.{k}" not in wrong}
    arrays: dict[str, np.ndarray] = {}
    for ext, data in members.items():
        if ext.endswith(".npy"):
            try:
                arrays[ext[:-4]] = decode_npy(data, ext)
            except InputError as exc:
                out.append(_p("sample_decode", f"{at}.{ext}", str(exc)))
    n_channels = len(manifest.get("channels", []))
    anim = arrays.get("anim")
    frames = None
    if anim is not None:
        problems, frames = _check_anim(anim, at, n_channels)
        out += problems
    mask = arrays.get("mask")
    if mask is not None:
        if mask.dtype != np.bool_:
            out.append(_p("dtype", f"{at}.mask.npy", f"mask is {mask.dtype}, expected bool"))
        if frames is not None and mask.shape != (frames,):
            out.append(
                _p(
                    "length_mismatch",
                    f"{at}.mask.npy",
                    f"mask has shape {mask.shape}, animation {frames} frames",
                )
            )
        elif (
            on_arrays is not None
            and frames is not None
            and anim.dtype.kind == "f"
            and anim.shape[1] == n_channels
        ):
            on_arrays(arrays, mask.astype(bool) & np.isfinite(anim).all(axis=1))
        if "channel_mask" in arrays and frames is not None and mask.shape == (frames,):
            problem = channel_mask_problem(arrays["channel_mask"], mask, n_channels)
            if problem is not None:
                out.append(_p("channel_mask", f"{at}.channel_mask.npy", problem))
    out += _check_features(arrays, at, manifest, frames)
    phones = arrays.get("phones")
    if phones is not None and frames is not None and phones.shape != (frames,):
        out.append(
            _p(
                "length_mismatch",
                f"{at}.phones.npy",
                f"phones have shape {phones.shape}, animation {frames} frames",
            )
        )
    if meta is not None:
        out += _check_metadata(meta, key, at, manifest, frames)
    if "flac" in members:
        out += _check_audio(members["flac"], f"{at}.flac", meta, manifest, deep)
    return out, meta


def _check_audio(
    data: bytes, loc: str, meta: dict | None, manifest: dict[str, Any], deep: bool
) -> list[Problem]:
    import soundfile as sf

    out: list[Problem] = []
    try:
        if deep:
            x, rate = decode_flac(data)
            n = x.shape[0]
            if not np.all(np.isfinite(x)):
                out.append(_p("nonfinite", loc, "audio holds NaN/inf"))
        else:
            info = sf.info(io.BytesIO(data))
            rate, n = int(info.samplerate), int(info.frames)
    except InputError as exc:  # decode_flac's own message
        return [_p("sample_decode", loc, str(exc))]
    except (sf.LibsndfileError, RuntimeError, TypeError) as exc:
        return [_p("sample_decode", loc, f"audio is not readable FLAC ({str(exc).split(': ', 1)[-1]})")]
    want = manifest.get("sample_rate")
    if rate != want:
        out.append(_p("sample_rate", loc, f"audio at {rate} Hz; the dataset is {want} Hz"))
    elif meta is not None:
        if meta.get("audio_samples") != n:
            out.append(_p("frame_rate", loc, f"{n} audio samples; metadata says {meta.get('audio_samples')}"))
        fps = manifest.get("fps")
        frames = meta.get("frames")
        if isinstance(fps, (int, float)) and isinstance(frames, int) and fps > 0:
            if abs(n / rate - frames / fps) > 1.0 / fps:
                out.append(
                    _p(
                        "frame_rate",
                        loc,
                        f"audio lasts {n / rate:.3f} s but {frames} frames at {fps} fps last "
                        f"{frames / fps:.3f} s",
                    )
                )
    return out


# ------------------------------------------------------------------------------------------ splits


def _in_several(
    groups: dict[str, set[str]], location: Callable[[str], str], message: Callable[[str, str], str]
) -> list[Problem]:
    """A ``split_leakage`` problem for each group (take, speaker, recording) found in several splits."""
    return [
        _p("split_leakage", location(name), message(name, ", ".join(sorted(splits))))
        for name, splits in sorted(groups.items())
        if len(splits) > 1
    ]


def validate_splits(manifest: dict[str, Any], seen: list[dict[str, Any]], **_: Any) -> list[Problem]:
    """Duplicates and leakage across all samples found in shards, and agreement with the manifest.

    ``seen`` holds, per sample found, ``key``, ``shard``, ``split`` (of its shard) and its metadata."""
    out: list[Problem] = []
    keys: dict[str, str] = {}
    for s in seen:
        if s["key"] in keys:
            out.append(_p("duplicate_key", f"{s['shard']}:{s['key']}", f"key also in {keys[s['key']]}"))
        else:
            keys[s["key"]] = s["shard"]
    by = manifest.get("splits", {}).get("rule", {}).get("by", "take")
    splits_of: dict[str, set[str]] = {}
    speaker_splits: dict[str, set[str]] = {}
    take_of_sha: dict[str, str] = {}
    for s in seen:
        meta = s.get("meta") or {}
        take = meta.get("take")
        if take is None:
            continue
        if meta.get("split") not in (None, s["split"]):
            out.append(
                _p(
                    "split_leakage",
                    f"{s['shard']}:{s['key']}",
                    f"sample says split {meta.get('split')!r} but sits in a {s['split']} shard",
                )
            )
        splits_of.setdefault(take, set()).add(s["split"])
        speaker_splits.setdefault(str(meta.get("speaker")), set()).add(s["split"])
        sha = meta.get("content_sha256", meta.get("take_sha256"))
        if sha is not None:
            if take_of_sha.setdefault(sha, take) != take:
                out.append(
                    _p(
                        "duplicate_take",
                        f"{s['shard']}:{s['key']}",
                        f"take {take!r} has the same content as take {take_of_sha[sha]!r}",
                    )
                )
    out += _in_several(splits_of, lambda t: f"take {t}", lambda t, s: f"take is in splits {s}")
    if by == "speaker":
        out += _in_several(speaker_splits, lambda k: f"speaker {k}", lambda k, s: f"speaker is in splits {s}")
    # segments align cut from one recording go to one split, by take or by speaker (a take naming no
    # speaker is its recording's: a segment on each side of a speaker split is the same session)
    recordings: dict[str, set[str]] = {}
    recording_of = take_recordings(manifest)
    for take, splits in splits_of.items():
        recordings.setdefault(recording_of.get(take, take), set()).update(splits)
    out += _in_several(
        recordings,
        lambda r: f"recording {r}",
        lambda r, s: f"segments of one recording are in splits {s}",
    )
    listed: dict[str, set[str]] = {}
    for split in SPLITS:
        for take in manifest.get("splits", {}).get(split, {}).get("takes", []):
            listed.setdefault(take, set()).add(split)
    out += _in_several(listed, lambda t: f"{MANIFEST_FILE}:splits", lambda t, s: f"take {t} is listed in {s}")
    out += manifest_consistency(manifest)
    manifest_keys = {m.get("key"): m for m in manifest.get("samples", [])}
    found = set(keys)
    for key in sorted(set(manifest_keys) - found):
        out.append(
            _p(
                "manifest_mismatch",
                f"{manifest_keys[key].get('shard')}:{key}",
                "listed in the manifest, not found",
            )
        )
    for key in sorted(found - set(manifest_keys)):
        out.append(
            _p("manifest_mismatch", f"{keys[key]}:{key}", "found in a shard, not listed in the manifest")
        )
    first = {}
    for s in seen:
        first.setdefault(s["key"], s)
    for key in sorted(found & set(manifest_keys)):
        if manifest_keys[key].get("shard") != keys[key]:
            out.append(
                _p(
                    "manifest_mismatch",
                    f"{keys[key]}:{key}",
                    f"manifest puts it in {manifest_keys[key].get('shard')}",
                )
            )
        out += _entry_mismatch(manifest_keys[key], first[key], manifest.get("fps"))
    return out


def _listing_problems(manifest: dict[str, Any]) -> list[Problem]:
    """splits.SPLIT.takes and sources[].split against the split of each take's samples."""
    out: list[Problem] = []
    sample_splits: dict[str, set[str]] = {}
    for s in manifest["samples"]:
        sample_splits.setdefault(s["take"], set()).add(s["split"])
    listed = {t: split for split in SPLITS for t in manifest["splits"][split]["takes"]}
    for take, splits in sorted(sample_splits.items()):
        if take not in listed:
            out.append(
                _p(
                    "split_listing",
                    f"{MANIFEST_FILE}:splits",
                    f"take {take} has samples but no split lists it",
                )
            )
        elif splits != {listed[take]}:
            out.append(
                _p(
                    "split_listing",
                    f"{MANIFEST_FILE}:splits.{listed[take]}.takes",
                    f"take {take} is listed under {listed[take]}; its samples are in "
                    + ", ".join(sorted(splits)),
                )
            )
    for i, src in enumerate(manifest.get("sources", [])):
        take, split = src.get("take"), src.get("split")
        if isinstance(take, str) and isinstance(split, str) and take in listed and listed[take] != split:
            out.append(
                _p(
                    "split_listing",
                    f"{MANIFEST_FILE}:sources[{i}].split",
                    f"says {split}; splits.{listed[take]}.takes lists take {take}",
                )
            )
    return out


def _close(a: float, b: float, tolerance: float) -> bool:
    return abs(a - b) <= tolerance + 1e-9 * max(abs(a), abs(b))


def _stats_problems(manifest: dict[str, Any]) -> list[Problem]:
    """What ``s2a-dataset stats`` shows (stats.SPLIT, shards[i].duration_s) against the manifest's own
    takes and samples; durations agree within a frame."""
    out: list[Problem] = []
    fps = manifest["fps"]
    frame = 1.0 / fps
    stats = manifest.get("stats", {})
    for split in SPLITS:
        takes = manifest["splits"][split]["takes"]
        samples = [s for s in manifest["samples"] if s["split"] == split]
        entry = stats.get(split)
        at = f"{MANIFEST_FILE}:stats.{split}"
        if entry is None:
            if takes:
                out.append(_p("stats_mismatch", at, f"missing; the split lists {len(takes)} take(s)"))
            continue
        seconds = sum(s["duration_s"] for s in samples)
        usable = sum(s.get("usable_frames", 0) for s in samples)
        per_speaker: dict[str, float] = {}
        for s in samples:
            per_speaker[s["speaker"]] = per_speaker.get(s["speaker"], 0.0) + s["duration_s"]
        found = {
            "takes": (entry["takes"], len(takes)),
            "samples": (entry["samples"], len(samples)),
        }
        if all("usable_frames" in s for s in samples):
            found["usable_frames"] = (entry["usable_frames"], usable)
        for name, (says, has) in found.items():
            if says != has:
                out.append(_p("stats_mismatch", f"{at}.{name}", f"says {says}; the manifest lists {has}"))
        tolerance = frame * max(1, len(samples))
        if not _close(entry["hours"] * 3600.0, seconds, tolerance):
            out.append(
                _p(
                    "stats_mismatch",
                    f"{at}.hours",
                    f"says {entry['hours'] * 3600.0:.3f} s; the split's samples last {seconds:.3f} s",
                )
            )
        hours = entry["hours_per_speaker"]
        if set(hours) != set(per_speaker) or not all(
            _close(hours[k] * 3600.0, v, tolerance) for k, v in per_speaker.items()
        ):
            out.append(
                _p(
                    "stats_mismatch",
                    f"{at}.hours_per_speaker",
                    "differs from the durations of the split's samples by speaker",
                )
            )
    for i, shard in enumerate(manifest["shards"]):
        mine = [s["duration_s"] for s in manifest["samples"] if s["shard"] == shard["name"]]
        if not _close(shard["duration_s"], sum(mine), frame):
            out.append(
                _p(
                    "stats_mismatch",
                    f"{MANIFEST_FILE}:shards[{i}].duration_s",
                    f"says {shard['duration_s']} s; its {len(mine)} sample(s) last {sum(mine):.6f} s",
                )
            )
    return out


BASE_MEMBERS = ("json", "flac", "anim.npy", "mask.npy")
# phones with a phone-aware PPG; channel_mask where some frame is usable in some channels only
OPTIONAL_MEMBERS = ("phones.npy", CHANNEL_MASK)


def _feature_problems(manifest: dict[str, Any]) -> list[Problem]:
    """The features the manifest names, in each place it names them."""
    features = manifest["features"]
    names = features["names"]
    out: list[Problem] = []
    at = f"{MANIFEST_FILE}:features"

    def differ(where: str, theirs: set[str], ours: set[str]) -> None:
        if theirs != ours:
            gone, extra = sorted(ours - theirs), sorted(theirs - ours)
            said = (f"lacks {', '.join(gone)}" if gone else "") + ("; " if gone and extra else "")
            said += f"names {', '.join(extra)} that features.names does not" if extra else ""
            out.append(_p("feature_names", where, f"{said} (features.names: {', '.join(names) or 'none'})"))

    if len(set(names)) != len(names):
        out.append(_p("feature_names", f"{at}.names", "names a feature twice"))
    dims = features.get("dims")
    if isinstance(dims, dict):
        differ(f"{at}.dims", set(dims), set(names))
    members = manifest.get("members")
    if isinstance(members, list):
        named = {m[:-4] for m in members if isinstance(m, str) and m.endswith(".npy")}
        named -= {m[:-4] for m in BASE_MEMBERS + OPTIONAL_MEMBERS if m.endswith(".npy")}
        differ(f"{MANIFEST_FILE}:members", named, set(names))
        lacking = sorted(set(BASE_MEMBERS) - set(members))
        if lacking:
            out.append(_p("feature_names", f"{MANIFEST_FILE}:members", f"lacks {', '.join(lacking)}"))
    norm = manifest["normalization"].get("features")
    if isinstance(norm, dict):
        differ(f"{MANIFEST_FILE}:normalization.features", set(norm), set(names) - {"pitch"})
    return out


def _empty_split_problems(manifest: dict[str, Any]) -> list[Problem]:
    """Warnings: a val or test split its fraction asked for that holds no take; a split with takes but
    no usable frame (nothing to train or evaluate on)."""
    out: list[Problem] = []
    rule = manifest["splits"].get("rule", {})
    for split in ("val", "test"):
        fraction = rule.get(f"{split}_fraction")
        if is_finite_number(fraction) and fraction > 0 and not manifest["splits"][split]["takes"]:
            out.append(
                _p(
                    "split_empty",
                    f"{MANIFEST_FILE}:splits.{split}",
                    f"no take, though the build asked for {fraction:.0%} of the audio (too few takes or "
                    "speakers)",
                    "warning",
                )
            )
    for split, entry in manifest.get("stats", {}).items():
        if entry.get("takes") and entry.get("usable_frames") == 0:
            out.append(
                _p(
                    "split_empty",
                    f"{MANIFEST_FILE}:stats.{split}",
                    f"its {entry['takes']} take(s) have no usable frame",
                    "warning",
                )
            )
    return out


def _scale_problems(manifest: dict[str, Any]) -> list[Problem]:
    """Animation scales that are not powers of two: the build rounds every one to 2^k so that
    normalising and back is exact (docs/dataset.md, Normalisation); another value was edited in."""

    scales = manifest["normalization"]["animation"]["scale"]
    channels = manifest["channels"]
    return [
        _p(
            "normalization_scale",
            f"{MANIFEST_FILE}:normalization.animation.scale[{c}]",
            f"{scale!r} ({channels[c]}) is not a power of two, as the build makes every scale",
        )
        for c, scale in enumerate(scales)
        if not is_power_of_two(float(scale))
    ]


def manifest_consistency(manifest: dict[str, Any]) -> list[Problem]:
    """Fields of a manifest (that passed ``manifest_schema``) that contradict each other: splits against
    samples, stats against samples, feature names against members and normalisation, empty splits,
    animation scales that are not powers of two."""
    return (
        _listing_problems(manifest)
        + _stats_problems(manifest)
        + _feature_problems(manifest)
        + _empty_split_problems(manifest)
        + _scale_problems(manifest)
    )


def _entry_mismatch(entry: dict[str, Any], found: dict[str, Any], fps: Any) -> list[Problem]:
    """A manifest sample entry against the sample found in a shard: its split (the shard's), its usable
    values (its members'), and the take, speaker, frames, usable frames and duration (within a frame)
    its metadata gives."""
    meta = found.get("meta") or {}
    held = {"split": found["split"], "usable_values": found.get("values")} | {
        k: meta.get(k) for k in ("take", "speaker", "frames", "usable_frames")
    }
    out = []
    for field, value in held.items():
        if field in entry and value is not None and entry[field] != value:
            out.append(
                _p(
                    "manifest_mismatch",
                    f"{MANIFEST_FILE}:samples[{entry['key']}].{field}",
                    f"manifest says {entry[field]!r}; the sample in {found['shard']} has {value!r}",
                )
            )
    duration = meta.get("duration_s")
    if isinstance(fps, (int, float)) and fps > 0 and isinstance(duration, (int, float)):
        if abs(entry.get("duration_s", duration) - duration) > 1.0 / fps:
            out.append(
                _p(
                    "manifest_mismatch",
                    f"{MANIFEST_FILE}:samples[{entry['key']}].duration_s",
                    f"manifest says {entry['duration_s']} s; the sample in {found['shard']} "
                    f"lasts {duration} s",
                )
            )
    return out


# ------------------------------------------------------------------------------------------ takes


def still_channels(
    stds: dict[str, np.ndarray], channels: list[str]
) -> dict[str, list[tuple[str, float, float]]]:
    """{take: [(channel, the take's std, median std over the takes)]} of the channels each take leaves
    still while the takes as a whole animate them (see ``MOVING_STD``, ``STILL_RATIO``); ``stds`` holds
    each take's per-channel standard deviation. Empty with fewer than ``MIN_TAKES`` takes."""
    if len(stds) < MIN_TAKES:
        return {}
    takes = sorted(stds)
    table = np.stack([np.asarray(stds[t], np.float64) for t in takes])
    median = np.median(table, axis=0)
    out: dict[str, list[tuple[str, float, float]]] = {}
    for take, row in zip(takes, table):
        still = np.flatnonzero((median >= MOVING_STD) & (row < STILL_RATIO * median))
        if still.size:
            out[take] = [(channels[c], float(row[c]), float(median[c])) for c in still]
    return out


def describe_still(found: list[tuple[str, float, float]]) -> str:
    listed = ", ".join(f"{name} (std {std:.3f}; median over takes {med:.3f})" for name, std, med in found)
    return (
        f"leaves still what the other takes animate: {listed}. A tracking or calibration fault, or a rig "
        "mapped differently? s2a-train's drop_takes leaves a take out of training"
    )


def validate_takes(manifest: dict[str, Any], seen: list[dict[str, Any]], **_: Any) -> list[Problem]:
    """Channels a take leaves still, from the usable animation frames of its samples (``seen[i]
    ["moments"]``: frame count, per-channel sums and sums of squares, or None); takes with less than
    ``MIN_TAKE_S`` of usable animation are left out."""
    sums: dict[str, list[np.ndarray]] = {}
    for s in seen:
        take = (s.get("meta") or {}).get("take")
        if take is None or s.get("moments") is None:
            continue
        moments = s["moments"]
        if take in sums:
            sums[take] = [a + b for a, b in zip(sums[take], moments)]
        else:
            sums[take] = list(moments)
    stds = {}
    fps = manifest.get("fps")
    min_frames = MIN_TAKE_S * fps if isinstance(fps, (int, float)) and fps > 0 else math.inf
    for take, (n, total, total_sq) in sums.items():
        if n.max() >= min_frames:
            mean = total / n
            stds[take] = np.sqrt(np.maximum(total_sq / n - mean * mean, 0.0))
    channels = list(manifest.get("channels", []))
    return [
        _p("still_channel", f"take {take}", describe_still(found), "warning")
        for take, found in still_channels(stds, channels).items()
    ]


def moments(anim: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(frame count per channel, sums, sums of squares) of (frames, channels) values, float64."""
    x = np.asarray(anim, np.float64)
    return np.full(x.shape[1], x.shape[0], np.float64), x.sum(0), (x * x).sum(0)


# ------------------------------------------------------------------------------------------ statistics
# --deep decodes every sample: the statistics the build stored in the manifest are gathered again with
# the build's own accumulators and fitted with its own functions. Sums come out in another order than
# the build's (per sample, not per take), so numbers agree to rounding; percentiles (and the neutral
# offset, a 5th percentile) to a histogram bin.


class Recomputed:
    """What the build computes from a dataset's frames, gathered from its decoded samples: per split
    the channel accumulator of the usable frames (a sample's ``neutral`` standing for its take's); over
    the training split each feature's sums; per take its voiced log-F0 sums, as the build's records."""

    def __init__(self, manifest: dict[str, Any]):

        self.n_channels = len(manifest["channels"])
        self.feature_names = [f for f in manifest["features"]["names"] if f != "pitch"]
        self.channels = {s: ChannelAccumulator(self.n_channels) for s in SPLITS}
        self.samples = dict.fromkeys(SPLITS, 0)
        self.features: dict[str, Any] = {}  # name: FeatureAccumulator over the training split
        self.takes: dict[str, dict[str, Any]] = {}  # take: {"speaker", "split", "pitch_stats"}

    def add(
        self, split: str, meta: dict[str, Any] | None, arrays: dict[str, np.ndarray], anim: np.ndarray
    ) -> None:
        """One decoded sample: its arrays, and ``anim`` its animation's usable frames."""

        if split not in self.channels or meta is None:
            return
        self.channels[split].add(anim, usable_neutral(meta.get("neutral"), self.n_channels))
        self.samples[split] += 1
        if split == "train":
            for name in self.feature_names:
                x = arrays.get(name)
                if x is not None and x.ndim == 2:
                    self.features.setdefault(name, FeatureAccumulator(x.shape[1])).add(x)
        pitch = arrays.get("pitch")
        if pitch is not None and pitch.ndim == 2 and pitch.shape[1] == 2:
            take = self.takes.setdefault(
                str(meta.get("take")),
                {
                    "speaker": str(meta.get("speaker")),
                    "split": split,
                    "pitch_stats": dict.fromkeys(("count", "sum", "sumsq"), 0),
                },
            )
            st = take["pitch_stats"]
            for key, value in voiced_log_f0_sums(pitch).items():  # every frame: a sample has no audio span
                st[key] += value


def _near(stored: Any, ours: float, tolerance: float) -> bool:
    """Whether a stored statistic agrees with the recomputed one (rounding to 6 decimals and to float32
    included)."""
    return is_finite_number(stored) and abs(stored - ours) <= tolerance + 2e-6 + 1e-6 * abs(ours)


def _distribution_problems(manifest: dict[str, Any], ours: Recomputed, complete: list[str]) -> list[Problem]:
    """stats.SPLIT.channels against the distributions of the split's decoded samples."""

    out: list[Problem] = []
    for split in complete:
        stored = manifest.get("stats", {}).get(split, {}).get("channels", {})
        for name, found in ours.channels[split].summary(manifest["channels"]).items():
            theirs = stored.get(name)
            at = f"{MANIFEST_FILE}:stats.{split}.channels.{name}"
            if not isinstance(theirs, dict):
                out.append(_p("stats_mismatch", at, "missing; the split's samples hold the channel"))
                continue
            if not found["frames"]:
                found = {"frames": 0}  # older builds stored 0, not null, for the rest of an empty channel
            for key, value in found.items():
                if key == "frames":
                    same = theirs.get(key) == value
                else:  # a percentile is read from the histogram: right to a bin
                    bins = float(histogram_resolution(value)) if key in ("p05", "p50", "p95") else 0.0
                    same = _near(theirs.get(key), value, bins)
                if not same:
                    out.append(
                        _p(
                            "stats_mismatch",
                            f"{at}.{key}",
                            f"says {theirs.get(key)!r}; the split's samples give {value:.6g}",
                        )
                    )
                    break  # one line per channel
    return out


def _animation_problems(manifest: dict[str, Any], ours: Recomputed) -> list[Problem]:
    """normalization.animation against the offsets and spreads the build fits to the training split."""

    norm = manifest["normalization"]["animation"]
    acc = ours.channels["train"]
    if norm.get("kind") not in KINDS:
        return []
    offset, spread = animation_statistics(norm["kind"], acc)
    out: list[Problem] = []
    at = f"{MANIFEST_FILE}:normalization.animation"
    for c, name in enumerate(manifest["channels"]):
        if not acc.count[c]:
            continue
        bin_width = float(histogram_resolution(offset[c])) if norm["kind"] == "neutral" else 0.0
        if not _near(norm["offset"][c], float(offset[c]), bin_width):
            out.append(
                _p(
                    "normalization_mismatch",
                    f"{at}.offset[{c}]",
                    f"{name}: says {norm['offset'][c]!r}; the training split's samples give {offset[c]:.6g}",
                )
            )
        # the build's rounding; a spread within a hair of the midpoint between two powers may round
        # either way with the sums in another order
        octave = math.log2(spread[c])
        nearest = {float(power_of_two(spread[c]))}
        if abs(octave % 1.0 - 0.5) < MIDPOINT_EPS:
            nearest |= {2.0 ** math.floor(octave), 2.0 ** math.ceil(octave)}
        if norm["scale"][c] not in nearest:
            out.append(
                _p(
                    "normalization_mismatch",
                    f"{at}.scale[{c}]",
                    f"{name}: says {norm['scale'][c]!r}; the training split's samples give "
                    f"{min(nearest):g} ({norm['kind']} spread {spread[c]:.6g})",
                )
            )
    return out


def _feature_norm_problems(manifest: dict[str, Any], ours: Recomputed) -> list[Problem]:
    """normalization.features.NAME against the training split's frames. The build counts only frames
    inside a take's audio, which a sample does not record: compared when the frame counts agree (the
    audio covers every frame, as align writes takes); more frames than the samples hold is wrong, fewer
    is a take with audio shorter than its frames (as in ``_pitch_norm_problems``)."""
    out: list[Problem] = []
    for name, st in manifest["normalization"].get("features", {}).items():
        acc = ours.features.get(name)
        at = f"{MANIFEST_FILE}:normalization.features.{name}"
        if acc is None or not _count(st.get("frames")):
            continue
        if st["frames"] > acc.count:
            out.append(
                _p(
                    "normalization_mismatch",
                    f"{at}.frames",
                    f"says {st['frames']}; the training split's samples hold {acc.count} frames",
                )
            )
        if st["frames"] != acc.count:
            continue  # fewer: a take's audio ends before its frames, which a sample does not record
        for key, values in zip(("mean", "std"), acc.mean_std(), strict=True):
            bad = [d for d, v in enumerate(values) if not _near(st[key][d], v, 1e-5 * abs(v))]
            if bad:
                d = bad[0]
                out.append(
                    _p(
                        "normalization_mismatch",
                        f"{at}.{key}[{d}]",
                        f"says {st[key][d]!r}; the training split's samples give {values[d]:.6g}"
                        + (f" ({len(bad)} dimensions differ)" if len(bad) > 1 else ""),
                    )
                )
    return out


def _pitch_norm_problems(manifest: dict[str, Any], ours: Recomputed) -> list[Problem]:
    """normalization.pitch.speakers against each speaker's voiced log-F0, as for the features: compared
    where the voiced frame counts agree, and more voiced frames than the samples hold is wrong."""
    from .build import pitch_normalization  # here: build imports this module

    stored = manifest["normalization"].get("pitch", {}).get("speakers", {})
    records = [ours.takes[t] for t in sorted(ours.takes)]  # in take order, as the build sums them
    found = pitch_normalization(records, sorted({r["speaker"] for r in records}))
    out: list[Problem] = []
    for speaker, mine in found.items():
        theirs = stored.get(speaker)
        at = f"{MANIFEST_FILE}:normalization.pitch.speakers.{speaker}"
        if not isinstance(theirs, dict) or not _count(theirs.get("voiced_frames")):
            continue  # a missing speaker or count is manifest_schema's
        if theirs["voiced_frames"] > mine["voiced_frames"]:
            out.append(
                _p(
                    "normalization_mismatch",
                    f"{at}.voiced_frames",
                    f"says {theirs['voiced_frames']}; the speaker's samples hold {mine['voiced_frames']} "
                    "voiced frames",
                )
            )
        if theirs["voiced_frames"] != mine["voiced_frames"]:
            continue  # fewer: a take's audio ends before its frames, which a sample does not record
        for key in ("mean", "std"):
            if not _near(theirs.get(key), mine[key], 1e-5 * abs(mine[key])):
                out.append(
                    _p(
                        "normalization_mismatch",
                        f"{at}.{key}",
                        f"says {theirs.get(key)!r}; the speaker's voiced log-F0 gives {mine[key]:.6g}",
                    )
                )
    return out


def validate_statistics(manifest: dict[str, Any], ours: Recomputed, **_: Any) -> list[Problem]:
    """The manifest's normalisation and channel distributions against those recomputed from the decoded
    samples (``validate --deep``), for the splits whose every sample decoded (the others' missing or
    damaged samples are reported already)."""
    listed = Counter(sample["split"] for sample in manifest["samples"])
    complete = [s for s in SPLITS if listed[s] and ours.samples[s] == listed[s]]
    out = _distribution_problems(manifest, ours, complete)
    if "train" in complete:
        out += _animation_problems(manifest, ours) + _feature_norm_problems(manifest, ours)
    # a held-out speaker's log-F0 statistics come from its takes in every split
    if "pitch" in manifest["features"]["names"] and all(ours.samples[s] == listed[s] for s in SPLITS):
        out += _pitch_norm_problems(manifest, ours)
    return out


VALIDATORS: dict[str, Callable[..., Any]] = {
    "manifest": validate_manifest,
    "shard": validate_shard,
    "sample": validate_sample,
    "splits": validate_splits,
    "takes": validate_takes,
}


@dataclass
class Report:
    dataset: str
    deep: bool
    shards: int
    samples: int
    problems: list[Problem]

    @property
    def valid(self) -> bool:
        return not any(p.severity == "error" for p in self.problems)

    def to_json(self) -> dict[str, Any]:
        return {
            "dataset": self.dataset,
            "valid": self.valid,
            "deep": self.deep,
            "shards": self.shards,
            "samples": self.samples,
            "errors": sum(p.severity == "error" for p in self.problems),
            "warnings": sum(p.severity == "warning" for p in self.problems),
            "problems": [p.to_json() for p in self.problems],
        }


def validate(ds: str | Path, deep: bool = False, progress: Callable[[str], None] | None = None) -> Report:
    """Check dataset ``ds`` against its manifest; every problem found is in the report.

    Raises ``InputError`` only when there is no manifest at all."""
    ds = Path(ds)
    if ds.is_file() and ds.name == MANIFEST_FILE:
        ds = ds.parent
    elif ds.exists() and not ds.is_dir():
        raise InputError("not a dataset (a file, not a dataset folder or its manifest.json)", ds)
    try:
        manifest = load_manifest(ds)
    except InputError as exc:
        if not (ds / MANIFEST_FILE).is_file():
            raise
        # a manifest that is there but unusable is a finding, reported like any other
        message = str(exc).split(": ", 1)[-1]
        return Report(str(ds), deep, 0, 0, [_p("manifest_schema", MANIFEST_FILE, message)])
    problems = list(VALIDATORS["manifest"](manifest))
    if problems:  # the shards cannot be checked against fields of the wrong types
        return Report(str(ds), deep, 0, 0, problems)
    seen: list[dict[str, Any]] = []
    listed = set()
    shards = manifest.get("shards", [])
    recomputed = Recomputed(manifest) if deep else None
    for i, entry in enumerate(shards, 1):
        name = entry.get("name", "?")
        listed.add(name)
        split = entry.get("split")

        def on_sample(
            key: str,
            members: dict[str, bytes],
            metadata: dict[str, Any] | InputError | None,
            name=name,
            split=split,
        ) -> None:
            decoded: list[tuple[dict[str, np.ndarray], np.ndarray]] = []
            found, meta = VALIDATORS["sample"](
                key,
                members,
                name,
                manifest,
                deep=deep,
                on_arrays=lambda a, u: decoded.append((a, u)),
                metadata=metadata,
            )
            problems.extend(found)
            sums = values = None
            if decoded:
                arrays, usable = decoded[0]
                anim = arrays["anim"][usable]  # the usable frames, masked once
                sums = moments(anim)
                if not any(p.code == "channel_mask" for p in found):  # checked there, not again here
                    values = usable_values(arrays, anim.shape[1])
                if recomputed is not None and not any(p.severity == "error" for p in found):
                    recomputed.add(split, meta, arrays, anim)
            seen.append(
                {"key": key, "shard": name, "split": split, "meta": meta, "moments": sums, "values": values}
            )

        problems.extend(VALIDATORS["shard"](entry, ds, manifest, deep=deep, on_sample=on_sample))
        if progress:
            progress(f"[{i}/{len(shards)}] {name}")
    problems.extend(VALIDATORS["splits"](manifest, seen))
    problems.extend(VALIDATORS["takes"](manifest, seen))
    if recomputed is not None:
        problems.extend(validate_statistics(manifest, recomputed))
    for p in sorted(ds.glob("*.tar")):
        if p.name not in listed and not is_litter(p):  # a copy's ._train-000000.tar is no shard
            problems.append(_p("shard_unlisted", p.name, "not listed in the manifest", "warning"))
    problems.extend(leftover_problems(ds))
    return Report(str(ds), deep, len(shards), len(seen), problems)


LEFTOVERS = (WORK, LOCK_FILE)


def _only_take_records(path: Path) -> bool:
    """Whether ``path`` is a ``.work`` folder holding nothing but the build's take records."""
    try:
        return path.name == WORK and path.is_dir() and {p.name for p in path.iterdir()} <= {TAKE_RECORDS}
    except OSError:
        return False


def leftover_problems(ds: Path) -> list[Problem]:
    """Warnings for what a build leaves only while it runs or when it was stopped: ``.work/``, its
    lock, hidden ``.NAME.partial`` files. A finished dataset to share has none (a ``.work`` holding only
    the take records a build keeps for the next, ``.work/takes``, is no leftover)."""
    found = sorted(
        p.name
        for p in ds.iterdir()
        if (p.name in LEFTOVERS or p.name.endswith(".partial")) and not _only_take_records(p)
    )
    if not found:
        return []
    state = (
        "a build is writing into this folder right now"
        if held_elsewhere(ds / LOCK_FILE)
        else "left by a build that failed or was stopped: rerun the build to finish it, or remove them "
        "before sharing"
    )
    return [_p("build_leftover", ", ".join(found[:4]) + (" ..." if len(found) > 4 else ""), state, "warning")]
