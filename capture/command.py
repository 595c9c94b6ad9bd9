"""What every stage's command line shares: one-line errors with exit code 1, JSON lines on stdout,
progress on stderr. Usage errors exit with 2 (argparse)."""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

from .errors import S2AError


def json_safe(value: Any) -> Any:
    """``value`` with NaN and infinite numbers as ``None`` (nested in dicts and lists): strict JSON."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value


def emit_json(obj: dict[str, Any]) -> None:
    """One JSON object on one line of stdout."""
    sys.stdout.write(json.dumps(obj, allow_nan=False, default=str) + "\n")
    sys.stdout.flush()


def progress(message: str) -> None:
    """Human-readable progress on stderr."""
    print(message, file=sys.stderr, flush=True)


# The stage packages and their commands: Ctrl-C while one of them imports stops it quietly (below).
COMMANDS = {
    "capture": "s2a-capture",
    "align": "s2a-align",
    "dataset": "s2a-dataset",
    "train": "s2a-train",
    "viewer": "s2a-view",
}
_guarding: str | None = None  # the stage whose command is importing under the guard


def running_command() -> str | None:
    """The stage package whose command this process is (its console script, or ``python -m package``),
    or None for a program that imports the packages."""
    argv = getattr(sys, "argv", None) or [""]
    by_script = {prog: package for package, prog in COMMANDS.items()}
    if os.path.basename(argv[0]) in by_script:
        return by_script[os.path.basename(argv[0])]
    module = _module_run(getattr(sys, "orig_argv", None) or [])  # the interpreter's own arguments
    package = module.split(".")[0] if module else None
    return package if package in COMMANDS else None


# Interpreter options that take the next argument as their value (``python -X importtime -m align``).
_OPTION_VALUES = ("-X", "-W", "--check-hash-based-pycs")


def _module_run(orig: list[str]) -> str | None:
    """The module ``python -m MODULE`` runs, from the interpreter's arguments: only an ``-m`` among its
    own options counts, not one among a script's arguments (``python tool.py -m train``)."""
    i = 1
    while i < len(orig):
        arg = orig[i]
        if arg == "-m":
            return orig[i + 1] if i + 1 < len(orig) else None
        if arg.startswith("-m"):
            return arg[2:]
        if arg.startswith("-c") or arg == "-" or not arg.startswith("-"):
            return None  # a command, standard input or a script: what follows is its own
        i += 2 if arg in _OPTION_VALUES else 1
    return None


def _stop_quietly(_signum: int, _frame: Any) -> None:
    print(f"{COMMANDS.get(_guarding or '', 'command')}: interrupted", file=sys.stderr, flush=True)
    os._exit(130)  # nothing has been written yet


def guard_imports() -> None:
    """Called first by ``capture`` (which every stage imports first): while a stage command imports
    numpy, scipy and PyTorch (its first second or more), Ctrl-C stops it at once, quietly, with exit code
    130. Ctrl-C in the middle of an import leaves a half-imported library whose errors follow (a
    KeyboardInterrupt traceback, or a RecursionError inside numpy). Only in the command itself, on the
    main thread, where Ctrl-C was Python's own: a program that imports the packages keeps its Ctrl-C."""
    global _guarding
    package = running_command()
    if (
        _guarding is None
        and package is not None
        and threading.current_thread() is threading.main_thread()
        and signal.getsignal(signal.SIGINT) is signal.default_int_handler
    ):
        _guarding = package
        signal.signal(signal.SIGINT, _stop_quietly)


def imports_done(package: str) -> bool:
    """Called by each stage package once its imports are done: the command of ``package`` gets Python's
    own Ctrl-C back (its commands handle it from here). Returns whether its imports were guarded."""
    global _guarding
    if _guarding != package:
        return False
    _guarding = None
    if signal.getsignal(signal.SIGINT) is _stop_quietly:  # unless an import installed its own
        signal.signal(signal.SIGINT, signal.default_int_handler)
    return True


class Terminated(KeyboardInterrupt):
    """SIGTERM reached the command (``timeout``, ``kill``, a batch scheduler): it stops as on Ctrl-C,
    with exit code 143."""


@contextmanager
def sigterm_stops() -> Iterator[None]:
    """Inside, SIGTERM raises ``Terminated`` in the main thread (once; a second SIGTERM ends the process
    at once), so that the command stops as on Ctrl-C: its ``finally`` blocks run, its partial files go.
    Left alone off the main thread and where the caller already handles SIGTERM."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGTERM)
    if previous is not signal.SIG_DFL:
        yield
        return

    def handler(signum: int, frame: Any) -> None:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        raise Terminated()

    signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def out_of_memory(exc: BaseException) -> bool:
    """Whether ``exc`` says memory ran out: a MemoryError (NumPy's too), or PyTorch's allocator refusing
    (the CPU's "can't allocate memory", ``torch.OutOfMemoryError``'s "CUDA out of memory")."""
    message = str(exc).lower()
    return isinstance(exc, MemoryError) or (
        isinstance(exc, RuntimeError)
        and (
            type(exc).__name__ == "OutOfMemoryError"
            or "can't allocate memory" in message
            or "out of memory" in message
        )
    )


def run(
    prog: str,
    parser: argparse.ArgumentParser,
    main: Callable[[argparse.Namespace], int],
    argv: Sequence[str] | None,
) -> int:
    """Parse ``argv`` and run ``main``; the toolkit's own errors become one line and exit code 1."""
    args = parser.parse_args(argv)
    try:
        return main(args)
    except S2AError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 1
    except Terminated:
        print(f"{prog}: terminated (SIGTERM)", file=sys.stderr)
        return 143
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0
    except OSError as exc:  # the file system refused (read-only, no permission, a file in the way, full)
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"{prog}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 1
    except (MemoryError, RuntimeError) as exc:
        if not out_of_memory(exc):
            raise
        detail = str(exc).strip().splitlines()
        print(f"{prog}: error: out of memory{f' ({detail[-1][:200]})' if detail else ''}", file=sys.stderr)
        return 1


# On import: capture's __init__ imports this module before anything else (numpy first).
guard_imports()
