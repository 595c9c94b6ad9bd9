"""``s2a-align``: raw takes -> aligned takes (16 kHz audio, uniform frames, measured offset) + reports."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from capture.command import (
    StageParser,
    add_version,
    emit_json,
    jobs_count,
    progress,
    run,
    sigterm_stops,
    warn,
)
from capture.import_guard import imports_done

from .batch import align_takes
from .options import FRAME_CLOCKS, VAD_METHODS, AlignOptions, range_problem

# The command's imports are done: Ctrl-C is its own from here (capture.import_guard).
_guard = imports_done("align")

PROG = "s2a-align"


def _in_range(option: str):
    """An argparse type for ``option``'s numbers: one outside its range (``options.RANGES``) is a usage
    error, as a word is."""

    def number(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"invalid float value: {text!r}") from None
        problem = range_problem(option, value)
        if problem:
            raise argparse.ArgumentTypeError(problem)
        return value

    return number


def build_parser() -> argparse.ArgumentParser:
    p = StageParser(
        prog=PROG,
        description="Put speech and face on one clock: measure the audio/face offset (timecodes, sync "
        "events, claps, content), correct drift, trim silence by VAD, resample audio to 16 kHz and frames "
        "onto a uniform grid. Offset sign: offset_s > 0 means the face lags the audio in the raw take.",
    )
    add_version(p)
    p.add_argument("takes", nargs="+", type=Path, help="take folders, or folders holding them (recursive)")
    p.add_argument("-o", "--out", type=Path, required=True, help="folder to write the aligned takes into")
    p.add_argument("--fps", type=_in_range("--fps"), help="output frame rate (default: each take's own)")
    p.add_argument(
        "--face-lead-ms",
        type=_in_range("--face-lead-ms"),
        default=0.0,
        help="how far the face moves ahead of the sound, used only when content is the chosen evidence "
        "(offset = content lag + lead; default 0: no assumption, see docs/align.md)",
    )
    p.add_argument("--vad", choices=VAD_METHODS, default="silero", help="speech detector for trimming")
    p.add_argument(
        "--max-gap-ms",
        type=_in_range("--max-gap-ms"),
        default=250.0,
        help="longest gap filled by interpolation",
    )
    p.add_argument(
        "--max-offset-ms", type=_in_range("--max-offset-ms"), default=500.0, help="offset search range (±)"
    )
    p.add_argument(
        "--offset-ms",
        type=_in_range("--offset-ms"),
        help="use this audio/face offset (ms, > 0: the face lags the audio, as reports give it) for the "
        "takes given, instead of the measured one; the evidence is still measured and reported",
    )
    p.add_argument(
        "--max-disagreement-ms",
        type=_in_range("--max-disagreement-ms"),
        default=50.0,
        help="evidence further apart flags the take",
    )
    p.add_argument(
        "--min-segment-s",
        type=_in_range("--min-segment-s"),
        default=1.0,
        help="shorter segments are left out",
    )
    p.add_argument(
        "--frame-clock",
        choices=FRAME_CLOCKS,
        default="auto",
        help="frame times from the timecodes, or frame index / fps; auto: index for paired data sets "
        "(frame i <-> audio i/fps), timecodes otherwise (see docs/align.md)",
    )
    p.add_argument("--no-drift", action="store_true", help="do not correct clock drift")
    p.add_argument("--no-video", action="store_true", help="do not look for a clap in the reference video")
    p.add_argument(
        "-j", "--jobs", type=jobs_count, default=1, metavar="N", help="takes aligned in parallel (processes)"
    )
    p.add_argument("--force", action="store_true", help="re-align takes whose inputs are unchanged")
    p.add_argument(
        "--skip-without-audio",
        action="store_true",
        help="report takes that have no audio as skipped instead of as errors (mixed folders)",
    )
    p.add_argument(
        "--prune",
        action="store_true",
        help="remove aligned takes in -o whose raw take is gone (neither given nor on disk any more); "
        "without it they are named in a warning",
    )
    p.add_argument("--json", action="store_true", help="one JSON report per take on stdout")
    return p


def _summary(r: dict) -> str:
    """One line for a take's report; a stored report (an unchanged take) may lack fields."""

    def num(key: str, scale: float = 1.0, fmt: str = ".3f") -> str:
        value = r.get(key)
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        return format(value * scale, fmt) if ok else "?"

    trim = r.get("trim_s")
    trim_text = "?"
    if isinstance(trim, list) and len(trim) == 2 and all(isinstance(t, (int, float)) for t in trim):
        trim_text = f"{trim[0]:.3f}..{trim[1]:.3f}"
    state = "unchanged, skipped" if r.get("skipped") else f"{r.get('segments', '?')} segment(s)"
    flags = r.get("flags")
    flag_text = f" FLAGS {','.join(map(str, flags))}" if isinstance(flags, list) and flags else ""
    return (
        f"{r.get('id')}: offset {num('offset_s', 1000, '+.1f')} ms ({r.get('offset_source')}, confidence "
        f"{num('offset_confidence', fmt='.2f')}), drift {num('drift_ppm', fmt='.1f')} ppm, "
        f"trim {trim_text} s, {r.get('frames', '?')} frames at {num('fps', fmt='g')} fps, {state}{flag_text}"
    )


def _main(args: argparse.Namespace) -> int:
    opts = AlignOptions(
        fps=args.fps,
        face_lead_ms=args.face_lead_ms,
        vad=args.vad,
        max_gap_s=args.max_gap_ms / 1000.0,
        max_offset_s=args.max_offset_ms / 1000.0,
        max_disagreement_s=args.max_disagreement_ms / 1000.0,
        min_segment_s=args.min_segment_s,
        drift=not args.no_drift,
        use_video=not args.no_video,
        frame_clock=args.frame_clock,
        offset_s=None if args.offset_ms is None else args.offset_ms / 1000.0,
    )

    def show(r: dict) -> None:
        if args.json:
            emit_json(r)
        if "error" in r:
            print(f"{PROG}: error: {r['error']}", file=sys.stderr)
        elif r.get("reason"):
            if not args.json:
                progress(f"{r['id']}: skipped ({r['reason']})")
        elif not args.json:
            progress(_summary(r))
            for warning in r.get("warnings") or []:
                warn(warning)

    with sigterm_stops():  # as Ctrl-C: workers stopped, takes aligned so far kept; exit 143
        reports = align_takes(
            args.takes,
            args.out,
            opts,
            jobs=args.jobs,
            force=args.force,
            on_report=show,
            skip_without_audio=args.skip_without_audio,
            prune=args.prune,
            on_message=lambda message: progress(f"{PROG}: {message}"),  # stderr, with --json too
            on_warning=warn,
        )
    return 1 if any("error" in r for r in reports) else 0


def main(argv: list[str] | None = None) -> int:
    return run(PROG, build_parser, _main, argv)


if __name__ == "__main__":
    sys.exit(main())
