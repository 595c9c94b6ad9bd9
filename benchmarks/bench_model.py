"""Transformer-S2A: the MoE layer's fused paths against a per-expert loop (inference at batch 1 on a
12 s utterance, and a training step at the training shape), and real-time factors of Transformer-S2A,
BLSTM and NVP on a 12 s utterance (CPU, batch 1).

Why the dense path cannot beat the loop on a CPU: it runs every expert on every frame, experts / top_k
= 3 times the multiply-adds of the loop, which runs each expert only on its routed frames; the loop's
48 Python iterations cost well under a millisecond next to that. The grouped path does the loop's
arithmetic in two grouped matrix products without Python iterations or padding, so on a CPU it can only
save the loop's small overhead; the large wins of fusing are on GPUs, where the loop's many small
kernel launches dominate."""

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


TRAIN_BATCH, TRAIN_FRAMES = 16, 240  # the default training batch (fit: batch_size 16, window 240)


def training_step_times(c: S2AConfig, repeat: int) -> dict[str, float]:
    """Seconds of one forward + backward pass of the MoE layer at the training shape, per path."""
    layer = MoELayer(c.d_model, c.expert_hidden, c.experts, c.top_k, c.expert_kernel).train()
    h = torch.randn(TRAIN_BATCH, TRAIN_FRAMES, c.d_model, requires_grad=True)
    out = {}
    for mode in ("dense", "grouped", "loop"):
        layer.mode = "dense" if mode == "loop" else mode

        def step(mode=mode):
            y = expert_loop_reference(layer, h) if mode == "loop" else layer(h)
            y.square().mean().backward()

        step()
        out[mode] = best_time(step, repeat)
    return out


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
        times = {}
        for mode in ("dense", "sparse", "grouped"):
            layer.mode = mode
            layer(h)
            times[mode] = best_time(lambda: layer(h), repeat)
        expert_loop_reference(layer, h)
        loop = best_time(lambda: expert_loop_reference(layer, h), repeat)
    fused, sparse, grouped = times["dense"], times["sparse"], times["grouped"]
    train_times = training_step_times(c, 3 if quick else 5)
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
        Figure(
            "MoE layer, grouped routed frames",
            grouped * 1e3,
            "ms",
            "per-expert loop",
            loop * 1e3,
            False,
            0.2,
            note,
        ),
        *(
            Figure(
                f"MoE training step ({TRAIN_BATCH}x{TRAIN_FRAMES}), {mode}",
                train_times[mode] * 1e3,
                "ms",
                "per-expert loop",
                train_times["loop"] * 1e3,
                False,
                None,
                "forward + backward",
            )
            for mode in ("dense", "grouped")
        ),
        Figure("Transformer-S2A RTF", s2a, "s/s", "paper's P100 figure", 0.005, False, 1.0, note),
        Figure("Transformer-S2A RTF vs BLSTM", s2a, "s/s", "BLSTM RTF", blstm, False, None, note),
        Figure("Transformer-S2A RTF vs NVP-9", s2a, "s/s", "NVP-9 RTF", nvp, False, None, note),
    ]
