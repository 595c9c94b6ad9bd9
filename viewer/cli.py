"""``s2a-view``: see a take or a prediction as a face (PNG/MP4), as curves, live in Unreal, and a
dataset as one HTML page."""

from __future__ import annotations

import argparse
import math
import re
import sys
import time
from pathlib import Path

from capture.command import StageParser, TimedProgress, add_version, emit_json, progress, run, warn
from capture.errors import InputError, first_few
from capture.import_guard import imports_done

from .output import (
    prepare_output,
    raise_if_stopped,
    refuse_writing_over_inputs,
    stopped_by_signals,
    stops_between_frames,
)
from .plot import VAD_METHODS

# The command's imports are done: Ctrl-C is its own from here (capture.import_guard).
_guard = imports_done("viewer")

PROG = "s2a-view"
# What argparse takes as a value rather than an option: its own '-5' and '-.5', and also '-1e9', '-inf'
# and '-nan', so that a --compare-offset -inf is refused by the finiteness check, not as an unknown option.
NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*(e[+-]?\d+)?|\.\d+(e[+-]?\d+)?|inf|infinity|nan)$", re.IGNORECASE)


def _number(cast: type, low: float, high: float, what: str):
    """An argparse type: a ``cast`` number (finite) in ``low..high``; one outside is a usage error, as a
    word is (exit 2, argparse's usage line first). A range the input sets (a frame past its last, a time
    past its end) is checked against the input, an error of exit code 1."""

    def number(text: str):
        try:
            value = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"invalid {cast.__name__} value: {text!r}") from None
        if not (math.isfinite(value) and low <= value <= high):
            raise argparse.ArgumentTypeError(f"must be {what}, not {text}")
        return value

    return number


SECONDS = _number(float, -math.inf, math.inf, "a number of seconds")
SIZE = _number(int, 16, 4096, "in 16..4096")
FRAME = _number(int, 0, math.inf, "a frame index, 0 or more")
TIME = _number(float, 0.0, math.inf, "seconds after the input's first frame, 0 or more")
SPEED = _number(float, 0.01, 1000.0, "in 0.01..1000")
LIMIT = _number(int, 0, math.inf, "0 or more (0: no curve thumbnails)")
LATENCY = _number(float, 0.0, 10.0, "in 0..10 seconds")
CONTEXT = _number(float, 0.5, 30.0, "in 0.5..30 seconds")
HOP = _number(float, 0.01, 1.0, "in 0.01..1 seconds")
# speak's defaults, chosen on measurements (the module's report): see docs/viewer.md
DEFAULT_LATENCY_S = 0.3
DEFAULT_CONTEXT_S = 4.0
DEFAULT_HOP_S = 0.25
THREADS = _number(int, 1, 256, "in 1..256")


