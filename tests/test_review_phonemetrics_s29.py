"""Review of ``s2a-train eval`` by phone (train/lipsync.py): the open-vowel opening figure beside the
bilabial closure hit rate, so that a face that never moves cannot pass both, checked on a run's real
predictions (its own, with the lips shut throughout, with jawOpen raised on bilabials) and through the
command line."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import run_here
from test_phonemetrics_s29 import sim  # noqa: F401 - the module's fixture: simulated takes, a ridge run

from train.evaluate import RawSamples, manifest_phones
from train.lipsync import (
    BILABIAL,
    CLOSED,
    OPEN_VOWEL,
    OPENED,
    TOLERANCE,
    LipSyncTally,
    aperture_columns,
    lip_aperture,
    phone_classes,
)
from train.predict import animate, load_for_animation


def _real_predictions(run, ds, split="test"):
    """Each sample of ``ds``'s split with the run's prediction from the sample's audio (as ``s2a-train
    predict`` animates it), the run's channels: (phone ids, prediction, floor, recorded, mask)."""
    model, payload, ppg = load_for_animation(run, say=lambda _m: None)
    manifest = json.loads((ds / "manifest.json").read_text())
    channels = payload["dataset"]["channels"]
    assert channels == manifest["channels"]
    floor = np.array([manifest["stats"]["train"]["channels"][c]["mean"] for c in channels])
    out = []
    for item in RawSamples(ds, split, window=None, normalize=False, audio=True):
        true = item["anim"].numpy().astype(np.float64)
        pred = animate(model, payload, item["audio"], ppg, speaker=item["speaker"]).astype(np.float64)
        assert pred.shape == true.shape
        out.append((item["phones"], pred, np.broadcast_to(floor, true.shape), true, item["mask"].numpy()))
    return manifest, out


def _tally(manifest, utterances, change=lambda pred, ids: pred) -> LipSyncTally:
    tally = LipSyncTally(manifest["channels"], manifest_phones(manifest), manifest["fps"])
    for ids, pred, floor, true, mask in utterances:
        tally.add(ids, change(pred.copy(), ids), floor, true, mask)
    return tally


def test_opening_figure_tells_a_lip_sync_from_a_face_that_never_moves(sim):  # noqa: F811
    """A run's real predictions against the same with the lips shut on every frame (every closure kept:
    the closure rate alone called it perfect) and with jawOpen raised by 0.3 on its bilabials."""
    manifest, utterances = _real_predictions(sim / "run", sim / "ds")
    channels = manifest["channels"]
    columns = aperture_columns(channels)
    bilabial = phone_classes(manifest_phones(manifest)) == BILABIAL
    jaw = channels.index("jawOpen")

    def shut(pred, _ids):  # aperture 0 everywhere: jawOpen = mouthClose, the lips' raise and lower at 0
        pred[:, columns[0]] = 0.0
        pred[:, columns[1]] = 0.0
        return pred

    def open_on_bilabials(pred, ids):
        on = (ids >= 0) & bilabial[np.maximum(ids, 0)]
        pred[np.convolve(on.astype(float), np.ones(3), "same") > 0, jaw] += 0.3  # ± 1 frame at 60 fps
        return pred

    real, closed, opened = (
        _tally(manifest, utterances, c) for c in (lambda p, _i: p, shut, open_on_bilabials)
    )
    r_close, r_open = real.bilabial_closure(), real.open_vowel_opening()
    assert r_close["recorded_closures"] >= 5 and r_open["recorded_openings"] >= 10, (r_close, r_open)
    # the run closes on most recorded closures and opens on most recorded openings
    assert r_close["model"]["hit_rate"] >= 0.6 and r_open["model"]["hit_rate"] >= 0.5, (r_close, r_open)
    # the face that never opens: every closure "kept", no opening made
    assert closed.bilabial_closure()["model"]["hit_rate"] == 1.0
    assert closed.open_vowel_opening()["model"]["hits"] == 0
    # jaw open on bilabials: closures lost, no opening lost (a bilabial beside a vowel may add one)
    assert opened.bilabial_closure()["model"]["hit_rate"] <= 0.2
    assert opened.open_vowel_opening()["model"]["hits"] >= r_open["model"]["hits"]
    before, after = (t.per_phone_class()["classes"]["bilabial"]["rmse"] for t in (real, opened))
    assert after > 1.5 * before
    # the floor is one face too: it cannot pass both (a constant aperture <= CLOSED + TOLERANCE < OPENED)
    assert CLOSED + TOLERANCE < OPENED
    floor_rates = [f()["floor"]["hit_rate"] for f in (real.bilabial_closure, real.open_vowel_opening)]
    assert min(floor_rates) == 0.0, floor_rates
    for figure in (real.bilabial_closure(), closed.bilabial_closure()):
        assert figure["floor"] == r_close["floor"]


