"""Live in, live out: speech (a microphone, or an audio file spoken as if live) animates a face in Unreal
over Live Link while it is spoken, a known time behind it.

Every hop the speech heard so far is given to ``train.streaming.LiveAnimator`` (the run's features and
model over the last ``context_s`` seconds); a frame is ready once ``latency_s`` seconds of speech after
it have arrived, so with hops of ``hop_s`` it is sent ``latency_s + 2 hop_s`` after its time (one hop to
arrive, one to compute): the send delay, the same for every frame. Frames go out at the run's fps as
Live Link packets version 6 (capture's encoder, ``capture.livelink``; frame numbers on the time of day
at the start, as the phone's timecode), each at its time plus the send delay on this process's
monotonic clock; one computed later than that is sent at once and counted late. ``--play`` plays the
file's speech delayed by the send delay, so lips and sound line up.
"""

from __future__ import annotations

import math
import queue
import socket
import threading
import time
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from align.resample import TARGET_RATE
from capture import Take, TakeMeta, read_audio
from capture import livelink as ll
from capture.channels import is_known
from capture.command import Terminated, warn
from capture.errors import InputError
from capture.replay import (
    format_destination,
    frame_times,
    packet_names,
    parse_destination,
    rate_of,
    udp_target,
    values_in_engine_order,
)

from .stream import AudioPlayer


class FileSpeech:
    """An audio file spoken as if live: its 16 kHz samples arrive as the monotonic clock reaches them
    (``speed`` times real time)."""

    live = False
    overflows = 0  # a file loses no samples

    def __init__(self, path: Path):
        from train.predict import model_audio

        if path.is_dir():
            raise InputError("is a folder, not an audio file", path)
        repairs: list[dict[str, Any]] = []
        self.raw = read_audio(path, repairs)  # unreadable, empty: one line naming the file
        for r in repairs:
            warn(f"{path}: {r['message']} ({r['kind']}, as s2a-capture import repairs it)")
        self.samples = model_audio(self.raw, where=path)
        self.given = 0

    def start(self) -> None:
        pass

    def arrived(self, audio_s: float) -> tuple[np.ndarray, bool]:
        """The samples newly arrived by ``audio_s`` seconds into the speech, and whether it has ended."""
        upto = min(self.samples.size, int(round(audio_s * TARGET_RATE)))
        out, self.given = self.samples[self.given : upto], max(self.given, upto)
        return out, self.given >= self.samples.size

    def close(self) -> None:
        pass


class MicBlocks:
    """A microphone's blocks at its own ``rate`` as speak takes them at 16 kHz: ``heard`` (the input
    stream's callback, in PortAudio's thread) queues each block and counts the input overflows (samples
    the sound card lost: the stream goes on); ``taken`` resamples what has arrived with libsoxr's stream
    (align's resampler, ``align/resample.py`` says why), whose filter keeps its state from block to
    block: the joins are seamless, the samples ``soxr.resample``'s of the whole, the latest 9-85 ms held
    back for the next call (the filter's delay and its block at 44.1 and 48 kHz: a median of 45 ms)."""

    def __init__(self, rate: int):
        import soxr

        self.rate = rate
        self.blocks: queue.Queue[np.ndarray] = queue.Queue()
        self.overflows = 0
        self.stream = (
            None
            if rate == TARGET_RATE
            else soxr.ResampleStream(rate, TARGET_RATE, 1, dtype="float32", quality="VHQ")
        )

    def heard(self, data: np.ndarray, frames: int, when, status) -> None:
        self.blocks.put(data[:, 0].copy())
        self.overflows += bool(status.input_overflow)

    def taken(self) -> np.ndarray:
        """The 16 kHz samples of the blocks heard since the last call."""
        parts = []
        while not self.blocks.empty():
            parts.append(self.blocks.get_nowait())
        block = np.concatenate(parts) if parts else np.zeros(0, np.float32)
        return block if self.stream is None else self.stream.resample_chunk(block)


def _input_rate(sd, dev) -> int:
    """16 kHz when the input device takes it (nothing then held back by a resampler), else its default
    rate (most cards take only 44.1 or 48 kHz)."""
    try:
        sd.check_input_settings(device=dev, samplerate=TARGET_RATE, channels=1, dtype="float32")
        return TARGET_RATE
    except Exception:  # PortAudio's refusals come in several exception types
        rate = int(round(sd.query_devices(dev, "input")["default_samplerate"]))
        sd.check_input_settings(device=dev, samplerate=rate, channels=1, dtype="float32")
        return rate


