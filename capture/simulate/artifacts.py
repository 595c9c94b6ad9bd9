"""What a real capture adds to the face: sensor noise, blinks and head motion on the channels speech
does not drive, dropped frames, face-lost stretches, silence around the speech, and an offset between
the audio and the blendshape clocks. Each is switchable; names as on the command line."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import numpy as np

from ..channels import ARKIT61, PRONUNCIATION32
from ..errors import InputError

ARTIFACT_NAMES = {
    "noise": "sensor_noise",
    "blinks": "blinks",
    "head": "head_motion",
    "drops": "dropped_frames",
    "face-lost": "face_lost",
    "silence": "silence",
    "offset": "offset",
}


@dataclass(frozen=True)
class Artifacts:
    """Which capture artifacts a simulated take has (all on by default)."""

    sensor_noise: bool = True
    blinks: bool = True
    head_motion: bool = True
    dropped_frames: bool = True
    face_lost: bool = True
    silence: bool = True
    offset: bool = True

    @classmethod
    def without(cls, names: list[str] | tuple[str, ...]) -> Artifacts:
        """All artifacts but the named ones (``noise``, ``blinks``, ``head``, ``drops``, ``face-lost``,
        ``silence``, ``offset``; ``all`` switches every one off)."""
        off: dict[str, bool] = {}
        for raw in names:
            name = raw.strip().lower()
            if not name:
                continue
            if name == "all":
                off |= {f.name: False for f in fields(cls)}
                continue
            if name not in ARTIFACT_NAMES:
                known = ", ".join([*ARTIFACT_NAMES, "all"])
                raise InputError(f"unknown artifact {raw!r} (artifacts: {known})")
            off[ARTIFACT_NAMES[name]] = False
        return cls(**off)

    def to_json(self) -> dict[str, bool]:
        return asdict(self)


def frame_period_s(rng: np.random.Generator, fps: int) -> float:
    """The phone's real frame period: a little longer than nominal (the app writes 59.90 rows/s)."""
    return (1.0 + float(rng.uniform(0.0008, 0.0024))) / fps


def drop_mask(rng: np.random.Generator, n: int, enabled: bool) -> np.ndarray:
    """Frames the capture lost (no CSV row): isolated or pairs, never the first or last frame."""
    mask = np.zeros(n, dtype=bool)
    if not enabled or n < 10:
        return mask
    rate = float(rng.uniform(0.001, 0.006))
    starts = np.flatnonzero(rng.random(n) < rate)
    for s in starts:
        length = 2 if rng.random() < 0.2 else 1
        mask[s : s + length] = True
    mask[:2] = False
    mask[-2:] = False
    return mask


def face_lost_mask(rng: np.random.Generator, n: int, fps: int, enabled: bool) -> np.ndarray:
    """Stretches where ARKit lost the face (written as ``<timecode>,0`` rows): 0-2 per take."""
    mask = np.zeros(n, dtype=bool)
    if not enabled or n < 4 * fps:
        return mask
    for _ in range(int(rng.choice((0, 1, 1, 2)))):
        length = int(rng.uniform(0.2, 1.2) * fps)
        start = int(rng.integers(fps, max(n - fps - length, fps + 1)))
        mask[start : start + length] = True
    return mask


def _smooth_noise(rng: np.random.Generator, n: int, fps: int, tau_s: float) -> np.ndarray:
    """Unit-variance noise low-passed with time constant ``tau_s`` (an AR(1) process)."""
    from scipy.signal import lfilter  # here, not at the top: the CLI imports this module at start-up

    a = np.exp(-1.0 / (tau_s * fps))
    x = lfilter([np.sqrt(1 - a * a)], [1.0, -a], rng.standard_normal(n))
    return x


