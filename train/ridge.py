"""Ridge regression on stacked frames: the closed-form sanity floor of the model table.

Each output frame is a linear function of the inputs (content + prosody) of the ``context`` frames on
either side (zero outside the utterance). Fitted in one pass over the training split by accumulating
the normal equations of its usable values on standardised inputs (a channel glitched in some frames
is solved alone, without them); ``alpha`` is the L2 penalty
(per frame, on the correlation scale), chosen on the validation split from a grid when 0.
"""

from __future__ import annotations

import copy
import os

import torch
from torch import nn

from capture.errors import InputError

# An input constant over the frames summed is left with a variance of rounding in place of 0: that of its
# float64 sums over those frames (Σx²/n less the squared mean), or of every frame's when the sums were
# taken by subtraction. A variance below this share of its Σx² (over every frame subtracted from, if so)
# per frame summed counts as constant, and the input gets no weight: rounding is ~1e-13 of it over 2
# million frames; an input varying by less than ~1e-5 of its root mean square (5 ± 5e-5) counts as
# constant too (the toolkit's inputs are z-scored over the training split: a mean square of about 1).
ROUNDING = 1e-10

# The sums' memory: input-by-input float64 matrices (Σxxᵀ), one per set of sums, besides which a solution
# works in up to SOLVING more (a channel's sums taken by subtraction, covariance, correlation, identity,
# system, its factors). The budget: MEMORY_SHARE of the memory available when the sums start.
SOLVING = 7
MEMORY_SHARE = 0.8
ADVICE = "use a smaller ridge_context, fewer channels (s2a-dataset build --channels), or more memory"

ALPHAS = (1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0)  # ridge_alpha 0: the grid val chooses from