class MicSpeech:
    """A sounddevice input stream, mono, at 16 kHz or else the device's own rate (``device``:
    PortAudio's index or name, None: the default input), taken at 16 kHz (``MicBlocks``)."""

    live = True

    def __init__(self, device: str | None):
        try:
            import sounddevice as sd
        except (ImportError, OSError) as exc:
            raise InputError(f"--mic needs sounddevice and PortAudio (libportaudio2): {exc}") from None
        dev = int(device) if device is not None and device.isdigit() else device
        try:
            rate = _input_rate(sd, dev)
        except Exception as exc:  # PortAudio reports a missing device in several exception types
            raise InputError(f"--mic: no usable audio input device ({exc})") from None
        self.blocks = MicBlocks(rate)
        self.stream = sd.InputStream(  # opened, started by ``start``
            device=dev, samplerate=rate, channels=1, dtype="float32", callback=self.blocks.heard
        )

    @property
    def overflows(self) -> int:
        return self.blocks.overflows

    def start(self) -> None:
        self.stream.start()

    def arrived(self, audio_s: float) -> tuple[np.ndarray, bool]:
        return self.blocks.taken(), False

    def close(self) -> None:
        self.stream.close()  # stopped first, when started


class LiveLinkOut:
    """Frames of the run's channels as Live Link packets to ``destination``, frame numbers on the time of
    day at ``start`` at the run's rate."""

    def __init__(self, destination: str, channels: list[str], fps: float, name: str, subject, device):
        host, port = parse_destination(destination)
        self.meta = TakeMeta(id=name, source_kind="predicted", fps=fps, channels=channels)
        blank = Take(self.meta, np.zeros(0), np.zeros((0, len(channels)), np.float32), np.zeros(0, np.uint8))
        self.device, self.subject = packet_names(blank, device, subject)
        self.header = ll.header_bytes(self.device, self.subject)
        self.num, self.den = rate_of(fps)
        self.fps = fps
        self.where = format_destination(host, port)
        self.target, self.family = udp_target(host, port)
        self.sock: socket.socket | None = None
        self.day_s = 0.0

    def begin(self) -> None:
        self.sock = socket.socket(self.family, socket.SOCK_DGRAM)
        now = datetime.now()
        self.day_s = now.hour * 3600 + now.minute * 60 + now.second + now.microsecond / 1e6

    def engine_order(self, first: int, values: np.ndarray) -> np.ndarray:
        """(frames, 61) float32 in Live Link order; channels the run lacks are 0."""
        n = values.shape[0]
        take = Take(self.meta, (first + np.arange(n)) / self.fps, values, np.zeros(n, np.uint8))
        return values_in_engine_order(take)

    def send(self, frame: int, values61: np.ndarray) -> None:
        number, sub = frame_times(np.array([self.day_s + frame / self.fps]), self.num, self.den)
        packet = self.header + ll.frame_block(int(number[0]), float(sub[0]), self.num, self.den, values61)
        try:
            self.sock.sendto(packet, self.target)
        except OSError as exc:
            raise InputError(f"cannot send to {self.where}: {exc}") from None

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()


class Pacer(threading.Thread):
    """Sends each frame queued (frame, values, due on the monotonic clock) at its due time, while the
    model computes the next hop in the main thread; counts what it sent, the late frames (sent more than
    ``late_after`` seconds past due) and each frame's lag (sent - ``zero`` - frame time, times ``speed``:
    seconds of speech)."""

    def __init__(self, out: LiveLinkOut, zero: float, speed: float, late_after: float):
        from train.streaming import RunningStats

        super().__init__(daemon=True)
        self.out, self.zero, self.speed, self.late_after = out, zero, speed, late_after
        self.frames: queue.Queue[tuple[int, np.ndarray, float] | None] = queue.Queue()
        self.stopping = threading.Event()
        self.sent = self.late = 0
        self.lag_s = RunningStats()
        self.error: InputError | None = None

    def run(self) -> None:
        while (item := self.frames.get()) is not None:
            frame, values, due = item
            if self.stopping.wait(max(0.0, due - time.monotonic())):
                return
            try:
                self.out.send(frame, values)
            except InputError as exc:
                self.error = exc
                return
            sent = time.monotonic()
            self.sent += 1
            self.late += sent - due > self.late_after
            self.lag_s.add((sent - self.zero) * self.speed - frame / self.out.fps)


