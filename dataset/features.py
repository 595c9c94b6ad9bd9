"""The one preprocessor: every frame-level feature from one analysis setting.

Speech at 16 kHz is cut into 40 ms Hann windows every 20 ms (the paper's setting), centred at
``k * hop`` seconds (the signal is reflect-padded by half a window). On that grid we compute log energy,
log-mel filter banks, MFCC, pitch (``pitch.py``) and the phonetic posteriorgram (``ppg.py``, which
consumes the filter banks), then interpolate every feature linearly to the animation frame times
``i / fps``. Statistics for normalisation are gathered by the build and stored once in the manifest.

With a speech level in the settings (``level="speech -26 dBFS"``, the default of new builds) the take's
audio is first scaled so that its active speech level (``speech_level``, in the spirit of ITU-T P.56) is
that target: the microphone's gain is arbitrary, the face does not depend on it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import scipy.fft

from capture.audio_io import SILENT_PEAK
from capture.errors import InputError
from capture.numbers import is_finite_number

from .pitch import PitchSettings, pitch_pieces, track_pitch

FEATURES = ("pitch", "energy", "fbank", "mfcc", "ppg")
DEFAULT_FEATURES = ("pitch", "energy", "fbank")
DEFAULT_LEVEL = "speech -26 dBFS"  # new builds; settings without a level (older datasets) are "none"
LEVEL_MARGIN_DB = 15.9  # P.56's margin: frames within it of the active level are speech
LEVEL_HANGOVER_S = 0.2  # P.56's hangover: a pause shorter than this stays active
LEVEL_FRAME_S = 0.010
MAX_LEVEL_GAIN_DB = 60.0  # a take at -86 dBFS active level is raised no further than to -26


@dataclass(frozen=True)
class FeatureSettings:
    """Analysis setting shared by all features: rates in Hz, window and hop in seconds.

    The defaults are not those of a build, which normalises the speech level
    (``FeatureSettings(level=DEFAULT_LEVEL)``): the settings a dataset was built with are
    ``FeatureSettings.from_manifest(manifest)``."""

    sample_rate: int = 16000
    window_s: float = 0.040
    hop_s: float = 0.020
    n_fft: int = 1024
    n_mels: int = 40
    n_mfcc: int = 13
    fmin_hz: float = 0.0
    fmax_hz: float = 8000.0
    pitch: PitchSettings = field(default_factory=PitchSettings)
    level: str = "none"  # "none" or "speech <dB> dBFS" (parse_level): speech-level normalisation

    def __post_init__(self) -> None:
        parse_level(self.level)  # ValueError for another text

    @property
    def level_target_db(self) -> float | None:
        """The active speech level the audio is scaled to before features, or None (as recorded)."""
        return _level_target(self.level)

    @property
    def win_length(self) -> int:
        return int(round(self.window_s * self.sample_rate))

    @property
    def hop_length(self) -> int:
        return int(round(self.hop_s * self.sample_rate))

    def to_json(self) -> dict:
        return asdict(self)

    @classmethod
    def from_json(cls, data: Any) -> FeatureSettings:
        """The settings ``to_json`` wrote (a manifest's ``features.settings``), nested ``pitch`` included,
        each field checked; a field left out takes its default (``level``: ``"none"``, as datasets built
        before speech-level normalisation recorded none). An unknown field or a value of the wrong type
        or range is an ``InputError`` naming it."""
        kwargs = dict(_checked(data, cls, _SETTINGS_FIELDS, "feature settings", "hold", ""))
        if "pitch" in kwargs:
            pitch = _checked(
                kwargs["pitch"], PitchSettings, _PITCH_FIELDS, "feature settings: pitch", "holds", "pitch."
            )
            kwargs["pitch"] = PitchSettings(**pitch)
        try:
            settings = cls(**kwargs)
        except ValueError as exc:  # a level that is no "none" or "speech <dB> dBFS"
            raise InputError(f"feature settings: {exc}") from None
        if not settings.fmin_hz < settings.fmax_hz <= settings.sample_rate / 2:
            raise InputError(
                f"feature settings: fmin_hz {settings.fmin_hz:g} and fmax_hz {settings.fmax_hz:g} must be "
                f"0 <= fmin_hz < fmax_hz <= half the sample rate ({settings.sample_rate / 2:g} Hz)"
            )
        if not settings.pitch.floor_hz < settings.pitch.ceiling_hz:
            raise InputError("feature settings: pitch.floor_hz must be below pitch.ceiling_hz")
        return settings

    @classmethod
    def from_manifest(cls, manifest: Any) -> FeatureSettings:
        """The settings a dataset's features were computed with: from its manifest (a dict as
        ``dataset.read_manifest`` returns it, or the dataset folder or its ``manifest.json``), or from the
        copy of it a training checkpoint keeps (``payload["dataset"]``, or its ``features`` entry).
        Use these, not ``FeatureSettings()``, to compute features a run or a dataset's statistics fit:
        the defaults are not a build's (a build normalises the speech level, ``DEFAULT_LEVEL``).
        Settings that are missing or malformed are an ``InputError`` (``from_json``)."""
        if isinstance(manifest, (str, Path)):
            from .manifest import read_manifest  # the manifest module imports this one

            manifest = read_manifest(manifest)
        if not isinstance(manifest, dict):
            raise InputError(f"not a dataset manifest (a JSON object), but {type(manifest).__name__}")
        features = manifest.get("features", manifest)  # a manifest, or its features entry
        if not isinstance(features, dict) or not isinstance(features.get("settings"), dict):
            raise InputError("the manifest records no feature settings (features.settings)")
        return cls.from_json(features["settings"])


def _count(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v > 0


def _checked(data: Any, cls: type, tests: tuple, what: str, hold: str, prefix: str) -> dict[str, Any]:
    """``data`` as the JSON object of dataclass ``cls``: no field ``cls`` lacks, each field of ``tests``
    passing its test; else an ``InputError`` saying so (``what``: the object in the message)."""
    if not isinstance(data, dict):
        raise InputError(f"{what} must be a JSON object, not {data!r:.60}")
    known = {f.name for f in fields(cls)}
    unknown = sorted(str(k) for k in data if k not in known)
    if unknown:
        raise InputError(f"{what} {hold} unknown field(s) {', '.join(unknown)}")
    for name, test, wanted in tests:
        if name in data and not test(data[name]):
            raise InputError(f"feature settings: {prefix}{name} must be {wanted}, not {data[name]!r:.60}")
    return data


# What each field of FeatureSettings.from_json must hold: (field, test, what the test asks for).
_SETTINGS_FIELDS = (
    ("sample_rate", _count, "a positive whole number of Hz"),
    ("window_s", lambda v: is_finite_number(v) and v > 0, "a positive number of seconds"),
    ("hop_s", lambda v: is_finite_number(v) and v > 0, "a positive number of seconds"),
    ("n_fft", _count, "a positive whole number"),
    ("n_mels", _count, "a positive whole number"),
    ("n_mfcc", _count, "a positive whole number"),
    ("fmin_hz", lambda v: is_finite_number(v) and v >= 0, "a number of Hz, at least 0"),
    ("fmax_hz", lambda v: is_finite_number(v) and v > 0, "a positive number of Hz"),
    ("level", lambda v: isinstance(v, str), "text ('none' or 'speech <dB> dBFS')"),
)
_PITCH_FIELDS = (
    ("floor_hz", lambda v: is_finite_number(v) and v > 0, "a positive number of Hz"),
    ("ceiling_hz", lambda v: is_finite_number(v) and v > 0, "a positive number of Hz"),
    ("method", lambda v: isinstance(v, str), "text"),
)


def parse_features(spec: str | list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """Feature names from a comma list, in canonical order; rejects unknown names."""
    names = [s.strip().lower() for s in (spec.split(",") if isinstance(spec, str) else spec)]
    names = [n for n in names if n]
    bad = [n for n in names if n not in FEATURES]
    if bad:
        raise InputError(f"unknown feature(s) {', '.join(bad)} (known: {', '.join(FEATURES)})")
    return tuple(n for n in FEATURES if n in names)


def _level_target(text: str) -> float | None:
    if text == "none":
        return None
    parts = text.split()
    if len(parts) == 3 and parts[0] == "speech" and parts[2] == "dBFS":
        try:
            target = float(parts[1])
        except ValueError:
            target = math.nan
        if -80.0 <= target <= 0.0:
            return target
    raise ValueError(f"level {text!r} is not 'none' or 'speech <dB between -80 and 0> dBFS'")


def parse_level(spec: str) -> str:
    """The settings' ``level`` from ``none``, ``speech`` (-26 dBFS), a target in dBFS (``-23``) or the
    stored form ``speech -23 dBFS``; a ``ValueError`` for anything else."""
    spec = " ".join(str(spec).split())
    if spec.lower() == "none":
        return "none"
    if spec.lower() == "speech":
        return DEFAULT_LEVEL
    try:
        spec = f"speech {float(spec):g} dBFS"
    except ValueError:
        pass
    _level_target(spec)
    return spec


def speech_level(audio: np.ndarray, sample_rate: int) -> float | None:
    """Active speech level of ``audio`` in dBFS (RMS over the frames where speech is active), or None for
    silent audio (peak under -70 dBFS).

    In the spirit of ITU-T P.56: 10 ms frames are active when their level is within 15.9 dB of the
    active level (with a 200 ms hangover), found as the fixed point of that rule reached from the level
    of the whole take upward, so a click or a loud stretch does not set it and pauses do not lower it."""
    x = np.asarray(audio).ravel()
    if x.size == 0:
        return None
    dc = float(x.mean(dtype=np.float64))  # a DC offset is no speech
    if max(abs(float(x.max()) - dc), abs(float(x.min()) - dc)) < SILENT_PEAK:
        return None
    step = max(1, int(round(LEVEL_FRAME_S * sample_rate)))
    n = max(1, x.size // step)
    power = np.zeros(n)
    rows = max(1, (1 << 20) // step)  # a block of frames at a time: memory stays small for long audio
    for r in range(0, n, rows):
        block = np.zeros((min(rows, n - r), step))
        part = x[r * step : (r + block.shape[0]) * step]
        block.ravel()[: part.size] = part - dc
        power[r : r + block.shape[0]] = np.mean(block * block, axis=1)
    db = 10.0 * np.log10(np.maximum(power, 1e-20))
    hang = int(round(LEVEL_HANGOVER_S / LEVEL_FRAME_S))
    level = 10.0 * np.log10(max(float(power.mean()), 1e-20))
    for _ in range(100):
        onset = (db >= level - LEVEL_MARGIN_DB).astype(np.int64)
        counts = np.cumsum(onset)
        behind = np.concatenate([np.zeros(hang + 1, np.int64), counts[: -hang - 1]])[:n]
        active = counts - behind > 0  # an active frame within the last `hang` frames (or this one)
        new = 10.0 * np.log10(max(float(power[active].mean()), 1e-20))
        if new - level < 0.01:
            level = max(level, new)
            break
        level = new
    return level


def level_gain(audio: np.ndarray, settings: FeatureSettings) -> float:
    """Factor that brings ``audio``'s active speech level to the settings' target (1 without a target
    or for silent audio; at most +-60 dB)."""
    if settings.level_target_db is None:
        return 1.0
    return gain_for_level(speech_level(audio, settings.sample_rate), settings)


def gain_for_level(level: float | None, settings: FeatureSettings) -> float:
    """``level_gain`` for audio whose active speech level (``speech_level``) is ``level`` dBFS."""
    target = settings.level_target_db
    if target is None or level is None:
        return 1.0
    gain_db = float(np.clip(target - level, -MAX_LEVEL_GAIN_DB, MAX_LEVEL_GAIN_DB))
    return 10.0 ** (gain_db / 20.0)


def mel_filters(settings: FeatureSettings) -> np.ndarray:
    """(n_mels, n_fft // 2 + 1) triangular HTK-mel filters, area-normalised (Slaney style)."""

    def hz_to_mel(f):
        return 2595.0 * np.log10(1.0 + np.asarray(f, np.float64) / 700.0)

    def mel_to_hz(m):
        return 700.0 * (10.0 ** (np.asarray(m, np.float64) / 2595.0) - 1.0)

    n_bins = settings.n_fft // 2 + 1
    freqs = np.linspace(0.0, settings.sample_rate / 2.0, n_bins)
    edges = mel_to_hz(
        np.linspace(hz_to_mel(settings.fmin_hz), hz_to_mel(settings.fmax_hz), settings.n_mels + 2)
    )
    fb = np.zeros((settings.n_mels, n_bins))
    for m in range(settings.n_mels):
        lo, mid, hi = edges[m], edges[m + 1], edges[m + 2]
        up = (freqs - lo) / max(mid - lo, 1e-9)
        down = (hi - freqs) / max(hi - mid, 1e-9)
        fb[m] = np.maximum(0.0, np.minimum(up, down)) * (2.0 / (hi - lo))
    return fb


def dct_matrix(n_in: int, n_out: int) -> np.ndarray:
    """(n_out, n_in) orthonormal DCT-II, the MFCC transform."""
    k = np.arange(n_out)[:, None]
    n = np.arange(n_in)[None, :]
    m = np.cos(np.pi / n_in * (n + 0.5) * k) * np.sqrt(2.0 / n_in)
    m[0] /= np.sqrt(2.0)
    return m


def n_analysis_frames(n_samples: int, settings: FeatureSettings) -> int:
    """Frames on the analysis grid for ``n_samples`` of audio (centres 0, hop, 2 hop, ...)."""
    return 1 + n_samples // settings.hop_length


SPECTRAL_BLOCK = 2048  # analysis frames computed at a time (41 s of audio at a 20 ms hop)
_SCALE_BLOCK = 1 << 18  # samples scaled by the level gain at a time


def spectral_features(
    audio: np.ndarray,
    settings: FeatureSettings,
    block: int = SPECTRAL_BLOCK,
    tick: Callable[[], None] | None = None,
    gain: float = 1.0,
) -> dict[str, np.ndarray]:
    """Log energy (frames,), log-mel filter banks (frames, n_mels) and MFCC (frames, n_mfcc) on the
    analysis grid of ``audio`` scaled by ``gain`` (float32 ``audio * np.float32(gain)``, made in the
    padded copy). Computed block by block so memory stays bounded for long takes; ``tick`` is called
    after each block of ``block`` frames."""
    x = np.asarray(audio, np.float32)
    win, hop = settings.win_length, settings.hop_length
    pad = win // 2
    n = n_analysis_frames(x.size, settings)
    # x reflected at both ends by half a window (zeros when too short to reflect), then zeros up to the
    # last frame's end: one copy of the audio, not one per step
    padded = np.zeros(max(x.size + 2 * pad, (n - 1) * hop + win), np.float32)
    if gain == 1.0:
        padded[pad : pad + x.size] = x
    else:  # scaled a block at a time into the copy: no scaled copy of an hour of audio besides
        for lo in range(0, x.size, _SCALE_BLOCK):
            part = x[lo : lo + _SCALE_BLOCK]
            padded[pad + lo : pad + lo + part.size] = part * np.float32(gain)
    if x.size > pad:  # reflected from the (scaled) samples in place: x[pad:0:-1] and x[-2:-pad-2:-1]
        padded[:pad] = padded[2 * pad : pad : -1]
        padded[pad + x.size : 2 * pad + x.size] = padded[pad + x.size - 2 : x.size - 2 : -1]
    window = np.hanning(win + 2)[1:-1].astype(np.float32)  # periodic-ish Hann without zero ends
    mel = mel_filters(settings).astype(np.float32).T
    dct = dct_matrix(settings.n_mels, settings.n_mfcc).astype(np.float32).T
    energy = np.empty(n, np.float32)
    fbank = np.empty((n, settings.n_mels), np.float32)
    frames_view = np.lib.stride_tricks.sliding_window_view(padded, win)[::hop][:n]
    for start in range(0, n, block):
        frames = frames_view[start : start + block].astype(np.float32)
        energy[start : start + block] = 0.5 * np.log(np.mean(frames * frames, axis=1) + 1e-10)
        spec = scipy.fft.rfft(frames * window, n=settings.n_fft, axis=1)  # float32 in, complex64 out
        power = (spec.real**2 + spec.imag**2).astype(np.float32)
        fbank[start : start + block] = np.log(np.maximum(power @ mel, 1e-10))
        if tick is not None:
            tick()
    return {"energy": energy, "fbank": fbank, "mfcc": fbank @ dct}


def to_animation_rate(values: np.ndarray, hop_s: float, n_frames: int, fps: float) -> np.ndarray:
    """Linear interpolation of analysis-grid ``values`` (frames at ``k * hop_s`` s) to the animation
    frames at ``i / fps`` s; float32, ``(n_frames, ...)``. Holds the ends flat."""
    dst_t = np.arange(n_frames) / fps
    pos = np.clip(dst_t / hop_s, 0.0, values.shape[0] - 1)
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, values.shape[0] - 1)
    w = (pos - lo).astype(np.float32)
    if values.ndim == 1:
        return (values[lo] * (1 - w) + values[hi] * w).astype(np.float32)
    return (values[lo] * (1 - w)[:, None] + values[hi] * w[:, None]).astype(np.float32)


