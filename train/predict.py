"""Speech → animation with a trained run, written as Live Link Face CSV.

Audio goes through the dataset's own feature pipeline (``dataset.features.compute_features``) with the
settings the dataset recorded (copied into every checkpoint), is normalised as the reader normalises
it, and the model's output is de-normalised to blendshape weights. ARKit blendshape weights are clipped
to 0..1 (the app's range; how many were outside is reported). The CSV has the app's 61 columns;
channels the model does not predict are 0, and channels of the run that are no ARKit name are listed
in a warning. A run none of whose channels is an ARKit name (a rig's own controls) writes a rig CSV
instead: a ``time`` column in seconds and one column per channel, as ``s2a-capture import --matrix``
reads it. The header's second column is spelt ``BlendShapeCount`` (Epic's importer and the 2021 app) unless
``count_name`` asks for the newer app's ``BlendshapeCount``, which NeuroSync's loader drops by that exact
name.
"""

from __future__ import annotations

import math
import os
import stat
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from align.clipping import CLIPPED_AUDIO_SHARE, clipped_share
from align.resample import TARGET_RATE, mono_mean, to_16k_mono
from capture import FrameStatus, Take, TakeMeta, read_audio, read_livelink_csv, read_take, write_livelink_csv
from capture.atomic import atomic_write, written_into
from capture.audio_io import SILENT_PEAK, Audio, whole_sample_rate
from capture.channels import ARKIT52, is_known
from capture.command import TimedProgress, duration_words, progress, warn
from capture.csv_take import COUNT_NAMES
from capture.errors import InputError, shown_against
from capture.take import make_out_dir, sha256_file
from dataset.build import NARROWBAND_HZ, is_narrowband
from dataset.features import FeatureSettings, compute_features, gain_for_level, speech_level
from dataset.normalize import Normalizer
from dataset.ppg import make_extractor

from .checkpoint import NOT_FINITE, load_for_inference
from .data import InputSpec, normalize_features, to_model_inputs
from .style import MEAN
from .systems import max_frames
from .windowed import PREDICT_WINDOW_S, infer_windowed

BLENDSHAPES_LOWER = {c.lower() for c in ARKIT52}  # weights in 0..1 (the other 9 are angles)


def feature_settings(features: dict[str, Any]) -> FeatureSettings:
    """The feature settings a checkpoint's dataset recorded (``FeatureSettings.from_manifest``), which
    predict needs at ``TARGET_RATE``."""
    rate = (features.get("settings") or {}).get("sample_rate") if isinstance(features, dict) else None
    if isinstance(rate, (int, float)) and rate != TARGET_RATE:  # said first: what the other fields follow
        raise InputError(
            f"checkpoint's features were computed at {rate:g} Hz; datasets and predict use "
            f"{TARGET_RATE} Hz (a malformed checkpoint?)"
        )
    try:
        return FeatureSettings.from_manifest(features)
    except InputError as exc:
        raise InputError(f"checkpoint has malformed dataset feature settings ({exc})") from None


# PCM sample formats an array may hold, with the subtype ``capture.Audio`` keeps them as (full scale:
# ``capture.audio_io.full_scale``)
_PCM = {"int16": "PCM_16", "int32": "PCM_32"}


