"""``s2a-dataset``: build a dataset from aligned takes, validate it, report its statistics."""

from __future__ import annotations

import argparse
import math
import re
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TypeVar

from capture.command import (
    StageParser,
    Terminated,
    add_version,
    emit_json,
    emit_line,
    handle_stoppable,
    jobs_count,
    progress,
    run,
    warn,
)
from capture.errors import InputError, printable
from capture.import_guard import imports_done

from .build import BuildOptions, build_dataset
from .features import DEFAULT_FEATURES, FeatureSettings, parse_level
from .manifest import MANIFEST_FILE, build_running, dataset_dir
from .normalize import KINDS
from .ppg import BACKENDS
from .qa import validate
from .splits import SplitRule
from .stats import dataset_stats, format_stats

# The command's imports are done: Ctrl-C is its own from here (capture.import_guard).
_guard = imports_done("dataset")

PROG = "s2a-dataset"
RESUME = "finished takes are kept: rerun to resume"
T = TypeVar("T")


def build_parser() -> argparse.ArgumentParser:
    parser = StageParser(prog=PROG, description=__doc__)
    add_version(parser)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser(
        "build",
        help="aligned takes -> features, normalisation, splits, shards, manifest",
        description="Build (or resume building) a dataset. Folders are searched recursively for takes; "
        "takes that are not aligned yet are aligned first.",
    )
    p.add_argument("takes", nargs="+", type=Path, help="take folders, or folders holding them")
    p.add_argument("-o", "--out", type=Path, required=True, help="dataset folder to write")
    p.add_argument(
        "--channels",
        default="pronunciation32",
        help="pronunciation32 (default), arkit52, arkit61, varying (moves in train), all, or a comma list",
    )
    p.add_argument(
        "--features",
        default=",".join(DEFAULT_FEATURES),
        help="comma list of pitch, energy, fbank, mfcc, ppg (default: %(default)s; ppg added by --ppg)",
    )
    p.add_argument("--ppg", default="none", choices=BACKENDS, help="PPG backend (default: none)")
    p.add_argument(
        "--ppg-model", metavar="FILE", help="checkpoint (bottleneck) or model file (torchscript, onnx)"
    )
    p.add_argument("--normalization", default="zscore", choices=KINDS, help="animation normalisation")
    p.add_argument(
        "--level",
        default="speech",
        help="speech-level normalisation before features: speech (active speech level -26 dBFS, the "
        "default), a target in dBFS (-23), or none (features at the recorded level)",
    )
    p.add_argument("--split-by", default="take", choices=("take", "speaker"), help="unit of the splits")
    p.add_argument("--val-fraction", type=float, default=0.1, help="share of total duration (default: 0.1)")
    p.add_argument("--test-fraction", type=float, default=0.1, help="share of total duration (default: 0.1)")
    p.add_argument(
        "--val", nargs="+", default=[], metavar="ID", help="takes, recordings or speakers pinned to val"
    )
    p.add_argument(
        "--test", nargs="+", default=[], metavar="ID", help="takes, recordings or speakers pinned to test"
    )
    p.add_argument("--seed", metavar="N", type=int, default=0, help="seed of the split order")
    p.add_argument("--shard-mb", type=float, default=256.0, help="size cap of a shard in MB (default: 256)")
    p.add_argument("--max-sample-s", type=float, default=30.0, help="longest sample in seconds (default: 30)")
    p.add_argument("-j", "--jobs", type=jobs_count, default=1, metavar="N", help="worker processes")
    p.add_argument("--keep-work", action="store_true", help="keep DS/.work (per-take cache) after success")
    p.add_argument(
        "--skip-flagged",
        action="store_true",
        help="leave out takes whose audio/face offset s2a-align flagged (evidence_disagrees, low_confidence, "
        "no_evidence); without it they are kept with a warning",
    )
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(handler=cmd_build)

    p = sub.add_parser("validate", help="check a dataset against its manifest; exit 1 when invalid")
    p.add_argument("dataset", type=Path, help="dataset folder (or its manifest.json)")
    p.add_argument(
        "--deep",
        action="store_true",
        help="also decode all audio and recompute the statistics the manifest holds (every shard's sha256 "
        "is checked without it)",
    )
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.set_defaults(handler=cmd_validate)

    p = sub.add_parser("stats", help="hours per speaker and split, phone coverage, channel distributions")
    p.add_argument("dataset", type=Path, help="dataset folder (or its manifest.json)")
    p.add_argument("--json", action="store_true", help="print the statistics as JSON")
    p.set_defaults(handler=cmd_stats)
    return parser


def _say(prefix: str):
    return lambda message: progress(f"{prefix}: {message}")


