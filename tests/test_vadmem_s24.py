"""Voice-activity detection of long takes without whole-take copies: the detectors are fed the 16 kHz
audio a block at a time, raised by the gain (quiet speech) and, for WebRTC, made 16-bit block by block.
The whole-array code made a raised copy of all of it and clipped it into another (2 x 460 MB for a 2 h
take), and WebRTC's 16-bit copy went through float temporaries as large (2.5 GB peak for ``s2a-view
plot --vad webrtc`` of 2 h at 48 kHz, 1.2 GB with ``--vad none``). Silero's state runs on from block to
block: the segments are those of the whole array in one call, checked against the package's own
whole-array functions here."""

from __future__ import annotations

import sys
import warnings

import numpy as np
import pytest
import soundfile as sf
from conftest import run_python

from align import vad
from align.resample import TARGET_RATE, to_16k_mono
from capture import read_audio

NEUROSYNC = "paired/neurosync-trainer-lite-testset/audio.wav"
BLOCK = 512 * 512  # samples silero's sequence model takes in one call: the blocks the detectors are fed

# A fresh process: 20 min of the real speech at 16 kHz, 60 dB down (so the detectors raise it), built in
# place; each detector run once on 20 s (its model loaded, its buffers for a whole block made), then on
# all of it: the peak resident memory that adds, its high-water mark reset before (/proc/self/clear_refs),
# in kB.
DETECTOR_PEAK = """
import sys
import numpy as np
from align.resample import to_16k_mono
from align.vad import speech_segments
from capture import read_audio

def peak():
    with open('/proc/self/status') as f:
        return int(next(line for line in f if line.startswith('VmHWM')).split()[1])

speech = to_16k_mono(read_audio(sys.argv[1]))
x = np.empty(20 * 60 * 16000, np.float32)
for lo in range(0, x.size, speech.size):
    x[lo : lo + speech.size] = speech[: x.size - lo]
x *= np.float32(1e-3)
for method in sys.argv[2:]:
    speech_segments(x[: 20 * 16000], method)
    with open('/proc/self/clear_refs', 'w') as f:
        f.write('5')
    before = peak()
    found = speech_segments(x, method)
    print(method, len(found), peak() - before)
"""


def test_the_detectors_hold_no_copy_of_a_long_take(samples):
    """20 min of quiet speech (73 MB of float32 at 16 kHz): the whole-array code raised its peak by two
    copies of it for either detector (147 MB and 219 MB measured); now by a few blocks (9 MB, 0 MB)."""
    proc = run_python(DETECTOR_PEAK, str(samples / NEUROSYNC), "silero", "webrtc", timeout=300)
    assert proc.returncode == 0, proc.stderr
    held_kb = 20 * 60 * TARGET_RATE * 4 // 1024
    for line in proc.stdout.splitlines():
        method, found, added_kb = line.split()
        assert int(found) > 0, line
        assert int(added_kb) < held_kb / 3, f"{method}: peak +{int(added_kb) // 1024} MB for 20 min"


# A fresh launcher (a few MB) runs the command and prints its child's peak resident memory, in kB.
CHILD_PEAK = (
    "import resource, subprocess, sys\n"
    "subprocess.run(sys.argv[1:], check=True, capture_output=True)\n"
    "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)\n"
)


def _plot_peak_kb(csv, wav, out, vad_method: str) -> int:
    plot = [sys.executable, "-m", "viewer", "plot", csv, "--audio", wav, "-o", out, "--vad", vad_method]
    proc = run_python(CHILD_PEAK, *map(str, plot), timeout=300)
    assert proc.returncode == 0, proc.stderr
    return int(proc.stdout.split()[-1])


def test_plotting_a_long_take_with_webrtc_holds_its_16k_audio_once(samples, tmp_path):
    """``s2a-view plot --vad webrtc`` of 20 min of the real speech (44.1 kHz int16): the detector's 16-bit
    copy went through float temporaries of the whole take, 255 MB over ``--vad none`` (its 16 kHz float32
    copy: 73 MB); now 114 MB over it."""
    pair = samples / "paired" / "neurosync-trainer-lite-testset"
    speech, rate = sf.read(pair / "audio.wav", dtype="int16")
    wav = tmp_path / "speech.wav"
    sf.write(wav, np.resize(speech, 20 * 60 * rate), rate, subtype="PCM_16")
    csv = pair / "testset.csv"
    none_kb = _plot_peak_kb(csv, wav, tmp_path / "none.png", "none")
    webrtc_kb = _plot_peak_kb(csv, wav, tmp_path / "webrtc.png", "webrtc")
    held_kb = 20 * 60 * TARGET_RATE * 4 // 1024
    assert webrtc_kb - none_kb < 2 * held_kb, f"+{(webrtc_kb - none_kb) // 1024} MB over --vad none"


