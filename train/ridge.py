"""Ridge regression on stacked frames: the closed-form sanity floor of the model table.

Each output frame is a linear function of the inputs (content + prosody) of the ``context`` frames on
either side (zero outside the utterance). Fitted in one pass over the training split by accumulating
the normal equations of its usable values on standardised inputs (a channel glitched in some frames
is solved alone, without them); ``alpha`` is the L2 penalty
(per frame, on the correlation scale), chosen on the validation split from a grid when 0.
"""

from __future__ import annotations

import torch
from torch import nn

# A subtraction of sums leaves an input constant over the frames left with a variance of rounding (float64
# sums of every frame subtracted from) in place of 0: below this share of its mean square over those
# frames it counts as constant, and gets no weight, as when its sums were taken over the frames left.
ROUNDING = 1e-10


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
    """Running sums Σx, Σxxᵀ, Σxyᵀ, Σy over the usable values of ``add``, float64: over the frames usable
    in some channel (``rows``), and, for each channel unusable in some of those frames (a glitch in it
    alone), the same sums over those frames (``gaps``: that channel's, y its column), which its own
    solution leaves out. Memory: one Σxxᵀ, plus one per glitched channel."""

    def __init__(self, n_in: int, n_out: int):
        self.n = 0
        self.sx = torch.zeros(n_in, dtype=torch.float64)
        self.sy = torch.zeros(n_out, dtype=torch.float64)
        self.xx = torch.zeros(n_in, n_in, dtype=torch.float64)
        self.xy = torch.zeros(n_in, n_out, dtype=torch.float64)
        self.gaps: dict[int, NormalEquations] = {}
        self.subtracted_from: torch.Tensor | None = None  # Σx² (n_in,) of the sums ``minus`` took these from

    def add(self, x: torch.Tensor, y: torch.Tensor, usable: torch.Tensor) -> None:
        """Add the inputs ``x`` (..., n_in) and targets ``y`` (..., n_out) of the ``usable`` values: a
        frame mask (...) (usable in every channel) or a value mask (..., n_out) (the reader's
        ``values``)."""
        values = usable.reshape(-1, usable.shape[-1]) if usable.dim() == y.dim() else None
        m = usable.reshape(-1) if values is None else values.any(dim=1)
        x = x.reshape(-1, x.shape[-1])[m].double()
        y = y.reshape(-1, y.shape[-1])[m].double()
        self._add_rows(x, y)
        if values is None:
            return
        unusable = ~values[m]
        for c in unusable.any(dim=0).nonzero().flatten().tolist():
            gap = self.gaps.setdefault(c, NormalEquations(x.shape[1], 1))
            gap._add_rows(x[unusable[:, c]], y[unusable[:, c], c : c + 1])

    def _add_rows(self, x: torch.Tensor, y: torch.Tensor) -> None:
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
        for c in sorted({c for part in parts for c in part.gaps}):
            out.gaps[c] = cls.total([part.gaps[c] for part in parts if c in part.gaps])
        return out

    def minus(self, part: NormalEquations) -> NormalEquations:
        """These sums without the frames of ``part`` (a subset of them)."""
        out = NormalEquations(self.sx.numel(), self.sy.numel())
        for name in self.FIELDS:
            setattr(out, name, getattr(self, name) - getattr(part, name))
        out.subtracted_from = (
            self.xx.diagonal().clone() if self.subtracted_from is None else self.subtracted_from
        )
        for c, gap in self.gaps.items():
            left = gap.minus(part.gaps[c]) if c in part.gaps else gap
            if left.n:  # a glitch in the frames left out only: none left
                out.gaps[c] = left
        return out

    def channel(self, c: int) -> NormalEquations:
        """The sums of channel ``c``'s usable values alone (its glitched frames taken out)."""
        out = NormalEquations(self.sx.numel(), 1)
        out.n, out.sx, out.xx = self.n, self.sx, self.xx
        out.sy, out.xy = self.sy[c : c + 1], self.xy[:, c : c + 1]
        out.subtracted_from = self.subtracted_from
        gap = self.gaps.get(c)
        return out if gap is None else out.minus(gap)

    def means(self) -> torch.Tensor:
        """Each channel's mean over its usable values (0 for a channel without any)."""
        mean = self.sy / max(self.n, 1)
        for c in self.gaps:
            eq = self.channel(c)
            mean[c] = eq.sy[0] / eq.n if eq.n else 0.0
        return mean

    def solution(self, alpha: float) -> tuple[torch.Tensor, torch.Tensor]:
        """(weight (n_in, n_out), bias (n_out,)), float64, of the ridge on standardised inputs, intercept
        not penalised: ``(C + alpha·I) w = c_xy`` with C the inputs' correlation matrix (alpha is per
        frame); a glitched channel solved alone on its usable values (none: weight and bias 0)."""
        n = max(self.n, 1)
        mx, my = self.sx / n, self.sy / n
        cov = self.xx / n - torch.outer(mx, mx)
        cxy = self.xy / n - torch.outer(mx, my)
        if self.subtracted_from is not None:
            constant = cov.diagonal() <= ROUNDING * self.subtracted_from / n
            cov[constant], cov[:, constant], cxy[constant] = 0.0, 0.0, 0.0
        std = cov.diagonal().clamp(min=1e-12).sqrt()
        corr = cov / torch.outer(std, std)
        eye = torch.eye(len(std), dtype=torch.float64)
        w_std = torch.linalg.solve(corr + alpha * eye, cxy / std[:, None])
        w = w_std / std[:, None]
        bias = my - mx @ w
        for c in self.gaps:
            eq = self.channel(c)
            w[:, c : c + 1], bias[c : c + 1] = eq.solution(alpha) if eq.n else (0.0, 0.0)
        return w, bias

    def solve(self, model: Ridge, alpha: float) -> None:
        """Set ``model.linear`` to ``solution(alpha)``."""
        w, bias = self.solution(alpha)
        with torch.no_grad():
            model.linear.weight.copy_(w.T.float())
            model.linear.bias.copy_(bias.float())
