"""Rendering faces offscreen with pyvista (VTK, EGL), frames → MP4 with PyAV, audio muxed in.

``FaceRenderer`` keeps one VTK scene per face model and re-poses its meshes each frame (about 10 ms
for a 256 px frame here). ``render_frame`` renders one or more panels side by side (a recording and a
prediction, or a face and the take's reference video) on one clock; ``write_mp4`` encodes such frames at
the animation's frame rate with the speech (``Speech``), a block of it at a time.
"""

from __future__ import annotations

import copy
import math
import os
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import numpy as np

from capture import ARKIT52, ARKIT61, Audio, InputError, Take
from capture.atomic import atomic_write, partial_path, put_in_place
from capture.audio_io import ffmpeg_name
from capture.channels import canonical, is_known
from capture.command import TimedProgress, stops_deferred
from capture.mov import opencv_name

from .face import FaceModel, vertex_normals, weights_from_values
from .inputs import ABSURD, bad_frames, clamp_blendshapes, read_input, with_face
from .output import lock_partial, raise_if_stopped, writing
from .probe import probe

BACKGROUND = (38, 40, 46)
# libx264 refuses a frame wider or taller than 16384 pixels (avcodec_open2 fails; tried with PyAV here:
# 16384 opens, 16400 does not). H.264's highest level, 6.2, allows 139,264 macroblocks of 16x16 pixels
# a frame (8192x4352): x264 encodes larger frames, but players and browsers may refuse to decode them.
H264_MAX_SIDE = 16384
H264_MAX_MACROBLOCKS = 139264
AUDIO_BLOCK = 1 << 20  # samples of silence around a video's speech given at a time (span_blocks)
AAC_FRAME = 1024  # samples per audio frame given to the AAC encoder


@dataclass
class Animation:
    """ARKit weights on a take's clock: ``time`` (frames,) seconds, ``weights`` (frames, 61); a take's
    channels that are not Live Link channels (a rig's own controls) in ``others``, by name."""

    label: str
    fps: float
    time: np.ndarray
    weights: np.ndarray
    audio: Audio | None = None
    audio_start_s: float = 0.0  # take time of the first audio sample
    audio_file: Path | None = None  # where the audio was read from
    take: Take | None = None
    offset_s: float = 0.0  # in side-by-side output: when this animation starts, after the first one's start
    bad_values: int = 0  # frames with NaN, infinite or absurd values, bridged
    clamped: int = 0  # blendshape values outside 0..1, clamped
    warnings: list[str] = field(default_factory=list)  # what reading repaired, bridged or clamped
    others: dict[str, np.ndarray] = field(default_factory=dict)  # (frames,) values of other channels

    @property
    def t0(self) -> float:
        return float(self.time[0])

    @property
    def frames(self) -> int:
        """Frames on the uniform grid from the first to the last frame time."""
        return int(round((self.time[-1] - self.time[0]) * self.fps)) + 1

    def at(self, t: np.ndarray) -> np.ndarray:
        """Weights (len(t), 61) at take times ``t`` (s), linear between frames, held at the ends.

        The two frames around each time are found by bisection and only their rows are read, so a frame
        of a long take costs what a frame of a short one does (``np.interp`` column by column copied
        every column of the whole take: 9 ms a frame for a 10-minute take, a render quadratic in its
        length)."""
        t = np.asarray(t, dtype=np.float64)
        last = self.time.size - 1
        # from the last frame's time on, the last row: two frames of one time there hold the later one
        i = np.clip(np.searchsorted(self.time, t, side="right") - 1, 0, last)
        j = np.minimum(i + 1, last)
        span = self.time[j] - self.time[i]
        with np.errstate(invalid="ignore", divide="ignore"):
            frac = np.where(span > 0, (t - self.time[i]) / span, 0.0)
        frac = np.clip(frac, 0.0, 1.0)[:, None]
        return self.weights[i] * (1.0 - frac) + self.weights[j] * frac


