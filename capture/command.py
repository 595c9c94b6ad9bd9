"""What every stage's command line shares: one-line errors with exit code 1, JSON lines on stdout,
progress on stderr. Usage errors exit with 2 (argparse)."""

from __future__ import annotations

import argparse
import atexit
import importlib.metadata
import json
import math
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path, PurePath
from typing import Any, TextIO

from .errors import (
    KEYS_RAW_BYTES,
    RAW_BYTES,
    InputError,
    S2AError,
    name_of,
    printable,
    printable_message,
    strict_names,
)
from .import_guard import COMMANDS, running_command, sigterm_guard_done


class _StageHelp(argparse.HelpFormatter):
    """Help that shows each option's default (``(default: 1)``) unless its text already speaks of it,
    or the option has none worth saying (unset, off, empty)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if (
            not action.option_strings
            or "default" in text
            or default in (None, "", [], argparse.SUPPRESS)
            or isinstance(default, bool)
        ):
            return text
        shown = " ".join(map(str, default)) if isinstance(default, (list, tuple)) else str(default)
        return f"{text} (default: {shown.replace('%', '%%')})"


class _Subcommands(argparse._SubParsersAction):
    """Subcommands whose own ``--help`` opens with their one-line help when they have no description."""

    def add_parser(self, name: str, **kwargs: Any) -> argparse.ArgumentParser:
        kwargs.setdefault("description", kwargs.get("help"))
        return super().add_parser(name, **kwargs)


# An option named with its unit (``--max-gap-ms``) shows the unit as what it expects: ``--max-gap-ms MS``.
UNIT_METAVARS = {"-ms": "MS", "-s": "S", "-mb": "MB", "-minutes": "MIN"}


class StageParser(argparse.ArgumentParser):
    """The ``ArgumentParser`` of every stage's command line: its usage errors say how to give a file
    whose name begins with ``-`` (``s2a-train predict RUN -d.wav``), which argparse takes for an option it
    does not know. Subcommands' parsers are of this class too (argparse makes them of the parent's). Its
    help shows defaults, a subcommand's help opens with its one line, an option named with its unit
    expects that unit (``UNIT_METAVARS``), and a description taken from a module's docstring loses its
    reST double backquotes."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", _StageHelp)
        if kwargs.get("description"):
            kwargs["description"] = kwargs["description"].replace("``", "")
        super().__init__(*args, **kwargs)
        self.register("action", "parsers", _Subcommands)

    def add_argument(self, *names: str, **kwargs: Any) -> argparse.Action:
        takes_value = kwargs.get("action", "store") in ("store", "append") and "choices" not in kwargs
        unit = next(
            (u for s, u in UNIT_METAVARS.items() for n in names if n[:2] == "--" and n.endswith(s)), None
        )
        if takes_value and unit and "metavar" not in kwargs:
            kwargs["metavar"] = unit
        return super().add_argument(*names, **kwargs)

    def parse_known_args(self, args=None, namespace=None):
        self.given = list(sys.argv[1:] if args is None else args)  # for error(), which is not told them
        return super().parse_known_args(args, namespace)

    def error(self, message: str):
        # a name not UTF-8 (the file taken for an option, a value refused) shows its bytes as \xff
        super().error(printable_message(message + _leading_dash_hint(self, message)))


def _leading_dash_hint(parser: argparse.ArgumentParser, message: str) -> str:
    """`` (-d.wav is taken for an option: ...)``: how to give the file named like an option that
    ``parser`` was given, or ``""`` when it was given none. Written as ``--out=-d.wav`` only for the
    option the ``message`` says lacks its value, and only when that name followed it."""
    given = getattr(parser, "given", [])
    given = given[: given.index("--")] if "--" in given else given  # what follows ``--`` is no option
    # argparse reads ``-`` and a word with a space (``-my take.csv``) as no option
    taken = [
        a
        for a in given
        if a.startswith("-")
        and a != "-"
        and " " not in a
        and _file_name_like(a)
        and not _known_option(a, parser)
    ]
    if not taken:
        return ""
    name, how = taken[0], f", or -- {taken[0]} after the options"
    if message.startswith("argument ") and ": expected" in message:  # an option's missing value
        options = message.removeprefix("argument ").split(":")[0].split("/")
        values = [b for a, b in zip(given, given[1:]) if b in taken and _abbreviates(a, options)]
        name, how = (values[0], f", or {options[-1]}={values[0]}") if values else (name, "")
    return f" ({name} is taken for an option: for a file of that name, write ./{name}{how})"


