"""``s2a-dataset build``: aligned takes → features, normalisation statistics, splits, shards, manifest.

Stages, each resumable:

1. find takes (folders searched recursively); takes that are not aligned are aligned with ``align``
   into ``DS/.work/aligned`` (cached by the source take's sha256);
2. assign splits by take or speaker, resolve the channel selection (``varying`` looks at train only);
3. per take (``--jobs N`` processes): the one preprocessor computes every feature; the take is cut
   into samples of at most ``max_sample_s`` seconds, each written as a one-sample tar in
   ``DS/.work/samples``, then a per-take record with its statistics (written last, so its presence
   means the take is done; a rerun skips it);
4. statistics of the training split are merged in take order; shards are planned from sample sizes
   (size-capped, keys sorted) and written atomically into ``DS/.work/staged`` (a shard the folder holds
   byte for byte already stays where it is); then they are swapped in and the manifest written last
   (``_swap_in``): a rebuild that fails or is stopped before leaves the previous dataset as it was.

Everything written depends only on the inputs and options (no clocks, no paths of the output, one
thread per process), so an interrupted and resumed build equals an uninterrupted one byte for byte.
Memory is bounded by the largest take, not by the dataset.
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import json
import math
import os
import re
import shutil
import sys
import time
from collections import Counter
from collections.abc import Callable, Iterator
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass, field
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

from capture.atomic import atomic_write, naming_failures, write_json_atomic
from capture.audio_io import Audio
from capture.channels import CHANNEL_SETS, ROTATIONS, canonical, channel_set, is_known
from capture.command import TimedProgress, sigterm_stops, stops_deferred
from capture.errors import InputError, S2AError, loads_names, shown_against, strict_names
from capture.file_lock import holding
from capture.importer import no_takes_found
from capture.npz import open_npz
from capture.numbers import is_count
from capture.take import (
    META_FILE,
    FrameStatus,
    Take,
    TakeMeta,
    find_takes,
    read_meta,
    read_take,
    sha256_file,
    write_take,
)
from capture.workers import submit_all, worker_pool

from .features import (
    DEFAULT_FEATURES,
    DEFAULT_LEVEL,
    FeatureSettings,
    compute_features,
    gain_for_level,
    parse_features,
    speech_level,
)
from .manifest import (
    LOCK_FILE,
    MANIFEST_FILE,
    TAKE_RECORDS,
    WORK,
    manifest_path,
    read_manifest,
    write_manifest,
)
from .normalize import (
    HIST_LAYOUT,
    KINDS,
    ChannelAccumulator,
    FeatureAccumulator,
    fit_normalizer,
    usable_neutral,
    voiced_log_f0_sums,
)
from .qa import ANIM_LIMIT, BASE_MEMBERS
from .shards import CHANNEL_MASK, ShardReader, ShardWriter, flac_bytes, json_bytes, npy_bytes, sample_size
from .splits import SPLITS, SplitRule, assign_splits, pinned_groups, speaker_key

# Part of every take's cache key and of the build's fingerprint: raised when what a take gives the dataset
# changes for the same input, so that a rebuild into an existing folder processes its takes again rather
# than keeping their earlier results (2: a take whose weights are on another scale gives none of its frames;
# 3: a glitch masks its channel only, kept apart in channel_mask.npy).
DATASET_VERSION = "3"
USABLE_STATUS = (0, 4)  # FrameStatus.TRACKED, FrameStatus.INTERPOLATED (align fills short gaps)
MAX_INTERPOLATED_SHARE = 0.5  # of a take's usable frames; beyond it the targets are mostly not measured
METRIC_CHANNELS = ("jawOpen", "mouthClose")  # the paper's "crucial" RMSE needs both
SHARD_NAME = re.compile(r"^(train|val|test)-\d{6}\.tar$")
MIN_USABLE_SHARE = 0.5  # a take with fewer usable frames than this share of its frames is warned about
# A take with more frames beyond ANIM_LIMIT than this share, a channel beyond it also past WEIGHT_REACH in
# over a tenth of the frames within it (``on_another_scale``), has values on another scale (0..100, 0..255,
# degrees, dB): not a glitch, and its quiet frames within reach are as wrong, so none of its frames is usable.
WRONG_SCALE_SHARE = 0.1
WEIGHT_REACH = 1.5  # a weight (0..1, the app's within about ±1.05) or an angle in radians stays within it
CONTENT_FEATURES = ("fbank", "mfcc", "ppg")
MAX_AUDIO_PEAK = 1000.0  # float audio this far past full scale (60 dB) is damaged, not loud
STRAY_FACTOR = 10.0  # 10 ms frames past full scale this far above the take's loud-frame RMS are stray
QUIET_GAIN = 10 ** (40 / 20)  # the level normalisation raising a take by more than 40 dB is warned about
NARROWBAND_HZ = 4500.0  # above the 4 kHz band edge of 8 kHz audio and its resampler's transition band
# align's flags that say the audio/face offset must not be trusted blindly (docs/align.md)
UNTRUSTED_FLAGS = (
    "evidence_disagrees",
    "low_confidence",
    "no_evidence",
)  # what a model reads the words from (pitch, energy: prosody)


@dataclass
class BuildOptions:
    """Everything that decides a dataset's content. ``shard_bytes`` caps a shard (a single larger
    sample gets a shard of its own); ``max_sample_s`` caps one sample's duration in seconds."""

    channels: str = "pronunciation32"
    features: tuple[str, ...] = DEFAULT_FEATURES
    ppg: str = "none"
    ppg_model: str | None = None
    normalization: str = "zscore"
    split: SplitRule = field(default_factory=SplitRule)
    shard_bytes: int = 256 * 1024 * 1024
    max_sample_s: float = 30.0
    jobs: int = 1
    keep_work: bool = False
    settings: FeatureSettings = field(default_factory=lambda: FeatureSettings(level=DEFAULT_LEVEL))
    skip_flagged: bool = False  # leave out takes whose audio/face offset align did not trust

    def __post_init__(self) -> None:
        self.features = parse_features(self.features)
        if self.ppg != "none" and "ppg" not in self.features:
            self.features = parse_features((*self.features, "ppg"))
        if "ppg" in self.features and self.ppg == "none":
            raise InputError("feature 'ppg' needs a backend: --ppg bottleneck|torchscript|onnx|pocketsphinx")
        if self.normalization not in KINDS:
            raise InputError(f"--normalization must be one of {', '.join(KINDS)}")
        if not set(self.features) & set(CONTENT_FEATURES):
            raise InputError(
                f"--features {','.join(self.features) or '(none)'} holds no content feature: a model needs "
                f"one of {', '.join(CONTENT_FEATURES)} (--ppg adds ppg)"
            )
        if self.shard_bytes < 1:  # the command line says it in MB first (dataset.cli)
            raise InputError(f"a shard's size cap must be at least one byte, not {self.shard_bytes}")
        if not 0 < self.max_sample_s < math.inf:
            raise InputError(f"--max-sample-s must be a positive number of seconds, not {self.max_sample_s}")
        if self.jobs < 1:
            raise InputError(f"--jobs must be at least 1 (worker processes), not {self.jobs}")


# ------------------------------------------------------------------------------------------ takes


@dataclass
class SourceTake:
    """An aligned take folder ready for the build, and where it came from."""

    folder: Path
    id: str
    key: str
    sha256: str
    speaker: str
    speaker_assumed: bool
    duration_s: float
    fps: float
    channels: list[str]
    source: dict[str, Any]
    content_sha256: str
    recording: str = ""  # the raw take align cut this one from (its own id when not cut)
    notes: list[str] = field(default_factory=list)  # warnings about the take (align's flags, clipping)

    @property
    def given(self) -> Path:
        """The folder to name in a message: the raw take the user gave for one the build aligned (its copy
        under ``DS/.work/aligned/`` is no folder of theirs), else ``folder``."""
        return Path(self.source["path"]) if "aligned_from_sha256" in self.source else self.folder


RACY_NS = 3_000_000_000  # files modified this recently are hashed afresh (see _file_digests)
TAKE_SWAP_S = 1.0  # how long a take folder that lost its files while read is waited for (see _take_read)


def _identity(folder: Path) -> tuple[int, int] | None:
    try:
        st = os.stat(folder)
    except OSError:
        return None
    return st.st_dev, st.st_ino


@contextmanager
def _take_read(folder: str | Path) -> Iterator[None]:
    """Reading the take folder ``folder``. ``s2a-align --force`` rewriting a take swaps a new folder in,
    where the file system cannot exchange two folders in one step by moving the old one aside for a
    moment: a read then found no meta.json and said "not a take folder". When the folder changed while
    it was read (another folder at its path now, or its meta.json back within ``TAKE_SWAP_S``), the
    error says so; a folder that just lacks meta.json (or is gone) keeps its error."""
    folder = Path(folder)
    before = _identity(folder)
    try:
        yield
    except (InputError, FileNotFoundError, NotADirectoryError) as exc:
        if _changed_while_read(folder, before):
            raise InputError(
                f"the take folder changed while it was read (is s2a-align writing into {folder.parent}?): "
                "run the build again once it is done",
                folder,
            ) from exc
        raise


def _changed_while_read(folder: Path, before: tuple[int, int] | None) -> bool:
    """Whether another folder stands at ``folder`` than ``before`` (its identity as a read began), or a
    folder that lacked meta.json (or was missing) has it again within ``TAKE_SWAP_S``."""
    now = _identity(folder)
    if now is not None and before is not None and now != before:
        return True
    if (folder / META_FILE).is_file():
        return False  # there all along: the error is about the take itself
    deadline = time.monotonic() + TAKE_SWAP_S
    while time.monotonic() < deadline:
        time.sleep(0.02)
        now = _identity(folder)
        if now is not None and ((folder / META_FILE).is_file() or (before is not None and now != before)):
            return True
    return False


def _file_digests(folder: Path) -> dict[str, str]:
    """sha256 of each (non-hidden) file of a take folder, by name."""
    files = sorted(p for p in folder.iterdir() if p.is_file() and not p.name.startswith("."))
    digests = {}
    for p in files:
        st = p.stat()
        # a file changed in the last seconds may change again within the clock's granularity: no cache
        if time.time_ns() - st.st_mtime_ns < RACY_NS:
            digests[p.name] = sha256_file(p)
        else:
            digests[p.name] = _sha256_of(str(p.resolve()), st.st_size, st.st_mtime_ns, st.st_ino)
    return digests


@functools.lru_cache(maxsize=4096)
def _sha256_of(path: str, size: int, mtime_ns: int, inode: int) -> str:
    """A file's sha256, read once per (path, size, modification time, inode): one build asks for a
    take's digests twice (the input fingerprint, then the takes it collects)."""
    return sha256_file(path)


def _combine(digests: dict[str, str], skip: tuple[str, ...] = ()) -> str:
    lines = "".join(f"{name} {sha}\n" for name, sha in sorted(digests.items()) if name not in skip)
    return hashlib.sha256(lines.encode()).hexdigest()


def take_sha256(folder: str | Path) -> str:
    """sha256 of a take folder: of the lines ``"<file name> <sha256 of file>\\n"`` for meta.json,
    frames.npz and the audio file, in name order."""
    return _combine(_file_digests(Path(folder)))