def build_parser() -> argparse.ArgumentParser:
    parser = StageParser(prog=PROG, description=__doc__)
    add_version(parser)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser(
        "render",
        help="render a take or prediction as a face: one frame (PNG) or the whole take (MP4 with audio)",
        description="Render a take folder or Live Link Face CSV with the built-in face or a glTF/GLB head "
        "with ARKit morph targets. .png: one frame; .mp4: every frame at the take's rate with its audio.",
    )
    p.add_argument(
        "input",
        type=Path,
        help="take folder or Live Link Face CSV (a recording or a prediction), or a zip of one "
        "(ARCHIVE.zip/TAKE names one take of an archive of several)",
    )
    p.add_argument("-o", "--out", type=Path, required=True, help="output .png (one frame) or .mp4 (the take)")
    p.add_argument(
        "--compare",
        type=Path,
        nargs="+",
        default=[],
        metavar="TAKE_OR_CSV",
        help="more takes/predictions rendered beside the input, on the same clock",
    )
    p.add_argument(
        "--compare-offset",
        type=SECONDS,
        nargs="+",
        metavar="S",
        help="seconds after the input's first frame at which each --compare input starts (default: 0, "
        "or an aligned segment's start when it was aligned from the input)",
    )
    p.add_argument(
        "--video",
        metavar="FILE|auto",
        help="reference video beside the face: a file, or 'auto' for the take's own .mov",
    )
    p.add_argument(
        "--video-start",
        type=SECONDS,
        metavar="S",
        help="take time (s) of the video's first frame (default: the audio's start, else 0)",
    )
    p.add_argument(
        "--face",
        default="builtin",
        metavar="builtin|FILE.glb",
        help="the face: the built-in head (default) or a glTF/GLB file with ARKit morph targets",
    )
    p.add_argument(
        "--audio", metavar="FILE", type=Path, help="speech for a CSV input (a take folder brings its own)"
    )
    p.add_argument(
        "--size", metavar="PX", type=SIZE, default=512, help="panel height and width in pixels (default: 512)"
    )
    p.add_argument(
        "--frame", metavar="N", type=FRAME, help="PNG: frame index of the input (default: widest open jaw)"
    )
    p.add_argument("--time", metavar="S", type=TIME, help="PNG: seconds after the input's first frame")
    p.add_argument("--labels", help="comma list of panel names, one per input (default: take ids)")
    p.add_argument("--no-labels", action="store_true", help="no panel names in side-by-side output")
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(handler=cmd_render)

    p = sub.add_parser(
        "plot",
        help="channels over time for takes/predictions, waveform and VAD segments beneath (PNG/SVG)",
    )
    p.add_argument(
        "inputs",
        type=Path,
        nargs="+",
        help="take folders or Live Link Face CSVs, or zips of one (ARCHIVE.zip/TAKE)",
    )
    p.add_argument("-o", "--out", type=Path, required=True, help="output .png or .svg")
    p.add_argument(
        "--channels",
        help="comma list of channels or a set name (default: jawOpen; when no input holds it, the mouth "
        "channel that moves most, lips parting first)",
    )
    p.add_argument("--audio", metavar="FILE", type=Path, help="speech for the first input when it is a CSV")
    p.add_argument(
        "--vad",
        default="auto",
        choices=VAD_METHODS,
        help="speech segments beneath the curves: auto (the default) takes an aligned take's report, else "
        "runs silero VAD; or this detector, or none",
    )
    p.add_argument("--labels", help="comma list of legend names, one per input")
    p.add_argument("--start", metavar="S", type=SECONDS, help="first second shown")
    p.add_argument("--end", metavar="S", type=SECONDS, help="last second shown")
    p.add_argument("--title", help="figure title")
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(handler=cmd_plot, usage_error=p.error)

    p = sub.add_parser(
        "stream",
        help="send a take or prediction as Live Link packets to Unreal (v6, 61 channels, real time)",
    )
    p.add_argument(
        "input", type=Path, help="take folder or Live Link Face CSV, or a zip of one (ARCHIVE.zip/TAKE)"
    )
    p.add_argument("--to", required=True, metavar="HOST:PORT", help="where Unreal listens (port 11111)")
    p.add_argument(
        "--audio",
        nargs="?",
        const="take",
        metavar="FILE",
        help="play the speech on this machine on the same clock (the take's, or FILE)",
    )
    p.add_argument("--speed", type=SPEED, default=1.0, help="playback speed (1 = the phone's timing)")
    p.add_argument("--subject", help="Live Link subject name (default: the take's, else iPhone)")
    p.add_argument(
        "--device", help="device id in the packets (default: the take's, else derived from its id)"
    )
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(handler=cmd_stream)

    p = sub.add_parser(
        "speak",
        help="speech to Unreal live: a trained run animates a microphone or an audio file as it is spoken",
        description="Animate speech with a run of s2a-train while it is spoken and send the face to Unreal "
        "as Live Link packets at the run's fps, a known time behind the speech: --latency (the speech the "
        "model hears after each frame) plus two hops.",
    )
    p.add_argument("run", type=Path, help="run folder of s2a-train fit (or a checkpoint file)")
    p.add_argument("--to", required=True, metavar="HOST:PORT", help="where Unreal listens (port 11111)")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument(
        "--mic",
        nargs="?",
        const="",
        metavar="DEVICE",
        help="speech from a microphone: the default input, or this PortAudio device (index or name)",
    )
    source.add_argument("--audio", type=Path, metavar="FILE", help="an audio file, spoken as if live")
    p.add_argument("--play", action="store_true", help="play --audio's speech here, delayed as the face is")
    p.add_argument(
        "--latency",
        type=LATENCY,
        default=DEFAULT_LATENCY_S,
        metavar="S",
        help="seconds of speech the model hears after a frame before it is sent "
        f"(default: {DEFAULT_LATENCY_S})",
    )
    p.add_argument(
        "--context",
        type=CONTEXT,
        default=DEFAULT_CONTEXT_S,
        metavar="S",
        help=f"seconds of speech the model hears at each hop (default: {DEFAULT_CONTEXT_S})",
    )
    p.add_argument(
        "--hop",
        type=HOP,
        default=DEFAULT_HOP_S,
        metavar="S",
        help=f"seconds between two runs of the model (default: {DEFAULT_HOP_S})",
    )
    p.add_argument("--speed", type=SPEED, default=1.0, help="--audio's pace (1 = real time; more: tests)")
    p.add_argument(
        "--threads",
        type=THREADS,
        default=1,
        metavar="N",
        help="CPU threads the model runs on (default: 1, steady beside Unreal's own)",
    )
    p.add_argument("--speaker", help="dataset speaker whose pitch statistics to use")
    p.add_argument("--style", help="speaker style of a run trained with styles (default: the mean style)")
    p.add_argument(
        "--ppg-model", metavar="FILE", type=Path, help="PPG model file when the run's dataset used one"
    )
    p.add_argument("--subject", help="Live Link subject name (default: iPhone)")
    p.add_argument("--device", help="device id in the packets (default: derived from the run's name)")
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(handler=cmd_speak)

    p = sub.add_parser("report", help="one self-contained HTML page for a dataset or a folder of takes")
    p.add_argument(
        "dataset",
        type=Path,
        help="dataset folder (manifest.json) or a folder of take folders (or a zip of one)",
    )
    p.add_argument("-o", "--out", type=Path, required=True, help="output .html")
    p.add_argument(
        "--takes",
        metavar="TAKE",
        type=Path,
        nargs="+",
        default=[],
        help="aligned take folders whose align reports to show",
    )
    p.add_argument(
        "--limit", metavar="N", type=LIMIT, default=500, help="at most this many takes get curve thumbnails"
    )
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(handler=cmd_report)

    p = sub.add_parser("export-face", help="write the built-in face as GLB with ARKit morph targets")
    p.add_argument("-o", "--out", type=Path, required=True, help="output .glb")
    p.add_argument(
        "--names",
        choices=("arkit", "pascal", "suffix"),
        default="arkit",
        help="target name style: jawOpen, JawOpen, or eyeBlink_L (default: arkit)",
    )
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(handler=cmd_export_face)

    p = sub.add_parser("probe", help="check that offscreen rendering works here (and say what to install)")
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(handler=cmd_probe)
    for p in sub.choices.values():  # argparse has no public setting for this (Python 3.11)
        p._negative_number_matcher = NEGATIVE_NUMBER
    return parser


