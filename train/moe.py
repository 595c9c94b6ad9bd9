"""The Mixture-of-Experts feed-forward layer of Transformer-S2A (paper §2.3, equation 3).

Each expert is a stride-1 Conv1d over time followed by a Linear: ``E_i(h) = W_i · act(conv_i(h))``.
A gating network scores the experts per frame, the top-k scores are kept, a softmax over the kept
scores gives ``Prob_i(h)``, and the output is ``Σ_i Prob_i(h) · E_i(h)`` (the paper writes ``G_i(h)``
where the expert output is meant).

No Python loop runs over experts. The dense path computes every expert with one convolution (all
experts' kernels stacked into one weight) and one grouped matrix product; the sparse path gathers, for
each expert, only the frames routed to it (im2col patches, padded to the busiest expert) and runs two
batched matrix products; the grouped path sorts the routed frames by expert and runs two grouped matrix
products (``torch._grouped_mm``, no padding). All give the same numbers.

Inference (eval mode, no autograd) takes the ``inference`` path, by default ``"routed"``: the routed
(frame, expert) pairs are sorted by expert, their convolution patches gathered straight from the input
rows (one index per tap) into a buffer reused from call to call (fresh 35 MB buffers cost page faults
that outweigh the saved arithmetic), and two grouped matrix products (``torch._grouped_mm``) run every
expert on its own frames; the experts' weights are rearranged once and cached until they change. Only
the routed arithmetic, no padding, no Python loop over experts (on PyTorch without ``_grouped_mm``, for
dtypes it cannot take (float64), or when d_model or the expert width is not a whole multiple of 16
bytes, which the grouped product needs: batched products padded to the busiest expert). Under
``torch.compile`` (whose grouped product takes bfloat16 only) and while tracing, the training path runs.
``inference = "train"`` keeps the training path. The same code runs in bfloat16 (train/precision.py).

One layer may run in several threads at once (a server's thread pool around one loaded model): the
scratch buffers belong to the calling thread (shared by all layers that thread runs, freed with the
thread), and the cached weights are rebuilt into fresh tensors and published in one assignment, so a
call never sees another call's half-written data. Neither is part of the state: deepcopy and pickle
drop the weight cache.
"""

from __future__ import annotations

import math
import threading

import torch
import torch.nn.functional as F
from torch import nn

# Per-thread scratch buffers of the routed inference path: {(name, dtype, device, inference): tensor}.
_SCRATCH = threading.local()

# Dtypes torch._grouped_mm takes (float64 and integer types go through batched products instead).
_GROUPED_DTYPES = (torch.float32, torch.bfloat16, torch.float16)


