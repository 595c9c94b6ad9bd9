"""Align on paired data whose face lags the speech by a known amount just past the search range, from an
end-to-end review: the NeuroSync take's weights (60 fps) resampled to 25 fps and delayed by 0.8 s
against its own speech. The content correlation was looked at 0.25 s past ``--max-offset-ms`` only; its
highest value there sat at that search's edge (0.75 s), which gives no confidence, so the take kept the
pairing's offset 0 with no flag and no warning: a face 0.8 s late passed as aligned."""

from __future__ import annotations

import csv
import json

import numpy as np
import soundfile as sf
from conftest import run_here

LAG_S = 0.8
FPS = 25
SECONDS = 20.0  # the whole take: content evidence needs its length (a 12 s cut peaks inside the range)


def test_a_face_late_by_just_more_than_the_search_range_is_flagged_and_found(tmp_path, samples):
    folder = samples / "paired" / "neurosync-trainer-lite-testset"
    with open(folder / "testset.csv", newline="") as f:
        rows = list(csv.reader(f))
    names = rows[0][2:54]
    weights = np.array([[float(x) for x in r[2:54]] for r in rows[1:]], np.float32)
    # frame i at i / 25 s shows what the 60 fps take showed LAG_S earlier: the face lags the speech
    t = np.arange(int(SECONDS * FPS)) / FPS - LAG_S
    late = np.stack([np.interp(t, np.arange(len(weights)) / 60, w) for w in weights.T], axis=1)
    np.save(tmp_path / "late.npy", late.astype(np.float32))
    (tmp_path / "names.txt").write_text("\n".join(names) + "\n")
    audio, rate = sf.read(folder / "audio.wav", frames=int(SECONDS * 44100))
    sf.write(tmp_path / "late.wav", audio, rate)
    run_here(
        "capture", "import", "--matrix", tmp_path / "late.npy", "--audio", tmp_path / "late.wav",
        "--names", tmp_path / "names.txt", "--fps", FPS, "-o", tmp_path / "takes", check=True,
    )  # fmt: skip
    # --vad none: the take is speech from end to end, and the test need not load the VAD
    args = ["-o", tmp_path / "aligned", "--json", "--vad", "none"]
    proc = run_here("align", tmp_path / "takes" / "late", *args, check=True)
    report = json.loads(proc.stdout.splitlines()[-1])
    (content,) = [e for e in report["alternatives"] if e["source"] == "content"]
    # followed to its top past the 0.75 s searched before (the sample's own lag is +6 ms)
    assert abs(content["detail"]["best_lag_outside_range_s"] - LAG_S) < 0.03, content["detail"]
    assert content["detail"]["outside_confidence"] >= 0.3
    assert report["offset_s"] == 0 and "evidence_disagrees" in report["flags"]
    (warning,) = [w for w in report["warnings"] if "outside the" in w]
    assert "at an offset of +0.80" in warning and "--max-offset-ms 1100" in warning