def _face(spec: str):
    from .face import builtin_face
    from .gltf import load_gltf

    return builtin_face() if spec == "builtin" else load_gltf(spec)


def _warn(anims) -> None:
    """What reading, bridging and clamping the inputs changed, one warning line each."""
    for a in anims:
        for w in a.warnings:
            warn(w)


def _face_gaps(model, anims) -> tuple[list[str], list[str]]:
    """The ARKit blendshapes the inputs move that ``model`` has no morph target for (a glTF head whose
    targets are named in a way ``arkit_channel`` does not know, or that lacks them): the face shows
    them still, a closed mouth for a missing jawOpen. Returns them, the widest moved first, and a
    warning line that names them and the head's targets left unread; empty lists when the head moves
    everything the inputs move."""
    import numpy as np

    from capture.channels import ARKIT52

    held = set(model.channels)
    peak = {
        c: max(float(np.abs(a.weights[:, k]).max()) for a in anims)
        for k, c in enumerate(ARKIT52)
        if c not in held
    }
    moved = sorted((c for c, p in peak.items() if p > 1e-6), key=lambda c: -peak[c])
    if not moved:
        return [], []
    names = first_few(moved)
    unread = model.extra.get("unmapped", [])
    hint = f"; its morph targets not matched to one: {', '.join(unread[:5])}" if unread else ""
    hint += f" (and {len(unread) - 5} more)" if len(unread) > 5 else ""
    return moved, [
        f"{model.name}: {len(moved)} blendshape(s) the input moves have no morph target in this head and "
        f"stay still: {names}{hint}"
    ]


