"""train: Transformer-S2A (MoE), its baselines, training, evaluation, prediction, export and the PPG
extractor's training. The command line is ``s2a-train`` (``train.cli``)."""

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
