"""The build of a dataset a run trains on: manifest.json's sha256 and the takes that train and validate
the run (the checkpoint's ``dataset`` entry). During training a rebuild of the dataset stops the run
(``DatasetWatch``; under DDP every rank together, ``agreed_failure``); a resumed run whose validation
takes changed restarts best_val; evaluation names the takes the run trained on (``leaked_takes``)."""

from __future__ import annotations

import hashlib
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import torch
import torch.distributed as dist

from capture.errors import InputError, first_few, loads_names
from capture.take import sha256_file
from dataset.manifest import FORMAT, SCHEMA_VERSION, manifest_path, manifest_problems, read_manifest

from .data import split_keys

RUN_DATASET = ("channels", "fps", "features", "normalization")  # what a resumed run's dataset must match
DIFFERS = {
    "channels": "its channels differ",
    "fps": "its frame rate differs",
    "features": "its features differ",
    "normalization": "its normalization differs",
}
MANIFEST_GRACE_S = 2.0  # how long a run waits for a manifest.json that is missing (being swapped in)


def file_sha256(path: Path) -> str | None:
    """``capture.take.sha256_file``, None when the file cannot be read (missing, being replaced)."""
    try:
        return sha256_file(path)
    except OSError:
        return None


def read_manifest_sha(ds: str | Path) -> tuple[dict[str, Any], str]:
    """(manifest, sha256 of manifest.json) of one read of the file: the fingerprint is that of the
    manifest returned, even when a rebuild replaces the file meanwhile. Errors as ``read_manifest``."""
    path = manifest_path(ds)
    for _ in range(5):
        try:
            raw = path.read_bytes()
            data = loads_names(raw.decode("utf-8"))
        except (OSError, ValueError, RecursionError):  # JSON and UTF-8 errors are ValueErrors
            data = raw = None
        usable = (
            isinstance(data, dict)
            and data.get("format") == FORMAT
            and data.get("schema_version") == SCHEMA_VERSION
            and not manifest_problems(data)
        )
        if usable and raw is not None:
            return data, hashlib.sha256(raw).hexdigest()
        read_manifest(ds)  # raises its one-line error, unless the file was replaced meanwhile: read again
    raise InputError("manifest.json keeps changing while it is read (a build writing it?)", path)


def take_sha256(manifest: dict[str, Any]) -> dict[str, str]:
    """{take: sha256 of its contents} from the manifest's sources (as the build recorded them)."""
    out = {}
    for src in manifest.get("sources") or []:
        if isinstance(src, dict) and isinstance(src.get("take"), str) and isinstance(src.get("sha256"), str):
            out[src["take"]] = src["sha256"]
    return out


def run_takes(manifest: dict[str, Any], cfg: dict[str, Any]) -> dict[str, Any]:
    """The takes that train and validate a run of ``cfg`` on this dataset, as the manifest names them
    (``val_takes`` and ``drop_takes`` applied): ``{"train": [...], "val": [...], "sha256": {take:
    sha256}}``, what a checkpoint's ``dataset.takes`` records. Errors as ``split_keys``."""
    keys = split_keys(manifest, cfg)
    chosen: dict[str, set[str]] = {"train": set(), "val": set()}
    for s in manifest["samples"]:
        for i, split in enumerate(("train", "val")):
            if (s["key"] in keys[i]) if keys is not None else s["split"] == split:
                chosen[split].add(s["take"])
    sha = take_sha256(manifest)
    used = chosen["train"] | chosen["val"]
    return {
        "train": sorted(chosen["train"]),
        "val": sorted(chosen["val"]),
        "sha256": {t: sha[t] for t in sorted(used) if t in sha},
    }


def recorded_takes(info: Any) -> dict[str, Any] | None:
    """The ``takes`` a checkpoint's ``dataset`` entry records (``run_takes``), None when it records none
    (a checkpoint written before runs recorded them) or a malformed record."""
    takes = info.get("takes") if isinstance(info, dict) else None
    if not isinstance(takes, dict):
        return None
    for split in ("train", "val"):
        if not isinstance(takes.get(split), list) or not all(isinstance(t, str) for t in takes[split]):
            return None
    sha = takes.get("sha256")
    if not isinstance(sha, dict) or not all(isinstance(v, str) for v in sha.values()):
        sha = {}
    return {"train": list(takes["train"]), "val": list(takes["val"]), "sha256": dict(sha)}


