"""``align_takes``: many takes, in parallel, skipping those whose inputs and options are unchanged.

The fingerprint of a take = sha256 over the align version, the options and the bytes of the raw take's
``meta.json``, ``frames.npz`` and audio file. It is stored in every output's ``meta.extra["align"]``;
a later run with the same fingerprint and all outputs present does nothing for that take.

One run at a time writes into an output folder (``output_lock``: ``flock`` on its hidden ``.align.lock``).
Aligned takes whose raw take is gone (neither given to the run nor in the folder that held it) are named
in one warning and, with ``prune``, removed (``orphans``, ``prune_orphans``); those whose raw take's folder
cannot be reached (a drive not mounted) are named in another warning and never removed.
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing as mp
import os
import re
import shutil
import sys
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from capture import InputError, S2AError, Take, TakeMeta, find_takes, read_meta, read_take, write_take
from capture.atomic import all_or_none, batch_of_writes
from capture.command import json_safe, stops_deferred
from capture.file_lock import another_writer, holding
from capture.importer import no_takes_found
from capture.numbers import is_count
from capture.take import AUDIO_FILE, FRAMES_FILE, META_FILE, is_take_dir, make_out_dir, safe_id, sha256_file
from capture.workers import submit_all, worker_pool

from .aligner import ALIGN_VERSION, align_with_report
from .grid import interpolated_share
from .options import AlignOptions
from .recorded import RecordedAudio, reading_from_file
from .torch_threads import torch_threads

# The name of an aligned segment: ``<id>.segNN``, numbered from 01 (the aligner writes ``:02d``, so a take
# of 100 segments or more has ``.seg100``): the one pattern the outputs of a take are recognised by.
SEGMENT_SUFFIX = r"\.seg[0-9]{2,}"


def _segment_number(name: str) -> int:
    """The number of an aligned segment from its name (``X.seg07`` -> 7)."""
    return int(name.rsplit(".seg", 1)[1])


def fingerprint(folder: Path, options: AlignOptions) -> str:
    """sha256 (hex) of the align version, the options and the raw take's files."""
    h = hashlib.sha256()
    h.update(json.dumps({"version": ALIGN_VERSION, "options": options.to_json()}, sort_keys=True).encode())
    for name in (META_FILE, FRAMES_FILE, AUDIO_FILE):
        p = folder / name
        if p.is_file():
            h.update(f"{name} {sha256_file(p)}\n".encode())
    return h.hexdigest()


_SEGMENT_OF = re.compile(r"(.+)" + SEGMENT_SUFFIX)  # group 1: the raw take's ``safe_id``


def _segments_listed(out_dir: Path) -> dict[str, list[str]] | None:
    """The names in ``out_dir`` of aligned segments (``<id>.segNN``) by the ``safe_id`` of the raw take
    they would be cut from, from one listing of the folder; None when it cannot be listed."""
    try:
        names = os.listdir(out_dir)
    except OSError:
        return None
    by_take: dict[str, list[str]] = {}
    for n in names:
        if (m := _SEGMENT_OF.fullmatch(n)) is not None:
            by_take.setdefault(m.group(1), []).append(n)
    return by_take


def _outputs_of(
    out_dir: Path, take_id: str, segments: list[str] | None = None
) -> list[tuple[Path, TakeMeta]]:
    """Aligned take folders in ``out_dir`` made from the raw take ``take_id``, with their metadata.
    ``segments``: the names of its segments in ``out_dir`` (``_segments_listed``); None: listed here."""
    base = safe_id(take_id)
    if segments is None:
        segments = (_segments_listed(out_dir) or {}).get(base, [])
    found = []
    for p in [out_dir / base, *(out_dir / n for n in sorted(segments, key=_segment_number))]:
        if (p / META_FILE).is_file():
            try:
                m = read_meta(p)
            except S2AError:
                continue
            report = m.extra.get("align")
            parent = report.get("parent") if isinstance(report, dict) else None
            if m.source_kind == "aligned" and isinstance(parent, dict) and parent.get("id") == take_id:
                found.append((p, m))
    return found


