"""Phonetic posteriorgrams (PPG): one extractor interface, three kinds of backend.

Every backend turns a take's 16 kHz speech into a (frames, dim) float32 matrix on the preprocessor's
20 ms analysis grid (``features.py`` interpolates it to the animation rate):

- ``bottleneck``: the paper's 64-dim ASR bottleneck. ``BottleneckPPG`` (``bottleneck.py``) is a small
  network (log-mel filter banks in, convolutions, a 64-dim linear bottleneck, a phone classifier on top for
  training). ``s2a-train ppg`` trains it; the build loads its checkpoint with
  ``torch.load(weights_only=True)``, so no pickled code is ever run.
- ``torchscript`` / ``onnx``: a user's model. Input: log-mel filter banks ``(1, frames, n_mels)``
  float32 exactly as the preprocessor computes them; output ``(1, frames, dim)``.
- ``pocketsphinx``: phone posteriors from the English acoustic model bundled with the ``pocketsphinx``
  wheel: phone-loop recognition, each decoded phone segment turned into one-hot frames.
"""

from __future__ import annotations

import hashlib
from dataclasses import asdict
from pathlib import Path
from typing import Any, NamedTuple, Protocol

import numpy as np

from capture.errors import InputError
from capture.take import sha256_file

from .features import FeatureSettings
from .phones import ARPABET

# what a model file is probed with at load: half a second of silence and the build's filter-bank width
_PROBE_AUDIO = np.zeros(1600, np.float32)
_PROBE_FBANK = np.zeros((5, FeatureSettings.n_mels), np.float32)

BACKENDS = ("none", "bottleneck", "torchscript", "onnx", "pocketsphinx")


class PPGResult(NamedTuple):
    """``posteriors`` (frames, dim) float32 on the 20 ms grid; ``phone_ids`` (frames,) int or None."""

    posteriors: np.ndarray
    phone_ids: np.ndarray | None


class PPGExtractor(Protocol):
    """What the preprocessor needs from a PPG backend."""

    name: str
    dim: int
    phones: list[str] | None

    def extract(self, audio: np.ndarray, fbank: np.ndarray, transcript: str | None = None) -> PPGResult:
        """``audio``: mono float32 at 16 kHz; ``fbank``: (frames, n_mels) log-mel on the 20 ms grid;
        ``transcript``: the words spoken, when known (backends that cannot use it ignore it)."""
        ...

    def describe(self) -> dict[str, Any]:
        """Backend, dimension, model checksum and library versions, for the manifest."""
        ...


def _torch():
    try:
        import torch
    except ImportError:  # pragma: no cover - torch is a dependency
        raise InputError("PyTorch is not installed; this PPG backend needs it") from None
    return torch


def _one_thread():
    """One torch thread while a model runs (bit-identical results from run to run); the caller's own
    thread count is given back afterwards."""
    from align.torch_threads import torch_threads

    return torch_threads(1)


class BottleneckExtractor:
    name = "bottleneck"

    def __init__(self, checkpoint: str | Path):
        _torch()
        self.path = Path(checkpoint)
        from .bottleneck import load_bottleneck

        self.model = load_bottleneck(self.path)
        self.dim = self.model.config.bottleneck
        self.phones = list(self.model.config.phones)
        self._sha = sha256_file(self.path)

    def extract(self, audio: np.ndarray, fbank: np.ndarray, transcript: str | None = None) -> PPGResult:
        torch = _torch()
        if fbank.shape[1] != self.model.config.n_mels:
            raise InputError(
                f"PPG checkpoint expects {self.model.config.n_mels} mel bins, got {fbank.shape[1]}"
            )
        with torch.inference_mode(), _one_thread():
            b, logits = self.model(torch.from_numpy(np.ascontiguousarray(fbank, np.float32))[None])
        return PPGResult(b[0].numpy().astype(np.float32), logits[0].argmax(-1).numpy().astype(np.int16))

    def describe(self) -> dict[str, Any]:
        torch = _torch()
        return {
            "backend": self.name,
            "dim": self.dim,
            "model": self.path.name,
            "model_sha256": self._sha,
            "config": asdict(self.model.config),
            "input": "log-mel filter banks on the 20 ms grid",
            "versions": {"torch": torch.__version__.split("+")[0]},
        }


# ----------------------------------------------------------------------------------- user models


MAX_PPG_DIM = 4096  # phone posteriors or a bottleneck: tens to hundreds of values per frame


def _check_output(out: np.ndarray, frames: int, path: Path) -> np.ndarray:
    """A user model's output as (frames, dim), checked: shape, 1..MAX_PPG_DIM values per frame, finite."""
    out = np.asarray(out, np.float32)
    if out.ndim == 3 and out.shape[0] == 1:
        out = out[0]
    if out.ndim != 2 or out.shape[0] != frames or not 1 <= out.shape[1] <= MAX_PPG_DIM:
        raise InputError(
            f"PPG model returned shape {tuple(out.shape)}; expected (1, {frames}, dim) with dim in "
            f"1..{MAX_PPG_DIM}",
            path,
        )
    if not np.isfinite(out).all():
        raise InputError(f"PPG model returned {int((~np.isfinite(out)).sum())} NaN or infinite values", path)
    return out


