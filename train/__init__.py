"""train: Transformer-S2A (MoE), its baselines, training, evaluation and export."""

from .model import BLSTM, NVP, BLSTMConfig, NVPConfig, S2AConfig, TransformerS2A, masked_mse
from .moe import MoELayer

__all__ = [
    "BLSTM",
    "BLSTMConfig",
    "MoELayer",
    "NVP",
    "NVPConfig",
    "S2AConfig",
    "TransformerS2A",
    "masked_mse",
]
