"""Aligned takes for the dataset tests, written with ``capture.write_take`` following the align
contract: source_kind "aligned", 16 kHz mono float32 audio from take time 0, a uniform frame grid
``time[i] = i / fps``, TRACKED (0) and INTERPOLATED (4) frames usable, others masked."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from capture import ARKIT52, Audio, Take, TakeMeta, write_take

SR = 16000


def speech_like(seconds: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Voiced syllables (harmonics on a gliding F0) with pauses; returns audio and its envelope."""
    n = int(seconds * SR)
    t = np.arange(n) / SR
    f0 = 120 + 30 * np.sin(2 * np.pi * 0.7 * t + rng.uniform(0, 6))
    phase = 2 * np.pi * np.cumsum(f0) / SR
    voice = sum(np.sin(k * phase) / k for k in range(1, 8))
    syll = np.clip(np.sin(2 * np.pi * 3.0 * t + rng.uniform(0, 6)), 0, None) ** 2
    env = syll * (np.sin(2 * np.pi * 0.25 * t) > -0.6)
    audio = 0.1 * env * voice + 0.003 * rng.standard_normal(n)
    return audio.astype(np.float32), env


def make_aligned_take(
    take_id: str,
    seconds: float = 3.0,
    fps: float = 60.0,
    subject: str | None = "spk1",
    seed: int = 0,
    channels: tuple[str, ...] = ARKIT52,
    neutral: bool = False,
    gap: tuple[int, int] | None = None,
) -> Take:
    rng = np.random.default_rng(seed)
    audio, env = speech_like(seconds, rng)
    n = int(round(seconds * fps))
    times = np.arange(n) / fps
    env_frames = np.interp(times, np.arange(env.size) / SR, env)
    values = np.abs(rng.normal(0.02, 0.01, (n, len(channels)))).astype(np.float32)
    lowered = [c.lower() for c in channels]
    for name, gain in (("jawopen", 0.6), ("mouthclose", 0.2), ("mouthfunnel", 0.3)):
        if name in lowered:
            values[:, lowered.index(name)] += (gain * env_frames).astype(np.float32)
    status = np.zeros(n, np.uint8)
    status[n // 3 : n // 3 + 3] = 4  # interpolated across a short gap: usable
    if gap is not None:
        status[gap[0] : gap[1]] = 1  # face lost: masked
        values[gap[0] : gap[1]] = np.nan
    meta = TakeMeta(id=take_id, source_kind="aligned", fps=fps, channels=list(channels), subject=subject)
    meta.extra["align"] = {"offset_s": 0.0, "speech_segments": [[0.0, seconds]], "parent": take_id + "_raw"}
    take = Take(meta, times, values, status)
    take.attach_audio(Audio(audio, SR, "FLOAT"), start_s=0.0, start_source="aligned")
    if neutral:
        take.neutral = np.full(len(channels), 0.01, np.float32)
    return take


def write_aligned_set(root: Path, count: int = 6, speakers: int = 2, seconds: float = 3.0, **kw) -> Path:
    """``count`` aligned takes of ``speakers`` speakers under ``root``; returns ``root``."""
    for i in range(count):
        take = make_aligned_take(f"take{i:02d}", seconds, subject=f"spk{i % speakers}", seed=i, **kw)
        write_take(take, root)
    return root


def build_take_split(takes: Path, out: Path, **options) -> Path:
    """``out``: the dataset of the aligned takes in ``takes`` as the train stage's small datasets are built:
    pitch, energy and filter banks, 1 s samples, take03 validates, take04 tests, the others train;
    ``options``: other ``BuildOptions`` (``channels``, ``normalization``)."""
    from dataset import BuildOptions, build_dataset
    from dataset.splits import SplitRule

    split = SplitRule("take", 0.1, 0.1, 0, ("take03",), ("take04",))
    options = BuildOptions(features=("pitch", "energy", "fbank"), split=split, max_sample_s=1.0, **options)
    build_dataset([takes], out, options, say=lambda _m: None)
    return out


def build_five_take_dataset(root: Path, gap: tuple[int, int] | None = None) -> Path:
    """``root/ds``: five aligned 2 s takes of two speakers (``build_take_split``: take03 validates, take04
    tests, take00-02 train; the train stage's small adversity datasets). ``gap``: frames where each take lost
    the face (``make_aligned_take``)."""
    takes = write_aligned_set(root / "takes", count=5, speakers=2, seconds=2.0, gap=gap)
    return build_take_split(takes, root / "ds")


def build_default_dataset(root: Path) -> Path:
    """``root/ds``: five aligned 2 s takes of two speakers built by the command line with its defaults."""
    from conftest import run_cli

    takes = write_aligned_set(root / "takes", count=5, speakers=2, seconds=2.0)
    proc = run_cli("dataset", "build", takes, "-o", root / "ds", "--json")
    assert proc.returncode == 0, proc.stderr
    return root / "ds"