class TorchScriptExtractor:
    name = "torchscript"

    def __init__(self, model_path: str | Path):
        torch = _torch()
        self.path = Path(model_path)
        if not self.path.is_file():
            raise InputError("TorchScript model not found", self.path)
        try:
            with open(self.path, "rb") as f:  # open here: torch's C++ takes a name as UTF-8 (fails if not)
                self.model = torch.jit.load(f, map_location="cpu").eval()
        except Exception as exc:
            raise InputError(f"not a TorchScript model ({str(exc).splitlines()[0]})", self.path) from None
        self.phones = None
        self._sha = sha256_file(self.path)
        self.dim = self.extract(_PROBE_AUDIO, _PROBE_FBANK).posteriors.shape[1]

    def extract(self, audio: np.ndarray, fbank: np.ndarray, transcript: str | None = None) -> PPGResult:
        torch = _torch()
        with torch.inference_mode(), _one_thread():
            try:
                out = self.model(torch.from_numpy(np.ascontiguousarray(fbank, np.float32))[None])
            except Exception as exc:  # a user's model: its own shape checks fail inside TorchScript
                msg = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
                raise InputError(
                    f"TorchScript model failed on (1, frames, {fbank.shape[1]}) filter banks: {msg}",
                    self.path,
                ) from None
        if isinstance(out, (tuple, list)):
            out = out[0]
        return PPGResult(_check_output(out.numpy(), fbank.shape[0], self.path), None)

    def describe(self) -> dict[str, Any]:
        torch = _torch()
        return {
            "backend": self.name,
            "dim": self.dim,
            "model": self.path.name,
            "model_sha256": self._sha,
            "input": "log-mel filter banks (1, frames, n_mels) on the 20 ms grid",
            "versions": {"torch": torch.__version__.split("+")[0]},
        }


class OnnxExtractor:
    name = "onnx"

    def __init__(self, model_path: str | Path):
        self.path = Path(model_path)
        if not self.path.is_file():
            raise InputError("ONNX model not found", self.path)
        try:
            import onnxruntime as ort
        except ImportError:
            raise InputError("onnxruntime is not installed (pip install onnxruntime)") from None
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = 1
        opts.inter_op_num_threads = 1
        try:
            # its bytes: onnxruntime takes a name as UTF-8 and refused a model whose name is not
            model = self.path.read_bytes()
            self.session = ort.InferenceSession(model, opts, providers=["CPUExecutionProvider"])
        except Exception as exc:
            raise InputError(f"not a usable ONNX model ({str(exc).splitlines()[0]})", self.path) from None
        self._input = self.session.get_inputs()[0].name
        self._version = ort.__version__
        self.phones = None
        self._sha = sha256_file(self.path)
        self.dim = self.extract(_PROBE_AUDIO, _PROBE_FBANK).posteriors.shape[1]

    def extract(self, audio: np.ndarray, fbank: np.ndarray, transcript: str | None = None) -> PPGResult:
        x = np.ascontiguousarray(fbank, np.float32)[None]
        try:
            out = self.session.run(None, {self._input: x})[0]
        except Exception as exc:
            raise InputError(f"ONNX model failed: {str(exc).splitlines()[0]}", self.path) from None
        return PPGResult(_check_output(out, fbank.shape[0], self.path), None)

    def describe(self) -> dict[str, Any]:
        return {
            "backend": self.name,
            "dim": self.dim,
            "model": self.path.name,
            "model_sha256": self._sha,
            "input": "log-mel filter banks (1, frames, n_mels) on the 20 ms grid",
            "versions": {"onnxruntime": self._version},
        }


# ----------------------------------------------------------------------------------- pocketsphinx


