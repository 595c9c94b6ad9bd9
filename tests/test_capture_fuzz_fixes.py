"""Inputs a fuzzer found to crash or hang the capture readers: each is now a one-line ``InputError``
naming the file (and line), or a recorded repair."""

from __future__ import annotations

import json
import socket
import struct
import subprocess
import sys
import threading

import numpy as np
import pytest

from capture import Audio, InputError, osc_remote, read_take_folder, write_reference_mov
from capture.channels import CSV_ORDER
from capture.csv_take import read_csv_rows, read_livelink_csv
from capture.mov import probe_mov, read_mov_audio
from capture.take import write_take
from capture.take_folder import read_frame_log
from capture.textgrid import read_textgrid
from capture.timecode import Timecode
from tests.conftest import ROOT, run_here
from tests.test_take_folder import make_take_folder

TC = "19:18:11:20.500"


# -- 1. frame_log.csv rows ---------------------------------------------------------------------------------
def test_frame_log_row_with_a_bad_index_is_skipped_whole(tmp_path):
    log = tmp_path / "frame_log.csv"
    log.write_text(f"V,0,0,60,{TC},0\nV,x,1,60,19:18:11:21.500,0\nA,0,0,48000,19:18:11:19.000\n")
    repairs: list = []
    read = read_frame_log(log, repairs)
    assert read.kinds == ["V", "A"] and read.indices.tolist() == [0, 0] and len(read.timecodes) == 2
    assert read.timecodes[read.first("A")] == "19:18:11:19.000"
    assert [(r["line"], r["kind"]) for r in repairs] == [(2, "frame_log_row")]


def test_take_folder_with_a_bad_frame_log_row_imports(tmp_path, samples):
    bad_row = f"V,0,0,60,{TC},0\nV,x,1,60,19:18:11:21.500,1\nA,0,0,48000,19:18:11:19.000\n"
    take = read_take_folder(make_take_folder(tmp_path, samples, frame_log=bad_row))
    assert take.meta.audio.start_source == "frame_log_audio"
    assert any(r["kind"] == "frame_log_row" and r["line"] == 2 for r in take.meta.repairs)


def test_frame_log_time_beyond_a_float_is_skipped(tmp_path):
    log = tmp_path / "frame_log.csv"
    log.write_text(f"V,0,{'1' * 400},1,{TC},0\nV,1,{'1' * 400},{'9' * 400},{TC},0\nV,2,2,60,{TC},0\n")
    repairs: list = []
    read = read_frame_log(log, repairs)
    assert read.kinds == ["V", "V"] and read.times_s.tolist() == pytest.approx([0.11111111, 2 / 60])
    assert [(r["line"], r["kind"]) for r in repairs] == [(1, "frame_log_row")]
    assert "out of range" in repairs[0]["message"]


# -- 6. lines end at \n, \r\n or \r only -------------------------------------------------------------------
def test_frame_log_lines_are_not_split_at_form_feeds(tmp_path):
    log = tmp_path / "frame_log.csv"
    log.write_text(f"V,0,0,60,{TC},0\x0c\nV,1,1,60,{TC},0\x1e\nV,x,2,60,{TC},0\n")
    repairs: list = []
    assert read_frame_log(log, repairs).kinds == ["V", "V"]
    assert [r["line"] for r in repairs] == [3]


def _csv(rows: list[str]) -> str:
    return "Timecode,BlendShapeCount," + ",".join(CSV_ORDER) + "\n" + "".join(r + "\n" for r in rows)


def _row(i: int, value: str = "0.1000000000", tc: str | None = None) -> str:
    tc = tc or Timecode.from_seconds(45000 + i / 60).format()
    return f"{tc},61," + ",".join([value] * len(CSV_ORDER))


def test_csv_lines_are_not_split_at_form_feeds(tmp_path):
    rows = [_row(i) for i in range(8)]
    rows[1] += "\x0c"  # a form feed ending line 3
    rows[2] = rows[2].replace(",0.1000000000", ",0.1\x1c000000000", 1)  # a file separator inside a cell
    rows[5] = _row(5, "abc")  # line 7
    path = tmp_path / "take.csv"
    path.write_text(_csv(rows))
    repairs = read_csv_rows(path).repairs
    assert all(r["kind"] != "wrong_fields" for r in repairs)
    assert (7, "bad_value") in [(r["line"], r["kind"]) for r in repairs]
    with pytest.raises(InputError, match=r"take\.csv:\d+:"):
        read_csv_rows(path, strict=True)
    assert read_csv_rows(path).seconds_of_day.size == 8


def test_csv_lone_carriage_returns_end_lines(tmp_path):
    path = tmp_path / "take.csv"
    path.write_bytes(_csv([_row(i) for i in range(4)] + [_row(4, "abc")]).replace("\n", "\r").encode())
    rows = read_csv_rows(path)
    assert rows.seconds_of_day.size == 5 and [(r["line"], r["kind"]) for r in rows.repairs] == [
        (6, "bad_value")
    ]


