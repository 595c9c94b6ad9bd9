"""The command lines the README and docs/*.md show a user parse with the current parsers.

Every example command in a code block (``s2a-...``, ``python -m <stage>``, ``torchrun ... -m <stage>``;
``\\`` continuations joined, ``$ `` prompts, comments and shell redirections left off) parses with its
stage's ``build_parser()``; an inline command may name a command without its arguments. Every usage
synopsis (a block line with ``[--option ...]``) names only options its command has, shows the parser's
default where it gives a number, the parser's choices where it gives ``a|b``, and leaves out no option.
The README's dependency table names exactly the packages of pyproject.toml, and every ``make TARGET``
the docs name is a target of the Makefile. Parsing only: nothing runs, so a stale option or default in
a guide fails here, not in front of a user."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import io
import re
import shlex

import pytest
from conftest import ROOT

# each command's stage: its parser is ``<stage>.cli.build_parser()``
STAGES = {
    "s2a-capture": "capture",
    "s2a-align": "align",
    "s2a-dataset": "dataset",
    "s2a-train": "train",
    "s2a-view": "viewer",
}
# results.md is written by benchmarks.paper and shows its own command lines, not the toolkit's
DOCS = [ROOT / "README.md", *sorted(p for p in (ROOT / "docs").glob("*.md") if p.name != "results.md")]
SHELL_OPERATORS = {"|", "&", "&&", ";", "2>&1"}
# a usage synopsis rather than an example: optional parts, alternatives, repetition, or a placeholder
# word in capitals standing for a value (RUN, TAKE, PHONE)
SYNOPSIS = re.compile(r"\[|\.\.\.|\||(?<![\w$/-])[A-Z][A-Z_]+(?![\w/.-])")


@pytest.fixture(scope="module")
def parsers() -> dict[tuple[str, ...], argparse.ArgumentParser]:
    """Every command and subcommand's parser, keyed by its words (``("s2a-capture", "remote", "target")``)."""
    found: dict[tuple[str, ...], argparse.ArgumentParser] = {}

    def walk(parser: argparse.ArgumentParser, words: tuple[str, ...]) -> None:
        parser.allow_abbrev = False  # a doc's option cut short (an old name) must not pass as a prefix
        found[words] = parser
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(sub, (*words, name))

    for command, stage in STAGES.items():
        walk(importlib.import_module(f"{stage}.cli").build_parser(), (command,))
    return found


def code_lines(text: str) -> list[tuple[int, str]]:
    """(line number, command) of each code-block line, ``\\`` continuations joined, ``$ `` dropped."""
    out, inside, held, start = [], False, "", 0
    for number, line in enumerate(text.splitlines(), 1):
        if line.strip().startswith("```"):
            inside, held = not inside, ""
            continue
        if not inside:
            continue
        if not held:
            start = number
        held = f"{held} {line.strip()}" if held else line.strip()
        if held.endswith("\\"):
            held = held[:-1]
            continue
        out.append((start, held.removeprefix("$ ")))
        held = ""
    return out


def inline_spans(text: str) -> list[tuple[int, str]]:
    """(line number, text) of each inline code span outside code blocks."""
    out, inside = [], False
    for number, line in enumerate(text.splitlines(), 1):
        if line.strip().startswith("```"):
            inside = not inside
        elif not inside:
            out += [(number, span) for span in re.findall(r"`([^`]+)`", line)]
    return out


def command_words(line: str) -> tuple[str, list[str]] | None:
    """(stage, arguments) of a toolkit command line, else None (other programs, prose, messages)."""
    try:
        words = shlex.split(line, comments=True)
    except ValueError:
        return None
    for i, word in enumerate(words):
        if word in SHELL_OPERATORS or word.startswith((">", "2>")):
            words = words[:i]
            break
    if len(words) < 2 or any(w.endswith(":") for w in words[:2]):  # an error message quoted
        return None
    if words[0] in STAGES:
        return STAGES[words[0]], words[1:]
    if words[0] in ("python", "torchrun") and "-m" in words:
        stage = words[words.index("-m") + 1]
        return (stage, words[words.index("-m") + 2 :]) if stage in STAGES.values() else None
    return None


