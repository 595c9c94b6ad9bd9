"""Paired speech + animation data as other generators write it (a probe's findings): JSON names files,
time columns under other names, frame numbers counting from 1, compressed audio that keeps its encoder
delay, weights on a 0..100 scale, Audio2Face-3D's emotion CSVs, `_bsweight` exports, pandas' `Unnamed: 0`
index, `.npz` matrices, two clock columns and a clock that starts late."""

from __future__ import annotations

import csv
import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from conftest import run_here
from test_take_folder import encode

from capture import InputError, read_paired, read_take
from capture.audio_io import read_audio
from capture.importer import audio_beside
from capture.paired import read_names

NS = "paired/neurosync-trainer-lite-testset"


@pytest.fixture(scope="module")
def ns(samples):
    """The NeuroSync take at 30 fps (every other row): its 52 ARKit names and their values."""
    with open(samples / NS / "testset.csv", newline="") as f:
        header, *rows = csv.reader(f)
    names = [n[0].lower() + n[1:] for n in header[2:54]]
    return names, np.array([r[2:54] for r in rows[::2]], dtype=np.float64)


@pytest.fixture
def wav(tmp_path):
    """Three seconds of silence at 16 kHz."""
    path = tmp_path / "a.wav"
    sf.write(path, np.zeros(48000, np.int16), 16000, subtype="PCM_16")
    return path


def write_csv(path: Path, header: list[str], first: list[str], values: np.ndarray) -> Path:
    """A CSV of a ``first`` column of cells (times, frames, an index) and the values, under ``header``."""
    lines = [",".join(header)] + [
        f"{c}," + ",".join(f"{x:.6f}" for x in row) for c, row in zip(first, values)
    ]
    path.write_text("\n".join(lines) + "\n")
    return path


def kinds(take) -> list[str]:
    return [r["kind"] for r in take.meta.repairs]


def import_cli(tmp_path: Path, *args):
    proc = run_here("capture", "import", *args, "-o", tmp_path / "takes", "--json")
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc, [json.loads(line) for line in proc.stdout.splitlines()]


RAMP = np.linspace(0, 0.9, 60)[:, None] * np.ones((1, 2))  # 60 frames of two channels


# 1. a names file holding a JSON list


@pytest.mark.parametrize("indent", [None, 2])
def test_a_json_names_file_is_a_list_of_names(tmp_path, ns, wav, indent):
    names, values = ns
    np.save(tmp_path / "w.npy", values)
    (tmp_path / "names.json").write_text(json.dumps(names, indent=indent))
    take = read_paired(wav, tmp_path / "w.npy", 30, tmp_path / "names.json")
    assert take.meta.channels == names  # not '["eyeBlinkLeft"' ... 'tongueOut]'
    for held in ({"names": names}, {"facsNames": names, "joints": ["jaw"]}):
        (tmp_path / "held.json").write_text(json.dumps(held))
        assert read_names(tmp_path / "held.json") == names


@pytest.mark.parametrize(
    "text",
    ['{"a": ["x"], "b": ["y"]}', "[1, 2, 3]", '"jawOpen"', '[["jawOpen"]]', "jawOpen\nmouthClose\n"],
)
def test_a_json_names_file_of_anything_else_is_a_one_line_error(tmp_path, text):
    (tmp_path / "names.json").write_text(text)
    with pytest.raises(
        InputError, match=r"names\.json: (a \.json names file must hold a list|not a JSON file)"
    ):
        read_names(tmp_path / "names.json")


def test_a_text_names_file_holding_a_json_list_is_an_error(tmp_path, ns):
    names, _ = ns
    for indent in (None, 2):
        (tmp_path / "names.txt").write_text(json.dumps(names, indent=indent))
        with pytest.raises(InputError, match=r"names\.txt:1: .*brackets or quotes: a JSON list of names"):
            read_names(tmp_path / "names.txt")


# 2. time columns under other names; a column that steps like a clock is no channel