def _outside(what: str, start: float, end: float, lo: float, hi: float, shown: str) -> list[str]:
    """A warning when ``what``, spanning ``start..end`` s, lies wholly outside the rendered ``lo..hi``
    s (seconds after the input's first frame): that panel shows nothing of it but ``shown``."""
    if start <= hi and end >= lo:
        return []

    def sec(x: float) -> str:
        return f"{x:.3f}" if abs(x) < 1e6 else f"{x:.4g}"  # an offset of 1e300 s stays one short line

    rendered = f"{sec(lo)}..{sec(hi)} s" if hi > lo else f"{sec(lo)} s"
    return [f"{what} spans {sec(start)}..{sec(end)} s, outside the rendered {rendered}: {shown}"]


def _files_read(anims, paths) -> list[tuple[Path | None, str]]:
    """What the inputs were read from, as (file, what it is) for ``refuse_writing_over_inputs``: each
    one's speech file and the files its take records as its sources (its CSV, its .mov)."""
    files: list[tuple[Path | None, str]] = []
    for a, path in zip(anims, paths):
        files.append((a.audio_file, f"the speech of {path}"))
        sources = a.take.meta.sources if a.take is not None else []
        files += [(Path(s.path), f"a file of the take {path} ({s.role.replace('_', ' ')})") for s in sources]
    return files


