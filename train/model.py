"""Transformer-S2A (Chen et al., ICASSP 2022, Figure 2) and the baselines of its tables.

    PPG (B, T, ppg_dim) at the animation rate
      → input projection + sinusoidal positional encoding
      → content encoder (Transformer blocks)
      → concatenate prosody (pitch, energy) and project
      → expert decoder (Transformer blocks whose feed-forward is a MoE layer)
      → linear head → blendshapes (B, T, out_dim)

Sizes live in ``S2AConfig``; the paper's MoE settings (48 experts, top-16, Conv1d+Linear experts) are the
defaults, the rest (widths, depths) are ours where the paper is silent. Model code does no I/O.

Every model takes ``(content, prosody, mask)``; ``mask`` (B, T) is bool, True on real frames (0/1
integer or floating masks are converted, other values refused). A batch row with no real frame gives
zeros, and ``masked_mse`` ignores it. Real means the frame exists, not that its animation is a target:
from the reader, the model takes ``present`` (False on padding only) and the loss takes ``values``
(usable values, (B, T, channels)) or ``mask`` (usable frames), since the speech at a frame whose face
was lost is real and at inference every frame is seen.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

from .moe import MoELayer


@dataclass
class S2AConfig:
    """Sizes of Transformer-S2A. ``content_dim`` is the per-frame content input (64 for the PPG
    bottleneck, or the MFCC count for the MFCC ablation); ``prosody_dim`` 0 removes pitch and energy."""

    content_dim: int = 64
    prosody_dim: int = 3  # log-F0, voicing flag, energy
    out_dim: int = 32
    d_model: int = 256
    heads: int = 4
    encoder_layers: int = 3
    decoder_layers: int = 3
    ff_dim: int = 1024  # feed-forward width of the encoder and of the no-MoE ablation
    experts: int = 48
    top_k: int = 16
    expert_hidden: int = 64  # 48 experts x 64 = 3072 units; 16 active = the 1024 of a dense FFN
    expert_kernel: int = 3
    moe: bool = True
    moe_mode: str = "dense"  # or "sparse", "grouped" (same numbers; see moe.py)
    moe_inference: str = "routed"  # MoE path in eval mode without autograd: "routed" or "train"
    dropout: float = 0.1
    max_frames: int = 8192


def check_inputs(
    content: torch.Tensor, prosody: torch.Tensor | None, mask: torch.Tensor, prosody_dim: int
) -> torch.Tensor:
    """Clear errors for inputs the models cannot take; returns ``mask`` as bool (B, T).

    ``content`` (B, T, C) with T > 0; ``prosody`` (B, T, prosody_dim), or None when prosody_dim is 0;
    ``mask`` bool, or integer/floating holding only 0 and 1 (converted: nonzero = real frame). While
    tracing for export only the conversion runs (shapes are symbolic there)."""
    if torch.jit.is_tracing():
        return mask if mask.dtype == torch.bool else mask != 0
    if content.dim() != 3:
        raise ValueError(f"content must be (batch, frames, features), got shape {tuple(content.shape)}")
    b, t = content.shape[:2]
    if t == 0:
        raise ValueError("the input has no frames (T = 0): give at least one frame per sequence")
    if prosody_dim:
        if prosody is None:
            raise ValueError(
                f"this model was built with prosody_dim={prosody_dim}: give prosody (B, T, {prosody_dim}), "
                "not None (prosody_dim=0 builds a model without prosody)"
            )
        if tuple(prosody.shape) != (b, t, prosody_dim):
            raise ValueError(f"prosody must have shape {(b, t, prosody_dim)}, got {tuple(prosody.shape)}")
    if tuple(mask.shape) != (b, t):
        raise ValueError(f"mask must have shape {(b, t)} (batch, frames), got {tuple(mask.shape)}")
    if mask.dtype == torch.bool:
        return mask
    if mask.is_complex():
        raise TypeError(f"mask must be torch.bool (True on real frames), got {mask.dtype}")
    if bool(((mask != 0) & (mask != 1)).any()):
        raise ValueError(
            f"mask must be torch.bool (True on real frames) or hold only 0 and 1; this {mask.dtype} "
            "mask holds other values"
        )
    return mask != 0


# the most bytes of the position table a model computes when built (8192 x 256 floats, the default, is
# 8 MB): more is a mistyped max_frames, never a model (attention over that many frames would not fit)
MAX_TABLE_BYTES = 1 << 28


class PositionalEncoding(nn.Module):
    """Sinusoidal positions (Vaswani et al.) added to (B, T, d_model). A table past ``MAX_TABLE_BYTES``
    is refused before it is computed: one of max_frames 100,000,000 took 24 GB and 107 s of a 2-core
    machine until the kernel killed the process."""

    def __init__(self, d_model: int, max_frames: int):
        super().__init__()
        size = max_frames * d_model * torch.get_default_dtype().itemsize
        if size > MAX_TABLE_BYTES:
            raise ValueError(
                f"max_frames ({max_frames}) x d_model ({d_model}) makes the model compute {size} bytes of "
                f"tables when built, more than {MAX_TABLE_BYTES}: give a smaller max_frames"
            )
        pos = torch.arange(max_frames).unsqueeze(1)
        div = torch.exp(torch.arange(0, d_model, 2) * (-math.log(10000.0) / d_model))
        pe = torch.zeros(max_frames, d_model)
        pe[:, 0::2] = torch.sin(pos * div)
        pe[:, 1::2] = torch.cos(pos * div[: d_model // 2])
        self.register_buffer("pe", pe, persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.shape[1] > self.pe.shape[0]:
            raise ValueError(f"{x.shape[1]} frames exceed max_frames={self.pe.shape[0]}")
        return x + self.pe[: x.shape[1]]


class FeedForward(nn.Module):
    def __init__(self, d_model: int, ff_dim: int, dropout: float):
        super().__init__()
        self.net = nn.Sequential(
            nn.Linear(d_model, ff_dim), nn.GELU(), nn.Dropout(dropout), nn.Linear(ff_dim, d_model)
        )

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        return self.net(x)


class Block(nn.Module):
    """Pre-norm Transformer block: self-attention, then a feed-forward (plain or MoE)."""

    def __init__(self, d_model: int, heads: int, ff: nn.Module, dropout: float):
        super().__init__()
        self.norm1 = nn.LayerNorm(d_model)
        self.attn = nn.MultiheadAttention(d_model, heads, dropout=dropout, batch_first=True)
        self.norm2 = nn.LayerNorm(d_model)
        self.ff = ff
        self.drop = nn.Dropout(dropout)
        self.skip_full_mask = True  # False: always pass the padding mask (the reference path)

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        y = self.norm1(x)
        # No mask when every frame is real (batch-1 inference): the same numbers through the fused
        # attention kernel. Not while tracing for export, which must keep the mask input.
        skip = self.skip_full_mask and not torch.jit.is_tracing() and bool(mask.all())
        # A row with no real frame would leave attention nothing to attend to (NaN in the fused kernel):
        # it attends to all its frames instead (finite; the model zeroes that row's output).
        padding = None if skip else ~mask & mask.any(dim=1, keepdim=True)
        y, _ = self.attn(y, y, y, key_padding_mask=padding, need_weights=False)
        x = x + self.drop(y)
        return x + self.drop(self.ff(self.norm2(x), mask))


class TransformerS2A(nn.Module):
    """The paper's model; ``config.moe = False`` gives the no-MoE ablation."""

    def __init__(self, config: S2AConfig):
        super().__init__()
        c = self.config = config
        if c.heads < 1 or c.d_model % c.heads:
            raise ValueError(f"d_model ({c.d_model}) must be a multiple of heads ({c.heads})")
        self.content_in = nn.Linear(c.content_dim, c.d_model)
        self.positions = PositionalEncoding(c.d_model, c.max_frames)
        self.encoder = nn.ModuleList(
            Block(c.d_model, c.heads, FeedForward(c.d_model, c.ff_dim, c.dropout), c.dropout)
            for _ in range(c.encoder_layers)
        )
        self.prosody_in = nn.Linear(c.d_model + c.prosody_dim, c.d_model)
        self.decoder = nn.ModuleList(
            Block(c.d_model, c.heads, self._decoder_ff(), c.dropout) for _ in range(c.decoder_layers)
        )
        self.norm = nn.LayerNorm(c.d_model)
        self.head = nn.Linear(c.d_model, c.out_dim)
        self.drop = nn.Dropout(c.dropout)

    def _decoder_ff(self) -> nn.Module:
        c = self.config
        if not c.moe:
            return FeedForward(c.d_model, c.ff_dim, c.dropout)
        return MoELayer(
            c.d_model,
            c.expert_hidden,
            c.experts,
            c.top_k,
            c.expert_kernel,
            c.dropout,
            c.moe_mode,
            c.moe_inference,
        )

    def forward(
        self, content: torch.Tensor, prosody: torch.Tensor | None, mask: torch.Tensor
    ) -> torch.Tensor:
        """``content`` (B, T, content_dim), ``prosody`` (B, T, prosody_dim) or None when
        prosody_dim is 0, ``mask`` (B, T) bool, True on real frames → (B, T, out_dim); rows without
        a real frame give zeros."""
        mask = check_inputs(content, prosody, mask, self.config.prosody_dim)
        x = self.drop(self.positions(self.content_in(content)))
        for block in self.encoder:
            x = block(x, mask)
        if self.config.prosody_dim:
            x = torch.cat([x, prosody], dim=-1)
        x = self.prosody_in(x)
        for block in self.decoder:
            x = block(x, mask)
        return zero_empty_rows(self.head(self.norm(x)), mask)

    def aux_loss(self) -> torch.Tensor:
        """Sum of the MoE layers' load-balancing losses from the last forward pass."""
        losses = [m.aux_loss for m in self.modules() if isinstance(m, MoELayer)]
        return torch.stack(losses).sum() if losses else torch.zeros(())


