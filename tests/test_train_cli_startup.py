"""``s2a-train``'s command line imports PyTorch (1-2 s) only for a command that needs it: ``--help``,
``--version`` and usage errors answer at once. A command's own imports stay under the Ctrl-C guard
(capture.import_guard): a Ctrl-C there stops it quietly, as one during the command module's imports.
And ``predict`` does not replace an existing read-only CSV (its atomic rename would, silently)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from conftest import run_python
from dataset_helpers import build_five_take_dataset


def test_the_command_line_module_imports_no_torch():
    proc = run_python(
        "import sys, train.cli; print(sorted(m for m in ('torch', 'scipy') if m in sys.modules))", timeout=120
    )
    assert proc.returncode == 0 and proc.stdout.strip() == "[]", proc.stdout + proc.stderr


# The command's process (argv[0] is the console script), noting whether Ctrl-C is the guard's when the
# command (eval of a run that does not exist) looks PyTorch up, and whose it is once the command ended.
GUARDED = """
import signal, sys
sys.argv = ["s2a-train", "eval", sys.argv[1], "--data", sys.argv[1]]
import train.cli
from capture import import_guard

class NoteCtrlC:
    def find_spec(self, name, path=None, target=None):
        if name in ("torch", "train.evaluate"):
            print(name, signal.getsignal(signal.SIGINT) is import_guard._stop_quietly)
        return None

print("train.evaluate", "train.evaluate" in sys.modules)  # imported with train.cli: then guarded as it
sys.meta_path.insert(0, NoteCtrlC())
code = train.cli.main()
print("exit", code, signal.getsignal(signal.SIGINT) is signal.default_int_handler)
"""


def test_a_commands_own_imports_are_guarded_against_ctrl_c(tmp_path):
    proc = run_python(GUARDED, str(tmp_path / "none"), timeout=120)
    before, *during, end = proc.stdout.splitlines()
    # evaluate (with PyTorch) loads under the guard: among train.cli's imports, or the command's own ...
    assert before == "train.evaluate True" or "train.evaluate True" in during, proc.stdout + proc.stderr
    assert all(line.endswith(" True") for line in during), proc.stdout + proc.stderr
    # ... which ends with them: the command (here its error, exit 1) has Python's own Ctrl-C
    assert end == "exit 1 True", proc.stdout + proc.stderr
    assert "s2a-train: error:" in proc.stderr and "Traceback" not in proc.stderr, proc.stderr


@pytest.fixture(scope="module")
def ridge_run(tmp_path_factory) -> Path:
    """A ridge run (closed form: seconds) on five 2 s takes."""
    from train.config import resolve_config
    from train.fit import fit

    root = tmp_path_factory.mktemp("startup")
    fit(build_five_take_dataset(root), root / "run", resolve_config(sets=["model='ridge'"]), say=print)
    return root / "run"


def test_predict_does_not_replace_a_read_only_csv(ridge_run, tmp_path, capsys):
    from train.cli import main

    sf.write(tmp_path / "voice.wav", 0.3 * np.sin(np.arange(8000) * 0.07), 16000)
    kept = tmp_path / "kept.csv"
    kept.write_text("an animation kept on purpose\n")
    kept.chmod(0o444)
    code = main(["predict", str(ridge_run), str(tmp_path / "voice.wav"), "-o", str(kept)])
    err = capsys.readouterr().err
    assert code == 1 and "Traceback" not in err, err
    assert err.strip().splitlines()[-1] == (
        f"s2a-train: error: {kept}: output CSV exists and is read-only (-r--r--r--): not replaced; "
        "make it writable or choose another -o"
    )
    assert kept.read_text() == "an animation kept on purpose\n"
    kept.chmod(0o644)  # writable: replaced by the prediction
    assert main(["predict", str(ridge_run), str(tmp_path / "voice.wav"), "-o", str(kept)]) == 0
    assert kept.read_text().startswith("Timecode,BlendShapeCount,")


def test_the_package_offers_its_names_as_before():
    # the functions named as their modules stay the functions, whichever is imported first
    code = (
        "import train.predict as m, train.fit, train\n"
        "from train import evaluate, compare\n"
        "assert callable(m) and callable(train.fit) and callable(evaluate) and callable(compare)\n"
        "assert all(hasattr(train, name) for name in train.__all__) and 'TransformerS2A' in dir(train)\n"
        "import dataset\n"
        "assert all(hasattr(dataset, name) for name in dataset.__all__)\n"
    )
    proc = run_python(code, timeout=120)
    assert proc.returncode == 0, proc.stderr
