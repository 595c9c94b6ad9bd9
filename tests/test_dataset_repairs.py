"""What ``s2a-dataset`` does with material the happy path does not show: recordings cut into segments
(one split per recording), split fractions a long recording would wreck, animation values no rig
produces, float audio past full scale, aligned takes off their frame grid, takes whose alignment align
flagged, manifests whose normalisation contradicts the data, and paths that are files."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from conftest import run_here
from dataset_helpers import make_aligned_take

import dataset.build
from capture import write_take
from dataset import ShardReader, assign_splits
from dataset.build import is_narrowband
from dataset.shards import decode_flac
from dataset.splits import SplitRule


def _one_line_error(proc, needle: str) -> None:
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr and needle in proc.stderr, proc.stderr


def _build(takes, out, *extra):
    proc = run_here("dataset", "build", takes, "-o", out, "--json", *extra)
    assert proc.returncode == 0, proc.stderr
    return json.loads((out / "manifest.json").read_text())


def _segment(take_id: str, parent: str, seed: int, **kw):
    take = make_aligned_take(take_id, 2.0, seed=seed, **kw)
    take.meta.extra["align"]["parent"] = {"id": parent, "source_kind": "livelinkface_csv"}
    return take


def test_segments_of_one_recording_share_a_split_and_pin_by_the_recording():
    takes = {f"r{r}.seg0{s}": ("spk", 10.0) for r in range(6) for s in (1, 2)}
    recordings = {t: t.split(".")[0] for t in takes}
    for seed in range(8):
        split_of = assign_splits(takes, SplitRule("take", 0.2, 0.2, seed=seed), recordings)
        for r in range(6):
            assert split_of[f"r{r}.seg01"] == split_of[f"r{r}.seg02"]
        assert {"train", "val", "test"} <= set(split_of.values())
    pinned = assign_splits(takes, SplitRule("take", 0.0, 0.0, test=("r3",)), recordings)
    assert [t for t, s in pinned.items() if s == "test"] == ["r3.seg01", "r3.seg02"]
    # without recordings each segment is a unit of its own, as before
    loose = assign_splits(takes, SplitRule("take", 0.2, 0.2, seed=1))
    assert any(loose[f"r{r}.seg01"] != loose[f"r{r}.seg02"] for r in range(6))


def test_one_long_recording_does_not_become_the_val_split():
    takes = {"long": ("a", 600.0), **{f"short{i}": ("a", 12.0) for i in range(4)}}
    for seed in range(6):
        split_of = assign_splits(takes, SplitRule("take", 0.1, 0.05, seed=seed))
        assert split_of["long"] == "train", (seed, split_of)
        assert "val" in split_of.values() and "test" in split_of.values()
    # every free unit far over the target: the shortest one, not the first in order
    big = {"a": ("s", 100.0), "b": ("s", 300.0), "c": ("s", 500.0)}
    for seed in range(6):
        split_of = assign_splits(big, SplitRule("take", 0.05, 0.0, seed=seed))
        assert split_of["a"] == "val" and split_of["b"] == split_of["c"] == "train"


def test_build_keeps_recordings_together_and_validate_finds_a_split_one(tmp_path):
    for r in range(4):
        for s in (1, 2):
            write_take(
                _segment(f"rec{r}.seg0{s}", f"rec{r}", seed=10 * r + s, subject="spk"), tmp_path / "takes"
            )
    m = _build(tmp_path / "takes", tmp_path / "ds", "--test", "rec2", "--val", "rec1.seg02")
    split = {src["take"]: src["split"] for src in m["sources"]}
    assert split["rec2.seg01"] == split["rec2.seg02"] == "test"
    assert split["rec1.seg01"] == split["rec1.seg02"] == "val"  # pinning one segment pins its recording
    assert {src["recording"] for src in m["sources"]} == {"rec0", "rec1", "rec2", "rec3"}
    assert run_here("dataset", "validate", tmp_path / "ds").returncode == 0

    # a dataset whose segments of one recording sit in two splits (built by a tool that split takes,
    # or before recordings were kept together): validate finds it from the manifest's recordings, and
    # from align's .segNN names when the manifest predates them
    for r in range(2):
        for s in (1, 2):
            write_take(
                _segment(f"x{r}.seg0{s}", f"x{r}-{s}", seed=50 + 10 * r + s, subject="spk"),
                tmp_path / "loose",
            )
    m = _build(tmp_path / "loose", tmp_path / "leaky", "--test", "x0-1", "--val", "x1-1")
    split = {src["take"]: src["split"] for src in m["sources"]}
    assert split["x0.seg01"] == "test" and split["x0.seg02"] != "test"
    for src in m["sources"]:
        src["recording"] = src["take"].split(".")[0]
    (tmp_path / "leaky" / "manifest.json").write_text(json.dumps(m))
    for old in (False, True):
        if old:
            for src in m["sources"]:
                del src["recording"]
            (tmp_path / "leaky" / "manifest.json").write_text(json.dumps(m))
        proc = run_here("dataset", "validate", tmp_path / "leaky", "--json")
        leaks = [p["location"] for p in json.loads(proc.stdout)["problems"] if p["code"] == "split_leakage"]
        assert "recording x0" in leaks and "recording x1" in leaks, (old, leaks)


def test_build_warns_when_a_split_takes_far_more_than_its_fraction(tmp_path):
    write_take(make_aligned_take("big", 6.0, subject="a", seed=1), tmp_path / "takes")
    write_take(make_aligned_take("small", 2.0, subject="a", seed=2), tmp_path / "takes")
    m = _build(tmp_path / "takes", tmp_path / "ds")
    shares = [w for w in m["warnings"] if "of the audio (asked" in w]
    assert len(shares) == 1 and shares[0].startswith("the test split holds 25% of the audio (asked 10%)")


def test_narrowband_speech_is_recognised(samples, monkeypatch):
    import scipy.signal
    import soundfile as sf

    for wav in sorted((samples / "speech").rglob("*.wav"))[:3]:
        x, rate = sf.read(wav, dtype="float32")
        wide = scipy.signal.resample_poly(x, 16000, rate) if rate != 16000 else x
        phone = scipy.signal.resample_poly(scipy.signal.resample_poly(x, 8000, rate), 2, 1)
        assert not is_narrowband(wide.astype(np.float32), 16000), wav
        assert is_narrowband(phone.astype(np.float32), 16000), wav
        # long audio is measured a block at a time (memory): blocks of 4096 samples judge alike
        monkeypatch.setattr(dataset.build, "NARROWBAND_BLOCK", 4096)
        assert not is_narrowband(wide.astype(np.float32), 16000), wav
        assert is_narrowband(phone.astype(np.float32), 16000), wav
        monkeypatch.undo()


def test_long_audio_is_pitch_tracked_in_pieces_that_agree_with_one_piece(monkeypatch):
    import dataset.pitch

    rate, hop = 16000, 0.02
    t = np.arange(24 * rate) / rate
    f0 = 120 + 40 * np.sin(2 * np.pi * 0.3 * t)  # a voice gliding 80..160 Hz ...
    voiced = (t % 3) < 2  # ... in 2 s phrases with 1 s pauses; the first ones under Praat's silence
    level = np.where(t < 8, 0.005, 0.3)  # threshold (3 % of the peak), which only the whole audio has
    x = (np.sin(2 * np.pi * np.cumsum(f0) / rate) * voiced * level).astype(np.float32)
    x += np.random.default_rng(0).normal(0, 1e-3, x.size).astype(np.float32)
    n = 1 + x.size // int(hop * rate)
    whole = dataset.pitch.track_pitch(x, rate, n, hop, dataset.pitch.PitchSettings())
    monkeypatch.setattr(dataset.pitch, "CHUNK_S", 5.0)
    monkeypatch.setattr(dataset.pitch, "MARGIN_S", 1.0)
    pieces = dataset.pitch.track_pitch(x, rate, n, hop, dataset.pitch.PitchSettings())
    # Praat judges silence against the sound's own peak: each piece is judged against the whole's
    assert np.array_equal(whole[:, 1], pieces[:, 1]) and 0.35 < whole[:, 1].mean() < 0.55
    assert np.abs(whole[:, 0] - pieces[:, 0]).max() < 0.01


def test_out_of_range_values_loud_float_audio_and_narrowband_audio(tmp_path):
    import scipy.signal

    wild = make_aligned_take("wild", 2.0, subject="a", seed=1)
    wild.values[30:40, wild.meta.channels.index("jawOpen")] = 1e30
    percent = make_aligned_take("percent", 2.0, subject="a", seed=5)
    percent.values *= 100.0  # weights on a 0-100 scale, as some tools export them
    loud = make_aligned_take("loud", 2.0, subject="a", seed=2)
    loud.audio.samples[:] *= 40.0  # float WAV peaking far past full scale
    hot = make_aligned_take("hot", 2.0, subject="a", seed=4)
    hot.audio.samples[:] *= 1.01 / np.abs(hot.audio.samples).max()  # full scale, lifted 0.09 dB by filtering
    calm = make_aligned_take("calm", 2.0, subject="a", seed=3)
    x = calm.audio.samples[:, 0]
    calm.audio.samples[:, 0] = scipy.signal.resample_poly(scipy.signal.resample_poly(x, 1, 2), 2, 1)[: x.size]
    for t in (wild, loud, calm, hot, percent):
        write_take(t, tmp_path / "takes")
    m = _build(tmp_path / "takes", tmp_path / "ds", "--test", "wild", "--val", "calm")
    warnings = " | ".join(m["warnings"])
    assert (
        "take wild: 10 frame(s) hold values beyond +-10" in warnings
        and "0-100" not in warnings.split("take wild")[1].split("|")[0]
    )
    assert "0-100 or 0-255 scale?" in next(w for w in m["warnings"] if w.startswith("take percent: "))
    assert "take loud: audio peaks at" in warnings and "audio_gain" in warnings
    assert "take hot:" not in warnings  # scaled back (audio_gain, below) without a word
    narrow = [w for w in m["warnings"] if "no energy above" in w]
    assert len(narrow) == 1 and narrow[0].startswith("take calm: its audio has no energy above 4.5 kHz")
    wild_entry = next(s for s in m["samples"] if s["take"] == "wild")
    assert wild_entry["usable_frames"] == wild_entry["frames"] - 10
    proc = run_here("dataset", "validate", tmp_path / "ds", "--deep")
    assert proc.returncode == 0, proc.stdout + proc.stderr  # no value_range problem: the frames are masked
    loud_shard = next(s["shard"] for s in m["samples"] if s["take"] == "loud")
    gains = {}
    for _key, members in ShardReader(tmp_path / "ds" / loud_shard):
        meta = json.loads(members["json"])
        gains[meta["take"]] = meta["audio_gain"]
        audio, _rate = decode_flac(members["flac"])
        assert np.abs(audio).max() <= 1.0 and np.mean(np.abs(audio) >= 0.999) < 1e-4  # scaled, not clipped
    assert 0 < gains["loud"] < 0.5 and 0.98 < gains["hot"] < 1.0


def test_aligned_take_off_its_frame_grid_is_refused(tmp_path):
    take = make_aligned_take("stretched", 2.0, subject="a", seed=1)
    take.time = take.time * 1.5
    write_take(take, tmp_path / "takes")
    _one_line_error(
        run_here("dataset", "build", tmp_path / "takes", "-o", tmp_path / "ds"), "not the uniform grid i/fps"
    )


def test_flagged_takes_are_warned_about_or_left_out(tmp_path):
    for i in range(3):
        take = make_aligned_take(f"t{i}", 2.0, subject="a", seed=i)
        take.meta.extra["align"]["flags"] = ["evidence_disagrees"] if i == 1 else ["duration_mismatch"]
        if i == 2:
            take.meta.extra["align"] |= {"flags": ["clipped_audio"], "clipped_audio": 0.0162}
        write_take(take, tmp_path / "takes")
    kept = _build(tmp_path / "takes", tmp_path / "kept")
    assert "take t2: align found 1.62% of its audio samples clipped at full scale" in "\n".join(
        kept["warnings"]
    )
    flagged = [w for w in kept["warnings"] if "align flagged" in w]
    assert flagged == [
        "take t1: align flagged its audio/face offset (evidence_disagrees): check it, or build with "
        "--skip-flagged"
    ]
    assert "t1" in {s["take"] for s in kept["samples"]}
    skipped = _build(tmp_path / "takes", tmp_path / "skipped", "--skip-flagged")
    assert {s["take"] for s in skipped["samples"]} == {"t0", "t2"}
    assert any("left out (--skip-flagged)" in w for w in skipped["warnings"])
    pinned = run_here(
        "dataset", "build", tmp_path / "takes", "-o", tmp_path / "p", "--skip-flagged", "--test", "t1"
    )
    _one_line_error(pinned, "'t1' was left out by --skip-flagged (align flagged evidence_disagrees)")


@pytest.fixture(scope="module")
def small_ds(tmp_path_factory):
    root = tmp_path_factory.mktemp("repairs")
    for i in range(4):
        write_take(make_aligned_take(f"t{i}", 2.0, subject=f"s{i % 2}", seed=i), root / "takes")
    _build(root / "takes", root / "ds", "--features", "pitch,energy,fbank", "--val", "t1", "--test", "t2")
    return root / "ds"


EDITS = [
    (
        "fbank mean cut short",
        lambda m: m["normalization"]["features"]["fbank"].update(mean=[0.0] * 5),
        "normalization.features.fbank",
    ),
    (
        "fbank std 0",
        lambda m: m["normalization"]["features"]["fbank"]["std"].__setitem__(0, 0.0),
        "normalization.features.fbank.std",
    ),
    (
        "no pitch speakers",
        lambda m: m["normalization"]["pitch"].update(speakers={}),
        "normalization.pitch.speakers",
    ),
    ("channel renamed", lambda m: m["channels"].__setitem__(0, "foo"), "normalization.animation.channels"),
    ("val stats removed", lambda m: m["stats"].pop("val"), "stats.val"),
]


@pytest.mark.parametrize(("name", "edit", "location"), EDITS, ids=[e[0] for e in EDITS])
def test_manifest_normalisation_that_contradicts_the_data_is_invalid(
    small_ds, tmp_path, name, edit, location
):
    ds = tmp_path / "ds"
    shutil.copytree(small_ds, ds)
    m = json.loads((ds / "manifest.json").read_text())
    edit(m)
    (ds / "manifest.json").write_text(json.dumps(m))
    proc = run_here("dataset", "validate", ds, "--json")
    assert proc.returncode == 1, proc.stdout
    found = [p["location"] for p in json.loads(proc.stdout)["problems"] if p["code"] == "manifest_schema"]
    assert found == [f"manifest.json:{location}"], found
    _one_line_error(run_here("dataset", "stats", ds), location)


def test_sample_metadata_that_is_a_list_and_paths_that_are_files(small_ds, tmp_path):
    ds = tmp_path / "ds"
    shutil.copytree(small_ds, ds)
    m = json.loads((ds / "manifest.json").read_text())
    shard = ds / m["shards"][0]["name"]
    import tarfile

    with tarfile.open(shard) as tar:
        members = [
            (info, tar.extractfile(info).read() if info.isfile() else None) for info in tar.getmembers()
        ]
    with tarfile.open(shard, "w", format=tarfile.PAX_FORMAT) as tar:
        for info, data in members:
            if info.name.endswith(".json"):
                data = b"[1, 2]"
                info.size = len(data)
            tar.addfile(info, __import__("io").BytesIO(data))
    proc = run_here("dataset", "validate", ds, "--json")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "sample_decode" in {p["code"] for p in json.loads(proc.stdout)["problems"]}

    blocker = tmp_path / "afile"
    blocker.write_text("")
    _one_line_error(run_here("dataset", "validate", blocker), "not a dataset")
    _one_line_error(run_here("dataset", "stats", blocker), "not a dataset")
    _one_line_error(run_here("dataset", "build", small_ds.parent / "takes", "-o", blocker / "sub"), "afile")


def test_a_damaged_float_sample_far_past_full_scale_is_refused(tmp_path):
    take = make_aligned_take("spike", 2.0, subject="a", seed=1)
    take.audio.samples[1000, 0] = 1e30  # one damaged sample: scaling would silence the take
    write_take(take, tmp_path / "takes")
    _one_line_error(
        run_here("dataset", "build", tmp_path / "takes", "-o", tmp_path / "ds"), "over 1000 times full scale"
    )


def test_spellings_of_one_speaker_clashing_keys_and_interpolated_takes(tmp_path):
    """Material from several phones and tools: a subject typed twice in another case, take ids that map
    to one sample key, and a take whose face was mostly interpolated over."""
    for take_id, subject, seed in (("take.1", "Team/Anna", 1), ("take_1", "team/anna ", 2), ("b1", "Bob", 3)):
        take = make_aligned_take(take_id, 2.0, subject=subject, seed=seed)
        if take_id == "b1":
            take.frame_status[:] = 4  # two frames in three interpolated
            take.frame_status[::3] = 0
        write_take(take, tmp_path / "takes")
    m = _build(
        tmp_path / "takes", tmp_path / "ds", "--split-by", "speaker", "--test", "Bob", "--val-fraction", "0"
    )
    warnings = "\n".join(m["warnings"])
    assert (
        "speakers 'Team/Anna', 'team/anna ' differ only in case or spacing: one speaker, 'Team/Anna'"
        in warnings
    )
    assert {s["take"]: s["speaker"] for s in m["samples"]} == {
        "take.1": "Team/Anna",
        "take_1": "Team/Anna",
        "b1": "Bob",
    }
    keys = {s["take"]: s["key"] for s in m["samples"]}
    assert keys["take.1"] != keys["take_1"] and all(
        keys[t].startswith("take_1-") for t in ("take.1", "take_1")
    )
    assert "take ids 'take.1', 'take_1' give one sample key" in warnings
    assert "take b1: 67% of its usable frames were interpolated" in warnings
    assert not any("take.1" in w and "interpolated" in w for w in m["warnings"])
    assert run_here("dataset", "validate", tmp_path / "ds").returncode == 0