def parse_error(parser: argparse.ArgumentParser, args: list[str]) -> str | None:
    """argparse's error line for these arguments, None when they parse."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            parser.parse_args(args)
        except SystemExit as exc:
            if exc.code:
                return err.getvalue().strip().splitlines()[-1]
    return None


def test_every_example_command_parses(parsers):
    by_stage = {stage: parsers[(command,)] for command, stage in STAGES.items()}
    failures, checked = [], 0
    for doc in DOCS:
        text = doc.read_text(encoding="utf-8")
        for kind, items in (("block", code_lines(text)), ("inline", inline_spans(text))):
            for number, line in items:
                found = command_words(line)
                if found is None or SYNOPSIS.search(line.split("#")[0]):
                    continue
                stage, args = found
                error = parse_error(by_stage[stage], args)
                checked += 1
                # an inline mention may name a command, or an option, without what it takes
                named_only = "are required" in str(error) or "expected one argument" in str(error)
                if error and not (kind == "inline" and named_only):
                    failures.append(f"{doc.name}:{number}: {line}\n    {error}")
    assert not failures, "\n".join(failures)
    assert checked > 100, f"only {checked} command lines found: the extraction broke"


def synopses(text: str, parsers) -> list[tuple[int, tuple[str, ...], str]]:
    """(line, command words, text) of each usage synopsis in a code block: a line starting with a
    command that shows ``[...]`` or ``...``, with the indented lines that continue it."""
    out, current, inside = [], None, False
    for number, line in enumerate(text.splitlines(), 1):
        if line.strip().startswith("```"):
            inside, current = not inside, None
            continue
        words = line.split()
        if inside and words and words[0] in STAGES and ("[" in line or "..." in line):
            key = (words[0],)
            for word in words[1:]:
                if (*key, word) not in parsers:
                    break
                key = (*key, word)
            current = [number, key, line]
            out.append(current)
        elif inside and current and line.startswith(" "):
            current[2] += " " + line
        else:
            current = None
    return [tuple(s) for s in out]


def test_synopses_match_the_parsers(parsers):
    failures, count = [], 0
    for doc in DOCS:
        for number, key, text in synopses(doc.read_text(encoding="utf-8"), parsers):
            count += 1
            where = f"{doc.name}:{number} {' '.join(key)}"
            # the options of this command and of its subcommands (remote ACTION's --keep)
            options = {
                o: a
                for words, p in parsers.items()
                if words[: len(key)] == key
                for a in p._actions
                for o in a.option_strings
            }
            for m in re.finditer(r"(--[a-z][a-z0-9-]*)(?:[ =]([^\s\[\]]+))?", text):
                name, shown = m.groups()
                if name not in options:
                    failures.append(f"{where}: {name} is no option of this command")
                    continue
                default, choices = options[name].default, options[name].choices
                number = shown and re.fullmatch(r"-?\d+(\.\d+)?", shown)
                if number and isinstance(default, (int, float)) and float(shown) != float(default):
                    failures.append(f"{where}: {name} shows {shown}, the parser's default is {default}")
                if shown and "|" in shown and choices and set(shown.split("|")) != {str(c) for c in choices}:
                    failures.append(f"{where}: {name} shows {shown}, the parser takes {list(choices)}")
            named = set(re.findall(r"(?<![\w-])--?[a-zA-Z][\w-]*", text))
            left_out = [
                a.option_strings[-1]
                for a in parsers[key]._actions
                if a.option_strings and a.help != argparse.SUPPRESS and "-h" not in a.option_strings
                if not named & set(a.option_strings)
            ]
            if left_out:
                failures.append(f"{where}: leaves out {' '.join(left_out)}")
    assert not failures, "\n".join(failures)
    assert count >= 20, f"only {count} synopses found: the extraction broke"


def _package_name(text: str) -> str:
    return re.split(r"[<>=!~\[; ]", text.strip(), maxsplit=1)[0].lower()


def test_readme_dependencies_are_pyproject_packages():
    try:
        import tomllib
    except ImportError:  # Python 3.10
        import tomli as tomllib

    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    wanted = {_package_name(d) for d in project["dependencies"]}
    wanted |= {_package_name(d) for extra in project["optional-dependencies"].values() for d in extra}
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    table = readme.split("## Dependencies and why", 1)[1].split("\n## ", 1)[0]
    listed = set()
    for row in table.splitlines()[3:]:
        if row.startswith("|"):
            cell = re.sub(r"\([^)]*\)", "", row.split("|")[1])  # "(PyAV)", "(dev)", "(2.13.0 CPU ...)"
            listed |= {_package_name(name) for name in cell.split(",") if name.strip()}
    assert listed == wanted, (
        f"README only: {sorted(listed - wanted)}, pyproject only: {sorted(wanted - listed)}"
    )


def test_make_targets_named_exist():
    makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
    targets = set(re.findall(r"^([a-z][\w-]*):", makefile, re.M))
    named = {(d.name, t) for d in DOCS for t in re.findall(r"`make ([a-z][\w-]*)", d.read_text("utf-8"))}
    assert {t for _, t in named} >= {"demo", "test", "bench", "results"}, named
    assert not [f"{doc}: make {t}" for doc, t in sorted(named) if t not in targets]