@pytest.mark.parametrize(
    ("column", "scale", "unit_note"),
    [
        ("frame_timestamp_ms", 1000, False),
        ("timecode_ms", 1000, False),
        ("elapsed_s", 1, False),
        ("pts_time", 1, False),
        ("pts_time", 1000, True),  # no unit in the name: the step says milliseconds
        ("captureTimeUs", 1e6, False),
    ],
)
@pytest.mark.parametrize("fps", [None, 30.0])
def test_time_columns_are_recognised_by_their_words(tmp_path, wav, column, scale, unit_note, fps):
    kept = [i for i in range(60) if not 20 <= i < 26]  # 6 dropped frames
    first = [f"{i / 30 * scale:.3f}" for i in kept]
    m = write_csv(tmp_path / "m.csv", [column, "jawOpen", "mouthClose"], first, RAMP[kept])
    take = read_paired(wav, m, fps)
    assert take.meta.channels == ["jawOpen", "mouthClose"] and take.meta.fps == 30
    assert take.time.size == 60 and take.time[30] == pytest.approx(1.0, abs=1e-3)  # after the gap
    assert take.values[30, 0] == pytest.approx(RAMP[30, 0], abs=1e-6)
    assert "dropped_frames" in kinds(take) and ("time_unit" in kinds(take)) == unit_note


CLOCKS = [
    ([f"{i * 1000 / 30:.0f}" for i in range(60)], "milliseconds at 30"),
    ([str(i) for i in range(60)], "frame numbers"),
]


@pytest.mark.parametrize(("first", "what"), CLOCKS)
def test_a_first_column_that_steps_like_a_clock_is_no_channel(tmp_path, wav, first, what):
    m = write_csv(tmp_path / "m.csv", ["frame_ts", "jawOpen", "mouthClose"], first, RAMP)
    for fps in (30.0, None):
        with pytest.raises(
            InputError, match=f"column 'frame_ts' increases from row to row like a clock \\({what}"
        ):
            read_paired(wav, m, fps)
    # a ramp of a face channel is a channel, and so is a short or small one
    m = write_csv(tmp_path / "c.csv", ["jawOpen", "a", "b"], [f"{i / 30:.6f}" for i in range(60)], RAMP)
    assert read_paired(wav, m, 30).meta.channels == ["jawOpen", "a", "b"]


# 3. frame numbers counting from 1


def test_frame_numbers_from_1_place_frame_1_at_the_audios_start(tmp_path, wav):
    m = write_csv(
        tmp_path / "m.csv", ["Frame", "jawOpen", "mouthClose"], [str(i + 1) for i in range(60)], RAMP
    )
    take = read_paired(wav, m, 30)
    assert take.time[0] == 0 and take.time[59] == pytest.approx(59 / 30)
    assert "frame_numbers_from_1" in kinds(take)
    assert read_paired(wav, m, 30, first_frame=0).time[0] == pytest.approx(1 / 30)  # as before
    proc, out = import_cli(tmp_path, "--matrix", m, "--audio", wav, "--fps", "30", "--first-frame", "11")
    assert proc.returncode == 0 and read_take(out[0]["path"]).time[10] == 0
    proc, out = import_cli(tmp_path, "--matrix", m, "--audio", wav, "--fps", "30")
    assert "warning" in proc.stderr and "starts at 1: read as counting from 1" in proc.stderr
    plain = write_csv(tmp_path / "p.csv", ["a", "b", "c"], ["0.1"] * 60, RAMP)
    with pytest.raises(InputError, match="--first-frame applies to a frame-number column"):
        read_paired(wav, plain, 30, first_frame=1)


# 4. compressed audio that does not record its encoder delay


@pytest.mark.parametrize(
    ("name", "codec", "fmt", "options", "unknown"),
    [
        ("raw.aac", "aac", "adts", None, True),
        ("bare.mp3", "libmp3lame", "mp3", {"write_xing": "0"}, True),
        ("voice.m4a", "aac", "mp4", None, False),  # the edit list records it: FFmpeg drops it
        ("lame.mp3", "libmp3lame", "mp3", None, False),  # the LAME tag records it: mpg123 drops it
    ],
)
def test_audio_that_does_not_record_its_encoder_delay_is_noted(tmp_path, name, codec, fmt, options, unknown):
    tone = (0.3 * 32767 * np.sin(2 * np.pi * 440 * np.arange(44100) / 44100)).astype(np.int16)[:, None]
    path = encode(tmp_path / name, codec, tone, 44100, fmt, options)  # one second of a tone
    repairs = []
    audio = read_audio(path, repairs)
    assert audio.frames > 40000
    assert [r["kind"] for r in repairs] == (["encoder_delay_unknown"] if unknown else [])
    if unknown:
        assert repairs[0]["message"].startswith(f"{name}: ") and "up to ~50 ms late" in repairs[0]["message"]


