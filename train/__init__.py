"""train: Transformer-S2A (MoE), its baselines, training, evaluation, prediction, export and the PPG
extractor's training. The command line is ``s2a-train`` (``train.cli``)."""

import os
import signal
import sys
import threading


def _stop_quietly(_signum, _frame) -> None:
    print("s2a-train: interrupted", file=sys.stderr, flush=True)
    os._exit(130)  # nothing has been written yet


def _run_as_the_command() -> bool:
    """Whether this process is the ``s2a-train`` command (its console script, or ``python -m train``),
    not a program that imports the package."""
    argv = getattr(sys, "argv", None) or [""]
    if os.path.basename(argv[0]) == "s2a-train":
        return True
    orig = getattr(sys, "orig_argv", None) or []  # the interpreter's own arguments (Python 3.10+)
    if "-m" in orig[:-1]:
        return orig[orig.index("-m") + 1].split(".")[0] == "train"
    return False


# PyTorch, numpy and scipy load below, in the first 2-3 s of every s2a-train command. Ctrl-C in the middle
# of them leaves a half-imported library whose errors follow (a RecursionError inside numpy, say), so the
# command stops at once instead; a program that imports the package keeps its own Ctrl-C.
_guard = (
    _run_as_the_command()
    and threading.current_thread() is threading.main_thread()
    and signal.getsignal(signal.SIGINT) is signal.default_int_handler
)
if _guard:
    signal.signal(signal.SIGINT, _stop_quietly)
try:
    from .checkpoint import load_checkpoint, load_system
    from .compare import compare
    from .config import DEFAULTS, MODELS, resolve_config
    from .data import InputSpec, resolve_inputs
    from .evaluate import ErrorTally, evaluate
    from .export import export_onnx
    from .fit import fit
    from .model import BLSTM, NVP, BLSTMConfig, NVPConfig, S2AConfig, TransformerS2A, masked_mse
    from .moe import MoELayer
    from .ppg_train import train_ppg
    from .predict import animate, predict
    from .ridge import Ridge
    from .systems import build_model
finally:
    if _guard and signal.getsignal(signal.SIGINT) is _stop_quietly:  # unless an import installed its own
        signal.signal(signal.SIGINT, signal.default_int_handler)

__all__ = [
    "BLSTM",
    "BLSTMConfig",
    "DEFAULTS",
    "ErrorTally",
    "InputSpec",
    "MODELS",
    "MoELayer",
    "NVP",
    "NVPConfig",
    "Ridge",
    "S2AConfig",
    "TransformerS2A",
    "animate",
    "build_model",
    "compare",
    "evaluate",
    "export_onnx",
    "fit",
    "load_checkpoint",
    "load_system",
    "masked_mse",
    "predict",
    "resolve_config",
    "resolve_inputs",
    "train_ppg",
]