def take_and_content_sha256(folder: str | Path) -> tuple[str, str]:
    """``take_sha256`` and the sha256 of what the take holds, not what it is called (the same without
    meta.json, so a copy of a take under another id is recognised as a duplicate); files hashed once."""
    digests = _file_digests(Path(folder))
    return _combine(digests), _combine(digests, skip=("meta.json",))


def sample_key_base(take_id: str) -> str:
    """A WebDataset-safe key stem for a take id (no dots or slashes)."""
    return re.sub(r"[^A-Za-z0-9_-]", "_", take_id) or "take"


def _distinct_keys(takes: list[SourceTake]) -> list[str]:
    """Give takes whose ids map to one sample key (``take.1`` and ``take_1``) keys of their own: the
    stem plus 8 hex digits of the id's sha256, for every take of the clash, whatever the input order.
    Returns a warning per clash."""
    by_key: dict[str, list[SourceTake]] = {}
    for t in takes:
        by_key.setdefault(t.key.casefold(), []).append(t)
    warnings = []
    for clash in (group for group in by_key.values() if len(group) > 1):
        for t in clash:
            t.key = f"{t.key}-{hashlib.sha256(os.fsencode(t.id)).hexdigest()[:8]}"
        warnings.append(
            "take ids " + ", ".join(repr(t.id) for t in clash) + " give one sample key: their samples are "
            "keyed " + ", ".join(t.key for t in clash)
        )
    return warnings


def _one_spelling_per_speaker(takes: list[SourceTake]) -> list[str]:
    """Speakers whose names differ only in case or spacing (``Anna`` and ``anna ``, typed on two
    phones) are one speaker, named by the first spelling in sort order; a speaker split would
    otherwise put one person in train and test. Returns a warning per merged name. Only ``meta.subject``
    names are merged: an assumed speaker is a recording id, and ``Take1`` and ``take1`` are two."""
    named = [t for t in takes if not t.speaker_assumed]
    spellings: dict[str, set[str]] = {}
    for t in named:
        spellings.setdefault(speaker_key(t.speaker), set()).add(t.speaker)
    warnings = []
    for names in (sorted(n) for n in spellings.values() if len(n) > 1):
        for t in named:
            if t.speaker in names:
                t.speaker = names[0]
        warnings.append(
            "speakers "
            + ", ".join(map(repr, names))
            + f" differ only in case or spacing: one speaker, {names[0]!r}"
        )
    return warnings


def _align_module():
    try:
        import align
    except ImportError:
        return None
    return align


def _is_aligned(meta: TakeMeta) -> bool:
    """The align contract: an aligned take says so in ``meta.source_kind`` (cheap: no arrays read)."""
    return meta.source_kind == "aligned"


def _aligned_folders(
    folder: Path, sha: str, meta: TakeMeta, work: Path, say: Callable[[str], None]
) -> list[Path]:
    """Aligned take folders for the unaligned take ``folder`` (``take_sha256`` ``sha``), made once with
    ``align.align_take`` and cached."""
    align = _align_module()
    if align is None:
        raise InputError(
            f"take is not aligned (source_kind {meta.source_kind!r}) and the align stage is not installed; "
            "align it with s2a-align first",
            folder,
        )
    out = work / "aligned" / sha[:24]
    done = out / "done.json"
    if done.is_file():
        names = _read_work_json(done)["takes"]
        return [out / n for n in names]
    say(f"aligning {meta.id}")
    results = align.align_take(read_take(folder), align.AlignOptions())
    if not results:
        raise InputError("align produced no usable take (no speech or no tracked frames?)", folder)
    out.mkdir(parents=True, exist_ok=True)
    names = [write_take(t, out).name for t in results]
    _write_work_json(done, {"source": str(folder), "sha256": sha, "takes": names})
    return [out / n for n in names]


def unalignable_takes(errors: list[str]) -> InputError:
    """The one error for the raw takes align could not use (``errors``: why, for each): all named at once
    (the first three shown), with the way to build from the others. Before, a build stopped at the first,
    and a batch of clips with forty silent ones took forty runs to find them."""
    shown = "; ".join(errors[:3]) + (f"; and {len(errors) - 3} more" if len(errors) > 3 else "")
    return InputError(
        f"{len(errors)} raw take(s) cannot be aligned ({shown}): align the takes with s2a-align -o ALIGNED, "
        "which writes those it can and names the others, and build from ALIGNED; or remove these takes"
    )


def _malformed(field_name: str, what: str, value: Any, folder: str | Path | None) -> InputError:
    """The one-line error for an align field of the wrong type, naming the take's meta.json, as
    ``read_meta`` does for the other fields: a malformed field must not be read as "absent"."""
    path = Path(folder) / META_FILE if folder is not None else None
    return InputError(f"malformed metadata: {field_name} must be {what}, not {value!r:.60}", path)


def _align_record(meta: TakeMeta, folder: str | Path | None = None) -> dict[str, Any]:
    """The report align wrote into an aligned take (``extra.align``), or ``{}`` when there is none."""
    record = meta.extra.get("align")
    if record is None:
        return {}
    if not isinstance(record, dict):
        raise _malformed("extra.align", "an object (align's report)", record, folder)
    return record


def recording_of(meta: TakeMeta, folder: str | Path | None = None) -> str:
    """The id of the raw take an aligned take was cut from (align's ``extra.align.parent.id``; a bare
    id is read too), else the take's own id: the unit a split keeps together. ``folder``: the take's,
    named when the field is malformed."""
    parent = _align_record(meta, folder).get("parent")
    if parent is None:
        return meta.id
    parent_id = parent.get("id") if isinstance(parent, dict) else parent
    if not isinstance(parent_id, str) or not parent_id.strip():
        raise _malformed("extra.align.parent", "an object whose id names the raw take", parent, folder)
    return parent_id


def _align_flags(meta: TakeMeta, folder: str | Path | None = None) -> list[str]:
    """All the flags align raised about a take (``extra.align.flags``); a malformed list is an error,
    since reading it as "no flags" would keep a take ``--skip-flagged`` leaves out."""
    flags = _align_record(meta, folder).get("flags")
    if flags is None:
        return []
    if not isinstance(flags, list) or not all(isinstance(f, str) for f in flags):
        raise _malformed("extra.align.flags", "a list of flag names", flags, folder)
    return flags


def incomplete_segment_warnings(aligned: list[tuple[Path, TakeMeta]]) -> list[str]:
    """A warning for each raw take of which fewer segments are among the aligned takes ``(folder,
    meta)`` than align cut from it (``extra.align.segment`` of ``segment_count``, counted per raw take
    and align run): an s2a-align killed, or out of disk, while renaming them into place, or segments
    deleted; the dataset would hold part of the recording."""
    found: dict[tuple[str, str], tuple[int, set[int], Path]] = {}
    for folder, meta in aligned:
        record = _align_record(meta, folder)
        count, number = record.get("segment_count"), record.get("segment")
        if not (is_count(count) and is_count(number) and 1 <= number <= count):
            continue
        key = (recording_of(meta, folder), str(record.get("fingerprint")))
        found.setdefault(key, (count, set(), folder.parent))[1].add(number)
    out = []
    for (recording, _), (count, numbers, where) in sorted(found.items()):
        if len(numbers) < count:
            missing = [f"{recording}.seg{k:02d}" for k in range(1, count + 1) if k not in numbers]
            out.append(
                f"take {recording}: {where} holds {len(numbers)} of the {count} segments s2a-align cut "
                f"from it ({', '.join(missing[:3])}{' ...' if len(missing) > 3 else ''} missing: an "
                "s2a-align run stopped while writing them?), so the dataset holds only part of the "
                "recording: re-run s2a-align on the raw take to write them all"
            )
    return out


def aligned_twice_warnings(aligned: list[tuple[Path, TakeMeta]]) -> list[str]:
    """A warning for each raw take that the aligned takes built ``(folder, meta)`` hold from more than one
    s2a-align run with other options (two fingerprints of align's record): both runs' segments are
    built, so its speech counts twice. (Runs that cut it alike give takes of one id, refused as such,
    or skipped as duplicates.)"""
    runs: dict[str, dict[str, set[Path]]] = {}
    for folder, meta in aligned:
        run = _align_record(meta, folder).get("fingerprint")
        if isinstance(run, str):
            runs.setdefault(recording_of(meta, folder), {}).setdefault(run, set()).add(folder.parent)
    out = []
    for recording, by_run in sorted(runs.items()):
        if len(by_run) > 1:
            times = "twice" if len(by_run) == 2 else f"{len(by_run)} times"
            places = sorted({str(p) for where in by_run.values() for p in where})
            shown = ", ".join(places[:-1]) + f" and {places[-1]}" if len(places) > 1 else places[0]
            out.append(
                f"take {recording}: aligned {times} with other options (in {shown}): the segments of each "
                f"are built, so its speech counts {times} in the dataset: build from one of those folders"
            )
    return out