# 5. weights on a 0..100 scale


def test_weights_on_a_0_100_scale_are_noted_and_value_scale_fixes_them(tmp_path, ns, wav):
    names, values = ns
    (tmp_path / "names.txt").write_text("\n".join(names) + "\n")
    np.save(tmp_path / "pct.npy", values * 100)
    take = read_paired(wav, tmp_path / "pct.npy", 30, tmp_path / "names.txt")
    assert "percent_scale" in kinds(take) and np.nanmax(take.values) > 50  # kept as it is
    args = ["--audio", wav, "--names", tmp_path / "names.txt", "--fps", "30"]
    proc, out = import_cli(tmp_path, "--matrix", tmp_path / "pct.npy", *args)
    assert proc.returncode == 0 and "--value-scale 0.01" in proc.stderr
    scaled = read_paired(wav, tmp_path / "pct.npy", 30, tmp_path / "names.txt", value_scale=0.01)
    assert "percent_scale" not in kinds(scaled) and "value_scale" in kinds(scaled)
    np.testing.assert_allclose(scaled.values, values, atol=1e-5)
    # 0..1 weights overshooting 1, and a rig with head angles in degrees, are not a 0..100 scale
    np.save(tmp_path / "over.npy", values * 1.3)
    assert "percent_scale" not in kinds(read_paired(wav, tmp_path / "over.npy", 30, tmp_path / "names.txt"))
    degrees = values.copy()
    degrees[:, :3] = 30 * np.sin(np.arange(len(values)))[:, None]
    np.save(tmp_path / "deg.npy", degrees)
    assert "percent_scale" not in kinds(read_paired(wav, tmp_path / "deg.npy", 30, tmp_path / "names.txt"))


# 6. Audio2Face-3D's emotion CSVs beside its animation_frames.csv


EMOTIONS = [
    "amazement",
    "anger",
    "cheekiness",
    "disgust",
    "fear",
    "grief",
    "joy",
    "outofbreath",
    "pain",
    "sadness",
]


def test_emotion_csvs_are_no_face_takes(tmp_path, wav):
    folder = tmp_path / "20251120_101500"
    folder.mkdir()
    wav.rename(folder / "out.wav")
    index = [str(i) for i in range(60)]
    write_csv(folder / "animation_frames.csv", ["", "timeCode", "blendShapes.JawOpen"],
              index, np.column_stack([np.arange(60) / 30, RAMP[:, 0]]))  # fmt: skip
    header = ["", "time_code", *(f"emotion_values.{e}" for e in EMOTIONS)]
    timed = np.column_stack([np.arange(60) / 30, np.full((60, 10), 0.1)])
    for name in ("a2e_emotion_output", "a2f_smoothed_emotion_output"):
        write_csv(folder / f"{name}.csv", header, index, timed)
    write_csv(
        folder / "a2f_input_emotions.csv", header, ["0", "1"], timed[[0, 30]]
    )  # two keyframes, 0 and 1 s
    proc, out = import_cli(tmp_path, tmp_path, "--pair-audio")
    assert proc.returncode == 0 and [t["id"] for t in out] == ["animation_frames"]
    for name in ("a2e_emotion_output", "a2f_smoothed_emotion_output", "a2f_input_emotions"):
        assert f"{name}.csv: holds emotion weights (emotion_values.amazement" in proc.stderr
    proc, _ = import_cli(tmp_path, folder / "a2f_input_emotions.csv", "--audio", folder / "out.wav")
    assert proc.returncode == 1 and len(proc.stderr.strip().splitlines()) == 1
    assert "a2f_input_emotions.csv: holds emotion weights" in proc.stderr


# 7. Audio2Face's _bsweight exports go with the audio of their stem


def test_a_bsweight_export_pairs_with_the_audio_of_its_stem(tmp_path):
    for name in ("line01_bsweight.json", "line01.wav", "line02_bsweight.json", "line02.wav"):
        (tmp_path / name).write_text("")
    assert audio_beside(tmp_path / "line01_bsweight.json") == (tmp_path / "line01.wav", None)
    assert audio_beside(tmp_path / "line02_bsweight.json") == (tmp_path / "line02.wav", None)
    (tmp_path / "line02.wav").unlink()  # the only audio left is line01's
    assert audio_beside(tmp_path / "line02_bsweight.json")[0] is None