def test_opening_counts_follow_the_recorded_apertures(sim):  # noqa: F811
    """Segments and recorded openings counted from the recorded apertures of each open-vowel run, and the
    model's hits from the prediction's maximum, on the real predictions."""
    manifest, utterances = _real_predictions(sim / "run", sim / "ds")
    columns = aperture_columns(manifest["channels"])
    open_vowel = phone_classes(manifest_phones(manifest)) == OPEN_VOWEL
    tally = _tally(manifest, utterances)
    segments = recorded = hits = 0
    margin = tally.margin
    for ids, pred, _floor, true, mask in utterances:
        on = np.concatenate([[False], (ids >= 0) & open_vowel[np.maximum(ids, 0)], [False]])
        starts, ends = np.flatnonzero(~on[:-1] & on[1:]), np.flatnonzero(on[:-1] & ~on[1:])
        for start, end in zip(starts, ends):
            segments += 1
            frames = np.arange(max(start - margin, 0), min(end + margin, mask.size))
            frames = frames[mask[frames]]
            if frames.size and lip_aperture(true[frames], columns).max() >= OPENED:
                recorded += 1
                hits += lip_aperture(pred[frames], columns).max() >= OPENED
    figure = tally.open_vowel_opening()
    assert (figure["segments"], figure["recorded_openings"], figure["model"]["hits"]) == (
        segments, recorded, hits
    )  # fmt: skip
    assert segments > recorded > 0


def test_eval_prints_and_reports_the_opening_figure(sim):  # noqa: F811
    proc = run_here("train", "eval", sim / "run", "--data", sim / "ds", "--json")
    assert proc.returncode == 0, proc.stderr
    figure = json.loads(proc.stdout)["open_vowel_opening"]
    n = figure["recorded_openings"]
    assert n >= 5 and figure["opened_at_least"] == OPENED, figure
    proc = run_here("train", "eval", sim / "run", "--data", sim / "ds")
    assert proc.returncode == 0, proc.stderr
    assert f"open-vowel openings made: {figure['model']['hits']}/{n}" in proc.stdout
    plain = run_here("train", "eval", sim / "run", "--data", sim / "plain", "--json")
    r = json.loads(plain.stdout)
    assert r["open_vowel_opening"] is None and "no frame phones" in r["open_vowel_opening_note"]


def test_rig_without_jaw_channels_has_no_opening_figure():
    tally = LipSyncTally(["mouth_stretch_c", "jaw_open_x"], ["SIL", "AA", "M"], 30.0)
    ids = np.array([0, 1, 1, 2, 0])
    x = np.zeros((5, 2))
    tally.add(ids, x, x, x, np.ones(5, bool))
    assert tally.open_vowel_opening() is None and tally.bilabial_closure() is None
    assert tally.per_phone_class()["classes"]["open_vowel"]["frames"] == 2


@pytest.mark.parametrize("usable", [[True] * 7, [True, True, True, False, False, False, True]])
def test_opening_segment_edges(usable):
    """An open vowel at the start of an utterance, widened by one frame (60 fps), and one whose usable
    frames are all lost (unscored); a recorded opening the prediction reaches, one it does not."""
    channels = ["jawOpen", "mouthClose"]
    tally = LipSyncTally(channels, ["SIL", "AA", "M"], 60.0)
    ids = np.array([1, 1, 0, 0, 1, 0, 0])
    true = np.zeros((7, 2))
    true[[0, 4], 0] = 0.4  # the recorded take opens on both open vowels
    pred = np.zeros((7, 2))
    pred[2, 0] = OPENED  # inside the first vowel's widened segment only
    tally.add(ids, pred, np.zeros((7, 2)), true, np.array(usable))
    figure = tally.open_vowel_opening()
    lost = 0 if all(usable) else 1
    assert figure["segments"] == 2 and figure["unscored_segments"] == lost
    assert figure["recorded_openings"] == 2 - lost and figure["model"]["hits"] == 1
    assert figure["floor"]["hits"] == 0 and figure["margin_frames"] == 1