class PocketsphinxExtractor:
    """Phone-loop recognition with pocketsphinx's bundled en-us acoustic model and phone LM, or
    forced alignment (word then phone level, the bundled dictionary) when a transcript is given.

    Each recognised phone segment (10 ms decoder frames) becomes one-hot posteriors over ``ARPABET``
    on the 20 ms grid; noise and filler units count as silence."""

    name = "pocketsphinx"

    def __init__(self):
        try:
            import pocketsphinx
        except ImportError:
            raise InputError("pocketsphinx is not installed (pip install pocketsphinx)") from None
        self._ps = pocketsphinx
        self.phones = list(ARPABET)
        self.dim = len(self.phones)
        self._index = {p: i for i, p in enumerate(self.phones)}
        self._lm = pocketsphinx.get_model_path("en-us/en-us-phone.lm.bin")

    def segments(self, audio: np.ndarray, transcript: str | None = None) -> list[tuple[str, int, int]]:
        """Phone segments of 16 kHz ``audio``: (unit, first and last 10 ms decoder frame), by forced
        alignment to ``transcript`` when given and possible, else by phone-loop recognition. Units are
        ARPAbet phones, ``SIL`` and fillers such as ``+NSN+``."""
        pcm = np.rint(np.asarray(audio, np.float64) * 32768.0)
        # Digital silence (runs of exact zeros, as edited or generated audio has) can throw the decoder
        # off: a real FACEGOOD take, 31 % of its samples exact zeros, decoded as 45 % 'HH' and 29 %
        # silence; with one least-significant bit of seeded noise (the same every run) 46 % silence and
        # 7 % 'IY', as its aligned copy without the first 0.25 s decodes anyway.
        pcm += np.random.default_rng(0).integers(-1, 2, pcm.size)
        pcm = np.clip(pcm, -32768, 32767).astype(np.int16)
        segments = self._align(pcm, transcript) if transcript else None
        if segments is None:
            # A fresh decoder per utterance (about 0.15 s): a reused one carries state from the
            # utterances before, so a take's posteriors would depend on which takes a worker saw first.
            d = self._ps.Decoder(
                allphone=self._lm, lw=2.0, pip=0.3, beam=1e-10, pbeam=1e-10, cmn="batch", loglevel="FATAL"
            )
            d.start_utt()
            d.process_raw(pcm.tobytes(), full_utt=True)
            d.end_utt()
            segments = [(seg.word, seg.start_frame, seg.end_frame) for seg in d.seg()]
        return segments

    def extract(self, audio: np.ndarray, fbank: np.ndarray, transcript: str | None = None) -> PPGResult:
        segments = self.segments(audio, transcript)
        frames = fbank.shape[0]
        ids = np.zeros(frames, np.int16)  # silence where nothing was decoded
        for word, start, end in segments:
            pid = self._index.get(word.strip("+").upper(), 0)
            # decoder frames are 10 ms; our grid is 20 ms with centres at k * 20 ms
            a = int(np.ceil(start / 2.0))
            b = int(np.floor(end / 2.0)) + 1
            ids[max(a, 0) : min(b, frames)] = pid
        post = np.zeros((frames, self.dim), np.float32)
        post[np.arange(frames), ids] = 1.0
        return PPGResult(post, ids)

    def _align(self, pcm: np.ndarray, transcript: str) -> list[tuple[str, int, int]] | None:
        """Phone segments (name, first frame, last frame; 10 ms frames) by forced alignment to the
        words of ``transcript``; None when a word is not in the dictionary or alignment fails."""
        d = self._ps.Decoder(loglevel="FATAL", cmn="batch")  # fresh, as in extract
        words = " ".join(
            w for w in "".join(c if c.isalnum() or c in "' " else " " for c in transcript.lower()).split()
        )
        try:
            d.set_align_text(words)
            d.start_utt()
            d.process_raw(pcm.tobytes(), full_utt=True)
            d.end_utt()
            d.set_alignment()  # second pass: phone and state level
            d.start_utt()
            d.process_raw(pcm.tobytes(), full_utt=True)
            d.end_utt()
            alignment = d.get_alignment()
        except (RuntimeError, ValueError, KeyError):
            return None
        if alignment is None:
            return None
        return [(ph.name, ph.start, ph.start + ph.duration - 1) for word in alignment for ph in word]

    def describe(self) -> dict[str, Any]:
        model = Path(self._lm).parent / "en-us"
        digest = hashlib.sha256()
        for p in sorted(model.glob("*")):
            if p.is_file():
                digest.update(p.name.encode() + bytes.fromhex(sha256_file(p)))
        return {
            "backend": self.name,
            "dim": self.dim,
            "phones": self.phones,
            "model": "en-us (bundled), phone LM en-us-phone.lm.bin",
            "model_sha256": digest.hexdigest(),
            "decoder": {"lw": 2.0, "pip": 0.3, "dither_lsb": 1},
            "versions": {"pocketsphinx": getattr(self._ps, "__version__", "5")},
        }


def make_extractor(backend: str, model: str | Path | None = None) -> PPGExtractor | None:
    """The extractor for ``backend`` (one of ``BACKENDS``); ``model`` is the checkpoint or model file."""
    backend = (backend or "none").strip().lower()
    if backend not in (*BACKENDS, "none"):
        raise InputError(f"unknown PPG backend {backend!r} (known: {', '.join(BACKENDS)})")
    if model is not None and backend in ("none", "pocketsphinx"):
        raise InputError(
            f"--ppg-model given, but the PPG backend {backend!r} uses no model file: "
            "choose --ppg bottleneck, torchscript or onnx"
        )
    if backend == "none":
        return None
    if backend == "pocketsphinx":
        return PocketsphinxExtractor()
    if model is None:
        raise InputError(f"PPG backend {backend!r} needs a model file (--ppg-model PATH)")
    if backend == "bottleneck":
        return BottleneckExtractor(model)
    if backend == "torchscript":
        return TorchScriptExtractor(model)
    return OnnxExtractor(model)
