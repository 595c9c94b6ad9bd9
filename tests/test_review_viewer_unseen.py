"""``s2a-view`` against inputs and uses not seen before: a long take's frames cost what a short one's
do, an ``-o`` that names a file the render reads is refused before it is replaced, a glTF head whose
morph targets miss channels the take moves says so (and the spellings Maya and Blender give targets
are read), the speech of a video is cut without converting the whole take first, a second render to
one video at once is refused, and a stop during the audio does not wait for the rest of it."""

from __future__ import annotations

import fcntl
import os
import signal
import time
import tracemalloc

import numpy as np
import pytest
from conftest import run_here
from test_viewer_gltf_robustness import IDX, POS, _blob_uri, _doc, _write

from capture import ARKIT61, Audio
from capture.command import Terminated
from capture.errors import InputError
from capture.mov import write_reference_mov
from viewer.cli import _face_gaps
from viewer.face import builtin_face
from viewer.gltf import arkit_channel, load_gltf
from viewer.output import stopped_by_signals, stops_between_frames
from viewer.render import Animation, Speech, load_animation, span_blocks, write_image, write_mp4

CSV = "livelinkface/alexdjulin_S07/S07-001.csv"  # jawOpen moves from its first row


def _short_csv(samples, folder, rows: int = 12):
    folder.mkdir(exist_ok=True)
    path = folder / "take.csv"
    with open(samples / CSV, encoding="utf-8") as f:
        path.write_text("".join(next(f) for _ in range(rows + 1)), encoding="utf-8")
    return path


def _cpu_per_call(anim: Animation, calls: int) -> float:
    times = anim.time[0] + np.linspace(0, anim.time[-1] - anim.time[0], calls)
    start = time.process_time()
    for t in times:
        anim.at(np.array([t]))
    return (time.process_time() - start) / calls


def test_a_frame_of_a_long_take_costs_what_a_frame_of_a_short_one_does():
    """Each frame of a render asks ``at`` for one instant: it read every column of the whole take (9 ms
    a frame for a 10-minute take, 65 ms for an hour's: the render grew with the square of its length)."""
    rng = np.random.default_rng(0)
    long = Animation("long", 60.0, np.arange(60_000) / 60.0, rng.uniform(0, 1, (60_000, 61)))
    short = Animation("short", 60.0, long.time[:60].copy(), long.weights[:60].copy())
    _cpu_per_call(short, 20)  # warm
    assert _cpu_per_call(long, 40) < 4 * _cpu_per_call(short, 40) + 0.001


def test_weights_between_frames_are_those_np_interp_gives():
    rng = np.random.default_rng(1)
    times = np.cumsum(rng.uniform(0.01, 0.03, 300))
    anim = Animation("a", 60.0, times, rng.uniform(-1, 1, (300, 61)))
    asked = np.concatenate([rng.uniform(times[0] - 1, times[-1] + 1, 500), times, [-1e9, 1e9]])
    expected = np.stack([np.interp(asked, times, anim.weights[:, k]) for k in range(61)], axis=1)
    np.testing.assert_allclose(anim.at(asked), expected, rtol=0, atol=1e-12)
    one = Animation("one", 60.0, times[:1], anim.weights[:1])  # a take of one frame: held everywhere
    np.testing.assert_array_equal(one.at(asked[:5]), np.repeat(anim.weights[:1], 5, axis=0))


@pytest.fixture
def movie(tmp_path):
    """A user's clip with sound, named .mp4: usable as the reference video and as the speech."""
    t = np.arange(8000) / 16000
    tone = Audio((8000 * np.sin(2 * np.pi * 440 * t)).astype(np.int16)[:, None], 16000, "PCM_16")
    return write_reference_mov(tmp_path / "clip.mp4", 60, 4, tone, size=(16, 16))


@pytest.mark.parametrize("option", ["--video", "--audio"])
def test_an_output_naming_a_file_the_render_reads_is_refused(samples, tmp_path, movie, option):
    """``-o clip.mp4 --video clip.mp4`` replaced the user's clip with the render once it was done."""
    before = movie.read_bytes()
    csv = _short_csv(samples, tmp_path / "take")
    proc = run_here("viewer", "render", csv, option, movie, "-o", tmp_path / "." / "clip.mp4", "--size", 16)
    assert proc.returncode == 1, proc.stderr
    (line,) = proc.stderr.strip().splitlines()
    assert "read by this command: give the output another name" in line, line
    assert movie.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.mp4", "take"]