def cmd_build(args: argparse.Namespace) -> int:
    if not 0 < args.shard_mb < math.inf:
        raise InputError(f"--shard-mb must be a positive number, not {args.shard_mb}")
    shard_bytes = int(args.shard_mb * 1024 * 1024)
    if shard_bytes < 1:
        raise InputError(f"--shard-mb {args.shard_mb:g} is under one byte: give the cap in MB (default 256)")
    try:
        level = parse_level(args.level)
    except ValueError:
        raise InputError(
            f"--level must be speech, none or a target in dBFS between -80 and 0, not {args.level!r}"
        ) from None
    options = BuildOptions(
        channels=args.channels,
        features=args.features,
        ppg=args.ppg,
        ppg_model=args.ppg_model,
        normalization=args.normalization,
        split=SplitRule(
            args.split_by, args.val_fraction, args.test_fraction, args.seed, tuple(args.val), tuple(args.test)
        ),
        shard_bytes=shard_bytes,
        max_sample_s=args.max_sample_s,
        jobs=args.jobs,
        keep_work=args.keep_work,
        skip_flagged=args.skip_flagged,
        settings=FeatureSettings(level=level),
    )
    try:
        summary = build_dataset(args.takes, args.out, options, say=_say("build"))
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM (Terminated)
        # what the build left in the folder, when it replaced a dataset (dataset.build.build_dataset)
        left = getattr(exc, "dataset_state", "")
        if isinstance(exc, Terminated):
            print(printable(f"{PROG}: terminated (SIGTERM); {left or RESUME}"), file=sys.stderr)
            return 143
        print(printable(f"{PROG}: interrupted" + (f"; {left}" if left else "")), file=sys.stderr)
        return 130
    if args.json:
        emit_json(summary)
    else:
        emit_line(
            f"{summary['dataset']}: {summary['takes']} takes, {summary['samples']} samples in "
            f"{summary['shards']} shards, {summary['hours'] * 60:.2f} min, {summary['channels']} channels, "
            f"splits {summary['splits']}"
            + (" (up to date)" if summary["up_to_date"] else "")
            + (f" (repaired {', '.join(summary['repaired'])})" if summary.get("repaired") else "")
        )
        for w in grouped_warnings(summary["warnings"]):  # about its inputs: stderr, as every stage's
            warn(w)
    return 0


_OF_A_TAKE = re.compile(r"take (\S+): (.+)", re.DOTALL)
GROUP_FROM = 4  # takes warned alike from which one line names them together


def grouped_warnings(warnings: list[str], named: int = 3) -> list[str]:
    """The build's warnings as printed: those saying the same of ``GROUP_FROM`` or more takes
    (``take X: align flagged its audio/face offset (low_confidence): ...``) as one line naming the first
    ``named`` of them and how many more, at the first one's place; the manifest keeps every line."""
    alike: dict[str, list[str]] = {}  # what is said -> the takes it is said of, each once, in order
    for w in warnings:
        m = _OF_A_TAKE.fullmatch(w)
        if m and m[1] not in alike.setdefault(m[2], []):
            alike[m[2]].append(m[1])
    out, said = [], set()
    for w in warnings:
        m = _OF_A_TAKE.fullmatch(w)
        takes = alike[m[2]] if m else []
        if len(takes) < GROUP_FROM:
            out.append(w)
        elif m[2] not in said:
            said.add(m[2])
            more = f" and {len(takes) - named} more" if len(takes) > named else ""
            out.append(f"{len(takes)} takes ({', '.join(takes[:named])}{more}): {m[2]}")
    return out


def _not_while_building(ds: Path) -> None:
    """Refuse to read a dataset that a live build is writing into (see ``build_running``)."""
    busy = build_running(ds)
    if busy is not None:
        raise InputError(busy)


def dataset_files_state(ds: Path) -> list[tuple[str, int, int, int]]:
    """(name, inode, mtime in ns, size) of the manifest and the shards of dataset ``ds``, sorted: what a
    build swapping the dataset in changes (it renames new files into place)."""
    folder = dataset_dir(ds)
    out = []
    for p in [folder / MANIFEST_FILE, *folder.glob("*.tar")]:
        try:
            st = p.stat()
        except OSError:  # missing or unreadable: reported by the reader itself
            continue
        out.append((p.name, st.st_ino, st.st_mtime_ns, st.st_size))
    return sorted(out)


def read_unchanged(ds: Path, read: Callable[[], T], command: str) -> T:
    """``read()`` of dataset ``ds``, refused when a build started writing into it meanwhile or swapped
    new files in: the lock is checked only before reading, and a build started after that could make
    validate report faults of a half-swapped dataset (or none of a dataset just replaced)."""
    _not_while_building(ds)
    before = dataset_files_state(ds)
    result = read()
    if build_running(ds) is not None or dataset_files_state(ds) != before:
        raise InputError(
            f"the dataset changed while {command} read it (a build wrote into it?): "
            f"run s2a-dataset {command} again",
            dataset_dir(ds),
        )
    return result


def cmd_validate(args: argparse.Namespace) -> int:
    report = read_unchanged(
        args.dataset, lambda: validate(args.dataset, deep=args.deep, progress=_say("validate")), "validate"
    )
    if args.json:
        emit_json(report.to_json())
    else:
        for p in report.problems:
            emit_line(f"{p.severity}: {p.location}: {p.message} [{p.code}]")
        verdict = "valid" if report.valid else "INVALID"
        errors = sum(p.severity == "error" for p in report.problems)
        emit_line(
            f"{report.dataset}: {verdict} ({report.shards} shards, {report.samples} samples, "
            f"{errors} error(s), {len(report.problems) - errors} warning(s){', deep' if report.deep else ''})"
        )
    return 0 if report.valid else 1


def cmd_stats(args: argparse.Namespace) -> int:
    s = read_unchanged(args.dataset, lambda: dataset_stats(args.dataset), "stats")
    if args.json:
        emit_json(s)
    else:
        emit_line(format_stats(s))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    return run(PROG, build_parser, handle_stoppable, argv)


if __name__ == "__main__":
    sys.exit(main())