# -- 7. only ASCII digits ----------------------------------------------------------------------------------
def test_non_ascii_digits_are_no_timecode_or_value(tmp_path):
    with pytest.raises(ValueError):
        Timecode.parse("\u0661\u0662:28:37:46.758")
    rows = [_row(i) for i in range(6)]
    rows[2] = _row(2, tc="\u0661\u0662:30:00:02.000")  # line 4: Arabic-Indic 12
    rows[4] = rows[4].replace(",0.1000000000", ",\u0661", 1)  # line 6: Arabic-Indic 1
    path = tmp_path / "take.csv"
    path.write_text(_csv(rows))
    read = read_csv_rows(path)
    assert [(r["line"], r["kind"]) for r in read.repairs] == [(4, "bad_timecode"), (6, "bad_value")]
    assert read.seconds_of_day.size == 5 and np.isnan(read.values[3, 0])
    with pytest.raises(InputError, match=r"take\.csv:4:.*strict"):
        read_csv_rows(path, strict=True)


# -- 2. damaged .mov ---------------------------------------------------------------------------------------
def _damaged_mov(tmp_path, old: bytes, new: bytes):
    audio = Audio(np.zeros((4800, 1), np.int16), 48000, "PCM_16")
    path = write_reference_mov(tmp_path / "take.mov", 30, 10, audio, timecode="01:00:00:00")
    data = path.read_bytes()
    assert data.count(old) == 1
    path.write_bytes(data.replace(old, new))
    return path


def test_mov_with_a_video_codec_ffmpeg_does_not_know(tmp_path):
    path = _damaged_mov(tmp_path, b"jpeg", b"\0\0\0\0")
    info = probe_mov(path)
    assert (info.width, info.height, info.timecode, info.audio_tracks) == (None, None, "01:00:00:00", 1)
    assert read_mov_audio(path).samples.shape == (4800, 1)


def test_mov_with_metadata_that_is_not_utf8(tmp_path):
    path = _damaged_mov(tmp_path, b"\x0cSoundHandler", b"\x0c\xb2oundHandler")
    with pytest.raises(InputError, match=r"take\.mov: video could not be opened.*not UTF-8"):
        probe_mov(path)
    with pytest.raises(InputError, match=r"take\.mov: "):
        read_mov_audio(path)


def test_take_folder_with_a_damaged_mov_is_a_one_line_error(tmp_path, samples):
    folder = make_take_folder(tmp_path, samples)
    mov = folder / "MySlate_166_iPhone.mov"
    mov.write_bytes(mov.read_bytes().replace(b"\x0cSoundHandler", b"\x0c\xb2oundHandler"))
    proc = run_here("capture", "import", "-o", tmp_path / "out", folder)
    assert proc.returncode == 1
    assert "MySlate_166_iPhone.mov" in proc.stderr and "Traceback" not in proc.stderr


# -- 3. OSC bundles ----------------------------------------------------------------------------------------
def _bundle(*elements: bytes) -> bytes:
    return b"#bundle\0" + bytes(8) + b"".join(struct.pack(">i", len(e)) + e for e in elements)


MESSAGE = b"/Battery\0\0\0\0,f\0\0" + struct.pack(">f", 0.5)


@pytest.mark.parametrize(
    "dgram",
    [
        b"#bundle\0" + bytes(8) + struct.pack(">i", -4),  # python-osc loops forever on this
        b"#bundle\0" + bytes(8) + struct.pack(">i", 0),
        _bundle(MESSAGE) + b"\0\0",  # stray bytes
        b"#bundle\0" + bytes(8) + struct.pack(">i", 6) + b"/a\0\0,\0",  # not a multiple of 4
        b"#bundle\0" + bytes(8) + struct.pack(">i", 64) + MESSAGE,  # past the end
        b"#bundle\0" + bytes(4),  # cut in the time tag
    ],
)
def test_malformed_bundles_are_refused(dgram):
    with pytest.raises(ValueError):
        osc_remote.bundled_messages(dgram)


def test_bundles_nest_to_a_bounded_depth():
    nested = MESSAGE
    for _ in range(osc_remote.MAX_BUNDLE_DEPTH):
        nested = _bundle(nested)
    assert osc_remote.bundled_messages(nested) == [MESSAGE]
    assert osc_remote.bundled_messages(_bundle(MESSAGE, _bundle(MESSAGE))) == [MESSAGE, MESSAGE]
    with pytest.raises(ValueError, match="nested"):
        osc_remote.bundled_messages(_bundle(nested))