def test_a_head_without_targets_for_channels_the_take_moves_says_which(samples, tmp_path):
    """A head whose jaw target is named in a way no rule reads rendered a still mouth without a word
    (``render`` prints these lines and puts the channels in its summary's ``face_missing``)."""
    head = _write(
        tmp_path / "head.gltf",
        _doc(
            **{
                "meshes.0.primitives.0.targets": [{"POSITION": 2}, {"POSITION": 2}],
                "meshes.0.extras.targetNames": ["eyeBlinkLeft", "FACS_JawDrop"],
            }
        ),
    )
    take = load_animation(_short_csv(samples, tmp_path / "take", rows=12))
    assert take.weights[:, ARKIT61.index("jawOpen")].max() > 0
    missing, lines = _face_gaps(load_gltf(head), [take])
    assert "jawOpen" in missing and "eyeBlinkLeft" not in missing
    (line,) = lines
    assert line.startswith(f"head.gltf: {len(missing)} blendshape(s) the input moves have no morph target")
    widest = max(missing, key=lambda c: take.weights[:, ARKIT61.index(c)].max())
    assert missing[0] == widest and f": {widest}, " in line and f"and {len(missing) - 5} more;" in line
    assert line.endswith("its morph targets not matched to one: FACS_JawDrop")
    assert _face_gaps(builtin_face(), [take]) == ([], [])  # the built-in face moves all 52


@pytest.mark.parametrize(
    "name, channel",
    [
        ("blendShape1_jawOpen", "jawOpen"),  # Maya's numbered blendShape node, joined by "_"
        ("blendShape12.eyeBlink_L", "eyeBlinkLeft"),
        ("jawOpen.001", "jawOpen"),  # Blender's duplicate
        ("mouthSmile.L.001", "mouthSmileLeft"),
        ("target0", None),
        ("shape_12", None),
    ],
)
def test_numbered_target_names_map_to_their_channel(name, channel):
    assert arkit_channel(name) == channel


def test_a_head_of_numbered_maya_targets_loads(tmp_path):
    head = _write(tmp_path / "maya.gltf", _doc(**{"meshes.0.extras.targetNames": ["blendShape1_jawOpen"]}))
    assert load_gltf(head).extra["mapped"] == ["jawOpen"]


def test_speech_for_a_span_is_cut_before_it_is_converted():
    """A video's speech was converted whole to float (three copies on the way) before its span was cut."""
    rng = np.random.default_rng(2)
    stereo = Audio(rng.integers(-30000, 30000, (48000 * 60, 2), dtype=np.int16), 48000, "PCM_16")
    anim = Animation("a", 60.0, np.arange(10) / 60, np.zeros((10, 61)), audio=stereo, audio_start_s=-0.5)
    list(span_blocks(anim, 0.0, 0.01).blocks)  # the modules it imports on first use are not the span's memory
    tracemalloc.start()
    try:
        speech = span_blocks(anim, 10.0, 1.0)
        samples = np.concatenate(list(speech.blocks))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 8 * samples.nbytes, peak  # the whole take as float is 60 times the span
    whole = stereo.mono_float()
    np.testing.assert_array_equal(samples, whole[int(10.5 * 48000) :][:48000])
    edges = np.concatenate(list(span_blocks(anim, 59.0, 2.0).blocks))  # past the end: zero-padded
    np.testing.assert_array_equal(edges[:24000], whole[-24000:])
    assert not edges[24000:].any() and speech.rate == 48000