def _previous(outs: list[tuple[Path, TakeMeta]], fp: str, source: str) -> dict[str, Any] | None:
    """The stored report of the outputs ``outs`` of a raw take (``_outputs_of``) when they are complete,
    made with the fingerprint ``fp`` and from the raw take folder at ``source`` (a take folder moved or
    renamed since is aligned again once, so that its outputs record where it is: ``orphans`` goes by
    it); None otherwise."""
    if not outs:
        return None
    reports = [m.extra["align"] for _, m in outs]
    count = reports[0].get("segment_count")
    if any(r.get("fingerprint") != fp for r in reports) or len(reports) != count:
        return None
    if any(r["parent"].get("path") != source for r in reports):
        return None
    if not all(is_count(r.get("frames")) and is_count(r.get("gaps_interpolated")) for r in reports):
        return None  # an output edited by hand: aligned again
    own = {
        "segment",
        "segment_count",
        "segment_start_s",
        "speech_segments",
        "parent",
        "fingerprint",
        "options",
    }
    out = {k: v for k, v in reports[0].items() if k not in own}
    out["frames"] = sum(r["frames"] for r in reports)
    out["gaps_interpolated"] = sum(r["gaps_interpolated"] for r in reports)
    out["interpolated_share"] = interpolated_share(out["gaps_interpolated"], out["frames"])
    out["segment_list"] = [
        {
            "id": m.id,
            "frames": r["frames"],
            "start_s": r.get("segment_start_s"),
            "duration_s": round(r["frames"] / r["fps"], 6) if r.get("fps") else None,
            "gaps_interpolated": r["gaps_interpolated"],
            "interpolated_share": interpolated_share(r["gaps_interpolated"], r["frames"]),
            "speech_segments": r.get("speech_segments"),
        }
        for (_, m), r in zip(outs, reports)
    ]
    out["outputs"] = [str(p) for p, _ in outs]
    return out


def align_folder(
    folder: str | Path,
    out_dir: str | Path,
    options: AlignOptions,
    force: bool = False,
    skip_without_audio: bool = False,
    listed: dict[str, list[str]] | None = None,
) -> dict:
    """Align one raw take folder into ``out_dir``; returns its report (``skipped`` True when unchanged
    or, with ``skip_without_audio``, when the take has no audio; ``error`` set when the take could not
    be aligned). ``listed``: ``_segments_listed`` of ``out_dir`` as a batch listed it once for all its
    takes (no take's segments are written by another), holding at least this take's; its id not in
    it, or None: listed here."""
    folder, out_dir = Path(folder), Path(out_dir)
    try:
        meta = read_meta(folder)
        fp = fingerprint(folder, options)
        outs = _outputs_of(out_dir, meta.id, (listed or {}).get(safe_id(meta.id)))
        if not force:
            prev = _previous(outs, fp, str(folder.resolve()))
            if prev is not None:
                return json_safe({"id": meta.id, "path": str(folder), "skipped": True} | prev)
        if meta.audio is None and skip_without_audio:
            return {"id": meta.id, "path": str(folder), "skipped": True, "reason": "no audio"}
        segments, report = _align_read(folder, meta, options)
        stale = [p for p, _ in outs]
        for seg in segments:
            seg.meta.extra["align"]["fingerprint"] = fp
            seg.meta.extra["align"]["parent"]["path"] = str(folder.resolve())
        written = write_segments(segments, out_dir)
        for p in stale:
            if p not in written:
                shutil.rmtree(p, ignore_errors=True)
        report = {"id": meta.id, "path": str(folder), "skipped": False} | report
        report["outputs"] = [str(p) for p in written]
        report.pop("options", None)
        return json_safe(report)
    except S2AError as exc:
        return _error(folder, str(exc))
    except OSError as exc:  # a file of the take or the output folder could not be read or written
        return _error(folder, f"{exc.filename or folder}: {exc.strerror or exc}")
    except Exception as exc:  # a fault of this program on this take: reported, the batch goes on
        return _error(
            folder, f"{folder}: internal error ({type(exc).__name__}: {str(exc)[:200]}); please report it"
        )