def model_audio(audio: Any, sample_rate: int | None = None, where: str | Path | None = None) -> np.ndarray:
    """``audio`` as the model hears it: 16 kHz mono float32 without DC offset or rumble, made as
    ``predict`` makes it of a file (``align.resample.to_16k_mono``: channels mixed, resampled).

    ``audio``: a ``capture.Audio`` (its own rate), or samples (a NumPy array, a torch tensor or a list)
    at ``sample_rate`` Hz (None: ``TARGET_RATE``), (samples,) or (samples, channels); float samples
    have full scale 1.0, int16 and int32 are PCM (scaled by 32768 and 2^31). Samples of another type,
    NaN or infinite samples, no samples, an array that is (channels, samples) or a rate that is not a
    whole number are an ``InputError`` naming ``where``."""
    if isinstance(audio, Audio):
        if sample_rate is not None and whole_sample_rate(sample_rate) != audio.sample_rate:
            raise InputError(
                f"sample_rate {sample_rate} differs from the audio's own {audio.sample_rate} Hz", where
            )
        raw = audio
    else:
        x = _samples_array(audio, where)
        rate = TARGET_RATE if sample_rate is None else sample_rate
        try:
            if x.dtype.kind == "f":
                raw = Audio(x.astype(np.float32, copy=False), rate, "FLOAT")
            elif x.dtype.name in _PCM:
                raw = Audio(x, rate, _PCM[x.dtype.name])
            else:
                raise InputError(
                    f"audio samples are {x.dtype}: give float samples (full scale 1.0) or int16/int32 PCM"
                )
        except InputError as exc:
            raise InputError(str(exc), where) from None
    if raw.frames == 0:
        raise InputError("audio holds no samples", where)
    if raw.samples.dtype.kind == "f":
        bad = int(np.count_nonzero(~np.isfinite(raw.samples)))
        if bad:
            raise InputError(
                f"audio holds {bad} NaN or infinite sample(s) (the input, not the model): repair them "
                "(s2a-capture import sets them to 0) or cut them out",
                where,
            )
    return to_16k_mono(raw, None if where is None else str(where))


def _samples_array(audio: Any, where: str | Path | None) -> np.ndarray:
    """Samples given as a NumPy array, a torch tensor or a (nested) list, as a NumPy array."""
    if isinstance(audio, torch.Tensor):
        t = audio.detach().to("cpu")
        if t.is_floating_point() and t.dtype not in (torch.float32, torch.float64):
            t = t.float()  # bfloat16 and float16 have no NumPy type of their own
        return t.numpy()
    if isinstance(audio, (np.ndarray, list, tuple)):
        try:
            x = np.asarray(audio)
        except ValueError as exc:  # a ragged list
            raise InputError(f"audio samples are not an array of numbers ({exc})", where) from None
        if x.dtype.kind not in "iuf":
            raise InputError(f"audio samples must be numbers, not {x.dtype}", where)
        if isinstance(audio, (list, tuple)) and x.dtype.kind in "iu":
            x = x.astype(np.float32)  # a list of numbers is float samples, never PCM by accident
        return x
    raise InputError(
        f"audio must be samples (a NumPy array, a torch tensor or a list) or a capture.Audio, not "
        f"{type(audio).__name__} (an audio file: read it with capture.read_audio, or use predict)",
        where,
    )


def animate(
    model,
    payload: dict[str, Any],
    audio: Any,
    ppg=None,
    speaker: str | None = None,
    where: str | Path | None = None,
    style: str | None = None,
    neutral: np.ndarray | None = None,
    level: float | None = None,
    sample_rate: int | None = None,
) -> np.ndarray:
    """(frames, channels) float32 blendshape weights at the dataset's fps for ``audio`` (named ``where``
    in error messages): a ``capture.Audio``, or samples at ``sample_rate`` Hz (None: 16 kHz) as a NumPy
    array, torch tensor or list, mono or (samples, channels), float (full scale 1.0) or int16/int32 PCM.
    The audio is made what the model hears as ``predict`` makes it of a file (``model_audio``: channels
    mixed, resampled to 16 kHz, DC offset and rumble removed); NaN or infinite samples are an
    ``InputError``. Pitch is normalised with ``speaker``'s statistics, and a run with speaker styles
    animates in ``style`` (default: ``speaker``'s style if the run has it, else the mean style). A run
    normalised to each take's neutral pose is de-normalised on ``neutral`` (the run's channels), else on
    the training split's offset. ``level``: the active speech level (``speech_level``) of
    ``model_audio(audio)`` when the caller has measured it (None: measured here). The model runs in
    eval mode (dropout off); the mode it was in is restored afterwards."""
    prepared = model_audio(audio, sample_rate, where)
    return animate_16k(model, payload, prepared, ppg, speaker, where, style, neutral, level)


