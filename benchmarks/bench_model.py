"""Transformer-S2A: the MoE layer's fused paths against a per-expert loop (inference at batch 1 on a
12 s utterance, and a training step at the training shape), and real-time factors of Transformer-S2A,
BLSTM and NVP on a 12 s utterance (CPU, batch 1), in float32 and, on CPUs with native bfloat16
arithmetic, in bfloat16 (train/precision.py).

The model's inference path (eval mode, no autograd: the MoE's ``routed`` path, attention without a
padding mask when every frame is real, ``torch.inference_mode``) is timed against the reference path
(the training code's dense MoE, the padding mask always passed) on the same weights and input; the
outputs are compared too.

Why no fused path can be 5x faster than the per-expert loop on a CPU: the loop already runs each expert
only on its routed frames with matrix products large enough for the BLAS (about 240 frames each), and
its 48 Python iterations cost well under a millisecond; a fused path can remove that overhead and the
gather copies, not the arithmetic. The dense path runs every expert on every frame, experts / top_k =
3 times the multiply-adds of the loop. The large wins of fusing are on GPUs, where the loop's many small
kernel launches dominate. Timings on a shared machine are noisy: every figure is the best of several
runs, and paths are timed interleaved."""

from __future__ import annotations

import os
import time
from collections.abc import Callable

import torch

from benchmarks.figure import Figure, best_time
from train import BLSTM, NVP, BLSTMConfig, NVPConfig, S2AConfig, TransformerS2A
from train.model import Block
from train.moe import MoELayer, expert_loop_reference
from train.precision import bf16_is_native, for_inference, infer

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


def reference_path(model: TransformerS2A, on: bool) -> None:
    """Switch ``model`` to the reference inference path (training MoE code, padding mask always
    passed) or back to its optimised one."""
    for m in model.modules():
        if isinstance(m, MoELayer):
            m.inference = "train" if on else "routed"
        if isinstance(m, Block):
            m.skip_full_mask = not on


def interleaved(runs: dict[str, Callable[[], torch.Tensor]], repeat: int):
    """({name: best seconds}, {name: output}) of several ways to compute one thing, each warmed up once
    and then timed in turn ``repeat`` times, so that load from other processes hits every way alike."""
    best = dict.fromkeys(runs, float("inf"))
    with torch.inference_mode():
        outs = {name: fn() for name, fn in runs.items()}
        for _ in range(repeat):
            for name, fn in runs.items():
                best[name] = min(best[name], best_time(fn, 1))
    return best, outs


def s2a_rtf_paths(c: S2AConfig, frames: int, repeat: int) -> tuple[float, float, float]:
    """(optimised RTF, reference RTF, largest output difference) of one model, timed interleaved."""
    model = TransformerS2A(c).eval()
    content, prosody = torch.randn(1, frames, 64), torch.randn(1, frames, 3)
    mask = torch.ones(1, frames, dtype=torch.bool)

    def on_path(reference: bool) -> torch.Tensor:
        reference_path(model, reference)
        return model(content, prosody, mask)

    best, outs = interleaved({"fast": lambda: on_path(False), "reference": lambda: on_path(True)}, repeat)
    reference_path(model, False)
    seconds = frames / FPS
    diff = float((outs["reference"] - outs["fast"]).abs().max())
    return best["fast"] / seconds, best["reference"] / seconds, diff


def s2a_bf16_rtf(c: S2AConfig, frames: int, repeat: int) -> tuple[float, float, float]:
    """(bf16 RTF, fp32 RTF, largest output difference relative to the output's largest magnitude) of
    one model's inference path, timed interleaved (call it on CPUs with native bfloat16 only)."""
    model = TransformerS2A(c).eval()
    half = for_inference(model, "bf16")
    content, prosody = torch.randn(1, frames, 64), torch.randn(1, frames, 3)
    mask = torch.ones(1, frames, dtype=torch.bool)
    models = {"fp32": model, "bf16": half}
    runs = {name: (lambda m=m: infer(m, content, prosody, mask)) for name, m in models.items()}
    best, outs = interleaved(runs, repeat)
    rel = float((outs["bf16"] - outs["fp32"]).abs().max() / outs["fp32"].abs().max())
    seconds = frames / FPS
    return best["bf16"] / seconds, best["fp32"] / seconds, rel