def load_animation(
    path: str | Path,
    audio: str | Path | None = None,
    label: str | None = None,
    one_take: str = "the viewer shows one take per input",
    clamp: bool = True,
    audio_flag: str | None = "--audio",
) -> Animation:
    """A take folder or a Live Link Face CSV (a recording or a prediction) as an ``Animation``.

    Frames without data (face lost, dropped) or with bad values (NaN, infinite, beyond ±10) are
    bridged linearly between the good frames around them (held at the ends), so the face does not
    collapse to neutral. With ``clamp``, blendshape weights are clamped to 0..1 (angles are not).
    ``audio`` overrides or adds the speech. What was repaired, bridged or clamped is in ``warnings``.
    A folder holding several takes is an ``InputError`` that starts with ``one_take``.
    """
    take, warnings, audio_file = read_input(path, one_take, audio, audio_flag)
    weights = weights_from_values(take.values, take.meta.channels)
    other_cols = [j for j, c in enumerate(take.meta.channels) if not is_known(c)]
    others = take.values[:, other_cols].astype(np.float64)
    ok = with_face(take)
    bad = ok & bad_frames(weights, ARKIT61)  # by the face's channels: the others are only plotted
    ok &= ~bad
    if not ok.any():
        raise InputError(f"take {take.meta.id} has no frame with usable values", path)
    if bad.any():
        warnings.append(
            f"{path}: {int(bad.sum())} frame(s) hold NaN, infinite or absurd (beyond ±{ABSURD:g}) values: "
            "bridged between the frames around them"
        )
    clamped = clamp_blendshapes(weights, ARKIT61, ok) if clamp else 0
    if clamped:
        warnings.append(f"{path}: {clamped} blendshape value(s) outside 0..1 clamped to 0..1")
    good = np.flatnonzero(ok)
    for k in range(weights.shape[1]):
        weights[:, k] = np.interp(take.time, take.time[good], weights[good, k])
    for k in range(others.shape[1]):  # each bridged over its own lost, dropped and unusable frames
        own = ok & (np.abs(others[:, k]) <= ABSURD)
        others[:, k] = np.interp(take.time, take.time[own], others[own, k]) if own.any() else np.nan
    anim = Animation(label or take.meta.id, float(take.meta.fps), take.time.copy(), weights, take=take)
    anim.others = {take.meta.channels[j]: others[:, k] for k, j in enumerate(other_cols)}
    anim.bad_values, anim.clamped, anim.warnings = int(bad.sum()), clamped, warnings
    if take.audio is not None:
        anim.audio = take.audio
        anim.audio_start_s = take.meta.audio.start_s if take.meta.audio else 0.0
        anim.audio_file = audio_file
    return anim