# compute_features refuses audio whose length at the settings' rate is further than this fraction (or two
# animation frames) from the animation's span: audio at another rate (44.1 kHz is 2.76 times as long)
LENGTH_TOLERANCE = 0.2


def check_feature_audio(
    audio: Any, n_frames: int, fps: float, settings: FeatureSettings, sample_rate: int | None = None
) -> np.ndarray:
    """``audio`` as the 1-D float samples ``compute_features`` needs, or an ``InputError`` saying what
    is wrong with it (see ``compute_features``)."""
    rate = settings.sample_rate
    if sample_rate is not None and sample_rate != rate:
        raise InputError(
            f"audio at {sample_rate} Hz, but the feature settings are for {rate} Hz: resample it first "
            f"(align.resample.to_16k_mono)"
        )
    x = np.asarray(audio)
    if x.ndim == 2 and x.shape[1] == 1:
        x = x[:, 0]
    if x.ndim != 1:
        raise InputError(f"audio must be mono samples (1-D), not an array of shape {x.shape}: mix it down")
    if x.dtype.kind != "f":
        raise InputError(
            f"audio must be float samples (full scale 1.0), not {x.dtype} (PCM: divide by its full scale, "
            "32768 for int16)"
        )
    # counted a block at a time: two boolean copies of an hour of audio are 115 MB
    bad = sum(
        int(np.count_nonzero(~np.isfinite(x[lo : lo + _SCALE_BLOCK])))
        for lo in range(0, x.size, _SCALE_BLOCK)
    )
    if bad:
        raise InputError(f"audio holds {bad} NaN or infinite sample(s): features would be NaN")
    if n_frames > 0 and fps > 0:
        span = n_frames / fps
        held = x.size / rate
        if abs(held - span) > max(LENGTH_TOLERANCE * span, 2.0 / fps):
            raise InputError(
                f"audio holds {held:.3f} s at the settings' {rate} Hz, but {n_frames} frames at {fps:g} fps "
                f"span {span:.3f} s: audio at another sample rate (resample it to {rate} Hz), or frames "
                "that are not this audio's?"
            )
    return x