def test_hostile_phone_times_out_as_asked():
    """A 'phone' answering every command with a bundle of element size -4: ``remote`` ignores it, warns
    once and gives up after its --timeout (it used to loop forever inside python-osc)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(10)
    evil = b"#bundle\0" + bytes(8) + struct.pack(">i", -4)

    def serve():
        try:
            for _ in range(3):
                _, addr = sock.recvfrom(65536)
                sock.sendto(evil, addr)
                sock.sendto(evil, addr)
        except OSError:
            return

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        proc = subprocess.run(
            [
                sys.executable,
                "-m",
                "capture",
                "remote",
                "--timeout",
                "1",
                f"127.0.0.1:{sock.getsockname()[1]}",
            ]
            + ["battery"],
            capture_output=True,
            text=True,
            cwd=ROOT,
            timeout=30,
        )
    finally:
        sock.close()
    assert proc.returncode == 1
    assert proc.stderr.count("warning") == 1 and "bundle element size -4" in proc.stderr
    assert "within 1 s" in proc.stderr and "2 datagram(s) that were not OSC were ignored" in proc.stderr
    assert len(proc.stderr) < 2000


# -- 4. TextGrid -------------------------------------------------------------------------------------------
HEAD = 'File type = "ooTextFile"\nObject class = "TextGrid"\n\n0\n1\n<exists>\n'


@pytest.mark.parametrize(
    "body, line, match",
    [
        ("1e999\n", 7, "number of tiers is out of range"),
        ('1\n"IntervalTier"\n"phones"\n0\n1\n1e999\n0\n1\n"a"\n', 12, "item count is out of range"),
        ('1\n"IntervalTier"\n"phones"\n0\n1\n-1\n', 12, "item count -1 is not a count"),
        ('1\n"IntervalTier"\n"phones"\n0\n1\n2.5\n0\n1\n"a"\n', 12, "item count 2.5 is not a count"),
        ("1000000000000000\n", 7, "number of tiers 1e\\+15 is not a count"),
        ('1\n"IntervalTier"\n"phones"\n0\n1e999\n', 11, "tier xmax is out of range"),
    ],
)
def test_textgrid_numbers_out_of_range(tmp_path, body, line, match):
    path = tmp_path / "bad.TextGrid"
    path.write_text(HEAD + body)
    with pytest.raises(InputError, match=rf"bad\.TextGrid:{line}: malformed TextGrid: {match}"):
        read_textgrid(path)


@pytest.mark.parametrize(
    "tail, reason",
    [(b"\x00", "truncated data"), (b"\x00\xd8A\x00", "illegal UTF-16 surrogate")],
)
def test_textgrid_that_is_not_utf16_after_its_bom(tmp_path, tail, reason):
    path = tmp_path / "bad.TextGrid"
    path.write_bytes((HEAD + '1\n"IntervalTier"\n"a"\n').encode("utf-16") + tail)
    with pytest.raises(InputError, match=rf"bad\.TextGrid:10: TextGrid is not UTF-16 text.*{reason}"):
        read_textgrid(path)


# -- 5. export-csv of a take folder whose meta.json was edited ---------------------------------------------
@pytest.mark.parametrize(
    "field, value, shown",
    [
        ("csv.count_name", True, "meta.json csv.count_name must be"),
        ("csv.count_name", "Frames,Oops", "meta.json csv.count_name must be"),
        ("csv.start_seconds_of_day", "../../x", "meta.json csv.start_seconds_of_day must be"),
        ("csv.start_seconds_of_day", {}, "meta.json csv.start_seconds_of_day must be"),
        ("start_timecode", "x", "meta.json start_timecode must be"),
    ],
)
def test_export_csv_refuses_a_bad_meta_json_field(tmp_path, samples, field, value, shown):
    take = read_livelink_csv(samples / "livelinkface/neurosync_MySlate_166/MySlate_166_iPhone_cal.csv")
    folder = write_take(take, tmp_path / "take")
    meta_path = folder / "meta.json"
    meta = json.loads(meta_path.read_text())
    if field == "start_timecode":
        del meta["csv"]["start_seconds_of_day"]
        meta["start_timecode"] = value
    else:
        meta["csv"][field.split(".")[1]] = value
    meta_path.write_text(json.dumps(meta))
    proc = run_here("capture", "export-csv", folder, "-o", tmp_path / "out.csv")
    assert proc.returncode == 1 and shown in proc.stderr
    assert proc.stderr.count("\n") == 1 and not (tmp_path / "out.csv").exists()


def test_export_csv_keeps_the_source_spelling_in_any_case(tmp_path, samples):
    take = read_livelink_csv(samples / "livelinkface/neurosync_MySlate_166/MySlate_166_iPhone_cal.csv")
    take.meta.csv["count_name"] = "blendShapeCount"
    folder = write_take(take, tmp_path / "take")
    proc = run_here("capture", "export-csv", folder, "-o", tmp_path / "out.csv")
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "out.csv").read_text().startswith("Timecode,blendShapeCount,")
