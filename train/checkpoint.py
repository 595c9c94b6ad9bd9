"""Run folders and checkpoints.

A checkpoint is a plain dict of tensors, numbers, strings and lists (no pickled objects), read with
``torch.load(weights_only=True)``: ``format`` "s2a-train-checkpoint", ``version`` 1, ``system`` (model
name), ``config`` (resolved training config), ``model_config``, ``inputs`` (InputSpec), ``dataset``
(channels, fps), ``state_dict``, ``optimizer``, ``step``, ``epoch``, ``batch`` (data position: next batch
index in ``epoch``), ``positions`` (that pair for every DDP rank), ``rng`` (torch CPU state),
``best_val``, ``bad_evals``, ``finished``, ``stopped``, ``data_order`` (``DATA_ORDER``: the order the
training data is read in; absent in checkpoints written before it was recorded, which resume in the
order they were written in, 1).
"""

from __future__ import annotations

import errno
import json
import os
import shutil
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import asdict
from pathlib import Path
from typing import Any

import torch

from capture.atomic import partial_path, put_in_place, write_json_atomic
from capture.command import stops_deferred
from capture.errors import InputError, loads_names, strict_names
from capture.file_lock import held_elsewhere, holding
from capture.numbers import is_count
from capture.take import MAX_FPS
from dataset.bottleneck import load_plain
from dataset.manifest import features_problems, normalization_problems
from dataset.normalize import FeatureNormalizer, Normalizer

FORMAT = "s2a-train-checkpoint"
VERSION = 1
# 1: shards in storage order every epoch; 2: shard order shuffled per epoch (seed, epoch) when
# shuffle_buffer > 1. A resumed run keeps its checkpoint's, so that it sees the batches it would have.
DATA_ORDER = 2
LAST, BEST, CONFIG, METRICS = "last.pt", "best.pt", "config.json", "metrics.jsonl"
LOCK = ".lock"  # held (fcntl.flock) by the fit writing the run folder, which writes its pid into it
FULL_BYTES = 1 << 20  # a file system with less than this free after a failed write counts as full


def disk_full(exc: BaseException, folder: Path) -> bool:
    """Whether a failed write failed because the file system is full: ENOSPC, its message (torch's
    writer raises a RuntimeError with the C library's text, or none at all), or, for an error that
    names no cause, no space left on the folder's file system."""
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return True
    if "no space left" in str(exc).lower() or "quota exceeded" in str(exc).lower():
        return True
    if isinstance(exc, OSError) and exc.errno is not None:  # another cause the system named (ENOENT, EROFS)
        return False
    try:
        return shutil.disk_usage(folder).free < FULL_BYTES
    except OSError:
        return False


def write_error(exc: BaseException, path: Path, what: str = "") -> InputError:
    """A one-line error naming ``path`` for a write that failed with ``exc`` (an OSError, or the
    RuntimeError torch.save raises: "[enforce fail at inline_container.cc:...]"). Call it while the
    partial file still exists, so that a full disk is still seen as full."""
    what = what or path.name
    if disk_full(exc, path.parent):
        return InputError(f"cannot write {what}: no space left on device", path)
    if isinstance(exc, OSError) and exc.strerror:
        reason = exc.strerror
    else:
        lines = str(exc).strip().splitlines()
        reason = lines[0] if lines else type(exc).__name__
    return InputError(f"cannot write {what}: {reason}", path)


def write_atomically(path: Path, write: Callable[[Path], None], what: str = "") -> None:
    """``write(tmp)`` a file beside ``path``, fsync it and rename it over ``path`` (a device or a pipe is
    written into: ``put_in_place``): a reader (or a full disk) never sees half a file, and an existing
    ``path`` stays as it was when writing fails. Failures become one-line errors naming ``path``."""
    tmp = partial_path(path)
    try:
        write(tmp)
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        put_in_place(tmp, path)
    except BaseException as exc:
        # named while the partial file still exists (``write_error``: a full disk is still seen as full)
        error = write_error(exc, path, what) if isinstance(exc, (OSError, RuntimeError)) else None
        with stops_deferred():  # a (second) Ctrl-C cuts no removal short
            tmp.unlink(missing_ok=True)
        if error is None:
            raise
        raise error from None


