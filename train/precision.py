"""Numeric precision of inference: ``fp32`` (the default) or ``bf16``.

``bf16`` runs a bfloat16 copy of the model (weights and activations; PyTorch's CPU kernels accumulate
matrix products, layer norms and softmaxes in float32) and returns float32. On a CPU with native
bfloat16 instructions (AVX512-BF16 or AMX; oneDNN reports them) the matrix products run about twice as
fast as in float32; elsewhere bfloat16 is emulated and slower, so it is refused there rather than
silently making inference slower. Training precision is the separate ``amp`` setting (docs/train.md).
"""

from __future__ import annotations

import copy

import torch

from capture.errors import InputError

from .choices import PRECISIONS

_DTYPES = {"fp32": torch.float32, "bf16": torch.bfloat16}


def bf16_is_native() -> bool:
    """Whether this machine's CPU computes bfloat16 matrix products in hardware."""
    try:
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):
        return False


def for_inference(model: torch.nn.Module, precision: str) -> torch.nn.Module:
    """``model`` itself for fp32; a bfloat16 copy for bf16 (the original keeps its float32 weights)."""
    if precision not in PRECISIONS:
        raise InputError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    if precision == "fp32":
        return model
    if not bf16_is_native():
        raise InputError("this CPU has no native bfloat16 arithmetic (AVX512-BF16 or AMX): use fp32")
    return copy.deepcopy(model).to(_DTYPES[precision])


def infer(model: torch.nn.Module, content: torch.Tensor, prosody: torch.Tensor | None, mask: torch.Tensor):
    """The model's float32 output for float32 inputs, whatever the model's own precision."""
    dtype = next(model.parameters()).dtype
    out = model(content.to(dtype), None if prosody is None else prosody.to(dtype), mask)
    return out.float()
