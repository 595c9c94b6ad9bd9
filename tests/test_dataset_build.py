"""s2a-dataset build / validate / stats on aligned takes: the command line, the manifest, the shard
layout (tarfile and webdataset), the PyTorch reader, resumability and byte-for-byte determinism."""

from __future__ import annotations

import filecmp
import io
import json
import random
import shutil
import signal
import subprocess
import sys
import tarfile
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT, run_cli, run_here
from dataset_helpers import make_aligned_take, write_aligned_set

from capture import PRONUNCIATION32, read_meta, write_take
from capture.atomic import write_json_atomic
from capture.take import sha256_file
from dataset import Normalizer, ShardReader, read_manifest
from dataset.build import take_sha256


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("ds")
    takes = write_aligned_set(root / "takes", count=6, speakers=2, neutral=False, gap=(20, 30))
    # in this process: build's command line runs as a subprocess in the tests below
    proc = run_here("dataset", "build", takes, "-o", root / "ds", "--shard-mb", "0.3", "--json")
    assert proc.returncode == 0, proc.stderr
    return takes, root / "ds"


def test_build_writes_manifest_shards_and_validates(built):
    takes, ds = built
    m = read_manifest(ds)
    assert m["channels"] == list(PRONUNCIATION32)
    assert m["fps"] == 60.0 and m["sample_rate"] == 16000
    assert m["features"]["names"] == ["pitch", "energy", "fbank"]
    assert m["features"]["dims"] == {"pitch": 2, "energy": 1, "fbank": 40}
    assert m["features"]["settings"]["window_s"] == 0.04 and m["features"]["settings"]["hop_s"] == 0.02
    # every shard's checksum, size and sample count match the file
    for s in m["shards"]:
        path = ds / s["name"]
        assert sha256_file(path) == s["sha256"] and path.stat().st_size == s["bytes"]
        assert sum(1 for _ in ShardReader(path)) == s["samples"]
    # every source take with its sha256; no take in two splits
    assert sorted(src["sha256"] for src in m["sources"]) == sorted(
        take_sha256(p) for p in sorted(takes.iterdir())
    )
    split_sets = [set(m["splits"][s]["takes"]) for s in ("train", "val", "test")]
    assert sum(len(s) for s in split_sets) == 6 and len(set().union(*split_sets)) == 6
    assert len(m["shards"]) > 3  # the 0.3 MB cap split train into several shards
    assert {p.name for p in (ds / ".work").iterdir()} == {"takes"}  # the take records only
    proc = run_cli("dataset", "validate", ds, "--deep", "--json")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    report = json.loads(proc.stdout)
    assert report["valid"] and report["samples"] == len(m["samples"]) and report["problems"] == []


def test_masks_follow_frame_status(built):
    _, ds = built
    m = read_manifest(ds)
    shard = next(s["name"] for s in m["shards"] if s["split"] == "train")
    for _key, members in ShardReader(ds / shard):
        mask = np.load(io.BytesIO(members["mask.npy"]))
        anim = np.load(io.BytesIO(members["anim.npy"]))
        assert mask.dtype == bool and not mask[20:30].any() and mask[:20].all()
        assert mask[60:63].all()  # INTERPOLATED (4) frames are usable
        assert np.all(anim[20:30] == 0) and np.isfinite(anim).all()
        break


def test_shards_read_with_tarfile_and_webdataset(built):
    wds = pytest.importorskip("webdataset")
    _, ds = built
    m = read_manifest(ds)
    shard = ds / m["shards"][0]["name"]
    with tarfile.open(shard) as tar:
        names = tar.getnames()
        infos = tar.getmembers()
    assert all(i.mtime == 0 and i.uid == 0 and i.uname == "" for i in infos)
    keys = [n.split(".", 1)[0] for n in names]
    assert keys == sorted(keys)
    ours = {k: v for k, v in ShardReader(shard)}
    theirs = list(wds.WebDataset(str(shard), shardshuffle=False).decode())
    assert [s["__key__"] for s in theirs] == list(ours)
    for s in theirs:
        np.testing.assert_array_equal(s["anim.npy"], np.load(io.BytesIO(ours[s["__key__"]]["anim.npy"])))
        assert s["json"]["take"] in {e["take"] for e in m["samples"]}
        assert set(s) >= {"flac", "anim.npy", "mask.npy", "pitch.npy", "energy.npy", "fbank.npy", "json"}


def test_stats_reports_hours_per_speaker_and_channels(built):
    _, ds = built
    proc = run_cli("dataset", "stats", ds, "--json")
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout)
    assert set(s["hours_per_speaker"]) == {"spk0", "spk1"}
    total = sum(h for per in s["hours_per_speaker"].values() for h in per.values())
    assert total == pytest.approx(6 * 3.0 / 3600, rel=1e-6)
    jaw = s["channel_distributions"]["train"]["jawOpen"]
    cheek = s["channel_distributions"]["train"]["mouthPucker"]
    assert jaw["std"] > 5 * cheek["std"]  # the simulated jaw moves with the speech, the pucker does not
    human = run_here("dataset", "stats", ds)
    assert human.returncode == 0 and "spk0" in human.stdout


