"""Ctrl-C while a stage command starts: its imports (numpy, scipy, PyTorch: a second or more) stop at once,
quietly, with exit code 130, instead of a KeyboardInterrupt traceback or the errors of a half-imported
library. ``capture`` imports this module first of all (it needs three standard modules that Python's
start-up has mostly loaded: ``typing`` alone took 0.1 s on a loaded machine, an unguarded window), which
installs the guard in a stage command; each stage's command module (``cli.py``, imported after its
package) ends it once its imports are done (``imports_done``). SIGTERM (``timeout``, ``kill``) likewise
says ``s2a-X: terminated (SIGTERM)`` and exits with 143, from the guard's start until the command begins
its work (``capture.command.run`` calls ``sigterm_guard_done``): it ended the process by the signal, with
no line. A program that imports the packages keeps its own Ctrl-C and SIGTERM."""

from __future__ import annotations

import os
import signal
import sys

# The stage packages and their commands: Ctrl-C while one of them imports stops it quietly (below).
COMMANDS = {
    "capture": "s2a-capture",
    "align": "s2a-align",
    "dataset": "s2a-dataset",
    "train": "s2a-train",
    "viewer": "s2a-view",
}
_guarding: str | None = None  # the stage whose command is importing under the guard
_guarding_sigterm = False  # SIGTERM is the guard's: the command has not begun its work


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


def _stop_quietly(signum: int, _frame: object) -> None:
    prog = COMMANDS.get(_guarding or running_command() or "", "command")
    if signum == signal.SIGTERM:
        print(f"{prog}: terminated (SIGTERM)", file=sys.stderr, flush=True)
        os._exit(143)  # nothing has been written yet
    print(f"{prog}: interrupted", file=sys.stderr, flush=True)
    os._exit(130)


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
        and signal.getsignal(signal.SIGINT) is signal.default_int_handler
    ):
        try:
            signal.signal(signal.SIGINT, _stop_quietly)
        except ValueError:  # not the main thread: only it may set a handler
            return
        _guarding = package


def imports_done(package: str) -> bool:
    """Called by each stage's ``cli.py`` once its imports are done: the command of ``package`` gets Python's
    own Ctrl-C back (its commands handle it from here). Returns whether its imports were guarded."""
    global _guarding
    if _guarding != package:
        return False
    _guarding = None
    if signal.getsignal(signal.SIGINT) is _stop_quietly:  # unless an import installed its own
        signal.signal(signal.SIGINT, signal.default_int_handler)
    return True


def _guard_sigterm() -> None:
    """SIGTERM stops a stage command quietly (``_stop_quietly``) from here until ``sigterm_guard_done``:
    only in the command itself, on the main thread, where SIGTERM still ends the process by default."""
    global _guarding_sigterm
    if running_command() is None or signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
        return
    try:
        signal.signal(signal.SIGTERM, _stop_quietly)
    except ValueError:  # not the main thread
        return
    _guarding_sigterm = True


def sigterm_guard_done() -> None:
    """Called by ``capture.command.run`` as the command begins its work, which may write files: SIGTERM
    is the command's own from here (its default, or the handler it sets to remove what it wrote)."""
    global _guarding_sigterm
    if _guarding_sigterm and signal.getsignal(signal.SIGTERM) is _stop_quietly:
        try:
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
        except ValueError:  # a command run off the main thread: the guard stays for the main thread's
            return
    _guarding_sigterm = False


guard_imports()  # on import: first thing in capture, so before numpy
_guard_sigterm()
