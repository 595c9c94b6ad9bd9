"""train: Transformer-S2A (MoE), its baselines, training, evaluation, prediction, export and the PPG
extractor's training. The command line is ``s2a-train`` (``train.cli``)."""

# capture, imported first, guards the imports of a stage command against Ctrl-C (capture.import_guard); the
# guard ends once the command's own module (cli.py) has imported, and each command guards its own imports.
import capture.import_guard  # noqa: F401  # isort: skip

from capture.lazy_package import lazy_package

# What the package offers and the module of each, imported on first use: ``import train.cli`` needs no
# PyTorch (1-2 s), so that ``s2a-train --help`` and usage errors answer at once.
__all__ = lazy_package(
    __name__,
    {
        "BLSTM": "model",
        "BLSTMConfig": "model",
        "DEFAULTS": "config",
        "ErrorTally": "evaluate",
        "InputSpec": "data",
        "MODELS": "config",
        "MoELayer": "moe",
        "NVP": "model",
        "NVPConfig": "model",
        "Ridge": "ridge",
        "S2AConfig": "model",
        "TransformerS2A": "model",
        "animate": "predict",
        "build_model": "systems",
        "compare": "compare",
        "evaluate": "evaluate",
        "export_onnx": "export",
        "fit": "fit",
        "load_checkpoint": "checkpoint",
        "load_system": "checkpoint",
        "masked_mse": "model",
        "model_audio": "predict",
        "normalize_features": "data",
        "predict": "predict",
        "resolve_config": "config",
        "resolve_inputs": "data",
        "train_ppg": "ppg_train",
    },
)