def test_torch_dataset_windows_workers_and_normalization(built):
    torch = pytest.importorskip("torch")
    from dataset.torch_dataset import ShardDataset

    _, ds = built
    m = read_manifest(ds)
    raw = ShardDataset(ds, "train", window=None, normalize=False)
    base = {item["key"]: item for item in raw}
    assert len(base) == len(raw)
    norm = Normalizer.from_json(m["normalization"]["animation"])
    data = ShardDataset(ds, "train", window=64, shuffle_buffer=4, seed=1)
    loader = torch.utils.data.DataLoader(data, batch_size=2, num_workers=2)
    seen = []
    for batch in loader:
        assert batch["anim"].shape[1:] == (64, 32) and batch["mask"].shape[1:] == (64,)
        assert batch["fbank"].shape[1:] == (64, 40) and batch["pitch"].shape[1:] == (64, 2)
        seen += batch["key"]
    assert sorted(seen) == sorted(base)  # each sample exactly once across the two workers
    # windows longer than a sample are padded with masked frames; normalised values invert exactly
    long = ShardDataset(ds, "train", window=400, random_crop=False)
    item = next(iter(long))
    src = base[item["key"]]
    n = src["anim"].shape[0]
    assert not item["mask"][n:].any() and item["mask"][:n].equal(src["mask"])
    back = norm.inverse(item["anim"][:n].numpy().astype(np.float64))
    ok = src["mask"].numpy()
    np.testing.assert_allclose(back[ok], src["anim"].numpy()[ok], atol=1e-6)
    assert abs(float(item["anim"][:n][src["mask"]].mean())) < 1.0


def _build_cmd(takes: Path, out: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "dataset", "build", str(takes), "-o", str(out), "--shard-mb", "0.5", *extra]


def _dataset_files(ds: Path) -> list[str]:
    return sorted(p.name for p in ds.iterdir() if not p.name.startswith("."))


