"""What every stage's command line shares: one-line errors with exit code 1, JSON lines on stdout,
progress on stderr. Usage errors exit with 2 (argparse)."""

from __future__ import annotations

import argparse
import json
import math
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
