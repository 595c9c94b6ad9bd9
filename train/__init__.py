"""train: Transformer-S2A (MoE), its baselines, training, evaluation, prediction, export and the PPG
extractor's training. The command line is ``s2a-train`` (``train.cli``)."""

# capture, imported first, guards the imports of a stage command against Ctrl-C (capture.import_guard):
# PyTorch, numpy and scipy load below, in the first 2-3 s of every s2a-train command. The guard ends once
# the command's own module (cli.py) has imported.
import capture.import_guard  # noqa: F401  # isort: skip

from .checkpoint import load_checkpoint, load_system
from .compare import compare
from .config import DEFAULTS, MODELS, resolve_config
from .data import InputSpec, normalize_features, resolve_inputs
from .evaluate import ErrorTally, evaluate
from .export import export_onnx
from .fit import fit
from .model import BLSTM, NVP, BLSTMConfig, NVPConfig, S2AConfig, TransformerS2A, masked_mse
from .moe import MoELayer
from .ppg_train import train_ppg
from .predict import animate, model_audio, predict
from .ridge import Ridge
from .systems import build_model

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
    "model_audio",
    "normalize_features",
    "predict",
    "resolve_config",
    "resolve_inputs",
    "train_ppg",
]