def test_a_second_render_to_the_same_video_at_once_leaves_the_first_alone(tmp_path):
    """Two renders to one name at once (a batch started twice) wrote into one partial file, and the
    first to finish renamed a mix of both as its video; the second is now refused, and the first's
    partial file is left as it was."""
    out = tmp_path / "take.mp4"
    partial = tmp_path / ".take.mp4.partial.mp4"
    partial.write_bytes(b"the first render's frames")
    with open(partial, "rb+") as first:
        fcntl.flock(first, fcntl.LOCK_EX | fcntl.LOCK_NB)  # as the render under way holds it
        with pytest.raises(InputError, match=r"another command is writing this video right now"):
            write_mp4(out, lambda k: np.zeros((16, 16, 3), np.uint8), 2, 30.0, None)
        assert partial.read_bytes() == b"the first render's frames" and not out.exists()
    write_mp4(out, lambda k: np.full((16, 16, 3), 9 * k, np.uint8), 2, 30.0, None)  # once it is done
    assert out.stat().st_size > 0 and sorted(p.name for p in tmp_path.iterdir()) == ["take.mp4"]


def test_a_stop_during_the_audio_stops_before_the_rest_of_it_is_encoded(tmp_path, monkeypatch, capsys):
    """A SIGTERM noted while the frames were done stopped the render only after all its audio was
    encoded (24-30 s for an hour of speech); now at the next block, the partial file removed."""
    monkeypatch.setenv("S2A_PROGRESS_INTERVAL_S", "0")  # a progress line for each block of audio
    speech = np.zeros(16000 * 20, np.float32)

    def last_frame(k: int) -> None:
        if k == 1:
            os.kill(os.getpid(), signal.SIGTERM)  # noted only: rendering is under way

    with pytest.raises(Terminated), stopped_by_signals(), stops_between_frames():
        write_mp4(
            tmp_path / "t.mp4",
            lambda k: np.zeros((16, 16, 3), np.uint8),
            2,
            30.0,
            Speech([speech], 16000, speech.size),
            last_frame,
        )
    assert list(tmp_path.iterdir()) == []
    assert "audio: 20/20 s" not in capsys.readouterr().err


@pytest.mark.parametrize(
    "offset, needle",
    [(np.nan, "not finite"), (np.inf, "not finite"), (1e30, "over 100 times the head's size (1)")],
)
def test_a_morph_target_of_damaged_offsets_is_refused_not_rendered_blank(tmp_path, offset, needle):
    """A target's offsets were not checked as its positions are: NaN, or a vertex thrown 1e30 away,
    rendered every frame that moves it as the background alone, without a word."""
    delta = np.array([[0, 0, 0], [0, offset, 0], [0, 0, 0], [0, 0, 0]], np.float32)
    head = _write(
        tmp_path / "head.gltf",
        _doc(**{"buffers.0.uri": _blob_uri(POS.tobytes() + IDX.tobytes() + delta.tobytes())}),
    )
    with pytest.raises(InputError) as err:
        load_gltf(head)
    assert str(err.value).startswith(f"{head}: mesh 0 primitive 0: morph target jawOpen moves ")
    assert needle in str(err.value)


@pytest.mark.parametrize("suffix", [".png", ".mp4"])
def test_a_name_too_long_only_for_its_partial_file_says_so(tmp_path, suffix):
    """A legal name of 250 bytes failed with "File name too long": true of the hidden partial file
    beside it, not of the name the user gave."""
    out = tmp_path / ("a" * (250 - len(suffix)) + suffix)
    img = np.zeros((16, 16, 3), np.uint8)
    with pytest.raises(InputError) as err:
        if suffix == ".png":
            write_image(out, img)
        else:
            write_mp4(out, lambda k: img, 2, 30.0, None)
    assert str(err.value).startswith(f"{out}: cannot write the ")
    assert "its name of 250 bytes leaves no room for the hidden .NAME.partial file" in str(err.value)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "uri", ["/etc/hostname", "file:///etc/hostname", "C:/head.bin", "\\\\server\\head.bin"]
)
def test_a_buffer_uri_that_is_not_beside_the_gltf_is_refused(tmp_path, uri):
    """A .gltf's buffer URI naming an absolute path or another scheme was read from wherever it pointed
    (any file on the machine taken as the head's vertices); glTF 2.0 buffers are data URIs or files
    relative to the .gltf: one line naming the buffer."""
    path = _write(tmp_path / "head.gltf", _doc(**{"buffers.0.uri": uri}))
    with pytest.raises(InputError, match="buffer 0: .* is not a file beside the .gltf"):
        load_gltf(path)