@torch.no_grad()
def animate_16k(
    model,
    payload: dict[str, Any],
    audio: np.ndarray,
    ppg=None,
    speaker: str | None = None,
    where: str | Path | None = None,
    style: str | None = None,
    neutral: np.ndarray | None = None,
    level: float | None = None,
    job: TimedProgress | None = None,
) -> np.ndarray:
    """``animate`` for audio made what the model hears already (``model_audio``: 16 kHz mono float32).
    ``job``: where the features and the windows the model runs are said, each counted."""
    spec = InputSpec.from_json(payload["inputs"])
    info = payload["dataset"]
    fps, settings = info["fps"], feature_settings(info["features"])
    # the nearest whole frame, as the dataset pairs a take's frames with its audio (round(n·rate/fps))
    n = int(round(audio.size / settings.sample_rate * fps))
    if n < 1:
        raise InputError("audio is shorter than half an animation frame", where)
    span = int(round(n * settings.sample_rate / fps))
    # cut or padded to the frames' span; a copy only when padded (an hour of audio is 230 MB)
    audio = audio[:span] if audio.size >= span else np.pad(audio, (0, span - audio.size))
    window = int(round(PREDICT_WINDOW_S * fps))
    limit = max_frames(payload.get("model_config"))
    if limit is not None:
        window = min(window, limit)
    gain = None if level is None else gain_for_level(level, settings)
    seconds = duration_words(audio.size / settings.sample_rate)
    names, rate = tuple(spec.features), settings.sample_rate
    counted = _counted_parts(job, f"features of {seconds} of audio") if job else None
    feats, _ = compute_features(
        audio, n, fps, names, settings, ppg=ppg, gain=gain, sample_rate=rate, on_block=counted
    )
    feats = normalize_features({"normalization": info["normalization"]}, feats, speaker)

    def on_window(done: int, count: int) -> None:  # the windows: the job's next step, counted
        if job is not None:
            job.step("", count, "windows") if done == 0 else job.update(done)

    item: dict[str, Any] = {name: torch.from_numpy(v).unsqueeze(0) for name, v in feats.items()}
    item["speaker"] = speaker or MEAN
    content, prosody = to_model_inputs(item, spec, style)
    mask = torch.ones(1, n, dtype=torch.bool)
    training = getattr(model, "training", False)
    if training:
        model.eval()  # dropout off: the same audio always animates alike
    try:
        y = infer_windowed(model, content, prosody, mask, window, on_window)[0].double().numpy()
    finally:
        if training:
            model.train()
    if not np.all(np.isfinite(y)):
        raise InputError(NOT_FINITE, where)
    return Normalizer.from_json(info["normalization"]["animation"]).inverse(y, neutral)


def _counted(job: TimedProgress, part: str) -> Callable[[int, int], None]:
    """A callback ``(done, total)`` that says ``part`` of ``job`` as a counted step: a fraction, a rate
    and the time left instead of the seconds so far."""

    begun = False

    def on_block(done: int, total: int) -> None:
        nonlocal begun
        if not begun:  # the step begins with its first block of work: its total is known then
            job.step(part, total, "blocks")
            begun = True
        job.update(done)

    return on_block


def _counted_parts(job: TimedProgress, step: str) -> Callable[[str, int, int, str], None]:
    """A callback ``(part, done, total, unit)`` that says each part of ``step`` of ``job`` as a counted
    step of its own (``step: part``): the spectra take a second an hour, the pitch tracker a minute."""
    current = None

    def on_block(part: str, done: int, total: int, unit: str) -> None:
        nonlocal current
        if part != current:
            job.step(f"{step}: {part}", total, unit)
            current = part
        job.update(done)

    return on_block


