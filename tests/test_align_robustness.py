"""The align stage against damaged take folders and hostile audio: one-line errors for malformed
metadata, a batch that goes on past a bad take, weak evidence that never moves the face, stereo whose
channels cancel, and outputs named by the take id."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import run_cli, run_here

import align.batch
from align import AlignOptions, align_takes
from align.evidence import Evidence, combine
from align.resample import mono_mix, remove_rumble, to_16k_mono
from capture import Audio, InputError, read_take, write_take

FAST = ("--vad", "none", "--no-video")  # no speech model to load: the tests stay fast


@pytest.fixture(scope="module")
def raw_takes(tmp_path_factory) -> Path:
    """Four imported simulated take folders (two speakers, 5 s each)."""
    root = tmp_path_factory.mktemp("raw")
    sim = root / "sim"
    run_here(
        "capture",
        "simulate",
        "-o",
        sim,
        "--speakers",
        2,
        "--takes",
        4,
        "--seconds",
        5,
        "--seed",
        1,
        check=True,
    )
    run_here("capture", "import", sim, "-o", root / "takes", check=True)
    folders = sorted(p for p in (root / "takes").iterdir() if p.is_dir())
    assert len(folders) == 4
    return root / "takes"


def _first(raw_takes: Path) -> Path:
    return sorted(p for p in raw_takes.iterdir() if p.is_dir())[0]


def _copy(raw_takes: Path, dest: Path, new_id: str | None = None) -> Path:
    """A copy of the first take folder at ``dest``, with its meta id set to ``new_id`` (default: the
    copy's folder name, so that it does not clash with the original)."""
    shutil.copytree(_first(raw_takes), dest)
    _edit_meta(dest, lambda m: m.__setitem__("id", new_id or dest.name))
    return dest


def _edit_meta(folder: Path, change) -> None:
    path = folder / "meta.json"
    meta = json.loads(path.read_text())
    change(meta)
    path.write_text(json.dumps(meta))  # NaN is written as NaN, which Python's json reads back


def _set(path: str, value):
    """A meta.json edit: ``path`` is ``field`` or ``audio.field``."""

    def change(meta):
        target = meta
        *parents, last = path.split(".")
        for p in parents:
            target = target[p]
        target[last] = value

    return change


def _reports(proc) -> dict[str, dict]:
    return {r["id"]: r for r in map(json.loads, proc.stdout.splitlines())}


# 1. Malformed meta.json fields are one-line errors naming the field.


@pytest.mark.parametrize(
    "field, value",
    [
        ("channels", "numbers"),
        ("channels", "twice"),
        ("channels", "empty name"),
        ("channels", "not a list"),
        ("extra", []),
        ("id", 7),
        ("id", " "),
        ("subject", 42),
        ("subject", {}),
        ("take_number", "3"),
        ("slate", 5),
        ("timecode_rate", -60),
        ("csv", []),
        ("repairs", ["bad"]),
        ("sources", [1]),
        ("audio", "audio.wav"),
        ("audio.sample_rate", "16000"),
        ("audio.sample_rate", 16000.5),
        ("audio.start_s", float("nan")),
        ("audio.start_s", "0"),
        ("audio.start_s", 10**400),
        ("audio.samples", "198191"),
        ("audio.samples", True),
        ("audio.channels", 0),
        ("audio.file", "../other/audio.wav"),
    ],
)
def test_malformed_meta_fields_are_one_line_errors(raw_takes, tmp_path, field, value):
    folder = _copy(raw_takes, tmp_path / "bad")
    if field == "channels":
        n = len(json.loads((folder / "meta.json").read_text())["channels"])
        value = {
            "numbers": list(range(n)),
            "twice": ["jawOpen", "JAWOPEN"] + [f"c{i}" for i in range(n - 2)],
            "empty name": [""] + [f"c{i}" for i in range(n - 1)],
            "not a list": "jawOpen",
        }[value]
    _edit_meta(folder, _set(field, value))
    with pytest.raises(InputError, match=r"malformed metadata: .*" + field.split(".")[-1]) as info:
        read_take(folder)
    assert "\n" not in str(info.value) and str(folder / "meta.json") in str(info.value)


def test_audio_that_disagrees_with_meta_is_refused(raw_takes, tmp_path):
    """The samples count, the channel count and the rate of audio.wav must be what meta.json says."""
    for field, real in (("channels", 1), ("sample_rate", 16000)):
        folder = _copy(raw_takes, tmp_path / field)
        meta = json.loads((folder / "meta.json").read_text())
        assert meta["audio"][field] == real
        _edit_meta(folder, _set(f"audio.{field}", real + 1))
        with pytest.raises(InputError, match="meta.json says"):
            read_take(folder)


def test_frames_with_text_or_infinite_times_are_refused(raw_takes, tmp_path):
    for damage in ("text values", "infinite time"):
        folder = _copy(raw_takes, tmp_path / damage.replace(" ", "_"))
        with np.load(folder / "frames.npz") as z:
            arrays = dict(z)
        if damage == "text values":
            arrays["values"] = arrays["values"].astype(str)
        else:
            arrays["time"][-1] = np.inf  # still "increasing"
        np.savez(folder / "frames.npz", **arrays)
        with pytest.raises(InputError, match="not numbers|infinite"):
            read_take(folder)


# 2. One bad take never ends the batch.


def _mixed_folder(raw_takes: Path, root: Path) -> tuple[Path, dict[str, str]]:
    """The four good takes plus bad ones that sort before them; returns the folder and, per bad take,
    a word its error must hold."""
    mixed = root / "mixed"
    shutil.copytree(raw_takes, mixed)
    bad = {}
    folder = _copy(raw_takes, mixed / "0_channels")
    _edit_meta(folder, lambda m: m.__setitem__("channels", list(range(len(m["channels"])))))
    bad[folder.name] = "channels"
    folder = _copy(raw_takes, mixed / "0_extra")
    _edit_meta(folder, _set("extra", []))
    bad[folder.name] = "extra"
    folder = _copy(raw_takes, mixed / "0_id")
    _edit_meta(folder, _set("id", 7))
    bad[folder.name] = "id"
    folder = _copy(raw_takes, mixed / "0_truncated")
    data = (folder / "frames.npz").read_bytes()
    (folder / "frames.npz").write_bytes(data[: len(data) // 2])
    bad[folder.name] = "unreadable"
    folder = _copy(raw_takes, mixed / "0_silent")
    take = read_take(folder)
    take.audio = Audio(np.zeros_like(take.audio.samples), take.audio.sample_rate, take.audio.subtype)
    write_take(take, mixed)
    bad[folder.name] = "silent"
    return mixed, bad


@pytest.mark.parametrize("jobs", [1, 2])
def test_one_bad_take_does_not_stop_the_batch(raw_takes, tmp_path, jobs):
    mixed, bad = _mixed_folder(raw_takes, tmp_path)
    out = tmp_path / "al"
    run = run_here if jobs == 1 else run_cli  # worker processes of a real command line, not of pytest's
    proc = run("align", mixed, "-o", out, "--json", "--jobs", jobs, *FAST)
    assert proc.returncode == 1, proc.stderr  # docs/align.md: any take that cannot be aligned
    assert "Traceback" not in proc.stderr
    reports = list(map(json.loads, proc.stdout.splitlines()))
    assert len(reports) == 4 + len(bad)
    errors = {Path(r["path"]).name: r for r in reports if "error" in r}
    assert set(errors) == set(bad)
    for name, word in bad.items():
        assert set(errors[name]) == {"id", "path", "error"}
        assert word in errors[name]["error"], errors[name]
    good = [r for r in reports if "error" not in r]
    assert len(good) == 4 and all(r["outputs"] for r in good)
    for r in good:
        for path in r["outputs"]:
            assert read_take(path).meta.source_kind == "aligned"
    # without --json: one line per failing take on stderr, the good takes still reported
    lines = run_here("align", mixed, "-o", tmp_path / "al2", *FAST).stderr.splitlines()
    assert sum(line.startswith("s2a-align: error:") for line in lines) == len(bad)
    assert len(lines) == 4 + len(bad) and "Traceback" not in "\n".join(lines)


def test_a_program_fault_on_one_take_is_reported_for_that_take(raw_takes, tmp_path, monkeypatch):
    """A genuine bug (not bad input) on one take: reported with its exception type, the rest go on."""
    real = align.batch.align_with_report
    victim = _first(raw_takes).name

    def faulty(take, options=None):
        if take.meta.id == victim:
            raise ZeroDivisionError("division by zero")
        return real(take, options)

    monkeypatch.setattr(align.batch, "align_with_report", faulty)
    reports = align_takes([raw_takes], tmp_path / "al", AlignOptions(vad="none", use_video=False))
    by_id = {r["id"]: r for r in reports}
    assert "ZeroDivisionError" in by_id[victim]["error"] and "internal error" in by_id[victim]["error"]
    assert sum("outputs" in r for r in reports) == 3


def test_a_hand_edited_output_is_aligned_again_not_a_crash(raw_takes, tmp_path):
    out = tmp_path / "al"
    first = _reports(run_here("align", raw_takes, "-o", out, "--json", *FAST, check=True))
    take_id, report = next(iter(first.items()))
    _edit_meta(Path(report["outputs"][0]), lambda m: m["extra"]["align"].pop("frames"))
    proc = run_here("align", raw_takes, "-o", out, "--json", *FAST)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr
    again = _reports(proc)
    assert again[take_id]["skipped"] is False  # aligned again: the stored report was damaged
    assert all(r["skipped"] for tid, r in again.items() if tid != take_id)


# 3. Weak evidence never moves the placement.


def test_weak_content_evidence_on_a_short_take_keeps_the_placement(tmp_path):
    run_here("capture", "simulate", "-o", tmp_path / "sim", "--seconds", 2, "--seed", 1, check=True)
    run_here("capture", "import", tmp_path / "sim", "-o", tmp_path / "takes", check=True)
    proc = run_here("align", tmp_path / "takes", "-o", tmp_path / "al", "--json", *FAST, check=True)
    (report,) = _reports(proc).values()
    content = [e for e in report["alternatives"] if e["source"] == "content"]
    # the evidence was measured, is weak, and would have moved the face
    assert content and 0 < content[0]["confidence"] < 0.3 and abs(content[0]["offset_s"]) > 0.02
    assert report["offset_s"] == 0.0 and report["offset_source"] == "timecode"
    assert "low_confidence" in report["flags"]
    assert "placement kept" in report["chosen"]["detail"]["note"]
    aligned = read_take(report["outputs"][0])
    assert aligned.meta.extra["align"]["offset_s"] == 0.0


def test_combine_uses_evidence_only_from_the_minimum_confidence_up():
    timecode = Evidence("timecode", 0.0, 0.0, 1.0, {"start_source": "assumed_first_csv_row"})
    noise = Evidence("content", 0.397, 0.018, 0.01)
    kept = combine([timecode, noise], 0.3, 0.05)
    assert kept.chosen.offset_s == 0.0 and kept.chosen.source == "timecode"
    assert kept.flags == ["low_confidence"] and noise in kept.alternatives
    assert timecode.detail == {"start_source": "assumed_first_csv_row"}  # not changed in place
    strong = Evidence("content", -0.1, 0.31, 0.01)
    used = combine([timecode, strong], 0.3, 0.05)
    assert used.chosen is strong and used.flags == []
    placed = Evidence("timecode", 0.0, 0.5, 0.1, {"start_source": "frame_log_audio"})
    assert combine([placed, noise], 0.3, 0.05).chosen is placed
    # without any placement evidence the offset stays 0 too
    alone = combine([noise], 0.3, 0.05)
    assert alone.chosen.offset_s == 0.0 and alone.chosen.source == "none" and "low_confidence" in alone.flags


# 4. Stereo whose channels cancel when mixed.


def _stereo_take(raw_takes: Path, root: Path, take_id: str, second) -> Path:
    take = read_take(_first(raw_takes))
    x = take.audio.samples[:, 0].astype(np.float32) / 32768.0
    take.meta.id = take_id
    stereo = np.stack([x, second(x)], axis=1).astype(np.float32)
    take.attach_audio(Audio(stereo, take.audio.sample_rate, "FLOAT"), 0.0, take.meta.audio.start_source)
    return write_take(take, root)


def test_phase_inverted_stereo_is_aligned_on_one_channel(raw_takes, tmp_path):
    raw = tmp_path / "raw"
    _stereo_take(raw_takes, raw, "inverted", lambda x: -x)
    _stereo_take(raw_takes, raw, "normal", lambda x: 0.5 * x)
    proc = run_here("align", raw, "-o", tmp_path / "al", "--json", *FAST)
    assert proc.returncode == 0, proc.stderr
    reports = _reports(proc)
    inverted, normal = reports["inverted"], reports["normal"]
    assert inverted["audio_mix"]["method"] == "louder_channel" and inverted["audio_mix"]["channel"] == 1
    assert "cancel" in inverted["warnings"][0]
    assert "audio_mix" not in normal and "warnings" not in normal
    stored = read_take(inverted["outputs"][0]).meta.extra["align"]
    assert stored["audio_mix"]["channel"] == 1 and stored["warnings"]
    # the speech survived: the aligned audio is as loud as one channel, not silence
    a = read_take(inverted["outputs"][0]).audio.samples[:, 0]
    b = read_take(normal["outputs"][0]).audio.samples[:, 0]
    assert np.sqrt(np.mean(a**2)) == pytest.approx(np.sqrt(np.mean(b**2)) / 0.75, rel=0.05)
    assert inverted["offset_s"] == pytest.approx(normal["offset_s"], abs=1e-3)
    # without --json the warning is a line of its own
    text = run_here("align", raw, "-o", tmp_path / "al2", *FAST).stderr
    assert "s2a-align: warning: take inverted: the 2 audio channels cancel" in text


def test_mono_mix_keeps_the_average_for_normal_stereo():
    rng = np.random.default_rng(0)
    x = rng.standard_normal(16000).astype(np.float32) * 0.1
    y = rng.standard_normal(16000).astype(np.float32) * 0.1
    for pair in ([x, y], [x, 0.5 * x], [x, -0.5 * x]):  # independent, a quieter copy, ...
        audio = Audio(np.stack(pair, axis=1), 16000, "FLOAT")
        mono, note = mono_mix(audio)
        assert note is None and np.array_equal(mono, audio.mono_float())
    # a silent channel is left out, not averaged in at half the level (docs/align.md, "Resampling")
    mono, note = mono_mix(Audio(np.stack([x, 0 * x], axis=1), 16000, "FLOAT"))
    assert np.array_equal(mono, x) and note["method"] == "channels_left_out" and note["used_channels"] == [1]
    nearly = Audio(np.stack([0.9 * x, -0.9 * x + 0.001 * y], axis=1), 16000, "FLOAT")
    mono, note = mono_mix(nearly)
    assert note["channel"] == 2 and note["mix_below_channel_db"] > 20
    notes: list = []
    out = to_16k_mono(Audio(np.stack([x, -x], axis=1).astype(np.float32), 16000, "FLOAT"), None, notes)
    assert np.allclose(out, remove_rumble(x), atol=1e-6) and notes[0]["mix_below_channel_db"] is None


# 5. Outputs are named by the take id in meta.json, not by the folder name.


def test_outputs_follow_the_meta_id_and_a_second_take_of_that_id_is_refused(raw_takes, tmp_path):
    raw = tmp_path / "raw"
    _copy(raw_takes, raw / "folder_a", new_id="speaker_take")
    _copy(raw_takes, raw / "folder_b", new_id="speaker_take")
    proc = run_here("align", raw, "-o", tmp_path / "al", "--json", *FAST)
    assert proc.returncode == 1
    reports = list(map(json.loads, proc.stdout.splitlines()))
    first, second = reports
    assert [Path(p).name for p in first["outputs"]] == ["speaker_take"]
    assert "also the id of" in second["error"] and second["path"].endswith("folder_b")
    out = read_take(first["outputs"][0])
    assert out.meta.extra["align"]["parent"]["path"].endswith("folder_a")