def cmd_render(args: argparse.Namespace) -> int:
    from .inputs import livelink_coverage, missing_face_channels
    from .probe import probe
    from .render import (
        FaceRenderer,
        ReferenceVideo,
        aac_rate,
        default_frame,
        distinct_labels,
        load_animation,
        mp4_frame_fits,
        place_on_parent_clock,
        reference_video_of,
        render_frame,
        resample_speech,
        speech_for_video,
        write_image,
        write_mp4,
    )

    suffix = args.out.suffix.lower()
    if suffix not in (".png", ".jpg", ".jpeg", ".mp4"):
        raise InputError("output must be .png (one frame) or .mp4 (the whole take)", args.out)
    if suffix == ".mp4" and (args.frame is not None or args.time is not None):
        raise InputError("--frame/--time pick one frame for a PNG; an MP4 has them all")
    if args.frame is not None and args.time is not None:
        raise InputError("--frame and --time both pick the frame: give one of them")
    if args.compare_offset is not None and len(args.compare_offset) != len(args.compare):
        raise InputError(
            f"--compare-offset gives {len(args.compare_offset)} offsets for {len(args.compare)} inputs"
        )
    if args.video_start is not None and not args.video:
        warn("--video-start places a reference video: without --video it is ignored")
    one = "render shows one take per input"
    anims = [load_animation(args.input, args.audio, one_take=one)]
    anims += [load_animation(c, one_take=one, audio_flag=None) for c in args.compare]
    paths = [args.input, *args.compare]
    for a, path in zip(anims, paths):
        a.warnings += livelink_coverage(a.take, path, "render") + missing_face_channels(a.take, path)
    first = anims[0]
    span = float(first.time[-1] - first.t0)
    if args.time is not None and not args.time <= span:  # the option's own range: argparse (TIME)
        raise InputError(f"--time {args.time:g} s is outside the take's 0..{span:.3f} s", args.input)
    if args.frame is not None and not args.frame < first.time.size:  # and 0 or more (FRAME)
        raise InputError(f"--frame {args.frame} is outside 0..{first.time.size - 1}", args.input)
    if args.labels:
        names = [s.strip() for s in args.labels.split(",")]
        if len(names) != len(anims):
            raise InputError(f"--labels names {len(names)} panels, but there are {len(anims)} inputs")
        for a, name in zip(anims, names):
            a.label = name
    else:
        distinct_labels(anims, paths)
    why = None  # how the frame shown was picked, when jawOpen could not pick it
    if suffix == ".mp4":
        shown = (0.0, span)
    elif args.time is not None:
        shown = (args.time, args.time)
    else:
        k, why = (args.frame, None) if args.frame is not None else default_frame(first)
        shown = (float(first.time[k] - first.t0),) * 2
    for i, (a, path) in enumerate(zip(anims[1:], paths[1:])):
        a.offset_s = args.compare_offset[i] if args.compare_offset else place_on_parent_clock(first, a, path)
        end = a.offset_s + float(a.time[-1] - a.t0)
        held = "its first frame" if a.offset_s > shown[1] else "its last frame"
        a.warnings += _outside(f"{path} (compare)", a.offset_s, end, *shown, f"its face stays at {held}")
    _warn(anims)
    vpath = None
    if args.video:
        vpath = reference_video_of(first.take) if args.video == "auto" else Path(args.video)
        if vpath is None:
            raise InputError("the take names no reference video (--video auto); give the file", args.input)
    read = _files_read(anims, paths) + [(vpath, "the reference video")]
    for note in refuse_writing_over_inputs(args.out, read):
        progress(f"note: {note}")
    model = _face(args.face)
    face_missing, warnings = _face_gaps(model, anims)
    for w in warnings:
        warn(w)
    probe()  # in a subprocess: without GL, say what to install instead of crashing
    video = None
    if vpath is not None:
        start = args.video_start if args.video_start is not None else first.audio_start_s
        video = ReferenceVideo(vpath, args.size, start)
        if video.duration_s is not None:
            v0 = start - first.t0
            for w in _outside(f"{vpath} (video)", v0, v0 + video.duration_s, *shown, "its panel stays black"):
                warn(w)

    def frame_width(size: int) -> int:
        return size * len(anims) + (video.width_for(size) if video is not None else 0)

    if suffix == ".mp4" and not mp4_frame_fits(frame_width(args.size), args.size):
        fits = next((s for s in range(args.size, 15, -1) if mp4_frame_fits(frame_width(s), s)), None)
        # No --size down to 16 fits when the panels side by side are too many for one video.
        panels = f"{len(anims)} inputs" + (" and the reference video" if video is not None else "")
        what = f"give --size {fits} or less" if fits else f"{panels} are too many panels for one video"
        raise InputError(
            f"the video would be {frame_width(args.size)}x{args.size} pixels, more than H.264 takes (at "
            f"most 16384 a side and 8192x4352 in all): {what}"
        )
    labels = not args.no_labels
    size = (args.size, args.size)
    summary: dict = {
        "input": str(args.input),
        "compare": [str(c) for c in args.compare],
        "compare_offset_s": [round(a.offset_s, 6) for a in anims[1:]],
        "face": model.name,
        "face_missing": face_missing,
        "bad_values": [a.bad_values for a in anims],
        "clamped_values": [a.clamped for a in anims],
        "audio_files": [str(a.audio_file) if a.audio_file else None for a in anims],
    }
    prepare_output(args.out)  # after the inputs are read: a bad input leaves no folder behind
    with FaceRenderer(model, size) as renderer, stops_between_frames():
        if suffix != ".mp4":
            t_rel = shown[0]
            t = time.perf_counter()
            img = render_frame(renderer, anims, t_rel, video, labels)
            raise_if_stopped()
            write_image(args.out, img)
            if why is not None:  # once the image is written: an error stays the one line it is
                progress(f"note: {args.input} {why}")
            summary |= {
                "output": str(args.out),
                "time_s": round(t_rel, 6),
                "width": img.shape[1],
                "height": img.shape[0],
                "render_s": round(time.perf_counter() - t, 4),
            }
        else:
            n = first.frames
            fps = first.fps
            speech = speech_for_video(anims, n / fps)
            audio = None
            if speech is None:
                progress(f"note: no input has audio: {args.out} is silent (--audio FILE: a CSV's speech)")
            else:
                voice, audio = speech
                a0 = voice.audio_start_s - (voice.t0 - voice.offset_s)  # seconds into the video
                a1 = a0 + voice.audio.frames / voice.audio.sample_rate
                for w in _outside(f"{voice.audio_file} (audio)", a0, a1, *shown, "the video is silent"):
                    warn(w)
                if (to := aac_rate(audio.rate)) != audio.rate:
                    progress(f"note: {voice.audio_file}: {audio.rate} Hz audio resampled to {to} Hz for AAC")
                    audio = resample_speech(audio, to)
            t_start = time.perf_counter()
            frames_done = TimedProgress(f"render: {args.out.name}", n, "frames")

            def tick(k: int) -> None:
                raise_if_stopped()  # a Ctrl-C or SIGTERM during frame k stops here, out of VTK's reach
                frames_done.update(k + 1)

            timing = write_mp4(
                args.out, lambda k: render_frame(renderer, anims, k / fps, video, labels), n, fps, audio, tick
            )
            total = time.perf_counter() - t_start
            summary |= {
                "output": str(args.out),
                "frames": n,
                "fps": fps,
                "duration_s": round(n / fps, 6),
                "width": timing["width"],
                "height": timing["height"],
                "audio": audio is not None,
                "audio_from": str(speech[0].audio_file) if speech is not None else None,
                "audio_rate": audio.rate if audio is not None else None,
                "render_ms_per_frame": round(1000 * timing["render_s"] / n, 2),
                "encode_ms_per_frame": round(1000 * timing["encode_s"] / n, 2),
                "frames_per_s": round(n / total, 2),
                "seconds": round(total, 3),
            }
    if video is not None:
        video.close()
    if args.json:
        emit_json(summary)
    else:
        progress(f"{args.input} -> {args.out}")
    return 0