class _Count:
    """One part of ``compute_features``' work (``part``: ``total`` ``unit``), said to its ``on_block``
    as it begins (0 done) and after each unit done."""

    def __init__(self, on_block, part: str, total: int, unit: str) -> None:
        self.on_block, self.part, self.total, self.unit, self.done = on_block, part, total, unit, 0
        if on_block is not None:  # said as the part begins: its rate is timed from here
            on_block(part, 0, total, unit)

    def tick(self) -> None:
        self.done = min(self.done + 1, self.total)
        if self.on_block is not None:
            self.on_block(self.part, self.done, self.total, self.unit)

    def finish(self) -> None:  # audio too short to track pitch in tracks no piece
        if self.done < self.total:
            self.done = self.total - 1
            self.tick()


def compute_features(
    audio: np.ndarray,
    n_frames: int,
    fps: float,
    names: tuple[str, ...],
    settings: FeatureSettings,
    ppg=None,
    transcript: str | None = None,
    gain: float | None = None,
    sample_rate: int | None = None,
    on_block: Callable[[str, int, int, str], None] | None = None,
) -> tuple[dict[str, np.ndarray], np.ndarray | None]:
    """Every requested feature for one take, at the animation rate.

    ``audio`` is mono float32 at ``settings.sample_rate`` Hz starting at take time 0; ``n_frames`` and
    ``fps`` (Hz) describe the animation grid. Returns ``{name: (n_frames, dim) float32}`` (pitch is
    (n_frames, 2): log-F0 and voicing) and the per-frame phone ids (int16, -1 unknown) when the PPG
    backend knows phones, else None. ``transcript`` (the words spoken) lets a PPG backend that can
    (pocketsphinx) force-align instead of recognising phones. With a speech level in the settings the
    audio is scaled by ``level_gain`` first (``gain``, when the caller has measured it already).

    The audio must be what the settings describe (``check_feature_audio``): an ``InputError`` for
    ``sample_rate`` (the audio's rate, when the caller knows it) other than ``settings.sample_rate``,
    audio whose length at ``settings.sample_rate`` is far from ``n_frames / fps`` seconds (audio at
    another rate: resample it, as ``align.resample.to_16k_mono`` does), audio that is not mono float
    samples, and NaN or infinite samples.

    ``on_block(part, done, total, unit)``: called as each part of the work begins and goes on, so that an
    hour of audio can say how far it has come: ``spectra`` (``SPECTRAL_BLOCK`` analysis frames a block),
    ``pitch`` (``pitch.CHUNK_S`` of audio a piece), ``ppg`` (at once).
    """
    audio = check_feature_audio(audio, n_frames, fps, settings, sample_rate)
    gain = level_gain(audio, settings) if gain is None else gain
    # the spectra and the pitch tracker scale their own copies (audio * np.float32(gain), the same
    # samples): an hour of scaled audio besides the caller's is 230 MB
    blocks = -(-n_analysis_frames(audio.size, settings) // SPECTRAL_BLOCK)
    spectral = spectral_features(
        audio, settings, tick=_Count(on_block, "spectra", blocks, "blocks").tick, gain=gain
    )
    n_an = spectral["energy"].shape[0]
    out: dict[str, np.ndarray] = {}
    phones = None
    for name in names:
        if name in ("energy", "fbank", "mfcc"):
            grid = spectral[name]
            if grid.ndim == 1:
                grid = grid[:, None]
        elif name == "pitch":
            pieces = _Count(on_block, "pitch", len(pitch_pieces(audio.size, settings.sample_rate)), "pieces")
            grid = track_pitch(
                audio, settings.sample_rate, n_an, settings.hop_s, settings.pitch, pieces.tick, gain
            )
            pieces.finish()
        elif name == "ppg":
            if ppg is None:
                raise InputError("feature 'ppg' requested but no PPG backend given (use --ppg)")
            scaled = audio if gain == 1.0 else np.asarray(audio, np.float32) * np.float32(gain)
            result = ppg.extract(scaled, spectral["fbank"], transcript)
            del scaled
            _Count(on_block, "ppg", 1, "passes").tick()
            grid = result.posteriors
            if result.phone_ids is not None:
                pos = np.clip(np.round(np.arange(n_frames) / fps / settings.hop_s), 0, n_an - 1)
                phones = result.phone_ids[pos.astype(np.int64)].astype(np.int16)
        else:  # pragma: no cover - parse_features rejects these
            raise InputError(f"unknown feature {name!r}")
        out[name] = to_animation_rate(grid, settings.hop_s, n_frames, fps)
    if "pitch" in out:
        out["pitch"][:, 1] = (out["pitch"][:, 1] >= 0.5).astype(np.float32)
    return out, phones