def _align_read(folder: Path, meta: TakeMeta, options: AlignOptions) -> tuple[list[Take], dict[str, Any]]:
    """The raw take in ``folder`` read and aligned. Its audio is read from its file a block at a time
    as it is converted (``RecordedAudio``): an hour at 44.1 kHz, 317 MB as int16 mono, was held whole
    through the alignment. Audio in a file ``read_take`` would refuse or that is not a WAV it writes is
    read whole, by ``read_take``, which says what is wrong with it."""
    file = None if meta.audio is None else RecordedAudio.from_take_file(folder / meta.audio.file, meta.audio)
    try:
        take = read_take(folder, audio=file is None)
        if take.meta.source_kind == "aligned":
            raise InputError("take is already aligned", folder)
        with reading_from_file(take, file):
            return align_with_report(take, options)
    finally:
        if file is not None:
            file.close()


def write_segments(segments: list[Take], out_dir: Path) -> list[Path]:
    """Write the aligned takes cut from one raw take so that they appear together (``all_or_none``):
    each is assembled complete under its hidden name, and only once all are written are they renamed
    into place, one right after another. An invalid segment, a kill or a full disk while they are
    written leaves none of them visible (the hidden folders of a kill are cleared by the next write);
    only a kill between the renames can leave the set incomplete, which ``s2a-dataset build`` reports."""
    with all_or_none():
        return [write_take(seg, out_dir) for seg in segments]


def _error(folder: Path, message: str) -> dict[str, Any]:
    """The report of a take that could not be aligned (one line: the message holds no line break)."""
    return {"id": folder.name, "path": str(folder), "error": " ".join(message.split())}


def _take_ids(folders: list[Path]) -> dict[Path, str]:
    """The id of each take folder whose metadata can be read (``align_folder`` reports the others)."""
    ids = {}
    for f in folders:
        try:
            ids[f] = read_meta(f).id
        except S2AError:
            pass
    return ids


def _id_clashes(ids: dict[Path, str]) -> dict[Path, str]:
    """Takes (of ``_take_ids``) whose id an earlier take of the run already has (their aligned takes
    would overwrite each other in the output folder), with the error to report for each."""
    seen: dict[str, Path] = {}
    clashes = {}
    for f, take_id in ids.items():
        key = safe_id(take_id).casefold()
        if key in seen:
            clashes[f] = (
                f"{f}: take id {take_id!r} is also the id of {seen[key]}: their aligned takes would "
                "overwrite each other; give one another id (s2a-capture import --id) or align them apart"
            )
        else:
            seen[key] = f
    return clashes


def _worker_context(opts: AlignOptions):
    """Worker processes forked on Linux, with the modules (and torch for silero) imported once in the
    parent: importing torch costs seconds per process, which a spawned worker would pay each time.
    Forking after ``import torch`` is safe while the parent has run no torch operation (the model is
    only loaded in the workers), as PyTorch's own data-loader workers rely on. Elsewhere: spawn."""
    if sys.platform.startswith("linux") and "fork" in mp.get_all_start_methods():
        if opts.vad == "silero":
            with torch_threads(None):  # silero_vad pins the process to one thread on import
                import silero_vad  # noqa: F401
            import torch  # noqa: F401
        return mp.get_context("fork")
    return mp.get_context("spawn")


def _result(folder: Path, future) -> dict[str, Any]:
    """A worker's report; a worker that died (killed, out of memory) is that take's error."""
    try:
        return future.result()
    except Exception as exc:  # BrokenProcessPool and the like: align_folder itself never raises
        return _error(folder, f"{folder}: the worker process failed ({type(exc).__name__}: {exc})")