def read_neutral(path: str | Path, channels: list[str]) -> np.ndarray:
    """The neutral pose of ``channels`` (float32): a take folder's calibrated ``neutral``, or the mean of
    the tracked frames of a Live Link Face CSV (the app's ``_neutral.csv``)."""
    path = Path(path)
    if path.is_dir():
        take = read_take(path, audio=False)
        if take.neutral is None:
            raise InputError("take has no neutral pose (import a calibrated take: its _neutral.csv)", path)
        pose = take.neutral.astype(np.float64)
    else:
        take = read_livelink_csv(path)
        tracked = take.values[take.frame_status == FrameStatus.TRACKED]
        if not tracked.size:
            raise InputError("CSV holds no tracked frame to take the neutral pose from", path)
        pose = tracked.mean(axis=0)
    try:
        out = pose[[take.channel_index(c) for c in channels]]
    except InputError as exc:
        raise InputError(f"neutral pose: {exc}", path) from None
    if not np.all(np.isfinite(out)):
        raise InputError("neutral pose holds NaN or infinite values", path)
    return out.astype(np.float32)


def load_for_animation(
    run: str | Path,
    ppg_model: str | Path | None = None,
    precision: str = "fp32",
    style: str | None = None,
    say: Callable[[str], None] = progress,
) -> tuple[Any, dict[str, Any], Any]:
    """(model ready for inference, checkpoint payload, PPG extractor or None) of ``run``: what
    ``animate_16k`` needs. A run's note (``training_note``) goes to ``say``; a style the run lacks, or a
    PPG run without the PPG model its dataset was built with, is an ``InputError``."""
    model, payload, spec = load_for_inference(run, precision, style, say)
    info = payload["dataset"]
    ppg = None
    if spec.content == "ppg":
        recorded = info["features"].get("ppg") or {}
        ppg = make_extractor(recorded.get("backend", "none"), ppg_model)
        want = recorded.get("model_sha256")
        if ppg_model is not None and want and sha256_file(ppg_model) != want:
            raise InputError(
                f"PPG model differs from the one the dataset was built with ({recorded.get('model')}, "
                f"sha256 {want[:12]}...): features would not match training",
                ppg_model,
            )
    if ppg is None and ppg_model is not None:
        say(f"note: the run reads {spec.content}, not a PPG: --ppg-model ignored")
    return model, payload, ppg


def check_speaker(info: dict[str, Any], speaker: str | None) -> None:
    """``speaker`` (``--speaker``) must be one of the run's dataset's speakers (``payload["dataset"]``)."""
    known = sorted(info["normalization"].get("pitch", {}).get("speakers", {}))
    if speaker is not None and speaker not in known:
        raise InputError(
            f"unknown speaker {speaker!r} (the run's dataset has: {', '.join(known) or 'none'})", "--speaker"
        )


