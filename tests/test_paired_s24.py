"""Paired data from generators the toolkit had not seen, through import, align and dataset build: an
ARKit layout with a misnamed channel (``jawOpen_L``), frames of NaN and infinities, weights on a 0..100
scale, a level in dB beside the weights, viseme curves. Inputs are made from the real NeuroSync pair (its
face curves in other generators' layouts)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
from conftest import run_cli
from dataset_helpers import make_aligned_take

from capture import write_take
from dataset.manifest import read_manifest

NEUROSYNC = Path("paired") / "neurosync-trainer-lite-testset"


def _arkit_csv(samples: Path, path: Path, rename: dict[str, str] | None = None, bad_rows=()) -> Path:
    """The NeuroSync take's 52 ARKit curves as a generator's CSV: a `time` column in seconds at 60 fps,
    the names in ARKit's camelCase (some renamed), the rows ``bad_rows`` NaN and one of them infinite."""
    with open(samples / NEUROSYNC / "testset.csv", newline="") as f:
        rows = list(csv.reader(f))
    names = [n[0].lower() + n[1:] for n in rows[0][2:54]]
    names = [(rename or {}).get(n, n) for n in names]
    values = np.array([[float(x) for x in r[2:54]] for r in rows[1:]])
    for i, row in enumerate(bad_rows):
        values[row] = np.inf if i == 0 else np.nan
    with open(path, "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(["time", *names])
        out.writerows([f"{i / 60:.6f}", *(f"{v:.6f}" for v in r)] for i, r in enumerate(values))
    return path


def test_arkit_layout_with_a_side_suffixed_jaw_open_warns_at_import(samples, tmp_path):
    """`jawOpen_L` for `jawOpen` (jawOpen has no sides): before, kept as a column of its own name without a
    word, the take had no jawOpen, and the dataset build failed later ("lacks 1 selected channel(s)
    (jawOpen)"). Now import warns, as it does for the app's CSV."""
    matrix = _arkit_csv(samples, tmp_path / "gen.csv", {"jawOpen": "jawOpen_L"})
    audio = samples / NEUROSYNC / "audio.wav"
    proc = run_cli("capture", "import", "--matrix", matrix, "--audio", audio, "-o", tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    assert "no JawOpen column; jawOpen_L is not a channel: did you mean JawOpen?" in proc.stderr
    meta = json.loads((tmp_path / "out" / "gen" / "meta.json").read_text())
    assert "jawOpen_L" in meta["channels"]  # never renamed silently
    assert "channel_typo" in [r["kind"] for r in meta["repairs"]]


def test_a_rigs_own_controls_are_not_taken_for_misspelt_channels(samples, tmp_path):
    """FACEGOOD's 116 controls (`mouth_press_l`, `tongue_u`, ...) are a rig's names: no channel_typo
    (50 such notes if they were looked at like an ARKit header)."""
    facegood = samples / "paired" / "facegood-audio2face"
    proc = run_cli(
        "capture", "import", "--matrix", facegood / "bs_value" / "bs_value_1114_3_16.npy",
        "--names", facegood / "bs_names.txt", "--audio", facegood / "wav" / "1114_3_16.wav",
        "--fps", "30", "-o", tmp_path / "out", "--json",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    meta = json.loads((tmp_path / "out" / "bs_value_1114_3_16" / "meta.json").read_text())
    assert "channel_typo" not in [r["kind"] for r in meta["repairs"]]
    assert "did you mean" not in proc.stderr


def test_align_of_frames_with_nan_and_infinite_values_prints_no_numpy_warning(samples, tmp_path):
    """A generator's CSV with NaN rows and a row of infinities (BAD_VALUE frames): before, the mouth
    opening summed +inf and -inf over that row and numpy printed `RuntimeWarning: invalid value
    encountered in add` with a line of align's source on stderr. The frames are left out of the
    content evidence either way."""
    matrix = _arkit_csv(samples, tmp_path / "gen.csv", bad_rows=(500, *range(100, 110)))
    audio = samples / NEUROSYNC / "audio.wav"
    run_cli("capture", "import", "--matrix", matrix, "--audio", audio, "-o", tmp_path / "raw", check=True)
    proc = run_cli("align", tmp_path / "raw", "-o", tmp_path / "aligned", "--json")
    assert proc.returncode == 0, proc.stderr
    assert "Warning" not in proc.stderr, proc.stderr
    (report,) = [json.loads(line) for line in proc.stdout.splitlines()]
    assert report["offset_source"] == "content" and report["gaps_interpolated"] > 0


def test_a_take_on_a_percent_scale_gives_the_dataset_none_of_its_frames(tmp_path):
    """A take whose weights are on 0..100 (imported without --value-scale 0.01): its loud frames pass
    ±10 and were masked, but its quiet frames stayed usable, 100 times too large, in the training
    targets and the normalisation (the build warned, and used them: 125 of 1136 frames of a NeuroSync
    pair at 30 fps). Now none of its frames is usable, and the warning says so."""
    takes = tmp_path / "takes"
    for i in range(3):
        write_take(make_aligned_take(f"take{i}", seconds=3.0, seed=i), takes)
    percent = make_aligned_take("percent", seconds=3.0, seed=7)
    percent.values = percent.values * 100
    within = np.all(np.abs(percent.values) <= 10, axis=1)
    assert 0 < within.sum() < 0.9 * within.size  # quiet frames within reach, the others beyond it
    write_take(percent, takes)
    ds = tmp_path / "ds"
    proc = run_cli("dataset", "build", takes, "-o", ds, "--val", "take1", "--test", "take2", "--json")
    assert proc.returncode == 0, proc.stderr
    usable = {s["take"]: s["usable_frames"] for s in read_manifest(ds)["samples"]}
    assert usable["take0"] > 0 and usable["percent"] == 0
    (warning,) = [w for w in json.loads(proc.stdout)["warnings"] if "beyond +-10" in w]
    assert "and so are its other frames" in warning and "--value-scale 0.01" in warning


def test_a_few_stray_values_mask_only_their_frames(tmp_path):
    """Below the share that says the scale is wrong, only the frames beyond reach are masked."""
    takes = tmp_path / "takes"
    for i in range(3):
        write_take(make_aligned_take(f"take{i}", seconds=3.0, seed=i), takes)
    glitch = make_aligned_take("glitch", seconds=3.0, seed=7)
    glitch.values[10:12] = 50.0  # two frames of a damaged value
    write_take(glitch, takes)
    ds = tmp_path / "ds"
    proc = run_cli("dataset", "build", takes, "-o", ds, "--val", "take1", "--test", "take2", "--json")
    assert proc.returncode == 0, proc.stderr
    (sample,) = [s for s in read_manifest(ds)["samples"] if s["take"] == "glitch"]
    assert sample["usable_frames"] == sample["frames"] - 2


def test_a_level_in_db_beyond_reach_is_not_taken_for_a_percent_scale(tmp_path):
    """CRI LipSync's viseme curves carry the audio level in dB (`Vol`, -96 in silence) beside the weights
    (game.criware.jp/manual/cri_lipsync_alive_for_tools/latest/en/CriLipsMake2/output_mpeg4csv). Built
    with that column, the warning advised `--value-scale 0.01`, which would shrink the visemes' weights a
    hundredfold and leave `Vol` as wrong; now it names the column and says to leave it out."""
    takes = tmp_path / "takes"
    channels = ("jawOpen", "mouthClose", "Vol")
    for i, level in enumerate((0.0, 0.0, -96.0)):
        take = make_aligned_take(f"take{i}", seconds=3.0, seed=i, channels=channels)
        take.values[:, 2] = level
        write_take(take, takes)
    ds = tmp_path / "ds"
    proc = run_cli(
        "dataset", "build", takes, "-o", ds, "--channels", ",".join(channels), "--val", "take1",
        "--test", "take2", "--json",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    (warning,) = [w for w in json.loads(proc.stdout)["warnings"] if "beyond +-10" in w]
    assert warning.startswith("take take2: 180 frame(s) hold values beyond +-10 in Vol ")
    assert "leave those channels out of --channels" in warning and "--value-scale" not in warning


def test_viseme_curves_give_content_evidence(samples, tmp_path):
    """CRI LipSync's MPEG-4 viseme curves (`time,PP,FF,...,aa,...,ou,Vol,tongue_up` at 100 Hz; the
    manual cited above) with their audio, here NeuroSync's jawOpen as `aa` and mouthClose as `PP`: before,
    align found "no moving mouth-opening channel" and kept the pairing's placement unmeasured (content
    evidence is what catches audio not cut to its frames); now `aa` and `PP` are the mouth opening."""
    with open(samples / NEUROSYNC / "testset.csv", newline="") as f:
        rows = list(csv.reader(f))
    names, values = rows[0][2:], np.array([[float(x) for x in r[2:]] for r in rows[1:]])
    t = np.arange(int(values.shape[0] / 60 * 100)) / 100
    visemes = ["PP", "FF", "TH", "DD", "kk", "CH", "SS", "nn", "RR", "aa", "E", "ih", "oh", "ou"]
    curves = np.zeros((t.size, len(visemes)))
    for viseme, channel in (("aa", "JawOpen"), ("PP", "MouthClose")):
        curves[:, visemes.index(viseme)] = np.interp(
            t, np.arange(values.shape[0]) / 60, values[:, names.index(channel)]
        )
    level = np.where(curves[:, visemes.index("aa")] > 0.05, -25.0, -96.0)
    with open(tmp_path / "cri.csv", "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(["time", *visemes, "Vol", "tongue_up"])
        out.writerows(
            [f"{s:.4f}", *(f"{v:.4f}" for v in r), f"{db:.4f}", "0.0000"]
            for s, r, db in zip(t, curves, level)
        )
    audio = samples / NEUROSYNC / "audio.wav"
    run_cli(
        "capture",
        "import",
        "--matrix",
        tmp_path / "cri.csv",
        "--audio",
        audio,
        "-o",
        tmp_path / "raw",
        check=True,
    )
    proc = run_cli("align", tmp_path / "raw", "-o", tmp_path / "aligned", "--json")
    assert proc.returncode == 0, proc.stderr
    (report,) = [json.loads(line) for line in proc.stdout.splitlines()]
    assert report["offset_source"] == "content" and report["offset_confidence"] >= 0.5, report
    assert abs(report["offset_s"]) < 0.02 and report["chosen"]["detail"]["channels"] == ["aa", "PP"]
