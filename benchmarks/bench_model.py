"""Transformer-S2A inference: the fused MoE layer against a per-expert loop, and real-time factors of
Transformer-S2A, BLSTM and NVP on a 12 s utterance (CPU, batch 1)."""

from __future__ import annotations

import os
import time

import torch

from benchmarks.figure import Figure, best_time
from train import BLSTM, NVP, BLSTMConfig, NVPConfig, S2AConfig, TransformerS2A
from train.moe import MoELayer, expert_loop_reference

SECONDS = 12.0
FPS = 60


def rtf(model: torch.nn.Module, frames: int, repeat: int) -> float:
    """Seconds of compute per second of animation."""
    content = torch.randn(1, frames, 64)
    prosody = torch.randn(1, frames, 3)
    mask = torch.ones(1, frames, dtype=torch.bool)
    model.eval()
    with torch.inference_mode():
        model(content, prosody, mask)  # warm-up
        return best_time(lambda: model(content, prosody, mask), repeat) / (frames / FPS)


def run(quick: bool = False) -> list[Figure]:
    torch.manual_seed(0)
    # Other stages pin torch to one thread for bit-identical features; inference uses every core.
    torch.set_num_threads(os.cpu_count() or 1)
    frames = int(SECONDS * FPS)
    repeat = 3 if quick else 10
    c = S2AConfig()
    layer = MoELayer(c.d_model, c.expert_hidden, c.experts, c.top_k, c.expert_kernel).eval()
    h = torch.randn(1, frames, c.d_model)
    with torch.inference_mode():
        layer(h)
        fused = best_time(lambda: layer(h), repeat)
        layer.mode = "sparse"
        layer(h)
        sparse = best_time(lambda: layer(h), repeat)
        expert_loop_reference(layer, h)
        loop = best_time(lambda: expert_loop_reference(layer, h), repeat)
    s2a = rtf(TransformerS2A(c), frames, repeat)
    blstm = rtf(BLSTM(BLSTMConfig()), frames, repeat)
    nvp = rtf(NVP(NVPConfig(window=9)), frames, repeat)
    threads = torch.get_num_threads()
    note = f"{frames} frames, {threads} threads, {time.strftime('%H:%M')}"
    return [
        Figure(
            "MoE layer, fused dense path", fused * 1e3, "ms", "per-expert loop", loop * 1e3, False, 0.2, note
        ),
        Figure(
            "MoE layer, sparse dispatch", sparse * 1e3, "ms", "per-expert loop", loop * 1e3, False, None, note
        ),
        Figure("Transformer-S2A RTF", s2a, "s/s", "paper's P100 figure", 0.005, False, 1.0, note),
        Figure("Transformer-S2A RTF vs BLSTM", s2a, "s/s", "BLSTM RTF", blstm, False, None, note),
        Figure("Transformer-S2A RTF vs NVP-9", s2a, "s/s", "NVP-9 RTF", nvp, False, None, note),
    ]