def align_takes(
    paths,
    out_dir: str | Path,
    options: AlignOptions | None = None,
    jobs: int = 1,
    force: bool = False,
    on_report=None,
    skip_without_audio: bool = False,
    prune: bool = False,
    on_message: Callable[[str], None] | None = None,
    on_warning: Callable[[str], None] | None = None,
) -> list[dict[str, Any]]:
    """Align every take under ``paths`` (take folders, searched recursively) into ``out_dir`` with
    ``jobs`` worker processes; returns one report dict per take, in input order. ``on_report`` is
    called with each report as it is ready. One run at a time writes into ``out_dir`` (``output_lock``;
    another is an ``InputError``). At the end, aligned takes in ``out_dir`` whose raw take is gone
    (``orphans``) are named in one warning to ``on_warning``, or removed with ``prune`` (and named as
    removed to ``on_message``); those whose raw take cannot be reached (``unreachable``) are named in
    another warning and never removed. The texts are bare: whoever prints them says what they are
    (``s2a-align: warning: ...``)."""
    opts = options or AlignOptions()
    opts.validate()
    out_dir = Path(out_dir)
    out = out_dir.resolve()
    # not into an input folder itself (its takes would be skipped as output) nor into a take folder
    if any(out == Path(p).resolve() for p in paths) or any(is_take_dir(d) for d in (out, *out.parents)):
        raise InputError("the output folder is an input folder or inside a take: choose another -o", out_dir)
    folders = [f for f in find_takes(paths) if out not in f.resolve().parents]
    folders = list({f.resolve(): f for f in folders}.values())  # a take named twice is aligned once
    if not folders:
        raise no_takes_found(paths, "s2a-align")
    make_out_dir(out_dir)
    with output_lock(out_dir), batch_of_writes(out_dir):  # listed once for leftovers of killed writes
        reports = _align_all(folders, out_dir, opts, jobs, force, on_report, skip_without_audio)
        lost = _lost(out_dir, folders)
        found, away = lost[GONE], lost[UNREACHABLE]
        if away:
            _say(
                on_warning,
                f"{_count(away)} in {out_dir} {'comes' if len(away) == 1 else 'come'} from raw "
                f"takes that are not reachable (the folder that held them is not there: a drive not "
                f"mounted, or a share mounted at another path?): {_names(away)}; kept"
                f"{', also with --prune' if prune else ''}: "
                "mount it where it was, or remove them by hand if the takes are gone",
            )
        if found and prune:
            removed, failed = prune_orphans(out_dir, found)
            if removed:
                _say(
                    on_message,
                    f"removed {_count(removed)} from {out_dir} whose raw take is gone: {_names(removed)}",
                )
            if failed:
                _say(on_warning, f"could not remove {_names(failed)} from {out_dir}: {failed[0][2]}")
        elif found:
            _say(
                on_warning,
                f"{_count(found)} in {out_dir} {'comes' if len(found) == 1 else 'come'} from raw "
                f"takes that are gone (not among this run's takes, not on disk): {_names(found)}; "
                "s2a-dataset build would still use them: align again with --prune to remove them",
            )
        return reports


def _align_all(
    folders: list[Path],
    out_dir: Path,
    opts: AlignOptions,
    jobs: int,
    force: bool,
    on_report,
    skip_without_audio: bool,
) -> list[dict[str, Any]]:
    ids = _take_ids(folders)
    clashes = _id_clashes(ids)
    # the output folder listed once, not once per take; each take is given its own segments
    listed = _segments_listed(out_dir)

    def own(f: Path) -> dict[str, list[str]] | None:
        if listed is None or f not in ids:
            return None
        base = safe_id(ids[f])
        return {base: listed.get(base, [])}

    reports: list[dict[str, Any]] = []
    if jobs <= 1 or len(folders) == 1:
        for f in folders:
            r = {"id": f.name, "path": str(f), "error": clashes[f]} if f in clashes else None
            r = r or align_folder(f, out_dir, opts, force, skip_without_audio, own(f))
            reports.append(r)
            if on_report:
                on_report(r)
        return reports
    todo = [f for f in folders if f not in clashes]
    with worker_pool(min(jobs, len(todo)), _worker_context(opts)) as pool:  # no idle workers
        calls = [(f, out_dir, opts, force, skip_without_audio, own(f)) for f in todo]
        futures = dict(zip(todo, submit_all(pool, align_folder, calls)))
        for f in folders:
            if f in futures:
                r = _result(f, futures[f])
            else:
                r = {"id": f.name, "path": str(f), "error": clashes[f]}
            reports.append(r)
            if on_report:
                on_report(r)
    return reports


