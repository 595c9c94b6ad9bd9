"""Bad input to s2a-dataset and s2a-view: one-line errors (exit 1) or warnings, never a traceback nor a
silently wrong result. Malformed manifest fields, non-finite build options, takes without a frame rate
or with truncated audio, datasets without a content feature, shards of another build, manifest sample
entries that contradict the shards, plot ranges and output folders."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import soundfile as sf
from conftest import run_here
from dataset_helpers import make_aligned_take, write_aligned_set

from capture import write_take
from capture.errors import InputError


def _one_line_error(proc, needle: str) -> None:
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr and needle in proc.stderr, proc.stderr
    lines = proc.stderr.strip().splitlines()  # progress lines may come first
    assert ": error: " in lines[-1] and sum(": error: " in line for line in lines) == 1, proc.stderr


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> dict[str, Path]:
    """Two datasets of different takes (``ds``, ``other``) and the takes of the first."""
    root = tmp_path_factory.mktemp("robust")
    takes = write_aligned_set(root / "takes", count=5, speakers=2, seconds=2.0)
    write_take(make_aligned_take("take05", 3.0, subject="spk1", seed=9, gap=(10, 170)), takes)
    proc = run_here("dataset", "build", takes, "-o", root / "ds", "--json")
    assert proc.returncode == 0, proc.stderr
    others = write_aligned_set(root / "others", count=4, speakers=2, seconds=1.0)
    proc = run_here("dataset", "build", others, "-o", root / "other", "--json")
    assert proc.returncode == 0, proc.stderr
    return {"takes": takes, "ds": root / "ds", "other": root / "other"}


def _copy(ds: Path, to: Path) -> Path:
    shutil.copytree(ds, to)
    return to


def _edit_manifest(ds: Path, edit) -> None:
    path = ds / "manifest.json"
    m = json.loads(path.read_text())
    edit(m)
    path.write_text(json.dumps(m))


def _set(path: str, value):
    """An edit that sets ``m[a][b]...`` for the dotted ``path`` (digits index lists)."""

    def edit(m):
        *parents, last = [int(p) if p.isdigit() else p for p in path.split(".")]
        for p in parents:
            m = m[p]
        m[last] = value

    return edit


# ------------------------------------------------------------------------------------------ bug 1

MALFORMED = [
    ("stats", None),
    ("stats.train", "x"),
    ("stats.train.hours", "x"),
    ("samples.0.frames", "x"),
    ("samples.0.duration_s", None),
    ("fps", "sixty"),
    ("fps", 0),
    ("shards.0.duration_s", "long"),
]


@pytest.mark.parametrize(("field", "value"), MALFORMED, ids=[f"{f}={v!r}" for f, v in MALFORMED])
def test_malformed_manifest_field_is_invalid_and_refused_by_every_reader(built, tmp_path, field, value):
    ds = _copy(built["ds"], tmp_path / "ds")
    _edit_manifest(ds, _set(field, value))
    where = field.replace(".0.", "[0].")
    proc = run_here("dataset", "validate", ds, "--json")
    assert proc.returncode == 1, proc.stdout + proc.stderr
    problems = json.loads(proc.stdout)["problems"]
    assert [p["location"] for p in problems if p["code"] == "manifest_schema"] == [f"manifest.json:{where}"]
    _one_line_error(run_here("dataset", "stats", ds), f"manifest field {where} ")
    _one_line_error(run_here("dataset", "stats", ds / "manifest.json"), f"manifest field {where} ")
    _one_line_error(run_here("viewer", "report", ds, "-o", tmp_path / "r.html"), f"manifest field {where} ")


# ------------------------------------------------------------------------------------------ bugs 2, 3, 6


def test_build_refuses_bad_options_and_takes_with_one_line(built, tmp_path):
    takes = built["takes"]
    _one_line_error(
        run_here("dataset", "build", takes, "-o", tmp_path / "a", "--max-sample-s", "nan"), "--max-sample-s"
    )
    _one_line_error(
        run_here("dataset", "build", takes, "-o", tmp_path / "b", "--shard-mb", "inf"), "--shard-mb"
    )
    for features in ("", "pitch,energy"):
        proc = run_here("dataset", "build", takes, "-o", tmp_path / "c", "--features", features)
        _one_line_error(proc, "no content feature")
    # a take whose meta.json says 0 fps, and one whose audio was cut short: named, one line
    bad = tmp_path / "bad"
    shutil.copytree(takes, bad)
    meta = json.loads((bad / "take01" / "meta.json").read_text())
    (bad / "take01" / "meta.json").write_text(json.dumps(meta | {"fps": 0}))
    _one_line_error(run_here("dataset", "build", bad / "take01", "-o", tmp_path / "d"), "take01")
    _one_line_error(run_here("dataset", "build", bad, "-o", tmp_path / "e"), "fps must be a frame rate")
    cut = tmp_path / "cut"
    shutil.copytree(takes, cut)
    x, rate = sf.read(cut / "take02" / "audio.wav", dtype="float32")
    sf.write(cut / "take02" / "audio.wav", x[:730], rate, subtype="FLOAT")
    _one_line_error(run_here("dataset", "build", cut, "-o", tmp_path / "f"), "take02")


def test_build_warns_about_a_take_with_few_usable_frames(built):
    m = json.loads((built["ds"] / "manifest.json").read_text())
    low = [w for w in m["warnings"] if "usable" in w]
    assert len(low) == 1 and low[0].startswith("take take05: only 20 of 180 frames are usable"), m["warnings"]


# ------------------------------------------------------------------------------------------ bugs 4, 8


def test_shard_dataset_refuses_shards_that_differ_from_the_manifest(built, tmp_path):
    pytest.importorskip("torch")
    from dataset.torch_dataset import ShardDataset

    ds = _copy(built["ds"], tmp_path / "ds")
    keys = sorted(item["key"] for item in ShardDataset(ds / "manifest.json", "train", features=[]))
    m = json.loads((ds / "manifest.json").read_text())
    assert keys == sorted(s["key"] for s in m["samples"] if s["split"] == "train")
    # another build's train shard, of another size, in place of ours
    shutil.copy(built["other"] / "train-000000.tar", ds / "train-000000.tar")
    with pytest.raises(InputError, match="shard size differs from the manifest: s2a-dataset validate"):
        ShardDataset(ds, "train")
    # the same with the manifest's size made to match: its samples are not the ones listed
    size = (ds / "train-000000.tar").stat().st_size
    _edit_manifest(ds, _set("shards.0.bytes", size))
    data = ShardDataset(ds, "train", features=[])
    # refused by the sample count, or earlier, by the first sample's shape against the manifest
    with pytest.raises(
        InputError, match=r"shard lacks 2 sample\(s\) the manifest lists|sample \w+: .*s2a-dataset validate"
    ):
        list(data)
    (ds / "train-000000.tar").unlink()
    with pytest.raises(InputError, match="missing"):
        ShardDataset(ds, "train")
    # a sample the manifest does not list for its shard
    ds = _copy(built["ds"], tmp_path / "ds2")
    _edit_manifest(ds, _set("samples.0.key", "renamed"))
    with pytest.raises(InputError, match=r"sample \w+ is not listed in the manifest for this shard"):
        list(ShardDataset(ds, "train", features=[]))


# ------------------------------------------------------------------------------------------ bug 5

ENTRIES = [("frames", 5), ("duration_s", 99), ("split", "test"), ("take", "someother"), ("usable_frames", 1)]


@pytest.mark.parametrize(("field", "value"), ENTRIES, ids=[e[0] for e in ENTRIES])
def test_validate_compares_manifest_sample_entries_with_the_shards(built, tmp_path, field, value):
    ds = _copy(built["ds"], tmp_path / "ds")
    _edit_manifest(ds, _set(f"samples.0.{field}", value))
    proc = run_here("dataset", "validate", ds, "--json")
    assert proc.returncode == 1, proc.stdout
    found = [p for p in json.loads(proc.stdout)["problems"] if p["code"] == "manifest_mismatch"]
    assert len(found) == 1 and found[0]["location"].endswith(f".{field}"), found


# ------------------------------------------------------------------------------------------ bug 7


def test_view_outputs_in_new_folders_and_plot_ranges(built, tmp_path):
    take = built["takes"] / "take00"
    out = tmp_path / "no" / "such" / "p.png"
    proc = run_here("viewer", "plot", take, "-o", out, "--vad", "energy")
    assert proc.returncode == 0, proc.stderr
    assert out.stat().st_size > 0
    report = tmp_path / "no" / "other" / "r.html"
    assert run_here("viewer", "report", built["ds"], "-o", report).returncode == 0 and report.is_file()
    bad = tmp_path / "q.png"
    for args in (["--start", "5", "--end", "1"], ["--start", "nan"]):  # usage errors (exit 2)
        proc = run_here("viewer", "plot", take, "-o", bad, *args)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
        assert "argument --start" in proc.stderr.strip().splitlines()[-1], proc.stderr
    _one_line_error(run_here("viewer", "plot", take, "-o", bad, "--start", "50", "--end", "60"), "no frame")
    assert not bad.exists()
    blocked = tmp_path / "file"
    blocked.write_text("")
    _one_line_error(run_here("viewer", "plot", take, "-o", blocked / "p.png"), "cannot create")