def available_memory() -> int | None:
    """Bytes of memory available: /proc/meminfo's MemAvailable (Linux), else the physical memory
    (os.sysconf); None where neither tells."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, AttributeError):
        return None


def _gb(size: float) -> str:
    return f"{size / 1e9:.2f} GB"


class Memory:
    """The memory sets of sums may hold together (those of a fit; agreement's takes): ``budget`` bytes
    (default MEMORY_SHARE of ``available_memory()``; None: no limit), counted in input-by-input matrices."""

    def __init__(self, budget: int | None = None):
        if budget is None and (available := available_memory()) is not None:
            budget = int(MEMORY_SHARE * available)
        self.budget = budget
        self.held = 0  # matrices

    def check(self, n_in: int, matrices: int, what: str) -> None:
        """An ``InputError`` if ``matrices`` more, beside those held and a solution's, pass the budget."""
        count = self.held + matrices + SOLVING
        need = count * 8 * n_in * n_in
        if self.budget is not None and need > self.budget:
            raise InputError(
                f"{what} need {_gb(need)} of memory ({count} matrices of {n_in:,} x {n_in:,} inputs, "
                f"{_gb(8 * n_in * n_in)} each, counting {SOLVING} to solve) but {_gb(self.budget)} is there "
                f"({MEMORY_SHARE:.0%} of the memory available): {ADVICE}",
                "config:ridge_context",
            )

    def hold(self, n_in: int, matrices: int, what: str) -> None:
        """``check``, then count them held."""
        self.check(n_in, matrices, what)
        self.held += matrices


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
    solution leaves out. Memory: one Σxxᵀ, plus one per glitched channel, held in ``memory`` (default: the
    machine's): past it, an ``InputError`` before allocating."""

    def __init__(self, n_in: int, n_out: int, memory: Memory | None = None):
        self.memory = Memory() if memory is None else memory
        self.memory.hold(n_in, 1, "the ridge's sums")
        self._zeros(n_in, n_out)

    @classmethod
    def _like(cls, other: NormalEquations, n_out: int) -> NormalEquations:
        """Empty sums in ``other``'s memory, not held there: a solution's own or a total's (counted by
        SOLVING, or by the caller)."""
        out = cls.__new__(cls)
        out.memory = other.memory
        out._zeros(other.sx.numel(), n_out)
        return out

    def _zeros(self, n_in: int, n_out: int) -> None:
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
            if c not in self.gaps:
                glitched = f"{len(self.gaps) + 1} channels glitched in some frames (each solved alone)"
                self.memory.hold(x.shape[1], 1, f"the ridge's sums and those of {glitched}")
                self.gaps[c] = self._like(self, 1)
            gap = self.gaps[c]
            gap._add_rows(x[unusable[:, c]], y[unusable[:, c], c : c + 1])

    def _add_rows(self, x: torch.Tensor, y: torch.Tensor) -> None:
        self.n += x.shape[0]
        self.sx += x.sum(0)
        self.sy += y.sum(0)
        self.xx += x.T @ x
        self.xy += x.T @ y

    SUMS = ("sx", "sy", "xx", "xy")  # besides the count n

    @classmethod
    def total(cls, parts: list[NormalEquations]) -> NormalEquations:
        """The sums of several sets of frames (e.g. takes) together."""
        out = cls._like(parts[0], parts[0].sy.numel())
        for part in parts:  # in place: no second input-by-input matrix while adding
            out.n += part.n
            for name in cls.SUMS:
                getattr(out, name).add_(getattr(part, name))
        for c in sorted({c for part in parts for c in part.gaps}):
            out.gaps[c] = cls.total([part.gaps[c] for part in parts if c in part.gaps])
        return out

    def minus(self, part: NormalEquations) -> NormalEquations:
        """These sums without the frames of ``part`` (a subset of them)."""
        out = self._like(self, self.sy.numel())
        out.n = self.n - part.n
        for name in self.SUMS:  # into out's zeros: no second input-by-input matrix
            torch.sub(getattr(self, name), getattr(part, name), out=getattr(out, name))
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
        out = copy.copy(self)  # shares n, sx, xx and subtracted_from: no input-by-input matrix of its own
        out.sy, out.xy, out.gaps = self.sy[c : c + 1], self.xy[:, c : c + 1], {}
        gap = self.gaps.get(c)
        return out if gap is None else out.minus(gap)

    def means(self) -> torch.Tensor:
        """Each channel's mean over its usable values (0 for a channel without any)."""
        mean = self.sy / max(self.n, 1)
        for c, gap in self.gaps.items():  # ``channel(c)``'s n and sy, without its input-by-input sums
            n = self.n - gap.n
            mean[c] = (self.sy[c] - gap.sy[0]) / n if n else 0.0
        return mean

    def solution(self, alpha: float) -> tuple[torch.Tensor, torch.Tensor]:
        """(weight (n_in, n_out), bias (n_out,)), float64, of the ridge on standardised inputs, intercept
        not penalised: ``(C + alpha·I) w = c_xy`` with C the inputs' correlation matrix (alpha is per
        frame); a glitched channel solved alone on its usable values (none: weight and bias 0), after the
        others' matrices are let go."""
        w, bias = self._solved_together(alpha)
        for c in self.gaps:
            eq = self.channel(c)
            w[:, c : c + 1], bias[c : c + 1] = eq.solution(alpha) if eq.n else (0.0, 0.0)
        return w, bias

    def _solved_together(self, alpha: float) -> tuple[torch.Tensor, torch.Tensor]:
        """``solution`` of every channel on the frames usable in some channel (``rows``)."""
        n = max(self.n, 1)
        mx, my = self.sx / n, self.sy / n
        cov = self.xx / n - torch.outer(mx, mx)
        cxy = self.xy / n - torch.outer(mx, my)
        summed = self.xx.diagonal() if self.subtracted_from is None else self.subtracted_from
        constant = cov.diagonal() <= ROUNDING * summed / n
        cov[constant], cov[:, constant], cxy[constant] = 0.0, 0.0, 0.0
        std = cov.diagonal().clamp(min=1e-12).sqrt()
        corr = cov / torch.outer(std, std)
        eye = torch.eye(len(std), dtype=torch.float64)
        w_std = torch.linalg.solve(corr + alpha * eye, cxy / std[:, None])
        w = w_std / std[:, None]
        return w, my - mx @ w

    def solve(self, model: Ridge, alpha: float) -> None:
        """Set ``model.linear`` to ``solution(alpha)``."""
        w, bias = self.solution(alpha)
        with torch.no_grad():
            model.linear.weight.copy_(w.T.float())
            model.linear.bias.copy_(bias.float())
