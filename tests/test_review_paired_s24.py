"""Second review of paired data from other generators: a tracker's glitch over more than a tenth of a take
is no scale (the take's other frames stay usable), and viseme curves are content evidence only for a take
with no other mouth-opening channel."""

from __future__ import annotations

import csv
import json

import numpy as np
from conftest import run_cli
from dataset_helpers import make_aligned_take
from test_paired_s24 import NEUROSYNC, _arkit_csv

from capture import ARKIT61, write_take
from dataset.manifest import read_manifest


def _build_with(take, tmp_path, channels: str = "arkit52") -> tuple[dict, list[str]]:
    """``take`` built beside three plain ones with ``--channels channels``: its manifest sample and the
    build's warnings about values beyond reach."""
    takes = tmp_path / "takes"
    for i in range(3):
        write_take(make_aligned_take(f"take{i}", seconds=3.0, seed=i, channels=ARKIT61), takes)
    write_take(take, takes)
    ds = tmp_path / "ds"
    proc = run_cli(
        "dataset", "build", takes, "-o", ds, "--channels", channels, "--val", "take1", "--test", "take2",
        "--json",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    (sample,) = [s for s in read_manifest(ds)["samples"] if s["take"] == take.meta.id]
    return sample, [w for w in json.loads(proc.stdout)["warnings"] if "beyond +-10" in w]


def test_a_long_glitch_in_one_channel_masks_only_its_frames(tmp_path):
    """A tracker's blow-up over 15 % of a 10 s take (jawOpen at 1000 for 1.5 s), its other frames weights
    on 0..1: before this review the whole take was masked (none of its 510 good frames usable) and the
    warning advised --value-scale 0.01, which would shrink every good weight a hundredfold."""
    take = make_aligned_take("glitch", seconds=10.0, seed=7, channels=ARKIT61)
    take.values[100:190, ARKIT61.index("jawOpen")] = 1e3
    sample, (warning,) = _build_with(take, tmp_path)
    assert sample["usable_frames"] == sample["frames"] - 90
    assert "--value-scale" not in warning and "other frames" not in warning


def test_head_rotation_in_degrees_gives_none_of_its_frames_when_selected_only(tmp_path):
    """headPitch in degrees (15..25, head bowed; another generator's unit, the app writes radians):
    selected (arkit61), its values within ±10 are as wrong, so no frame is usable, and the warning names
    degrees (before this review it advised --value-scale 0.01, which would shrink every weight too); not
    selected (arkit52), the take is whole."""
    take = make_aligned_take("degrees", seconds=10.0, seed=7, channels=ARKIT61)
    take.values[:, ARKIT61.index("headPitch")] = 20 + 5 * np.sin(np.arange(take.values.shape[0]) / 60)
    sample, (warning,) = _build_with(take, tmp_path / "selected", "arkit61")
    assert sample["usable_frames"] == 0
    assert "headPitch in degrees?" in warning and "--value-scale" not in warning
    sample, warnings = _build_with(take, tmp_path / "not_selected", "arkit52")
    assert sample["usable_frames"] == sample["frames"] and not warnings


def test_viseme_curves_beside_arkit_channels_leave_the_jaw_evidence_as_it_was(samples, tmp_path):
    """An avatar's take holding ARKit's channels and a viseme curve (Ready Player Me's viseme_aa beside
    jawOpen; here jawOpen 0.1 s late as viseme_aa): the mouth opening stays the ARKit channels', as
    before visemes counted; with the viseme added in, align measured another placement from another
    signal."""
    matrix = _arkit_csv(samples, tmp_path / "avatar.csv")
    with open(matrix, newline="") as f:
        rows = list(csv.reader(f))
    jaw = [r[rows[0].index("jawOpen")] for r in rows[1:]]
    rows[0].append("viseme_aa")
    for i, row in enumerate(rows[1:]):
        row.append(jaw[max(i - 6, 0)])
    with open(matrix, "w", newline="") as f:
        csv.writer(f).writerows(rows)
    audio = samples / NEUROSYNC / "audio.wav"
    run_cli("capture", "import", "--matrix", matrix, "--audio", audio, "-o", tmp_path / "raw", check=True)
    proc = run_cli("align", tmp_path / "raw", "-o", tmp_path / "aligned", "--json")
    assert proc.returncode == 0, proc.stderr
    (report,) = [json.loads(line) for line in proc.stdout.splitlines()]
    assert "viseme_aa" not in report["chosen"]["detail"]["channels"], report["chosen"]
