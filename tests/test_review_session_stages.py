"""A hostile review of the session's changes to align, dataset, train and paired import, on inputs their
authors did not try: a build's errors about a raw take it aligned name the user's folder, not the copy
under ``DS/.work/aligned/``; align's search past --max-offset-ms follows a long rising flank at the cost
of one search, not one per 0.25 s. Real files: 10 s of the NeuroSync take's speech and weights under a rig's
channel names (a raw take align aligns), real command lines run in this process."""

from __future__ import annotations

import csv
import shutil
import time

import numpy as np
import pytest
import soundfile as sf
from conftest import run_here

from align import content as ct
from align.aligner import BEYOND_RANGE_S

SECONDS = 10  # of real speech: align finds its content evidence in it


@pytest.fixture(scope="module")
def raw_rig_take(samples, tmp_path_factory):
    """A raw paired take ``talk`` (the NeuroSync weights under the rig names ``ctrl00``..``ctrl51``, its
    speech), and the failed build of it with ``--channels jawOpen`` (which aligned it into DS/.work):
    (the take's folder, the dataset folder, the build's result)."""
    folder = samples / "paired" / "neurosync-trainer-lite-testset"
    root = tmp_path_factory.mktemp("rig")
    with open(folder / "testset.csv", newline="") as f:
        rows = list(csv.reader(f))
    np.save(root / "w.npy", np.array([[float(x) for x in r[2:54]] for r in rows[1 : SECONDS * 60 + 1]], "f4"))
    (root / "names.txt").write_text("".join(f"ctrl{i:02d}\n" for i in range(52)))
    audio, rate = sf.read(folder / "audio.wav", frames=SECONDS * sf.info(folder / "audio.wav").samplerate)
    sf.write(root / "talk.wav", audio, rate)
    run_here(
        "capture", "import", "--matrix", root / "w.npy", "--audio", root / "talk.wav", "--names",
        root / "names.txt", "--fps", 60, "--id", "talk", "-o", root / "raw", check=True,
    )  # fmt: skip
    built = run_here("dataset", "build", root / "raw", "-o", root / "ds", "--channels", "jawOpen")
    return root / "raw" / "talk", root / "ds", built


def test_a_raw_take_lacking_a_selected_channel_is_named_as_given(raw_rig_take):
    raw, ds, built = raw_rig_take
    assert built.returncode == 1, built.stderr
    (error,) = [line for line in built.stderr.splitlines() if "error:" in line]
    assert "lacks 1 selected channel(s) (jawOpen)" in error
    assert f"error: {raw.resolve()}: take talk" in error and ".work" not in error


def test_two_takes_sharing_an_id_name_the_raw_take_as_given(raw_rig_take, tmp_path):
    raw, ds, _ = raw_rig_take
    # the user's own aligned take "talk": the build's aligned copy of the raw one, its speech quieter
    (copy,) = (ds / ".work" / "aligned").glob("*/talk")
    mine = tmp_path / "mine" / "talk"
    shutil.copytree(copy, mine)
    audio, rate = sf.read(mine / "audio.wav", dtype="int16")
    sf.write(mine / "audio.wav", audio // 2, rate, subtype="PCM_16")
    built = run_here("dataset", "build", raw, mine, "-o", ds, "--channels", "varying")
    assert built.returncode == 1, built.stderr
    (error,) = [line for line in built.stderr.splitlines() if "error:" in line]
    assert "two different takes share the id 'talk'" in error
    assert ".work" not in error and str(raw.resolve()) in error and str(mine) in error


def rising_flank(seconds: float) -> ct.CrossCorrelation:
    """The correlation of a click in the middle of the audio with a face whose movement (crests every
    0.25 s) grows towards its start: it rises towards ever larger lags, the top at half the take's length,
    so that align's search beyond --max-offset-ms widens range after range up to it."""
    n = int(seconds * ct.ANALYSIS_RATE)
    lag = np.arange(n) - n // 2
    audio = (lag == 0).astype(np.float64)
    face = np.where(lag < 0, np.abs(lag) + 1.0, 0.0) * np.cos(2 * np.pi * lag / 25)
    return ct.CrossCorrelation(audio, face, np.ones(n))


def test_the_search_past_the_range_follows_a_long_flank_at_the_cost_of_one_search():
    # the same range and peak as searching each range 0.25 s wider than the last, on a short take
    short = rising_flank(60.0)
    reach = 0.75
    wide = short.peak(reach)
    while wide.at_edge and reach < short.n / ct.ANALYSIS_RATE:
        reach += BEYOND_RANGE_S
        wide = short.peak(reach)
    assert reach > 29 and short.widened(0.75, BEYOND_RANGE_S) == (reach, wide)
    # forty minutes of it: 4,800 ranges searched one by one took 5 s of CPU
    long = rising_flank(2400.0)
    started = time.process_time()
    reach, top = long.widened(0.75, BEYOND_RANGE_S)
    assert time.process_time() - started < 1.5
    assert abs(top.lag_s + 1200) < 0.02 and not top.at_edge
