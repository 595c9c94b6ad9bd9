"""Ridge regression on stacked frames: the closed-form sanity floor of the model table.

Each output frame is a linear function of the inputs (content + prosody) of the ``context`` frames on
either side (zero outside the utterance). Fitted in one pass over the training split by accumulating
the normal equations on standardised inputs; ``alpha`` is the L2 penalty
(per frame, on the correlation scale), chosen on the validation split from a grid when 0.
"""

from __future__ import annotations

import torch
from torch import nn


def stack_frames(x: torch.Tensor, context: int) -> torch.Tensor:
    """(B, T, D) → (B, T, (2·context + 1)·D): frames t-context .. t+context side by side."""
    pad = torch.nn.functional.pad(x, (0, 0, context, context))
    return torch.cat([pad[:, k : k + x.shape[1]] for k in range(2 * context + 1)], dim=-1)


class Ridge(nn.Module):
    """The fitted regression as a module with the models' call signature."""

    def __init__(self, content_dim: int, prosody_dim: int, out_dim: int, context: int = 7):
        super().__init__()
        self.content_dim, self.prosody_dim, self.context = content_dim, prosody_dim, context
        n_in = (2 * context + 1) * (content_dim + prosody_dim)
        self.linear = nn.Linear(n_in, out_dim)

    def inputs(self, content: torch.Tensor, prosody: torch.Tensor | None, mask: torch.Tensor) -> torch.Tensor:
        """Stacked inputs (B, T, (2·context + 1)·D), zero at frames ``mask`` says are not there (the
        reader's ``present``: padding; unusable frames have real speech and stay)."""
        x = torch.cat([content, prosody], dim=-1) if self.prosody_dim else content
        return stack_frames(x * mask.unsqueeze(-1).to(x.dtype), self.context)

    def forward(self, content, prosody, mask):
        return self.linear(self.inputs(content, prosody, mask))


class NormalEquations:
    """Running sums Σx, Σxxᵀ, Σxyᵀ, Σy over the frames of ``add``'s mask (usable frames: the reader's
    ``mask``), float64."""

    def __init__(self, n_in: int, n_out: int):
        self.n = 0
        self.sx = torch.zeros(n_in, dtype=torch.float64)
        self.sy = torch.zeros(n_out, dtype=torch.float64)
        self.xx = torch.zeros(n_in, n_in, dtype=torch.float64)
        self.xy = torch.zeros(n_in, n_out, dtype=torch.float64)

    def add(self, x: torch.Tensor, y: torch.Tensor, mask: torch.Tensor) -> None:
        m = mask.reshape(-1)
        x = x.reshape(-1, x.shape[-1])[m].double()
        y = y.reshape(-1, y.shape[-1])[m].double()
        self.n += x.shape[0]
        self.sx += x.sum(0)
        self.sy += y.sum(0)
        self.xx += x.T @ x
        self.xy += x.T @ y

    FIELDS = ("n", "sx", "sy", "xx", "xy")

    @classmethod
    def total(cls, parts: list[NormalEquations]) -> NormalEquations:
        """The sums of several sets of frames (e.g. takes) together."""
        out = cls(parts[0].sx.numel(), parts[0].sy.numel())
        for part in parts:
            for name in cls.FIELDS:
                setattr(out, name, getattr(out, name) + getattr(part, name))
        return out

    def minus(self, part: NormalEquations) -> NormalEquations:
        """These sums without the frames of ``part`` (a subset of them)."""
        out = NormalEquations(self.sx.numel(), self.sy.numel())
        for name in self.FIELDS:
            setattr(out, name, getattr(self, name) - getattr(part, name))
        return out

    def solve(self, model: Ridge, alpha: float) -> None:
        """Set ``model.linear`` to the ridge solution on standardised inputs, intercept not penalised:
        ``(C + alpha·I) w = c_xy`` with C the inputs' correlation matrix (alpha is per frame)."""
        n = max(self.n, 1)
        mx, my = self.sx / n, self.sy / n
        cov = self.xx / n - torch.outer(mx, mx)
        cxy = self.xy / n - torch.outer(mx, my)
        std = cov.diagonal().clamp(min=1e-12).sqrt()
        corr = cov / torch.outer(std, std)
        eye = torch.eye(len(std), dtype=torch.float64)
        w_std = torch.linalg.solve(corr + alpha * eye, cxy / std[:, None])
        w = w_std / std[:, None]
        with torch.no_grad():
            model.linear.weight.copy_(w.T.float())
            model.linear.bias.copy_((my - mx @ w).float())