def predict(
    run: str | Path,
    audios: str | Path | list[str | Path],
    out: str | Path,
    ppg_model: str | Path | None = None,
    speaker: str | None = None,
    say: Callable[[str], None] = progress,
    precision: str = "fp32",
    style: str | None = None,
    neutral: str | Path | None = None,
    count_name: str | None = None,
) -> list[dict[str, Any]]:
    """Write one CSV per audio file: ``out`` is the CSV itself for one file ending in .csv (or a device
    or a pipe, such as ``/dev/stdout``: ``written_into``), else a folder receiving ``<audio stem>.csv``
    (one file and a new ``out`` named otherwise: a folder all the same, said in a note). Returns one
    summary per file; of several files, one that fails gets ``{"audio", "error"}`` and the others are
    still written (a single file's failure is raised). ``precision``: fp32 or bf16
    (train/precision.py); ``style``: see ``animate``; ``neutral``: the speaker's neutral pose
    (``read_neutral``) for a run normalised to each take's neutral; ``count_name``: the CSV's second
    column, one of ``COUNT_NAMES`` (None: ``BlendShapeCount``).
    ``audios``: a list of audio files, or one file (a ``str`` or ``Path``). Progress and notes go to
    ``say``, warnings to stderr through ``warn`` (named by the running command)."""
    if count_name is not None and count_name not in COUNT_NAMES:
        raise InputError(f"count name must be one of {', '.join(COUNT_NAMES)}, not {count_name!r}")
    if isinstance(audios, (str, os.PathLike)):
        audios = [audios]  # one file, never the characters of its name
    audios = list(audios)
    model, payload, ppg = load_for_animation(run, ppg_model, precision, style, say)
    spec = InputSpec.from_json(payload["inputs"])
    info = payload["dataset"]
    channels = list(info["channels"])
    arkit = [c for c in channels if is_known(c)]
    blendshapes = [i for i, c in enumerate(channels) if c.lower() in BLENDSHAPES_LOWER]
    if arkit and len(arkit) < len(channels):
        others = [c for c in channels if not is_known(c)]
        warn(f"{len(others)} channel(s) of the run are no ARKit name and are not in the CSV: {others[:5]}")
    pose = _neutral_pose(info, neutral, say)
    if count_name is not None and not arkit:
        say("note: the run writes rig CSVs (a time column, no BlendShapeCount): --count-name ignored")
    check_speaker(info, speaker)
    out = Path(out)
    single = len(audios) == 1 and (out.suffix.lower() == ".csv" or written_into(out)) and not out.is_dir()
    folder = out.parent if single else out
    made_for_one = len(audios) == 1 and not single and not os.path.lexists(out)
    make_out_dir(folder)
    paths = csv_paths(audios, out, single)
    if made_for_one:  # "-o out" for one file: a folder, as for several, said (the CSV's name ends in .csv)
        say(f"note: {out} is a folder, made for {paths[0].name}: give -o X.csv to write the CSV itself")
    _refuse_replacing(audios, paths)
    results = []
    for a, path in zip(map(Path, audios), paths):
        try:  # one unreadable file is reported and the others are still predicted
            result = _predict_one(
                model, payload, a, path, ppg, speaker, style, arkit, blendshapes, pose, count_name, say
            )
        except InputError as exc:
            if len(audios) == 1:
                raise
            say(f"failed: {exc}")
            results.append({"audio": str(a), "error": str(exc)})
            continue
        say(f"{a}: {result['frames']} frames at {result['fps']:g} fps -> {path}")
        if result["clipped_values"]:
            say(f"note: {a}: {result['clipped_values']} blendshape value(s) outside 0..1 clipped")
        if result["narrowband"]:
            say(
                f"note: {a}: no energy above {NARROWBAND_HZ / 1000:g} kHz (recorded at 8 kHz, or through a "
                "phone codec?): its features lack the upper bands the run was trained on"
            )
        if result["clipped_audio"] > CLIPPED_AUDIO_SHARE:
            warn(
                f"{a}: {result['clipped_audio']:.2%} of the audio samples are clipped (held flat at full "
                "scale): its loudest sounds are distorted, and so is their animation"
            )
        for r in result["repairs"]:
            warn(f"{a}: {r['message']} ({r['kind']}, as s2a-capture import repairs it)")
        if result["silent"]:
            quiet = _silence_words(result["peak_dbfs"], result["dc_offset_dbfs"])
            warn(f"{a}: the audio is silent{quiet}: no speech to animate, the face stays still")
        if spec.styles:
            result["style"] = style or (speaker if speaker in spec.styles else MEAN)
        results.append(result)
    return results


SILENT_DBFS = 20 * math.log10(SILENT_PEAK)  # -70


def _dbfs(amplitude: float) -> float | None:
    """An amplitude in dBFS to 0.1 dB, or to as many more decimals as it takes to stay on its side of
    -70 dBFS (``shown_against``: -70.04 is no -70.0, which is not under it); None for 0."""
    return float(shown_against(20 * math.log10(amplitude), SILENT_DBFS, 1)) if amplitude > 0 else None