class MoELayer(nn.Module):
    """``experts`` Conv1d+Linear experts of hidden width ``hidden``, ``top_k`` kept per frame.

    Input and output are (batch, frames, d_model). ``mode`` is "dense", "sparse" or "grouped" (see
    module doc).
    After a forward pass, ``aux_loss`` holds the load-balancing loss (Switch Transformer form: experts x
    Σ fraction-routed · mean-probability, over the real frames of ``mask``), 0 when ``top_k == experts``.
    """

    def __init__(
        self,
        d_model: int,
        hidden: int,
        experts: int = 48,
        top_k: int = 16,
        kernel_size: int = 3,
        dropout: float = 0.0,
        mode: str = "dense",
        inference: str = "routed",
    ):
        super().__init__()
        if not 1 <= top_k <= experts:
            raise ValueError(f"top_k must be in 1..{experts}, got {top_k}")
        if mode not in ("dense", "sparse", "grouped"):
            raise ValueError(f"mode must be dense, sparse or grouped, got {mode!r}")
        if inference not in ("routed", "train"):
            raise ValueError(f"inference must be routed or train, got {inference!r}")
        if mode == "grouped" and not hasattr(torch, "_grouped_mm"):
            raise ValueError("mode 'grouped' needs torch._grouped_mm (PyTorch 2.8 or later)")
        if kernel_size % 2 != 1:
            raise ValueError("kernel_size must be odd so that frames stay aligned")
        self.d_model, self.hidden, self.experts, self.top_k = d_model, hidden, experts, top_k
        self.kernel_size = kernel_size
        self.mode = mode
        self.inference = inference
        self._cache: dict[str, tuple] = {}  # inference: rearranged weights (see _weights)
        self.gate = nn.Linear(d_model, experts)
        # All experts' convolutions as one Conv1d: output channels grouped by expert.
        self.conv = nn.Conv1d(d_model, experts * hidden, kernel_size, padding=kernel_size // 2)
        # All experts' linears as one grouped weight: (experts, hidden, d_model).
        self.linear_weight = nn.Parameter(torch.empty(experts, hidden, d_model))
        self.linear_bias = nn.Parameter(torch.zeros(experts, d_model))
        nn.init.kaiming_uniform_(self.linear_weight.view(experts * hidden, d_model).T, a=5**0.5)
        self.dropout = nn.Dropout(dropout)
        self.aux_loss = torch.zeros(())

    def __getstate__(self) -> dict:
        """Deepcopy and pickle leave the weight cache behind (rebuilt on the first call)."""
        state = super().__getstate__().copy()
        state["_cache"] = {}
        return state

    def __setstate__(self, state: dict) -> None:
        super().__setstate__(state)
        self._cache = {}  # pickles of older versions held scratch buffers here
        self.__dict__.pop("_cache_key", None)

    def route(self, h: torch.Tensor, mask: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Top-k expert indices (B, T, k) and their probabilities (softmax over the kept scores). In
        training, the balance loss averages over the frames where ``mask`` (B, T) is true (all frames
        without a mask; 0 when no frame is real)."""
        scores = self.gate(h)
        top_scores, top_idx = scores.topk(self.top_k, dim=-1)
        probs = top_scores.softmax(dim=-1)
        if self.training and self.top_k < self.experts:
            routed = F.one_hot(top_idx, self.experts).sum(dim=-2).float()  # (B, T, E)
            all_probs = scores.softmax(dim=-1)
            if mask is None:
                fraction = routed.mean(dim=(0, 1)) / self.top_k
                mean_prob = all_probs.mean(dim=(0, 1))
            else:
                real = (mask != 0).unsqueeze(-1)
                frames = real.sum().clamp(min=1)
                fraction = torch.where(real, routed, 0.0).sum(dim=(0, 1)) / (frames * self.top_k)
                mean_prob = torch.where(real, all_probs, 0.0).sum(dim=(0, 1)) / frames
            self.aux_loss = self.experts * (fraction * mean_prob).sum()
        else:
            self.aux_loss = scores.new_zeros(())
        return top_idx, probs

    def forward(self, h: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        """``h`` (B, T, d_model); ``mask`` (B, T) True (or 1) where frames are real (padding is zeroed
        first, so it cannot leak into neighbours through the convolution)."""
        tracing = torch.jit.is_tracing()  # shapes are symbolic there: no checks on them
        if mask is not None:
            if not tracing and mask.shape != h.shape[:2]:
                raise ValueError(f"mask must have shape {tuple(h.shape[:2])} (B, T), got {tuple(mask.shape)}")
            h = h * mask.unsqueeze(-1).to(h.dtype)
        if not tracing and h.shape[0] * h.shape[1] == 0:
            return h * 0.0  # no frames: nothing to route (keeps the graph for autograd)
        top_idx, probs = self.route(h, mask)
        if (
            self.inference == "routed"
            and not self.training
            and not torch.is_grad_enabled()
            and not tracing
            and not torch.compiler.is_compiling()
        ):
            return self._routed(h, top_idx, probs)
        if self.mode == "sparse":
            return self._sparse(h, top_idx, probs)
        if self.mode == "grouped":
            return self._grouped(h, top_idx, probs)
        return self._dense(h, top_idx, probs)

    def _dense(self, h: torch.Tensor, top_idx: torch.Tensor, probs: torch.Tensor) -> torch.Tensor:
        b, t, _ = h.shape
        weights = torch.zeros(b, t, self.experts, dtype=probs.dtype, device=h.device)
        weights.scatter_(-1, top_idx, probs)  # Prob_i(h), zero outside the top k
        inner = F.gelu(self.conv(h.transpose(1, 2)))  # every expert's conv at once: (B, E*H, T)
        inner = self.dropout(inner).view(b, self.experts, self.hidden, t)
        # Weighting before the linears turns the sum over experts into one matrix product.
        inner = inner * weights.permute(0, 2, 1).unsqueeze(2)
        inner = inner.permute(0, 3, 1, 2).reshape(b, t, self.experts * self.hidden)
        flat_w = self.linear_weight.reshape(self.experts * self.hidden, self.d_model)
        return inner @ flat_w + weights @ self.linear_bias

    def _sparse(self, h: torch.Tensor, top_idx: torch.Tensor, probs: torch.Tensor) -> torch.Tensor:
        b, t, d = h.shape
        k, e = self.kernel_size, self.experts
        patches = im2col(h, k)
        expert = top_idx.reshape(-1)  # (B*T*k_top,)
        frame = torch.arange(b * t, device=h.device).repeat_interleave(self.top_k)
        prob = probs.reshape(-1)
        order = torch.argsort(expert, stable=True)
        expert, frame, prob = expert[order], frame[order], prob[order]
        counts = torch.bincount(expert, minlength=e)
        capacity = int(counts.max())
        # Slot of each routed frame inside its expert's batch.
        starts = torch.cumsum(counts, 0) - counts
        slot = torch.arange(expert.numel(), device=h.device) - starts[expert]
        batch = h.new_zeros(e, capacity, d * k)
        batch[expert, slot] = patches[frame]
        w_conv = self.conv.weight.view(e, self.hidden, d * k).transpose(1, 2)  # (E, d*k, H)
        b_conv = self.conv.bias.view(e, 1, self.hidden)
        inner = self.dropout(F.gelu(torch.bmm(batch, w_conv) + b_conv))  # (E, C, H)
        out = torch.bmm(inner, self.linear_weight) + self.linear_bias.unsqueeze(1)  # (E, C, D)
        picked = out[expert, slot] * prob.unsqueeze(-1)
        result = picked.new_zeros(b * t, d).index_add_(0, frame, picked)  # under autocast: float32
        return result.view(b, t, d)

    def _grouped(self, h: torch.Tensor, top_idx: torch.Tensor, probs: torch.Tensor) -> torch.Tensor:
        """Only the routed frames, sorted by expert, through two grouped matrix products (one kernel
        each for all experts, no padding): the dense path's FLOPs divided by experts / top_k. Computed
        in ``h``'s dtype (bfloat16 under autocast); widths the grouped product cannot take (rows not
        whole multiples of 16 bytes) go through the sparse path, which gives the same numbers."""
        if not self._grouped_fits(h.dtype):
            return self._sparse(h, top_idx, probs)
        b, t, d = h.shape
        k, e, dt = self.kernel_size, self.experts, h.dtype
        patches = im2col(h, k)
        expert = top_idx.reshape(-1)
        order = torch.argsort(expert, stable=True)
        expert = expert[order]
        frame = order // self.top_k
        prob = probs.reshape(-1)[order].to(dt)
        offsets = torch.cumsum(torch.bincount(expert, minlength=e), 0).to(torch.int32)
        w_conv = self.conv.weight.view(e, self.hidden, d * k).transpose(1, 2).to(dt)  # (E, d*k, H)
        inner = torch._grouped_mm(patches[frame], w_conv, offs=offsets)
        inner = self.dropout(F.gelu(inner + self.conv.bias.view(e, self.hidden)[expert].to(dt)))
        out = torch._grouped_mm(inner, self.linear_weight.to(dt), offs=offsets)
        out = out + self.linear_bias[expert].to(dt)
        return h.new_zeros(b * t, d).index_add_(0, frame, out * prob.unsqueeze(-1)).view(b, t, d)

    def _weights(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The convolution as (E, k*d, H) in tap-major order and its bias (E, 1, H), cached while the
        parameters are unchanged (same storage and version counter). Safe in concurrent calls: a
        rebuild makes fresh tensors and publishes them with their key in one dict assignment."""
        w, b = self.conv.weight, self.conv.bias
        # parameters made under inference_mode have no version counter: rearranged on every call
        key = (
            ()
            if w.is_inference()
            else (w.data_ptr(), w._version, b.data_ptr(), b._version, w.dtype, w.device)
        )
        entry = self._cache.get("weights")
        if not key or entry is None or entry[0] != key:
            e, hid, d, k = self.experts, self.hidden, self.d_model, self.kernel_size
            w_conv = w.detach().view(e, hid, d, k).permute(0, 3, 2, 1).reshape(e, k * d, hid)
            entry = (key, w_conv, b.detach().view(e, 1, hid).clone())
            if key:
                self._cache["weights"] = entry
        return entry[1], entry[2]

    def _grouped_fits(self, dtype: torch.dtype) -> bool:
        """Whether ``torch._grouped_mm`` exists and takes this layer's weights: a dtype it supports
        (float32, bfloat16, float16), rows (hidden and d_model values) that are whole multiples of 16
        bytes, and not while ``torch.compile`` traces (its grouped product takes bfloat16 only)."""
        size = dtype.itemsize
        return (
            hasattr(torch, "_grouped_mm")
            and dtype in _GROUPED_DTYPES
            and (self.hidden * size) % 16 == 0
            and (self.d_model * size) % 16 == 0
            and not torch.compiler.is_compiling()
        )

    def _row_width(self, dtype: torch.dtype) -> int:
        """d_model plus a column of ones, padded to a multiple of 16 bytes (the grouped product wants
        16-byte strides): 4 float32 or 8 bfloat16 values."""
        per = max(1, 16 // dtype.itemsize)
        return self.d_model + per - self.d_model % per

    def _weights_with_bias(self) -> torch.Tensor:
        """The convolution as (E, k*width, H): per tap the d input weights, then rows for the column of
        ones (the bias on the centre tap) and the zero padding columns; cached like ``_weights``."""
        w_conv, b_conv = self._weights()
        entry = self._cache.get("wb")
        if entry is None or entry[0] is not w_conv:
            e, hid, d, k = self.experts, self.hidden, self.d_model, self.kernel_size
            width = self._row_width(w_conv.dtype)
            wb = w_conv.new_zeros(e, k, width, hid)
            wb[:, :, :d] = w_conv.view(e, k, d, hid)
            wb[:, k // 2, d] = b_conv.view(e, hid)
            entry = (w_conv, wb.view(e, k * width, hid))
            self._cache["wb"] = entry  # published whole, after it is complete
        return entry[1]

    @staticmethod
    def _buffer(name: str, shape: tuple[int, ...], like: torch.Tensor) -> torch.Tensor:
        """A scratch tensor of at least ``shape``'s size, reused from call to call by the calling thread
        only (grown when needed): concurrent calls in other threads get their own."""
        n = math.prod(shape)
        pool = getattr(_SCRATCH, "pool", None)
        if pool is None:
            pool = _SCRATCH.pool = {}
        # inference tensors and normal ones follow different in-place rules: kept apart
        key = (name, like.dtype, like.device, torch.is_inference_mode_enabled())
        buf = pool.get(key)
        if buf is None or buf.numel() < n:
            buf = pool[key] = torch.empty(n, dtype=like.dtype, device=like.device)
        return buf[:n].view(shape)

    def _routed(self, h: torch.Tensor, top_idx: torch.Tensor, probs: torch.Tensor) -> torch.Tensor:
        """Inference: each expert on its routed frames only (see module doc)."""
        b, t, d = h.shape
        k, e, pad = self.kernel_size, self.experts, self.kernel_size // 2
        n = b * t
        # Rows of every utterance with `pad` zero rows on both sides, plus one zero row at the very
        # end: row of frame (i, j) is i*(t+2p) + j + p.
        stride = t + 2 * pad
        rows = self._buffer("rows", (b * stride + 1, d), h)
        rows.zero_()
        rows[: b * stride].view(b, stride, d)[:, pad : pad + t] = h
        zero_row = b * stride
        expert = top_idx.reshape(-1)
        order = torch.argsort(expert, stable=True)
        sorted_expert = expert[order]
        frame = order // self.top_k
        prob = probs.reshape(-1)[order].unsqueeze(-1)
        counts = torch.bincount(sorted_expert, minlength=e)
        centre = (frame // t) * stride + frame % t + pad  # row of each routed frame
        taps = torch.arange(-pad, pad + 1, device=h.device)
        if self._grouped_fits(h.dtype):
            # routed (frame, expert) pairs sorted by expert: two grouped matrix products, no padding.
            # The convolution bias rides on a column of ones (its weight row sits on the centre tap),
            # the linear bias is added per frame as Σ_i Prob_i · b_i: no per-pair bias gathers.
            m, width = order.numel(), self._row_width(h.dtype)
            rows1 = self._buffer("rows1", (rows.shape[0], width), h)
            rows1[:, :d] = rows
            rows1[:, d:] = 0.0
            rows1[:, d] = 1.0
            patches = self._buffer("patches", (m * k, width), h)
            torch.index_select(rows1, 0, (centre.unsqueeze(-1) + taps).reshape(-1), out=patches)
            offsets = torch.cumsum(counts, 0).to(torch.int32)
            w = self._weights_with_bias()
            inner = F.gelu(torch._grouped_mm(patches.view(m, k * width), w, offs=offsets))
            out = torch._grouped_mm(inner, self.linear_weight, offs=offsets).mul_(prob)
            dense_probs = h.new_zeros(n, e).scatter_(1, top_idx.reshape(n, -1), probs.reshape(n, -1))
            return (dense_probs @ self.linear_bias).index_add_(0, frame, out).view(b, t, d)
        # older PyTorch, or unaligned widths: experts' batches padded to the busiest one (slots on the
        # zero row, weight 0)
        capacity = int(counts.max())
        slot = (
            torch.arange(order.numel(), device=h.device) - (torch.cumsum(counts, 0) - counts)[sorted_expert]
        )
        index = torch.full((e, capacity), zero_row, dtype=torch.long, device=h.device)
        index[sorted_expert, slot] = centre
        weight = h.new_zeros(e, capacity, 1)
        weight[sorted_expert, slot] = prob
        tap_index = torch.where((index == zero_row).unsqueeze(-1), zero_row, index.unsqueeze(-1) + taps)
        patches = self._buffer("patches", (e * capacity * k, d), h)
        torch.index_select(rows, 0, tap_index.reshape(-1), out=patches)
        w_conv, b_conv = self._weights()
        inner = F.gelu(torch.baddbmm(b_conv, patches.view(e, capacity, k * d), w_conv))
        out = torch.baddbmm(self.linear_bias.unsqueeze(1), inner, self.linear_weight).mul_(weight)
        target = torch.full((e, capacity), n, dtype=torch.long, device=h.device)  # padding → spare row
        target[sorted_expert, slot] = frame
        result = h.new_zeros(n + 1, d).index_add_(0, target.view(-1), out.view(-1, d))
        return result[:n].view(b, t, d)


def im2col(h: torch.Tensor, k: int) -> torch.Tensor:
    """Each frame's receptive field of a centred kernel of ``k`` as one row: (B, T, D) -> (B*T, D*k),
    in Conv1d's weight layout (channel-major, then tap), zeros past the ends."""
    b, t, d = h.shape
    padded = F.pad(h.transpose(1, 2), (k // 2, k // 2))  # (B, D, T+k-1)
    return padded.unfold(2, k, 1).permute(0, 2, 1, 3).reshape(b * t, d * k)


def expert_loop_reference(layer: MoELayer, h: torch.Tensor) -> torch.Tensor:
    """The MoE output computed the naive way: a Python loop over experts, each run on the frames routed
    to it (with their convolution context). Only for tests and for the benchmark that shows what fusing
    saves; the model never calls it."""
    top_idx, probs = layer.route(h)
    b, t, d = h.shape
    k = layer.kernel_size
    patches = im2col(h, k)
    flat_idx, flat_prob = top_idx.reshape(b * t, -1), probs.reshape(b * t, -1)
    conv_w = layer.conv.weight.view(layer.experts, layer.hidden, d * k)
    conv_b = layer.conv.bias.view(layer.experts, layer.hidden)
    out = h.new_zeros(b * t, d)
    for i in range(layer.experts):
        frames, slot = (flat_idx == i).nonzero(as_tuple=True)
        if frames.numel() == 0:
            continue
        inner = F.gelu(patches[frames] @ conv_w[i].T + conv_b[i])
        expert_out = inner @ layer.linear_weight[i] + layer.linear_bias[i]
        out.index_add_(0, frames, expert_out * flat_prob[frames, slot].unsqueeze(-1))
    return out.view(b, t, d)