def s2a_multiply_adds(c: S2AConfig, frames: int) -> float:
    """Multiply-adds of one Transformer-S2A forward pass of ``frames`` frames at batch 1 on the inference
    path: every linear layer and projection, attention's two T x T products, and in the MoE only the
    top_k routed experts (a kernel_size-tap convolution and a linear each) plus the gate. Normalisation,
    activations, softmax and gathers are left out: they are not matrix products."""
    d = c.d_model
    attention = 4 * d * d  # query, key, value and output projections, per frame
    expert = c.expert_kernel * d * c.expert_hidden + c.expert_hidden * d
    per_frame = (
        c.content_dim * d
        + c.encoder_layers * (attention + 2 * d * c.ff_dim)
        + (d + c.prosody_dim) * d
        + c.decoder_layers * (attention + (d * c.experts + c.top_k * expert if c.moe else 2 * d * c.ff_dim))
        + d * c.out_dim
    )
    scores = (c.encoder_layers + c.decoder_layers) * 2 * frames * frames * d  # Q·Kᵀ and weights·V
    return float(per_frame * frames + scores)


def gemm_rate(c: S2AConfig, frames: int, repeat: int) -> float:
    """The best float32 multiply-adds per second of this CPU's matrix products at the model's largest
    shapes (the feed-forward's two products and the attention's input projection)."""
    best = 0.0
    for m, k, n in (
        (frames, c.d_model, c.ff_dim),
        (frames, c.ff_dim, c.d_model),
        (frames, c.d_model, 3 * c.d_model),
    ):
        a, b = torch.randn(m, k), torch.randn(k, n)
        a @ b
        best = max(best, m * k * n / best_time(lambda a=a, b=b: a @ b, repeat))
    return best


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
    paths = {
        "dense": ("dense", "train"),
        "sparse": ("sparse", "train"),
        "grouped": ("grouped", "train"),
        "routed": ("dense", "routed"),
    }
    times = dict.fromkeys([*paths, "loop"], float("inf"))
    with torch.inference_mode():
        for _ in range(repeat):  # interleaved: load from other processes hits every path alike
            for name, (mode, inference) in paths.items():
                layer.mode, layer.inference = mode, inference
                layer(h)
                times[name] = min(times[name], best_time(lambda: layer(h), 2))
            expert_loop_reference(layer, h)
            times["loop"] = min(times["loop"], best_time(lambda: expert_loop_reference(layer, h), 2))
    fused, sparse, grouped, routed, loop = (
        times[k] for k in ("dense", "sparse", "grouped", "routed", "loop")
    )
    train_times = training_step_times(c, 3 if quick else 5)
    s2a, s2a_reference, diff = s2a_rtf_paths(c, frames, repeat)
    macs, rate = s2a_multiply_adds(c, frames), gemm_rate(c, frames, 5 * repeat)
    floor = macs / rate / SECONDS
    half = s2a_bf16_rtf(c, frames, repeat) if bf16_is_native() else None
    blstm = rtf(BLSTM(BLSTMConfig()), frames, repeat)
    nvp = rtf(NVP(NVPConfig(window=9)), frames, repeat)
    threads = torch.get_num_threads()
    note = f"{frames} frames, {threads} threads, {time.strftime('%H:%M')}"
    return [
        *(
            Figure(f"MoE layer, {label}", t * 1e3, "ms", "per-expert loop", loop * 1e3, False, target, note)
            for label, t, target in (
                ("fused dense path", fused, 0.2),
                ("sparse dispatch", sparse, None),
                ("grouped routed frames", grouped, 0.2),
                ("routed inference path", routed, 0.2),
            )
        ),
        Figure("MoE layer, routed inference path vs dense", routed * 1e3, "ms", "dense", fused * 1e3, False),
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
        Figure(
            "Transformer-S2A RTF, arithmetic floor",
            floor,
            "s/s",
            "paper's P100 figure",
            0.005,
            False,
            None,
            f"{macs / 1e9:.2f} G multiply-adds at this CPU's best float32 matrix product rate, "
            f"{rate / 1e9:.0f} G/s; {note}",
        ),
        Figure("Transformer-S2A RTF vs its arithmetic floor", s2a, "s/s", "arithmetic floor", floor, False),
        Figure(
            "Transformer-S2A RTF, inference path",
            s2a,
            "s/s",
            "reference path",
            s2a_reference,
            False,
            None,
            f"{note}, max |difference| {diff:.1e}",
        ),
        *(
            [
                Figure(
                    "Transformer-S2A RTF, bf16",
                    half[0],
                    "s/s",
                    "paper's P100 figure",
                    0.005,
                    False,
                    1.0,
                    note,
                ),
                Figure(
                    "Transformer-S2A RTF, bf16 vs fp32",
                    half[0],
                    "s/s",
                    "fp32 RTF",
                    half[1],
                    False,
                    None,
                    f"{note}, max |bf16 - fp32| = {half[2]:.1%} of max |output|",
                ),
            ]
            if half
            else []
        ),
        Figure("Transformer-S2A RTF vs BLSTM", s2a, "s/s", "BLSTM RTF", blstm, False, None, note),
        Figure("Transformer-S2A RTF vs NVP-9", s2a, "s/s", "NVP-9 RTF", nvp, False, None, note),
    ]