def take_changes(old: dict[str, Any], new: dict[str, Any], split: str) -> list[str]:
    """How the ``split`` ("train" or "val") takes of two ``run_takes`` records differ, in words: takes
    gone, added, or whose contents changed (their sha256, where both records have it)."""
    before, after = set(old[split]), set(new[split])
    out = []
    if before - after:
        out.append(f"{split} take(s) {first_few(sorted(before - after), 3)} gone")
    if after - before:
        out.append(f"{split} take(s) {first_few(sorted(after - before), 3)} added")
    was, now = old.get("sha256", {}), new.get("sha256", {})
    edited = [t for t in sorted(before & after) if t in was and t in now and was[t] != now[t]]
    if edited:
        out.append(f"{split} take(s) {first_few(edited, 3)} changed")
    return out


def same_take(take: str, sha: str | None, record: dict[str, Any], splits: tuple[str, ...]) -> bool:
    """Whether ``take`` (of contents ``sha``, when known) is one of ``record``'s takes of ``splits``:
    the same id, or the same contents under another id."""
    ids = {t for split in splits for t in record[split]}
    if take in ids:
        return True
    known = record.get("sha256", {})
    return sha is not None and any(known.get(t) == sha for t in ids)


def leaked_takes(record: dict[str, Any], manifest: dict[str, Any], takes: list[str], split: str) -> list[str]:
    """The ``takes`` (of dataset ``manifest``, evaluated as ``split``) that trained or validated the run
    of ``record`` (``recorded_takes``), matched by id or contents. The run's own takes of the split
    evaluated (its train takes on --split train, its val takes on val) are what was asked for, not
    leaks."""
    sha = take_sha256(manifest)
    own = (split,) if split in ("train", "val") else ()
    return [
        t
        for t in sorted(takes)
        if same_take(t, sha.get(t), record, ("train", "val")) and not same_take(t, sha.get(t), record, own)
    ]


def dataset_changes(
    old: dict[str, Any], new: dict[str, Any], cfg: dict[str, Any]
) -> tuple[list[str], list[str]]:
    """(what differs between two manifests of one dataset, in words; those of them that a resumed run
    refuses: ``RUN_DATASET``). The run's train and val takes under ``cfg`` are compared take by take."""
    refused = [DIFFERS[k] for k in RUN_DATASET if old.get(k) != new.get(k)]
    out = list(refused)
    try:
        before = run_takes(old, cfg)
    except InputError:
        before = None
    try:
        after = run_takes(new, cfg)
    except InputError as exc:
        out.append(f"the run's val_takes/drop_takes do not fit it ({exc})")
        refused.append(out[-1])
        after = None
    if before is not None and after is not None:
        out += take_changes(before, after, "train") + take_changes(before, after, "val")
    if not out:
        out.append("the run's train and val takes are unchanged, other entries of manifest.json changed")
    return out, refused


class DatasetChanged(InputError):
    """The dataset a run reads is no longer the build it started on (``DatasetWatch``)."""


