"""Training data laid out for the trainers users migrate from, as ``s2a-capture import`` reads it.

NVIDIA's Audio2Face-3D training framework keeps one folder per actor: ``audio/<shot>.wav`` (WAV, 16 kHz
or more) and ``cache/skin/<shot>.npy`` (the skin's vertex positions, frames x vertices x 3, float32), or a
Maya cache (``cache/skin/<shot>/<shot>.xml`` + ``.mc``) or a ``.pc2``. The animation is a mesh, not
blendshape weights; the weights a deployed model gives are solved against the actor's blendshape setup,
``bs_data/bs_skin.npz`` (``poseNames``, the ``neutral`` mesh, one array of vertex deltas per pose,
``frontalMask``: the vertices the solve uses). A shot is read here by the same kind of solve: its weights
are the pose weights in [0, 1] that rebuild each frame's mesh from the neutral one best (least squares
over the ``frontalMask`` vertices). The rate is ``CACHE_FPS`` of the framework's ``config_dataset.py``
(per actor), looked for in the actor's folder and the two above it; ``SHOT_EMOTION_NAMES`` there (else
the Claire dataset's 11 emotions) names a shot's emotion when one of them is part of its name.

NeuroSync's trainer keeps one folder per take: the app's ``*_iPhone_cal.csv`` with ``audio.wav`` and,
once the trainer has run, ``audio_features.csv``: its cache of the audio's features (a header of column
numbers, pandas' default), no face weights.
"""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import soundfile as sf

from .audio_io import read_audio
from .csv_take import STANDARD_TOLERANCE, nearest_standard, repair
from .errors import InputError
from .npz import NPZ_ERRORS, npz_array, npz_headers, open_npz
from .paired import NoFrameRate, channel_name, exact_rate, note_length_mismatch, string_names
from .take import MAX_FPS, FrameStatus, Take, TakeMeta, safe_id, source_file
from .transfer_litter import is_litter
from .vertex_cache import read_vertex_cache

# The parts of an Audio2Face-3D training dataset (one actor's folder).
A2F_AUDIO = "audio"
A2F_SKIN = ("cache", "skin")
A2F_SETUP = ("bs_data", "bs_skin.npz")
A2F_CONFIG = "config_dataset.py"
# The files of a shot's skin cache the framework reads (a Maya cache's ``.xml`` names its ``.mc``).
SKIN_CACHE_SUFFIXES = (".npy", ".pc2", ".xml")
# The folders of an actor's dataset the framework names (its docs' "Files Organization"): what else the
# actor's folder holds is searched as any folder is.
A2F_PARTS = (A2F_AUDIO, A2F_SKIN[0], A2F_SETUP[0], "geom", "xform")
# Folders above the actor's looked in for ``A2F_CONFIG`` (``<dataset>/data/<actor>``: two).
CONFIG_LEVELS = 2
# The emotions of the Claire dataset, a shot's emotion when no config names others.
CLAIRE_EMOTIONS = (
    "neutral", "amazement", "anger", "cheekiness", "disgust", "fear", "grief", "joy", "outofbreath",
    "pain", "sadness",
)  # fmt: skip
# Added to the solve's normal equations, relative to their trace: two poses moving the same vertices
# (a setup's duplicate) still give one solution.
RIDGE = 1e-9
# A solve that leaves more of the motion than this (relative rms) unexplained is said in its note.
RESIDUAL_WARN = 0.05
# Frames solved at a time: a block of a large mesh's frames is read from the cache, not all of them.
SOLVE_BLOCK = 256

# NeuroSync's trainer writes its audio features beside each take's CSV under this name.
NEUROSYNC_FEATURES = "audio_features.csv"


def neurosync_features(name: str, header: list[str]) -> str | None:
    """Why a CSV named ``name`` whose first row is ``header`` is no face take, when it is the audio
    features NeuroSync's trainer caches beside a take (``audio_features.csv`` under a header of column
    numbers), else None."""
    numbered = len(header) >= 3 and header == [str(i) for i in range(len(header))]
    if name.lower() != NEUROSYNC_FEATURES or not numbered:
        return None
    return (
        f"NeuroSync's audio features ({len(header)} a frame, its trainer's cache of the audio), not face "
        "weights"
    )


def is_a2f_dataset(folder: Path) -> bool:
    """Whether a folder is one actor's Audio2Face-3D training data: ``audio/`` and ``cache/skin/``."""
    return (folder / A2F_AUDIO).is_dir() and folder.joinpath(*A2F_SKIN).is_dir()


