"""Voice-activity detection: where the speech is, to trim leading and trailing silence (as the paper does).

``silero``: the silero-vad package's bundled model (shipped inside the wheel; nothing is downloaded),
loaded once per process without torchaudio: its sequence ONNX export under onnxruntime when available,
else its TorchScript model under torch. ``webrtc``: the lighter WebRTC GMM detector (``webrtcvad``, from
the optional ``webrtcvad-wheels`` package). ``none``: no detection, the whole audio counts as speech.

Both detectors are trained on speech at ordinary recording levels and lose quiet speech: a simulated
take (silero) at a peak of -55 dBFS kept 286 of its 353 frames, at -60 dBFS 88, at -65 dBFS none ("no
speech"). So they are given the audio raised to ``VAD_LEVEL_DBFS`` when its speech is quieter than
that (``vad_gain``), a block at a time (``detector_blocks``: no raised copy of the take); the detectors
only say where the speech is, and the audio written keeps its level.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable, Iterator
from importlib import resources
from typing import Any

import numpy as np

from capture import InputError
from capture.runs import runs

from .resample import TARGET_RATE, in_rows
from .torch_threads import torch_threads

# Speech level (``speech_level_dbfs``) the detectors see at least: quieter audio is raised to it for
# detection. The real recordings checked (NeuroSync, FACEGOOD, LibriVox) speak at -12..-22 dBFS and
# the simulated takes at -8..-30 dBFS, and are left as they are. On a simulated take, silero finds
# all of the speech down to -55 dBFS and WebRTC down to about -35 dBFS (at -45 it loses a quarter).
VAD_LEVEL_DBFS = -35.0
MAX_VAD_GAIN_DB = 60.0  # the silent-track limit is -70 dBFS: more gain would only raise noise
LEVEL_FRAME_S = 0.032
LEVEL_PERCENTILE = 98.0

_SILERO = None
SEQUENCE_MODEL = "silero_vad_16k_sequence.onnx"


def _silero_model():
    """The bundled silero model: the sequence ONNX export run by onnxruntime when both are there (it
    takes up to 512 windows per call, about 8x faster than the TorchScript model stepped window by
    window), else the TorchScript model. Same network, same speech segments."""
    global _SILERO
    if _SILERO is None:
        try:
            with torch_threads(None):  # the package sets one torch thread for the process when imported
                import silero_vad
        except ImportError:
            raise InputError("--vad silero needs the package silero-vad (or use --vad webrtc/none)") from None
        _SILERO = _sequence_model(silero_vad)
        if _SILERO is None:
            with warnings.catch_warnings():  # the package's own deprecation notices (importlib, torch.jit)
                warnings.simplefilter("ignore", DeprecationWarning)
                _SILERO = ("torch", silero_vad.load_silero_vad())
    return _SILERO


def _sequence_model(silero_vad):
    if not hasattr(silero_vad, "SileroVADSequence"):
        return None
    try:
        import onnxruntime  # noqa: F401
    except ImportError:
        return None
    path = resources.files("silero_vad") / "data" / SEQUENCE_MODEL
    if not path.is_file():
        return None
    return ("onnx", silero_vad.SileroVADSequence(str(path)))


# Samples the detectors are given at a time (raised by the gain a block at a time: the raised copy of
# all of a 2 h take was 460 MB, and twice that while it was clipped): 512 of silero's 512-sample windows,
# the sequence model's own block, so that it runs the very calls it ran on the whole array.
DETECTOR_BLOCK = 512 * 512


# 16 kHz mono audio: all of it, or its samples in order given in blocks of any lengths, one pass through
# them (``align.resample.to_16k_passes``: a long take never whole in memory)
Samples = np.ndarray | Iterable[np.ndarray]


def in_blocks(x: Samples, size: int) -> Iterator[np.ndarray]:
    """The samples ``x`` in blocks of ``size`` (the last shorter): an array sliced, blocks given joined
    and cut."""
    if isinstance(x, np.ndarray):
        for lo in range(0, x.size, size):
            yield x[lo : lo + size]
        return
    for rows in in_rows(x, size, tail=True):
        yield from rows


def detector_blocks(x: Samples, gain: float = 1.0, size: int = DETECTOR_BLOCK) -> Iterator[np.ndarray]:
    """``x`` as float32 blocks of ``size`` samples (the last shorter), raised by ``gain`` and clipped to
    [-1, 1] when it is not 1: sample for sample the whole array raised and clipped, one block at a time."""
    for block in in_blocks(x, size):
        if gain != 1.0:
            block = np.clip(block * np.float32(gain), -1.0, 1.0)
        yield np.ascontiguousarray(block, dtype=np.float32)


def silero_segments(x: Samples, min_silence_s: float = 0.3, gain: float = 1.0) -> list[tuple[float, float]]:
    """Speech segments (start_s, end_s) of 16 kHz mono float32 audio, raised by ``gain`` for the detector
    (``detector_blocks``), by silero-vad (32 ms windows). The model's state runs on from block to block:
    the probabilities, and so the segments, are those of the whole array in one call."""
    kind, model = _silero_model()  # first: it imports the package with the caller's torch threads kept
    from silero_vad import get_speech_timestamps_from_probs

    seen = [0]  # samples given to the model

    def counted() -> Iterator[np.ndarray]:
        for block in detector_blocks(x, gain):
            seen[0] += block.size
            yield block

    probs = _sequence_probs(model, counted()) if kind == "onnx" else _torch_probs(model, counted())
    stamps = get_speech_timestamps_from_probs(
        probs,
        sampling_rate=TARGET_RATE,
        min_silence_duration_ms=int(min_silence_s * 1000),
        speech_pad_ms=0,
        audio_length_samples=seen[0],
    )
    return [(s["start"] / TARGET_RATE, s["end"] / TARGET_RATE) for s in stamps]


def _sequence_probs(model: Any, blocks: Iterable[np.ndarray]) -> np.ndarray:
    """Per-window speech probabilities of the sequence model over ``blocks`` (``DETECTOR_BLOCK`` samples,
    the last shorter), one ONNX call a block as ``SileroVADSequence.audio_forward`` makes them (its
    ``frame_blocks``), the state and each window's context carried on from the block before."""
    from silero_vad.sequence_vad import RATE_CONFIG, frame_blocks

    window, context = RATE_CONFIG[TARGET_RATE]
    hidden, cell = np.zeros((1, 1, 128), np.float32), np.zeros((1, 1, 128), np.float32)
    before = np.zeros(context, np.float32)  # the end of the last window of the block before
    probs = [np.zeros(0, np.float32)]
    for block in blocks:
        for frames in frame_blocks(block, window, context, DETECTOR_BLOCK // window):
            frames[0, :context] = before
            before = frames[-1, -context:].copy()
            values, hidden, cell = model.session.run(
                ["speech_probs", "hn", "cn"], {"input": frames, "h": hidden, "c": cell}
            )
            probs.append(values.reshape(-1))
    return np.concatenate(probs)  # float32, as audio_forward gives them (compared as float32)


def _torch_probs(model: Any, blocks: Iterable[np.ndarray]) -> list[float]:
    """Per-window speech probabilities of the TorchScript model over ``blocks`` (whole windows but the
    last), window by window as ``silero_vad.get_speech_timestamps`` steps it, the last zero-padded."""
    import torch

    window = 512
    probs: list[float] = []
    # Takes run in parallel processes; one thread each is fastest overall (the caller keeps its own).
    with torch.inference_mode(), torch_threads(1):
        model.reset_states()
        for block in blocks:
            for lo in range(0, block.size, window):
                chunk = block[lo : lo + window]
                if chunk.size < window:
                    chunk = np.concatenate([chunk, np.zeros(window - chunk.size, np.float32)])
                probs.append(model(torch.from_numpy(chunk), TARGET_RATE).item())
        model.reset_states()
    return probs


WEBRTC_FRAME = TARGET_RATE * 30 // 1000  # 30 ms


def webrtc_segments(
    x: Samples, aggressiveness: int = 2, min_silence_s: float = 0.3, gain: float = 1.0
) -> list[tuple[float, float]]:
    """Speech segments (start_s, end_s) of 16 kHz mono float32 audio, raised by ``gain`` for the detector
    (``detector_blocks``), by the WebRTC detector (30 ms frames), made 16-bit a block at a time (the
    int16 copy of a 2 h take and its float temporaries took 870 MB)."""
    vad = _webrtcvad().Vad(aggressiveness)
    hop = WEBRTC_FRAME
    flags: list[bool] = []
    for block in detector_blocks(x, gain, DETECTOR_BLOCK // hop * hop):
        block = block[: block.size // hop * hop]  # the last: its whole frames
        pcm = np.clip(np.rint(block * 32768.0), -32768, 32767).astype("<i2")
        flags += [vad.is_speech(pcm[i : i + hop].tobytes(), TARGET_RATE) for i in range(0, pcm.size, hop)]
    return runs_to_segments(np.array(flags), 0.03, min_silence_s, min_speech_s=0.09)


def _webrtcvad():
    """The ``webrtcvad`` module; an ``InputError`` naming its package when it is not installed."""
    try:
        import webrtcvad
    except ImportError:
        raise InputError("--vad webrtc needs the package webrtcvad (pip install webrtcvad-wheels)") from None
    return webrtcvad


def check_detector(method: str) -> None:
    """An ``InputError`` naming the package the detector ``method`` (silero or webrtc) needs when it is not
    installed, before any audio is read for it (silero's model is loaded, once per process)."""
    if method == "silero":
        _silero_model()
    elif method == "webrtc":
        _webrtcvad()


def runs_to_segments(
    flags: np.ndarray, step_s: float, min_silence_s: float, min_speech_s: float
) -> list[tuple[float, float]]:
    """Runs of True in per-step flags as (start_s, end_s), closing silences shorter than ``min_silence_s``."""
    if flags.size == 0:
        return []
    spans = [[a * step_s, b * step_s] for a, b in runs(flags)]
    merged: list[list[float]] = []
    for r in spans:
        if merged and r[0] - merged[-1][1] < min_silence_s:
            merged[-1][1] = r[1]
        else:
            merged.append(r)
    return [(a, b) for a, b in merged if b - a >= min_speech_s]


def speech_level_dbfs(x: Samples) -> float:
    """Level (dBFS RMS) of the loud parts of 16 kHz mono audio: the ``LEVEL_PERCENTILE`` percentile of the
    RMS of its ``LEVEL_FRAME_S`` frames (a clap or a click a few frames long does not set it, nor do the
    pauses between words), measured a block at a time. ``-inf`` for digital silence."""
    hop = int(LEVEL_FRAME_S * TARGET_RATE)
    levels, rest = [np.zeros(0)], np.zeros(0, np.float32)
    for block in in_blocks(x, DETECTOR_BLOCK):  # whole frames but the last
        n = block.size // hop
        frames = block[: n * hop].reshape(n, hop)
        levels.append(np.sqrt(np.einsum("ij,ij->i", frames, frames, dtype=np.float64) / hop))
        rest = block[n * hop :]
    rms = np.concatenate(levels)
    if rms.size == 0:  # shorter than a frame
        whole = np.sqrt(np.mean(np.square(rest, dtype=np.float64))) if rest.size else 0.0
        return 20.0 * float(np.log10(whole)) if whole > 0 else float("-inf")
    level = float(np.percentile(rms, LEVEL_PERCENTILE))
    return 20.0 * float(np.log10(level)) if level > 0 else float("-inf")


def vad_gain(x: Samples, level_dbfs: float | None = None) -> float:
    """Gain (linear, >= 1) that raises audio whose speech is quieter than ``VAD_LEVEL_DBFS`` to that
    level (at most ``MAX_VAD_GAIN_DB``); 1 for audio at an ordinary level. ``level_dbfs``: the speech
    level (``speech_level_dbfs``) when the caller has measured it already."""
    level = speech_level_dbfs(x) if level_dbfs is None else level_dbfs
    if not np.isfinite(level) or level >= VAD_LEVEL_DBFS:
        return 1.0
    return float(10 ** (min(VAD_LEVEL_DBFS - level, MAX_VAD_GAIN_DB) / 20))


def speech_segments(x: Samples, method: str, gain: float | None = None) -> list[tuple[float, float]]:
    """Speech segments (start_s, end_s) of 16 kHz mono audio; ``method`` is silero, webrtc or none.
    Quiet audio is raised for the detector by ``gain`` (default ``vad_gain(x)``: give it for audio given
    in blocks, a pass that is gone once read) a block at a time (``detector_blocks``); ``x`` itself is
    not changed, nor copied whole."""
    if method == "none":
        return [(0.0, _count(x) / TARGET_RATE)]
    gain = vad_gain(x) if gain is None else gain
    if method == "silero":
        return silero_segments(x, gain=gain)
    if method == "webrtc":
        return webrtc_segments(x, gain=gain)
    return [(0.0, _count(x) / TARGET_RATE)]


def _count(x: Samples) -> int:
    return x.size if isinstance(x, np.ndarray) else sum(block.size for block in x)