def _silence_words(peak_dbfs: float | None, dc_dbfs: float | None) -> str:
    """How silent audio is silent: quiet, a constant offset (DC) and nothing else, or all zero. An offset
    itself under -70 dBFS (float samples of 1e-40, say) is no offset worth naming: the audio is as quiet
    as its offset. The levels as ``_dbfs`` gives them."""
    if peak_dbfs is not None:
        return f" (peak {shown_against(peak_dbfs, SILENT_DBFS, 1)} dBFS, under -70 dBFS)"
    if dc_dbfs is None:
        return " (all zero)"
    if dc_dbfs < SILENT_DBFS:
        return f" (peak {shown_against(dc_dbfs, SILENT_DBFS, 1)} dBFS, under -70 dBFS)"
    return f" once its constant offset of {shown_against(dc_dbfs, SILENT_DBFS, 1)} dBFS is removed"


def _refuse_replacing(audios: list[str | Path], paths: list[Path]) -> None:
    """Refused before any file is written: an output CSV that is one of the audio files (``predict run
    voice.csv -o voice.csv``, or a folder receiving ``x.csv`` that holds the audio ``x.csv``), which would
    replace the recording with its animation; and an existing CSV whose mode has no write bit (``chmod
    a-w``: kept on purpose), which the atomic rename writing the new one would replace all the same (a
    rename asks the folder's permission, not the file's; root's ``os.access`` allows any file)."""
    inputs = {}  # (device, inode) → audio file: one stat a file, however long the batch
    for a in map(Path, audios):
        if a.is_file():
            st = a.stat()
            inputs[(st.st_dev, st.st_ino)] = a
    for path in paths:
        if path.is_file():
            st = path.stat()
            if (st.st_dev, st.st_ino) in inputs:
                a = inputs[(st.st_dev, st.st_ino)]
                raise InputError(f"output CSV is the audio file {a} itself: choose another -o", path)
            if not st.st_mode & 0o222:
                raise InputError(
                    f"output CSV exists and is read-only ({stat.filemode(st.st_mode)}): not replaced; "
                    "make it writable or choose another -o",
                    path,
                )


def _neutral_pose(info: dict[str, Any], neutral: str | Path | None, say) -> np.ndarray | None:
    """The pose a neutral-normalised run is de-normalised on (``--neutral``); a note when it has none."""
    kind = info["normalization"]["animation"].get("kind")
    if neutral is not None:
        if kind != "neutral":
            raise InputError(
                f"the run's animation is normalised by {kind}, not on a neutral pose", "--neutral"
            )
        return read_neutral(neutral, list(info["channels"]))
    if kind == "neutral":
        say(
            "note: the run predicts offsets from each take's calibrated neutral pose: without --neutral "
            "(the speaker's _neutral.csv or calibrated take) they are added to the training split's 5th "
            "percentile, and a face whose rest pose differs is shifted by the difference"
        )
    return None