@pytest.fixture(scope="module")
def speech(samples) -> np.ndarray:
    """The real NeuroSync speech (20 s) at 16 kHz, as align makes it."""
    return to_16k_mono(read_audio(samples / NEUROSYNC))


def _inputs(samples, speech: np.ndarray, sim_take) -> dict[str, np.ndarray]:
    """Real, simulated and hostile 16 kHz audio: lengths on and around the detectors' blocks and windows."""
    rng = np.random.default_rng(7)
    long = np.resize(speech, 3 * BLOCK + 1234)  # three block ends, in speech
    found = {
        "librivox": to_16k_mono(read_audio(next((samples / "speech").glob("*/*0870.wav")))),
        "simulated": to_16k_mono(read_audio(next(sim_take.glob("*.wav")))),
        "speech": speech,
        "long": long,
        "quiet": long * np.float32(10 ** (-50 / 20)),
        "very quiet": long * np.float32(10 ** (-90 / 20)),
        "clipped": np.clip(long * 40, -1, 1),
        "silence": np.zeros(BLOCK + 5, np.float32),
        "noise": (rng.standard_normal(BLOCK + 700) * 0.2).astype(np.float32),
        "float64": long.astype(np.float64),
    }
    for n in (
        0,
        1,
        479,
        480,
        511,
        512,
        513,
        BLOCK - 1,
        BLOCK,
        BLOCK + 1,
    ):
        found[f"{n} samples"] = np.resize(speech, n)
    return found


def _whole_silero(x: np.ndarray, gain: float, kind: str, model) -> list[tuple[float, float]]:
    """silero-vad's own whole-array functions on the whole raised copy (the code before)."""
    import silero_vad

    raised = np.ascontiguousarray(np.clip(x * np.float32(gain), -1.0, 1.0) if gain != 1.0 else x, np.float32)
    settings = {"sampling_rate": TARGET_RATE, "min_silence_duration_ms": 300, "speech_pad_ms": 0}
    if kind == "onnx":
        stamps = silero_vad.get_speech_timestamps_sequence(raised, model, **settings)
    else:
        import torch

        with torch.inference_mode():
            stamps = silero_vad.get_speech_timestamps(torch.from_numpy(raised), model, **settings)
    return [(s["start"] / TARGET_RATE, s["end"] / TARGET_RATE) for s in stamps]


def _whole_webrtc(x: np.ndarray, gain: float) -> list[tuple[float, float]]:
    """The WebRTC detector's flags of the whole raised array made 16-bit at once (the code before)."""
    import webrtcvad

    detector, hop = webrtcvad.Vad(2), 480  # 30 ms frames
    raised = np.clip(x * np.float32(gain), -1.0, 1.0).astype(np.float32) if gain != 1.0 else x
    pcm = np.clip(np.rint(raised * 32768.0), -32768, 32767).astype("<i2")
    flags = [
        detector.is_speech(pcm[i : i + hop].tobytes(), TARGET_RATE)
        for i in range(0, pcm.size // hop * hop, hop)
    ]
    return vad.runs_to_segments(np.array(flags), 0.03, 0.3, min_speech_s=0.09)


def test_segments_found_a_block_at_a_time_are_those_of_the_whole_array(samples, speech, sim_take):
    kind, model = vad._silero_model()
    assert kind == "onnx"  # the bundled sequence model under onnxruntime, as installed here
    for name, x in _inputs(samples, speech, sim_take).items():
        gain = vad.vad_gain(x)
        assert vad.speech_segments(x, "silero") == _whole_silero(x, gain, kind, model), name
        assert vad.speech_segments(x, "webrtc") == _whole_webrtc(x, gain), name
        assert vad.speech_segments(x, "silero", 37.5) == _whole_silero(x, 37.5, kind, model), name


def test_the_torchscript_model_is_stepped_through_the_blocks_as_through_the_whole(speech, monkeypatch):
    """Without onnxruntime, silero's TorchScript model: its windows stepped across the blocks' ends."""
    import silero_vad

    with warnings.catch_warnings():  # the package's own deprecation notices (torch.jit)
        warnings.simplefilter("ignore", DeprecationWarning)
        model = silero_vad.load_silero_vad()
    monkeypatch.setattr(vad, "_SILERO", ("torch", model))
    x = np.resize(speech, BLOCK + 3000)
    assert vad.speech_segments(x, "silero", 300.0) == _whole_silero(x, 300.0, "torch", model)
    assert vad.speech_segments(x[:700], "silero", 1.0) == _whole_silero(x[:700], 1.0, "torch", model)
