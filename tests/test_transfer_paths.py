"""Takes as they reach a user's computer after copying, zipping and downloading: macOS AppleDouble
``._*`` files and ``__MACOSX`` folders, Windows' recycle bin, Office owner files, unfinished downloads,
iCloud placeholders, zip archives, copies of a CSV, names in NFD, symbolic links."""

from __future__ import annotations

import json
import os
import shutil
import unicodedata
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from capture import read_take, read_take_folder
from capture.transfer_litter import Litter, icloud_original, is_appledouble, litter_kind
from tests.conftest import run_here

STEM = "SimSpk01_1_spk01"  # the simulated take's file names


def apple_double(path: Path) -> Path:
    """A minimal AppleDouble file, as Finder writes ``._X`` beside a copied ``X``."""
    head = b"\x00\x05\x16\x07" + b"\x00\x02\x00\x00" + b"Mac OS X        "
    path.write_bytes(head + bytes(4096 - len(head)))
    return path


def icloud_placeholder(folder: Path, name: str) -> Path:
    """iCloud Drive's stand-in ``.X.icloud`` (a binary property list) for a file not downloaded."""
    path = folder / f".{name}.icloud"
    path.write_bytes(b"bplist00\xd3\x01\x02\x03TnameTsizeXNSURLFileResourceTypeRegular" + bytes(40))
    return path


def copy_take(sim_take: Path, where: Path) -> Path:
    where.parent.mkdir(parents=True, exist_ok=True)
    return Path(shutil.copytree(sim_take, where))


def imported(out: Path) -> list[Path]:
    return sorted(p for p in out.iterdir() if (p / "meta.json").is_file()) if out.is_dir() else []


def warnings_of(proc) -> list[str]:
    return [line for line in proc.stderr.splitlines() if "warning:" in line]


def test_litter_names():
    assert litter_kind("._take.csv") and litter_kind("__MACOSX") and litter_kind("$Recycle.Bin")
    assert litter_kind("System Volume Information") and litter_kind("~$take.csv")
    assert (
        litter_kind("take.csv.part") and litter_kind("take.csv.crdownload") and litter_kind("takes.download")
    )
    assert not litter_kind("take.csv") and not litter_kind(".take.csv.icloud") and not litter_kind("a_$b.csv")
    assert (
        icloud_original(Path(".A_1_b.mov.icloud")) == "A_1_b.mov" and icloud_original(Path("a.mov")) is None
    )
    tally = Litter()
    assert tally.skips(Path("a/._x")) and tally.skips(Path("a/._x")) and tally.skips(Path("a/._y"))
    assert not tally.skips(Path("a/x.csv")) and tally.skips(Path("a/__MACOSX"))
    assert tally.lines() == [
        "skipped 2 macOS metadata files (._*)",
        "skipped 1 macOS metadata folder (__MACOSX)",
    ]


