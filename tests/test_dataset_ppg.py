"""PPG backends: the paper's bottleneck network (checkpoint written here, loaded weights-only), a
user's TorchScript and ONNX model, and pocketsphinx phone recognition checked against reference
phone alignments of real English speech."""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from conftest import ROOT, run_cli, run_here
from dataset_helpers import speech_like, write_aligned_set

from capture.take import sha256_file
from dataset import ShardReader, read_manifest
from dataset.features import FeatureSettings, compute_features, spectral_features
from dataset.ppg import make_extractor

torch = pytest.importorskip("torch")
pytestmark = [
    pytest.mark.filterwarnings("ignore:`torch.jit.script` is deprecated:DeprecationWarning"),
    pytest.mark.filterwarnings("ignore:`torch.jit.load` is deprecated:DeprecationWarning"),
]


@pytest.fixture(scope="module")
def takes(tmp_path_factory) -> Path:
    return write_aligned_set(tmp_path_factory.mktemp("ppg") / "takes", count=3, speakers=1, seconds=2.0)


def _ppg_arrays(ds: Path) -> dict[str, np.ndarray]:
    import io

    out = {}
    for s in read_manifest(ds)["shards"]:
        for key, members in ShardReader(ds / s["name"]):
            out[key] = np.load(io.BytesIO(members["ppg.npy"]))
    return out


def test_bottleneck_checkpoint_round_trip_and_build(takes, tmp_path):
    from dataset.bottleneck import BottleneckConfig, BottleneckPPG, load_bottleneck, save_bottleneck

    torch.manual_seed(0)
    model = BottleneckPPG(BottleneckConfig(hidden=64))
    ckpt = tmp_path / "ppg.pt"
    save_bottleneck(model, ckpt)
    loaded = load_bottleneck(ckpt)
    for (k, a), (k2, b) in zip(model.state_dict().items(), loaded.state_dict().items(), strict=True):
        assert k == k2 and torch.equal(a, b)
    ds = tmp_path / "ds"
    proc = run_cli("dataset", "build", takes, "-o", ds, "--ppg", "bottleneck", "--ppg-model", ckpt, "--json")
    assert proc.returncode == 0, proc.stderr
    m = read_manifest(ds)
    ppg = m["features"]["ppg"]
    assert ppg["backend"] == "bottleneck" and ppg["dim"] == 64 and ppg["model_sha256"] == sha256_file(ckpt)
    assert m["features"]["dims"]["ppg"] == 64 and "phones.npy" in m["members"]
    arrays = _ppg_arrays(ds)
    assert all(a.shape[1] == 64 and a.dtype == np.float32 and np.isfinite(a).all() for a in arrays.values())
    # the stored PPG is what the network computes from the preprocessor's filter banks
    # validate's and stats' command lines run as subprocesses in test_dataset_build.py: here, in this process
    assert run_here("dataset", "validate", ds, "--deep").returncode == 0
    stats = json.loads(run_here("dataset", "stats", ds, "--json").stdout)
    assert stats["phone_coverage"]["phones"] == 40 and stats["phone_coverage"]["covered"] >= 1


def test_checkpoint_with_pickled_code_is_refused(takes, tmp_path):
    marker = tmp_path / "pwned"

    class Evil:
        def __reduce__(self):
            return (open, (str(marker), "w"))

    ckpt = tmp_path / "evil.pt"
    torch.save({"format": "s2a-ppg-bottleneck", "config": {}, "state_dict": {}, "x": Evil()}, str(ckpt))
    proc = run_cli(
        "dataset", "build", takes, "-o", tmp_path / "ds", "--ppg", "bottleneck", "--ppg-model", ckpt
    )
    assert proc.returncode == 1 and "holds Python objects other than tensors" in proc.stderr, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
    assert not marker.exists()
    # a plain pickle (not a torch.save archive) with the same payload, and a WAV given by mistake
    import pickle

    ckpt.write_bytes(pickle.dumps(Evil(), protocol=4))
    wav = next(Path(takes).rglob("*.wav"))
    for model, needle in (
        (ckpt, "not an archive torch.save writes"),
        (wav, "not an archive torch.save writes"),
    ):
        proc = run_here(
            "dataset", "build", takes, "-o", tmp_path / "ds", "--ppg", "bottleneck", "--ppg-model", model
        )
        assert proc.returncode == 1 and needle in proc.stderr and "PPG checkpoint" in proc.stderr, proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1
    assert not marker.exists()


class _Tiny(torch.nn.Module):
    def __init__(self):
        super().__init__()
        torch.manual_seed(1)
        self.proj = torch.nn.Linear(40, 8)

    def forward(self, fbank):
        return torch.softmax(self.proj(fbank), dim=-1)