def _abbreviates(word: str, options: list[str]) -> bool:
    """Whether ``word`` names one of ``options`` (a long one may be abbreviated, as argparse allows)."""
    return word in options or (word.startswith("--") and any(o.startswith(word) for o in options))


DISTRIBUTION = "s2a-toolkit"  # the name pyproject.toml installs the five commands under


def add_version(parser: argparse.ArgumentParser) -> None:
    """``--version``: the command's name and the installed toolkit's version (package metadata)."""
    try:
        version = importlib.metadata.version(DISTRIBUTION)
    except importlib.metadata.PackageNotFoundError:  # run from a checkout that was never installed
        version = "unknown (not installed)"
    parser.add_argument("--version", action="version", version=f"%(prog)s {version}")


def jobs_count(text: str) -> int:
    """An argparse type for ``-j/--jobs``: a whole number of processes, at least 1 (else a usage
    error)."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError("must be at least 1")
    return n


def _file_name_like(word: str) -> bool:
    """Whether ``word`` names a file (it has an extension, or a file of that name is here) and is no
    negative number."""
    try:
        float(word)
        return False
    except ValueError:
        return bool(Path(word).suffix) or os.path.lexists(word)


def _known_option(word: str, parser: argparse.ArgumentParser) -> bool:
    """Whether argparse reads ``word`` as an option of ``parser`` or of its subcommands (at any depth:
    ``remote PHONE target --keep``): one of their option strings, an abbreviation of a long one,
    ``--name=value``, or ``-xVALUE``."""
    options = list(_option_strings(parser))
    head = word.split("=", 1)[0]
    if word.startswith("--"):
        return any(o.startswith(head) for o in options)
    return head in options or word[:2] in options


def _option_strings(parser: argparse.ArgumentParser) -> Iterator[str]:
    """The option strings of ``parser`` and of its subcommands' parsers, theirs too."""
    for action in parser._actions:
        yield from action.option_strings
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                yield from _option_strings(sub)


def json_safe(value: Any) -> Any:
    """``value`` with NaN and infinite numbers as ``None`` (nested in dicts and lists): strict JSON. A
    NumPy number or array is its Python number or list (``json.dumps`` wrote it as a string, ``"nan"``
    too)."""
    if hasattr(value, "tolist") and not isinstance(value, (str, bytes)):
        value = value.tolist()
    if isinstance(value, PurePath):  # a name, as the text ``strict_names`` then takes
        return str(value)
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value


def emit_json(obj: dict[str, Any]) -> None:
    """One JSON object on one line of stdout, strict: a NaN or infinite number anywhere in it is null
    (JSON has none; ``allow_nan=False`` alone made one a traceback instead of a result), and a name whose
    bytes are not UTF-8 is written as messages show it, its bytes in base64 beside it (``strict_names``:
    ``"path_b64"``; it was a lone surrogate, ``"\\udcff"``, which jq and JavaScript mangle)."""
    text = json.dumps(strict_names(json_safe(obj)), allow_nan=False, default=lambda v: printable(str(v)))
    with writing_stdout():
        out = _results()
        out.write(text + "\n")
        out.flush()


def emit_line(text: str) -> None:
    """A human-readable result line on stdout, a name's bytes that are not UTF-8 as ``\\xff`` (as on
    stderr): a strict stdout (a UTF-8 locale's) refused their surrogate escapes with a traceback, after
    the work was done; a stdout of a locale not UTF-8 (``LC_ALL=C`` with ``PYTHONUTF8=0``) gets what it
    cannot take as ``\xe9`` too (it was a UnicodeEncodeError traceback)."""
    out = _results()
    shown = printable(text)
    if out.encoding:
        shown = shown.encode(out.encoding, "backslashreplace").decode(out.encoding)
    with writing_stdout():
        print(shown, file=out, flush=True)


_output_on_stdout = False  # the command's output file went to its standard output (``-o /dev/stdout``)


def output_on_stdout() -> None:
    """Said by a writer that wrote the command's output into its standard output: the result lines go to
    stderr from then on (after a CSV or an ONNX model on stdout, a summary line corrupted it)."""
    global _output_on_stdout
    _output_on_stdout = True


def _results() -> TextIO:
    return sys.stderr if _output_on_stdout else sys.stdout