LOCK_FILE = ".align.lock"  # hidden: find_takes and the dataset stage pass it over


@contextmanager
def output_lock(out_dir: Path) -> Iterator[None]:
    """Hold an exclusive lock on the output folder ``out_dir`` (``flock`` on its hidden ``.align.lock``,
    which holds the pid) for a whole run: another run into it is refused at once (``InputError``). The
    kernel drops the lock when the process ends, however it ends (worker processes forked meanwhile
    share it until they end), so a killed run never blocks the next one; the file is removed when the
    run ends. Where no lock can be taken (a folder that cannot be written: each take's write then says
    so), the run goes on without one."""

    with holding(out_dir / LOCK_FILE, another_writer("s2a-align", out_dir), optional=True):
        yield


_PRUNED = re.compile(r"\..+\.pruned-[a-z0-9_]{8}")  # a folder being removed by --prune (a kill's leftover)


def _source_of(folder: Path) -> tuple[str, str] | None:
    """(id, absolute path) of the raw take the aligned take ``folder`` was made from, as its
    ``meta.extra["align"]["parent"]`` records them; None for anything that is not an aligned take this
    stage wrote (named ``<id>`` or ``<id>.segNN`` after its raw take's id) or records no absolute path."""
    try:
        if not is_take_dir(folder):
            return None
        m = read_meta(folder)
    except (S2AError, OSError):
        return None
    report = m.extra.get("align")
    parent = report.get("parent") if isinstance(report, dict) else None
    if m.source_kind != "aligned" or not isinstance(parent, dict):
        return None
    take_id, path = parent.get("id"), parent.get("path")
    if not isinstance(take_id, str) or not isinstance(path, str) or not os.path.isabs(path):
        return None
    if m.id != take_id and not re.fullmatch(re.escape(take_id) + SEGMENT_SUFFIX, m.id):
        return None
    return (take_id, path) if folder.name == safe_id(m.id) else None


def _same_id(a: str, b: str) -> bool:
    """Whether two take ids name the same output folder (``safe_id``, ignoring case)."""
    return safe_id(a).casefold() == safe_id(b).casefold()


THERE, GONE, UNREACHABLE = "there", "gone", "unreachable"


def _raw_take_state(path: str, take_id: str) -> str:
    """Whether the raw take ``take_id`` is still at ``path`` (``THERE``), is gone from the folder that
    held it (``GONE``: that folder, the parent of ``path``, is there and holds no take ``take_id`` at
    ``path``), or cannot be reached (``UNREACHABLE``: that folder is not there, as on a drive that is not
    mounted or a share mounted at another path, so nothing is known of the take). A take there whose
    metadata cannot be read, or a path that cannot be looked at, is not known to be gone: ``THERE``."""
    try:
        if not os.path.isdir(os.path.dirname(path)):
            return UNREACHABLE
        if not is_take_dir(path):
            return GONE
        return THERE if _same_id(read_meta(path).id, take_id) else GONE
    except (S2AError, OSError):
        return THERE


def orphans(out_dir: Path, folders: list[Path]) -> list[tuple[Path, str]]:
    """The aligned takes in ``out_dir`` (each with the path of its raw take) whose raw take is gone: not
    one of this run's take ``folders`` (by path or by take id: a renamed take folder keeps its id) and
    not at the path its outputs record, in a folder that is there (nothing at the path, or a take of
    another id). Takes aligned from other folders into ``out_dir`` by other runs stay as long as their
    raw takes do; those whose raw take's folder cannot be reached are no orphans (``unreachable``). Only
    aligned takes this stage wrote are looked at (``_source_of``)."""
    return _lost(out_dir, folders)[GONE]