def cmd_plot(args: argparse.Namespace) -> int:
    from capture.audio_io import audio_left_in_files

    from .plot import plot_curves
    from .render import distinct_labels, load_animation, place_on_parent_clock

    if args.start is not None and args.end is not None and args.start >= args.end:  # no input needed
        args.usage_error(f"argument --start: {args.start:g} s must come before --end {args.end:g} s")
    labels = [s.strip() for s in args.labels.split(",")] if args.labels else []
    if labels and len(labels) != len(args.inputs):
        raise InputError(f"--labels names {len(labels)} inputs, but {len(args.inputs)} were given")
    one = "plot draws one take per input (name each take to compare several)"
    anims = []
    # Audio libsndfile reads is left in its file, read a block at a time as it is plotted (a 2 h take's
    # samples held whole took 691 MB at 48 kHz).
    with audio_left_in_files():
        for i, path in enumerate(args.inputs):
            audio = args.audio if i == 0 else None
            label = labels[i] if labels else None
            # The curves show the values as they are (no clamping); bad values are bridged like gaps.
            anims.append(
                load_animation(path, audio, label, one, clamp=False, audio_flag="--audio" if i == 0 else None)
            )
    for a, path in zip(anims[1:], args.inputs[1:]):
        a.offset_s = place_on_parent_clock(anims[0], a, path)
    if not labels:
        distinct_labels(anims, args.inputs)  # a raw take and its aligned copy share their take id
    if args.out.suffix.lower() not in (".png", ".svg"):
        raise InputError("the plot is written as .png or .svg", args.out)
    prepare_output(args.out)
    _warn(anims)
    summary = plot_curves(anims, args.out, args.channels, args.vad, args.start, args.end, title=args.title)
    if summary["channel_note"]:
        progress(f"note: {summary['channel_note']}")
    for name in summary["repeated_channels"]:
        warn(f"--channels names {name} more than once: drawn once")
    for label in summary["inputs_without_these_channels"]:
        warn(f"{label} holds none of the channels plotted ({', '.join(summary['channels'])})")
    if summary["undrawable_characters"]:
        warn(
            f"no installed font has {summary['undrawable_characters']!r} (drawn as boxes): "
            "install one that has them, such as Noto Sans CJK"
        )
    if args.json:
        emit_json(summary)
    else:
        progress(f"{', '.join(map(str, args.inputs))} -> {args.out}")
    return 0