@contextmanager
def writing_stdout() -> Iterator[None]:
    """A result written to stdout: a stdout that cannot take it (``> /dev/full``, a full disk) is a
    one-line error saying so (it said only "No space left on device"); a closed pipe (``| head``)
    is left to ``run``, which ends quietly."""
    try:
        yield
    except BrokenPipeError:
        raise
    except OSError as exc:
        raise InputError(f"cannot write to standard output: {exc.strerror or exc}") from None


def named(record: dict[str, Any], key: str) -> str | list[str]:
    """The name ``record[key]`` stands for in a JSON line ``emit_json`` wrote: its bytes from ``key_b64``
    when they are not UTF-8 (``os.fsdecode``, as Python holds such a name), else the text itself; for a
    list of names, each name so."""
    raw = record.get(f"{key}{RAW_BYTES}")
    if isinstance(raw, list):
        return [name_of(text, each) for text, each in zip(record[key], raw, strict=True)]
    return name_of(record[key], raw)


def named_keys(record: dict[str, Any], key: str) -> dict[str, Any]:
    """The dict ``record[key]`` of a JSON line ``emit_json`` wrote, keyed by names (a speaker's hours),
    each key the name it stands for: its bytes from ``key_keys_b64`` when they are not UTF-8."""
    raw = record.get(f"{key}{KEYS_RAW_BYTES}") or {}
    return {name_of(text, raw.get(text)): value for text, value in record[key].items()}


def progress(message: str) -> None:
    """Human-readable progress on stderr (a name's bytes that are not UTF-8 as ``\\xff``)."""
    print(printable_message(message), file=sys.stderr, flush=True)


# The program of the stage whose command line runs (``run`` sets it): what ``warn`` names. Outside
# ``run``, the command this process is (a worker process a command started afresh: capture.import_guard
# knows it by its arguments), else the toolkit's.
_program: str | None = None


def warn(message: str) -> None:
    """``message`` as a warning on stderr, named by the running stage's program as argparse names its
    errors: ``s2a-capture: warning: message``, whose origin a pipeline's log that several stages write
    to still shows. The prefix is added here, where the line is printed; a library function returning
    warnings as text keeps them without it."""
    progress(f"{_program or _command_program()}: warning: {message}")


def _command_program() -> str:
    stage = running_command()
    return COMMANDS[stage] if stage else "s2a"


# Seconds between two lines of a long job's progress; this environment variable changes it (a test's
# small input reports within its run, a batch log may want fewer lines).
PROGRESS_INTERVAL_S = 5.0
PROGRESS_INTERVAL_VAR = "S2A_PROGRESS_INTERVAL_S"


def progress_interval() -> float:
    """``PROGRESS_INTERVAL_S``, or the seconds ``$S2A_PROGRESS_INTERVAL_S`` gives (0 or more)."""
    text = os.environ.get(PROGRESS_INTERVAL_VAR, "")
    try:
        seconds = float(text)
    except ValueError:
        return PROGRESS_INTERVAL_S
    return seconds if 0 <= seconds < math.inf else PROGRESS_INTERVAL_S


def duration_words(seconds: float) -> str:
    """``seconds`` as a person reads a wait: ``45 s``, ``12 min``, ``1 h 48 min``."""
    seconds = max(0, round(seconds))
    if seconds < 60:
        return f"{seconds} s"
    minutes = round(seconds / 60)
    return f"{minutes} min" if minutes < 60 else f"{minutes // 60} h {minutes % 60} min"