def _predict_one(
    model,
    payload,
    a: Path,
    path: Path,
    ppg,
    speaker,
    style,
    arkit,
    blendshapes,
    neutral,
    count_name=None,
    say: Callable[[str], None] = progress,
) -> dict[str, Any]:
    """Predict audio file ``a`` into CSV ``path``; the summary of ``predict``. An hour of speech runs
    for minutes: every few seconds a line says which step it is in (reading the audio, features,
    windows, writing the CSV) and how far (the windows' count, rate and time left)."""
    info = payload["dataset"]
    if a.is_dir():
        raise InputError("is a folder, not an audio file", a)
    if path.is_dir():
        raise InputError("output CSV path is a folder", path)
    repairs: list[dict[str, Any]] = []  # damaged samples are repaired as s2a-capture import repairs them
    job = TimedProgress(f"predict: {a.name}", say=say)
    with job.ticking("reading the audio"):  # the decoder says nothing of how far it is
        raw = read_audio(a, repairs)
    if repairs and not np.any(raw.samples):  # nothing but NaN/inf (and zeros): no sound left to animate
        raise InputError("audio holds only NaN or infinite samples (and zeros): nothing to animate", a)
    # without its DC offset, which is no sound; counted in blocks
    audio = to_16k_mono(raw, str(a), on_block=_counted(job, "16 kHz mono audio"))
    # each a pass over the whole audio (3 s of 20 min, more on a busy machine) that says nothing itself
    with job.ticking("checking the audio for clipping"):
        dc = abs(mono_mean(raw))  # block by block: no float32 copy of the file's samples
        clipped_audio = clipped_share(raw)  # on the recorded samples: resampling smears the flat tops
    del raw  # the recorded samples (317 MB for an hour at 44.1 kHz) are not needed any more
    with job.ticking("measuring the audio's bandwidth and level"):
        narrow = is_narrowband(audio, TARGET_RATE)
        peak = float(np.maximum(audio.max(initial=0.0), -audio.min(initial=0.0)))  # max |x|, no copy
        level = speech_level(audio, TARGET_RATE)
    values = animate_16k(model, payload, audio, ppg, speaker, a, style, neutral, level, job)
    n, fps = values.shape[0], info["fps"]
    outside = values[:, blendshapes]
    clipped = int(np.count_nonzero((outside < 0) | (outside > 1)))
    values[:, blendshapes] = np.clip(outside, 0.0, 1.0)
    meta = TakeMeta(id=a.stem, source_kind="predicted", fps=fps, channels=list(info["channels"]))
    take = Take(meta, np.arange(n) / fps, values, np.zeros(n, np.uint8))
    try:
        with job.ticking(f"writing {path.name}"):
            if arkit:
                write_livelink_csv(take, path, count_name=count_name)
            else:
                write_rig_csv(take, path)
    except OSError as exc:
        raise InputError(f"cannot write the CSV: {exc.strerror}", path) from None
    return {
        "audio": str(a),
        "csv": str(path),
        "format": "livelinkface" if arkit else "rig",
        "frames": n,
        "fps": fps,
        "duration_s": n / fps,
        "clipped_values": clipped,
        "narrowband": narrow,
        "silent": peak < SILENT_PEAK,
        "peak_dbfs": _dbfs(peak),
        "dc_offset_dbfs": _dbfs(dc),
        "speech_level_dbfs": None if level is None else round(level, 1),
        "clipped_audio": round(clipped_audio, 6),  # share of samples held flat at full scale
        "repairs": [{"kind": r["kind"], "message": r["message"]} for r in repairs],
    }


def write_rig_csv(take: Take, path: Path) -> None:
    """A ``time`` column (seconds) and one column per channel, 6 decimals, written atomically: the
    output for a rig whose controls are no ARKit names (``s2a-capture import --matrix`` reads it)."""
    header = ",".join(["time", *take.meta.channels])
    rows = np.column_stack([take.time, take.values])
    with atomic_write(path) as f:
        np.savetxt(f, rows, fmt="%.6f", delimiter=",", header=header, comments="")


def csv_paths(audios: list[str | Path], out: Path, single: bool) -> list[Path]:
    """``out`` itself for a single CSV, else ``out/<audio stem>.csv``, with ``-2``, ``-3``... added
    to the stems that several audio files share (``a/x.wav b/x.wav`` → ``x.csv``, ``x-2.csv``)."""
    if single:
        return [out]
    paths: list[Path] = []
    taken: set[str] = set()
    for a in audios:
        stem, name, i = Path(a).stem, f"{Path(a).stem}.csv", 1
        while name.lower() in taken:
            i += 1
            name = f"{stem}-{i}.csv"
        taken.add(name.lower())
        paths.append(out / name)
    return paths