class DatasetWatch:
    """The build of dataset ``ds`` that a run started on: its ``manifest`` and ``sha`` (manifest.json's
    sha256). ``check`` (each epoch, each validation, each checkpoint) stops the run with one line when
    manifest.json no longer holds that build: a rebuild mid-run would otherwise mix two builds' samples
    (shards of the new build read against the old manifest fail as damaged, validation reads the new
    val takes). A rebuild is told from manifest.json's contents alone; one that is missing for the
    moment (being swapped in) is waited for briefly. ``reading`` turns a read error into that line
    when the manifest changed (a shard differing from an unchanged manifest keeps its own error)."""

    def __init__(self, ds: Path, manifest: dict[str, Any], sha: str, cfg: dict[str, Any]):
        self.ds, self.manifest, self.sha, self.cfg = Path(ds), manifest, sha, cfg

    @classmethod
    def read(cls, ds: Path, cfg: dict[str, Any]) -> DatasetWatch:
        manifest, sha = read_manifest_sha(ds)
        return cls(ds, manifest, sha, cfg)

    def changed(self) -> DatasetChanged | None:
        """The error that stops the run when manifest.json changed since the run started, else None."""
        path = manifest_path(self.ds)
        sha = file_sha256(path)
        waited = time.monotonic() + MANIFEST_GRACE_S
        while sha is None and time.monotonic() < waited:
            time.sleep(0.1)
            sha = file_sha256(path)
        if sha == self.sha:
            return None
        if sha is None:
            return DatasetChanged(
                f"{self.ds}: manifest.json went away while this run was training (a rebuild under way, or "
                "the dataset moved): --resume continues once the dataset is back, or start a new run"
            )
        try:
            new, sha = read_manifest_sha(self.ds)
        except InputError as exc:
            return DatasetChanged(
                f"{self.ds} was rebuilt while this run was training (its manifest.json changed and is not "
                f"usable now: {exc}): --resume continues on a usable build, or start a new run"
            )
        what, refused = dataset_changes(self.manifest, new, self.cfg)
        advice = (
            "--resume continues on the new build, or start a new run"
            if not refused
            else f"start a new run (--resume refuses the new build: {'; '.join(refused)})"
        )
        return DatasetChanged(
            f"{self.ds} was rebuilt while this run was training (manifest.json sha256 {self.sha[:12]} -> "
            f"{sha[:12]}: {'; '.join(what)}): {advice}"
        )

    def check(self) -> None:
        error = self.changed()
        if error is not None:
            raise error

    def check_together(self, device: torch.device | str = "cpu") -> None:
        """``check`` decided by every rank of a DDP run at once (``agreed_failure``): every rank raises,
        or none does. Each rank must call it at the same point of the run (it holds a collective)."""
        error = agreed_failure(self.changed(), device)
        if error is not None:
            raise error

    def agree(self) -> None:
        """Stop every rank of a DDP run at start-up when they read manifest.json of two builds: each
        reads it on its own, so a rebuild landing between their reads would start them on different
        builds (one rank's samples read against another build's manifest, different val takes). One
        gather of the manifests' sha256; every rank raises the same line, or none does. Without a
        process group of more than one rank: nothing to agree."""
        if not (dist.is_available() and dist.is_initialized()) or dist.get_world_size() < 2:
            return
        shas: list[Any] = [None] * dist.get_world_size()
        dist.all_gather_object(shas, self.sha)
        if len(set(shas)) > 1:
            builds = ", ".join(f"rank {r}: {sha[:12]}" for r, sha in enumerate(shas))
            raise DatasetChanged(
                f"{self.ds} was rebuilt as this run started: its ranks read manifest.json of different "
                f"builds (sha256 {builds}): start the run again"
            )

    @contextmanager
    def reading(self) -> Iterator[None]:
        """Reads of the dataset in the block: an error there (a shard of another size, samples the
        manifest does not list, a missing file) is the rebuild's line when manifest.json changed."""
        try:
            yield
        except DatasetChanged:  # said already
            raise
        except (InputError, OSError):
            error = self.changed()
            if error is not None:
                raise error from None
            raise


def agreed_failure(error: Exception | None, device: torch.device | str = "cpu") -> Exception | None:
    """The error that stops every rank of a DDP run together, given this rank's own (None: it met none):
    its own when it met one, else another rank's line (naming that rank), None when no rank met one.
    Each rank reads its own shards and checks manifest.json when it gets there: a rank that failed alone
    (a damaged sample, a shard gone, a rebuild landing between two ranks' checks) and stopped would leave
    the others waiting at their next collective until it times out, and one that skipped a sample would
    train on other data than its peers. One all-reduce of a flag (on ``device``: the process group's,
    cuda for nccl), and a gather of the lines only on failure. A ``DatasetChanged`` met by another rank
    is one here too; any other error an ``InputError``. Without a process group of more than one rank:
    ``error``."""
    if not (dist.is_available() and dist.is_initialized()) or dist.get_world_size() < 2:
        return error
    flag = torch.tensor([0.0 if error is None else 1.0], dtype=torch.float32, device=device)
    dist.all_reduce(flag)
    if float(flag[0]) == 0:
        return None
    lines: list[Any] = [None] * dist.get_world_size()
    dist.all_gather_object(lines, None if error is None else (isinstance(error, DatasetChanged), str(error)))
    if error is not None:
        return error
    rank, (changed, line) = next((r, x) for r, x in enumerate(lines) if x is not None)
    if changed:
        return DatasetChanged(f"{line} (seen by another rank: rank {rank})")
    return InputError(f"{line} (met by another rank: rank {rank})")
