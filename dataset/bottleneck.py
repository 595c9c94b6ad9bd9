"""``BottleneckPPG``: the paper's ASR bottleneck network that yields 64-dim phonetic posteriorgrams.

Log-mel filter banks on the 20 ms grid → utterance mean/variance normalisation → 1-D convolutions →
a linear 64-dim bottleneck (the PPG) → a phone classifier used to train it (``s2a-train ppg``).
Checkpoints are plain dicts of config and tensors, read with ``torch.load(weights_only=True)``.
"""

from __future__ import annotations

import pickle
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import nn

from capture.errors import InputError

from .phones import ARPABET

CHECKPOINT_FORMAT = "s2a-ppg-bottleneck"


@dataclass
class BottleneckConfig:
    """Shape of the network: ``n_mels`` filter-bank bins in, ``bottleneck`` dims out."""

    n_mels: int = 40
    hidden: int = 256
    layers: int = 3
    kernel: int = 5
    bottleneck: int = 64
    phones: list[str] = field(default_factory=lambda: list(ARPABET))


class BottleneckPPG(nn.Module):
    """Filter banks (batch, frames, n_mels) → bottleneck (batch, frames, 64) and phone logits
    (batch, frames, phones). One output frame per input frame (20 ms)."""

    def __init__(self, config: BottleneckConfig | None = None):
        super().__init__()
        self.config = config = config or BottleneckConfig()
        blocks: list[nn.Module] = []
        width = config.n_mels
        for _ in range(config.layers):
            blocks += [nn.Conv1d(width, config.hidden, config.kernel, padding=config.kernel // 2), nn.ReLU()]
            width = config.hidden
        self.encoder = nn.Sequential(*blocks)
        self.bottleneck = nn.Linear(config.hidden, config.bottleneck)
        self.classifier = nn.Linear(config.bottleneck, len(config.phones))

    def forward(self, fbank: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        x = fbank - fbank.mean(dim=1, keepdim=True)
        x = x / (x.std(dim=1, keepdim=True, unbiased=False) + 1e-5)
        h = self.encoder(x.transpose(1, 2)).transpose(1, 2)
        b = self.bottleneck(h)
        return b, self.classifier(torch.relu(b))


def save_bottleneck(model: BottleneckPPG, path: str | Path) -> None:
    """Write a checkpoint ``load_bottleneck`` reads: a plain dict of format, config and tensors."""
    payload = {
        "format": CHECKPOINT_FORMAT,
        "version": 1,
        "config": asdict(model.config),
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
    }
    torch.save(payload, str(path))


ZIP_MAGIC = b"PK\x03\x04"  # torch.save writes zip archives (since PyTorch 1.6)


def load_plain(path: str | Path, what: str) -> Any:
    """What ``torch.save`` wrote to ``path``, read with ``weights_only=True``: tensors and plain data
    only, never pickled code. ``what`` names the file in errors ("PPG checkpoint"): a file that is not a
    torch.save archive, one that holds other Python objects, or a damaged one is a one-line error, and
    torch's warnings about the file's pickle protocol are not printed."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(4)
    except OSError as exc:
        raise InputError(f"cannot read the {what}: {exc.strerror or exc}", path) from None
    if head != ZIP_MAGIC:
        raise InputError(f"not a {what} (not an archive torch.save writes)", path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return torch.load(str(path), map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        raise InputError(
            f"not a {what}: it holds Python objects other than tensors and plain data, or is damaged "
            "(refused; nothing in it was run)",
            path,
        ) from None
    except Exception as exc:  # noqa: BLE001 - torch raises many kinds of error for a damaged file
        msg = str(exc).strip().splitlines()[0][:120] if str(exc).strip() else type(exc).__name__
        raise InputError(f"not a readable {what}, damaged or truncated? ({msg})", path) from None


def load_bottleneck(path: str | Path) -> BottleneckPPG:
    """The ``BottleneckPPG`` of a checkpoint, in eval mode. Never unpickles code (``weights_only``)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("PPG checkpoint not found", path)
    payload = load_plain(path, "PPG checkpoint")
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise InputError(f'not a bottleneck PPG checkpoint (expected "format": "{CHECKPOINT_FORMAT}")', path)
    try:
        model = BottleneckPPG(BottleneckConfig(**payload["config"]))
        model.load_state_dict(payload["state_dict"])
    except (KeyError, TypeError, RuntimeError) as exc:
        raise InputError(f"checkpoint does not fit BottleneckPPG: {str(exc).splitlines()[0]}", path) from None
    return model.eval()
