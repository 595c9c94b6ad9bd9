"""Review of take names matched in Unicode NFC and of the viewer unpacking a zipped take's ``.wav`` only
when its reader reads it: two files of one take whose names are equal in NFC but both present (a Mac's
decomposed copy beside a file named here) are an error naming both spellings, never one taken in silence;
names equal only in NFKC (``ﬁ`` and ``fi``) stay two names; a zipped take is shown as the folder
unzipped whatever its ``.mov`` (damaged, an iCloud placeholder, silent, two of them) or ``.wav``; and a
Ctrl-C or SIGTERM while the ``.wav`` is unpacked leaves nothing in the temporary folder."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import unicodedata
import zipfile
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT, run_here
from test_take_names_nfc import tone, write_csv, write_mov, write_wav, zip_folder

from capture.errors import InputError
from capture.importer import find_sources
from capture.take_archive import UNPACK_PREFIX
from capture.take_folder import read_take_folder, takes_side_by_side
from viewer.inputs import archives_unpacked, read_input

NFC = unicodedata.normalize("NFC", "Café_3")
NFD = unicodedata.normalize("NFD", "Café_3")
TWINS = "one name spelled two ways in Unicode"


def left_in(unpack_tmp: Path) -> list[str]:
    return sorted(p.name for p in unpack_tmp.iterdir() if p.name.startswith(UNPACK_PREFIX))


def view(path: Path) -> tuple:
    """What ``read_input`` shows of ``path``: the speech file's name, the frames' count, the speech's
    samples and start, the number of warnings; or the error's message less the path it names."""
    try:
        take, warnings, speech = read_input(path, "one")
    except InputError as exc:  # a name as spelled where it was found (NFD in a Mac's archive)
        return ("error", unicodedata.normalize("NFC", str(exc).split(": ", 1)[1]))
    audio = None if take.audio is None else take.audio.samples.tobytes()
    start = None if take.audio is None else (take.meta.audio.start_s, take.meta.audio.start_source)
    return (speech.name, take.values.shape, audio, start, len(warnings))


# -- two spellings of one name, both present --------------------------------------------------------
def test_a_mov_spelled_two_ways_is_an_error_naming_both_zipped_or_not(samples, tmp_path, unpack_tmp):
    """The take's .mov copied from a Mac (NFD) beside its copy named here (NFC), of other speech: which
    is the take's no name tells; the take folder, and the viewer on it zipped, say so."""
    folder = tmp_path / "T"
    folder.mkdir()
    write_csv(samples, folder / f"{NFC}.csv")
    write_mov(folder / f"{NFC}.mov", tone(440))
    write_mov(folder / f"{NFD}.mov", tone(660))
    with pytest.raises(InputError, match=TWINS) as err:
        read_take_folder(folder)
    assert "decomposed, NFD" in str(err.value) and "composed, NFC" in str(err.value)
    archive = zip_folder(folder, tmp_path / "t.zip", inside="T")
    for named in (archive, archive / "T", archive / "T" / f"{NFC}.csv"):
        with archives_unpacked():
            got = view(named)
        assert got == view(folder.parent / named.relative_to(archive)) and TWINS in got[1], named
    assert left_in(unpack_tmp) == []


def test_a_wav_spelled_two_ways_beside_a_silent_mov_is_an_error(samples, tmp_path):
    folder = tmp_path / "T"
    folder.mkdir()
    write_csv(samples, folder / "T.csv")
    write_mov(folder / "T.mov", None)
    write_wav(folder / f"{NFC}.wav", tone(440))
    write_wav(folder / f"{NFD}.wav", tone(660))
    with pytest.raises(InputError, match=TWINS):
        read_take_folder(folder)


def test_a_flat_folder_with_a_csv_spelled_two_ways_is_not_split_in_silence(samples, tmp_path):
    """A flat folder of two takes, one of whose CSVs is there twice (NFC and NFD, other rows): not two
    takes of which one CSV is dropped, but an error naming both, for the folder, import and info."""
    flat = tmp_path / "flat"
    flat.mkdir()
    write_csv(samples, flat / f"{NFC}.csv")
    write_csv(samples, flat / f"{NFD}.csv", rows=40)
    write_mov(flat / f"{NFC}.mov", tone(440))
    write_csv(samples, flat / "B.csv")
    write_mov(flat / "B.mov", tone(660))
    assert takes_side_by_side(flat) == [] and find_sources([flat]) == [flat]
    with pytest.raises(InputError, match=TWINS):
        read_take_folder(flat)
    for args in (("import", flat, "-o", tmp_path / "takes"), ("info", flat)):
        proc = run_here("capture", *args)
        assert proc.returncode != 0 and TWINS in proc.stderr and "Traceback" not in proc.stderr, proc.stderr


