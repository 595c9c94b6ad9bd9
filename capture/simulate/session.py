"""Simulated recording sessions: takes of simulated speakers, written as Live Link Face take folders.

A take folder holds what the app writes (``<slate>_<take>_<subject>.csv`` in the app's CSV format,
``take.json``, ``video_metadata.json``, ``audio_metadata.json``; with ``mov=True`` also the reference
``.mov`` and ``frame_log.csv``) plus the audio as ``<prefix>.wav`` (16-bit PCM), the phone and word
alignment as ``<prefix>.TextGrid`` and the ground truth as ``simulation.json``.

Clocks. Audio time ``τ`` counts seconds from the first audio sample. Frame ``k`` is captured at audio
time ``τ_k`` and stamped at take time ``t_k = audio_start_s + τ_k + capture_offset_s`` (take time 0 =
the first CSV row). It shows the face of audio time ``τ_k + face_lead_s``. Signs, as the align stage
reads them: ``capture_offset_s`` > 0 means that in the raw take the face lags the audio;
``face_lead_s`` > 0 means the face moves before the sound. The lag at which the raw face best matches
the audio is ``capture_offset_s - face_lead_s`` (``apparent_offset_s``).
"""

from __future__ import annotations

import datetime as dt
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.signal import lfilter

from ..atomic import folder_in_place
from ..audio_io import Audio, write_audio
from ..channels import ARKIT61, PRONUNCIATION32
from ..csv_take import counted, write_livelink_csv
from ..errors import InputError
from ..mov import write_reference_mov
from ..runs import runs
from ..take import FrameStatus, Take, TakeMeta, make_out_dir
from ..textgrid import TextGrid, interval_tier, write_textgrid
from ..timecode import CSV_TIMECODE_RATE, Timecode
from .articulation import Articulation, articulate
from .artifacts import Artifacts, drop_mask, face_lost_mask, frame_period_s, sensor_noise, upper_face
from .phones import inventory
from .prosody import Utterance, plan_utterance
from .speaker import Speaker, draw_speaker
from .voice import microphone, synthesis_rate, synthesize

SIMULATION_FILE = "simulation.json"
SIMULATION_SCHEMA = 1
SAMPLE_RATES = (16000, 22050, 44100, 48000)
FRAME_RATES = (30, 60)
MAX_SECONDS = 600.0  # per take; memory grows with take length (about 1 MB per second at 48 kHz)
MAX_TAKES = 10_000  # per run: a larger number is much more likely a typo than a plan
_BASE_DATE = dt.date(2025, 1, 6)


@dataclass(frozen=True)
class TakeSpec:
    """What to simulate for one take. ``take`` is the take number (1-based) within the speaker's slate."""

    seed: int
    speaker: int
    take: int
    seconds: float = 20.0
    fps: int = 60
    language: str = "en"
    sample_rate: int = 16000
    artifacts: Artifacts = field(default_factory=Artifacts)
    mov: bool = False

    @property
    def take_key(self) -> tuple[int, int]:
        return self.speaker, self.take

    def validate(self) -> None:
        if not (0 <= self.seed < 2**63):
            raise InputError(f"--seed must be a non-negative integer below 2**63, not {self.seed}")
        if self.fps not in FRAME_RATES:
            raise InputError(f"--fps must be 30 or 60 (the app's rates), not {self.fps:g}")
        if self.sample_rate not in SAMPLE_RATES:
            raise InputError(f"--sample-rate must be one of {SAMPLE_RATES}, not {self.sample_rate}")
        if not (2.0 <= self.seconds <= MAX_SECONDS):
            raise InputError(
                f"--seconds must be between 2 and {MAX_SECONDS:g} per take, not {self.seconds:g} "
                "(make longer data sets from more takes)"
            )
        inventory(self.language)


@dataclass
class SimulatedTake:
    """One simulated take in memory: the audio, the captured take, the alignment and the ground truth."""

    spec: TakeSpec
    speaker: Speaker
    utterance: Utterance
    articulation: Articulation
    audio: Audio
    take: Take  # 61 channels on the take clock as the CSV will hold them (dropped frames marked)
    textgrid: TextGrid
    truth: dict[str, Any]
    prefix: str
    folder_name: str