def collect_takes(
    inputs: list[str | Path], work: Path, say: Callable[[str], None], skip_flagged: bool = False
) -> tuple[list[SourceTake], list[str], dict[str, str]]:
    """Aligned takes from ``inputs`` (aligning raw ones), de-duplicated; also returns warnings and the
    takes left out (``{take id, recording and speaker: why}``). Takes whose offset align flagged are
    warned about, or left out with ``skip_flagged``; raw takes of which only some segments are here too
    (``incomplete_segment_warnings``)."""
    warnings: list[str] = []
    left_out: dict[str, str] = {}
    folders = find_takes(inputs)
    if not folders:
        raise no_takes_found(inputs, "s2a-dataset build")
    seen_paths: set[Path] = set()
    takes: list[SourceTake] = []
    candidates: list[SourceTake] = []
    skipped: dict[str, str] = {}  # take id: why --skip-flagged left it out
    by_id: dict[str, SourceTake] = {}
    by_sha: dict[str, SourceTake] = {}
    segments: list[tuple[Path, TakeMeta]] = []  # every aligned take, to find incomplete segment sets
    # hundreds of raw takes to align are not hundreds of lines: the first said at once, then a line
    # every few seconds
    reading = TimedProgress("reading takes", len(folders), "takes", say)
    aligned_now = 0
    unalignable: list[str] = []  # why each raw take align cannot use failed

    def aligning(message: str) -> None:
        nonlocal aligned_now
        reading.update(detail=message, at_once=not aligned_now)
        aligned_now += 1

    for i, folder in enumerate(folders, 1):
        resolved = folder.resolve()
        if resolved in seen_paths or (WORK in resolved.parts):
            reading.update(i)
            continue
        seen_paths.add(resolved)
        with _take_read(folder):
            meta = read_meta(folder)
            origin: dict[str, Any] = {"path": str(resolved), "source_kind": meta.source_kind}
            if _is_aligned(meta):
                aligned = [folder]
            else:
                origin["sha256"] = take_sha256(folder)
                try:
                    aligned = _aligned_folders(folder, origin["sha256"], meta, work, aligning)
                except InputError as exc:  # the others are still aligned: every such take is told at once
                    if _align_module() is None:  # the same for every take: said once
                        raise
                    unalignable.append(str(exc))
                    reading.update(i)
                    continue
        reading.update(i, meta.id if aligned == [folder] else f"{meta.id} aligned: {len(aligned)} take(s)")
        for af in aligned:
            with _take_read(af):
                m = read_meta(af)
            if m.audio is None:
                raise InputError("aligned take has no audio; a dataset needs speech", af)
            if m.audio.sample_rate != 16000:
                raise InputError(
                    f"aligned take audio is {m.audio.sample_rate} Hz; expected 16000 (re-run align)", af
                )
            if abs(m.audio.start_s) > 1e-9:
                raise InputError(
                    f"aligned take audio starts at {m.audio.start_s} s; expected 0 (re-run align)", af
                )
            segments.append((af, m))
            all_flags = _align_flags(m, af)
            flags = [f for f in all_flags if f in UNTRUSTED_FLAGS]  # about its audio/face offset
            # a take naming no subject counts as its recording's speaker, with the other segments align
            # cut from it: as a speaker of its own, one session could sit on both sides of a speaker split
            recording = recording_of(m, af)
            speaker = m.subject or recording
            if flags and skip_flagged:
                # keyed by take id: the raw and the aligned copy of one take are told once
                named = ", ".join(flags)
                skipped[m.id] = (
                    f"take {m.id}: align flagged its audio/face offset ({named}): left out (--skip-flagged)"
                )
                why = f"left out by --skip-flagged (align flagged {named})"
                left_out.update(dict.fromkeys((m.id, recording, speaker), why))
                continue
            notes = []  # said only of the takes kept: a duplicate's would repeat its twin's
            if flags:
                notes.append(
                    f"take {m.id}: align flagged its audio/face offset ({', '.join(flags)}): check it, or "
                    "build with --skip-flagged"
                )
            record = _align_record(m, af)
            clipped = record.get("clipped_audio")
            if af != folder:
                # aligned here, not by the user: what align warned about the take (with its first segment)
                if record.get("segment", 1) == 1 and isinstance(record.get("warnings"), list):
                    notes += [w for w in record["warnings"] if isinstance(w, str)]
            elif (
                record.get("segment", 1) == 1 and isinstance(clipped, float) and "clipped_audio" in all_flags
            ):
                # the recording's audio: said with its first segment, as align's warnings are
                notes.append(
                    f"take {m.id}: align found {clipped:.2%} of its audio samples clipped at full scale "
                    "(its loudest sounds are distorted)"
                )
            with _take_read(af):
                sha, content_sha = take_and_content_sha256(af)
            st = SourceTake(
                af,
                m.id,
                sample_key_base(m.id),
                sha,
                speaker,
                not m.subject,
                m.audio.samples / m.audio.sample_rate,
                float(m.fps),
                list(m.channels),
                origin | {"take": m.id, "sha256": sha},
                content_sha,
                recording,
                notes,
            )
            if af != folder:
                st.source["aligned_from_sha256"] = origin["sha256"]
            candidates.append(st)
    if unalignable:
        raise unalignable_takes(unalignable)
    warnings += incomplete_segment_warnings(segments)
    warnings += skipped.values()
    # duplicates in id order (the first id is kept), whatever the order of the inputs
    for st in sorted(candidates, key=lambda t: (t.id, t.source["path"])):
        if st.content_sha256 in by_sha:
            twin = by_sha[st.content_sha256].id
            warnings.append(
                f"take {st.id} ({st.source['path']}) has the same frames and audio as take {twin}: "
                "skipped as a duplicate"
            )
            left_out.setdefault(st.id, f"skipped as a duplicate of take {twin} (same frames and audio)")
            continue
        if st.id in by_id:
            raise InputError(
                f"two different takes share the id {st.id!r} (also {by_id[st.id].given})", st.given
            )
        by_id[st.id] = by_sha[st.content_sha256] = st
        takes.append(st)
        warnings += st.notes
    # of the takes built: a duplicate skipped, or a take --skip-flagged left out, counts no speech
    built = {t.folder for t in takes}
    warnings += aligned_twice_warnings([(af, m) for af, m in segments if af in built])
    if not takes:
        raise InputError("no take is left to build from: " + "; ".join(warnings))
    takes.sort(key=lambda t: t.id)
    warnings += _distinct_keys(takes) + _one_spelling_per_speaker(takes)
    first_at: dict[float, SourceTake] = {}  # a take of each frame rate, to name in the error
    for t in takes:
        first_at.setdefault(round(t.fps, 6), t)
    if len(first_at) > 1:
        # the user's input, not the copy the build aligned from it under .work/
        examples = ", ".join(f"{rate:g} fps: {first_at[rate].source['path']}" for rate in sorted(first_at))
        raise InputError(
            f"takes have different frame rates ({examples}); align them to one rate (s2a-align --fps) or "
            "build separate datasets"
        )
    return takes, warnings, left_out


def resolve_channels(
    spec: str, takes: list[SourceTake], splits: dict[str, str]
) -> tuple[list[str], list[str]]:
    """Channel names selected by ``spec`` (set name, ``varying``, ``all`` or a comma list), and warnings."""
    warnings: list[str] = []
    key = spec.strip().lower()
    first = takes[0].channels
    if key in ("varying", "all"):
        ours = Counter(c.lower() for c in first)
        for t in takes:  # the same channels, in any order (each take's are picked by name)
            theirs = Counter(c.lower() for c in t.channels)
            if theirs != ours:
                odd = sorted(((theirs - ours) + (ours - theirs)).elements())
                raise InputError(
                    f"--channels {key} needs takes with the same channels; {t.id} differs from "
                    f"{takes[0].id} (they differ in {', '.join(odd[:5])})"
                )
        if key == "all":
            names = list(first)
        else:
            lo = np.full(len(first), np.inf)
            hi = np.full(len(first), -np.inf)
            for t in takes:
                if splits[t.id] != "train":
                    continue
                with open_npz(t.folder / "frames.npz") as z:
                    v, s = z["values"], z["frame_status"]
                column = {c.lower(): j for j, c in enumerate(t.channels)}
                v = v[:, [column[c.lower()] for c in first]]  # in the first take's order
                v = v[np.isin(s, USABLE_STATUS)]
                v = np.where(np.isfinite(v), v, np.nan)
                if v.size:
                    lo = np.fmin(lo, np.nanmin(v, 0))
                    hi = np.fmax(hi, np.nanmax(v, 0))
            names = [c for c, a, b in zip(first, lo, hi, strict=True) if np.isfinite(a) and b - a > 1e-6]
            if not names:
                raise InputError("--channels varying: no channel moves in the training split")
    elif key in CHANNEL_SETS:
        names = list(channel_set(spec))
    else:
        # Live Link channels in any spelling and a rig's own names (generic paired import), the latter
        # matched case-insensitively against the takes' channels
        given = [p.strip() for p in spec.split(",") if p.strip()]
        names = [canonical(n) if is_known(n) else n for n in given]
        if not names:
            raise InputError(f"empty channel selection {spec!r}")
        # names are matched to the takes' channels without case, and Live Link names in any spelling:
        # one channel named twice would give identical columns and one key in the statistics
        seen: dict[str, str] = {}
        for spelled, name in zip(given, names, strict=True):
            if name.lower() in seen:
                raise InputError(
                    f"--channels names one channel twice ({seen[name.lower()]!r} and {spelled!r}: case and "
                    "Live Link spellings are ignored)"
                )
            seen[name.lower()] = spelled
        held = {c.lower() for t in takes for c in t.channels}
        unknown = [n for n in names if not is_known(n) and n.lower() not in held]
        if unknown:
            raise InputError(
                f"unknown channel {unknown[0]!r}: neither a Live Link channel nor a channel of the takes "
                f"(sets: {', '.join(CHANNEL_SETS)}, varying, all)"
            )
    for t in takes:
        have = {c.lower(): c for c in t.channels}
        missing = [n for n in names if n.lower() not in have]
        if missing:
            shown = ", ".join(missing[:5]) + (" ..." if len(missing) > 5 else "")
            raise InputError(
                f"take {t.id} lacks {len(missing)} selected channel(s) ({shown}); "
                "choose --channels varying, all, or a list of its channels",
                t.given,
            )
    lowered = {n.lower() for n in names}
    lacking = [need for need in METRIC_CHANNELS if need.lower() not in lowered]
    if lacking:
        warnings.append(
            f"the selection lacks {' and '.join(lacking)} (MetaHuman rigs, for one, lack mouthClose): the "
            "'crucial' RMSE over jawOpen and mouthClose cannot be computed on this dataset"
        )
    return names, warnings


# ------------------------------------------------------------------------------------------ per take


@dataclass
class TakeJob:
    """What one worker needs to turn a take into samples (all picklable)."""

    folder: str
    take_id: str
    key: str
    sha256: str
    content_sha256: str
    speaker: str
    split: str
    channels: list[str]
    features: tuple[str, ...]
    ppg: str
    ppg_model: str | None
    max_sample_s: float
    settings: FeatureSettings
    work: str
    config_hash: str
    given: str = ""  # the take the user gave, to name in errors: for one the build aligned, the raw take

    @property
    def record(self) -> Path:
        return Path(self.work) / TAKE_RECORDS / f"{self.key}.json"

    @property
    def stats(self) -> Path:
        return Path(self.work) / TAKE_RECORDS / f"{self.key}.stats.npz"


_EXTRACTORS: dict[tuple[str, str | None], Any] = {}


def _extractor(backend: str, model: str | None):
    if backend == "none" and model is None:
        return None
    if (backend, model) not in _EXTRACTORS:
        from .ppg import make_extractor

        _EXTRACTORS[(backend, model)] = make_extractor(backend, model)
    return _EXTRACTORS[(backend, model)]


# Resampling and align's high-pass lift a recording that reaches full scale past it by up to about 1 dB
# (measured: 1.012 on the simulator's takes): such audio is scaled back (audio_gain) without a warning.
FILTER_OVERSHOOT = 10 ** (1 / 20)
NARROWBAND_BLOCK = 1 << 20  # samples per block of the narrowband check's spectrum


def is_narrowband(audio: np.ndarray, sample_rate: int) -> bool:
    """Whether speech ``audio`` carries (almost) no energy between ``NARROWBAND_HZ`` and 7.5 kHz, as
    audio recorded at 8 kHz and resampled does: under 1e-5 of its power (measured: 3e-7..1.5e-6 for
    LibriVox speech through 8 kHz, 1e-3..2e-2 for the same speech at 16 kHz)."""
    if audio.size < 2048 or sample_rate < 16000:
        return False
    import scipy.signal  # here, not at the top: scipy.signal costs 0.6 s of every command's start

    power = 0.0
    block = NARROWBAND_BLOCK
    for start in range(0, audio.size, block):  # a block at a time: memory stays small for long audio
        part = audio[start : start + block]
        if part.size >= 1024:
            freqs, p = scipy.signal.welch(part.astype(np.float64), fs=sample_rate, nperseg=1024)
            power = power + p * part.size
    total = float(np.sum(power))
    band = (freqs > NARROWBAND_HZ) & (freqs < 7500.0)
    return total > 0 and float(power[band].sum()) < 1e-5 * total