def upper_face(
    rng: np.random.Generator,
    n: int,
    fps: int,
    rest: tuple[float, ...],
    accent_curve: np.ndarray,
    blinks: bool,
    head_motion: bool,
) -> dict[str, np.ndarray]:
    """Eyes, brows and head for ``n`` frames: the channels outside ``pronunciation32`` (0..1 units;
    head and eye angles signed). ``accent_curve`` (per frame, 0..1) raises the brows and nods the head
    on accented words, as speakers do."""
    look_down, wide, brow_in, brow_out, head_pitch = rest
    out = {c: np.zeros(n) for c in ARKIT61 if c not in PRONUNCIATION32}
    for side in ("Left", "Right"):
        out[f"eyeLookDown{side}"][:] = look_down
        out[f"eyeWide{side}"][:] = wide
    out["browInnerUp"][:] = brow_in + 0.12 * accent_curve
    for side in ("Left", "Right"):
        out[f"browOuterUp{side}"][:] = brow_out + 0.08 * accent_curve
    out["headPitch"][:] = head_pitch
    out["leftEyePitch"][:] = 0.08
    out["rightEyePitch"][:] = 0.08
    if head_motion:
        yaw = 0.03 * _smooth_noise(rng, n, fps, 1.5)
        pitch = 0.015 * _smooth_noise(rng, n, fps, 1.0) + 0.012 * accent_curve
        roll = 0.01 * _smooth_noise(rng, n, fps, 2.0)
        out["headYaw"] += yaw
        out["headPitch"] += pitch
        out["headRoll"] += roll
        # Gaze: fixations held 0.3-2 s, with saccades between them; both eyes move together.
        gaze_yaw = np.zeros(n)
        gaze_pitch = np.zeros(n)
        i = 0
        while i < n:
            hold = int(rng.uniform(0.3, 2.0) * fps)
            gaze_yaw[i : i + hold] = rng.normal(0.0, 0.05)
            gaze_pitch[i : i + hold] = rng.normal(0.0, 0.04)
            i += max(hold, 1)
        for eye in ("leftEye", "rightEye"):
            out[f"{eye}Yaw"] += gaze_yaw - 0.5 * yaw
            out[f"{eye}Pitch"] += gaze_pitch - 0.5 * pitch
        # ARKit's eyeLook* shapes follow gaze: in/out by yaw (mirrored per eye), up/down by pitch.
        out["eyeLookOutLeft"] += np.maximum(-gaze_yaw, 0) * 2.0
        out["eyeLookInLeft"] += np.maximum(gaze_yaw, 0) * 2.0
        out["eyeLookInRight"] += np.maximum(-gaze_yaw, 0) * 2.0
        out["eyeLookOutRight"] += np.maximum(gaze_yaw, 0) * 2.0
        for side in ("Left", "Right"):
            out[f"eyeLookDown{side}"] += np.maximum(gaze_pitch, 0) * 1.5
            out[f"eyeLookUp{side}"] += np.maximum(-gaze_pitch, 0) * 1.5
    if blinks:
        t = 0.0
        blink = np.zeros(n)
        while True:
            t += float(rng.exponential(3.5)) + 0.3
            i = int(t * fps)
            if i >= n:
                break
            close = max(int(0.07 * fps), 1)
            reopen = max(int(rng.uniform(0.12, 0.25) * fps), 1)
            peak = float(rng.uniform(0.6, 0.95))
            shape = np.concatenate([np.linspace(0, 1, close, endpoint=False), np.linspace(1, 0, reopen)])
            seg = blink[i : i + shape.size]
            np.maximum(seg, peak * shape[: seg.size], out=seg)
        for side in ("Left", "Right"):
            out[f"eyeBlink{side}"] += blink
            out[f"eyeSquint{side}"] += 0.15 * blink
            out[f"eyeLookDown{side}"] += 0.1 * blink
    return out


def sensor_noise(rng: np.random.Generator, values: np.ndarray, fps: int) -> np.ndarray:
    """ARKit-like tracking noise: small, slightly smoothed, larger on eyes than on the mouth."""
    from scipy.signal import lfilter

    n, c = values.shape
    a = np.exp(-1.0 / (0.02 * fps))
    noise = lfilter([1.0 - a], [1.0, -a], rng.standard_normal((n, c)), axis=0)
    scale = np.full(c, 0.012)
    for j, name in enumerate(ARKIT61[:c]):
        if name.startswith("eye") or name.endswith(("Yaw", "Pitch", "Roll")):
            scale[j] = 0.02
    return values + noise * scale