@dataclass
class BLSTMConfig:
    content_dim: int = 64
    prosody_dim: int = 3
    out_dim: int = 32
    hidden: int = 128
    layers: int = 2
    dropout: float = 0.1


class BLSTM(nn.Module):
    """Sequence-level bidirectional LSTM baseline (Audio2Face-style, paper Table 1)."""

    def __init__(self, config: BLSTMConfig):
        super().__init__()
        c = self.config = config
        self.lstm = nn.LSTM(
            c.content_dim + c.prosody_dim,
            c.hidden,
            c.layers,
            batch_first=True,
            bidirectional=True,
            dropout=c.dropout if c.layers > 1 else 0.0,
        )
        self.head = nn.Linear(2 * c.hidden, c.out_dim)

    def forward(self, content, prosody, mask):
        mask = check_inputs(content, prosody, mask, self.config.prosody_dim)
        x = torch.cat([content, prosody], dim=-1) if self.config.prosody_dim else content
        x = x * mask.unsqueeze(-1).to(x.dtype)  # a frame inside a row that is not real reads as zeros
        # each row runs up to its last real frame (padding sits at the end of a row)
        positions = torch.arange(1, mask.shape[1] + 1, device=mask.device)
        lengths = (positions * mask).amax(dim=1).clamp(min=1).cpu()
        packed = nn.utils.rnn.pack_padded_sequence(x, lengths, batch_first=True, enforce_sorted=False)
        y, _ = self.lstm(packed)
        y, _ = nn.utils.rnn.pad_packed_sequence(y, batch_first=True, total_length=x.shape[1])
        return zero_empty_rows(self.head(y), mask)