class TimedProgress:
    """Progress of a long job by the clock, not by the fraction done: a tenth of a 60-minute render is
    twelve silent minutes, while a line every few seconds shows at once that the job moves and when
    it ends. ``update(done)`` after each unit of work says ``what: done/total unit (%), rate, about ...
    left`` once ``interval`` seconds have passed since the start or the last line, and a last line
    when the job ends having said anything; a job over within the first interval says nothing
    (``at_once``: the first update speaks at once; ``bar``: a bar of that many ``#`` before the
    count). A job of several steps goes on with ``step``; a step that cannot count its work says
    ``what: step: 25 s so far`` from ``ticking``. The interval runs across steps, so no step is
    silent for longer. Units done without work (``update``'s ``skipped``: taken from a cache) count
    in the share done, not in the rate, and a rate counts from when the first unit of work began
    (``update``'s ``began``) when the job says so: starting worker processes is no work done. The
    ``clock`` and ``interval`` are injectable so that a test needs no sleeping."""

    def __init__(
        self,
        what: str,
        total: int | None = None,
        unit: str = "",
        say: Callable[[str], None] = progress,
        interval: float | None = None,
        clock: Callable[[], float] = time.monotonic,
        at_once: bool = False,
        bar: int = 0,
    ) -> None:
        self.say, self.clock, self.bar = say, clock, bar
        self.interval = progress_interval() if interval is None else interval
        self.last = -math.inf if at_once else clock()
        self.said = False
        self.lock = threading.Lock()  # ``ticking``'s thread and the job's own updates
        self.name = what
        self.step("", total, unit)

    def step(self, part: str, total: int | None = None, unit: str = "") -> None:
        """Go on with the next step of the job, said as ``what: part`` (``what`` for ""), with its own
        count, rate and time left."""
        self.what = f"{self.name}: {part}" if part and self.name else part or self.name
        self.total, self.unit = total, unit
        self.start, self.done, self.skipped = self.clock(), 0, 0
        self.working_since: float | None = None  # when the first unit of work began (``update``'s began)

    def update(
        self,
        done: int | None = None,
        detail: str = "",
        skipped: int | None = None,
        at_once: bool = False,
        began: float | None = None,
    ) -> None:
        """``done`` units (None: as many as last time) and, in a line said, ``: detail`` after it.
        ``skipped``: how many of ``done`` needed no work (None: as many as last time), left out of the
        rate and the time left (a thousand takes from a cache are no rate of computing them).
        ``at_once``: this line is said whatever the clock (the first unit of real work, a last line).
        ``began``: when (the clock's reading) the unit of work just done began: the rate and the time
        left count from the earliest such, not from the step's start (a pool of workers starting, a
        cache checked: no rate of work); the time the step took still counts from its start."""
        with self.lock:
            if began is not None and (self.working_since is None or began < self.working_since):
                self.working_since = max(began, self.start)
            self.done = self.done if done is None else done
            self.skipped = self.skipped if skipped is None else skipped
            now = self.clock()
            over = self.total is not None and self.done >= self.total
            if now - self.last < self.interval and not (over and self.said) and not at_once:
                return
            self.say(self._line(now - self.start, over) + (f": {detail}" if detail else ""))
            self.last, self.said = now, True

    def _line(self, elapsed: float, over: bool) -> str:
        if self.total is None:
            took = duration_words(elapsed)
            return f"{self.what}: done in {took}" if over else f"{self.what}: {took} so far"
        done = self.done
        worked = done - self.skipped
        working = elapsed if self.working_since is None else elapsed - (self.working_since - self.start)
        rate = worked / working if working > 0 else math.inf
        share = 100 * done / self.total if self.total else 100.0
        share = share if over else min(share, 99.9)  # 100 % is for the end
        line = f"{self.what}: " if self.what else ""
        if self.bar:
            line += f"[{'#' * round(self.bar * share / 100):<{self.bar}}] "
        line += f"{done:,}/{self.total:,} {self.unit} ({share:.1f} %)"
        if math.isfinite(rate) and worked > 0:  # no rate (nor time left) before any work is done
            line += f", {rate:,.0f}" if rate >= 10 else f", {rate:.2g}"
            line += f" {self.unit}/s"
        if over:
            line += f", done in {duration_words(elapsed)}"
        elif worked > 0 and rate > 0:
            line += f", about {duration_words((self.total - done) / rate)} left"
        return line

    @contextmanager
    def ticking(self, part: str) -> Iterator[None]:
        """A step that cannot count its work (a library call that reports nothing): while the block
        runs, a thread says ``what: part: N s so far`` each interval, and ``...: done in N s`` at its
        end when the job has said anything."""
        self.step(part)
        stop = threading.Event()

        def tick() -> None:
            while not stop.wait(max(0.05, min(self.interval / 10, 1.0))):
                self.update()

        self.update()
        thread = threading.Thread(target=tick, daemon=True)
        thread.start()
        try:
            yield
        finally:
            stop.set()
            thread.join()
        with self.lock:
            if self.said:
                self.say(self._line(self.clock() - self.start, True))
                self.last = self.clock()


class Terminated(KeyboardInterrupt):
    """SIGTERM reached the command (``timeout``, ``kill``, a batch scheduler): it stops as on Ctrl-C,
    with exit code 143."""


