"""Ctrl-C while ``s2a-train fit`` starts, after the command's import guard is gone: PyTorch still imports
lazily then (``torch._dynamo``, 1 s, on the optimizer's first ``add_param_group``; TensorBoard's writer for
the metrics log). Ctrl-C in the middle of such an import is one line and exit code 130, and the same
command run again trains: the interrupted start-up leaves nothing in its way.

A timed SIGINT lands in these imports only now and then (a probe of 90 delays over the first 4 s hit
them in about a third); here the process sends itself SIGINT the moment the import begins, every run."""

from __future__ import annotations

import pytest
from conftest import run_here, run_python
from test_train_pipeline import TINY

# The command as pip's s2a-train script runs it, sending itself Ctrl-C (a real SIGINT, to whatever handler
# is installed) when the module named by its first argument starts importing.
CTRL_C_AT_IMPORT = """
import signal, sys
module = sys.argv.pop(1)

class CtrlCAt:
    def find_spec(self, name, path=None, target=None):
        if name == module:
            sys.meta_path.remove(self)
            signal.raise_signal(signal.SIGINT)
        return None

sys.meta_path.insert(0, CtrlCAt())
sys.argv[0] = "s2a-train"
from train.cli import main
sys.exit(main())
"""


@pytest.mark.parametrize(
    "module",
    [
        "torch._dynamo.convert_frame",  # halfway through torch._dynamo: the optimizer is being built
        "torch.utils.tensorboard",  # the metrics log opens its writer: config.json is written
    ],
)
def test_ctrl_c_while_fit_imports_pytorch_lazily_is_one_line_and_the_run_starts_again(ds, tmp_path, module):
    run = tmp_path / "run"
    fit = ["fit", "--data", str(ds), "--model", "s2a", "-o", str(run), "--max-steps", "2"]
    fit += [a for s in TINY for a in ("--set", s)]
    proc = run_python(CTRL_C_AT_IMPORT, module, *fit, timeout=300)
    lines = proc.stderr.splitlines()
    assert proc.returncode == 130, proc.stderr  # 0: the fit never imported the module (nothing tested)
    assert "Traceback" not in proc.stderr and lines[-1] == "s2a-train: interrupted", proc.stderr
    assert sum("interrupted" in line for line in lines) == 1 and proc.stdout == "", proc.stderr
    again = run_here("train", *fit)
    assert again.returncode == 0 and "Traceback" not in again.stderr, again.stderr
    assert (run / "last.pt").is_file()
