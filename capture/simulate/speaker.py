"""Simulated speakers: voice, speaking style and face, drawn once per (seed, speaker)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from ..channels import PRONUNCIATION32


@dataclass(frozen=True)
class Speaker:
    """One simulated person. Frequencies in Hz, levels in dB, times in seconds.

    ``vtl_scale`` multiplies every formant (a shorter vocal tract gives higher formants; 1 = adult
    male). ``jaw_energy_coupling`` (per dB) and ``jaw_pitch_coupling`` (per semitone) say how much wider
    the jaw opens on louder and higher-pitched vowels: the prosody coupling Transformer-S2A relies on.
    ``face_lead_s`` > 0: the face articulates that long before the sound it goes with.
    """

    index: int
    name: str
    f0_hz: float
    f0_range_st: float
    vtl_scale: float
    loudness_db: float
    rate: float
    face_lead_s: float
    articulation_gain: float
    channel_gain: tuple[float, ...]
    left_right_asymmetry: float
    jaw_energy_coupling: float
    jaw_pitch_coupling: float
    jitter: float
    breathiness: float
    upper_face: tuple[float, ...]  # rest values: eyeLookDown, eyeWide, browInnerUp, browOuterUp, headPitch

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def speaker_rng(seed: int, speaker: int) -> np.random.Generator:
    """The generator of a speaker's traits: depends only on (seed, speaker)."""
    return np.random.default_rng([int(seed), int(speaker), 0x5BEA])


def draw_speaker(seed: int, index: int) -> Speaker:
    """Draw speaker ``index`` (0-based) of a simulation seeded with ``seed``."""
    rng = speaker_rng(seed, index)
    # Alternate low and high voices so that even two speakers differ in F0 and vocal-tract length.
    high = (index % 2 == 1) != bool(rng.random() < 0.15)
    f0 = float(rng.uniform(170, 240) if high else rng.uniform(90, 140))
    vtl = float(rng.uniform(1.1, 1.22) if high else rng.uniform(0.92, 1.04))
    gains = np.exp(rng.normal(0.0, 0.18, len(PRONUNCIATION32)))
    return Speaker(
        index=index,
        name=f"spk{index + 1:02d}",
        f0_hz=round(f0, 3),
        f0_range_st=round(float(rng.uniform(2.5, 6.0)), 3),
        vtl_scale=round(vtl, 4),
        loudness_db=round(float(rng.normal(0.0, 2.5)), 3),
        rate=round(float(rng.uniform(0.82, 1.22)), 4),
        face_lead_s=round(float(rng.uniform(0.01, 0.04)), 4),
        articulation_gain=round(float(rng.uniform(0.75, 1.3)), 4),
        channel_gain=tuple(round(float(g), 4) for g in gains),
        left_right_asymmetry=round(float(rng.normal(0.0, 0.06)), 4),
        jaw_energy_coupling=round(float(rng.uniform(0.04, 0.07)), 4),
        jaw_pitch_coupling=round(float(rng.uniform(0.025, 0.05)), 4),
        jitter=round(float(rng.uniform(0.005, 0.015)), 4),
        breathiness=round(float(rng.uniform(0.02, 0.08)), 4),
        upper_face=tuple(
            round(float(x), 4)
            for x in (
                rng.uniform(0.05, 0.2),
                rng.uniform(0.0, 0.2),
                rng.uniform(0.0, 0.15),
                rng.uniform(0.0, 0.1),
                rng.uniform(-0.03, 0.1),
            )
        ),
    )
