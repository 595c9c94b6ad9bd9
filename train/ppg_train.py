"""Training the 64-dim bottleneck PPG extractor (``dataset.bottleneck.BottleneckPPG``) on speech with
phone alignments, written with ``save_bottleneck`` for ``s2a-dataset build --ppg bottleneck``.

Alignments come as Praat TextGrids beside their audio (same stem; the simulator writes them beside its
takes; tier ``phones``, empty label = silence) or as a JSON file mapping audio stems to
``{"words": [{"phones": [{"phone", "start", "end"}]}]}`` (the LibriVox sample). Phone labels are
ARPAbet in any case, stress digits dropped; labels outside ARPAbet count as SIL. Features are the
dataset's own log-mel filter banks on its 20 ms grid; frame ``k`` (centre ``k · 20 ms``) takes the
phone spanning that instant.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from align.resample import to_16k_mono
from capture import read_audio
from capture.command import progress
from capture.errors import InputError
from capture.textgrid import read_textgrid
from dataset.bottleneck import ARPABET, BottleneckConfig, BottleneckPPG, save_bottleneck
from dataset.features import FeatureSettings, spectral_features

AUDIO_SUFFIXES = (".wav", ".flac")
Segments = list[tuple[float, float, str]]


def _phone_id(label: str) -> int:
    p = re.sub(r"\d", "", label.strip()).upper()
    return ARPABET.index(p) if p in ARPABET else 0


def _audio_beside(path: Path) -> Path:
    for suffix in AUDIO_SUFFIXES:
        if path.with_suffix(suffix).is_file():
            return path.with_suffix(suffix)
    raise InputError("no audio file (.wav, .flac) with the same name", path)


def find_alignments(paths: list[str | Path]) -> list[tuple[Path, Segments]]:
    """(audio file, phone segments in seconds) for every aligned utterance under ``paths``."""
    found: list[tuple[Path, Segments]] = []
    for p in map(Path, paths):
        if not p.exists():
            raise InputError("not found", p)
        grids = (
            [p] if p.suffix.lower() == ".textgrid" else sorted(p.rglob("*.TextGrid")) if p.is_dir() else []
        )
        jsons = [p] if p.suffix.lower() == ".json" else sorted(p.rglob("*.json")) if p.is_dir() else []
        for g in grids:
            tier = read_textgrid(g).tier("phones")
            found.append((_audio_beside(g), [(iv.xmin, iv.xmax, iv.text) for iv in tier.intervals]))
        for j in jsons:
            try:
                data = json.loads(j.read_text())
            except (json.JSONDecodeError, UnicodeDecodeError):
                continue
            if not isinstance(data, dict):
                continue
            for stem, utt in data.items():
                if not (isinstance(utt, dict) and isinstance(utt.get("words"), list)):
                    continue
                segs = [
                    (ph["start"], ph["end"], ph["phone"]) for w in utt["words"] for ph in w.get("phones", [])
                ]
                found.append((_audio_beside(j.parent / stem), segs))
    if not found:
        raise InputError(
            "no phone alignments found (TextGrid with a 'phones' tier, or alignment JSON)", paths[0]
        )
    return found


def frame_labels(segments: Segments, n_frames: int, hop_s: float) -> np.ndarray:
    """Phone id per analysis frame (centre ``k · hop_s`` s); SIL outside every segment."""
    labels = np.zeros(n_frames, np.int64)
    t = np.arange(n_frames) * hop_s
    for start, end, label in segments:
        labels[(t >= start) & (t < end)] = _phone_id(label)
    return labels


def train_ppg(
    paths: list[str | Path],
    out: str | Path,
    steps: int = 300,
    seed: int = 0,
    window: int = 200,
    batch_size: int = 8,
    lr: float = 1e-3,
    say: Callable[[str], None] = progress,
) -> dict[str, Any]:
    """Train a BottleneckPPG on every aligned utterance under ``paths`` and save it to ``out``. Every
    tenth utterance (at least one when there are two or more) is held out for the frame accuracy."""
    settings = FeatureSettings()
    utts = []
    for audio_path, segs in find_alignments(paths):
        fbank = spectral_features(to_16k_mono(read_audio(audio_path), str(audio_path)), settings)["fbank"]
        utts.append(
            (torch.from_numpy(fbank), torch.from_numpy(frame_labels(segs, len(fbank), settings.hop_s)))
        )
    held = set(range(0, len(utts), 10)) if len(utts) > 1 else set()
    train = [u for i, u in enumerate(utts) if i not in held] or utts
    val = [u for i, u in enumerate(utts) if i in held]
    frames = sum(len(u[1]) for u in train)
    say(
        f"ppg: {len(utts)} utterances ({frames * settings.hop_s / 60:.1f} min for training, "
        f"{len(val)} held out)"
    )
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    model = BottleneckPPG(BottleneckConfig(n_mels=settings.n_mels))
    opt = torch.optim.AdamW(model.parameters(), lr=lr)
    for step in range(steps):
        xs, ys = [], []
        picks = rng.integers(0, len(train), batch_size)
        length = min(window, *(len(train[j][1]) for j in picks))  # crops of one length, no padding
        for j in picks:
            x, y = train[j]
            s = int(rng.integers(0, len(y) - length + 1))
            xs.append(x[s : s + length])
            ys.append(y[s : s + length])
        _, logits = model(torch.stack(xs))
        loss = F.cross_entropy(logits.reshape(-1, logits.shape[-1]), torch.stack(ys).reshape(-1))
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        if (step + 1) % 50 == 0:
            say(f"ppg step {step + 1}: cross-entropy {loss.item():.3f}")
    model.eval()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    save_bottleneck(model, out)
    return {
        "checkpoint": str(out),
        "utterances": len(utts),
        "train_frames": frames,
        "steps": steps,
        "train_accuracy": _accuracy(model, train),
        "val_accuracy": _accuracy(model, val) if val else None,
        "majority_accuracy": _majority(train, val or train),
    }


@torch.no_grad()
def _accuracy(model: BottleneckPPG, utts) -> float:
    hit = n = 0
    for x, y in utts:
        _, logits = model(x.unsqueeze(0))
        hit += int((logits[0].argmax(-1) == y).sum())
        n += len(y)
    return hit / max(n, 1)


def _majority(train, evaluate) -> float:
    """Frame accuracy of always answering the most frequent training phone (the chance level)."""
    top = int(torch.cat([y for _, y in train]).bincount().argmax())
    ys = torch.cat([y for _, y in evaluate])
    return float((ys == top).float().mean())