def take_rng(seed: int, speaker: int, take: int) -> np.random.Generator:
    """The one generator behind a take: depends only on (seed, speaker, take)."""
    return np.random.default_rng([int(seed), int(speaker), int(take), 0x7A4E])


def _quantize(x: float, step: float) -> float:
    return round(round(x / step) * step, 9)


def simulate_take(spec: TakeSpec) -> SimulatedTake:
    """Simulate one take (nothing is written)."""
    spec.validate()
    rng = take_rng(spec.seed, spec.speaker, spec.take)
    inv = inventory(spec.language)
    speaker = draw_speaker(spec.seed, spec.speaker)
    art = spec.artifacts
    sr, fps = spec.sample_rate, spec.fps

    lead_sil = float(rng.uniform(0.4, 1.5)) if art.silence else 0.15
    trail_sil = float(rng.uniform(0.4, 1.5)) if art.silence else 0.15
    utt = plan_utterance(rng, inv, speaker, spec.seconds, synthesis_rate(sr), lead_sil, trail_sil)
    articulation = articulate(utt, speaker)
    speech = synthesize(utt, speaker, rng)
    mic_gain_db = float(rng.uniform(-6.0, 3.0))
    noise_db = float(rng.uniform(-68.0, -50.0))
    pcm = microphone(speech, rng, mic_gain_db, noise_db, utt.sample_rate, sr)
    audio = Audio(pcm, sr, "PCM_16")  # 16-bit, as the phone stores it

    # Take clock. Timecodes resolve 1/(1000 fps) s in frame_log.csv and 1/60000 s in the CSV.
    tick = 1.0 / (1000.0 * fps)
    period = frame_period_s(rng, fps)
    capture_offset = _quantize(float(rng.uniform(-0.12, 0.12)), 1e-4) if art.offset else 0.0
    audio_start = _quantize(float(rng.uniform(-0.04, 0.06)), tick) if spec.mov else 0.0
    tod0 = _quantize(float(rng.uniform(0.0, 86400.0 - 2 * spec.seconds - 60.0)), tick)
    n_frames = int(np.ceil((utt.duration_s + max(audio_start, 0.0)) / period))
    t_take = np.arange(n_frames) * period
    tau = t_take - audio_start - capture_offset  # audio time each frame was captured at

    mouth = articulation.face_at(tau)
    accent_curve = _accent_curve(utt, tau + speaker.face_lead_s)
    upper = upper_face(rng, n_frames, fps, speaker.upper_face, accent_curve, art.blinks, art.head_motion)
    values = np.zeros((n_frames, len(ARKIT61)))
    for j, name in enumerate(ARKIT61):
        values[:, j] = mouth[:, PRONUNCIATION32.index(name)] if name in PRONUNCIATION32 else upper[name]
    if art.sensor_noise:
        values = sensor_noise(rng, values, fps)
    # ARKit reports shapes >= 0 (never clamped at 1: real takes reach 1.05); angles are signed.
    values[:, :52] = np.maximum(values[:, :52], 0.0)

    dropped = drop_mask(rng, n_frames, art.dropped_frames)
    lost = face_lost_mask(rng, n_frames, fps, art.face_lost) & ~dropped
    status = np.full(n_frames, FrameStatus.TRACKED, dtype=np.uint8)
    status[lost] = FrameStatus.FACE_LOST
    status[dropped] = FrameStatus.DROPPED
    values[status != FrameStatus.TRACKED] = np.nan

    slate, folder_name = take_names(spec, speaker)
    # The collector names the Live Link subject after the speaker, so imports know who spoke.
    prefix = f"{slate}_{spec.take}_{speaker.name}"
    meta = TakeMeta(
        id=folder_name,
        source_kind="simulated",
        fps=float(fps),
        channels=list(ARKIT61),
        slate=slate,
        take_number=spec.take,
        subject=speaker.name,
        device="iPhone13,3",
        start_timecode=Timecode.from_seconds(tod0).format(),
        timecode_rate=CSV_TIMECODE_RATE,
        csv={"count_name": "BlendshapeCount", "start_seconds_of_day": tod0},
    )
    take = Take(meta, t_take, values, status)

    intervals = utt.phone_intervals()
    xmax = audio.duration_s
    tg = TextGrid(
        0.0,
        xmax,
        [
            interval_tier("words", [w for w in utt.word_intervals() if w[2]], 0.0, xmax),
            interval_tier("phones", [p for p in intervals if p[2]], 0.0, xmax),
        ],
    )
    truth = {
        "format": "s2a-simulation",
        "schema_version": SIMULATION_SCHEMA,
        "seed": spec.seed,
        "speaker": speaker.name,
        "speaker_index": spec.speaker,
        "take": spec.take,
        "language": inv.name,
        "clock": (
            "frame k: take time t_k = audio_start_s + tau_k + capture_offset_s, shows the face of "
            "audio time tau_k + face_lead_s; take time 0 = first CSV row"
        ),
        "face_lead_s": speaker.face_lead_s,
        "face_lead_sign": "> 0: the face articulates before the sound (natural, part of the mapping)",
        "capture_offset_s": capture_offset,
        "capture_offset_sign": "> 0: in the raw take the face lags the audio (align-stage offset_s)",
        "apparent_offset_s": round(capture_offset - speaker.face_lead_s, 9),
        "audio_start_s": audio_start,
        "audio_start_source": "frame_log_audio" if spec.mov else "assumed_first_csv_row",
        "start_timecode": meta.start_timecode,
        "start_seconds_of_day": tod0,
        "fps": fps,
        "frame_period_s": period,
        "frames": n_frames,
        "csv_rows": int(n_frames - dropped.sum()),
        "dropped_frames": int(dropped.sum()),
        "dropped_frame_indices": np.flatnonzero(dropped).tolist(),
        "face_lost_frames": int(lost.sum()),
        "face_lost_frame_runs": _runs(lost),  # [first, last] frame index of each stretch
        "sample_rate": sr,
        "audio_samples": audio.frames,
        "audio_duration_s": audio.duration_s,
        "leading_silence_s": utt.end[0] / utt.sample_rate,
        "trailing_silence_s": (utt.end[-1] - utt.start[-1]) / utt.sample_rate,
        "microphone_gain_db": round(mic_gain_db, 4),
        "room_noise_dbfs": round(noise_db, 4),
        "phones": sum(1 for p in intervals if p[2]),
        "words": len(utt.words),
        "textgrid": f"{prefix}.TextGrid",
        "audio_file": f"{prefix}.wav",
        "artifacts": art.to_json(),
        "speaker_traits": speaker.to_json(),
    }
    return SimulatedTake(spec, speaker, utt, articulation, audio, take, tg, truth, prefix, folder_name)


