"""Speech to animation while it is spoken: a run's model over a bounded context of the latest audio.

A Transformer is not causal: each frame depends on the audio after it as well. ``LiveAnimator`` holds
the last ``context_s`` seconds of 16 kHz audio (``model_audio``'s: mono, DC offset and rumble removed)
and, every hop, recomputes the run's features over that context and runs the model on it
(``predict.animate_16k``, as ``s2a-train predict`` does over a whole file); it hands out each frame
once ``latency_s`` seconds of audio after the frame's time have arrived, and the frames still missing
when the speech ends (``finish``). The context starts on a frame's boundary, so frame ``k`` of the
stream is frame ``k`` of ``predict`` on the same audio: they differ by what the model did not hear
(the audio before the context, and after ``latency_s``) and by the speech level, measured over the
context rather than over the whole file (in a pause longer than the context: the loudest speech's
before it, ``_speech_level``).
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from align.resample import TARGET_RATE
from capture.errors import InputError
from dataset.features import LEVEL_MARGIN_DB, speech_level

from .predict import BLENDSHAPES_LOWER, animate_16k


class RunningStats:
    """Count, mean and maximum of a series of numbers in constant memory: a stream of any length (a
    microphone left on for a day) keeps none of them."""

    def __init__(self) -> None:
        self.count, self.total, self.max = 0, 0.0, 0.0

    def add(self, x: float) -> None:
        self.max = x if self.count == 0 else max(self.max, x)
        self.count += 1
        self.total += x

    def summary(self, digits: int) -> dict[str, float]:
        """{"mean", "max"} rounded to ``digits``; 0 for an empty series."""
        mean = self.total / self.count if self.count else 0.0
        return {"mean": round(mean, digits), "max": round(self.max, digits)}


class LiveAnimator:
    """Audio in (``add``), animation frames out (``hop``, ``finish``) of the run ``model``/``payload``
    (``predict.load_for_animation``). Frames are the run's channels de-normalised, ARKit blendshape
    weights clipped to 0..1 as ``predict`` writes them."""

    def __init__(
        self,
        model,
        payload: dict[str, Any],
        context_s: float,
        latency_s: float,
        ppg=None,
        speaker: str | None = None,
        style: str | None = None,
    ):
        info = payload["dataset"]
        self.model, self.payload, self.ppg = model, payload, ppg
        self.speaker, self.style = speaker, style
        self.fps = float(info["fps"])
        self.rate = TARGET_RATE
        self.channels = list(info["channels"])
        self.blendshapes = [i for i, c in enumerate(self.channels) if c.lower() in BLENDSHAPES_LOWER]
        if not latency_s >= 0:
            raise InputError(f"latency must be 0 s or more, not {latency_s}")
        if not context_s >= latency_s + 2 / self.fps:
            raise InputError(
                f"context of {context_s:g} s is too short for a latency of {latency_s:g} s: give at least "
                f"{latency_s + 2 / self.fps:.3f} s"
            )
        self.context_s, self.latency_s = context_s, latency_s
        self.context = int(round(context_s * self.rate))
        self.audio = np.zeros(0, np.float32)  # the latest samples; audio[0] is sample ``start``
        self.start = 0
        self.received = 0  # samples added so far
        self.emitted = 0  # frames handed out so far
        self.level: float | None = None  # the loudest context's active speech level so far (dBFS)
        self.compute_ms = RunningStats()  # milliseconds each model run took

    def warm_up(self) -> None:
        """One run of the features and the model over a context of silence, its frames let go and
        nothing of the stream changed: the first run of a process (PyTorch's and the features' set-up)
        costs several times a later one, and would make the first hop late."""
        animate_16k(
            self.model,
            self.payload,
            np.zeros(self.context, np.float32),
            self.ppg,
            self.speaker,
            None,
            self.style,
        )

    def add(self, samples: np.ndarray) -> None:
        """Append 16 kHz mono float32 ``samples``; what lies before both the context and the first frame
        not handed out yet is let go."""
        self.audio = np.concatenate([self.audio, np.asarray(samples, np.float32)])
        self.received += len(samples)
        # a context starts on a frame's boundary: up to a frame before the last context_s
        keep_from = min(self.received - self.context - self._sample_of(2), self._sample_of(self.emitted))
        if keep_from > self.start:
            self.audio = self.audio[keep_from - self.start :]
            self.start = keep_from

    def _sample_of(self, frame: int) -> int:
        """The first sample of ``frame`` (as the dataset pairs frames with audio)."""
        return int(round(frame * self.rate / self.fps))

    def _frames_of(self, samples: int) -> int:
        """Whole frames whose time lies in the first ``samples`` samples."""
        return int(math.floor(samples / self.rate * self.fps + 1e-9))

    def hop(self) -> tuple[int, np.ndarray]:
        """(first frame index, frames) newly ready: each frame whose time is ``latency_s`` or more
        before the end of the audio added; none when none is."""
        latency = int(round(self.latency_s * self.rate))
        ready = self._frames_of(self.received - latency) + 1 if self.received >= latency else 0
        covered = self._frames_of(self.received)
        ready = min(ready, covered)
        if ready <= self.emitted:
            return self.emitted, np.zeros((0, len(self.channels)), np.float32)
        return self._run(ready, covered)

    def finish(self) -> tuple[int, np.ndarray]:
        """(first frame index, frames) left when the audio has ended: up to ``predict``'s frame count
        (the audio's length in frames, rounded); audio shorter than half a frame is an ``InputError``."""
        total = int(round(self.received / self.rate * self.fps))
        if total < 1:  # no frame to send: as predict says of such a file
            raise InputError("audio is shorter than half an animation frame")
        if total <= self.emitted:
            return self.emitted, np.zeros((0, len(self.channels)), np.float32)
        return self._run(total, total)

    def _run(self, ready: int, covered: int) -> tuple[int, np.ndarray]:
        """Frames ``emitted..ready`` of the model over contexts ending at frame ``covered``: one context
        when the frames are due (the last ``context_s``), more when the stream fell behind by more than
        a context (each of them ``context_s`` long, the frames ``latency_s`` before its end taken)."""
        first, parts = self.emitted, []
        span = int(math.floor(self.context_s * self.fps))
        ahead = int(math.ceil(self.latency_s * self.fps))
        while self.emitted < ready:
            end = min(covered, self.emitted + span)
            upto = ready if end == covered else max(self.emitted + 1, end - ahead)
            parts.append(self._model(max(0, end - span), end, upto))
            self.emitted += parts[-1].shape[0]
        return first, np.concatenate(parts)

    def _model(self, k0: int, end: int, upto: int) -> np.ndarray:
        """The model over frames ``k0..end`` of the audio (padded past its end, as predict pads it);
        frames ``emitted..upto``, blendshape weights clipped as predict writes them."""
        s0 = self._sample_of(k0)
        audio = self.audio[s0 - self.start : self._sample_of(end) - self.start]
        span = int(round((end - k0) * self.rate / self.fps))
        if audio.size < span:
            audio = np.pad(audio, (0, span - audio.size))
        t = time.perf_counter()
        level = self._speech_level(audio)
        values = animate_16k(
            self.model, self.payload, audio, self.ppg, self.speaker, None, self.style, level=level
        )
        self.compute_ms.add((time.perf_counter() - t) * 1000)
        values = values[self.emitted - k0 : upto - k0].astype(np.float32)
        values[:, self.blendshapes] = np.clip(values[:, self.blendshapes], 0.0, 1.0)
        return values

    def _speech_level(self, audio: np.ndarray) -> float | None:
        """The speech level the features are scaled from (``speech_level``): the context's own, or, when
        the context holds no speech (silent, or more than P.56's margin under the loudest speech heard so
        far: a pause longer than the context), that speech's. Else a pause's noise would be raised to the
        level of speech and move the face, where ``predict`` measures one level over the whole file."""
        level = speech_level(audio, self.rate)
        if level is not None and (self.level is None or level > self.level):
            self.level = level
        if self.level is not None and (level is None or level < self.level - LEVEL_MARGIN_DB):
            return self.level
        return level
