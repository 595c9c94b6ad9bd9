"""Takes as copies leave them: names from macOS (decomposed Unicode) and Windows (device names), names
that read as options, symbolic links to take folders, and frames.npz with members a take never has."""

from __future__ import annotations

import io
import os
import unicodedata
import zipfile

import numpy as np
import pytest

from capture import read_take, write_take
from capture.errors import InputError
from capture.take import find_takes, safe_id
from tests.conftest import run_cli
from tests.live_helpers import synthetic_take


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        (unicodedata.normalize("NFD", "Café_1"), "Café_1"),  # as macOS writes it: one id with the NFC name
        ("Café_1", "Café_1"),
        (unicodedata.normalize("NFD", "Zoë"), "Zoë"),
        ("--help", "help"),  # a folder `--help` made `s2a-align *` print its help and do nothing
        ("-take", "take"),
        ("AUX", "AUX_"),  # Windows device names cannot be folders there
        ("com1", "com1_"),
        ("nul.seg01", "nul_.seg01"),
        ("COM10", "COM10"),
        ("console", "console"),
        ("...", "take"),
    ],
)
def test_take_ids_are_the_same_and_usable_everywhere(name, expected):
    assert safe_id(name) == expected


def test_symlinked_takes_are_found_once_and_links_upward_are_not_followed(tmp_path):
    """Python's rglob does not follow links: align, build and report skipped symlinked takes."""
    elsewhere = write_take(synthetic_take(10), tmp_path / "elsewhere")
    write_take(synthetic_take(10, seed=2), tmp_path / "other")  # reachable only through the link up
    here = tmp_path / "takes"
    own = write_take(synthetic_take(10, seed=1), here)
    os.symlink(elsewhere.parent, here / "session1")  # a folder of takes linked in
    os.symlink(elsewhere, here / "again")  # the same take through a second link: found once
    os.symlink("..", here / "up")  # up to the folder holding `elsewhere` and `takes` again
    os.symlink(".", here / "self")
    found = find_takes([here])
    assert sorted(os.path.realpath(p) for p in found) == sorted(map(os.path.realpath, [elsewhere, own]))
    assert find_takes([tmp_path / "elsewhere"]) == [elsewhere]


def test_align_reads_a_symlinked_take(tmp_path):
    take = write_take(synthetic_take(180, audio=True), tmp_path / "raw")
    (tmp_path / "links").mkdir()
    os.symlink(take, tmp_path / "links" / take.name)
    proc = run_cli("align", tmp_path / "links", "-o", tmp_path / "al", "--vad", "none")
    assert proc.returncode == 0, proc.stderr
    assert find_takes([tmp_path / "al"]), proc.stderr


def _npz_with(folder, extra: dict[str, bytes]) -> None:
    """frames.npz of ``folder`` rewritten with ``extra`` raw members added."""
    path = folder / "frames.npz"
    members = {}
    with zipfile.ZipFile(path) as z:
        for name in z.namelist():
            members[name] = z.read(name)
    members.update(extra)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in members.items():
            z.writestr(name, data)


def _npy_header(shape: tuple[int, ...]) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f8", "fortran_order": False, "shape": shape})
    return buf.getvalue()


def test_a_take_folder_named_like_a_download_is_found(tmp_path):
    """Take ids keep dots: `interview.part.csv` makes the take `interview.part`, no unfinished download."""
    take = synthetic_take(10)
    take.meta.id = "interview.part"
    folder = write_take(take, tmp_path)
    assert find_takes([tmp_path]) == [folder]


def test_frames_saved_as_one_npy_array_are_named_so(tmp_path):
    folder = write_take(synthetic_take(10), tmp_path)
    with open(folder / "frames.npz", "wb") as f:
        np.save(f, np.zeros(3))
    with pytest.raises(InputError, match="a .npy array, not a .npz archive"):
        read_take(folder)


def test_frames_members_a_take_never_has_are_not_read(tmp_path):
    """A member declaring 2 GiB in a few compressed bytes made read_take allocate it."""
    folder = write_take(synthetic_take(10), tmp_path)
    _npz_with(folder, {"extra.npy": _npy_header((1 << 28,)) + b"\0" * 64, "README.txt": b"notes"})
    _npz_with(folder, {"damaged.npy": b"\x93NUMPY\x01\x00{'descr': "})  # a header cut short: not read
    take = read_take(folder)
    assert take.values.shape[0] == 10


def test_a_take_array_declaring_more_than_any_take_holds_is_refused_before_reading(tmp_path):
    folder = write_take(synthetic_take(10), tmp_path)
    _npz_with(folder, {"values.npy": _npy_header((1 << 20, 1 << 10)) + b"\0" * 64})
    with pytest.raises(InputError, match="array 'values' holds 1073741824 values"):
        read_take(folder)


def test_plot_of_a_take_named_in_chinese_warns_once_of_characters_no_font_has(tmp_path):
    """Each missing glyph was a matplotlib UserWarning of two lines, repeated per draw."""
    from matplotlib import font_manager

    from viewer.plot import CJK_FONTS

    take = synthetic_take(60)
    take.meta.id = "你好_take"
    folder = write_take(take, tmp_path)
    proc = run_cli("viewer", "plot", folder, "-o", tmp_path / "p.png", "--title", "说话")
    assert proc.returncode == 0 and "UserWarning" not in proc.stderr, proc.stderr
    installed = {f.name for f in font_manager.fontManager.ttflist} & set(CJK_FONTS)
    warned = [line for line in proc.stderr.splitlines() if "no installed font has" in line]
    assert warned == (
        []
        if installed
        else [
            "s2a-view: warning: no installed font has '你好说话' (drawn as boxes): "
            "install one that has them, such as Noto Sans CJK"
        ]
    ), proc.stderr


def test_takes_inside_what_systems_leave_are_not_found(tmp_path):
    """A drive root's recycle bin (deleted takes) and a Finder zip's __MACOSX are not takes to align."""
    own = write_take(synthetic_take(10), tmp_path / "drive")
    write_take(synthetic_take(10, seed=1), tmp_path / "drive" / "$RECYCLE.BIN" / "S-1-5-21")
    write_take(synthetic_take(10, seed=2), tmp_path / "drive" / "__MACOSX")
    assert find_takes([tmp_path / "drive"]) == [own]


def test_validate_passes_over_macos_metadata_beside_the_shards(tmp_path):
    from dataset.qa import validate
    from tests.dataset_helpers import build_five_take_dataset

    ds = build_five_take_dataset(tmp_path)
    (ds / "._train-000000.tar").write_bytes(b"\x00\x05\x16\x07" + b"\0" * 4092)  # a copy to an exFAT drive
    report = validate(ds)
    assert not [p for p in report.problems if p.check == "shard_unlisted"], report.problems