def cmd_stream(args: argparse.Namespace) -> int:
    from capture.replay import check_speed, packet_names, parse_destination

    from .inputs import ABSURD, livelink_coverage, missing_face_channels, prepared_for_stream
    from .stream import load_take, speech_player, stream_take

    parse_destination(args.to)  # a malformed destination or speed is reported before any file is read
    check_speed(args.speed)
    audio_file = args.audio if args.audio not in (None, "take") else None
    take, warnings, speech_file = load_take(args.input, audio_file)
    warnings += livelink_coverage(take, args.input, "stream") + missing_face_channels(take, args.input)
    packet_names(take, args.device, args.subject)  # names too long for a datagram: before any output
    take, outside = prepared_for_stream(take)
    for w in warnings:
        warn(w)
    if outside:
        warn(
            f"{outside} blendshape value(s) outside 0..1 are sent as they are (the phone sends "
            "up to 1.05; a rig may expect 0..1)"
        )
    player = speech_player(take, args.speed) if args.audio is not None else None
    if not args.json:
        progress(f"streaming {take.meta.id} to {args.to} ({take.duration_s / args.speed:.1f} s)")
    summary = stream_take(take, args.to, args.speed, player, args.subject, args.device)
    summary["outside_0_1"] = outside
    summary["audio_file"] = str(speech_file) if summary["audio"] and speech_file else None
    if args.json:
        emit_json(summary)
    else:
        progress(f"sent {summary['frames']} frames in {summary['duration_s']:.2f} s")
    if summary["bad_values"]:
        warn(
            f"{summary['bad_values']} frames with NaN/inf values sent as no-face packets "
            f"(values beyond ±{ABSURD:g} count as such)"
        )
    return 0


def _live_run(args: argparse.Namespace):
    """speak's run (``LiveAnimator``) and where its frames go (``LiveLinkOut``)."""
    from train.predict import check_speaker, load_for_animation
    from train.streaming import LiveAnimator

    from .speak import LiveLinkOut, live_channels

    model, payload, ppg = load_for_animation(args.run, args.ppg_model, style=args.style)
    info = payload["dataset"]
    check_speaker(info, args.speaker)
    channels = list(info["channels"])
    for w in live_channels(channels, args.run):
        warn(w)
    animator = LiveAnimator(model, payload, args.context, args.latency, ppg, args.speaker, args.style)
    name = f"{Path(args.run).resolve().name}-live"
    return animator, LiveLinkOut(args.to, channels, animator.fps, name, args.subject, args.device)