# 8. pandas' Unnamed: 0 index


def test_a_pandas_unnamed_index_is_left_out(tmp_path, wav):
    m = write_csv(
        tmp_path / "m.csv", ["Unnamed: 0", "jawOpen", "mouthClose"], [str(i) for i in range(60)], RAMP
    )
    take = read_paired(wav, m, 30)
    assert take.meta.channels == ["jawOpen", "mouthClose"]
    m = write_csv(tmp_path / "n.csv", ["Unnamed: 0", "jawOpen", "mouthClose"], ["0.5"] * 60, RAMP)
    with pytest.raises(
        InputError, match=r"n\.csv:1: the first column, 'Unnamed: 0' .* does not count the rows"
    ):
        read_paired(wav, m, 30)


# 9. .npz matrices, two clock columns, a clock that starts late


def test_an_npz_matrix_is_read(tmp_path, wav):
    np.savez(tmp_path / "one.npz", RAMP)  # a single unnamed array; its names given apart
    (tmp_path / "names.txt").write_text("jawOpen\nrig_lip\n")
    assert read_paired(wav, tmp_path / "one.npz", 30, tmp_path / "names.txt").values.shape == (60, 2)
    np.savez(
        tmp_path / "named.npz", weights=RAMP, names=np.array(["jawOpen", "rig_lip"]), fps=30.0, other=RAMP
    )
    take = read_paired(wav, tmp_path / "named.npz", None)
    assert take.meta.channels == ["jawOpen", "rig_lip"] and take.meta.fps == 30
    np.savez(tmp_path / "two.npz", a=RAMP, b=RAMP)
    with pytest.raises(InputError, match=r"two\.npz: a \.npz needs one 2-D frames x channels array"):
        read_paired(wav, tmp_path / "two.npz", 30)


def test_a_frame_column_beside_a_time_column_is_left_out(tmp_path, wav):
    lines = ["frame,timestamp_ms,jawOpen"] + [f"{i},{i * 1000 / 30:.0f},{RAMP[i, 0]:.6f}" for i in range(60)]
    (tmp_path / "m.csv").write_text("\n".join(lines) + "\n")
    take = read_paired(wav, tmp_path / "m.csv", None)
    assert take.meta.channels == ["jawOpen"] and take.meta.fps == 30 and "frame_column" in kinds(take)
    (tmp_path / "t.csv").write_text("time,timestamp_ms,jawOpen\n0,0,0.1\n")
    with pytest.raises(InputError, match="several time columns: time, timestamp_ms: keep one and delete"):
        read_paired(wav, tmp_path / "t.csv", 30)


def test_a_clock_that_starts_late_is_named_as_the_cause_of_a_length_mismatch(tmp_path):
    sf.write(tmp_path / "a.wav", np.zeros(16000 * 2, np.int16), 16000, subtype="PCM_16")
    m = write_csv(tmp_path / "m.csv", ["timestamp_ms", "jawOpen", "mouthClose"],
                  [f"{1500 + i * 1000 / 30:.1f}" for i in range(60)], RAMP)  # fmt: skip
    [note] = [
        r for r in read_paired(tmp_path / "a.wav", m, None).meta.repairs if r["kind"] == "length_mismatch"
    ]
    assert "the time column starts at 1.500 s" in note["message"] and "--fps" not in note["message"]


# 10. a review's findings: damaged .npz files, rates they store, --variant and --first-frame in batches,
# hints of length mismatches, the 0..100 scale test, bracketed names, digits of other scripts


def npy_member(shape: tuple[int, ...]) -> bytes:
    """A .npy header declaring a float64 array of ``shape``, with no data after it."""
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f8", "fortran_order": False, "shape": shape})
    return buf.getvalue()


def npy_names(names: list[str]) -> bytes:
    """A .npy of an array of names."""
    buf = io.BytesIO()
    np.save(buf, np.array(names))
    return buf.getvalue()