@contextmanager
def sigterm_stops() -> Iterator[None]:
    """Inside, SIGTERM raises ``Terminated`` in the main thread (once; a second SIGTERM ends the process
    at once), so that the command stops as on Ctrl-C: its ``finally`` blocks run, its partial files go.
    In a stage command's own process it goes on doing so after the block, until ``run`` ends: what
    follows it (a lock released, the result printed) ended the process by the signal, with no line.
    Left alone off the main thread and where the caller already handles SIGTERM."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGTERM)
    if previous is not signal.SIG_DFL:
        yield
        return

    def handler(signum: int, frame: Any) -> None:
        global _sigterm_met
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        _sigterm_met = True
        raise Terminated()

    signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        if running_command() is None:  # a program's own SIGTERM back (the command's ends with ``run``)
            signal.signal(signal.SIGTERM, previous)


def handle_stoppable(args: argparse.Namespace) -> int:
    """Run the parsed command (``args.handler``), SIGTERM stopping it as Ctrl-C does (``sigterm_stops``,
    exit 143): its partial files go, a fit keeps its last checkpoint. What a stage's ``main`` runs."""
    with sigterm_stops():
        return args.handler(args)


# Whether a SIGTERM has stopped the command (``sigterm_stops``, ``stops_at_once``): one more ends it at once.
_sigterm_met = False
# The line a SIGTERM that ends a command whose work is over says (``_end_now``); "" once the command said
# it (``run``, or the command itself: ``dataset build``'s line says what it kept).
_ending_line = ""


def _command_ending(outer: str | None) -> None:
    """As ``run`` ends in a stage command's own process: its work is over, so a SIGTERM from here (as it
    prints its error, as Python exits) is let go, the exit code the command's own; a second one ends
    the process at once (``_end_now``), and so does the first after a SIGTERM that stopped the command,
    until Python's last exit handler (``_sigterm_ignored_as_python_exits``) ignores every one after.
    It ended the process by the signal, with no line, after the work was done; after a stop, the second
    SIGTERM was let go as if it were the first."""
    global _ending_line
    if (
        outer is None
        and running_command() is not None
        and threading.current_thread() is threading.main_thread()
    ):
        # a command a SIGTERM stopped has said so (``run``, ``dataset build``): the next one adds no line
        _ending_line = "" if _sigterm_met else f"{_program}: terminated (SIGTERM)\n"
        signal.signal(signal.SIGTERM, _end_now if _sigterm_met else _let_go)


def _let_go(_signum: int, _frame: Any) -> None:
    """A SIGTERM as a command that has done its work ends: let go, and the next one ends the process."""
    signal.signal(signal.SIGTERM, _end_now)


def _end_now(_signum: int, _frame: Any) -> None:
    """A SIGTERM that ends a command whose work is over at once: with the line a stopped command says
    (unless ``run`` said it already) and its exit code, 143. Written to the file descriptor itself: the
    handler may run while ``sys.stderr`` is printing the command's error."""
    if _ending_line:
        os.write(2, _ending_line.encode("utf-8", "backslashreplace"))
    os._exit(143)


def _sigterm_ignored_as_python_exits() -> None:
    """The last of Python's exit a handler can see (``atexit``; registered as this module is imported, so
    run after those registered later): a SIGTERM from here on, after a stage command's work, is ignored
    and the process exits with the code it was exiting with. Python resets its handlers to the default as
    it tears its modules down (seconds after the command's last line, with PyTorch): such a SIGTERM
    ended the process by the signal (-15) instead, even the first one, which ``_let_go`` lets go. A second
    SIGTERM is ignored too: a teardown that hangs (a library's finalizer) is ended by SIGKILL only."""
    if signal.getsignal(signal.SIGTERM) in (_let_go, _end_now):
        signal.signal(signal.SIGTERM, signal.SIG_IGN)