def test_a_neutral_csv_spelled_two_ways_in_a_flat_folder_is_an_error(samples, tmp_path):
    flat = tmp_path / "flat"
    flat.mkdir()
    write_csv(samples, flat / f"{NFC}_cal.csv")
    write_csv(samples, flat / f"{NFC}_neutral.csv", rows=3)
    write_csv(samples, flat / f"{NFD}_neutral.csv", rows=5)
    write_mov(flat / f"{NFC}.mov", tone(440))
    write_csv(samples, flat / "B.csv")
    write_mov(flat / "B.mov", tone(660))
    with pytest.raises(InputError, match=f"{TWINS}.*keep the take's own"):
        read_take_folder(flat, csv=flat / f"{NFC}_cal.csv")


def test_a_take_folders_csv_spelled_two_ways_is_named_as_such(samples, tmp_path):
    """Two CSVs whose names print alike: the error says how they differ, not just lists them."""
    folder = tmp_path / "T"
    folder.mkdir()
    write_csv(samples, folder / f"{NFC}.csv")
    write_csv(samples, folder / f"{NFD}.csv", rows=40)
    write_mov(folder / f"{NFC}.mov", tone(440))
    with pytest.raises(InputError, match=TWINS):
        read_take_folder(folder)


def test_a_csv_named_alone_beside_its_twin_is_not_read_without_its_take_json(samples, tmp_path):
    """A take folder's CSV named alone while its NFD twin sits beside it: not read as a CSV of no take
    (its take.json, take number and frame_log.csv dropped in silence), but an error naming both."""
    folder = tmp_path / "T"
    folder.mkdir()
    write_csv(samples, folder / f"{NFC}.csv")
    write_mov(folder / f"{NFC}.mov", tone(440))
    (folder / "take.json").write_text(
        f'{{"slate": "Café", "take": 3, "identifier": "{NFC}"}}', encoding="utf-8"
    )
    assert read_take_folder(folder, csv=folder / f"{NFC}.csv").meta.take_number == 3
    write_csv(samples, folder / f"{NFD}.csv", rows=40)
    with pytest.raises(InputError, match=TWINS):
        read_take_folder(folder, csv=folder / f"{NFC}.csv")
    proc = run_here("capture", "import", folder / f"{NFC}.csv", "-o", tmp_path / "takes")
    assert proc.returncode != 0 and TWINS in proc.stderr and "Traceback" not in proc.stderr, proc.stderr


# -- names equal only in NFKC are two names -----------------------------------------------------------
def test_names_equal_only_in_nfkc_are_not_merged(samples, tmp_path):
    """``ﬁle_3`` (a ligature) is not ``file_3``, nor ``Take_３`` (full-width) ``Take_3``: the take named
    ``file_3`` reads ``FILE_3.csv`` (its name in another case), not the ligature's."""
    folder = tmp_path / "T"
    folder.mkdir()
    write_csv(samples, folder / "\ufb01le_3.csv")
    write_csv(samples, folder / "FILE_3.csv", rows=40)
    write_mov(folder / "clip.mov", tone(440))
    (folder / "take.json").write_text('{"identifier": "file_3"}', encoding="utf-8")
    assert read_take_folder(folder).values.shape[0] == 40

    flat = tmp_path / "flat"
    flat.mkdir()
    write_csv(samples, flat / "Take_\uff13.csv")
    write_mov(flat / "Take_3.mov", tone(440))
    write_csv(samples, flat / "B.csv")
    write_mov(flat / "B.mov", tone(660))
    assert takes_side_by_side(flat) == []


def test_an_archive_member_named_with_a_ligature_is_not_another(samples, tmp_path, unpack_tmp):
    """An archive holding ``file_3.csv`` holds no ``ﬁle_3.csv`` (a name typed in another case still finds
    its member, as macOS's file system would)."""
    write_csv(samples, tmp_path / "FILE_3.csv", rows=40)
    archive = tmp_path / "a.zip"
    with zipfile.ZipFile(archive, "w") as z:
        z.write(tmp_path / "FILE_3.csv", "file_3.csv")
    with archives_unpacked(), pytest.raises(InputError, match="holds no \ufb01le_3.csv"):
        read_input(archive / "\ufb01le_3.csv", "one")
    with archives_unpacked():
        assert read_input(archive / "FILE_3.csv", "one")[0].values.shape[0] == 40  # case: as on a Mac
    assert left_in(unpack_tmp) == []


# -- the zipped take shows as the folder unzipped --------------------------------------------------
class _FinderInfo(zipfile.ZipInfo):
    """A member named as Archive Utility writes names: UTF-8 bytes, the UTF-8 flag (bit 11) not set."""

    def _encodeFilenameFlags(self):  # noqa: N802 (zipfile's own name)
        return self.filename.encode("utf-8"), self.flag_bits & ~0x800