def send_delay(latency_s: float, hop_s: float) -> float:
    """Seconds of speech between a frame's time and its packet: the latency, one hop for the speech to
    arrive and one for the model to compute it."""
    return latency_s + 2 * hop_s


def speak(
    animator,
    speech: FileSpeech | MicSpeech,
    out: LiveLinkOut,
    hop_s: float,
    speed: float = 1.0,
    player: AudioPlayer | None = None,
) -> dict[str, Any]:
    """Animate ``speech`` with ``animator`` (``train.streaming.LiveAnimator``) and send each frame to
    ``out`` at its time plus the send delay, until the speech ends, Ctrl-C or SIGTERM. Returns the
    summary: frames sent, the model's compute per hop, the latency achieved, frames late."""
    fps = animator.fps
    delay = send_delay(animator.latency_s, hop_s)
    animator.warm_up()  # before the speech is taken: a first model run costs several later ones
    out.begin()
    speech.start()
    start = time.monotonic()
    # later than a frame's period past its due time is late
    pacer = Pacer(out, start, speed, 1.0 / fps / speed)
    pacer.start()
    if player is not None:
        player.start()
    hops, ended, stopped_by = 0, False, None
    try:
        while not ended:
            hop = math.floor((time.monotonic() - start) * speed / hop_s + 1e-9) + 1  # the next hop's end
            time.sleep(max(0.0, start + hop * hop_s / speed - time.monotonic()))
            samples, ended = speech.arrived(hop * hop_s)
            animator.add(samples)
            first, values = animator.finish() if ended else animator.hop()
            hops += 1
            rows = out.engine_order(first, values)
            for i in range(rows.shape[0]):
                pacer.frames.put((first + i, rows[i], start + ((first + i) / fps + delay) / speed))
            if pacer.error is not None:
                raise pacer.error
        pacer.frames.put(None)
        while pacer.is_alive():  # in steps: a signal reaches this thread meanwhile
            pacer.join(0.1)
        if pacer.error is not None:
            raise pacer.error
    except Terminated:  # a KeyboardInterrupt of SIGTERM's
        stopped_by = "SIGTERM"
    except KeyboardInterrupt:
        stopped_by = "SIGINT"
    finally:
        pacer.stopping.set()
        pacer.frames.put(None)
        pacer.join()
        speech.close()
        out.close()
        if player is not None:
            player.stop()
    return {
        "frames": pacer.sent,
        "fps": fps,
        "duration_s": round(pacer.sent / fps, 3),
        "hops": hops,
        "latency_s": animator.latency_s,
        "context_s": animator.context_s,
        "hop_s": hop_s,
        "send_delay_s": round(delay, 4),
        "achieved_latency_s": pacer.lag_s.summary(4),
        "compute_ms_per_hop": animator.compute_ms.summary(2),
        "late_frames": pacer.late,
        "input_overflows": speech.overflows,
        "frames_not_sent": animator.emitted - pacer.sent,
        "stopped_by": stopped_by,
        "device": out.device,
        "subject": out.subject,
    }


def live_channels(channels: list[str], run: Path) -> list[str]:
    """Warnings for a run's channels Live Link does not carry; an ``InputError`` when it carries none
    (a rig's own controls: ``s2a-train predict`` writes them as a rig CSV)."""
    others = [c for c in channels if not is_known(c)]
    if len(others) == len(channels):
        raise InputError(
            f"the run animates {len(channels)} rig controls, none of them a Live Link Face channel: nothing "
            "to send to Unreal (s2a-train predict writes them as a rig CSV)",
            run,
        )
    return (
        [f"{len(others)} channel(s) of the run are no ARKit name and are not sent: {others[:5]}"]
        if others
        else []
    )


def delayed_player(speech: FileSpeech, delay_s: float) -> AudioPlayer:
    """A player of the file's speech from ``delay_s`` seconds of silence on: the face's send delay."""
    raw = speech.raw
    lead = np.zeros(int(round(delay_s * raw.sample_rate)), np.float32)
    return AudioPlayer(np.concatenate([lead, raw.mono_float()]), raw.sample_rate)
