"""Align on inputs a probe found mishandled: a speech burst taken for a clap, a half-lost face passed as
usable, a one-frame take's error, and clipped recordings nobody reported. Real files, real command lines."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from conftest import run_here

from align.clipping import clipped_share
from align.resample import to_16k_mono
from align.transient import audio_claps
from capture import Audio, read_audio

NEUROSYNC = "paired/neurosync-trainer-lite-testset"


def _speech(samples: Path) -> tuple[np.ndarray, int]:
    """The NeuroSync take's speech as float64 samples and its rate (44.1 kHz)."""
    x, rate = sf.read(samples / NEUROSYNC / "audio.wav", dtype="float64")
    return x, rate


def _import(tmp_path: Path, csv: Path, wav: Path, take_id: str) -> Path:
    run_here("capture", "import", csv, "--audio", wav, "-o", tmp_path / "takes", "--id", take_id, check=True)
    return tmp_path / "takes" / take_id


def _align(take: Path, out: Path, *options: str) -> dict:
    proc = run_here("align", take, "-o", out, "--json", *options)
    return json.loads(proc.stdout.splitlines()[-1])


def _csv_rows(samples: Path) -> tuple[str, list[str]]:
    header, *rows = (samples / NEUROSYNC / "testset.csv").read_text().splitlines()
    return header, [r for r in rows if r]


def test_a_speech_burst_is_not_a_clap(samples):
    x, rate = _speech(samples)
    # The plosive burst at 13.51 s jumps 37 dB in 2 ms and dies within 50 ms, but the speech around it is
    # only 12 dB quieter: no clap. A real clap in the pause before the speech still is one.
    assert audio_claps(to_16k_mono(read_audio(samples / NEUROSYNC / "audio.wav")), 0.0) == []
    clapped = x.copy()
    k = int(0.4 * rate)
    clapped[k : k + 200] += np.random.default_rng(0).normal(0, 0.5, 200) * np.exp(-np.arange(200) / 40.0)
    claps = audio_claps(to_16k_mono(Audio(clapped.astype(np.float32), rate, "FLOAT")), 0.0)
    assert len(claps) == 1 and claps[0].time_s == pytest.approx(0.4, abs=0.002)


def test_speech_after_a_quiet_lead_in_is_not_placed_by_a_clap(samples, tmp_path):
    x, rate = _speech(samples)
    lead = 0.003 * np.random.default_rng(5).standard_normal(5 * rate)  # 5 s of faint room noise
    wav = tmp_path / "lead5s.wav"
    sf.write(wav, np.concatenate([lead, x]), rate, subtype="PCM_16")
    take = _import(tmp_path, samples / NEUROSYNC / "testset.csv", wav, "lead5")
    rep = _align(take, tmp_path / "aligned", "--max-offset-ms", "6000")
    evidence = [rep["chosen"], *rep["alternatives"]]
    assert not any(e and e["source"] == "clap" for e in evidence)
    # Placed by what the speech says (about -5 s), or kept and flagged, never moved 0.94 s by a "clap".
    placed = rep["offset_source"] == "content" and rep["offset_s"] == pytest.approx(-5.0, abs=0.05)
    assert placed or {"low_confidence", "evidence_disagrees"} & set(rep["flags"]), rep


def test_a_half_lost_face_is_flagged_mostly_interpolated(samples, tmp_path):
    header, rows = _csv_rows(samples)
    lost = np.random.default_rng(1).random(len(rows)) < 0.5
    csv = tmp_path / "lost50.csv"
    csv.write_text(
        "\n".join([header] + [r.split(",")[0] + ",0" if o else r for r, o in zip(rows, lost)]) + "\n"
    )
    take = _import(tmp_path, csv, samples / NEUROSYNC / "audio.wav", "lost50")
    rep = _align(take, tmp_path / "aligned")
    assert "mostly_interpolated" in rep["flags"]
    assert rep["interpolated_share"] == pytest.approx(rep["gaps_interpolated"] / rep["frames"], abs=1e-4)
    assert rep["interpolated_share"] > 0.7
    assert all(s["interpolated_share"] > 0.5 for s in rep["segment_list"])
    # The share stays in the aligned take and in the report of a later run that skips the take.
    again = _align(take, tmp_path / "aligned")
    assert again["skipped"] and again["interpolated_share"] == rep["interpolated_share"]
    assert "mostly_interpolated" in again["flags"]

    whole = _import(tmp_path, samples / NEUROSYNC / "testset.csv", samples / NEUROSYNC / "audio.wav", "whole")
    rep = _align(whole, tmp_path / "aligned")
    assert "mostly_interpolated" not in rep["flags"] and rep["interpolated_share"] < 0.05


def test_a_one_frame_take_is_too_short_not_untracked(samples, tmp_path):
    header, rows = _csv_rows(samples)
    x, rate = _speech(samples)
    wav = tmp_path / "three_s.wav"
    sf.write(wav, x[: 3 * rate], rate, subtype="PCM_16")
    for n in (1, 2):
        csv = tmp_path / f"frames{n}.csv"
        csv.write_text("\n".join([header, *rows[300 : 300 + n]]) + "\n")
        take = _import(tmp_path, csv, wav, f"frames{n}")
        rep = _align(take, tmp_path / "aligned", "--vad", "none")
        assert f"the face is tracked for {n / 60:.3f} s, shorter than 1 s" in rep["error"], rep


@pytest.mark.parametrize(
    "subtype, scale, flagged",
    [
        ("PCM_16", 1.0, True),  # clipped by the converter: flat at int16 full scale
        ("FLOAT", 0.7, True),  # clipped, then turned down: flat at 0.7
        ("FLOAT", None, False),  # 3x in float, past full scale but nothing lost (not clipped)
    ],
)
def test_clipped_audio_is_flagged(samples, tmp_path, subtype, scale, flagged):
    x, rate = _speech(samples)
    loud = 3.0 * x if scale is None else np.clip(3.0 * x, -1.0, 1.0) * scale
    wav = tmp_path / "loud.wav"
    sf.write(wav, loud, rate, subtype=subtype)
    take = _import(tmp_path, samples / NEUROSYNC / "testset.csv", wav, "loud")
    rep = _align(take, tmp_path / "aligned", "--vad", "webrtc")
    assert ("clipped_audio" in rep["flags"]) == flagged
    if flagged:
        assert 0.01 < rep["clipped_audio"] < 0.03
        assert any("clipped" in w for w in rep["warnings"])
    else:
        assert rep["clipped_audio"] == 0.0 and "warnings" not in rep


def test_real_recordings_are_not_clipped(samples, tmp_path):
    take = _import(tmp_path, samples / NEUROSYNC / "testset.csv", samples / NEUROSYNC / "audio.wav", "ns")
    rep = _align(take, tmp_path / "aligned")
    assert rep["clipped_audio"] == 0.0 and "clipped_audio" not in rep["flags"]
    wavs = sorted((samples / "paired/facegood-audio2face/wav").glob("*.wav"))
    wavs += sorted((samples / "speech").rglob("*.wav"))
    assert len(wavs) >= 10
    for wav in wavs:
        assert clipped_share(read_audio(wav)) == 0.0, wav