def a2f_shots(folder: Path) -> list[Path]:
    """The shots of an Audio2Face-3D training dataset: each entry of ``cache/skin`` that is a cache (a
    ``.npy`` or ``.pc2`` file, a Maya cache's folder or ``.xml``), litter and other files left out."""
    skin = folder.joinpath(*A2F_SKIN)
    return sorted(
        p
        for p in skin.iterdir()
        if not is_litter(p)
        and not p.name.startswith(".")
        and (p.is_dir() or p.suffix.lower() in SKIN_CACHE_SUFFIXES)
    )


def a2f_root(source: Path) -> Path | None:
    """The dataset an entry of its ``cache/skin`` belongs to (absolute: its name is the actor's, its
    parents hold the config), or None for any other source."""
    skin = source.absolute().parent
    root = skin.parent.parent
    if skin != root.joinpath(*A2F_SKIN) or not is_a2f_dataset(root):
        return None
    return root


def read_a2f_shot(source: Path, fps: float | None = None, audio: str | Path | None = None) -> Take:
    """One shot of an Audio2Face-3D training dataset (``source``: its skin cache) as a take: blendshape
    weights solved from its vertex positions against the actor's ``bs_data/bs_skin.npz``, with
    ``audio/<shot>.wav`` (or ``audio``) from its start, frame ``i`` at ``i / fps`` (``fps``: else the
    config's ``CACHE_FPS``, else the standard rate the frames fill the audio at). The cache is a ``.npy``,
    a ``.pc2`` or a Maya cache (its ``.xml``, or the shot's folder holding it); a dataset without a
    blendshape setup is a one-line error saying what is missing."""
    root = a2f_root(source)
    if root is None:
        raise InputError("not in the cache/skin folder of an Audio2Face-3D training dataset", source)
    shot = source.stem if source.is_file() else source.name
    setup = root.joinpath(*A2F_SETUP)
    if not setup.is_file():
        raise InputError(
            "an Audio2Face-3D training shot holds vertex positions, not blendshape weights, and the dataset "
            f"has no blendshape setup ({'/'.join(A2F_SETUP)}) to solve them from",
            source,
        )
    audio_path = Path(audio) if audio is not None else root / A2F_AUDIO / f"{shot}.wav"
    if not audio_path.is_file():
        raise InputError(f"no {A2F_AUDIO}/{shot}.wav for this shot in its dataset", source)
    names, neutral, deltas, rows = _skin_setup(setup)
    frames, cache_files = _skin_cache(source, neutral.shape[0], setup)
    weights, residual = solve_weights(frames, neutral, deltas, rows)
    config = _config(root)
    notes: list[dict] = []
    rate = _rate(fps, config, root.name, frames.shape[0], audio_path, notes, source)
    meta = TakeMeta(
        id=safe_id(shot),
        source_kind="paired_matrix",
        fps=rate,
        channels=[channel_name(n) for n in names],
        sources=[*(source_file(p, "matrix") for p in cache_files), source_file(setup, "blendshape_setup")],
    )
    emotions = config.get("SHOT_EMOTION_NAMES")
    emotions = emotions if isinstance(emotions, (list, tuple)) else CLAIRE_EMOTIONS
    meta.extra["audio2face_shot"] = {
        "actor": root.name,
        "emotion": next((e for e in emotions if isinstance(e, str) and e.lower() in shot.lower()), None),
    }
    meta.repairs.extend(notes)
    unexplained = f"; {residual:.1%} of the motion unexplained" if residual > RESIDUAL_WARN else ""
    repair(
        meta.repairs,
        None,
        "blendshape_solve",
        f"weights of {len(names)} poses solved from {frames.shape[1]} vertices' positions against "
        f"{'/'.join(A2F_SETUP)} ({rows.size} vertices used){unexplained}",
    )
    finite = np.isfinite(weights).all(axis=1)  # a frame of the cache holding NaN
    status = np.where(finite, FrameStatus.TRACKED, FrameStatus.BAD_VALUE).astype(np.uint8)
    if not finite.all():
        repair(meta.repairs, None, "bad_value", f"{(~finite).sum()} frames hold NaN/inf: marked invalid")
    take = Take(meta, np.arange(weights.shape[0]) / rate, weights.astype(np.float32), status)
    take.attach_audio(read_audio(audio_path, meta.repairs), 0.0, "paired_frame_convention")
    meta.sources.append(source_file(audio_path, "audio"))
    note_length_mismatch(take, f"check the frame rate ({rate:g} fps) and that the audio is this shot's")
    return take


