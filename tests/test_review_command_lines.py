"""The command-line surface of the five stages as a first-time user meets it through ``--help``: every
script says its version, every option its default, every subcommand and argument what it is; the same
concept is spelled the same way in every stage (``-j/--jobs``); ``remote``'s options go where a user
writes them. In-process through each stage's ``build_parser()``; subprocesses only where the installed
script and ``python -m`` are the subject."""

from __future__ import annotations

import argparse
import importlib
import importlib.metadata
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
from test_docs_commands import STAGES  # each command's stage


def _walk(parser: argparse.ArgumentParser, words: tuple[str, ...], found: dict) -> None:
    found[words] = parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                _walk(sub, (*words, name), found)


def _parsers() -> dict[tuple[str, ...], argparse.ArgumentParser]:
    found: dict[tuple[str, ...], argparse.ArgumentParser] = {}
    for command, stage in STAGES.items():
        _walk(importlib.import_module(f"{stage}.cli").build_parser(), (command,), found)
    return found


PARSERS = _parsers()


def _subcommand_lines(parser: argparse.ArgumentParser) -> dict[str, str | None]:
    """Each subcommand of ``parser`` and the one line of help its parent lists it with."""
    return {
        choice.dest: choice.help
        for action in parser._actions
        if isinstance(action, argparse._SubParsersAction)
        for choice in action._choices_actions
    }