def cmd_speak(args: argparse.Namespace) -> int:
    from capture.replay import parse_destination

    from .speak import FileSpeech, MicSpeech, delayed_player, send_delay, speak

    parse_destination(args.to)  # a malformed destination is said before anything is read
    if args.mic is not None and (args.play or args.speed != 1.0):
        raise InputError("--play and --speed are for --audio FILE: a microphone speaks in real time")
    if args.play and args.speed != 1.0:
        raise InputError("--play plays the speech in real time: use it with --speed 1")
    # the speech and the sound card first: a missing microphone is said before the run is loaded
    speech = FileSpeech(args.audio) if args.audio is not None else MicSpeech(args.mic or None)
    behind = send_delay(args.latency, args.hop)
    player = delayed_player(speech, behind) if args.play else None

    try:
        animator, out = _live_run(args)
    except BaseException:
        speech.close()  # the microphone's stream, opened
        raise
    if not args.json:
        what = args.audio if args.audio is not None else "the microphone"
        progress(f"speaking {what} to {args.to} ({behind:.2f} s behind; Ctrl-C stops)")
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(args.threads)  # one: 5-10x faster than two beside other busy processes
    try:
        summary = speak(animator, speech, out, args.hop, args.speed, player)
    finally:
        torch.set_num_threads(threads)
    summary |= {"run": str(args.run), "to": args.to, "audio_file": str(args.audio) if args.audio else None}
    summary |= {"mic": args.mic is not None, "played": args.play}
    if args.json:
        emit_json(summary)
    else:
        c, lag = summary["compute_ms_per_hop"], summary["achieved_latency_s"]
        progress(
            f"sent {summary['frames']} frames at {summary['fps']:g} fps; compute per hop {c['mean']:.0f} ms "
            f"(max {c['max']:.0f}); latency {lag['mean']:.3f} s (max {lag['max']:.3f}); "
            f"{summary['late_frames']} late"
            + (f" (stopped by {summary['stopped_by']})" if summary["stopped_by"] else "")
        )
    if summary["late_frames"]:
        warn(
            f"{summary['late_frames']} frame(s) were sent late: a hop's compute took longer than its "
            f"{args.hop / args.speed:g} s (--hop {args.hop:g} at --speed {args.speed:g}); give a larger "
            "--hop or a shorter --context"
        )
    if summary["input_overflows"]:
        warn(
            f"the sound card lost samples {summary['input_overflows']} time(s) (input overflow: this "
            "process took the microphone's blocks too late); the face went on over the gaps"
        )
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from capture.atomic import atomic_write

    from .inputs import shown, shown_in_page, unpacked_folder
    from .output import writing
    from .report import write_report

    if args.out.suffix.lower() not in (".html", ".htm"):
        raise InputError("the report is written as .html", args.out)
    # A zipped dataset or folder of takes (and --takes) is reported on unpacked, named as the archive.
    try:
        places = [unpacked_folder(p) for p in (args.dataset, *args.takes)]
    except InputError as exc:
        raise InputError(shown(exc)) from None
    dataset, *takes = [place[0] if place else p for place, p in zip(places, (args.dataset, *args.takes))]
    if not dataset.exists():
        raise InputError("no such dataset or folder", args.dataset)
    prepare_output(args.out)
    try:
        summary = write_report(dataset, args.out, takes, args.limit)
    except InputError as exc:  # "import them first (s2a-capture import X ...)" names the archive itself
        raise InputError(shown(exc).replace(f"import {shown(dataset)} ", f"import {args.dataset} ")) from None
    if any(places):  # the page and the summary name the archives' members, not the unpacked copies
        page = args.out.read_text(encoding="utf-8")
        if (named := shown_in_page(page)) != page:
            with writing(args.out, "report"), atomic_write(args.out, "w", encoding="utf-8") as f:
                f.write(named)
            summary["bytes"] = args.out.stat().st_size
        summary["warnings"] = [shown(w) for w in summary["warnings"]]
        summary["unreadable"] = [{k: shown(v) for k, v in u.items()} for u in summary["unreadable"]]
    for w in summary["warnings"]:
        warn(w)
    for u in summary["unreadable"]:
        warn(f"{u['error']}: listed as unreadable")
    if summary["thumbnails"] < summary["takes"] and args.limit < summary["takes"]:
        progress(f"note: --limit {args.limit}: curve thumbnails for {args.limit} of {summary['takes']} takes")
    if args.json:
        emit_json(summary)
    else:
        progress(
            f"{args.dataset} -> {args.out} ({summary['takes']} takes, {len(summary['outliers'])} outliers)"
        )
    return 0


def cmd_export_face(args: argparse.Namespace) -> int:
    from .face import builtin_face
    from .gltf import write_glb

    if args.out.suffix.lower() != ".glb":
        raise InputError("the face is written as binary glTF: give a file name ending in .glb", args.out)
    prepare_output(args.out)
    model = builtin_face()
    out = write_glb(model, args.out, args.names)
    summary = {
        "output": str(out),
        "parts": len(model.parts),
        "channels": len(model.channels),
        "bytes": out.stat().st_size,
    }
    if args.json:
        emit_json(summary)
    else:
        progress(f"built-in face -> {out}")
    return 0


def cmd_probe(args: argparse.Namespace) -> int:
    from .probe import probe

    info = probe()
    if args.json:
        emit_json(info)
    else:
        progress(f"offscreen rendering works ({info['window']})")
    return 0


def _stoppable(args: argparse.Namespace) -> int:
    """Run the command; SIGTERM (``timeout``, ``kill``) stops it as Ctrl-C does (``run`` says so, exit
    143 instead of 130), and either removes a half-written output's ``.partial`` file on the way out,
    and the zip archives unpacked for the command's inputs (``inputs.archives_unpacked``)."""
    from .inputs import archives_unpacked

    with stopped_by_signals(), archives_unpacked():
        return args.handler(args)


def main(argv: list[str] | None = None) -> int:
    return run(PROG, build_parser, _stoppable, argv)


if __name__ == "__main__":
    sys.exit(main())
