"""Live out: a take or a prediction as Live Link packets (version 6, 61 channels) to Unreal, in real time.

The packets, their frame numbers and the timing are capture's simulated iPhone (``capture.replay``):
frame times from the take's timecode at the take's rate, one packet per frame on the take's clock.
With audio, the speech starts on the sound card when the first packet leaves, both on the monotonic
clock of this process, so a MetaHuman in Unreal moves its lips with the sound.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from capture import Take
from capture.errors import InputError
from capture.replay import check_speed, packet_names, parse_destination, rebased_audio, replay_take

from .inputs import read_input


class AudioPlayer:
    """Plays mono float32 samples on the default output device (sounddevice), started on demand."""

    def __init__(self, samples: np.ndarray, rate: int):
        try:
            import sounddevice as sd
        except (ImportError, OSError) as exc:
            raise InputError(f"--audio needs sounddevice and PortAudio (libportaudio2): {exc}") from None
        try:
            sd.check_output_settings(samplerate=rate, channels=1, dtype="float32")
        except Exception as exc:  # PortAudio reports a missing device in several exception types
            raise InputError(f"--audio: no usable audio output device ({exc})") from None
        self.sd = sd
        self.samples = np.ascontiguousarray(samples, dtype=np.float32)
        self.rate = rate

    def start(self) -> None:
        self.sd.play(self.samples, self.rate, blocking=False)

    def wait(self) -> None:
        self.sd.wait()

    def stop(self) -> None:
        self.sd.stop()


def speech_player(take: Take, speed: float) -> AudioPlayer:
    """A player of ``take``'s speech from its first frame on, its output device checked: asked for
    before the stream is announced, so that a missing device or speech is an error before anything
    is said to stream or sent."""
    if speed != 1.0:
        raise InputError("--audio plays the speech in real time: use it with --speed 1")
    a = rebased_audio(take)
    if a is None:
        raise InputError(f"take {take.meta.id} has no audio to play (give one with --audio FILE)")
    first = float(take.time[0])  # the first packet is the take's first frame
    return AudioPlayer(a.mono_float()[int(round(first * a.sample_rate)) :], a.sample_rate)


def stream_take(
    take: Take,
    destination: str,
    speed: float = 1.0,
    player: AudioPlayer | None = None,
    subject: str | None = None,
    device: str | None = None,
) -> dict:
    """Send ``take`` to ``destination`` (``HOST:PORT``), ``player`` (``speech_player``) playing its
    speech; blocks for the take's duration / speed.

    Returns what was sent: ``packets_sent``, of which ``frames`` carried face values and ``no_face``
    were no-face packets (``face_lost``: frames the tracker lost; ``bad_values``: frames holding NaN,
    infinite or absurd values), and duration, device, subject, rate.
    """
    host, port = parse_destination(destination)
    check_speed(speed)
    packet_names(take, device, subject)  # names too long for a datagram: an error before any sound
    if player is not None:
        # replay_take sends its first packet as soon as its socket is open: start the sound just before.
        player.start()
    report = replay_take(take, host, port, speed=speed, subject=subject, device=device)
    if player is not None:
        player.wait()
    out = report.to_json() | {"to": f"{host}:{port}", "id": take.meta.id, "audio": player is not None}
    out.pop("lost", None)
    out.pop("duplicated", None)
    out.pop("reordered", None)
    return out


def load_take(path: str | Path, audio: str | Path | None = None) -> tuple[Take, list[str], Path | None]:
    """A take folder or a Live Link Face CSV (optionally with its audio) as a take, warnings about what
    reading it repaired, and the file its speech comes from. A folder holding several takes is an
    ``InputError``."""
    return read_input(path, "stream sends one take", audio, "--audio FILE")
