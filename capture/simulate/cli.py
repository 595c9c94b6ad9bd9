"""``s2a-capture simulate``: paired speech, blendshapes and phone alignments from simulated speakers."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..command import emit_json, progress
from .artifacts import ARTIFACT_NAMES, Artifacts
from .phones import INVENTORIES


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``simulate`` subcommand to ``s2a-capture``'s subparsers."""
    p = sub.add_parser(
        "simulate",
        help="simulated speakers -> Live Link Face take folders with audio and phone alignments",
        description="Write N simulated takes spread over K speakers as Live Link Face take folders: the "
        "app's CSV, take.json and metadata, the speech as WAV (optionally a .mov with frame_log.csv), the "
        "phone alignment as a Praat TextGrid and the ground truth (offsets, drops) in simulation.json. "
        "The same arguments and seed give byte-identical output.",
    )
    p.add_argument("-o", "--out", type=Path, required=True, help="folder to write the take folders into")
    p.add_argument("--speakers", metavar="N", type=int, default=1, help="number of simulated speakers")
    p.add_argument("--takes", metavar="N", type=int, default=1, help="number of takes in all")
    p.add_argument("--seconds", metavar="S", type=float, default=20.0, help="length of each take in seconds")
    p.add_argument("--fps", type=int, default=60, help="blendshape frame rate: 60 or 30")
    p.add_argument(
        "--language",
        default="en",
        help=f"phone inventory: {', '.join(f'{k} ({v.description})' for k, v in INVENTORIES.items())}",
    )
    p.add_argument("--seed", metavar="N", type=int, default=0, help="random seed")
    p.add_argument("--sample-rate", metavar="HZ", type=int, default=16000, help="audio rate in Hz")
    p.add_argument("--mov", action="store_true", help="also write the reference .mov and frame_log.csv")
    p.add_argument(
        "--without",
        default="",
        metavar="LIST",
        help=f"comma-separated artifacts to leave out: {', '.join(ARTIFACT_NAMES)}, or all",
    )
    p.add_argument("--json", action="store_true", help="print one JSON summary line per take")
    p.set_defaults(handler=cmd_simulate)


def cmd_simulate(args: argparse.Namespace) -> int:
    from .session import simulate  # scipy and the synthesiser load only when simulating

    artifacts = Artifacts.without(args.without.split(","))

    def report(summary: dict) -> None:
        if args.json:
            emit_json(summary)
        else:
            progress(
                f"{summary['path']}: {summary['speaker']}, {summary['duration_s']:.2f} s, "
                f"{summary['frames']} frames at {summary['fps']} fps, {summary['phones']} phones, "
                f"{summary['dropped_frames']} dropped, {summary['face_lost_frames']} face-lost"
            )

    simulate(
        args.out,
        speakers=args.speakers,
        takes=args.takes,
        seconds=args.seconds,
        fps=args.fps,
        language=args.language,
        seed=args.seed,
        sample_rate=args.sample_rate,
        artifacts=artifacts,
        mov=args.mov,
        on_take=report,
    )
    return 0
