"""``s2a-train eval`` by phone (train/lipsync.py): RMSE per articulatory class of the frame's phone and
the share of the recorded bilabial closures a model keeps, on simulated takes built with a pocketsphinx
PPG, and the lip aperture checked on the real Live Link Face take with its audio."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
from conftest import run_cli, run_here
from test_channelmask_s26 import _copy_with

from align import align_take
from capture import read_csv_with_audio, write_take
from dataset.phones import ARPABET
from train.evaluate import RawSamples, evaluate, manifest_phones
from train.lipsync import (
    CLASS_NAMES,
    CLOSED,
    PHONE_CLASSES,
    LipSyncTally,
    aperture_columns,
    lip_aperture,
    phone_classes,
    runs,
)


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """Six simulated 10 s takes of two speakers, aligned, built with a pocketsphinx PPG (``ds``) and
    without one (``plain``), and a ridge run on filter banks (it fits both) trained on ``ds``."""
    pytest.importorskip("pocketsphinx")
    root = tmp_path_factory.mktemp("phonemetrics")
    sim_args = ["--speakers", 2, "--takes", 6, "--seconds", 10, "--seed", 5]
    run_here("capture", "simulate", "-o", root / "sim", *sim_args, check=True)
    run_here("capture", "import", root / "sim", "-o", root / "takes", check=True)
    run_here("align", root / "takes", "-o", root / "aligned", check=True)
    split = ["--split-by", "take", "--test-fraction", "0.3"]
    for name, ppg in (("ds", ["--ppg", "pocketsphinx"]), ("plain", [])):
        run_here("dataset", "build", root / "aligned", "-o", root / name, *split, *ppg, check=True)
    fit = ["--data", root / "ds", "-o", root / "run", "--model", "ridge", "--set", "input=fbank"]
    run_here("train", "fit", *fit, check=True)
    return root


def test_every_arpabet_phone_is_in_one_class():
    members = [p for _, phones, _ in PHONE_CLASSES for p in phones]
    assert sorted(members) == sorted(ARPABET)
    # names read as aligners write them; a name outside ARPAbet is unclassified
    classes = phone_classes(["m", "AA1", "uw", "v", "SIL", "xx"])
    assert [CLASS_NAMES[k] if k >= 0 else None for k in classes] == [
        "bilabial", "open_vowel", "rounded", "labiodental", "silence", None
    ]  # fmt: skip
    # a rig without jawOpen or mouthClose has no lip aperture; one without the lip channels, the jaw's
    tally = LipSyncTally(["jawOpen", "mouthFunnel"], list(ARPABET), 60.0)
    assert tally.bilabial_closure() is None and tally.per_phone_class()["unclassified_frames"] == 0
    assert aperture_columns(["mouthClose", "jawOpen"]) == ([1, 0], [])
    x = np.array([[0.3, 0.1], [0.1, 0.3], [1.5, 0.0]])  # jawOpen, mouthClose
    assert lip_aperture(x, ([0, 1], [])) == pytest.approx([0.2, 0.0, 1.0])


def test_eval_reports_errors_by_phone_class_and_bilabial_closures(sim):
    proc = run_cli("train", "eval", sim / "run", "--data", sim / "ds", "--json")
    assert proc.returncode == 0, proc.stderr
    r = json.loads(proc.stdout)
    by_class = r["per_phone_class"]["classes"]
    assert list(by_class) == list(CLASS_NAMES)
    frames = np.array([c["frames"] for c in by_class.values()])
    # pocketsphinx gives every frame a phone: the classes split exactly the frames rmse_entire scores
    assert r["per_phone_class"]["unclassified_frames"] == 0 and frames.sum() == r["frames"]
    for who, pooled in (("rmse", r["rmse_pooled"]), ("floor", r["floor"]["rmse_pooled"])):
        rmse = np.array([c[who] or 0.0 for c in by_class.values()])
        assert np.sqrt((rmse**2 * frames).sum() / frames.sum()) == pytest.approx(pooled, rel=1e-9)
    assert by_class["bilabial"]["frames"] > 0 and by_class["open_vowel"]["frames"] > 0
    closure = r["bilabial_closure"]
    assert closure["recorded_closures"] >= 5, closure
    # the ridge model closes the lips where the simulated face does; the train-mean floor never does
    assert closure["model"]["hit_rate"] >= 0.6 and closure["floor"]["hit_rate"] <= 0.2, closure
    proc = run_here("train", "eval", sim / "run", "--data", sim / "ds")
    assert proc.returncode == 0, proc.stderr
    assert "by phone class, rmse/floor (frames): bilabial" in proc.stdout
    n = closure["recorded_closures"]
    assert f"bilabial closures kept: {closure['model']['hits']}/{n}" in proc.stdout


def test_dataset_without_phones_says_so(sim):
    r = evaluate(sim / "run", sim / "plain", say=lambda _m: None)
    assert r["per_phone_class"] is None and r["bilabial_closure"] is None
    assert "no frame phones" in r["per_phone_class_note"] and "--ppg" in r["bilabial_closure_note"]
    proc = run_here("train", "eval", sim / "run", "--data", sim / "plain")
    assert proc.returncode == 0, proc.stderr
    assert "by phone class: n/a (the dataset stores no frame phones" in proc.stdout


def test_recorded_take_closes_its_lips_on_bilabials(samples, sim, tmp_path):
    """The real NeuroSync Live Link Face take with its audio, phones by pocketsphinx phone recognition:
    the lip aperture reaches closure on most of its bilabial segments, on few of its open vowels; a
    run trained on simulated takes is scored on it."""
    folder = samples / "paired" / "neurosync-trainer-lite-testset"
    (take,) = align_take(read_csv_with_audio(folder / "testset.csv", folder / "audio.wav"))
    write_take(take, tmp_path / "takes")
    ds = tmp_path / "ds"
    run_here("dataset", "build", tmp_path / "takes", "-o", ds, "--ppg", "pocketsphinx", check=True)
    manifest = json.loads((ds / "manifest.json").read_text())
    classes = phone_classes(manifest_phones(manifest))
    columns = aperture_columns(manifest["channels"])
    assert columns is not None and columns[1]  # pronunciation32 has the four lip channels
    closed = {"bilabial": [], "open_vowel": []}
    for item in RawSamples(ds, "train", window=None, normalize=False):
        aperture = lip_aperture(item["anim"].numpy().astype(np.float64), columns)
        ids, mask = item["phones"], item["mask"].numpy()
        cls = np.where(ids >= 0, classes[ids], -1)
        for name in closed:
            for start, end in runs(cls == CLASS_NAMES.index(name)):
                usable = mask[max(start - 1, 0) : end + 1]
                if usable.any():
                    closed[name].append(aperture[max(start - 1, 0) : end + 1][usable].min() <= CLOSED)
    assert len(closed["bilabial"]) >= 8 and len(closed["open_vowel"]) >= 10, closed
    assert np.mean(closed["bilabial"]) >= 0.75 and np.mean(closed["open_vowel"]) <= 0.4, closed
    r = evaluate(sim / "run", ds, "train", say=lambda _m: None)
    assert r["bilabial_closure"]["recorded_closures"] == sum(closed["bilabial"])
    # the counterpart: the open vowels the take opens on (17 of 20 reach OPENED)
    opened = r["open_vowel_opening"]
    assert opened["segments"] == len(closed["open_vowel"]) and opened["recorded_openings"] >= 12, opened
    assert r["per_phone_class"]["classes"]["bilabial"]["frames"] > 0


def test_damaged_phones_are_a_one_line_error(sim, tmp_path):
    """A sample whose phones.npy holds ids the manifest's phone list lacks (its shard's sha256 updated,
    as if the build had written it) is named, not scored as another phone."""
    manifest = json.loads((sim / "ds" / "manifest.json").read_text())
    key = next(s["key"] for s in manifest["samples"] if s["split"] == "test")
    frames = next(s["frames"] for s in manifest["samples"] if s["key"] == key)
    bad = io.BytesIO()
    np.save(bad, np.full(frames, 99, np.int16))
    ds = _copy_with(sim / "ds", tmp_path / "ds", key, "phones.npy", bad.getvalue())
    proc = run_here("train", "eval", sim / "run", "--data", ds)
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
    assert key in proc.stderr and "phones.npy holds ids outside -1..39" in proc.stderr