atexit.register(_sigterm_ignored_as_python_exits)


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
    build_parser: Callable[[], argparse.ArgumentParser],
    main: Callable[[argparse.Namespace], int],
    argv: Sequence[str] | None,
) -> int:
    """Build the parser, parse ``argv`` and run ``main``; the toolkit's own errors become one line and
    exit code 1. ``prog`` names the warnings ``warn`` prints meanwhile. The parser is built inside, so
    that Ctrl-C while it is (reading the package's version from its metadata) is one line too. In the
    command's own process, SIGTERM stops it with its line until ``main`` begins (capture.import_guard),
    is ``main``'s own inside, and is let go once ``main`` is over (``_command_ending``)."""
    global _program, _ending_line, _output_on_stdout
    outer, _program = _program, prog
    _output_on_stdout = False  # this command's own (a process may run several: tests, a batch script)
    try:
        args = build_parser().parse_args(argv)
        sigterm_guard_done()  # nothing written so far: the guard's SIGTERM handler exits at once
        try:
            return main(args)
        finally:
            _command_ending(outer)
    except S2AError as exc:
        print(printable_message(f"{prog}: error: {exc}"), file=sys.stderr)
        return 1
    except Terminated:
        _ending_line = ""  # said below: a SIGTERM from here ends the process without a second line
        print(f"{prog}: terminated (SIGTERM)", file=sys.stderr, flush=True)
        return 143
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0
    except OSError as exc:  # the file system refused (read-only, no permission, a file in the way, full)
        where = f"{exc.filename}: " if exc.filename else ""
        print(printable_message(f"{prog}: error: {where}{exc.strerror or exc}"), file=sys.stderr)
        return 1
    except (MemoryError, RuntimeError) as exc:
        if not out_of_memory(exc):
            raise
        detail = str(exc).strip().splitlines()
        print(
            printable_message(f"{prog}: error: out of memory{f' ({detail[-1][:200]})' if detail else ''}"),
            file=sys.stderr,
        )
        return 1
    finally:
        _program = outer  # a command run from another's process (a test's) leaves the name as it was
        _forget_interrupts_of_executed_text()


def _forget_interrupts_of_executed_text() -> None:
    """The exit code ``run`` returns is the process's. CPython notes a KeyboardInterrupt that ends code
    run from text (``exec`` of a string: every dataclass and namedtuple a module defines as it is
    imported) and, at exit, kills the process with SIGINT (returncode -2) whatever the exit code, even
    when the interrupt was handled (``run``'s one line) or a library's import swallowed it. Running text
    that ends normally clears that note (CPython 3.8+, ``run_eval_code_obj``)."""
    exec("None")


@contextmanager
def stops_deferred(redeliver: bool = True) -> Iterator[None]:
    """Inside, Ctrl-C and SIGTERM wait until the block ends, then reach the process as they would have
    (each once, in the order met), for work a stop must not cut in half (a dataset's swap, removing what
    was unpacked). Not after a block that raised (its own error says more), nor without ``redeliver``
    (the process is ending anyway). Python handlers note them meanwhile: blocking them
    (``pthread_sigmask``) would hold them off this thread only, another thread (OpenBLAS's, FFmpeg's)
    would take them, and Python would run the handler in this thread all the same. Left alone off the
    main thread, and for handlers not set from Python or ignored."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    previous = {sig: h for sig, h in previous.items() if h is not None and h != signal.SIG_IGN}
    held: dict[int, Any] = {}  # the handlers set aside so far (a SIGTERM met as SIGINT's is, raises here)
    try:
        for sig, handler in previous.items():
            signal.signal(sig, lambda signum, _frame: caught.append(signum))
            held[sig] = handler
        yield
    finally:
        _set_back(held)
    for sig in dict.fromkeys(caught) if redeliver else ():
        signal.raise_signal(sig)


def _set_back(handlers: dict[int, Any]) -> None:
    """Set each signal's handler back, every one of them even when a stop raises as one is (a Ctrl-C met
    once SIGINT's own handler is back raises as SIGTERM's is set); that stop is raised once all are back.
    Left half set, the handler that only notes its signal stayed in place: that signal was lost from then
    on."""
    stop = None
    for sig, handler in handlers.items():
        try:
            signal.signal(sig, handler)
        except BaseException as exc:  # KeyboardInterrupt, Terminated
            stop = stop or exc
            signal.signal(sig, handler)
    if stop is not None:
        raise stop


@contextmanager
def stops_at_once() -> Iterator[None]:
    """Inside, Ctrl-C raises ``KeyboardInterrupt`` and SIGTERM ``Terminated`` at once, also where the
    caller's handler only notes them (a render's, between frames): for a wait that only a stop ends.
    Left alone off the main thread, and for handlers not set from Python or ignored."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum: int, _frame: Any) -> None:
        global _sigterm_met
        if signum == signal.SIGTERM:
            _sigterm_met = True
            raise Terminated()
        raise KeyboardInterrupt()

    held = {}
    try:
        for sig in (signal.SIGINT, signal.SIGTERM):
            if callable(handler := signal.getsignal(sig)):
                held[sig] = handler
                signal.signal(sig, stop)
        yield
    finally:
        _set_back(held)