def test_apple_double_files_in_a_take_folder_are_skipped_and_the_audio_kept(sim_take, tmp_path):
    take = copy_take(sim_take, tmp_path / "card" / "T")
    for name in (f"{STEM}.mov", f"{STEM}_cal.csv", "frame_log.csv", f"{STEM}_neutral.csv", f"{STEM}.WAV"):
        apple_double(take / f"._{name}")
    assert is_appledouble(take / f"._{STEM}.mov")
    # a zip made by Finder: its __MACOSX holds a copy of the take's layout of ._ files
    shadow = tmp_path / "card" / "__MACOSX" / "T"
    shadow.mkdir(parents=True)
    for name in ("take.json", "frame_log.csv", f"{STEM}.csv", f"{STEM}.mov"):
        apple_double(shadow / f"._{name}")
    proc = run_here("capture", "import", tmp_path / "card", "-o", tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    (out,) = imported(tmp_path / "out")
    t = read_take(out)
    assert t.audio is not None and t.meta.audio.start_source == "frame_log_audio"
    assert t.meta.extra["reference_video"] == f"{STEM}.mov" and t.meta.csv["variant"] is None
    assert t.neutral is None
    lines = warnings_of(proc)
    assert sum("skipped 5 macOS metadata files (._*)" in w for w in lines) == 1, proc.stderr
    assert sum("skipped 1 macOS metadata folder (__MACOSX)" in w for w in lines) == 1, proc.stderr


def test_apple_double_mov_alone_never_takes_the_audio(sim_take, tmp_path):
    take = copy_take(sim_take, tmp_path / "T")
    (take / f"{STEM}.wav").unlink()
    apple_double(take / f"._{STEM}.mov")
    t = read_take_folder(take)
    assert t.audio is not None and t.meta.extra["reference_video"] == f"{STEM}.mov"
    assert not [r for r in t.meta.repairs if r["kind"] == "no_audio"]


def test_apple_double_beside_a_loose_csv_and_info_of_the_folder(samples, tmp_path):
    folder = tmp_path / "csvs"
    folder.mkdir()
    shutil.copy(samples / "livelinkface/alexdjulin_S07/S07-001.csv", folder / "S07-001.csv")
    apple_double(folder / "._S07-001.csv")
    apple_double(folder / "._S07-001_cal.csv")
    proc = run_here("capture", "import", folder, "-o", tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    assert [p.name for p in imported(tmp_path / "out")] == ["S07-001"]
    assert "skipped 2 macOS metadata files (._*)" in proc.stderr
    proc = run_here("capture", "info", folder, "--json")
    assert proc.returncode == 0, proc.stderr
    assert [json.loads(line)["id"] for line in proc.stdout.splitlines()] == ["S07-001"]
    assert "skipped 2 macOS metadata files (._*)" in proc.stderr
    # named directly (a path typed by hand), an AppleDouble file is passed over and counted all the same
    proc = run_here(
        "capture", "import", folder / "._S07-001.csv", folder / "S07-001.csv", "-o", tmp_path / "o2"
    )
    assert proc.returncode == 0 and "skipped 1 macOS metadata file (._*)" in proc.stderr, proc.stderr


def test_windows_and_download_litter_is_skipped(sim_take, tmp_path):
    drive = tmp_path / "E"
    copy_take(sim_take, drive / "takes" / "T")
    copy_take(sim_take, drive / "$RECYCLE.BIN" / "S-1-5-21" / "$R1A2B3C")  # a deleted take
    copy_take(sim_take, drive / "System Volume Information" / "T")
    partial = drive / "takes" / "T2.download"  # Safari's download in progress: a cut copy of the take
    copy_take(sim_take, partial / "T2")
    (drive / "takes" / f"~${STEM}.csv").write_bytes(b"\x0cuser" + bytes(150))  # Excel's owner file
    (drive / "takes" / f"{STEM}.csv.crdownload").write_text("Timecode,BlendShapeCount\n")
    (drive / "takes" / f"{STEM}.csv.part").write_text("Timecode,Blend")
    proc = run_here("capture", "import", drive, "-o", tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    assert len(imported(tmp_path / "out")) == 1
    for line in (
        "skipped 1 Windows recycle bin ($RECYCLE.BIN)",
        "skipped 1 Windows system folder (System Volume Information)",
        "skipped 1 Office owner file (~$*)",
        "skipped 3 unfinished downloads",
    ):
        assert line in proc.stderr, proc.stderr


def test_apple_double_textgrid_does_not_stop_ppg_training(tmp_path):
    from capture.textgrid import TextGrid, interval_tier, write_textgrid
    from train.ppg_train import find_speech

    rng = np.random.default_rng(0)
    sf.write(tmp_path / "utt.wav", (0.1 * rng.standard_normal(32000)).astype(np.float32), 16000)
    tier = interval_tier("phones", [(0.0, 1.0, "aa"), (1.0, 2.0, "s")], 0.0, 2.0)
    write_textgrid(TextGrid(0.0, 2.0, [tier]), tmp_path / "utt.TextGrid")
    apple_double(tmp_path / "._utt.TextGrid")
    apple_double(tmp_path / "._utt.wav")
    proc = run_here("train", "ppg", "--data", tmp_path, "-o", tmp_path / "p.pt", "--steps", "1", "--json")
    assert proc.returncode == 0, proc.stderr
    assert "skipped 2 macOS metadata files (._*)" in proc.stderr
    warnings: list[str] = []
    assert find_speech([tmp_path], warnings) == [tmp_path / "utt.wav"]
    assert warnings == ["skipped 2 macOS metadata files (._*)"]


def _wav(path: Path, seconds: float) -> Path:
    sf.write(path, np.zeros(int(16000 * seconds), np.int16), 16000, subtype="PCM_16")
    return path


def test_pair_audio_ignores_apple_double_audio_and_pairs_nfd_names(samples, tmp_path):
    csv = samples / "livelinkface/alexdjulin_S07/S07-001.csv"
    one = tmp_path / "one"
    one.mkdir()
    shutil.copy(csv, one / "take.csv")
    _wav(one / "voice.wav", 1.0)
    apple_double(one / "._voice.wav")
    cafe = tmp_path / "cafe"
    cafe.mkdir()
    shutil.copy(csv, cafe / (unicodedata.normalize("NFC", "Café") + ".csv"))
    _wav(cafe / "other.wav", 1.0)
    _wav(cafe / (unicodedata.normalize("NFD", "Café") + ".wav"), 1.0)
    proc = run_here("capture", "import", one, cafe, "--pair-audio", "-o", tmp_path / "out", "--json")
    assert proc.returncode == 0, proc.stderr
    summaries = {s["id"]: s for s in map(json.loads, proc.stdout.splitlines())}
    assert set(summaries) == {"take", unicodedata.normalize("NFC", "Café")}, proc.stdout
    for take in imported(tmp_path / "out"):
        t = read_take(take)
        assert t.audio is not None, take
    voice = [s for s in read_take(summaries["take"]["path"]).meta.sources if s.role == "external_audio"]
    assert Path(voice[0].path).name == "voice.wav"  # not its AppleDouble file ._voice.wav
    cafe_audio = read_take(summaries[unicodedata.normalize("NFC", "Café")]["path"]).meta.sources
    (nfd,) = [s for s in cafe_audio if s.role == "external_audio"]
    assert Path(nfd.path).name == unicodedata.normalize("NFD", "Café") + ".wav"
    assert "imported without audio" not in proc.stderr


def _other_csv(samples: Path) -> str:
    """Another take's CSV (alexdjulin's S07: another length and rate than the simulated take's)."""
    return (samples / "livelinkface/alexdjulin_S07/S07-001.csv").read_text()


@pytest.mark.parametrize("copy", [f"{STEM} (1).csv", f"{STEM} copy.csv", f"{STEM.upper()}.csv"])
def test_the_csv_named_after_the_take_wins_over_a_copy(sim_take, samples, tmp_path, copy):
    take = copy_take(sim_take, tmp_path / "T")
    real_rows = read_take_folder(take).time.size
    (take / copy).write_text(_other_csv(samples))
    assert sorted(p.name for p in take.glob("*.csv") if p.name != "frame_log.csv")[0] == copy  # sorts first
    proc = run_here("capture", "import", take, "-o", tmp_path / "out", "--json")
    assert proc.returncode == 0, proc.stderr
    (summary,) = map(json.loads, proc.stdout.splitlines())
    t = read_take(summary["path"])
    assert t.time.size == real_rows and Path(t.meta.sources[0].path).name == f"{STEM}.csv"


def test_two_csvs_none_named_after_the_take_are_an_error_naming_them(sim_take, samples, tmp_path):
    take = copy_take(sim_take, tmp_path / "T")
    for name in ("take.json", f"{STEM}.mov", f"{STEM}.wav"):
        (take / name).unlink()
    shutil.move(take / f"{STEM}.csv", take / "A.csv")
    (take / "B.csv").write_text(_other_csv(samples))
    proc = run_here("capture", "import", take, "-o", tmp_path / "out")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "2 plain CSVs (A.csv, B.csv)" in proc.stderr and "remove the others" in proc.stderr
    assert not imported(tmp_path / "out")


def test_a_csv_cut_short_is_a_warning(samples, tmp_path):
    text = (samples / "livelinkface/alexdjulin_S07/S07-001.csv").read_text()
    cut = tmp_path / "cut.csv"
    cut.write_text(text.rstrip("\n")[:-40])
    proc = run_here("capture", "import", cut, "-o", tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    assert "last row cut short" in proc.stderr and "an incomplete copy or download?" in proc.stderr


def test_icloud_placeholders_refuse_their_take_and_others_import(sim_take, tmp_path):
    root = tmp_path / "iCloud"
    good = copy_take(sim_take, root / "good")
    no_mov = copy_take(sim_take, root / "no_mov")
    for name in (f"{STEM}.mov", f"{STEM}.wav"):
        (no_mov / name).unlink()
        icloud_placeholder(no_mov, name)
    no_csv = copy_take(sim_take, root / "no_csv")
    (no_csv / f"{STEM}.csv").unlink()
    icloud_placeholder(no_csv, f"{STEM}.csv")
    loose = root / "loose"
    loose.mkdir()
    icloud_placeholder(loose, "S07-001.csv")
    proc = run_here("capture", "import", root, "-o", tmp_path / "out", "--json")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    errors = [line for line in proc.stderr.splitlines() if "error:" in line]
    assert len(errors) == 3, proc.stderr
    assert any(
        str(no_mov) in e and f"{STEM}.mov is an iCloud placeholder, not downloaded: download it first" in e
        for e in errors
    )
    assert any(str(no_csv) in e and f"{STEM}.csv is an iCloud placeholder" in e for e in errors)
    assert any("S07-001.csv is an iCloud placeholder" in e for e in errors)
    (out,) = imported(tmp_path / "out")
    assert read_take(out).audio is not None and str(good) in read_take(out).meta.sources[0].path


def test_zip_archives_are_imported_and_viewed(samples, tmp_path):
    """import reads archives (tests/test_take_archives.py), and s2a-view (tests/test_viewer_archives.py)."""
    folder = tmp_path / "dl"
    folder.mkdir()
    shutil.copy(samples / "livelinkface/alexdjulin_S07/S07-001.csv", folder / "S07-001.csv")
    shutil.make_archive(str(tmp_path / "takes"), "zip", folder)
    shutil.copy(tmp_path / "takes.zip", folder / "more takes.zip")
    proc = run_here("capture", "import", tmp_path / "takes.zip", "-o", tmp_path / "out")
    assert proc.returncode == 0 and "takes.zip/S07-001.csv ->" in proc.stderr, proc.stderr
    proc = run_here("capture", "import", folder, "-o", tmp_path / "out2")
    assert proc.returncode == 0, proc.stderr
    assert "more takes.zip/S07-001.csv ->" in proc.stderr
    proc = run_here("viewer", "plot", tmp_path / "takes.zip", "-o", tmp_path / "p.png")
    assert proc.returncode == 0 and (tmp_path / "p.png").stat().st_size > 0, proc.stderr


def test_symlinks_to_a_parent_and_dangling_links_are_skipped(sim_take, tmp_path):
    copy_take(sim_take, tmp_path / "unrelated" / "T")  # beside the folder imported: never reached
    folder = tmp_path / "session"
    copy_take(sim_take, folder / "T")
    os.symlink("..", folder / "loop")
    os.symlink("missing.csv", folder / "gone.csv")
    proc = run_here("capture", "import", folder, "-o", tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    assert len(imported(tmp_path / "out")) == 1
    lines = warnings_of(proc)
    assert any("loop" in w and "holds the folder searched" in w for w in lines), proc.stderr
    assert any("gone.csv" in w and "does not exist" in w for w in lines), proc.stderr


def test_apple_double_data_under_a_csv_name_says_what_to_import(samples, tmp_path):
    from capture.errors import InputError
    from capture.importer import import_source

    renamed = apple_double(tmp_path / "S07-001.csv")  # AppleDouble data copied over (or renamed to) X.csv
    with pytest.raises(InputError, match="AppleDouble") as err:
        import_source(renamed)
    assert "without the ._" not in str(err.value) and "import the CSV itself" in str(err.value)
    named = apple_double(tmp_path / "._S07-001.csv")
    with pytest.raises(InputError, match="import the file without the ._ in its name"):
        import_source(named)
    proc = run_here("capture", "import", renamed, "-o", tmp_path / "out")
    assert proc.returncode == 1 and "AppleDouble" in proc.stderr and "Traceback" not in proc.stderr
    assert "without the ._" not in proc.stderr and not imported(tmp_path / "out")


def test_pair_audio_refuses_a_csv_whose_only_audio_is_an_icloud_placeholder(samples, tmp_path):
    csv = samples / "livelinkface/alexdjulin_S07/S07-001.csv"
    one = tmp_path / "one"
    one.mkdir()
    shutil.copy(csv, one / "take.csv")
    icloud_placeholder(one, "voice.wav")  # the only audio beside it, named otherwise, not downloaded
    two = tmp_path / "two"
    two.mkdir()
    shutil.copy(csv, two / "take.csv")
    icloud_placeholder(two, "a.wav")
    icloud_placeholder(two, "b.wav")
    for folder, name in ((one, "voice.wav"), (two, "a.wav")):
        proc = run_here("capture", "import", folder, "--pair-audio", "-o", tmp_path / "out")
        assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
        assert f"{name} is an iCloud placeholder, not downloaded" in proc.stderr, proc.stderr
        assert str(folder / "take.csv") in proc.stderr and not imported(tmp_path / "out")
    # the placeholder of another CSV's audio: that CSV's error, this one's warning as for a real file
    shutil.copy(csv, two / "a.csv")
    shutil.copy(csv, two / "b.csv")
    proc = run_here("capture", "import", two / "take.csv", "--pair-audio", "-o", tmp_path / "out")
    assert proc.returncode == 0 and "2 audio files beside it and none named take.*" in proc.stderr


def test_icloud_placeholders_of_files_the_take_never_reads_do_not_refuse_it(sim_take, tmp_path):
    extra_mov = copy_take(sim_take, tmp_path / "extra_mov")
    icloud_placeholder(extra_mov, "other_take.mov")  # a second .mov, not named as the CSV
    wav_unused = copy_take(sim_take, tmp_path / "wav_unused")
    (wav_unused / f"{STEM}.wav").unlink()
    icloud_placeholder(wav_unused, f"{STEM}.wav")  # the .mov holds the audio: the .wav is never read
    icloud_placeholder(wav_unused, "notes.json")
    for take in (extra_mov, wav_unused):
        t = read_take_folder(take)
        assert t.audio is not None and t.meta.extra["reference_video"] == f"{STEM}.mov"
    # without the .mov, the .wav is the take's audio: its placeholder refuses the take
    (wav_unused / f"{STEM}.mov").unlink()
    with pytest.raises(Exception, match=f"{STEM}.wav is an iCloud placeholder"):
        read_take_folder(wav_unused)
    # the app's JSON the take reads still refuses it
    app_json = copy_take(sim_take, tmp_path / "app_json")
    if (app_json / "video_metadata.json").exists():
        (app_json / "video_metadata.json").unlink()
    icloud_placeholder(app_json, "video_metadata.json")
    with pytest.raises(Exception, match="video_metadata.json is an iCloud placeholder"):
        read_take_folder(app_json)


def test_a_take_folder_named_like_a_zip_is_imported(sim_take, tmp_path):
    take = copy_take(sim_take, tmp_path / "T.zip")
    proc = run_here("capture", "import", take, "-o", tmp_path / "out")
    assert proc.returncode == 0 and "zip archive" not in proc.stderr, proc.stderr
    proc = run_here("capture", "import", tmp_path, "-o", tmp_path / "out2")
    assert proc.returncode == 0 and "zip archive" not in proc.stderr, proc.stderr
    assert len(imported(tmp_path / "out")) == 1 and len(imported(tmp_path / "out2")) == 1