def test_torchscript_and_onnx_models_agree(takes, tmp_path):
    model = _Tiny().eval()
    ts = tmp_path / "ppg.ts"
    torch.jit.script(model).save(str(ts))
    ds_ts = tmp_path / "ds_ts"
    proc = run_here("dataset", "build", takes, "-o", ds_ts, "--ppg", "torchscript", "--ppg-model", ts)
    assert proc.returncode == 0, proc.stderr
    assert read_manifest(ds_ts)["features"]["ppg"]["dim"] == 8
    ts_arrays = _ppg_arrays(ds_ts)
    for a in ts_arrays.values():
        np.testing.assert_allclose(a.sum(1), 1.0, atol=1e-5)  # posteriors, interpolated, still sum to one

    pytest.importorskip("onnxruntime")
    pytest.importorskip("onnx")
    onnx_path = tmp_path / "ppg.onnx"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            model,
            (torch.zeros(1, 10, 40),),
            str(onnx_path),
            input_names=["fbank"],
            output_names=["ppg"],
            dynamic_axes={"fbank": {1: "frames"}, "ppg": {1: "frames"}},
            dynamo=False,
        )
    ds_onnx = tmp_path / "ds_onnx"
    proc = run_here("dataset", "build", takes, "-o", ds_onnx, "--ppg", "onnx", "--ppg-model", onnx_path)
    assert proc.returncode == 0, proc.stderr
    onnx_arrays = _ppg_arrays(ds_onnx)
    assert onnx_arrays.keys() == ts_arrays.keys()
    for k in ts_arrays:
        np.testing.assert_allclose(onnx_arrays[k], ts_arrays[k], atol=1e-5)