def read_run_config(path: Path) -> dict[str, Any]:
    """A run's (or an ensemble's) config.json as a dict."""
    try:
        saved = loads_names(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"unreadable run config ({type(exc).__name__})", path) from None
    if not isinstance(saved, dict):
        raise InputError("run config is not a JSON object", path)
    return saved


def save_checkpoint(payload: dict[str, Any], path: Path) -> None:
    """Atomic write (temporary file, fsync, rename); a failure (a full disk) is a one-line error naming
    the checkpoint, and the previous checkpoint of that name stays."""
    write_atomically(path, lambda tmp: torch.save({"format": FORMAT, "version": VERSION, **payload}, tmp))


@contextmanager
def run_lock(run: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``run/.lock`` (created if needed) while the block runs: a second
    ``fit`` into the same run folder is refused instead of interleaving its checkpoints and metrics.
    A lock file this fit created goes again if the folder holds no run afterwards (a refused fit
    into a folder of the user's leaves it as it was); a fit that locked a file another one removed
    meanwhile locks the new one instead. The holder's pid is written into the file (``fit_in_progress``
    reads it while the lock is held; once released, what the file holds means nothing)."""

    def refused(holder: str) -> InputError:
        return InputError(
            f"another s2a-train fit{holder} is writing this run folder (it holds its .lock): wait for it to "
            "finish, or train into another -o",
            run,
        )

    def remove(created: bool) -> bool:  # while still held: no other fit can be inside it
        return created and not (run / CONFIG).exists()

    lock = ExitStack()
    try:
        lock.enter_context(holding(run / LOCK, refused, remove))
    except OSError as exc:
        raise write_error(exc, run / LOCK, "the run folder's lock file") from None
    with lock:
        yield


def fit_in_progress(run: str | Path) -> tuple[Path, int | None] | None:
    """(run folder, pid or None) when a live ``fit`` holds the lock of the run folder that ``run`` (a run
    folder or a checkpoint file in one) is, or belongs to (an ensemble's member ``fold-i``: the
    ensemble's folder), else None."""
    path = Path(run)
    folder = path if path.is_dir() else path.parent
    folders = [folder, folder.parent] if folder.name.startswith("fold-") else [folder]
    for candidate in folders:
        lock = candidate / LOCK
        if lock.is_file() and held_elsewhere(lock):
            try:
                pid: int | None = int(lock.read_text().split()[0])
            except (OSError, ValueError, IndexError, UnicodeDecodeError):
                pid = None  # a fit of an older version writes none
            return candidate, pid
    return None


def training_note(run: str | Path, payload: dict[str, Any]) -> str | None:
    """The note of ``eval`` and ``predict`` on a run whose ``fit`` is still going: which checkpoint (of
    which step) they use, that a later one may replace. None when no fit holds the run's lock."""
    live = fit_in_progress(run)
    if live is None:
        return None
    folder, pid = live
    who = f" (pid {pid})" if pid is not None else ""
    if "ensemble" in payload:
        using = "its members' checkpoints as they are now"
    else:
        using = f"{checkpoint_path(run).name} of step {payload.get('step')}"
    return f"{folder} is still training{who}: using {using}"


def refuse_other_world(trained: int, world: int, what: str, where: Path) -> None:
    """A run (``what``: "run", "ensemble") resumes only under as many processes as it was trained with:
    its data positions and its random state are per rank."""
    if trained != world:
        raise InputError(f"the {what} was trained with {trained} process(es): resume it with as many", where)


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    if not path.is_file():
        raise InputError("checkpoint not found", path)
    payload = load_plain(path, "training checkpoint")
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise InputError(f'not a training checkpoint (expected "format": "{FORMAT}")', path)
    if payload.get("version") != VERSION:
        raise InputError(f"checkpoint version {payload.get('version')!r}; this reads version {VERSION}", path)
    return payload


# a model whose output is NaN or infinite: refused by eval, predict and export alike
NOT_FINITE = "the model's output is not finite (NaN or inf): a damaged checkpoint?"


def checkpoint_path(run: str | Path) -> Path:
    """The checkpoint file a run folder (or file) loads, for messages; an ensemble's folder itself."""
    try:
        return run_checkpoint(run)
    except InputError:
        return Path(run)


def run_checkpoint(run: str | Path) -> Path:
    """The checkpoint to use for a finished run folder (best on validation, else last), or a file."""
    run = Path(run)
    if run.is_file():
        return run
    if not run.is_dir():
        raise InputError("run folder not found", run)
    for name in (BEST, LAST):
        if (run / name).is_file():
            return run / name
    if any(run.glob("fold-*")):
        raise InputError("the ensemble has not finished (no ensemble.json): resume its training", run)
    raise InputError(f"run folder has no {BEST} or {LAST} (train it with s2a-train fit)", run)


def load_system(run: str | Path):
    """(model in eval mode, checkpoint payload) of a run; of a cross-validation ensemble's run folder,
    the members' mean (train/ensemble.py)."""
    from .ensemble import ENSEMBLE, load_ensemble

    if Path(run).is_dir() and (Path(run) / ENSEMBLE).is_file():
        return load_ensemble(Path(run), _load_run)  # a member's last.pt is no ensemble: no hint
    try:
        return _load_run(run)
    except InputError as exc:
        raise _last_instead(exc, Path(run)) from None


def load_for_inference(run: str | Path, precision: str, style: str | None, say: Callable[[str], None]):
    """(model ready for inference at ``precision``, checkpoint payload, its ``InputSpec``) of ``run``,
    as eval, predict and speak load it: the run's note (``training_note``) goes to ``say``; a style the
    run lacks is an ``InputError``."""
    from .data import InputSpec
    from .precision import for_inference
    from .style import check_style

    model, payload = load_system(run)
    note = training_note(run, payload)
    if note is not None:
        say(f"note: {note}")
    spec = InputSpec.from_json(payload["inputs"])
    check_style(spec.styles, style)
    return for_inference(model, precision), payload, spec


def _last_instead(exc: InputError, run: Path) -> InputError:
    """``exc``, about the best.pt a run folder loads, with how to load its last.pt instead: never done
    unasked, as it is another model (the last step's weights, not the best on validation)."""
    if not (run.is_dir() and exc.path == str(run / BEST) and (run / LAST).is_file()):
        return exc
    return InputError(
        f"{exc.reason}; to use the run's last checkpoint instead (the last step's weights, not the best "
        f"on validation), give {run / LAST} in place of the run folder",
        exc.path,
    )


def _load_run(run: str | Path):
    """(model in eval mode, checkpoint payload) of one run folder's checkpoint, or a checkpoint file."""
    from .data import InputSpec
    from .systems import build_model

    path = run_checkpoint(run)
    payload = load_checkpoint(path)
    check_payload(payload, path)
    try:
        spec = InputSpec.from_json(payload["inputs"])
    except (TypeError, KeyError) as exc:
        raise InputError(f"checkpoint has malformed inputs ({exc})", path) from None
    check_declared_sizes(payload, spec, path)
    try:
        with torch.device("meta"):  # sizes only: nothing allocated before they match the weights
            shaped, _ = build_model(payload["system"], spec, payload["config"])
    except InputError as exc:
        raise InputError(f"checkpoint has a malformed config ({exc})", path) from None
    check_model_shapes(shaped, payload["state_dict"], path)
    model, _ = build_model(payload["system"], spec, payload["config"])
    try:
        model.load_state_dict(payload["state_dict"])
    except (RuntimeError, TypeError, AttributeError) as exc:
        first = str(exc).strip().splitlines()[:2]
        raise InputError(f"checkpoint has a malformed state_dict ({' '.join(first)})", path) from None
    model.eval()
    return model, payload


def _arch_sizes(arch: Any, at: str = "arch") -> Iterator[tuple[str, int]]:
    """(name, value) of every integer of a config's ``arch`` (its system tables included)."""
    for key, value in arch.items() if isinstance(arch, dict) else ():
        if isinstance(value, dict):
            yield from _arch_sizes(value, f"{at}.{key}")
        elif isinstance(value, int) and not isinstance(value, bool):
            yield f"{at}.{key}", value


def _system_sizes(payload: dict[str, Any], spec) -> Iterator[tuple[str, int]]:
    """(name, value) of the sizes the checkpoint's system is built with, resolved from its config as
    ``build_model`` resolves them but without building anything: the fields of that system's arch
    dataclass (arch keys of other systems, and other systems' tables, are ignored as the system ignores
    them), ridge's ``ridge_context``. A config the system cannot resolve gives none: ``build_model``
    refuses it, before building any layer."""
    from .systems import ARCH_TABLES, _config

    system, cfg = payload["system"], payload["config"]
    if system == "ridge":
        yield from _arch_sizes({"ridge_context": cfg.get("ridge_context")}, "config")
    elif system in ARCH_TABLES:
        try:
            resolved = asdict(_config(ARCH_TABLES[system], spec, {}, dict(cfg.get("arch", {})), system))
        except (InputError, ValueError, TypeError, AttributeError):
            return
        yield from _arch_sizes(resolved)


def check_declared_sizes(payload: dict[str, Any], spec, path: Path) -> None:
    """No size a checkpoint declares (its inputs' dims; the widths, layers, experts of its system's arch,
    as ``_system_sizes`` resolves them from its config) may exceed the number of weights its state_dict
    holds: the model it describes would hold at least that many. Building the model loops over its
    layers and experts, so this comes first. ``max_frames`` sizes a computed table instead
    (``model.PositionalEncoding`` refuses one past ``model.MAX_TABLE_BYTES`` before computing it)."""
    weights = sum(v.numel() for v in payload["state_dict"].values() if isinstance(v, torch.Tensor))
    inputs = payload["inputs"]
    sizes = [(f"inputs.{k}", inputs[k]) for k in ("content_dim", "prosody_dim", "out_dim")]
    sizes += [(k, v) for k, v in _system_sizes(payload, spec) if not k.endswith(".max_frames")]
    for name, value in sizes:
        if value > weights:
            raise InputError(
                f"checkpoint has malformed {name} ({value}): more than the {weights} weights it holds", path
            )


def check_model_shapes(model: torch.nn.Module, state_dict: dict[str, Any], path: Path) -> None:
    """The model a checkpoint's inputs and config build, on the meta device (sizes only, nothing
    allocated), against the weights it holds: every tensor the model loads must have the shape of the
    stored one (building it has refused a position table past ``model.MAX_TABLE_BYTES``). The model is
    built for real after this, so it allocates no more than the checkpoint holds."""
    expected = model.state_dict()
    for key, tensor in expected.items():
        theirs = state_dict.get(key)
        if not isinstance(theirs, torch.Tensor) or theirs.shape != tensor.shape:
            found = f"shape {tuple(theirs.shape)}" if isinstance(theirs, torch.Tensor) else "missing"
            raise InputError(
                f"checkpoint has a malformed state_dict ({key}: {found}, its inputs and config make "
                f"shape {tuple(tensor.shape)})",
                path,
            )


# what inference reads from a checkpoint, with the types it needs
NEEDED = {"system": str, "config": dict, "inputs": dict, "dataset": dict, "state_dict": dict, "step": int}
NEEDED_DATASET = {"channels": list, "features": dict, "normalization": dict}


def check_payload(payload: dict[str, Any], path: Path) -> None:
    """Refuse a checkpoint whose contents inference cannot use, naming the first bad entry."""
    for key, kind in NEEDED.items():
        if key not in payload:
            raise InputError(f"checkpoint lacks {key!r}", path)
        if not isinstance(payload[key], kind) or isinstance(payload[key], bool):
            raise InputError(f"checkpoint has malformed {key!r} (not a {kind.__name__})", path)
    info = payload["dataset"]
    for key, kind in NEEDED_DATASET.items():
        if not isinstance(info.get(key), kind):
            raise InputError(f"checkpoint lacks or has malformed dataset {key!r}", path)
    fps = info.get("fps")
    if not isinstance(fps, (int, float)) or isinstance(fps, bool) or not 0 < fps <= MAX_FPS:
        raise InputError(
            f"checkpoint has malformed dataset 'fps' ({fps!r}): not a frame rate up to {MAX_FPS:g}", path
        )
    if not all(isinstance(c, str) for c in info["channels"]):
        raise InputError("checkpoint has malformed dataset 'channels'", path)
    out_dim = payload["inputs"].get("out_dim")
    if out_dim != len(info["channels"]):
        raise InputError(
            f"checkpoint has malformed dataset 'channels': {len(info['channels'])} listed, the model "
            f"outputs {out_dim!r}",
            path,
        )
    # the dataset's features and normalisation as the run read them from its manifest: the same checks
    problems = features_problems(info["features"])
    problems += normalization_problems(info["normalization"], info["channels"], info["features"])
    if problems:
        field, message = problems[0]
        raise InputError(f"checkpoint has malformed dataset '{field}' ({message})", path)
    try:
        Normalizer.from_json(info["normalization"]["animation"])
        FeatureNormalizer(info["normalization"])
    except (KeyError, TypeError, ValueError, AttributeError, InputError) as exc:
        raise InputError(f"checkpoint has malformed dataset 'normalization' ({exc})", path) from None
    check_inputs(payload["inputs"], info["features"]["dims"], path)
    if not isinstance(payload.get("model_config"), dict | None):
        raise InputError("checkpoint has malformed 'model_config' (not a dict)", path)


def check_inputs(inputs: dict[str, Any], dims: dict[str, int], path: Path) -> None:
    """The checkpoint's InputSpec: its fields' types, and its sizes those of its dataset's features
    (plus one prosody column per speaker style)."""
    names = ("prosody", "styles")
    if not isinstance(inputs.get("content"), str) or not all(
        isinstance(inputs.get(k, []), list | tuple) and all(isinstance(n, str) for n in inputs.get(k, []))
        for k in names
    ):
        raise InputError("checkpoint has malformed inputs (content, prosody or styles not names)", path)
    for key in ("content_dim", "prosody_dim", "out_dim"):
        if not is_count(inputs.get(key)):
            raise InputError(f"checkpoint has malformed inputs ({key} {inputs.get(key)!r})", path)
    for name in (inputs["content"], *inputs["prosody"]):
        if name not in dims:
            raise InputError(
                f"checkpoint has malformed inputs ({name} is not among its dataset's features)", path
            )
    prosody = sum(dims[p] for p in inputs["prosody"]) + len(inputs.get("styles", []))
    if (inputs["content_dim"], inputs["prosody_dim"]) != (dims[inputs["content"]], prosody):
        raise InputError(
            f"checkpoint has malformed inputs (content_dim {inputs['content_dim']}, prosody_dim "
            f"{inputs['prosody_dim']}; its dataset's features give {dims[inputs['content']]} and {prosody})",
            path,
        )


def write_json(path: Path, obj: Any) -> None:
    try:
        write_json_atomic(path, strict_names(obj), allow_nan=True)
    except OSError as exc:
        raise write_error(exc, path) from None
