"""Review of the import of Audio2Face-3D training data: what else its folder holds still imports, a shot
named from inside its folder, damaged vertex caches and setups, hostile configs."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
from conftest import SAMPLES, run_cli, run_here
from test_migrate_s29 import SHOTS, make_a2f_dataset

from capture import read_take
from capture.take import FrameStatus

LIVE_LINK = SAMPLES / "livelinkface" / "alexdjulin_S07" / "S07-001.csv"


def _takes(out: Path) -> list[str]:
    return sorted(p.name for p in out.iterdir() if p.is_dir())


def test_a_take_beside_folders_named_like_a_dataset_still_imports(samples, tmp_path):
    """A Live Link take in a folder that also has ``audio/`` and a ``cache/skin/`` with no shot, and one
    in an actor's dataset folder, are imported, a note in ``cache/skin`` passed over (the commit's walk
    stopped at such a folder: the take was left out without a word, exit 0 when another source was
    found; the note was "a Maya cache (.xml + .mc)" that failed the run)."""
    project = tmp_path / "project"
    for part in ("audio", "cache/skin"):
        (project / part).mkdir(parents=True)
    shutil.copy(LIVE_LINK, project)
    proc = run_here("capture", "import", project, "-o", tmp_path / "takes")
    assert proc.returncode == 0, proc.stderr
    assert _takes(tmp_path / "takes") == ["S07-001"]

    actor, _ = make_a2f_dataset(tmp_path / "a2f")
    shutil.copy(LIVE_LINK, actor)
    (actor / "cache" / "skin" / "README.txt").write_text("exported from Maya, 30 fps\n")  # no shot
    proc = run_here("capture", "import", actor, "-o", tmp_path / "both")
    assert proc.returncode == 0, proc.stderr
    assert _takes(tmp_path / "both") == sorted([*SHOTS, "S07-001"])


def test_a_shot_named_from_inside_its_folder_has_its_actor_and_config(samples, tmp_path, monkeypatch):
    """``cd cache/skin && s2a-capture import cp1_neutral.npy``: the actor and the config two folders
    above it are found as with a full path (the commit: "not a Live Link Face CSV"; named
    ``cache/skin/<shot>.npy`` from the actor's folder: actor "", the config missed, the rate guessed from
    the audio)."""
    actor, made = make_a2f_dataset(tmp_path / "a2f")
    monkeypatch.chdir(actor / "cache" / "skin")
    proc = run_here("capture", "import", f"{SHOTS[2]}.npy", "-o", tmp_path / "takes")
    assert proc.returncode == 0, proc.stderr
    take = read_take(tmp_path / "takes" / SHOTS[2])
    assert take.meta.extra["audio2face_shot"] == {"actor": "mark", "emotion": "anger"}
    assert [r["kind"] for r in take.meta.repairs] == ["blendshape_solve"]  # no fps_from_audio
    assert np.abs(take.values - made[SHOTS[2]]).max() < 1e-3


def test_vertices_holding_nan_mark_their_frames_invalid(samples, tmp_path):
    """A NaN and an inf among the vertices the solve uses mark those two frames invalid, the others
    solved as before (the commit: a traceback, "array must not contain infs or NaNs")."""
    actor, made = make_a2f_dataset(tmp_path / "a2f")
    cache = actor / "cache" / "skin" / f"{SHOTS[1]}.npy"
    frames = np.load(cache)
    used = np.load(actor / "bs_data" / "bs_skin.npz")["frontalMask"]
    frames[10, used[3], 0], frames[20, used[4], 1] = np.nan, np.inf
    np.save(cache, frames)
    proc = run_here("capture", "import", cache, "-o", tmp_path / "takes")
    assert proc.returncode == 0, proc.stderr
    take = read_take(tmp_path / "takes" / SHOTS[1])
    bad = np.flatnonzero(take.frame_status != FrameStatus.TRACKED)
    assert bad.tolist() == [10, 20]
    assert (take.frame_status[bad] == FrameStatus.BAD_VALUE).all()
    good = np.delete(np.arange(len(frames)), bad)
    assert np.abs(take.values[good] - made[SHOTS[1]][good]).max() < 1e-3
    assert "2 frames hold NaN/inf" in str(take.meta.repairs)


def _rewrite_setup(actor: Path, **changes) -> None:
    setup = actor / "bs_data" / "bs_skin.npz"
    with np.load(setup) as npz:
        arrays = {k: npz[k] for k in npz.files}
    np.savez(setup, **(arrays | changes))


def test_a_frontal_mask_of_flags_selects_its_vertices(samples, tmp_path):
    """A ``frontalMask`` of a flag per vertex (not the framework's indices) solves over the flagged
    vertices (the commit read the flags as the indices 0 and 1: two vertices, weights far off)."""
    actor, made = make_a2f_dataset(tmp_path / "a2f")
    with np.load(actor / "bs_data" / "bs_skin.npz") as npz:
        flags = np.zeros(npz["neutral"].shape[0], bool)
        flags[npz["frontalMask"]] = True
    _rewrite_setup(actor, frontalMask=flags)
    cache = actor / "cache" / "skin" / f"{SHOTS[0]}.npy"
    proc = run_here("capture", "import", cache, "-o", tmp_path / "takes")
    assert proc.returncode == 0, proc.stderr
    take = read_take(tmp_path / "takes" / SHOTS[0])
    assert np.abs(take.values - made[SHOTS[0]]).max() < 1e-3
    assert f"({flags.sum()} vertices used)" in str(take.meta.repairs)

    _rewrite_setup(actor, frontalMask=flags[:-1])
    proc = run_here("capture", "import", cache, "-o", tmp_path / "short")
    assert proc.returncode == 1
    assert proc.stderr.strip().endswith(
        f"frontalMask flags {flags.size - 1} vertices, the neutral {flags.size}"
    )


def test_a_setup_holding_nan_is_a_one_line_error(samples, tmp_path):
    """A NaN in the neutral at a vertex the solve uses is one line naming the setup (the commit: the
    solve a traceback, "array must not contain infs or NaNs")."""
    actor, _ = make_a2f_dataset(tmp_path / "a2f")
    with np.load(actor / "bs_data" / "bs_skin.npz") as npz:
        neutral, used = npz["neutral"].copy(), npz["frontalMask"]
    neutral[used[0], 2] = np.nan
    _rewrite_setup(actor, neutral=neutral)
    proc = run_here("capture", "import", actor / "cache" / "skin" / f"{SHOTS[0]}.npy", "-o", tmp_path / "t")
    assert proc.returncode == 1 and not (tmp_path / "t" / SHOTS[0]).exists()
    assert proc.stderr.strip().endswith("bs_skin.npz: the neutral or a pose's deltas hold NaN/inf")


def test_a_config_nested_past_the_parser_is_a_one_line_error(samples, tmp_path):
    """A config_dataset.py whose expression is nested deeper than Python's parser goes is one line per
    shot naming it, never run (the commit: a traceback, RecursionError)."""
    actor, _ = make_a2f_dataset(tmp_path / "a2f")
    config = actor.parents[1] / "config_dataset.py"
    config.write_text("CACHE_FPS = {'mark': 30.0}\nDEPTH = " + "+".join(["1"] * 300_000) + "\n")
    proc = run_cli("capture", "import", actor, "-o", tmp_path / "takes")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    errors = [line for line in proc.stderr.splitlines() if ": error: " in line]
    assert len(errors) == len(SHOTS)
    assert all(
        line.endswith(f"{config}: not a readable Python config (nested too deeply to parse)")
        for line in errors
    )