def mono_padded(audio: Audio, length: int) -> np.ndarray:
    """A take's audio as mono float32 in [-1, 1) (channels averaged, as ``Audio.mono_float``), zero-padded
    to ``length`` samples: filled a block at a time (``align.resample.mono_blocks``), so that an hour of
    audio is held once here besides the take's own samples, not three times (``mono_float`` converts,
    averages and copies all at once)."""
    from align.resample import gathered, mono_blocks

    return gathered(mono_blocks(audio), np.zeros(length, np.float32))


def audio_gain(audio: np.ndarray, sample_rate: int, peak: float | None = None) -> tuple[float, np.ndarray]:
    """The factor that brings float audio past full scale back to a peak of 1 (FLAC would clip it),
    and the stray samples left out of that peak (a bool mask): the 10 ms frames (and the frames either
    side) that hold a sample past full scale and whose RMS is over ``STRAY_FACTOR`` times the take's
    loud-frame level (the 99th percentile of frame RMS; real speech peaks at 2.6-4.6 times it), such as
    one damaged sample that the resampler spread over its neighbours. A stray burst must not scale the
    whole take's speech down: it is muted instead (set to 0, as NaN samples are on import). ``peak``:
    the audio's largest magnitude, when the caller has it."""
    if peak is not None and peak <= 1.0:
        return 1.0, np.zeros(np.size(audio), bool)
    mag = np.abs(np.asarray(audio, np.float32))
    if (peak if peak is not None else float(mag.max(initial=0.0))) <= 1.0:
        return 1.0, np.zeros(mag.size, bool)
    step = max(1, sample_rate // 100)
    n = -(-mag.size // step)
    frames = np.pad(mag, (0, n * step - mag.size)).astype(np.float64).reshape(n, step)
    rms = np.sqrt(np.mean(frames * frames, axis=1))
    burst = (rms > STRAY_FACTOR * float(np.percentile(rms, 99))) & (frames.max(axis=1) > 1.0)
    burst[1:] |= burst[:-1].copy()
    burst[:-1] |= burst[1:].copy()  # and the frames either side, where the damage rings
    stray = np.repeat(burst, step)[: mag.size]
    kept = float(np.max(mag[~stray], initial=0.0))
    return (1.0 / kept if kept > 1.0 else 1.0), stray


def check_frame_grid(times: np.ndarray, fps: float, folder: str | Path) -> None:
    """Refuse an aligned take whose frame times are not the uniform grid ``i / fps`` (the align
    contract): features are computed on that grid, so other times would pair wrong audio and face."""
    grid = np.arange(times.shape[0]) / fps
    off = np.abs(np.asarray(times, np.float64) - grid)
    if times.shape[0] and not np.all(off <= 0.01 / fps):  # also NaN times
        first = int(np.argmax(~(off <= 0.01 / fps)))
        raise InputError(
            f"aligned take's frame times are not the uniform grid i/fps (frame {first} at "
            f"{float(times[first]):.4f} s, expected {grid[first]:.4f} s): re-run s2a-align on its source",
            folder,
        )


def split_share_warnings(
    durations: dict[str, tuple[str, float]],
    split_of: dict[str, str],
    rule: SplitRule,
    recordings: dict[str, str] | None = None,
    assumed: set[str] | None = None,
) -> list[str]:
    """A warning for each val or test split (not pinned) holding more than twice its fraction of the
    audio (and over 10 points more): the recordings are too few or too long for the fractions; and for
    each pinned split that its fraction topped up with takes nobody named (``recordings``: the recording
    each take was cut from; ``assumed``: the takes whose speaker is assumed, see ``pinned_groups``)."""
    total = sum(d for _, d in durations.values()) or 1.0
    group_of, pinned_to = pinned_groups(durations, rule, recordings, assumed)
    out = []
    for split, fraction, pinned in (
        ("val", rule.val_fraction, rule.val),
        ("test", rule.test_fraction, rule.test),
    ):
        added = sorted(t for t in durations if split_of[t] == split and group_of[t] not in pinned_to)
        if pinned and added and fraction > 0:
            out.append(
                f"the {split} split holds {len(added)} take(s) besides those pinned with --{split} "
                f"({', '.join(added[:3])}{', ...' if len(added) > 3 else ''}), added to reach "
                f"--{split}-fraction {fraction:g}: give --{split}-fraction 0 to keep only the pinned ones"
            )
        share = sum(d for t, (_, d) in durations.items() if split_of[t] == split) / total
        if not pinned and fraction > 0 and share > max(2 * fraction, fraction + 0.1):
            out.append(
                f"the {split} split holds {share:.0%} of the audio (asked {fraction:.0%}): the recordings "
                f"(or speakers) are too few or too long for these fractions: add data, change "
                f"--{split}-fraction, or pin takes with --{split}"
            )
    return out


def _write_work_json(path: Path, data: Any, compact: bool = False) -> None:
    """A record in ``.work`` written as the dataset's JSON is: a name not UTF-8 (a take, a speaker, a
    folder) as messages show it, its bytes beside it (``strict_names``); ``_read_work_json`` reads it."""
    write_json_atomic(path, strict_names(data), compact=compact, name_failures=True)


def _read_work_json(path: Path) -> Any:
    """A record ``_write_work_json`` wrote, each name as Python holds it (one written before, a lone
    surrogate, too). Errors: ``OSError``, ``ValueError`` (not UTF-8, not JSON)."""
    return loads_names(path.read_text(encoding="utf-8"))


def _record_of(job: TakeJob) -> dict[str, Any] | None:
    """The take's record when it is of this take as this build would process it (its samples unchecked)."""
    try:
        rec = _read_work_json(job.record)
    except (OSError, ValueError):
        return None
    if (
        not isinstance(rec, dict)
        or rec.get("config_hash") != job.config_hash
        or rec.get("take") != job.take_id
        or rec.get("sha256") != job.sha256
        or rec.get("split") != job.split
        or rec.get("speaker") != job.speaker  # another take's spelling may now name it
        or not isinstance(rec.get("samples"), list)
    ):
        return None
    return rec


def _record_is_current(job: TakeJob) -> dict[str, Any] | None:
    rec = _record_of(job)
    if rec is None:
        return None
    # each sample tar as the record wrote it (sha256): a build with other options that was stopped while
    # rewriting this take's samples must not lend them to this one (it drops the record first, too)
    samples_dir = Path(job.work) / "samples"
    if not job.stats.is_file() or not all(
        isinstance(s.get("sha256"), str) and _file_sha256(samples_dir / f"{s['key']}.tar") == s["sha256"]
        for s in rec.get("samples", [])
    ):
        return None
    return rec


def _file_sha256(path: Path) -> str | None:
    """sha256 of a file, or None when it cannot be read."""
    try:
        return sha256_file(path)
    except OSError:
        return None


def _invalidate(record: Path) -> None:
    """Remove a record that marks work as done, durably, before that work is redone: a build stopped
    halfway then finds no record, never a record vouching for files another build rewrote."""
    try:
        record.unlink()
    except FileNotFoundError:
        return
    _fsync_dir(record.parent)


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # pragma: no cover - not on every platform
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover
        pass
    finally:
        os.close(fd)


def take_transcript(take: Take) -> str | None:
    """The words spoken in a take, when known: ``meta.extra["transcript"]`` (align may carry it over)."""
    text = take.meta.extra.get("transcript")
    return text if isinstance(text, str) and text.strip() else None


def on_another_scale(values: np.ndarray, columns: np.ndarray, within: np.ndarray) -> bool:
    """Whether one of ``columns`` (the channels with values beyond ANIM_LIMIT) is on another scale than
    weights: it has no frame ``within`` reach, or passes WEIGHT_REACH in more than a tenth of them (a
    percent scale's quiet frames, degrees of a small turn). A tracker's glitch, however long, leaves the
    channel's other frames the weights they were."""
    for col in columns:
        near = np.abs(values[within, col])
        if not near.size or np.quantile(near, 0.9) > WEIGHT_REACH:
            return True
    return False


def process_take(job: TakeJob) -> dict[str, Any]:
    """Features, samples and statistics of one take; returns its record (cached on disk)."""
    rec = _record_is_current(job)
    if rec is not None:
        return rec | {"cached": True}
    _invalidate(job.record)  # before its samples are rewritten (see _record_is_current)
    with _take_read(job.folder):
        take = read_take(job.folder)
    idx = [take.channel_index(c) for c in job.channels]
    values = take.values[:, idx]
    n = values.shape[0]
    fps = float(take.meta.fps)
    check_frame_grid(take.time, fps, job.folder)
    sr = job.settings.sample_rate
    audio_len = take.audio.frames
    span = int(round(n * sr / fps))
    padded = mono_padded(take.audio, max(span, audio_len))
    take.audio = None  # its samples are in ``padded`` now: an hour of them is 230 MB
    audio = padded[:audio_len]
    narrow = is_narrowband(audio, sr)
    peak = max(float(audio.max(initial=0.0)), -float(audio.min(initial=0.0)))
    if peak > MAX_AUDIO_PEAK:  # no recording chain gets there: damaged samples, not a loud take
        at = int(np.argmax(np.abs(audio))) / sr
        shown = shown_against(peak, MAX_AUDIO_PEAK, 0) if peak < 1e6 else f"{peak:.3g}"  # 1000.4, not 1e+03
        raise InputError(
            f"audio holds a sample of {shown} at {at:.3f} s, over {MAX_AUDIO_PEAK:g} times full scale "
            "(damaged samples?): repair or re-export the audio (s2a-capture import repairs isolated ones)",
            job.folder,
        )
    gain, stray = audio_gain(audio, sr, peak)
    if gain != 1.0:
        audio *= np.float32(gain)
    audio[stray] = 0.0  # a stray burst (a damaged sample, spread by the resampler): muted
    speech_db = speech_level(padded[:span], sr)
    level = gain_for_level(speech_db, job.settings)
    t = np.arange(n) / fps
    in_audio = t < audio_len / sr
    finite_values = np.isfinite(values)
    finite = finite_values.all(axis=1)
    beyond = finite_values & (np.abs(values) > ANIM_LIMIT)  # per value: which channels, which sign
    in_range = ~beyond.any(axis=1)
    beyond_columns = np.flatnonzero(beyond.any(axis=0))
    out_of_range = int((finite & ~in_range).sum())
    wrong_scale = out_of_range > WRONG_SCALE_SHARE * n and on_another_scale(
        values, beyond_columns, finite & in_range
    )
    # usable per value: a frame's status, audio and scale hold for all its channels, a glitch (NaN,
    # beyond ±10) for its channel only; ``mask``: the frames usable in every channel
    channel_mask = finite_values & ~beyond
    channel_mask &= (np.isin(take.frame_status, USABLE_STATUS) & in_audio & (not wrong_scale))[:, None]
    del finite_values
    mask = channel_mask.all(axis=1)
    partly = channel_mask.any(axis=1) & ~mask  # frames usable in some channels only
    anim = np.where(channel_mask, values, 0.0).astype(np.float32)
    feats, phones = compute_features(
        padded[:span],
        n,
        fps,
        job.features,
        job.settings,
        _extractor(job.ppg, job.ppg_model),
        take_transcript(take),
        gain=level,
    )
    neutral = None
    neutral_nonfinite: list[str] = []  # selected channels whose calibrated neutral is NaN or infinite
    if take.neutral is not None and take.neutral.shape == (len(take.meta.channels),):
        nv = take.neutral[idx]
        neutral = usable_neutral(nv, len(job.channels))
        if neutral is None:
            neutral_nonfinite = [c for c, v in zip(job.channels, nv, strict=True) if not np.isfinite(v)]

    # statistics (float64 sums; merged later in take order)
    chan = ChannelAccumulator(len(job.channels))
    chan.add(anim[mask], neutral)
    feat_stats = {}
    for name, arr in feats.items():
        if name == "pitch":
            continue
        acc = FeatureAccumulator(arr.shape[1])
        acc.add(arr[in_audio])
        feat_stats[name] = acc.to_json()
    pitch_stats = None
    if "pitch" in feats:
        pitch_stats = voiced_log_f0_sums(feats["pitch"], in_audio)
    phone_counts = None
    if phones is not None:
        phone_counts = np.bincount(phones[mask & (phones >= 0)], minlength=1).tolist()

    # samples: equal chunks of at most max_sample_s
    max_frames = max(1, int(math.floor(job.max_sample_s * fps)))
    n_chunks = max(1, math.ceil(n / max_frames))
    bounds = [round(c * n / n_chunks) for c in range(n_chunks + 1)]
    samples_dir = Path(job.work) / "samples"
    samples_dir.mkdir(parents=True, exist_ok=True)
    samples = []
    for c in range(n_chunks):
        a, b = bounds[c], bounds[c + 1]
        s0, s1 = int(round(a * sr / fps)), int(round(b * sr / fps))
        key = f"{job.key}_c{c:03d}"
        meta = {
            "key": key,
            "take": job.take_id,
            "take_sha256": job.sha256,
            "content_sha256": job.content_sha256,
            "speaker": job.speaker,
            "split": job.split,
            "chunk": c,
            "chunks": n_chunks,
            "frame_start": a,
            "frames": b - a,
            "fps": fps,
            "t0_s": a / fps,
            "duration_s": (b - a) / fps,
            "sample_rate": sr,
            "audio_start_sample": s0,
            "audio_samples": s1 - s0,
            "channels": len(job.channels),
            "features": {k: int(v.shape[1]) for k, v in feats.items()},
            "usable_frames": int(mask[a:b].sum()),
            "neutral": None if neutral is None else [float(v) for v in neutral],
            "audio_gain": gain,
        }
        if job.settings.level_target_db is not None:
            meta["level_gain"] = level  # features only: the stored audio keeps the recorded level
        members = {
            "json": json_bytes(meta),
            "flac": flac_bytes(padded[s0:s1], sr),
            "anim.npy": npy_bytes(anim[a:b]),
            "mask.npy": npy_bytes(mask[a:b]),
        }
        if partly[a:b].any():  # else every channel's usable frames are the mask's: no member
            members[CHANNEL_MASK] = npy_bytes(channel_mask[a:b])
        for name, arr in feats.items():
            members[f"{name}.npy"] = npy_bytes(arr[a:b])
        if phones is not None:
            members["phones.npy"] = npy_bytes(phones[a:b])
        with naming_failures(samples_dir / f"{key}.tar") as path, ShardWriter(path) as w:
            w.add(key, members)
            written = w.close()
        samples.append(
            {
                "key": key,
                "bytes": sample_size(members),
                "frames": b - a,
                "duration_s": (b - a) / fps,
                "usable_frames": int(mask[a:b].sum()),
                "usable_values": int(channel_mask[a:b].sum()),  # a glitch in one channel leaves the others
                "sha256": written.sha256,  # of the one-sample tar: checked before it is reused
            }
        )
    rec = {
        "take": job.take_id,
        "sha256": job.sha256,
        "split": job.split,
        "speaker": job.speaker,
        "config_hash": job.config_hash,
        "frames": n,
        "usable_frames": int(mask.sum()),
        "out_of_range_frames": out_of_range,
        "out_of_range_channels": [job.channels[j] for j in beyond_columns],
        "out_of_range_below": bool((values[beyond] < 0).any()),
        "wrong_scale": wrong_scale,
        "interpolated_frames": int(np.count_nonzero(mask & (take.frame_status == FrameStatus.INTERPOLATED))),
        "narrowband": narrow,
        "neutral_nonfinite": neutral_nonfinite,
        "audio_gain": gain,
        "stray_samples": int(stray.sum()),
        "speech_level_dbfs": speech_db,
        "level_gain": level,
        "duration_s": n / fps,
        "samples": samples,
        "feature_stats": feat_stats,
        "pitch_stats": pitch_stats,
        "phone_counts": phone_counts,
    }
    job.record.parent.mkdir(parents=True, exist_ok=True)
    # the channel histograms go to an .npz beside the record (written first: the record marks done);
    # compressed, as most of their bins are empty
    with atomic_write(job.stats, name_failures=True) as f:
        np.savez_compressed(f, **chan.to_arrays())
    _write_work_json(job.record, rec, compact=True)
    return rec | {"cached": False}


# ------------------------------------------------------------------------------------------ build


def _fingerprint(data: Any) -> str:
    return hashlib.sha256(json.dumps(data, sort_keys=True, default=str).encode()).hexdigest()


def _library_versions() -> dict[str, str]:
    import importlib.metadata as md

    out = {}
    for name in ("numpy", "soundfile", "praat-parselmouth", "scipy"):
        try:
            out[name] = md.version(name)
        except md.PackageNotFoundError:
            pass
    try:
        out["s2a-toolkit"] = md.version("s2a-toolkit")
    except md.PackageNotFoundError:
        pass
    return out


def _prepare_output(out: Path) -> dict[str, Any] | None:
    """Create ``out`` or check it holds a dataset (or an interrupted build); returns the old manifest."""
    if out.exists() and not out.is_dir():
        raise InputError("output exists and is not a folder", out)
    out.mkdir(parents=True, exist_ok=True)
    old = None
    if (out / MANIFEST_FILE).is_file():
        try:
            old = read_manifest(out)
        except InputError:
            old = None
    others = [
        p
        for p in out.iterdir()
        if p.name not in (MANIFEST_FILE, WORK) and not SHARD_NAME.match(p.name) and not p.name.startswith(".")
    ]
    if others:
        raise InputError(f"output folder holds other files ({others[0].name}); choose an empty folder", out)
    for p in out.glob(".*.partial"):
        p.unlink()
    return old


def _merge_records(records: list[dict[str, Any]], channels: list[str], split: str | None):
    chan = ChannelAccumulator(len(channels))
    feats: dict[str, FeatureAccumulator] = {}
    for r in records:
        if split is not None and r["split"] != split:
            continue
        with np.load(r["stats_file"], allow_pickle=False) as z:
            chan.merge(ChannelAccumulator.from_arrays(z))
        for name, fs in r["feature_stats"].items():
            acc = FeatureAccumulator.from_json(fs)
            if name in feats:
                feats[name].merge(acc)
            else:
                feats[name] = acc
    return chan, feats


def plan_shards(records: list[dict[str, Any]], shard_bytes: int) -> list[dict[str, Any]]:
    """Shards per split: samples in key order, a new shard whenever the cap would be exceeded."""
    plan = []
    for split in SPLITS:
        samples = sorted(
            (s | {"split": split} for r in records if r["split"] == split for s in r["samples"]),
            key=lambda s: s["key"],
        )
        current: list[dict[str, Any]] = []
        size = 0
        for s in samples:
            if current and size + s["bytes"] + 2 * 512 > shard_bytes:
                plan.append({"split": split, "samples": current})
                current, size = [], 0
            current.append(s)
            size += s["bytes"]
        if current:
            plan.append({"split": split, "samples": current})
    counters = dict.fromkeys(SPLITS, 0)
    for shard in plan:
        shard["name"] = f"{shard['split']}-{counters[shard['split']]:06d}.tar"
        counters[shard["split"]] += 1
    return plan


def _holds(path: Path, done: dict[str, Any]) -> bool:
    """Whether the file ``path`` has the size and sha256 of the shard record ``done``."""
    try:
        if path.stat().st_size != done["bytes"]:
            return False
    except OSError:
        return False
    return _file_sha256(path) == done["sha256"]  # not damaged, nor rewritten by another build


def _write_shard(
    out: Path, work: Path, shard: dict[str, Any], fingerprint: str, stage: bool = True
) -> dict[str, Any]:
    """The shard ``shard`` of the plan, recorded in ``.work/shards``; ``"staged"`` in the result says
    whether it waits in ``.work/staged`` for ``_swap_in`` (False: ``out`` holds it already, those very
    bytes, and it is not rewritten). ``stage=False`` writes it into ``out`` at once (a repair of a
    damaged shard of an unchanged dataset)."""
    keys = [s["key"] for s in shard["samples"]]
    record = work / "shards" / f"{shard['name']}.json"
    target = out / shard["name"]
    staged = work / STAGED / shard["name"]
    try:
        done = _read_work_json(record)
        if done["keys"] == keys and done["fingerprint"] == fingerprint:
            if _holds(target, done):
                return done | {"staged": False}
            if stage and _holds(staged, done):
                return done | {"staged": True}
    except (FileNotFoundError, ValueError, KeyError, TypeError):
        pass
    _invalidate(record)
    dest = staged if stage else target
    dest.parent.mkdir(parents=True, exist_ok=True)
    # a failure names the dataset's shard (DS/train-000000.tar), whichever folder it is assembled in
    with naming_failures(target), ShardWriter(dest) as writer:
        for key in keys:
            for k, members in ShardReader(work / "samples" / f"{key}.tar"):
                writer.add(k, members)
        info = writer.close()
    done = {
        "name": info.name,
        "sha256": info.sha256,
        "bytes": info.bytes,
        "keys": keys,
        "fingerprint": fingerprint,
    }
    record.parent.mkdir(parents=True, exist_ok=True)
    _write_work_json(record, done)
    if stage and _holds(target, done):  # the dataset holds this shard already: nothing to swap in
        staged.unlink()
        return done | {"staged": False}
    return done | {"staged": stage}


def _worker_context(options: BuildOptions):
    """Workers forked from a fork server that imported the heavy modules once (torch, Praat): each
    worker starts in milliseconds, and no worker inherits thread pools from this process."""
    if sys.platform == "win32":  # pragma: no cover - no fork server there
        return get_context("spawn")
    ctx = get_context("forkserver")
    ctx.set_forkserver_preload(_take_modules(options))
    return ctx


def _take_modules(options: BuildOptions) -> list[str]:
    """The heavy modules computing a take imports (some lazily: scipy.signal in ``is_narrowband``), which
    are imported before a take is timed, as start-up: in the workers' fork server, or in this process
    before its first take computed with ``--jobs 1``. Left to the first take, they took seconds of it,
    which the build's progress counted as the rate of computing takes."""
    modules = ["dataset.build", "dataset.pitch", "parselmouth", "scipy.fft", "scipy.signal"]
    if options.ppg in ("bottleneck", "torchscript"):
        modules += ["torch", "dataset.bottleneck"]
    return modules


@contextmanager
def output_lock(out: Path) -> Iterator[None]:
    """Hold an exclusive lock on the dataset folder ``out`` (``flock`` on ``out/.build.lock``, which
    holds the pid) for a whole build; another build into it is refused at once. The kernel releases the
    lock when the process ends, however it ends, so a killed build never blocks the next one. The file
    is removed when the build ends."""

    def refused(holder: str) -> InputError:
        return InputError(
            f"another build{holder} is writing into this folder: wait for it to finish, or build into "
            "another -o",
            out,
        )

    with holding(out / LOCK_FILE, refused):
        yield


def _input_fingerprint(inputs: list[str | Path], options: BuildOptions) -> str:
    folders = sorted({str(f.resolve()) for f in find_takes(inputs)})
    model = options.ppg_model
    takes = []
    for f in folders:
        with _take_read(f):
            takes.append((Path(f).name, take_sha256(f)))
    return _fingerprint(
        {
            "takes": takes,
            "channels": options.channels,
            "features": list(options.features),
            "ppg": [options.ppg, sha256_file(model) if model and Path(model).is_file() else model],
            "normalization": options.normalization,
            "split": options.split.to_json(),
            "shard_bytes": options.shard_bytes,
            "max_sample_s": options.max_sample_s,
            "settings": options.settings.to_json(),
            "skip_flagged": options.skip_flagged,
            "dataset_version": DATASET_VERSION,
            "histogram": HIST_LAYOUT,
            "versions": _library_versions(),
        }
    )


def damaged_shards(out: Path, manifest: dict[str, Any]) -> list[str]:
    """Names of the manifest's shards that are missing or whose size or sha256 differ from it (one
    read of every shard: a flipped byte keeps the size)."""
    return [s["name"] for s in manifest["shards"] if not _holds(out / s["name"], s)]


def build_dataset(
    inputs: list[str | Path],
    out: str | Path,
    options: BuildOptions | None = None,
    say: Callable[[str], None] = lambda m: None,
) -> dict[str, Any]:
    """Build (or resume building) the dataset ``out`` from takes in ``inputs``; returns a summary.
    One build at a time writes into ``out`` (``output_lock``); SIGTERM stops it like Ctrl-C."""
    options = options or BuildOptions()
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError("output exists and is not a folder", out)
    out.mkdir(parents=True, exist_ok=True)
    state = _Replacing()
    with output_lock(out), sigterm_stops():
        try:
            return _build(inputs, out, options, say, state)
        except (S2AError, KeyboardInterrupt) as exc:
            left = _left(out, state)
            if left and isinstance(exc, S2AError):
                exc.args = (f"{exc} ({left})",)
            elif left:  # Ctrl-C, SIGTERM: the command line says it (dataset.cli)
                exc.dataset_state = left  # type: ignore[attr-defined]
            raise


PREVIOUS_SPLITS = "previous_splits.json"  # in .work: the splits of the manifest a rebuild replaces


def _previous_splits(old: dict[str, Any] | None, work: Path) -> dict[str, str]:
    """``{take: split}`` of the dataset this build replaces: its manifest, or, when there is none to
    read (a rebuild by an earlier version removed it before its takes), what a rebuild saved of it in
    ``.work``."""
    if old is not None:
        return {t: s for s in SPLITS for t in old["splits"][s]["takes"]}
    try:
        saved = _read_work_json(work / PREVIOUS_SPLITS)
    except (OSError, ValueError):
        return {}
    ok = isinstance(saved, dict) and all(isinstance(v, str) for v in saved.values())
    return saved if ok else {}


def empty_split_warnings(split_of: dict[str, str], rule: SplitRule, speakers: int) -> list[str]:
    """A warning for each val or test split that a fraction above 0 asked for and that got no take
    (one take, or one speaker split by speaker, leaves nothing to hold out)."""
    out = []
    for split, fraction in (("val", rule.val_fraction), ("test", rule.test_fraction)):
        if fraction > 0 and split not in split_of.values():
            what = f"{speakers} speaker(s)" if rule.by == "speaker" else f"{len(split_of)} take(s)"
            out.append(
                f"the {split} split is empty though --{split}-fraction {fraction:g} asked for "
                f"{fraction:.0%} of the audio: {what} are too few to hold some out"
                + (" by speaker" if rule.by == "speaker" else "")
                + f"; add data or pin with --{split}"
            )
    return out


def _process_takes(
    jobs: list[TakeJob],
    options: BuildOptions,
    say: Callable[[str], None],
    takes: TimedProgress | None = None,
):
    """Records of ``jobs`` by take id, ``--jobs`` processes at once, said by ``takes`` (a ``TimedProgress``
    counting them). A build that stops (an error in a take, Ctrl-C, SIGTERM) stops its workers too;
    finished takes stay cached."""
    records: dict[str, dict[str, Any]] = {}
    total = len(jobs)
    takes = takes or TimedProgress("", total, "takes", say, bar=20)
    modules = _take_modules(options)
    cached = 0
    computed = ""  # the last take computed, as a line names it

    def note(i: int, rec: dict[str, Any]) -> None:
        """A line for the first take computed, then one every few seconds (``TimedProgress``) and the
        last: hundreds of takes are not hundreds of lines. Takes from the cache are counted, not named
        (a line said while they are counted names the last take computed), and not in the rate, which
        counts from when the first take computed began: the workers' start-up and the cache's checks
        are no rate of computing takes. A rebuild from the cache says one line, "all N from the
        cache"."""
        nonlocal cached, computed
        began = rec.pop("began_s")  # None for a take from the cache
        first = not rec.get("cached") and i - 1 == cached  # the first take this build computes
        if rec.get("cached"):
            cached += 1
        else:
            computed = f"{rec['take']} ({rec['duration_s']:.1f} s of audio"
        from_cache = f"{cached} from the cache"
        if cached == total:
            detail = f"all {from_cache}"
        elif not computed:
            detail = from_cache
        else:
            detail = f"{computed}; {from_cache})" if cached else f"{computed})"
        takes.update(i, detail, skipped=cached, at_once=first or i == total, began=began)

    if options.jobs == 1 or total <= 1:
        for i, job in enumerate(jobs, 1):
            rec = _process_take_timed(job, modules)
            records[job.take_id] = rec
            note(i, rec)
        return records
    try:
        with worker_pool(min(options.jobs, total), _worker_context(options)) as pool:
            for i, future in enumerate(
                submit_all(pool, _process_take_timed, [(job, modules) for job in jobs]), 1
            ):
                rec = future.result()
                records[rec["take"]] = rec
                note(i, rec)
    except BrokenProcessPool:
        raise S2AError(
            "a worker process died (out of memory?); finished takes are kept: rerun to resume"
        ) from None
    return records


def _process_take_timed(job: TakeJob, modules: list[str]) -> dict[str, Any]:
    """``process_take``'s record with when computing it began (``began_s``: ``time.monotonic``, one
    clock for all the machine's processes; None for a take from the cache), from which the build's
    progress counts its rate: the ``modules`` it needs (``_take_modules``) are imported first, as
    start-up, not as the take's time (a take from the cache needs none)."""
    rec = _record_is_current(job)
    if rec is not None:  # checked here too, so that a rebuild from the cache imports nothing
        return rec | {"cached": True, "began_s": None}
    for module in modules:
        importlib.import_module(module)
    began = time.monotonic()
    try:
        return process_take(job) | {"began_s": began}
    except InputError as exc:
        raise _as_given(exc, job) from None


def _as_given(exc: InputError, job: TakeJob) -> InputError:
    """``exc`` naming the take the user gave rather than the copy the build aligned from it under
    ``DS/.work/aligned/`` (no folder of theirs; a file in it is said after the reason); ``exc`` itself
    for a take the user gave aligned, or an error about another file."""
    if exc.path is None or not job.given or Path(job.given) == Path(job.folder):
        return exc
    try:
        inside = Path(exc.path).relative_to(job.folder)
    except ValueError:
        return exc
    where = f" (in {inside} of the copy the build aligned from it)" if inside.parts else ""
    return InputError(exc.reason + where, job.given, exc.line)


def _repair_shards(
    out: Path,
    work: Path,
    old: dict[str, Any],
    damaged: list[str],
    jobs: list[TakeJob],
    fingerprint: str,
    options: BuildOptions,
    say: Callable[[str], None],
) -> bool:
    """Rewrite the ``damaged`` shards of a dataset whose inputs and options are unchanged, from their
    takes alone (the build is deterministic). True when every rewritten shard has the manifest's
    sha256 and size again; False sends the caller to a full rebuild."""
    names = set(damaged)
    takes = {s["take"] for s in old["samples"] if s["shard"] in names}
    mine = [j for j in jobs if j.take_id in takes]
    if {j.take_id for j in mine} != takes:
        return False
    say(f"repairing {len(names)} damaged shard(s) ({', '.join(sorted(names))}) from {len(mine)} take(s)")
    _process_takes(mine, options, say)
    for entry in old["shards"]:
        if entry["name"] not in names:
            continue
        keys = [{"key": s["key"]} for s in old["samples"] if s["shard"] == entry["name"]]
        done = _write_shard(out, work, {"name": entry["name"], "samples": keys}, fingerprint, stage=False)
        if done["sha256"] != entry["sha256"] or done["bytes"] != entry["bytes"]:
            say(f"{entry['name']} rebuilt differs from the manifest: rebuilding the dataset")
            return False
    return True


def _take_warnings(r: dict[str, Any], options: BuildOptions) -> list[str]:
    """What the build warns about one processed take (its record from ``process_take``)."""
    notes: list[str] = []
    if r.get("out_of_range_frames"):
        scale = r.get("wrong_scale", False)  # not a glitch
        channels = r.get("out_of_range_channels", [])
        where = f" in {', '.join(channels[:3])}{', ...' if len(channels) > 3 else ''}" if channels else ""
        angles = [c for c in channels if c in ROTATIONS]
        # Weights on 0..100 or 0..255 are never far below 0: such a column is no weight at all (a level in
        # dB, as CRI LipSync's `Vol`; an angle in degrees), which --value-scale would only hide.
        if angles:
            remedy = (
                f"{', '.join(angles)} in degrees? Live Link's head and eye angles are radians: convert them, "
                "or leave them out of --channels"
            )
        elif r.get("out_of_range_below"):
            remedy = (
                "values far below 0 are no weights on another scale (a level in dB?): leave those channels "
                "out of --channels"
            )
        else:
            remedy = (
                "weights on a 0-100 or 0-255 scale? They are 0..1: import the take again with "
                "s2a-capture import --value-scale 0.01 (or 1/255 = 0.00392157)"
            )
        notes.append(
            f"take {r['take']}: {r['out_of_range_frames']} frame(s) hold values beyond +-{ANIM_LIMIT:g}"
            f"{where} (no blendshape weight is): masked as unusable"
            + (
                f", and so are its other frames (their values are on that scale too); {remedy}"
                if scale
                else ""
            )
        )
    interpolated = r.get("interpolated_frames", 0) / max(r.get("usable_frames", 0), 1)
    if interpolated > MAX_INTERPOLATED_SHARE:
        notes.append(
            f"take {r['take']}: {interpolated:.0%} of its usable frames were interpolated over a lost "
            "face, not tracked: check the recording (face out of view?)"
        )
    if r.get("narrowband"):
        notes.append(
            f"take {r['take']}: its audio has no energy above {NARROWBAND_HZ / 1000:g} kHz (recorded at "
            "8 kHz, or through a phone codec?): its filter banks lack the upper bands of the other takes"
        )
    if r.get("neutral_nonfinite"):
        bad = r["neutral_nonfinite"]
        notes.append(
            f"take {r['take']}: its calibrated neutral pose is not a number for {len(bad)} selected "
            f"channel(s) ({', '.join(bad[:3])}{', ...' if len(bad) > 3 else ''}): not used (its samples' "
            "neutral is null)"
        )
    if r.get("audio_gain", 1.0) < 1.0 / FILTER_OVERSHOOT:  # a smaller gain is scaled without a word
        peak = 1 / r["audio_gain"]
        why = "clipped in the recording, then resampled?" if peak < 2 else "float audio"
        notes.append(
            f"take {r['take']}: audio peaks at {peak:.2f} (past full scale: {why}): scaled by "
            f"{r['audio_gain']:.3f} before features and storage (audio_gain in its samples)"
        )
    if r.get("stray_samples"):
        notes.append(
            f"take {r['take']}: a burst past full scale over {STRAY_FACTOR:g} times the take's level (a "
            f"damaged sample, or a click) muted ({r['stray_samples']} samples): not used for audio_gain"
        )
    if options.settings.level_target_db is not None and r.get("level_gain", 1.0) > QUIET_GAIN:
        notes.append(
            f"take {r['take']}: speech at {r['speech_level_dbfs']:.1f} dBFS active level, raised by "
            f"{20 * math.log10(r['level_gain']):.1f} dB for its features (a very quiet recording: check "
            "the microphone)"
        )
    if r["usable_frames"] < MIN_USABLE_SHARE * r["frames"]:
        notes.append(
            f"take {r['take']}: only {r['usable_frames']} of {r['frames']} frames are usable (face lost, "
            + ("values out of range, " if r.get("out_of_range_frames") else "")
            + "or audio shorter than the frames?); check it with s2a-view report"
        )
    return notes


def pitch_normalization(ordered: list[dict[str, Any]], speakers: list[str]) -> dict[str, Any]:
    """Per speaker, the mean and std of voiced log-F0 over the training split's takes (over all of the
    speaker's takes for a held-out speaker)."""
    pitch_norm = {}
    for spk in speakers:
        mine = [r for r in ordered if r["speaker"] == spk]
        use = [r for r in mine if r["split"] == "train"] or mine
        cnt = sum(r["pitch_stats"]["count"] for r in use)
        s = sum(r["pitch_stats"]["sum"] for r in use)
        ss = sum(r["pitch_stats"]["sumsq"] for r in use)
        mean = s / cnt if cnt else 0.0
        std = math.sqrt(max(ss / cnt - mean * mean, 0.0)) if cnt else 1.0
        pitch_norm[spk] = {
            "mean": float(np.float32(mean)),
            "std": float(np.float32(std if std > 1e-6 else 1.0)),
            "voiced_frames": cnt,
            "from": "train" if any(r["split"] == "train" for r in mine) else "all (held-out speaker)",
        }
    return pitch_norm


def _write_shards(
    out: Path, work: Path, plan: list[dict[str, Any]], fingerprint: str, progress: TimedProgress
) -> tuple[list[dict[str, Any]], list[str]]:
    """Write the planned shards into ``.work/staged`` (those ``out`` holds already, byte for byte, stay
    where they are and are not rewritten); their manifest entries and the names of the shards staged,
    which ``_swap_in`` moves into ``out``. Nothing in ``out`` changes here: the dataset it holds stays
    whole until the new one is complete. Said as the next step of ``progress`` (the build's): a line
    every few seconds, and the last."""
    shards = []
    staged = []
    held = 0  # shards the dataset holds already, byte for byte: no work, not in the rate
    progress.step("writing shards", len(plan), "shards")
    for i, shard in enumerate(plan, 1):
        done = _write_shard(out, work, shard, fingerprint)
        if done["staged"]:
            staged.append(done["name"])
        else:
            held += 1
        size = f"{done['bytes'] / 1e6:.1f} MB{', in place already' if not done['staged'] else ''}"
        progress.update(i, f"{done['name']} ({size})", skipped=held, at_once=i == len(plan))
        shards.append(
            {
                "name": done["name"],
                "split": shard["split"],
                "sha256": done["sha256"],
                "bytes": done["bytes"],
                "samples": len(shard["samples"]),
                "frames": sum(s["frames"] for s in shard["samples"]),
                "duration_s": round(sum(s["duration_s"] for s in shard["samples"]), 6),
            }
        )
    return shards, staged


STAGED = "staged"  # in .work: the shards of a build, complete, until _swap_in moves them into the dataset


def _clear_work(work: Path, options: BuildOptions, jobs: list[TakeJob] | None = None) -> None:
    """After a build: ``.work`` removed but for the take records (small: JSON and compressed histograms;
    the samples are in the shards), those of takes no longer built (``jobs``: the build's) among them
    too. ``--keep-work`` keeps everything."""
    if options.keep_work:
        return
    for p in work.iterdir() if work.is_dir() else []:
        if p.name != TAKE_RECORDS:
            shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)
    if jobs is not None:
        kept = {f for job in jobs for f in (job.record.name, job.stats.name)}
        for p in (work / TAKE_RECORDS).glob("*") if (work / TAKE_RECORDS).is_dir() else []:
            if p.name not in kept:
                p.unlink(missing_ok=True)


def _restore_samples(out: Path, old: dict[str, Any] | None, jobs: list[TakeJob]) -> int:
    """Put back into ``.work/samples`` the samples of takes whose record says this build would make
    them as the last one did (same take contents, options, split and speaker), read from the dataset's
    shards: a rebuild after adding one take to N computes the features of one take, not N + 1 (a take
    whose samples cannot be restored, from a damaged or missing shard, is processed again). Returns the
    number of takes restored. Each restored sample is checked against the sha256 its record holds
    (``_record_is_current``), as the samples a build leaves are."""
    if old is None or not jobs:
        return 0
    samples_dir = Path(jobs[0].work) / "samples"  # the build's one .work
    shard_of = {s.get("key"): s.get("shard") for s in old.get("samples", []) if isinstance(s, dict)}
    wanted: dict[str, dict[str, Path]] = {}  # shard -> {key: where its one-sample tar goes}
    takes = {}
    for job in jobs:
        rec = _record_of(job)
        if rec is None or not job.stats.is_file():
            continue
        missing = [s.get("key") for s in rec["samples"] if not (samples_dir / f"{s.get('key')}.tar").exists()]
        if not missing:
            continue  # left by a build that stopped: checked as ever
        if not all(isinstance(shard_of.get(k), str) and SHARD_NAME.match(shard_of[k]) for k in missing):
            continue
        for k in missing:
            wanted.setdefault(shard_of[k], {})[k] = samples_dir / f"{k}.tar"
        takes[job.take_id] = missing
    for shard, keys in sorted(wanted.items()):
        try:
            for key, members in ShardReader(out / shard):
                if key in keys:
                    keys[key].parent.mkdir(parents=True, exist_ok=True)
                    with ShardWriter(keys[key]) as w:
                        w.add(key, members)
                        w.close()
        except (InputError, OSError):
            continue  # those takes are processed again
    return sum(all((samples_dir / f"{k}.tar").exists() for k in keys) for keys in takes.values())


def _swap_in(out: Path, work: Path, staged: list[str], manifest: dict[str, Any]) -> None:
    """Replace the dataset in ``out`` with the new one: the staged shards renamed into place, then the
    manifest written (atomically), then the shards it does not list removed (of an earlier, larger
    build). The caller holds Ctrl-C and SIGTERM back meanwhile (``stops_deferred``); only a kill (or
    a crash) among these few renames leaves a manifest that does not match its shards, which the next
    build mends (its staged shards are still in .work)."""
    for name in staged:
        with naming_failures(out / name):
            os.replace(work / STAGED / name, out / name)
    _fsync_dir(out)
    with naming_failures(manifest_path(out)):
        write_manifest(out, manifest)
    _remove_unlisted_shards(out, manifest)


def _remove_unlisted_shards(out: Path, manifest: dict[str, Any]) -> None:
    """Remove the shards in ``out`` that ``manifest`` does not list: of an earlier, larger build into
    this folder (after a swap, or when a kill came between a swap's manifest and this)."""
    planned = {s["name"] for s in manifest["shards"]}
    unlisted = [p for p in out.iterdir() if SHARD_NAME.match(p.name) and p.name not in planned]
    for p in unlisted:
        p.unlink()
    if unlisted:
        _fsync_dir(out)


def _split_stats(
    ordered: list[dict[str, Any]], channels: list[str], train_chan, phones: list[str] | None
) -> tuple[dict[str, Any], list[str]]:
    """Per split: takes, samples, hours (per speaker), usable frames, channel distributions and, with
    phones, frames per phone; and the warnings about splits with no usable frame."""
    stats: dict[str, Any] = {}
    notes: list[str] = []
    for split in SPLITS:
        mine = [r for r in ordered if r["split"] == split]
        if not mine:
            continue
        chan = train_chan if split == "train" else _merge_records(ordered, channels, split)[0]
        speakers: dict[str, float] = {}
        for r in mine:
            speakers[r["speaker"]] = speakers.get(r["speaker"], 0.0) + r["duration_s"]
        entry: dict[str, Any] = {
            "takes": len(mine),
            "samples": sum(len(r["samples"]) for r in mine),
            "hours": sum(r["duration_s"] for r in mine) / 3600.0,
            "usable_frames": sum(r["usable_frames"] for r in mine),
            "hours_per_speaker": {k: v / 3600.0 for k, v in sorted(speakers.items())},
            "channels": chan.summary(channels),
        }
        if phones is not None and all(r["phone_counts"] is not None for r in mine):
            counts = np.zeros(len(phones), np.int64)
            for r in mine:
                c = np.asarray(r["phone_counts"], np.int64)[: len(phones)]
                counts[: c.size] += c
            entry["phone_frames"] = {p: int(c) for p, c in zip(phones, counts, strict=True)}
        stats[split] = entry
        if not entry["usable_frames"]:  # never train: _build refuses a training split without any
            notes.append(
                f"the {split} split has no usable frame (its {len(mine)} take(s) lost the face, or their "
                "audio, throughout): nothing can be evaluated on it"
            )
    return stats, notes


@dataclass
class _Replacing:
    """How far a build got with the dataset its folder held, told when the build stops (``_left``):
    ``previous``, the folder held a readable dataset when the build began; ``phase``: ``"reading"``
    (that dataset untouched: new shards go to .work/staged), ``"repairing"`` (damaged shards of an
    unchanged dataset rewritten in place), ``"swapping"`` (``_swap_in``), ``"done"``."""

    previous: bool = False
    phase: str = "reading"


def _left(out: Path, state: _Replacing) -> str:
    """What a build that stopped (an error, Ctrl-C, SIGTERM) left in ``out``; "" for a first build."""
    if state.phase == "swapping":
        return (
            f"it stopped while swapping the new dataset into {out}, whose manifest and shards may not "
            "match: run the build again to finish it"
        )
    if state.phase == "done":
        return f"{out} holds the new dataset, complete"
    if not state.previous:
        return ""
    if state.phase == "repairing":
        return f"it stopped while rewriting damaged shards of {out}: run the build again to finish it"
    return f"the previous dataset in {out} is intact: its manifest.json and shards are unchanged"


def _build(
    inputs: list[str | Path],
    out: Path,
    options: BuildOptions,
    say: Callable[[str], None],
    state: _Replacing | None = None,
) -> dict[str, Any]:
    state = state or _Replacing()
    old = _prepare_output(out)
    state.previous = old is not None
    damaged: list[str] | None = None
    work = out / WORK

    def up_to_date() -> dict[str, Any]:
        say("dataset is up to date")
        _remove_unlisted_shards(out, old)  # a swap killed after its manifest was written ends here
        _clear_work(work, options)  # what a rebuild that failed or was stopped left: of no use now
        return _summary(out, old, up_to_date=True)

    def intact() -> bool:
        """The old dataset's shards as its manifest says (checked once, when its inputs match)."""
        nonlocal damaged
        if damaged is None:
            damaged = damaged_shards(out, old)
            if damaged:
                say(f"{len(damaged)} shard(s) differ from the manifest: {', '.join(damaged)}")
        return not damaged

    # Cheap check first: the same input take folders and options as the finished dataset → nothing
    # to do (without re-aligning raw takes, whose aligned copies went with .work).
    input_fingerprint = _input_fingerprint(inputs, options)
    if old is not None and old.get("build", {}).get("input_fingerprint") == input_fingerprint and intact():
        return up_to_date()
    work.mkdir(exist_ok=True)
    takes, warnings, left_out = collect_takes(inputs, work, say, options.skip_flagged)
    fps = takes[0].fps  # all takes share it (collect_takes)
    if options.max_sample_s * fps < 1 - 1e-9:  # a sample is at least one frame: it would be longer
        raise InputError(
            f"--max-sample-s {options.max_sample_s:g} is shorter than one frame at {fps:g} fps "
            f"({1 / fps:.4g} s): a sample holds at least one frame"
        )
    kept = {name for t in takes for name in (t.id, t.recording, t.speaker)}
    for pinned in (*options.split.val, *options.split.test):
        if pinned in left_out and pinned not in kept:
            raise InputError(f"pinned take or speaker {pinned!r} was {left_out[pinned]}")
    durations = {t.id: (t.speaker, t.duration_s) for t in takes}
    recordings = {t.id: t.recording for t in takes}
    assumed = {t.id for t in takes if t.speaker_assumed}  # their speaker is a recording id: pinned exactly
    split_of = assign_splits(durations, options.split, recordings, assumed)
    warnings += split_share_warnings(durations, split_of, options.split, recordings, assumed)
    warnings += empty_split_warnings(split_of, options.split, len({t.speaker for t in takes}))
    previous = _previous_splits(old, work)
    moved = {t: {"from": previous[t], "to": s} for t, s in split_of.items() if previous.get(t, s) != s}
    channels, channel_warnings = resolve_channels(options.channels, takes, split_of)
    warnings += channel_warnings
    assumed = sorted(assumed)  # as the manifest lists them
    if assumed:
        warnings.append(
            f"{len(assumed)} take(s) name no speaker (meta.subject): each recording (a raw take with the "
            "segments align cut from it) counts as its own speaker"
        )
    extractor = _extractor(options.ppg, options.ppg_model)
    ppg_info = extractor.describe() if extractor is not None else None
    config = {
        "dataset_version": DATASET_VERSION,
        "channels": channels,
        "features": list(options.features),
        "settings": options.settings.to_json(),
        "ppg": ppg_info,
        "max_sample_s": options.max_sample_s,
        "versions": _library_versions(),
    }
    config_hash = _fingerprint(config | {"histogram": HIST_LAYOUT})
    fingerprint = _fingerprint(
        {
            "config": config_hash,
            "normalization": options.normalization,
            "split": options.split.to_json(),
            "shard_bytes": options.shard_bytes,
            "takes": [(t.id, t.sha256) for t in takes],
        }
    )
    jobs = [
        TakeJob(
            str(t.folder),
            t.id,
            t.key,
            t.sha256,
            t.content_sha256,
            t.speaker,
            split_of[t.id],
            channels,
            options.features,
            options.ppg,
            options.ppg_model,
            options.max_sample_s,
            options.settings,
            str(work),
            config_hash,
            str(t.given),
        )
        for t in takes
    ]
    if old is not None and old.get("build", {}).get("fingerprint") == fingerprint:
        if intact():
            return up_to_date()
        state.phase = "repairing"
        if _repair_shards(out, work, old, damaged or [], jobs, fingerprint, options, say):
            _clear_work(work, options)
            return _summary(out, old, up_to_date=False) | {"repaired": sorted(damaged or [])}
        state.phase = "reading"  # not repairable in place: a full rebuild, as for changed inputs
    if old is not None:
        # what the old manifest said of the splits outlives it (a rebuild stopped while swapping the
        # new dataset in still reports moved takes when rerun)
        _write_work_json(work / PREVIOUS_SPLITS, previous)
    # The old manifest and its shards stay as they are until the new dataset is complete: new shards
    # are written into .work/staged and swapped in at the end (_swap_in), so a rebuild that fails or is
    # stopped leaves the previous dataset readable.

    restored = _restore_samples(out, old, jobs)
    if restored:
        say(f"{restored} take(s) unchanged since the last build: their samples taken from its shards")
    # one clock for the takes and then the shards: no stretch of the build is silent for longer
    progress = TimedProgress("", len(jobs), "takes", say, bar=20)
    records = _process_takes(jobs, options, say, progress)
    stats_files = {job.take_id: str(job.stats) for job in jobs}
    ordered = [records[t.id] | {"stats_file": stats_files[t.id]} for t in takes]
    for r in ordered:
        warnings += _take_warnings(r, options)

    # statistics of the training split, merged in take order (deterministic float sums)
    train_chan, train_feats = _merge_records(ordered, channels, "train")
    if train_chan.count.sum() == 0:
        raise InputError("the training split has no usable frames")
    normalizer = fit_normalizer(options.normalization, channels, train_chan)
    feature_norm = {}
    for name, acc in train_feats.items():
        mean, std = acc.mean_std()
        feature_norm[name] = {"mean": mean, "std": std, "frames": acc.count}
    pitch_norm = {}
    if "pitch" in options.features:
        pitch_norm = pitch_normalization(ordered, sorted({t.speaker for t in takes}))

    plan = plan_shards(ordered, options.shard_bytes)
    shards, staged = _write_shards(out, work, plan, fingerprint, progress)

    sample_entries = []
    rec_of = {s["key"]: r for r in ordered for s in r["samples"]}
    for shard in plan:
        for s in shard["samples"]:
            r = rec_of[s["key"]]
            sample_entries.append(
                {
                    "key": s["key"],
                    "take": r["take"],
                    "speaker": r["speaker"],
                    "split": shard["split"],
                    "shard": shard["name"],
                    "frames": s["frames"],
                    "usable_frames": s["usable_frames"],
                    # a take record of a build before it has none: readers fall back to the samples
                    **({"usable_values": s["usable_values"]} if "usable_values" in s else {}),
                    "duration_s": s["duration_s"],
                }
            )
    phones = ppg_info.get("phones") if ppg_info else None
    if phones is None and extractor is not None:
        phones = getattr(extractor, "phones", None)
    stats, split_notes = _split_stats(ordered, channels, train_chan, phones)
    warnings += split_notes

    feature_dims = {}
    if ordered and ordered[0]["samples"]:
        rec0 = ordered[0]
        for name in options.features:
            feature_dims[name] = (
                len(rec0["feature_stats"][name]["sum"]) if name in rec0["feature_stats"] else 2
            )
    manifest = {
        "fps": takes[0].fps,
        "sample_rate": options.settings.sample_rate,
        "channels": channels,
        "channel_selection": options.channels,
        "features": {
            "names": list(options.features),
            "dims": feature_dims,
            "settings": options.settings.to_json(),
            "frame_rate": "interpolated linearly from the 20 ms analysis grid to the animation frames",
            "ppg": ppg_info,
            "pitch": "log-F0 (natural log of Hz) interpolated through unvoiced frames, and a voicing flag",
            "versions": config["versions"],
        },
        "members": [*BASE_MEMBERS, *[f"{n}.npy" for n in options.features]]
        + (["phones.npy"] if "ppg" in options.features and phones is not None else []),
        "normalization": {
            "animation": normalizer.to_json(),
            "features": feature_norm,
            "pitch": {"kind": "per-speaker z-score of voiced log-F0", "speakers": pitch_norm},
        },
        "splits": {
            "rule": options.split.to_json(),
            **{
                s: {
                    "takes": sorted(t for t, sp in split_of.items() if sp == s),
                    "speakers": sorted({t.speaker for t in takes if split_of[t.id] == s}),
                }
                for s in SPLITS
            },
        },
        "speakers_assumed": assumed,
        "shards": shards,
        "samples": sample_entries,
        "sources": [
            t.source | {"speaker": t.speaker, "recording": t.recording, "split": split_of[t.id]}
            for t in takes
        ],
        "stats": stats,
        "warnings": sorted(warnings),  # the same whatever the order of the inputs
        "build": {
            "fingerprint": fingerprint,
            "input_fingerprint": input_fingerprint,
            "config_hash": config_hash,
            "max_sample_s": options.max_sample_s,
            "shard_bytes": options.shard_bytes,
            "dataset_version": DATASET_VERSION,
        },
    }
    state.phase = "swapping"
    with stops_deferred():  # a Ctrl-C or SIGTERM meanwhile stops the build once the swap is done
        _swap_in(out, work, staged, manifest)
        state.phase = "done"
    _clear_work(work, options, jobs)
    return _summary(out, read_manifest(out), up_to_date=False, moved=moved)


def _summary(
    out: Path, manifest: dict[str, Any], up_to_date: bool, moved: dict[str, dict[str, str]] | None = None
) -> dict[str, Any]:
    """What a build did, for ``--json``. ``split_changes``: takes of the dataset this build replaced
    that changed split (``{take: {"from", "to"}}``), also said in a warning (not in the manifest: it
    depends on the folder's history, not on the inputs)."""
    moved = moved or {}
    warnings = list(manifest.get("warnings", []))
    if moved:
        listed = ", ".join(f"{t} ({c['from']} -> {c['to']})" for t, c in sorted(moved.items()))
        warnings.append(
            f"{len(moved)} take(s) of the dataset this build replaced changed split: {listed}; pin "
            "splits with --val/--test to keep a release's splits"
        )
    splits = manifest.get("splits", {})
    return {
        "dataset": str(out),
        "up_to_date": up_to_date,
        "takes": len(manifest.get("sources", [])),
        "samples": len(manifest["samples"]),
        "shards": len(manifest["shards"]),
        "hours": round(sum(s["duration_s"] for s in manifest["shards"]) / 3600.0, 6),
        "channels": len(manifest["channels"]),
        "features": manifest["features"]["names"],
        "splits": {s: len(splits.get(s, {}).get("takes", [])) for s in SPLITS},
        "split_changes": moved,
        "warnings": warnings,
    }