def test_killed_build_resumes_to_identical_bytes(tmp_path):
    takes = write_aligned_set(tmp_path / "takes", count=10, speakers=3, seconds=4.0)
    ref = tmp_path / "ref"
    # the builds that are not killed run in this process, but for the one with --jobs 2 (its workers)
    assert run_here(*_build_cmd(takes, ref)[2:]).returncode == 0
    rng = random.Random()
    out = tmp_path / "resumed"
    for attempt in range(10):
        shutil.rmtree(out, ignore_errors=True)  # a build that finished before the kill: start over
        # a random point: after 1..9 of the 10 takes are finished, or once the first shard is written
        stop_after = rng.choice([*range(1, 10), "shard"])
        proc = subprocess.Popen(
            _build_cmd(takes, out, "--features", "pitch,energy,fbank,mfcc"),
            cwd=ROOT,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        deadline = time.monotonic() + 120
        while proc.poll() is None and time.monotonic() < deadline:
            if stop_after == "shard":
                reached = any((out / ".work" / "shards").glob("*.json"))
            else:
                reached = len(list((out / ".work" / "takes").glob("*.json"))) >= stop_after
            if reached:
                proc.send_signal(signal.SIGKILL)
                break
            time.sleep(0.002)
        proc.wait()
        if proc.returncode == -signal.SIGKILL:
            break
        assert attempt < 9, "the build never ran long enough to be killed"
    assert not (out / "manifest.json").exists()
    # the rerun (with more features than the reference) is a different dataset; build the same one
    resumed = run_here(*_build_cmd(takes, out, "--features", "pitch,energy,fbank,mfcc")[2:])
    assert resumed.returncode == 0, resumed.stderr
    full = tmp_path / "full"
    subprocess.run(
        _build_cmd(takes, full, "--features", "pitch,energy,fbank,mfcc", "--jobs", "2"),
        check=True,
        capture_output=True,
        cwd=ROOT,
        timeout=300,
    )
    assert _dataset_files(out) == _dataset_files(full)
    match, mismatch, errors = filecmp.cmpfiles(out, full, _dataset_files(out), shallow=False)
    assert mismatch == [] and errors == []
    assert len(match) == len(_dataset_files(full)) >= 4
    # a finished build rerun is a no-op; the reference (fewer features) differs
    proc = run_here(
        "dataset",
        "build",
        takes,
        "-o",
        full,
        "--shard-mb",
        "0.5",
        "--features",
        "pitch,energy,fbank,mfcc",
        "--json",
    )
    assert proc.returncode == 0 and json.loads(proc.stdout)["up_to_date"] is True
    assert (ref / "manifest.json").read_bytes() != (full / "manifest.json").read_bytes()


def test_split_by_speaker_holds_out_speakers(tmp_path):
    takes = write_aligned_set(tmp_path / "takes", count=8, speakers=4, seconds=2.0)
    ds = tmp_path / "ds"
    proc = run_here(
        "dataset",
        "build",
        takes,
        "-o",
        ds,
        "--split-by",
        "speaker",
        "--test",
        "spk3",
        "--val-fraction",
        "0.25",
        "--json",
    )
    assert proc.returncode == 0, proc.stderr
    m = read_manifest(ds)
    assert m["splits"]["test"]["speakers"] == ["spk3"]
    speakers = [set(m["splits"][s]["speakers"]) for s in ("train", "val", "test")]
    assert all(speakers) and not (speakers[0] & speakers[1]) and not (speakers[0] & speakers[2])
    # pitch is normalised per speaker; the held-out speaker's statistics come from its own takes
    assert m["normalization"]["pitch"]["speakers"]["spk3"]["from"].startswith("all")
    assert run_here("dataset", "validate", ds).returncode == 0


def test_neutral_normalization_uses_calibrated_neutral(tmp_path):
    takes = tmp_path / "takes"
    for i in range(4):
        write_take(make_aligned_take(f"n{i}", 2.0, seed=i, neutral=(i % 2 == 0)), takes)
    ds = tmp_path / "ds"
    proc = run_here(
        "dataset",
        "build",
        takes,
        "-o",
        ds,
        "--normalization",
        "neutral",
        "--val-fraction",
        "0",
        "--test-fraction",
        "0",
    )
    assert proc.returncode == 0, proc.stderr
    m = read_manifest(ds)
    norm = m["normalization"]["animation"]
    assert norm["kind"] == "neutral" and len(norm["offset"]) == 32 and min(norm["scale"]) > 0
    metas = [json.loads(mem["json"]) for s in m["shards"] for _, mem in ShardReader(ds / s["name"])]
    assert sorted(meta["neutral"] is not None for meta in metas) == [False, False, True, True]


def test_channel_selection_and_metric_warning(tmp_path):
    rig = ("JawOpen_ctl", "LipPress_ctl", "Unused_ctl")
    takes = tmp_path / "takes"
    for i in range(3):
        take = make_aligned_take(f"r{i}", 2.0, seed=i, channels=rig)
        take.values[:, 2] = 0.0  # never moves
        write_take(take, takes)
    ds = tmp_path / "ds"
    proc = run_here("dataset", "build", takes, "-o", ds, "--channels", "varying", "--json")
    assert proc.returncode == 0, proc.stderr
    m = read_manifest(ds)
    assert m["channels"] == ["JawOpen_ctl", "LipPress_ctl"]
    assert any("mouthClose" in w for w in m["warnings"])
    # ARKit selection on a rig without those channels: one clear line, exit 1
    bad = run_here("dataset", "build", takes, "-o", tmp_path / "ds2")
    assert bad.returncode == 1 and "lacks 32 selected channel(s)" in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1 and "Traceback" not in bad.stderr


def test_rig_takes_with_their_channels_in_another_order_build_by_name(tmp_path):
    """Two writers of the same rig order its controls differently: --channels all/varying used to refuse
    them; a typo in a list of rig names used to blame the first, valid, name."""
    rig = ("JawOpen_ctl", "LipPress_ctl", "Unused_ctl")
    takes = tmp_path / "takes"
    for i in range(3):
        take = make_aligned_take(f"r{i}", 2.0, seed=i, channels=rig)
        take.values[:, 1] = 0.25  # LipPress_ctl: a constant that tells the columns apart
        take.values[:, 2] = 0.0
        if i == 2:  # the same controls, written in reverse order
            take.meta.channels = list(reversed(rig))
            take.values = take.values[:, ::-1].copy()
        write_take(take, takes)
    for spec in ("all", "varying"):
        ds = tmp_path / f"ds-{spec}"
        proc = run_here("dataset", "build", takes, "-o", ds, "--channels", spec, "--json")
        assert proc.returncode == 0, proc.stderr
        m = read_manifest(ds)
        want = list(rig) if spec == "all" else ["JawOpen_ctl"]  # LipPress_ctl is constant too
        assert m["channels"] == want
        lip = m["channels"].index("LipPress_ctl") if spec == "all" else None
        for shard in m["shards"]:
            for _key, members in ShardReader(ds / shard["name"]):
                anim = np.load(io.BytesIO(members["anim.npy"]))
                if lip is not None:
                    assert np.allclose(anim[:, lip], 0.25)  # every take's own column, by name
    typo = run_here(
        "dataset", "build", takes, "-o", tmp_path / "ds3", "--channels", "JawOpen_ctl,LipPres_ctl,jawOpen"
    )
    assert typo.returncode == 1 and "unknown channel 'LipPres_ctl'" in typo.stderr, typo.stderr


def test_bad_input_and_usage_errors(tmp_path):
    """The first as a user runs it (a subprocess), the others in this process (the commands run as
    subprocesses elsewhere in this file)."""
    missing = run_cli("dataset", "build", tmp_path / "nope", "-o", tmp_path / "ds")
    assert missing.returncode == 1 and "no such take folder" in missing.stderr
    assert len(missing.stderr.strip().splitlines()) == 1
    usage = run_here("dataset", "build", tmp_path, "-o", tmp_path / "ds", "--split-by", "window")
    assert usage.returncode == 2
    not_ds = run_here("dataset", "validate", tmp_path)
    assert not_ds.returncode == 1 and "no manifest.json" in not_ds.stderr
    takes = write_aligned_set(tmp_path / "takes", count=2, seconds=1.0)
    wrong = run_here("dataset", "build", takes, "-o", tmp_path / "ds", "--channels", "jawOpen,noSuchChannel")
    assert wrong.returncode == 1 and "noSuchChannel" in wrong.stderr
    ppg = run_here("dataset", "build", takes, "-o", tmp_path / "ds", "--ppg", "bottleneck")
    assert ppg.returncode == 1 and "--ppg-model" in ppg.stderr


def test_build_aligns_raw_simulated_takes(tmp_path):
    pytest.importorskip("align")
    raw = tmp_path / "raw"
    sim = run_cli("capture", "simulate", "-o", raw, "--takes", "2", "--speakers", "2", "--seconds", "6")
    if sim.returncode != 0:
        pytest.skip(f"simulator unavailable: {sim.stderr.strip()[-200:]}")
    assert run_cli("capture", "import", raw, "-o", tmp_path / "takes").returncode == 0
    ds = tmp_path / "ds"
    proc = run_cli("dataset", "build", tmp_path / "takes", "-o", ds, "--json")
    assert proc.returncode == 0, proc.stderr
    m = read_manifest(ds)
    assert m["sources"] and all(
        s["source_kind"] != "aligned" and s["aligned_from_sha256"] for s in m["sources"]
    )
    assert run_here("dataset", "validate", ds, "--deep").returncode == 0
    again = run_cli("dataset", "build", tmp_path / "takes", "-o", ds, "--json")
    assert again.returncode == 0 and json.loads(again.stdout)["up_to_date"] is True


DDP_READER = """
import json, sys
import torch.distributed as dist
from dataset.torch_dataset import ShardDataset
rank = int(sys.argv[1])
dist.init_process_group("gloo", init_method="file://" + sys.argv[2], rank=rank, world_size=2)
print(json.dumps([item["key"] for item in ShardDataset(sys.argv[3], "train", window=32)]))
dist.destroy_process_group()
"""


def test_ddp_ranks_read_disjoint_shards(built, tmp_path):
    pytest.importorskip("torch")
    _, ds = built
    rendezvous = tmp_path / "rendezvous"
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", DDP_READER, str(rank), str(rendezvous), str(ds)],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for rank in (0, 1)
    ]
    outs = [p.communicate(timeout=120) for p in procs]
    assert all(p.returncode == 0 for p in procs), [o[1][-500:] for o in outs]
    keys = [json.loads(o[0]) for o in outs]
    everything = [e["key"] for e in read_manifest(ds)["samples"] if e["split"] == "train"]
    assert keys[0] and keys[1] and not set(keys[0]) & set(keys[1])
    assert sorted(keys[0] + keys[1]) == sorted(everything)


def test_duplicate_take_under_another_id_is_kept_once(tmp_path):
    takes = write_aligned_set(tmp_path / "takes", count=3, seconds=1.5)
    # The folder copied and renamed in its metadata. (Not the take written a second time: libsndfile
    # stamps float WAV files with the current second in their PEAK chunk, so those bytes may differ.)
    copy = tmp_path / "more" / "take00_copy"
    shutil.copytree(takes / "take00", copy)
    meta = read_meta(copy)
    meta.id = "take00_copy"
    write_json_atomic(copy / "meta.json", meta.to_json())
    ds = tmp_path / "ds"
    proc = run_here("dataset", "build", takes, tmp_path / "more", "-o", ds, "--json")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["takes"] == 3 and any("take00_copy" in w and "duplicate" in w for w in summary["warnings"])
    assert run_here("dataset", "validate", ds).returncode == 0
    pinned = run_here(
        "dataset", "build", takes, tmp_path / "more", "-o", tmp_path / "p", "--test", "take00_copy"
    )
    assert pinned.returncode == 1 and "Traceback" not in pinned.stderr
    assert "'take00_copy' was skipped as a duplicate of take take00" in pinned.stderr
