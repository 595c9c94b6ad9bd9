"""Normalisation of the animation (the paper calls it vital) and of the input features.

Animation, per channel ``c``, with statistics from the training split only::

    zscore:   y = (x - mean_c) / std_c
    neutral:  y = (x - n_c) / s_c     n_c = the take's calibrated neutral pose when it has one
                                      (``_neutral.csv``), else the training split's 5th percentile;
                                      s_c = root-mean-square of (x - n_c) over the training split
    inverse:  x = y * scale_c + offset_c

Scales are powers of two (the standard deviation or RMS rounded in log2, so a normalised channel's
standard deviation lies between 1/sqrt(2) and sqrt(2)) and offsets are float32 values; the arithmetic is
float64. Dividing and multiplying by a power of two is exact, and so is subtracting two float32 values
in float64 unless their magnitudes are more than 2^29 apart, so for float32 input ``x`` (zero, or
|x| >= 2^-29 |offset|) ``inverse(forward(x)) == x`` bit for bit.
Shards keep the raw values; the reader applies ``forward`` with the manifest's statistics.

Features (energy, filter banks, MFCC, PPG) are z-scored per dimension with training-split statistics;
log-F0 is z-scored per speaker over voiced frames.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from typing import Any

import numpy as np

from capture.errors import InputError

ANIM_LIMIT = 10.0  # |value| above this is no blendshape weight nor angle in radians


KINDS = ("zscore", "neutral")
# The percentile histogram: bins 1e-3 wide over [-2, 2] (blendshape weights), then bins 1 % wide out to
# the build's ANIM_LIMIT, ±10 (controls beyond 2, angles in radians); frames beyond it are masked out.
HIST_INNER = 2.0
HIST_INNER_BINS = 4000
HIST_RATIO = 1.01
HIST_OUTER_BINS = int(np.ceil(np.log(ANIM_LIMIT / HIST_INNER) / np.log(HIST_RATIO)))  # 162
HIST_BINS = HIST_INNER_BINS + 2 * HIST_OUTER_BINS
HIST_LAYOUT = f"linear ±{HIST_INNER} × {HIST_INNER_BINS}, ratio {HIST_RATIO} × {HIST_OUTER_BINS} each side"
# Frames binned at a time: binning holds several float64 copies of what it bins (an hour of 32 channels at
# 60 fps binned at once raised a build's peak memory by 155 MB)
HIST_ROWS = 1 << 14
MIN_SCALE = 1e-4  # a channel that never moves keeps scale 1 rather than blowing up


class ChannelAccumulator:
    """Streaming per-channel statistics: count, sum, sum of squares, min, max, a fixed histogram
    (for percentiles) and, for takes with a calibrated neutral, sums around that neutral."""

    def __init__(self, n: int):
        self.n = n
        self.count = np.zeros(n, np.int64)
        self.sum = np.zeros(n, np.float64)
        self.sumsq = np.zeros(n, np.float64)
        self.min = np.full(n, np.inf)
        self.max = np.full(n, -np.inf)
        self.hist = np.zeros((n, HIST_BINS), np.int64)
        # Frames from takes with their own neutral: count and sum of squares of (x - neutral).
        self.own_count = np.zeros(n, np.int64)
        self.own_sumsq = np.zeros(n, np.float64)
        # Frames from takes without one: needed to centre on the global neutral later.
        self.rest_count = np.zeros(n, np.int64)
        self.rest_sum = np.zeros(n, np.float64)
        self.rest_sumsq = np.zeros(n, np.float64)

    def add(self, values: np.ndarray, neutral: np.ndarray | None = None) -> None:
        """Add (frames, channels) usable values (no NaN)."""
        x = np.asarray(values, np.float64)
        if x.shape[0] == 0:
            return
        total, total_sq = x.sum(0), (x * x).sum(0)
        self.count += x.shape[0]
        self.sum += total
        self.sumsq += total_sq
        self.min = np.minimum(self.min, x.min(0))
        self.max = np.maximum(self.max, x.max(0))
        offsets = np.arange(self.n) * HIST_BINS
        for lo in range(0, x.shape[0], HIST_ROWS):  # binned a block of frames at a time (see HIST_ROWS)
            # one bincount for every channel: channel c's bins are offset by c * HIST_BINS
            flat = (histogram_bins(x[lo : lo + HIST_ROWS]) + offsets).ravel()
            self.hist += np.bincount(flat, minlength=self.n * HIST_BINS).reshape(self.n, HIST_BINS)
        if neutral is not None:
            d = x - np.asarray(neutral, np.float64)
            self.own_count += x.shape[0]
            self.own_sumsq += (d * d).sum(0)
        else:
            self.rest_count += x.shape[0]
            self.rest_sum += total
            self.rest_sumsq += total_sq

    def merge(self, other: ChannelAccumulator) -> None:
        for name in self.FIELDS:
            if name == "min":
                self.min = np.minimum(self.min, other.min)
            elif name == "max":
                self.max = np.maximum(self.max, other.max)
            else:
                setattr(self, name, getattr(self, name) + getattr(other, name))

    FIELDS = (
        "count",
        "sum",
        "sumsq",
        "min",
        "max",
        "hist",
        "own_count",
        "own_sumsq",
        "rest_count",
        "rest_sum",
        "rest_sumsq",
    )

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The statistics as arrays (for ``np.savez``)."""
        return {k: getattr(self, k) for k in self.FIELDS}

    @classmethod
    def from_arrays(cls, arrays) -> ChannelAccumulator:
        acc = cls(len(arrays["count"]))
        for k in cls.FIELDS:
            setattr(acc, k, np.array(arrays[k]))
        return acc

    def mean(self) -> np.ndarray:
        return self.sum / np.maximum(self.count, 1)

    def std(self) -> np.ndarray:
        m = self.mean()
        return np.sqrt(np.maximum(self.sumsq / np.maximum(self.count, 1) - m * m, 0.0))

    def percentile(self, q: float) -> np.ndarray:
        """Per-channel ``q``-th percentile (0..100) from the histogram: the bin's centre, within 5e-4 of
        the value inside ±2 and within 0.5 % of it beyond."""
        centres = histogram_centres()
        out = np.zeros(self.n)
        for c in range(self.n):
            cum = np.cumsum(self.hist[c])
            if cum[-1] == 0:
                continue
            out[c] = centres[min(np.searchsorted(cum, q / 100.0 * cum[-1]), HIST_BINS - 1)]
        return np.clip(out, self.min, self.max) if np.all(np.isfinite(self.min)) else out

    def summary(self, channels: list[str]) -> dict[str, dict[str, Any]]:
        """Per-channel distribution: frames, mean, std, min, 5/50/95th percentile, max; null statistics,
        not 0, for a channel without frames (a split whose takes lost the face throughout)."""
        mean, std = self.mean(), self.std()
        p = {q: self.percentile(q) for q in (5, 50, 95)}
        out: dict[str, dict[str, Any]] = {}
        for c, name in enumerate(channels):
            if not self.count[c]:  # nothing measured
                out[name] = {"frames": 0, **dict.fromkeys(("mean", "std", "min", "p05", "p50", "p95", "max"))}
                continue
            out[name] = {
                "frames": int(self.count[c]),
                "mean": round(float(mean[c]), 6),
                "std": round(float(std[c]), 6),
                "min": round(float(self.min[c]), 6) if np.isfinite(self.min[c]) else None,
                "p05": round(float(p[5][c]), 6),
                "p50": round(float(p[50][c]), 6),
                "p95": round(float(p[95][c]), 6),
                "max": round(float(self.max[c]), 6) if np.isfinite(self.max[c]) else None,
            }
        return out