def _finder_zip(folder: Path, archive: Path) -> Path:
    """``folder`` zipped as macOS's Archive Utility does: names decomposed (NFD), UTF-8 without the flag
    (zipfile then reads them as code page 437), and ``__MACOSX/._X`` AppleDouble members."""
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as z:
        for p in sorted(folder.iterdir()):
            for name, data in ((p.name, p.read_bytes()), (f"__MACOSX/._{p.name}", b"\x00\x05\x16\x07")):
                info = _FinderInfo(unicodedata.normalize("NFD", f"{folder.name}/{name}"))
                if name.startswith("__MACOSX"):
                    info.filename = unicodedata.normalize("NFD", f"__MACOSX/{folder.name}/._{p.name}")
                info.compress_type = zipfile.ZIP_DEFLATED
                z.writestr(info, data)
    assert not any(i.flag_bits & 0x800 for i in zipfile.ZipFile(archive).infolist())
    return archive


def _case(kind: str, folder: Path, samples: Path) -> list[str]:
    """Write the take of ``kind`` in ``folder``; the CSVs to name in it."""
    csv = folder / f"{NFC}.csv"
    write_csv(samples, csv)
    if kind == "damaged_mov":
        (folder / f"{NFC}.mov").write_bytes(b"\0" * 4000)
    elif kind == "icloud_mov":
        (folder / f".{NFC}.mov.icloud").write_bytes(b"bplist00")
    elif kind in ("silent_mov", "two_movs"):
        write_mov(folder / f"{NFD}.mov", None)
    if kind == "two_movs":
        write_mov(folder / "B-roll.mov", tone(440))
    if kind == "wav_only":
        (folder / "take.json").write_text("{}")
    write_wav(folder / f"{NFD}.wav", tone(660, seconds=1.0))
    return [csv.name]


@pytest.mark.parametrize("kind", ["damaged_mov", "icloud_mov", "silent_mov", "two_movs", "wav_only"])
@pytest.mark.parametrize("finder", [False, True], ids=["zip", "finder_zip"])
def test_a_zipped_take_shows_as_the_folder_unzipped(samples, tmp_path, unpack_tmp, kind, finder):
    folder = tmp_path / "src" / "T"
    folder.mkdir(parents=True)
    csvs = _case(kind, folder, samples)
    archive = (
        _finder_zip(folder, tmp_path / "t.zip") if finder else zip_folder(folder, tmp_path / "t.zip", "T")
    )
    for named in (archive, archive / "T", *(archive / "T" / c for c in csvs)):
        want = view(folder.parent / named.relative_to(archive))
        with archives_unpacked():
            got = view(named)
        assert got == want, (kind, named)
    assert left_in(unpack_tmp) == []
    if kind in ("silent_mov", "wav_only"):  # read from the .wav, as from the folder
        assert want[0] == f"{NFD}.wav" and np.frombuffer(want[2], np.int16).size == 16000


# -- a stop while the .wav is unpacked ----------------------------------------------------------------
_STOP_IN_SECOND_UNPACK = """
import os, signal, sys
from pathlib import Path
import capture.take_archive as take_archive
from viewer.inputs import archives_unpacked, read_input
from viewer.output import stopped_by_signals

real = take_archive._unpack_member

def unpack_member(zf, info, target, archive):  # the stop comes while the .wav is being written
    if target.suffix == ".wav":
        os.kill(os.getpid(), int(sys.argv[2]))
    return real(zf, info, target, archive)

take_archive._unpack_member = unpack_member
try:
    with stopped_by_signals(), archives_unpacked():
        read_input(Path(sys.argv[1]), "one")
    sys.exit(3)  # not stopped
except KeyboardInterrupt:
    sys.exit(130)
"""


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_while_the_wav_is_unpacked_leaves_nothing(samples, tmp_path, sig):
    folder = tmp_path / "T"
    folder.mkdir()
    write_csv(samples, folder / "T.csv")
    write_mov(folder / "T.mov", None)
    write_wav(folder / "T.wav", tone(660))
    archive = zip_folder(folder, tmp_path / "t.zip", inside="T")
    unpack_tmp = tmp_path / "tmp"
    unpack_tmp.mkdir()
    proc = subprocess.run(
        [sys.executable, "-c", _STOP_IN_SECOND_UNPACK, str(archive / "T"), str(int(sig))],
        cwd=ROOT,
        env=os.environ | {"TMPDIR": str(unpack_tmp), "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode in (130, 143) and "Traceback" not in proc.stderr, proc.stderr
    assert left_in(unpack_tmp) == [] and list(unpack_tmp.iterdir()) == []


def test_audio_files_of_one_name_spelled_two_ways_beside_a_csv_are_told_apart(tmp_path):
    """``audio_beside`` takes neither of two .wav files named alike but for their Unicode spelling, and
    its warning says how they differ (it listed "Café_3.wav, Café_3.wav")."""
    from capture.importer import audio_beside

    nfd = unicodedata.normalize("NFD", NFC)
    (tmp_path / f"{NFC}.csv").write_text("Timecode,BlendshapeCount,JawOpen\n")
    for name in (NFC, nfd):
        (tmp_path / f"{name}.wav").write_bytes(b"")
    audio, why = audio_beside(tmp_path / f"{NFC}.csv")
    assert audio is None and "composed, NFC" in why and "decomposed, NFD" in why, why