class FaceRenderer:
    """Offscreen renders of one face model at ``size`` (width, height) pixels, RGB uint8."""

    def __init__(self, model: FaceModel, size: tuple[int, int] = (256, 256), background=BACKGROUND):
        probe()  # raises RenderUnavailable with what to install, before VTK can crash this process
        import pyvista as pv

        self.model = model
        self.size = size
        self.plotter = pv.Plotter(off_screen=True, window_size=list(size))
        # No multisampling: 40% faster here, and the same pixels on every GL driver's sample pattern.
        self.plotter.ren_win.SetMultiSamples(0)
        self.plotter.set_background([c / 255 for c in background])
        self.meshes = []
        for part in model.parts:
            faces = np.hstack([np.full((len(part.triangles), 1), 3), part.triangles]).ravel()
            mesh = pv.PolyData(part.vertices.copy(), faces)
            mesh.point_data["rgb"] = part.colors
            if part.smooth:
                mesh.point_data.active_normals = vertex_normals(part.vertices, part.triangles)
            actor = self.plotter.add_mesh(
                mesh, scalars="rgb", rgb=True, smooth_shading=False, specular=0.15, specular_power=12
            )
            if part.smooth:
                actor.prop.interpolation = "gouraud"  # our own normals, kept when the points move
            self.meshes.append(mesh)
        cam = self.plotter.camera
        cam.position = model.camera_position
        cam.focal_point = model.camera_focus
        cam.up = (0.0, 1.0, 0.0)
        cam.view_angle = model.view_angle
        self.plotter.reset_camera_clipping_range()

    def render(self, weights: np.ndarray) -> np.ndarray:
        """The face posed by ``weights`` (61,) in ARKIT61 order, as an (H, W, 3) uint8 image."""
        for mesh, part, verts in zip(self.meshes, self.model.parts, self.model.pose(weights)):
            mesh.points[:] = verts
            if part.smooth:
                mesh.point_data.active_normals = vertex_normals(verts, part.triangles)
            mesh.Modified()
        self.plotter.reset_camera_clipping_range()
        self.plotter.render()
        return np.ascontiguousarray(self.plotter.screenshot(return_img=True)[:, :, :3])

    def project(self, points: np.ndarray) -> np.ndarray:
        """Pixel (column, row) of world points (N, 3) in the last rendered image, row 0 at the top."""
        import vtk

        coord = vtk.vtkCoordinate()
        coord.SetCoordinateSystemToWorld()
        out = np.empty((len(points), 2))
        for i, p in enumerate(np.asarray(points, dtype=np.float64)):
            coord.SetValue(*p)
            x, y = coord.GetComputedDoubleDisplayValue(self.plotter.renderer)
            out[i] = (x, self.size[1] - 1 - y)
        return out

    def close(self) -> None:
        self.plotter.close()

    def __enter__(self) -> FaceRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def label_image(img: np.ndarray, text: str) -> np.ndarray:
    """``text`` in white on a dark box in the top-left corner (OpenCV's Hershey font), a copy."""
    import cv2

    out = img.copy()
    scale = max(0.35, img.shape[0] / 640)
    thick = max(1, int(round(scale * 1.6)))
    (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
    pad = max(3, h // 3)
    cv2.rectangle(out, (0, 0), (min(w + 2 * pad, img.shape[1] - 1), h + base + 2 * pad), (0, 0, 0), -1)
    cv2.putText(
        out, text, (pad, pad + h), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), thick, cv2.LINE_AA
    )
    return out


def place_on_parent_clock(first: Animation, other: Animation, where: Path | None = None) -> float:
    """Seconds after ``first``'s first frame at which ``other`` starts: an aligned segment of ``first``
    (align report parent = ``first``'s take, an object with its id or the id alone, read as the dataset
    reads it: ``dataset.build.recording_of``) starts at its segment start; anything else with it. A
    malformed report is a one-line error naming ``where``, the input ``other`` was read from."""
    from dataset.build import recording_of

    if first.take is None or other.take is None:
        return 0.0
    try:
        parent = recording_of(other.take.meta)
    except InputError as exc:
        raise InputError(str(exc), where) from None
    start = (other.take.meta.extra.get("align") or {}).get("segment_start_s")
    if parent != first.take.meta.id or not isinstance(start, (int, float)) or not math.isfinite(start):
        return 0.0
    return float(start) - first.t0


def distinct_labels(anims: Sequence[Animation], paths: Sequence[Path]) -> None:
    """Make panel (and legend) names unique: equal take ids get the name of the folder holding the take
    folder, or of the file, they came from; the path as given where those are equal too."""
    names = [a.label for a in anims]
    twins = [i for i, name in enumerate(names) if names.count(name) > 1]
    where = {i: Path(paths[i]).parent.name if Path(paths[i]).is_dir() else Path(paths[i]).name for i in twins}
    for i in twins:
        same = [j for j in twins if names[j] == names[i] and where[j] == where[i]]
        anims[i].label = f"{names[i]} ({where[i] if len(same) == 1 else paths[i]})"


class ReferenceVideo:
    """Frames of a video (the take's reference .mov) by time, resized to a panel height (OpenCV)."""

    def __init__(self, path: str | Path, height: int, start_s: float = 0.0):
        import cv2

        self.cv2 = cv2
        self.path = Path(path)
        with opencv_name(path) as name:  # read through a descriptor of its own once opened
            self.cap = cv2.VideoCapture(name)
        if not self.cap.isOpened():
            raise InputError("video could not be opened", path)
        self.fps = self.cap.get(cv2.CAP_PROP_FPS) or 30.0
        self.height = height
        self.start_s = start_s
        self.index = -1
        self.frame: np.ndarray | None = None
        self.aspect = (self.cap.get(cv2.CAP_PROP_FRAME_WIDTH) or height) / (
            self.cap.get(cv2.CAP_PROP_FRAME_HEIGHT) or height
        )
        self.width = self.width_for(height)
        count = self.cap.get(cv2.CAP_PROP_FRAME_COUNT)
        self.duration_s = count / self.fps if count > 0 else None  # None: the container does not say

    def width_for(self, height: int) -> int:
        """The panel's width at ``height``: the video's aspect, an even number of pixels."""
        return max(2, int(round(self.aspect * height / 2)) * 2)

    def at(self, t: float) -> np.ndarray:
        """RGB frame shown at take time ``t`` (s); black before the start and after the end."""
        want = int(math.floor((t - self.start_s) * self.fps + 1e-6))
        if want < 0:
            return np.zeros((self.height, self.width, 3), np.uint8)
        while self.index < want:
            ok, frame = self.cap.read()
            if not ok:
                self.frame = np.zeros((self.height, self.width, 3), np.uint8)
                self.index = want
                break
            self.index += 1
            rgb = self.cv2.cvtColor(frame, self.cv2.COLOR_BGR2RGB)
            self.frame = self.cv2.resize(rgb, (self.width, self.height), interpolation=self.cv2.INTER_AREA)
        assert self.frame is not None
        return self.frame

    def close(self) -> None:
        self.cap.release()


def reference_video_of(take: Take | None) -> Path | None:
    """The take's reference video (the app's .mov) when its metadata names one that exists."""
    if take is None:
        return None
    for s in take.meta.sources:
        if s.role == "reference_video" and Path(s.path).is_file():
            return Path(s.path)
    return None


MOUTH_CHANNELS = tuple(c for c in ARKIT52 if c.startswith(("jaw", "mouth")))


def holds_channel(anim: Animation, name: str) -> bool:
    """Whether ``anim``'s take has channel ``name`` (a Live Link channel in any spelling, or another)."""
    if name in anim.others:
        return True
    channels = anim.take.meta.channels if anim.take is not None else []
    return any(is_known(c) and canonical(c) == name for c in channels)


# The lips parting, which opens the mouth with the jaw: a smile or a pucker moves as far (the widest
# range of the mouth's channels in all four sample takes) with the mouth about closed.
OPENING_MOUTH = ("mouthLowerDownLeft", "mouthLowerDownRight", "mouthUpperUpLeft", "mouthUpperUpRight")
MOVING_MOUTH = "the mouth channel that moves most, lips parting first"  # most_moving_mouth's choice, said


def most_moving_mouth(anims: Sequence[Animation]) -> str | None:
    """The blendshape opening the mouth (``OPENING_MOUTH``) whose values span the widest range in any of
    ``anims``, or when none of those moves, the jaw or mouth one; None when none of them moves."""
    for names in (OPENING_MOUTH, MOUTH_CHANNELS):
        spans = {c: max(float(np.ptp(a.weights[:, ARKIT61.index(c)])) for a in anims) for c in names}
        widest = max(spans, key=spans.__getitem__)
        if spans[widest] > 0:
            return widest
    return None


def default_frame(anim: Animation) -> tuple[int, str | None]:
    """The frame to show when none is asked for: the widest open jaw (a face mid-speech), and None. An
    input whose jawOpen is missing or 0 throughout (a rig's export without it) showed frame 0 without a
    word: its frame is then the highest value of ``most_moving_mouth``'s channel (the first frame when
    none moves), and a note saying so is returned with it. A frame without a face (its values bridged from
    the frames around it) is not picked: frame 0 of a take whose face was lost at its start was.
    """
    seen = with_face(anim.take) if anim.take is not None else np.ones(anim.time.size, bool)

    def highest(channel: str) -> int:
        return int(np.argmax(np.where(seen, anim.weights[:, ARKIT61.index(channel)], -np.inf)))

    jaw = anim.weights[:, ARKIT61.index("jawOpen")]
    if np.any(jaw != 0):
        return highest("jawOpen"), None
    why = "has jawOpen at 0 on every frame" if holds_channel(anim, "jawOpen") else "holds no jawOpen"
    mouth = most_moving_mouth([anim])
    if mouth is None:
        k = int(np.argmax(seen))  # the first frame with a face
        return k, f"{why} and no mouth channel moves: frame {k} shown; give --frame or --time to pick one"
    k = highest(mouth)
    return k, (
        f"{why}: frame {k} shown, where {mouth} ({MOVING_MOUTH}) is highest; give --frame or --time to pick "
        "another"
    )


def render_frame(
    renderer: FaceRenderer,
    anims: Sequence[Animation],
    t_rel: float,
    video: ReferenceVideo | None = None,
    labels: bool = True,
) -> np.ndarray:
    """One side-by-side image of every animation ``t_rel`` seconds after its own first frame, with the
    reference video's frame at the first animation's take time after them."""
    panels = []
    for a in anims:
        img = renderer.render(a.at(np.array([a.t0 + t_rel - a.offset_s]))[0])
        panels.append(label_image(img, a.label) if labels and (len(anims) > 1 or video) else img)
    if video is not None:
        frame = video.at(anims[0].t0 + t_rel)
        panels.append(label_image(frame, "reference video") if labels else frame)
    return np.hstack(panels)


@dataclass
class Speech:
    """A video's sound: ``frames`` mono float32 samples at ``rate`` Hz, given a block at a time by
    ``blocks`` (one pass), so that the sound of a long take is never whole in memory as float."""

    blocks: Iterable[np.ndarray]
    rate: int
    frames: int


def _silence(count: int) -> Iterator[np.ndarray]:
    """``count`` zero samples, at most ``AUDIO_BLOCK`` a block."""
    zeros = np.zeros(min(count, AUDIO_BLOCK), np.float32)
    for start in range(0, count, AUDIO_BLOCK):
        yield zeros[: min(AUDIO_BLOCK, count - start)]


def span_blocks(anim: Animation, t0: float, duration_s: float) -> Speech | None:
    """``anim``'s audio from take time ``t0`` for ``duration_s`` as mono float32 ``Speech``, zero-padded
    where the audio does not reach. Only the span is converted, a block at a time as it is asked for
    (``align.resample.mono_blocks``, the samples of ``Audio.mono_float``): the whole take as float cost
    3 copies of an hour of speech (2 GB at 48 kHz), and the span's float copy held for the encoder
    still 460 MB for two hours at 16 kHz."""
    from align.resample import mono_blocks

    if anim.audio is None:
        return None
    audio = anim.audio
    rate = audio.sample_rate
    first = int(round((t0 - anim.audio_start_s) * rate))
    n = int(round(duration_s * rate))
    lo, hi = max(first, 0), min(first + n, audio.frames)
    heard = max(hi - lo, 0)
    before = lo - first if heard else n

    def blocks() -> Iterator[np.ndarray]:
        yield from _silence(before)
        if heard:
            span = copy.copy(audio)  # a view of the span: a new Audio would check its samples again
            span.samples = audio.samples[lo:hi]
            yield from mono_blocks(span)
        yield from _silence(n - before - heard)

    return Speech(blocks(), rate, n)


def speech_for_video(anims: Sequence[Animation], duration_s: float) -> tuple[Animation, Speech] | None:
    """The speech of the first input that has audio, for a video of ``duration_s`` s: that input and its
    ``Speech``. An input shown ``offset_s`` after the first one is at its take time ``t0 - offset_s``
    when the video starts, so its sound is cut from there and stays with its face."""
    voice = next((a for a in anims if a.audio is not None), None)
    if voice is None:
        return None
    speech = span_blocks(voice, voice.t0 - voice.offset_s, duration_s)
    assert speech is not None
    return voice, speech


def aac_rate(rate: int) -> int:
    """The sample rate speech at ``rate`` is encoded at in AAC: ``rate`` itself when the encoder takes
    it, else the lowest rate it takes above it (nothing of the sound lost), its highest beyond them all."""
    import av

    rates = sorted(av.codec.Codec("aac", "w").audio_rates)
    if rate in rates:
        return rate
    return next((r for r in rates if r > rate), rates[-1])


def resample_speech(speech: Speech, to: int) -> Speech:
    """``speech`` resampled to ``to`` Hz with soxr, as align resamples speech (``align/resample.py`` says
    why soxr), a block at a time as it is asked for: libsoxr's stream gives the samples of
    ``soxr.resample`` on the whole."""
    import soxr

    stream = soxr.ResampleStream(speech.rate, to, 1, dtype="float32", quality="VHQ")

    def blocks() -> Iterator[np.ndarray]:
        for block in speech.blocks:
            yield stream.resample_chunk(block, last=False)
        yield stream.resample_chunk(np.zeros(0, np.float32), last=True)

    return Speech(blocks(), to, math.floor(speech.frames * to / speech.rate + 0.5))  # libsoxr's count


def mp4_frame_fits(width: int, height: int) -> bool:
    """Whether H.264 (libx264, and decoders up to level 6.2) takes a ``width`` x ``height`` frame."""
    macroblocks = math.ceil(width / 16) * math.ceil(height / 16)
    return max(width, height) <= H264_MAX_SIDE and macroblocks <= H264_MAX_MACROBLOCKS


def _fps_fraction(fps: float) -> Fraction:
    return Fraction(fps).limit_denominator(1001)


def write_mp4(
    path: str | Path,
    frames: Callable[[int], np.ndarray],
    count: int,
    fps: float,
    audio: Speech | None,
    on_frame: Callable[[int], None] | None = None,
) -> dict:
    """Encode ``count`` frames (``frames(k)`` → RGB uint8) as H.264 at ``fps`` with AAC audio (a
    ``Speech``, encoded as its blocks come; None: no sound track).

    Written as ``.NAME.partial.mp4`` beside ``path``, locked (``flock``) until it is renamed into place:
    another render to the same ``path`` meanwhile is an ``InputError`` that leaves it alone.
    Returns timing figures: seconds spent rendering (inside ``frames``) and encoding. What follows the
    frames (the encoder's last frames, the audio, the file's index: 24 s for an hour of audio here) is
    said every few seconds when it takes that long (``TimedProgress``: ``render: NAME: audio: k/n s``).
    """
    import av

    path = Path(path)
    tmp = partial_path(path, ".mp4")  # beside it; for a device or pipe, in a folder of our own
    render_s = encode_s = 0.0
    rate = _fps_fraction(fps)
    # Held until the file is renamed into place: a second render to the same name at once (a batch run
    # twice) wrote into the same partial file, and the first one renamed a mix of both as its output.
    # Taken inside the ``try``, with a stop held back until ``lock`` holds it: one landing between the
    # lock and the ``try`` left the lock held and the partial file behind.
    lock = None
    try:
        with stops_deferred():
            lock = lock_partial(tmp, path)
        with writing(path, "video"), av.open(ffmpeg_name(tmp), "w", format="mp4") as out:
            t = time.perf_counter()
            first = frames(0)
            render_s = time.perf_counter() - t  # the first frame's too: a 1-frame video said 0 ms a frame
            h, w = first.shape[:2]
            vs = out.add_stream("libx264", rate=rate)
            vs.width, vs.height = w - w % 2, h - h % 2
            vs.pix_fmt = "yuv420p"
            vs.options = {"crf": "20", "preset": "veryfast"}
            astream = None
            if audio is not None:
                astream = out.add_stream("aac", rate=audio.rate, layout="mono")
            for k in range(count):
                t = time.perf_counter()
                img = first if k == 0 else frames(k)
                t2 = time.perf_counter()
                render_s += t2 - t
                vf = av.VideoFrame.from_ndarray(
                    np.ascontiguousarray(img[: vs.height, : vs.width]), format="rgb24"
                )
                vf.pts = k
                for packet in vs.encode(vf):
                    out.mux(packet)
                encode_s += time.perf_counter() - t2
                if on_frame is not None:
                    on_frame(k)
            t2 = time.perf_counter()
            job = TimedProgress(f"render: {path.name}")
            with job.ticking("finishing the video"):
                for packet in vs.encode():
                    out.mux(packet)
            if astream is not None:
                sr, at = audio.rate, 0
                job.step("audio", math.ceil(audio.frames / sr), "s")
                from align.resample import in_rows  # align's imports only for a video with sound

                for rows in in_rows(audio.blocks, AAC_FRAME, tail=True):
                    for row in rows:
                        raise_if_stopped()  # a Ctrl-C here stopped only after the whole audio (30 s an hour)
                        job.update(at // sr)
                        af = av.AudioFrame.from_ndarray(row[None, :], format="flt", layout="mono")
                        af.sample_rate = sr
                        af.pts = at
                        af.time_base = Fraction(1, sr)
                        for packet in astream.encode(af):
                            out.mux(packet)
                        at += row.size
                for packet in astream.encode():
                    out.mux(packet)
                job.update(job.total)
            with job.ticking("writing the file"):
                out.close()  # the container's index: leaving the ``with`` closes it again, a no-op
            encode_s += time.perf_counter() - t2
        # A signal during the flush and mux above was only noted (stops_between_frames): stop before the
        # rename, so that a stopped render never leaves its output.
        raise_if_stopped()
        with writing(path, "video"):
            put_in_place(tmp, path)
    except BaseException:
        if lock is not None:  # else another render's partial file, or none
            with stops_deferred():  # a second Ctrl-C cuts no removal short
                tmp.unlink(missing_ok=True)
        raise
    finally:
        if lock is not None:
            os.close(lock)
    return {"render_s": render_s, "encode_s": encode_s, "width": w - w % 2, "height": h - h % 2}


def write_image(path: str | Path, img: np.ndarray) -> None:
    """PNG/JPEG by extension (OpenCV), written atomically; ``InputError`` naming ``path`` when the
    extension is not an image format or the file cannot be written."""
    import cv2

    path = Path(path)
    try:
        ok, data = cv2.imencode(path.suffix.lower(), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    except cv2.error:
        ok = False
    if not ok:
        raise InputError(f"OpenCV cannot write {path.suffix or 'a file without extension'} images", path)
    with writing(path, "image"), atomic_write(path) as f:
        f.write(data.tobytes())
        raise_if_stopped()  # a signal noted while writing stops here, before the partial file is renamed