def histogram_bins(x: np.ndarray) -> np.ndarray:
    """The histogram bin of each value (int64, same shape): linear inside ±HIST_INNER, geometric outside,
    values beyond ±ANIM_LIMIT in the outermost bins."""
    x = np.asarray(x, np.float64)
    inner = np.minimum(np.floor((x + HIST_INNER) * (HIST_INNER_BINS / (2 * HIST_INNER))), HIST_INNER_BINS - 1)
    with np.errstate(divide="ignore"):
        steps = np.floor(np.log(np.maximum(np.abs(x), HIST_INNER) / HIST_INNER) / np.log(HIST_RATIO))
    steps = np.minimum(steps, HIST_OUTER_BINS - 1)
    last_inner = HIST_OUTER_BINS + HIST_INNER_BINS
    bins = np.where(
        x >= HIST_INNER,
        last_inner + steps,
        np.where(x < -HIST_INNER, HIST_OUTER_BINS - 1 - steps, HIST_OUTER_BINS + inner),
    )
    return bins.astype(np.int64)


def histogram_centres() -> np.ndarray:
    """The value each histogram bin stands for: its middle (inside ±2), its geometric middle (beyond)."""
    inner = -HIST_INNER + (np.arange(HIST_INNER_BINS) + 0.5) * (2 * HIST_INNER / HIST_INNER_BINS)
    outer = HIST_INNER * HIST_RATIO ** (np.arange(HIST_OUTER_BINS) + 0.5)
    return np.concatenate([-outer[::-1], inner, outer])