def take_names(spec: TakeSpec, speaker: Speaker | None = None) -> tuple[str, str]:
    """The slate and the take folder's name (``<YYYYMMDD>_<slate>_<take>``) of ``spec``."""
    speaker = speaker or draw_speaker(spec.seed, spec.speaker)
    slate = f"Sim{speaker.name.capitalize()}"
    date = _BASE_DATE + dt.timedelta(days=int(spec.seed % 1000))
    return slate, f"{date:%Y%m%d}_{slate}_{spec.take}"


def _runs(mask: np.ndarray) -> list[list[int]]:
    """``[first, last]`` frame index of each run of True."""
    return [[a, b - 1] for a, b in runs(mask)]


def _accent_curve(utt: Utterance, t: np.ndarray) -> np.ndarray:
    """0..1 per time ``t`` (s): the accent of the word being spoken, smoothed over ~0.3 s."""
    sr = utt.sample_rate
    seg = np.clip(np.searchsorted(utt.end / sr, t, side="right"), 0, utt.phone.size - 1)
    raw = np.where((t >= 0) & (t < utt.duration_s), utt.accent[seg], 0.0)
    if raw.size < 2:
        return raw
    step = float(np.median(np.diff(t))) if t.size > 1 else 1 / 60
    a = np.exp(-step / 0.15)
    y = lfilter([1 - a], [1, -a], raw)
    return lfilter([1 - a], [1, -a], y[::-1])[::-1]


def _mouth_image(values: np.ndarray, size: tuple[int, int]) -> Callable[[int], np.ndarray]:
    """Frame ``i`` of the reference video: a dark mouth whose opening follows jawOpen."""
    w, h = size
    jaw = np.nan_to_num(values[:, ARKIT61.index("jawOpen")])
    spread = np.nan_to_num(
        values[:, ARKIT61.index("mouthStretchLeft")] - values[:, ARKIT61.index("mouthPucker")]
    )
    yy, xx = np.mgrid[0:h, 0:w]

    def image(i: int) -> np.ndarray:
        img = np.full((h, w, 3), 170, np.uint8)
        half_w = w * (0.18 + 0.3 * max(spread[i], -0.3))
        half_h = 2 + h * 0.45 * jaw[i]
        inside = ((xx - w / 2) / max(half_w, 1)) ** 2 + ((yy - h * 0.6) / half_h) ** 2 <= 1
        img[inside] = (60, 20, 20)
        return img

    return image


