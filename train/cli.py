"""``s2a-train``: fit, eval, predict, compare, agreement, ppg, export."""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from capture.command import StageParser, add_version, emit_json, emit_line, handle_stoppable, run
from capture.csv_take import COUNT_NAMES
from capture.errors import InputError
from capture.import_guard import guard_imports, imports_done

from .choices import PRECISIONS
from .config import MODELS, resolve_config

# The command's imports are done: Ctrl-C is its own from here (capture.import_guard). PyTorch is not
# among them: each command imports what it needs (_command_imports), so --help and usage errors are fast.
_guard = imports_done("train")

PROG = "s2a-train"
RUN_HELP = (
    "run folder (its best.pt, else last.pt), or a checkpoint file: RUN/last.pt for the last step's weights "
    "rather than the best on validation"
)


def _path(text: str) -> Path:
    """A path option's value: an empty (or all-blank) one is a usage error, not the current folder
    (``Path("")`` is ``.``: ``-o ''`` would write there)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty path: name a file or folder")
    return Path(text)


def build_parser() -> argparse.ArgumentParser:
    parser = StageParser(prog=PROG, description=__doc__)
    add_version(parser)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("fit", help="train a system on a dataset into a run folder")
    p.add_argument(
        "--data", metavar="DS", type=_path, required=True, help="dataset folder (s2a-dataset build)"
    )
    p.add_argument("--model", choices=MODELS, help="system to train (default: the config's, else s2a)")
    p.add_argument("-o", "--out", type=_path, required=True, help="run folder")
    p.add_argument("--config", metavar="FILE", type=Path, help="TOML file of config keys (see docs/train.md)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config key")
    p.add_argument("--max-steps", metavar="N", type=int, help="optimizer steps (overrides max_steps)")
    p.add_argument("--max-minutes", type=float, help="wall-clock limit in minutes (overrides max_minutes)")
    p.add_argument(
        "--seed",
        metavar="N",
        type=int,
        help="seed of the initial weights and the batch order (overrides seed)",
    )
    p.add_argument("--resume", action="store_true", help="continue the run from its last checkpoint")
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(handler=cmd_fit)

    p = sub.add_parser("eval", help="RMSE (paper scale), per-channel errors, floor and RTF of a run")
    p.add_argument("run", type=_path, help=RUN_HELP)
    p.add_argument("--data", metavar="DS", type=_path, required=True, help="dataset folder")
    p.add_argument("--split", default="test", help="split to evaluate (default: test)")
    _precision_option(p)
    _style_option(p, "each utterance's own speaker's, the mean style for a speaker the run did not train on")
    p.add_argument("--json", action="store_true", help="print the metrics as JSON")
    p.set_defaults(handler=cmd_eval)

    p = sub.add_parser("predict", help="speech -> Live Link Face CSV")
    p.add_argument("run", type=_path, help=RUN_HELP)
    p.add_argument("audio", nargs="+", type=Path, help="audio files (any rate; mixed to mono)")
    p.add_argument("-o", "--out", type=_path, required=True, help="CSV (one input) or folder")
    p.add_argument(
        "--ppg-model", metavar="FILE", type=Path, help="PPG model file when the run's dataset used one"
    )
    p.add_argument(
        "--speaker", help="dataset speaker whose pitch statistics to use (default: the utterance's)"
    )
    p.add_argument(
        "--neutral",
        type=Path,
        help="the speaker's neutral pose (a _neutral.csv or a calibrated take folder), for a run built "
        "with --normalization neutral",
    )
    p.add_argument(
        "--count-name",
        choices=COUNT_NAMES,
        help="spelling of the CSV's second header column (default: BlendShapeCount, as Epic's importer "
        "reads it; NeuroSync's loader drops BlendshapeCount by that exact name)",
    )
    _precision_option(p)
    _style_option(p, "the --speaker's when the run trained on that speaker, else the mean style")
    p.add_argument("--json", action="store_true", help="print one JSON line per file")
    p.set_defaults(handler=cmd_predict)

    p = sub.add_parser("compare", help="train and evaluate several systems; Table 1 and Table 2")
    p.add_argument("--data", metavar="DS", type=_path, required=True, help="dataset folder")
    p.add_argument("-o", "--out", type=_path, required=True, help="folder for the runs and results")
    p.add_argument(
        "--models",
        nargs="+",
        default=list(MODELS),
        choices=MODELS,
        metavar="SYSTEM",
        help=f"systems to compare, of {', '.join(MODELS)} (default: all)",
    )
    p.add_argument("--config", metavar="FILE", type=Path, help="TOML file shared by all systems")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config key")
    p.add_argument("--max-steps", metavar="N", type=int, help="optimizer steps per system")
    p.add_argument("--max-minutes", type=float, help="wall-clock limit per system in minutes")
    p.add_argument("--seed", metavar="N", type=int, help="seed of every system's training (overrides seed)")
    p.add_argument("--split", default="test", help="split to evaluate (default: test)")
    p.add_argument("--json", action="store_true", help="print one JSON line per system")
    p.set_defaults(handler=cmd_compare)

    p = sub.add_parser(
        "agreement", help="how well the takes predict each other (ridge, leave one take out): odd takes out"
    )
    p.add_argument("--data", metavar="DS", type=_path, required=True, help="dataset folder")
    p.add_argument(
        "--config", metavar="FILE", type=Path, help="TOML file (input, prosody, ridge_context, ridge_alpha)"
    )
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config key")
    p.add_argument(
        "--splits",
        nargs="+",
        default=["train", "val"],
        help="splits whose takes to compare (default: train val; adding test is for studying a dataset, "
        "not for choosing a model)",
    )
    p.add_argument("--json", action="store_true", help="print the scores as JSON")
    p.set_defaults(handler=cmd_agreement)

    p = sub.add_parser("ppg", help="train the 64-dim bottleneck PPG extractor from phone alignments")
    p.add_argument(
        "--data",
        metavar="PATH",
        type=_path,
        nargs="+",
        required=True,
        help="phone alignments beside same-named audio (as s2a-capture simulate writes its take folders, "
        "or a forced aligner's output: Praat TextGrids, the toolkit's, Gentle's or MFA's JSON, MFA's CSV, "
        "Kaldi CTM, BAS Partitur), or folders of them; folders are searched recursively (imported take "
        "folders carry no alignments). With --labels pocketsphinx: take folders and audio files",
    )
    p.add_argument(
        "--labels",
        choices=("alignments", "pocketsphinx"),
        default="alignments",
        help="where the frame phone labels come from: the alignments (default), or phone-loop recognition "
        "by pocketsphinx's bundled English model, for speech without alignments in any language",
    )
    p.add_argument("-o", "--out", type=_path, required=True, help="checkpoint to write (ppg.pt)")
    p.add_argument("--steps", metavar="N", type=int, default=300, help="optimizer steps (default: 300)")
    p.add_argument(
        "--seed", metavar="N", type=int, default=0, help="seed of the initial weights and the batch order"
    )
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(handler=cmd_ppg)

    p = sub.add_parser("export", help="ONNX export checked against PyTorch with onnxruntime")
    p.add_argument("run", type=_path, help=RUN_HELP)
    p.add_argument("-o", "--out", type=_path, required=True, help="ONNX file to write")
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(handler=cmd_export)
    return parser


def _precision_option(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--precision",
        choices=PRECISIONS,
        default="fp32",
        help="inference arithmetic: fp32 (default) or bf16 (about 2x faster on CPUs with AVX512-BF16 or AMX)",
    )


def _style_option(p: argparse.ArgumentParser, default: str) -> None:
    p.add_argument(
        "--style",
        metavar="SPEAKER",
        help=f"for runs trained with speaker_style: animate in this training speaker's style, or 'mean' "
        f"(default: {default})",
    )


def _config(args: argparse.Namespace, model: str | None = None) -> dict:
    cfg = resolve_config(args.config, args.set)
    if model is not None:
        cfg["model"] = model
    return resolve_config(None, None, base=cfg | _options_given(args))


# config keys with an option of their own in fit and compare (agreement has none of them)
CONFIG_OPTIONS = ("max_steps", "max_minutes", "seed")


def _options_given(args: argparse.Namespace) -> dict:
    """The config keys given as options (``--max-steps``, ``--max-minutes``, ``--seed``)."""
    return {key: getattr(args, key) for key in CONFIG_OPTIONS if getattr(args, key, None) is not None}


def _given(args: argparse.Namespace, model: str | None) -> dict:
    """Only the config keys the user set (``--config``, ``--set``, ``--model``, ``CONFIG_OPTIONS``):
    what a resumed run checks against its own config."""
    given = resolve_config(args.config, args.set, base={}, check=False)
    if model is not None:
        given["model"] = model
    return given | _options_given(args)  # keys given as options count as set by the user


@contextmanager
def _command_imports() -> Iterator[None]:
    """Around a command's own imports (PyTorch's 1-2 s): Ctrl-C there stops the command quietly, as it
    does while this module imports (capture.import_guard), rather than leaving a half-imported library."""
    guard_imports()
    try:
        yield
    finally:
        imports_done("train")


def cmd_fit(args: argparse.Namespace) -> int:
    with _command_imports():
        from .fit import fit

    cfg = _config(args, args.model)
    summary = fit(args.data, args.out, cfg, resume=args.resume, given=_given(args, args.model))
    if summary.get("rank", 0) == 0:  # under torchrun, rank 0 reports for all
        if args.json:
            emit_json(summary)
        else:
            emit_line(
                f"{summary['run']}: {summary['model']} {summary['steps']} steps, "
                f"stopped: {summary['stopped']}, best val mse {summary['best_val']}"
            )
    if summary.get("world_size", 1) > 1:
        _leave_distributed_process()
    return 0


def _leave_distributed_process() -> None:
    """End a torchrun worker without interpreter shutdown. Gloo's run-loop threads release the last
    collective's tensors after ``wait()`` has returned; when that happens while Python is shutting
    down, the thread cannot take the GIL and the C++ runtime aborts the process (SIGABRT, seen on
    busy machines). Everything is written and closed by now: flush the streams and leave."""
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


def cmd_eval(args: argparse.Namespace) -> int:
    with _command_imports():
        from .evaluate import evaluate, format_result

    result = evaluate(args.run, args.data, args.split, precision=args.precision, style=args.style)
    if args.json:
        emit_json(result)
    else:
        emit_line(format_result(result))
    return 0


def cmd_predict(args: argparse.Namespace) -> int:
    with _command_imports():
        from .predict import predict

    results = predict(
        args.run,
        args.audio,
        args.out,
        args.ppg_model,
        args.speaker,
        precision=args.precision,
        style=args.style,
        neutral=args.neutral,
        count_name=args.count_name,
    )
    failed = [r for r in results if "error" in r]
    for r in results:
        if args.json:
            emit_json(r)
        elif "error" not in r:
            emit_line(f"{r['csv']}: {r['frames']} frames ({r['duration_s']:.2f} s)")
    if failed:
        written = "none was written" if len(failed) == len(results) else "the others were written"
        raise InputError(
            f"{len(failed)} of {len(results)} audio files failed ({written}); first: {failed[0]['error']}"
        )
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    with _command_imports():
        from .compare import compare, format_tables

    rows = compare(
        args.data,
        args.out,
        args.models,
        lambda m: _config(args, m),
        args.split,
        given_for=lambda m: _given(args, m),
    )
    if args.json:
        for r in rows:
            emit_json(r)
    else:
        emit_line(format_tables(rows))
    failed = [r for r in rows if "error" in r]
    if failed:
        held = "each one's error" if len(failed) == len(rows) else "the others' results"
        raise InputError(
            f"{len(failed)} of {len(rows)} systems failed (compare.json holds {held}); "
            f"first: {failed[0]['error']}"
        )
    return 0


def cmd_agreement(args: argparse.Namespace) -> int:
    with _command_imports():
        from .agreement import format_agreement, take_agreement

    result = take_agreement(args.data, _config(args), tuple(args.splits))
    if args.json:
        emit_json(result)
    else:
        emit_line(format_agreement(result))
    return 0


def cmd_ppg(args: argparse.Namespace) -> int:
    with _command_imports():
        from .ppg_train import train_ppg

    summary = train_ppg(args.data, args.out, steps=args.steps, seed=args.seed, labels=args.labels)
    if args.json:
        emit_json(summary)
    else:
        acc = summary["val_accuracy"] if summary["val_accuracy"] is not None else summary["train_accuracy"]
        emit_line(
            f"{summary['checkpoint']}: frame phone accuracy {acc:.3f} "
            f"(chance {summary['majority_accuracy']:.3f})"
        )
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    with _command_imports():
        from .export import export_onnx

    summary = export_onnx(args.run, args.out)
    if args.json:
        emit_json(summary)
    else:
        emit_line(f"{summary['onnx']}: max |onnxruntime - torch| = {summary['max_abs_diff']:.2e}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    return run(PROG, build_parser, handle_stoppable, argv)


if __name__ == "__main__":
    sys.exit(main())