def _skin_setup(path: Path) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray]:
    """Pose names, neutral mesh (vertices x 3), deltas (poses x vertices x 3) and the vertices the solve
    uses (``frontalMask``, else all) of a ``bs_skin.npz``; what is missing or misshapen is a one-line
    error."""
    try:
        with open_npz(path) as npz:
            if not isinstance(npz, np.lib.npyio.NpzFile):
                raise InputError("a .npy array, not the .npz of a blendshape setup", path)
            arrays = npz_headers(npz)
            missing = [k for k in ("posenames", "neutral") if k not in arrays]
            if missing:
                raise InputError(f"a blendshape setup without {' or '.join(missing)}", path)
            pose_names = string_names(npz_array(npz, arrays["posenames"], path), path)
            names = [n for n in pose_names if n.lower() != "neutral"]  # listed with the poses, or not
            neutral = npz_array(npz, arrays["neutral"], path).astype(np.float64)
            if neutral.ndim != 2 or neutral.shape[1] != 3:
                raise InputError(f"neutral holds {neutral.shape}, not vertices x 3", path)
            absent = [n for n in names if n.lower() not in arrays]
            if absent or not names:
                raise InputError(f"no delta array for pose {absent[0] if absent else 'any'!r}", path)
            deltas = np.stack([npz_array(npz, arrays[n.lower()], path) for n in names]).astype(np.float64)
            if deltas.shape[1:] != neutral.shape:
                raise InputError(f"pose deltas hold {deltas.shape[1:]}, the neutral {neutral.shape}", path)
            rows = np.arange(neutral.shape[0])
            if "frontalmask" in arrays:
                mask = npz_array(npz, arrays["frontalmask"], path).ravel()
                if mask.dtype == bool:  # a flag per vertex, not the framework's vertex indices
                    if mask.size != neutral.shape[0]:
                        raise InputError(
                            f"frontalMask flags {mask.size} vertices, the neutral {neutral.shape[0]}", path
                        )
                    rows = np.flatnonzero(mask)
                else:
                    rows = np.unique(mask.astype(np.int64))
                if rows.size == 0 or rows[0] < 0 or rows[-1] >= neutral.shape[0]:
                    raise InputError("frontalMask holds indices outside the neutral mesh", path)
            if not (np.isfinite(neutral[rows]).all() and np.isfinite(deltas[:, rows]).all()):
                raise InputError("the neutral or a pose's deltas hold NaN/inf", path)
    except NPZ_ERRORS as exc:
        raise InputError(f"not a readable .npz ({exc})", path) from None
    return names, neutral, deltas, rows


def _skin_cache(path: Path, vertices: int, setup: Path) -> tuple[np.ndarray, list[Path]]:
    """A shot's vertex positions (frames x vertices x 3; a ``.npy`` mapped from the file, not read whole)
    and the files they were read from (a Maya cache: its ``.xml`` and one-file data)."""
    if path.is_dir() or path.suffix.lower() != ".npy":  # a Maya cache (.xml + .mc/.mcx) or a .pc2
        cache = read_vertex_cache(path, vertices)
        frames, files = cache.frames, [cache.path, *([cache.data] if cache.data else [])]
    else:
        try:
            frames, files = np.load(path, mmap_mode="r", allow_pickle=False), [path]
        except (ValueError, OSError, EOFError) as exc:
            raise InputError(f"not a numeric .npy array ({exc})", path) from None
        if isinstance(frames, np.lib.npyio.NpzFile):  # a .npz archive under a .npy name
            frames.close()
            raise InputError("a .npz archive, not a .npy array", path)
    if frames.ndim != 3 or frames.shape[2] != 3 or frames.dtype.kind not in "fiu" or not frames.shape[0]:
        raise InputError(f"holds {frames.shape} {frames.dtype}, not frames x vertices x 3", path)
    if frames.shape[1] != vertices:
        raise InputError(
            f"{frames.shape[1]} vertices, the blendshape setup ({setup.name}) {vertices}: another mesh", path
        )
    return frames, files