def write_frame_log(sim: SimulatedTake, path: Path) -> None:
    """``frame_log.csv``: a ``V`` row per video frame (6th field 1 where dropped) and an ``A`` row per
    1024-sample audio buffer, timecodes at the video rate."""
    fps = sim.spec.fps
    tod0 = sim.truth["start_seconds_of_day"]
    status = sim.take.frame_status
    lines = []
    for k, t in enumerate(sim.take.time):
        tc = Timecode.from_seconds(tod0 + t, fps).format()
        drop = 1 if status[k] == FrameStatus.DROPPED else 0
        lines.append(f"V,{k},{int(round(t * 1_000_000))},1000000,{tc},{drop}\n")
    sr = sim.audio.sample_rate
    start = sim.truth["audio_start_s"]
    for i, pos in enumerate(range(0, sim.audio.frames, 1024)):
        t = start + pos / sr
        tc = Timecode.from_seconds(tod0 + t, fps).format()
        lines.append(f"A,{i},{int(round(t * sr))},{sr},{tc},0\n")
    path.write_text("".join(lines), encoding="ascii")


def _same_takes_there(out_dir: Path, specs: list[TakeSpec]) -> dict[tuple[int, int], SimulatedTake]:
    """The takes of ``specs`` whose folders exist already, simulated (a run repeated with the same
    arguments and seed writes the same bytes again). A folder of that name holding anything else (a take
    simulated with other settings, a recording) is never replaced: ``InputError`` before a byte is written.
    """
    made, other = {}, []
    for spec in specs:
        folder = out_dir / take_names(spec)[1]
        if not folder.exists() and not folder.is_symlink():
            continue
        try:
            there = json.loads((folder / SIMULATION_FILE).read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, ValueError):
            there = None
        sim = simulate_take(spec)
        if there != json.loads(json.dumps(sim.truth)):
            other.append(folder.name)
        made[spec.take_key] = sim
    if other:
        more = f" and {len(other) - 3} more" if len(other) > 3 else ""
        verb = "is" if len(other) == 1 else "are"
        raise InputError(
            f"{counted(len(other), 'take folder')} this simulation writes {verb} there already, holding "
            f"other takes ({', '.join(other[:3])}{more}: simulated with other "
            "settings, or recorded): simulate into another folder, or move them away first",
            out_dir,
        )
    return made


def write_take_folder(sim: SimulatedTake, out_dir: str | Path) -> Path:
    """Write ``sim`` as a Live Link Face take folder ``out_dir/<YYYYMMDD>_<slate>_<take>/``."""
    out_dir = Path(out_dir)
    make_out_dir(out_dir)
    target = out_dir / sim.folder_name
    # Assembled under a hidden name and renamed into place: no half-written take, no stale files.
    try:
        with folder_in_place(target) as folder:
            _write_files(sim, folder)
    except OSError as exc:
        raise InputError(f"cannot write the take folder ({exc.strerror or exc})", target) from None
    return target