@dataclass
class NVPConfig:
    content_dim: int = 64
    prosody_dim: int = 3
    out_dim: int = 32
    window: int = 9  # frames of context, centred (3 or 9 in the paper's table)
    hidden: int = 256
    dropout: float = 0.1


class NVP(nn.Module):
    """Frame-level sliding-window network (Audio2ExpressionNet / NVP style): each output frame sees only
    ``window`` input frames around it, through convolutions over time and a per-frame MLP."""

    def __init__(self, config: NVPConfig):
        super().__init__()
        c = self.config = config
        if c.window % 2 != 1:
            raise ValueError("window must be odd")
        dim = c.content_dim + c.prosody_dim
        self.window_conv = nn.Conv1d(dim, c.hidden, c.window, padding=c.window // 2)
        self.mlp = nn.Sequential(
            nn.GELU(),
            nn.Dropout(c.dropout),
            nn.Linear(c.hidden, c.hidden),
            nn.GELU(),
            nn.Linear(c.hidden, c.out_dim),
        )

    def forward(self, content, prosody, mask):
        mask = check_inputs(content, prosody, mask, self.config.prosody_dim)
        x = torch.cat([content, prosody], dim=-1) if self.config.prosody_dim else content
        x = x * mask.unsqueeze(-1).to(x.dtype)
        return zero_empty_rows(self.mlp(self.window_conv(x.transpose(1, 2)).transpose(1, 2)), mask)


def zero_empty_rows(out: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """``out`` (B, T, C) with the rows whose ``mask`` has no real frame set to zero."""
    return out.masked_fill(~mask.any(dim=1)[:, None, None], 0.0)


def masked_mse(
    pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor, weights: torch.Tensor | None = None
) -> torch.Tensor:
    """Mean squared error over the target values only: ``mask`` (B, T) True on usable frames (the
    reader's ``mask``, not the model's ``present``), or (B, T, channels) True on usable values (the
    reader's ``values``: a glitch in one channel leaves the frame's others); the mean is over the values
    it marks (a (B, T) mask gives the same numbers as that mask repeated in every channel). ``weights``
    (channels,) scales each channel's squared error. Whatever the padding holds (even NaN, or a row
    without a real frame) is ignored."""
    m = (mask.unsqueeze(-1) if mask.dim() == 2 else mask).to(pred.dtype).expand_as(pred)
    # padding zeroed before squaring: NaN there would otherwise reach the loss (NaN · 0) and the gradient
    se = torch.where(m != 0, pred - target, 0.0).square()
    if weights is not None:
        se = se * weights.to(se)
    return (se * m).sum() / m.sum().clamp(min=1)