def test_model_inference_leaves_the_callers_thread_count(tmp_path):
    """PPG models run on one torch thread (bit-identical features) only while they run: the caller's
    count is back afterwards, as it is after the align stage's silero VAD."""
    from dataset.bottleneck import BottleneckConfig, BottleneckPPG, save_bottleneck

    torch.manual_seed(0)
    ckpt = tmp_path / "ppg.pt"
    save_bottleneck(BottleneckPPG(BottleneckConfig(hidden=64)), ckpt)
    ts = tmp_path / "ppg.ts"
    torch.jit.script(_Tiny().eval()).save(str(ts))
    audio, _ = speech_like(2.0, np.random.default_rng(3))
    caller = torch.get_num_threads()
    try:
        for backend, model in (("bottleneck", ckpt), ("torchscript", ts)):
            torch.set_num_threads(3)
            extractor = make_extractor(backend, model)  # the TorchScript one runs its model once here
            assert torch.get_num_threads() == 3, backend
            inside: list[int] = []  # the thread count the bottleneck network sees
            if backend == "bottleneck":
                extractor.model.register_forward_pre_hook(
                    lambda *_, seen=inside: seen.append(torch.get_num_threads())
                )
            runs = []
            for threads in (3, 2):
                torch.set_num_threads(threads)
                feats, _ = compute_features(
                    audio, 120, 60.0, ("fbank", "ppg"), FeatureSettings(), ppg=extractor
                )
                assert torch.get_num_threads() == threads, backend
                runs.append(feats["ppg"])
            assert np.array_equal(runs[0], runs[1]), backend  # bit-identical whatever the caller's count
            if backend == "bottleneck":
                assert inside == [1, 1]
    finally:
        torch.set_num_threads(caller)
    # silero-vad pins one thread for the whole process when first imported: in a fresh process.
    code = (
        "import numpy as np, torch; torch.set_num_threads(2)\n"
        "from align.vad import speech_segments\n"
        "x = (0.3 * np.sin(np.arange(32000) * 0.1) * (np.arange(32000) > 16000)).astype(np.float32)\n"
        "print(len(speech_segments(x, 'silero')), torch.get_num_threads())\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split()[1] == "2"


def test_model_with_wrong_output_is_rejected(takes, tmp_path):
    class Pool(torch.nn.Module):
        def forward(self, fbank):
            return fbank[:, ::2]

    ts = tmp_path / "bad.ts"
    torch.jit.script(Pool()).save(str(ts))
    proc = run_here(
        "dataset", "build", takes, "-o", tmp_path / "ds", "--ppg", "torchscript", "--ppg-model", ts
    )
    assert proc.returncode == 1 and "expected (1, " in proc.stderr and "bad.ts" in proc.stderr


def test_pocketsphinx_phones_match_reference_alignments(samples):
    pytest.importorskip("pocketsphinx")
    from dataset.ppg import ARPABET, PocketsphinxExtractor

    folder = samples / "speech" / "pocketsphinx-testdata-librivox"
    ref = json.loads((folder / "alignments_pocketsphinx.json").read_text())
    extractor = PocketsphinxExtractor()
    hits = total = 0
    first = {}
    for name, entry in ref.items():
        x, rate = sf.read(folder / f"{name}.wav", dtype="float32")
        assert rate == 16000
        fbank = spectral_features(x, FeatureSettings())["fbank"]
        result = extractor.extract(x, fbank)
        first[name] = (x, fbank, result.phone_ids)
        assert result.posteriors.shape == (fbank.shape[0], len(ARPABET))
        np.testing.assert_array_equal(result.posteriors.sum(1), 1.0)
        t = np.arange(fbank.shape[0]) * 0.02
        want = np.full(t.size, -1)
        for word in entry["words"]:
            for p in word["phones"]:
                ph = p["phone"].upper()
                want[(t >= p["start"]) & (t < p["end"])] = ARPABET.index(ph) if ph in ARPABET else 0
        ok = want >= 0
        hits += int((result.phone_ids[ok] == want[ok]).sum())
        total += int(ok.sum())
    # phone-loop recognition without a word model: far above the 1-in-40 chance level
    assert hits / total > 0.35
    # An utterance's phones do not depend on what the extractor decoded before (a reused decoder's
    # state made builds with --jobs 2 differ from --jobs 1).
    for name in reversed(list(first)):
        x, fbank, ids = first[name]
        np.testing.assert_array_equal(extractor.extract(x, fbank).phone_ids, ids, err_msg=name)


def test_pocketsphinx_forced_alignment_with_transcript(samples):
    pytest.importorskip("pocketsphinx")
    from dataset.ppg import ARPABET, PocketsphinxExtractor

    folder = samples / "speech" / "pocketsphinx-testdata-librivox"
    ref = json.loads((folder / "alignments_pocketsphinx.json").read_text())
    name, entry = sorted(ref.items())[0]
    x, _ = sf.read(folder / f"{name}.wav", dtype="float32")
    fbank = spectral_features(x, FeatureSettings())["fbank"]
    result = PocketsphinxExtractor().extract(x, fbank, transcript=entry["text"])
    t = np.arange(fbank.shape[0]) * 0.02
    want = np.full(t.size, -1)
    for word in entry["words"]:
        for p in word["phones"]:
            want[(t >= p["start"]) & (t < p["end"])] = ARPABET.index(p["phone"].upper())
    ok = want >= 0
    # the reference was made by pocketsphinx's aligner: the phones agree almost everywhere
    assert (result.phone_ids[ok] == want[ok]).mean() > 0.9


def test_model_for_another_filter_bank_width_gets_a_clear_error(takes, tmp_path):
    """A user's model built for 80 mel bins fails inside TorchScript; the build names the width it fed."""
    ts = tmp_path / "mel80.ts"
    torch.jit.script(torch.nn.Linear(80, 64)).save(str(ts))
    proc = run_here(
        "dataset", "build", takes, "-o", tmp_path / "ds", "--ppg", "torchscript", "--ppg-model", ts
    )
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "(1, frames, 40) filter banks" in proc.stderr and "mel80.ts" in proc.stderr


@pytest.mark.parametrize(
    ("forward", "needle"),
    [
        ("fbank[:, :, :8] * float('nan')", "NaN or infinite"),
        ("fbank[:, :, :0]", "dim in 1..4096"),
    ],
    ids=["nan", "no-width"],
)
def test_model_with_unusable_values_is_rejected(takes, tmp_path, forward, needle):
    source = tmp_path / "bad_model.py"
    source.write_text(
        f"import torch\nclass M(torch.nn.Module):\n    def forward(self, fbank):\n        return {forward}\n"
    )
    import importlib.util

    spec = importlib.util.spec_from_file_location("bad_model", source)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    ts = tmp_path / "bad.ts"
    torch.jit.script(module.M()).save(str(ts))
    proc = run_here(
        "dataset", "build", takes, "-o", tmp_path / "ds", "--ppg", "torchscript", "--ppg-model", ts
    )
    assert proc.returncode == 1 and needle in proc.stderr and "Traceback" not in proc.stderr, proc.stderr


@pytest.mark.parametrize("backend", ["none", "pocketsphinx"])
def test_a_model_file_for_a_backend_without_one_is_an_error(takes, tmp_path, backend):
    model = tmp_path / "ppg.pt"
    model.write_bytes(b"x")
    proc = run_here("dataset", "build", takes, "-o", tmp_path / "ds", "--ppg", backend, "--ppg-model", model)
    assert proc.returncode == 1 and "uses no model file" in proc.stderr, proc.stderr