def unreachable(out_dir: Path, folders: list[Path]) -> list[tuple[Path, str]]:
    """The aligned takes in ``out_dir`` (each with the path of its raw take) whose raw take is not among
    the take ``folders`` and whose raw take's folder is not there (a drive not mounted, a share mounted
    elsewhere): not known to be gone, never pruned."""
    return _lost(out_dir, folders)[UNREACHABLE]


def _lost(out_dir: Path, folders: list[Path]) -> dict[str, list[tuple[Path, str]]]:
    """The aligned takes in ``out_dir`` whose raw take is not among the take ``folders``, by the state
    of their raw take (``GONE``, ``UNREACHABLE``; see ``orphans``)."""
    given_paths = {str(f.resolve()) for f in folders}
    given_ids = []
    for f in folders:
        try:
            given_ids.append(safe_id(read_meta(f).id).casefold())
        except S2AError:
            pass  # its outputs, if any, record its path
    given = set(given_ids)
    state: dict[tuple[str, str], str] = {}
    found: dict[str, list[tuple[Path, str]]] = {GONE: [], UNREACHABLE: []}
    try:
        with os.scandir(out_dir) as entries:
            names = sorted(
                e.name for e in entries if not e.name.startswith(".") and e.is_dir(follow_symlinks=False)
            )
    except OSError:
        return found
    for name in names:
        source = _source_of(out_dir / name)
        if source is None:
            continue
        take_id, path = source
        if path in given_paths or safe_id(take_id).casefold() in given:
            continue
        if source not in state:
            state[source] = _raw_take_state(path, take_id)
        if state[source] != THERE:
            found[state[source]].append((out_dir / name, path))
    return found


def prune_orphans(out_dir: Path, found: list[tuple[Path, str]]) -> tuple[list, list]:
    """Remove the aligned takes ``found`` by ``orphans``: each is first renamed to a hidden
    ``.NAME.pruned-XXXXXXXX`` (readers never see half a take; a kill's leftover is removed by the next
    prune), then deleted. Returns (removed, failed): ``found``'s entries, those that failed with the
    reason added."""
    _clear_pruned(out_dir)
    removed, failed = [], []
    for folder, source in found:
        hidden = None
        try:
            # Ctrl-C and SIGTERM wait until the folder is noted here: met as it was made, a stop left it
            with stops_deferred():
                hidden = Path(tempfile.mkdtemp(prefix=f".{folder.name}.pruned-", dir=out_dir))
            os.replace(folder, hidden / "take")
        except OSError as exc:
            failed.append((folder, source, exc.strerror or str(exc)))
            continue
        finally:
            if hidden is not None:
                with stops_deferred():  # a second Ctrl-C cuts no removal short
                    shutil.rmtree(hidden, ignore_errors=True)
        removed.append((folder, source))
    return removed, failed


def _clear_pruned(out_dir: Path) -> None:
    """Remove the hidden folders a prune that was killed left in ``out_dir``."""
    try:
        with os.scandir(out_dir) as entries:
            left = [e.path for e in entries if _PRUNED.fullmatch(e.name) and e.is_dir(follow_symlinks=False)]
    except OSError:
        return
    for path in left:
        shutil.rmtree(path, ignore_errors=True)


MAX_NAMED = 20  # aligned takes named in one message; the rest counted


def _count(found: list) -> str:
    return f"{len(found)} aligned take{'' if len(found) == 1 else 's'}"


def _names(found: list) -> str:
    """ "a.seg01, a.seg02 (from /raw/a), b (from /raw/b)": the folders grouped by their raw take."""
    by_source: dict[str, list[str]] = {}
    for folder, source, *_ in found[:MAX_NAMED]:
        by_source.setdefault(source, []).append(folder.name)
    text = ", ".join(f"{', '.join(names)} (from {source})" for source, names in by_source.items())
    more = len(found) - MAX_NAMED
    return text + (f" and {more} more" if more > 0 else "")


def _say(on_message: Callable[[str], None] | None, message: str) -> None:
    if on_message:
        on_message(message)