def solve_weights(
    frames: np.ndarray, neutral: np.ndarray, deltas: np.ndarray, rows: np.ndarray
) -> tuple[np.ndarray, float]:
    """Pose weights in [0, 1] (frames x poses) whose deltas added to ``neutral`` rebuild each frame's
    vertices ``rows`` best (least squares), and the rms of what they leave relative to the motion's."""
    from scipy.linalg import cho_solve, solve_triangular  # here: every capture command imports this module
    from scipy.optimize import lsq_linear

    basis = deltas[:, rows].reshape(deltas.shape[0], -1).T  # (vertices x 3) x poses
    gram = basis.T @ basis
    gram[np.diag_indices_from(gram)] += RIDGE * max(np.trace(gram), 1e-30)
    lower = np.linalg.cholesky(gram)  # the bounded solve of a frame works on the poses x poses factor
    weights = np.empty((frames.shape[0], deltas.shape[0]))
    moved = left = 0.0
    for start in range(0, frames.shape[0], SOLVE_BLOCK):
        used = frames[start : start + SOLVE_BLOCK][:, rows]  # the used vertices of a block of frames
        target = (np.asarray(used, np.float64) - neutral[rows]).reshape(-1, basis.shape[0])
        with np.errstate(invalid="ignore"):  # a frame holding NaN/inf: marked by the caller
            rhs = basis.T @ target.T
        block = cho_solve((lower, True), rhs, check_finite=False).T
        finite = np.isfinite(block).all(axis=1)  # else a used vertex holds NaN/inf: the frame's weights too
        for i in np.flatnonzero(finite & ((block < 0) | (block > 1)).any(axis=1)):  # outside [0, 1]: bounded
            reduced = solve_triangular(lower, rhs[:, i], lower=True, check_finite=False)
            block[i] = lsq_linear(lower.T, reduced, bounds=(0, 1), method="bvls").x
        weights[start : start + block.shape[0]] = block
        moved += float((target[finite] ** 2).sum())
        left += float(((block[finite] @ basis.T - target[finite]) ** 2).sum())
    return weights, math.sqrt(left / moved) if moved > 0 else 0.0


def _config(root: Path) -> dict:
    """The literal settings (``NAME = <literal>``) of the first ``config_dataset.py`` in the actor's
    folder or the ``CONFIG_LEVELS`` above it; never run (a setting that is no literal is left out)."""
    for folder in [root, *root.parents[:CONFIG_LEVELS]]:
        path = folder / A2F_CONFIG
        if not path.is_file():
            continue
        try:  # bytes: Python's own reading of a source file (UTF-8, or the encoding its first lines declare)
            tree = ast.parse(path.read_bytes(), str(path))
        except (SyntaxError, UnicodeDecodeError, ValueError, OSError) as exc:
            raise InputError(f"not a readable Python config ({exc})", path) from None
        except (RecursionError, MemoryError):  # an expression nested deeper than Python's parser goes
            raise InputError("not a readable Python config (nested too deeply to parse)", path) from None
        settings = {}
        for node in tree.body:
            if (
                isinstance(node, ast.Assign)
                and len(node.targets) == 1
                and isinstance(node.targets[0], ast.Name)
            ):
                try:
                    settings[node.targets[0].id] = ast.literal_eval(node.value)
                except (ValueError, TypeError, SyntaxError, MemoryError, RecursionError):
                    continue
        return settings | {"__path__": path}
    return {}


def _rate(
    fps: float | None, config: dict, actor: str, frames: int, audio: Path, notes: list[dict], source: Path
) -> float:
    """A shot's frame rate: ``fps``, else the config's ``CACHE_FPS`` of its actor (or its only one),
    else the standard rate at which its frames last as long as its audio (the framework asks for the
    two to match; repair ``fps_from_audio``)."""
    if fps is not None:
        if not 0 < fps <= MAX_FPS:  # also NaN
            raise InputError(f"--fps must be a frame rate in (0, {MAX_FPS:g}], not {fps:g}")
        return exact_rate(fps)
    rates = config.get("CACHE_FPS")
    if isinstance(rates, dict) and rates:
        rate = rates.get(actor, next(iter(rates.values())) if len(rates) == 1 else None)
        if rate is None:
            raise NoFrameRate(f"CACHE_FPS of {config['__path__']} names no rate for actor {actor!r}", source)
        if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not 0 < rate <= MAX_FPS:
            raise InputError(
                f"CACHE_FPS of actor {actor!r} is {rate!r}, not a frame rate", config["__path__"]
            )
        return exact_rate(float(rate))
    try:
        seconds = sf.info(str(audio)).duration
    except (RuntimeError, sf.LibsndfileError):
        seconds = 0.0
    filled = frames / seconds if seconds > 0 else math.nan
    standard = nearest_standard(filled) if math.isfinite(filled) else None
    if standard is None or abs(filled / standard - 1) > STANDARD_TOLERANCE / 3:
        raise NoFrameRate(
            f"no frame rate: no {A2F_CONFIG} with CACHE_FPS beside the dataset, and its {frames} frames "
            f"fill the audio at {filled:.4g} frames per second, no standard rate: give --fps (with "
            "--pair-audio)",
            source,
        )
    repair(
        notes,
        None,
        "fps_from_audio",
        f"no {A2F_CONFIG} with CACHE_FPS found: {standard:g} fps, at which its {frames} frames last as "
        f"long as its audio ({seconds:.3f} s)",
    )
    return standard
