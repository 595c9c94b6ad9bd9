"""Datasets from the real samples: FACEGOOD's Mandarin speech with rig controls (30 fps, the rig's
own channel names, ``--channels varying``) and the NeuroSync ARKit take (60 fps, pronunciation32),
each aligned by the align stage first, as ``s2a-align`` would."""

from __future__ import annotations

import json

import numpy as np
from conftest import run_cli, run_here

from align import align_take, is_aligned
from capture import Take, read_csv_with_audio, read_paired, write_take
from dataset import read_manifest


def aligned(raw: Take) -> Take:
    """The one aligned take of a paired take (audio and face already on one clock)."""
    (take,) = align_take(raw)
    report = take.meta.extra["align"]
    assert is_aligned(take) and report["parent"]["id"] == raw.meta.id
    # paired data shares one clock: what align measures is a small correction (content evidence
    # lands within tens of ms), not a shift that would misplace speech against the face
    assert abs(report["offset_s"]) < 0.1
    return take


def test_facegood_dataset_builds_and_validates(samples, tmp_path):
    fg = samples / "paired" / "facegood-audio2face"
    takes = tmp_path / "takes"
    for name in ("1114_3_15", "1114_3_16", "1114_2_05", "1114_2_04"):
        raw = read_paired(
            fg / "wav" / f"{name}.wav",
            fg / "bs_value" / f"bs_value_{name}.npy",
            30.0,
            fg / "bs_names.txt",
            take_id=f"facegood_{name}",
        )
        raw.meta.subject = "shirley"
        write_take(aligned(raw), takes)
    ds = tmp_path / "ds"
    proc = run_cli(
        "dataset",
        "build",
        takes,
        "-o",
        ds,
        "--channels",
        "varying",
        "--test",
        "facegood_1114_3_16",
        "--val-fraction",
        "0",
        "--json",
    )
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["takes"] == 4 and summary["samples"] >= 11  # 30 s samples: 112.8 s → 4, 49 s → 2, ...
    m = read_manifest(ds)
    names = (fg / "bs_names.txt").read_text().split()
    assert 10 < len(m["channels"]) < 116 and set(m["channels"]) <= set(names)
    assert m["fps"] == 30.0 and m["splits"]["test"]["takes"] == ["facegood_1114_3_16"]
    assert any("mouthClose" in w for w in m["warnings"])  # a rig without ARKit's metric channels
    # the speech is voiced Mandarin: a plausible share of voiced frames and F0 range
    # stats and validate in this process: what they find is the subject here (the dataset stage's command
    # lines run as subprocesses in test_dataset_build.py and the build above)
    stats = json.loads(run_here("dataset", "stats", ds, "--json").stdout)
    assert stats["hours"] * 3600 > 200
    spk = m["normalization"]["pitch"]["speakers"]["shirley"]
    assert 100 < np.exp(spk["mean"]) < 400 and spk["voiced_frames"] > 1000
    proc = run_here("dataset", "validate", ds, "--deep", "--json")
    assert proc.returncode == 0, proc.stdout
    report = json.loads(proc.stdout)
    assert report["valid"]
    # 1114_2_04 barely uses mouth_oh_c (std 0.03), which the other takes animate (std 0.20-0.24)
    still = {p["location"]: p["message"] for p in report["problems"] if p["code"] == "still_channel"}
    assert "mouth_oh_c" in still["take facegood_1114_2_04"]
    assert [t for t, message in still.items() if "mouth_oh_c" in message] == ["take facegood_1114_2_04"]
    # and the other takes predict it worst (s2a-train agreement, leave one take out)
    proc = run_cli("train", "agreement", "--data", ds, "--splits", "train", "test", "--json")
    assert proc.returncode == 0, proc.stderr
    loo = json.loads(proc.stdout)["leave_one_out"]
    assert max(loo, key=lambda t: loo[t]["ratio"]) == "facegood_1114_2_04", loo


def test_neurosync_arkit_take_builds_and_validates(samples, tmp_path):
    folder = samples / "paired" / "neurosync-trainer-lite-testset"
    raw = read_csv_with_audio(folder / "testset.csv", folder / "audio.wav")
    take = aligned(raw)
    write_take(take, tmp_path / "takes")
    ds = tmp_path / "ds"
    proc = run_cli(
        "dataset", "build", tmp_path / "takes", "-o", ds, "--features", "pitch,energy,mfcc", "--json"
    )
    assert proc.returncode == 0, proc.stderr
    m = read_manifest(ds)
    assert len(m["channels"]) == 32 and m["fps"] == 60.0 and m["warnings"]  # no speaker named: said so
    assert m["speakers_assumed"] == [take.meta.id]
    assert m["splits"]["train"]["takes"] == [take.meta.id]  # one take: train keeps it
    assert run_cli("dataset", "validate", ds, "--deep").returncode == 0