def test_a_damaged_or_foreign_npz_is_a_one_line_error(tmp_path, wav):
    np.savez(tmp_path / "ok.npz", weights=RAMP, channel_names=np.array(["jawOpen", "rig_lip"]), frame_rate=30)
    take = read_paired(wav, tmp_path / "ok.npz", None)
    assert take.meta.channels == ["jawOpen", "rig_lip"] and take.meta.fps == 30
    raw = (tmp_path / "ok.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(InputError, match=r"cut\.npz: not a \.npz"):
        read_paired(wav, tmp_path / "cut.npz", 30)
    np.save(tmp_path / "x.npy", RAMP)
    (tmp_path / "x.npz").write_bytes((tmp_path / "x.npy").read_bytes())
    with pytest.raises(InputError, match=r"x\.npz: a \.npy array, not a \.npz archive"):
        read_paired(wav, tmp_path / "x.npz", 30)
    with zipfile.ZipFile(tmp_path / "readme.npz", "w") as z:  # a README beside the array is no array
        z.writestr("weights.npy", (tmp_path / "x.npy").read_bytes())
        z.writestr("names.npy", npy_names(["jawOpen", "rig_lip"]))
        z.writestr("README.txt", "exported by tool X")
    assert read_paired(wav, tmp_path / "readme.npz", 30).values.shape == (60, 2)


def test_an_npz_reads_only_the_arrays_it_uses(tmp_path, wav):
    buf = io.BytesIO()
    np.save(buf, RAMP)
    with zipfile.ZipFile(tmp_path / "extra.npz", "w") as z:  # an unused array, never read
        z.writestr("weights.npy", buf.getvalue())
        z.writestr("names.npy", npy_names(["jawOpen", "rig_lip"]))
        z.writestr("extra.npy", npy_member((10**9,)))
    assert read_paired(wav, tmp_path / "extra.npz", 30).values.shape == (60, 2)
    with zipfile.ZipFile(tmp_path / "huge.npz", "w") as z:  # its header gives its size before it is read
        z.writestr("weights.npy", npy_member((10**9, 2)))
    with pytest.raises(InputError, match=r"huge\.npz: array 'weights' holds 2000000000 values \(more than"):
        read_paired(wav, tmp_path / "huge.npz", 30)


@pytest.mark.parametrize("rate", [0.0, np.nan, 5000.0])
def test_a_rate_an_npz_stores_must_be_a_frame_rate(tmp_path, wav, rate):
    clock = np.column_stack([np.arange(60) / 30, RAMP[:, 0]])
    np.savez(tmp_path / "r.npz", weights=clock, names=np.array(["pts_time", "jawOpen"]), fps=rate)
    with pytest.raises(
        InputError,
        match=r"r\.npz: the frame rate must be in \[1, 1000\], not \w+ \(the rate the file gives\)",
    ):
        read_paired(wav, tmp_path / "r.npz", None)


def test_variant_leaves_generic_paired_csvs_alone(tmp_path, wav):
    folder = tmp_path / "in"
    folder.mkdir()
    sf.write(folder / "rig01.wav", np.zeros(32000, np.int16), 16000, subtype="PCM_16")
    write_csv(
        folder / "rig01.csv", ["time", "jawOpen", "rig_lip"], [f"{i / 30:.6f}" for i in range(60)], RAMP
    )
    proc, out = import_cli(tmp_path, folder, "--pair-audio", "--variant", "cal")
    assert proc.returncode == 0 and [Path(x["path"]).name for x in out] == ["rig01"], proc.stderr


def test_first_frame_in_a_batch_is_ignored_by_a_file_without_a_frame_column(tmp_path):
    folder = tmp_path / "in"
    folder.mkdir()
    for stem in ("line01", "line02"):
        sf.write(folder / f"{stem}.wav", np.zeros(32000, np.int16), 16000, subtype="PCM_16")
    export = {"exportFps": 30, "facsNames": ["jawOpen", "rig_lip"], "weightMat": RAMP.tolist()}
    (folder / "line01_bsweight.json").write_text(json.dumps(export))
    write_csv(folder / "line02.csv", ["frame", "jawOpen", "rig_lip"], [str(i + 5) for i in range(60)], RAMP)
    proc, out = import_cli(tmp_path, folder, "--pair-audio", "--fps", "30", "--first-frame", "5")
    assert proc.returncode == 0 and len(out) == 2, proc.stderr
    assert proc.stderr.count("--first-frame applies to a frame-number column") == 1
    assert "line01_bsweight.json: --first-frame applies" in proc.stderr and "ignored" in proc.stderr
    assert read_take(out[1]["path"]).time[0] == 0  # line02's frame 5 at the audio's start
    with pytest.raises(InputError, match="--first-frame applies to a frame-number column"):  # one file
        read_paired(folder / "line01.wav", folder / "line01_bsweight.json", None, first_frame=5)


def test_a_late_clock_is_named_only_when_it_explains_the_length_mismatch(tmp_path):
    sf.write(tmp_path / "a.wav", np.zeros(int(16000 * 1.2), np.int16), 16000, subtype="PCM_16")
    m = write_csv(
        tmp_path / "m.csv", ["time", "jawOpen", "rig_lip"], [f"{0.5 + i / 30:.6f}" for i in range(60)], RAMP
    )
    [note] = [
        r for r in read_paired(tmp_path / "a.wav", m, None).meta.repairs if r["kind"] == "length_mismatch"
    ]
    assert "check --fps" in note["message"] and "starts at" not in note["message"]  # 0.5 s of 1.3 s


def test_frame_numbers_from_1001_name_first_frame(tmp_path, wav):
    m = write_csv(
        tmp_path / "m.csv", ["frame", "jawOpen", "rig_lip"], [str(1001 + i) for i in range(60)], RAMP
    )
    with pytest.raises(
        InputError, match=r"lie outside the audio .*: .*starts at frame 1001: .*--first-frame 1001$"
    ):
        read_paired(wav, m, 30)
    sf.write(tmp_path / "long.wav", np.zeros(16000 * 60, np.int16), 16000, subtype="PCM_16")
    [note] = [
        r for r in read_paired(tmp_path / "long.wav", m, 30).meta.repairs if r["kind"] == "length_mismatch"
    ]
    assert note["message"].endswith("import again with --first-frame 1001")
    assert read_paired(tmp_path / "long.wav", m, 30, first_frame=1001).time[0] == 0


def test_the_frame_numbers_from_1_note_says_what_it_cannot_tell(tmp_path, wav):
    m = write_csv(tmp_path / "m.csv", ["frame", "jawOpen", "rig_lip"], [str(i + 1) for i in range(60)], RAMP)
    [note] = [r for r in read_paired(wav, m, 30).meta.repairs if r["kind"] == "frame_numbers_from_1"]
    assert "cannot tell that from counting from 0 with frame 0 missing" in note["message"]
    assert note["message"].endswith("--first-frame 0")


def test_small_scales_in_use_are_no_percent_scale(tmp_path, wav):
    rng = np.random.default_rng(0)
    (tmp_path / "au.txt").write_text("AU01_r\nAU02_r\nAU12_r\n")
    np.save(tmp_path / "au.npy", rng.uniform(0, 3.5, (60, 3)))  # OpenFace's intensities, 0..5
    assert "percent_scale" not in kinds(read_paired(wav, tmp_path / "au.npy", 30, tmp_path / "au.txt"))
    (tmp_path / "deg.txt").write_text("head_yaw_deg\njawOpen\n")
    np.save(tmp_path / "deg.npy", np.column_stack([np.linspace(0, 6, 60), RAMP[:, 0]]))
    assert "percent_scale" not in kinds(read_paired(wav, tmp_path / "deg.npy", 30, tmp_path / "deg.txt"))


def test_bracketed_rig_names_are_names_and_quoted_ones_are_debris(tmp_path):
    (tmp_path / "n.txt").write_text("brow_up[L]\nbrow_up[R]\n")
    assert read_names(tmp_path / "n.txt") == ["brow_up[L]", "brow_up[R]"]
    (tmp_path / "q.txt").write_text("it's\n'jawOpen',\n")
    with pytest.raises(InputError, match=r"q\.txt:2: channel name \"'jawOpen'\" carries brackets or quotes"):
        read_names(tmp_path / "q.txt")


def test_digits_of_other_scripts_are_not_numbers(tmp_path, wav):
    (tmp_path / "m.csv").write_text(
        "time,jawOpen\n" + "".join(f"{i / 30:.5f},\u0660.\u0665\n" for i in range(60))
    )
    with pytest.raises(InputError, match=r"m\.csv:2: non-numeric value in the matrix: '\u0660\.\u0665'"):
        read_paired(wav, tmp_path / "m.csv", None)