@dataclass
class Normalizer:
    """Affine, exactly invertible animation normalisation: ``y = (x - offset) / scale``.

    ``offset`` and ``scale`` are per channel (float32-representable, stored as float64).
    With ``kind == "neutral"``, a sample's own calibrated neutral replaces ``offset``."""

    kind: str
    channels: list[str]
    offset: np.ndarray
    scale: np.ndarray

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise InputError(f"unknown normalization {self.kind!r} (known: {', '.join(KINDS)})")
        self.offset = np.asarray(self.offset, np.float32).astype(np.float64)
        self.scale = np.asarray(self.scale, np.float32).astype(np.float64)
        if np.any(self.scale <= 0) or not np.all(np.isfinite(self.scale)):
            raise InputError("normalization scale must be positive and finite")

    def _offset(self, neutral: np.ndarray | None) -> np.ndarray:
        if self.kind == "neutral" and neutral is not None:
            return np.asarray(neutral, np.float32).astype(np.float64)
        return self.offset

    def forward(self, x: np.ndarray, neutral: np.ndarray | None = None, dtype=np.float64) -> np.ndarray:
        """Normalised values (frames, channels); float64 by default so that ``inverse`` is exact."""
        return ((np.asarray(x, np.float64) - self._offset(neutral)) / self.scale).astype(dtype)

    def inverse(self, y: Any, neutral: Any = None) -> Any:
        """Values in the take's own units (0..1 blendshape weights): float32 NumPy for an array, and for
        a torch tensor a tensor of its dtype on its device (float32 for an integer one), differentiable
        (a loss in the take's units can back-propagate through it). ``neutral`` may be a tensor too."""
        torch = sys.modules.get("torch")  # never imported here: this package does not need torch
        if torch is not None and isinstance(y, torch.Tensor):
            dtype = y.dtype if y.is_floating_point() else torch.float32
            # float32 arithmetic for float32 and narrower (MPS has no float64); the scales are powers of 2
            work = torch.float64 if dtype == torch.float64 else torch.float32
            scale = torch.as_tensor(self.scale, dtype=work, device=y.device)
            if self.kind == "neutral" and neutral is not None:
                if isinstance(neutral, torch.Tensor):
                    offset = neutral.to(device=y.device, dtype=torch.float32).to(work)
                else:
                    offset = torch.as_tensor(np.asarray(neutral, np.float32), device=y.device).to(work)
            else:
                offset = torch.as_tensor(self.offset, dtype=work, device=y.device)
            return (y.to(work) * scale + offset).to(dtype)
        if torch is not None and isinstance(neutral, torch.Tensor):
            neutral = neutral.detach().cpu().numpy()
        return (np.asarray(y, np.float64) * self.scale + self._offset(neutral)).astype(np.float32)

    def to_json(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "channels": list(self.channels),
            "offset": [float(v) for v in self.offset],
            "scale": [float(v) for v in self.scale],
            "formula": "y = (x - offset) / scale; x = y * scale + offset",
            "per_sample_offset": "sample json 'neutral' when present" if self.kind == "neutral" else None,
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Normalizer:
        try:
            return cls(
                data["kind"], list(data["channels"]), np.asarray(data["offset"]), np.asarray(data["scale"])
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"malformed normalization statistics: {exc}") from None


def animation_statistics(kind: str, acc: ChannelAccumulator) -> tuple[np.ndarray, np.ndarray]:
    """Per channel, the offset and the spread (std or RMS, 1 for a channel that barely moves) of
    ``fit_normalizer`` before the spread is rounded to a power of two (``validate --deep`` compares a
    manifest's scales with them)."""
    if kind == "zscore":
        offset = acc.mean()
        spread = acc.std()
    elif kind == "neutral":
        offset = acc.percentile(5.0)
        # RMS around each take's own neutral (calibrated takes) or around the global neutral (others)
        rest = acc.rest_sumsq - 2 * offset * acc.rest_sum + acc.rest_count * offset * offset
        total = np.maximum(acc.own_count + acc.rest_count, 1)
        spread = np.sqrt(np.maximum(acc.own_sumsq + rest, 0.0) / total)
    else:
        raise InputError(f"unknown normalization {kind!r} (known: {', '.join(KINDS)})")
    return offset, np.where(spread < MIN_SCALE, 1.0, spread)


def fit_normalizer(kind: str, channels: list[str], acc: ChannelAccumulator) -> Normalizer:
    """Normalizer from training-split statistics ``acc``."""
    offset, spread = animation_statistics(kind, acc)
    return Normalizer(kind, channels, offset.astype(np.float32), power_of_two(spread).astype(np.float32))


def power_of_two(spread: np.ndarray | float) -> np.ndarray:
    """The scale for ``spread``: the nearest power of two in log2 (a midpoint rounds to the even
    exponent), so that dividing and multiplying by it is exact. The build and ``validate`` both use it."""
    return np.exp2(np.round(np.log2(spread)))


def usable_neutral(neutral: Any, n: int) -> np.ndarray | None:
    """A neutral pose as float32 when it is ``n`` finite numbers, else None (the channel's percentile
    stands in): the build's test of a take's pose and ``validate``'s of a sample's."""
    if neutral is None:
        return None
    try:
        pose = np.asarray(neutral)
    except ValueError:  # a ragged list
        return None
    if pose.shape != (n,) or pose.dtype.kind not in "fiu" or not np.all(np.isfinite(pose)):
        return None  # text or true/false in a manifest is no number either
    return pose.astype(np.float32)


def voiced_log_f0_sums(pitch: np.ndarray, frames: np.ndarray | None = None) -> dict[str, Any]:
    """Count, sum and sum of squares of the voiced log-F0 of ``pitch`` (frames, [log-F0, voiced]), over
    ``frames`` (a mask) only when given: what per-speaker pitch normalisation merges, in float64."""
    voiced = pitch[:, 1] > 0.5
    if frames is not None:
        voiced &= frames
    lf0 = pitch[voiced, 0].astype(np.float64)
    return {"count": int(lf0.size), "sum": float(lf0.sum()), "sumsq": float((lf0 * lf0).sum())}


def is_power_of_two(x: float) -> bool:
    """Whether ``x`` is 2^k for an integer k (the animation scales are)."""
    mantissa, _ = math.frexp(x)
    return x > 0 and math.isfinite(x) and mantissa == 0.5


def histogram_resolution(x: np.ndarray) -> np.ndarray:
    """How far a percentile read from the histogram may lie from the value: a bin's width there."""
    inner = 2 * HIST_INNER / HIST_INNER_BINS
    return np.where(np.abs(x) < HIST_INNER, inner, np.abs(x) * (HIST_RATIO - 1.0) + inner)


class FeatureAccumulator:
    """Per-dimension count, sum and sum of squares of one feature (float64)."""

    def __init__(self, dim: int):
        self.count = 0
        self.sum = np.zeros(dim)
        self.sumsq = np.zeros(dim)

    def add(self, x: np.ndarray) -> None:
        x = np.asarray(x, np.float64)
        self.count += x.shape[0]
        self.sum += x.sum(0)
        self.sumsq += (x * x).sum(0)

    def merge(self, other: FeatureAccumulator) -> None:
        self.count += other.count
        self.sum = self.sum + other.sum
        self.sumsq = self.sumsq + other.sumsq

    def to_json(self) -> dict[str, Any]:
        return {"count": self.count, "sum": self.sum.tolist(), "sumsq": self.sumsq.tolist()}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> FeatureAccumulator:
        acc = cls(len(data["sum"]))
        acc.count = int(data["count"])
        acc.sum = np.asarray(data["sum"], np.float64)
        acc.sumsq = np.asarray(data["sumsq"], np.float64)
        return acc

    def mean_std(self) -> tuple[list[float], list[float]]:
        n = max(self.count, 1)
        mean = self.sum / n
        std = np.sqrt(np.maximum(self.sumsq / n - mean * mean, 0.0))
        std = np.where(std < 1e-6, 1.0, std)
        return [float(np.float32(v)) for v in mean], [float(np.float32(v)) for v in std]


class FeatureNormalizer:
    """The manifest's frame-level feature normalisation: each feature z-scored with its training-split
    mean and std; pitch's log-F0 z-scored with its speaker's voiced statistics (0 on unvoiced frames)."""

    def __init__(self, normalization: dict[str, Any]):
        self.features = {
            k: (np.asarray(v["mean"], np.float32), np.asarray(v["std"], np.float32))
            for k, v in normalization["features"].items()
        }
        self.pitch_speakers: dict[str, dict[str, float]] = normalization.get("pitch", {}).get("speakers", {})

    def apply(
        self, name: str, x: np.ndarray, speaker: str | None = None, unknown_speaker: str = "identity"
    ) -> np.ndarray:
        """``x`` (frames, dim) normalised. A speaker the dataset does not know keeps raw log-F0
        (``unknown_speaker="identity"``) or is z-scored with the utterance's own voiced log-F0
        (``"utterance"``, for speech from outside the dataset)."""
        x = np.asarray(x, np.float32)
        if name == "pitch":
            voiced = x[:, 1] > 0
            st = self.pitch_speakers.get(speaker) if speaker is not None else None
            if st is None:
                st = {"mean": 0.0, "std": 1.0}
                if unknown_speaker == "utterance" and voiced.any():
                    f0 = x[voiced, 0]
                    std = float(f0.std()) if f0.size > 1 else 1.0
                    st = {"mean": float(f0.mean()), "std": std if std > 1e-6 else 1.0}
            x = x.copy()
            x[:, 0] = np.where(voiced, (x[:, 0] - st["mean"]) / st["std"], 0.0)
            return x
        if name in self.features:
            mean, std = self.features[name]
            return (x - mean) / std
        return x