def _shown_help(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    """The help text ``--help`` prints for ``action`` (as the parser's formatter expands it)."""
    formatter = parser._get_formatter()
    return formatter._expand_help(action) if action.help else ""


@pytest.mark.parametrize("command", STAGES)
def test_every_script_says_its_version(command, capsys):
    parser = PARSERS[(command,)]
    with pytest.raises(SystemExit) as stop:
        parser.parse_args(["--version"])
    assert stop.value.code == 0
    assert capsys.readouterr().out.strip() == f"{command} {importlib.metadata.version('s2a-toolkit')}"


def test_version_of_python_m_and_of_the_script_agree():
    script = Path(sys.executable).parent / "s2a-align"
    if not script.exists():
        pytest.skip("the console scripts are not installed beside this interpreter")
    by_module = subprocess.run([sys.executable, "-m", "align", "--version"], capture_output=True, text=True)
    by_script = subprocess.run([str(script), "--version"], capture_output=True, text=True)
    assert by_module.returncode == by_script.returncode == 0
    assert by_module.stdout == by_script.stdout == f"s2a-align {importlib.metadata.version('s2a-toolkit')}\n"


def test_help_shows_every_default_worth_saying():
    hidden = [
        f"{' '.join(words)} {action.option_strings[-1]} (default {action.default!r})"
        for words, parser in PARSERS.items()
        for action in parser._actions
        if action.option_strings and action.help != argparse.SUPPRESS
        if action.default not in (None, "", [], argparse.SUPPRESS) and not isinstance(action.default, bool)
        if "default" not in _shown_help(parser, action)
    ]
    assert not hidden, "help leaves out the default of:\n" + "\n".join(hidden)


def test_default_shown_is_the_parsers():
    parser = PARSERS[("s2a-align",)]
    assert "speech detector for trimming (default: silero)" in " ".join(parser.format_help().split())
    jobs = next(a for a in parser._actions if "--jobs" in a.option_strings)
    assert _shown_help(parser, jobs).endswith("(default: 1)")


def test_every_argument_and_subcommand_has_help():
    missing = [
        f"{' '.join(words)} {'/'.join(action.option_strings) or action.dest}"
        for words, parser in PARSERS.items()
        for action in parser._actions
        if not action.help and not isinstance(action, argparse._SubParsersAction)
    ]
    missing += [
        f"{' '.join(words)} {name}"
        for words, parser in PARSERS.items()
        for name, line in _subcommand_lines(parser).items()
        if not line
    ]
    assert not missing, "no help for:\n" + "\n".join(missing)


def test_subcommand_help_says_what_it_does():
    """``s2a-capture info --help`` opens with what ``info`` does, not with its options alone."""
    silent = [
        " ".join((*words, name))
        for words, parser in PARSERS.items()
        for name, line in _subcommand_lines(parser).items()
        if not PARSERS[(*words, name)].description
    ]
    assert not silent, "no description in --help of:\n" + "\n".join(silent)
    text = " ".join(PARSERS[("s2a-capture", "info")].format_help().split())
    assert "frames, rate, drops, face-lost frames and audio of takes" in text


def test_help_shows_no_rest_markup():
    marked = [" ".join(words) for words, parser in PARSERS.items() if "``" in parser.format_help()]
    assert not marked, f"reST quotes in --help of: {marked}"


@pytest.mark.parametrize("command", [("s2a-align",), ("s2a-dataset", "build")])
def test_jobs_is_spelled_the_same_in_every_stage(command):
    parser = PARSERS[command]
    given = ["TAKE", "-o", "OUT"]
    prefix = list(command[1:])
    assert parser.parse_args([*prefix, *given, "-j", "3"]).jobs == 3
    assert parser.parse_args([*prefix, *given, "--jobs", "2"]).jobs == 2
    with pytest.raises(SystemExit) as stop:  # no worker processes: a usage error (2), as a word is
        parser.parse_args([*prefix, *given, "--jobs", "0"])
    assert stop.value.code == 2


def test_remote_options_also_after_the_action():
    parser = PARSERS[("s2a-capture",)]
    after = parser.parse_args(["remote", "phone.local", "battery", "--timeout", "7", "--json"])
    assert (after.timeout, after.json, after.reply_port) == (7.0, True, 0)
    before = parser.parse_args(["remote", "--timeout", "5", "--json", "phone.local", "battery"])
    assert (before.timeout, before.json) == (5.0, True)
    plain = parser.parse_args(["remote", "phone.local", "target", "10.0.0.2:11111", "--keep"])
    assert (plain.timeout, plain.json, plain.keep, plain.reply_host) == (2.0, False, True, None)


def test_replay_and_plot_help_say_what_the_code_does():
    replay = " ".join(PARSERS[("s2a-capture", "replay")].format_help().split())
    assert "Live Link Face CSV or take folder" not in replay  # said "take folder" twice
    vad = next(a for a in PARSERS[("s2a-view", "plot")]._actions if "--vad" in a.option_strings)
    assert vad.default == "auto" and "auto (the default)" in vad.help


def test_info_reads_a_folder_of_takes_as_its_help_says(tmp_path, capsys):
    """``info``'s help named take folders and CSV files only; it reads folders and zips of them too."""
    from dataset_helpers import write_aligned_set

    from capture.cli import main

    help_text = " ".join(PARSERS[("s2a-capture", "info")].format_help().split())
    assert "folders or zip archives of them" in help_text
    folder = write_aligned_set(tmp_path / "takes", count=2, seconds=1.0)
    assert main(["info", str(folder), "--json"]) == 0
    ids = [json.loads(line)["id"] for line in capsys.readouterr().out.splitlines()]
    assert sorted(ids) == ["take00", "take01"]


@pytest.mark.parametrize("command", ["fit", "compare"])
def test_train_seed_is_an_option_as_in_every_other_stage(command):
    """``--seed`` seeds dataset build, ppg, replay and simulate; fit and compare took it only as
    ``--set seed=N``, and refused ``--seed`` as a usage error."""
    from train.cli import _config

    parser = PARSERS[("s2a-train",)]
    args = parser.parse_args([command, "--data", "DS", "-o", "RUN", "--seed", "5", "--set", "max_steps=3"])
    assert (_config(args)["seed"], _config(args)["max_steps"]) == (5, 3)
    unset = parser.parse_args([command, "--data", "DS", "-o", "RUN", "--set", "seed=4"])
    assert _config(unset)["seed"] == 4  # --set still works; the option overrides it only when given


def test_an_option_named_with_its_unit_expects_that_unit():
    """``--max-gap-ms MAX_GAP_MS`` said nothing the name had not; ``--max-gap-ms MS`` says what to type."""
    units = {"-ms": "MS", "-s": "S", "-mb": "MB", "-minutes": "MIN"}
    wrong = [
        f"{' '.join(words)} {name} {action.metavar}"
        for words, parser in PARSERS.items()
        for action in parser._actions
        for name in action.option_strings
        for suffix, unit in units.items()
        if name.startswith("--") and name.endswith(suffix) and action.nargs != 0 and action.metavar != unit
    ]
    assert not wrong, "\n".join(wrong)
    usage = PARSERS[("s2a-align",)].format_usage()
    assert "[--max-gap-ms MS]" in usage and "[--min-segment-s S]" in usage


def test_values_have_metavars_that_say_what_is_expected():
    shown = {
        ("s2a-train", "fit"): [
            "--data DS",
            "--config FILE",
            "--max-steps N",
            "--max-minutes MIN",
            "--seed N",
        ],
        ("s2a-capture", "listen"): [
            "--duration S",
            "--audio-file FILE",
            "--audio-rate HZ",
            "--flush-interval S",
        ],
        ("s2a-capture", "remote"): ["--timeout S"],
        ("s2a-view", "plot"): ["--audio FILE", "--start S", "--end S"],
    }
    for words, expected in shown.items():
        usage = " ".join(PARSERS[words].format_usage().split())
        assert all(f"{e}]" in usage or f"{e} " in usage for e in expected), (words, usage)


def test_capture_description_names_what_it_does():
    """It said "import takes, inspect them, write them back as CSV": no word of live capture."""
    text = PARSERS[("s2a-capture",)].description
    assert all(word in text for word in ("import", "listen", "recover", "remote", "replay", "simulate"))


def test_json_lines_are_strict_whatever_the_numbers(capsys):
    """A NaN in a summary (a metric of an empty split, a diverged loss) raised ValueError out of
    ``emit_json`` (``allow_nan=False``): a traceback instead of the result line."""
    from capture.command import emit_json

    emit_json(
        {"id": "t", "rmse": float("nan"), "per_channel": {"jawOpen": float("inf")}, "s": [1.0, -math.inf]}
    )
    line = capsys.readouterr().out
    strict = json.loads(line, parse_constant=lambda word: pytest.fail(f"{word} in {line}"))
    assert strict == {"id": "t", "rmse": None, "per_channel": {"jawOpen": None}, "s": [1.0, None]}