def _write_files(sim: SimulatedTake, folder: Path) -> None:
    spec, truth = sim.spec, sim.truth
    write_livelink_csv(sim.take, folder / f"{sim.prefix}.csv")
    write_audio(folder / f"{sim.prefix}.wav", sim.audio)
    write_textgrid(sim.textgrid, folder / f"{sim.prefix}.TextGrid")
    when = _BASE_DATE + dt.timedelta(days=int(spec.seed % 1000))
    tc = Timecode.from_seconds(truth["start_seconds_of_day"])
    app_take = {
        "frames": truth["csv_rows"],
        "appVersion": "v1.4.2 (simulated)",
        "slate": sim.take.meta.slate,
        "calibrated": False,
        "subject": sim.take.meta.subject,
        "identifier": sim.folder_name,
        "date": f"{when:%Y-%m-%d}T{tc.hours:02d}:{tc.minutes:02d}:{tc.seconds:02d}Z",
        "version": 1,
        "take": spec.take,
        "deviceModel": "iPhone13,3",
    }
    _write_json(folder / "take.json", app_take)
    _write_json(
        folder / "video_metadata.json",
        {
            "FrameRate": spec.fps,
            "Dimensions": {"width": 160, "height": 120},
            "Quality": "high",
            "JpegCompressionQuality": 0.9,
        },
    )
    _write_json(
        folder / "audio_metadata.json",
        {"BitsPerChannel": 16, "SampleRate": spec.sample_rate, "ChannelsPerFrame": 1, "FormatFlags": 12},
    )
    if spec.mov:
        write_frame_log(sim, folder / "frame_log.csv")
        kept = sim.take.frame_status != FrameStatus.DROPPED
        start_tc = Timecode.from_seconds(truth["start_seconds_of_day"], spec.fps)
        mov_tc = (
            f"{start_tc.hours:02d}:{start_tc.minutes:02d}:{start_tc.seconds:02d}:{int(start_tc.frames):02d}"
        )
        write_reference_mov(
            folder / f"{sim.prefix}.mov",
            spec.fps,
            int(kept.sum()),
            sim.audio,
            mov_tc,
            _mouth_image(sim.take.values[kept], (160, 120)),
        )
    _write_json(folder / SIMULATION_FILE, truth)


def _write_json(path: Path, data: dict[str, Any]) -> None:
    path.write_text(json.dumps(data, indent=2, allow_nan=False) + "\n", encoding="utf-8")


def plan_session(
    speakers: int,
    takes: int,
    seconds: float,
    fps: int,
    language: str,
    seed: int,
    sample_rate: int = 16000,
    artifacts: Artifacts | None = None,
    mov: bool = False,
) -> list[TakeSpec]:
    """``takes`` takes spread round-robin over ``speakers`` speakers, numbered per speaker from 1."""
    if speakers < 1:
        raise InputError(f"--speakers must be at least 1, not {speakers}")
    if not 1 <= takes <= MAX_TAKES:
        raise InputError(f"--takes must be between 1 and {MAX_TAKES:,} per run, not {takes}")
    if speakers > takes:
        raise InputError(f"--speakers ({speakers}) exceeds --takes ({takes}): every speaker needs a take")
    specs = [
        TakeSpec(
            seed,
            i % speakers,
            i // speakers + 1,
            seconds,
            fps,
            language,
            sample_rate,
            artifacts or Artifacts(),
            mov,
        )
        for i in range(takes)
    ]
    for s in specs[:1]:
        s.validate()
    return specs


def simulate(
    out_dir: str | Path,
    speakers: int = 1,
    takes: int = 1,
    seconds: float = 20.0,
    fps: int = 60,
    language: str = "en",
    seed: int = 0,
    sample_rate: int = 16000,
    artifacts: Artifacts | None = None,
    mov: bool = False,
    on_take: Callable[[dict[str, Any]], None] | None = None,
) -> list[dict[str, Any]]:
    """Simulate a session and write its take folders under ``out_dir``; returns one summary per take.

    ``seconds`` is the length of each take (s), ``fps`` the frame rate (30 or 60), ``sample_rate`` the
    audio rate (Hz). The same arguments and seed give byte-identical folders.
    """
    specs = plan_session(speakers, takes, seconds, fps, language, seed, sample_rate, artifacts, mov)
    make_out_dir(Path(out_dir))  # before the first take is simulated
    made = _same_takes_there(Path(out_dir), specs)
    summaries = []
    for spec in specs:
        sim = made.pop(spec.take_key, None) or simulate_take(spec)
        folder = write_take_folder(sim, out_dir)
        t = sim.truth
        summary = {
            "id": sim.folder_name,
            "path": str(folder),
            "speaker": t["speaker"],
            "take": spec.take,
            "duration_s": round(t["audio_duration_s"], 6),
            "frames": t["frames"],
            "fps": spec.fps,
            "sample_rate": spec.sample_rate,
            "phones": t["phones"],
            "dropped_frames": t["dropped_frames"],
            "face_lost_frames": t["face_lost_frames"],
            "capture_offset_s": t["capture_offset_s"],
            "face_lead_s": t["face_lead_s"],
        }
        summaries.append(summary)
        if on_take is not None:
            on_take(summary)
    return summaries
