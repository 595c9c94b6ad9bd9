"""Live Link Face take folders (take.json, frame_log.csv, .mov audio, _cal/_raw/_neutral) and CSVs
paired with audio recorded elsewhere."""

from __future__ import annotations

import json
import shutil
from fractions import Fraction
from pathlib import Path

import av
import numpy as np
import pytest

from capture import Audio, InputError, read_audio, read_take, read_take_folder, write_reference_mov
from capture.take_folder import read_csv_with_audio
from capture.timecode import Timecode
from tests.conftest import run_here

CSV_T0 = Timecode.parse("19:18:11:20.002").seconds_of_day  # first row of MySlate_166_iPhone_cal.csv


def speech_like(rate: int, seconds: float) -> np.ndarray:
    """A deterministic 16-bit tone burst pattern (stands in for the talker's voice)."""
    t = np.arange(int(rate * seconds)) / rate
    envelope = (np.sin(2 * np.pi * 2 * t) > 0).astype(float)
    return (envelope * 8000 * np.sin(2 * np.pi * 220 * t)).astype(np.int16)[:, None]


def make_take_folder(root: Path, samples: Path, rate: int = 48000, frame_log: str | None = None) -> Path:
    folder = root / "20241204_MySlate_166"
    folder.mkdir(parents=True)
    src = samples / "livelinkface/neurosync_MySlate_166/MySlate_166_iPhone_cal.csv"
    shutil.copy(src, folder / "MySlate_166_iPhone_cal.csv")
    lines = src.read_text().splitlines(keepends=True)
    # A _raw file that differs from _cal, and a short neutral pose.
    raw = [lines[0]] + [
        ",".join(ln.split(",")[:19] + ["0.5000000000"] + ln.split(",")[20:]) for ln in lines[1:]
    ]
    (folder / "MySlate_166_iPhone_raw.csv").write_text("".join(raw))
    (folder / "MySlate_166_iPhone_neutral.csv").write_text("".join(lines[:4]))
    take_json = {
        "frames": 1848,
        "appVersion": "v1.4.2 (build 3)",
        "slate": "MySlate",
        "calibrated": True,
        "subject": "iPhone",
        "identifier": "20241204_MySlate_166",
        "date": "2024-12-04T19:18:11Z",
        "version": 1,
        "take": 166,
        "deviceModel": "iPhone14,2",
    }
    (folder / "take.json").write_text(json.dumps(take_json))
    (folder / "video_metadata.json").write_text(
        json.dumps({"FrameRate": 60, "Dimensions": {"width": 160, "height": 120}, "Quality": "high"})
    )
    (folder / "audio_metadata.json").write_text(
        json.dumps({"BitsPerChannel": 16, "SampleRate": rate, "ChannelsPerFrame": 1, "FormatFlags": 12})
    )
    audio = Audio(speech_like(rate, 1.5), rate, "PCM_16")
    write_reference_mov(folder / "MySlate_166_iPhone.mov", 60, 12, audio, timecode="19:18:11:10")
    if frame_log is None:
        frame_log = "V,0,0,60,19:18:11:20.500,0\nV,1,1,60,19:18:11:21.500,0\nA,0,0,48000,19:18:11:19.000\n"
    if frame_log:
        (folder / "frame_log.csv").write_text(frame_log)
    return folder


def test_take_folder_with_frame_log_audio_row(tmp_path, samples):
    folder = make_take_folder(tmp_path, samples)
    take = read_take_folder(folder)
    m = take.meta
    assert m.id == "20241204_MySlate_166" and m.source_kind == "livelink_take_folder"
    assert (m.slate, m.take_number, m.subject, m.device) == ("MySlate", 166, "iPhone", "iPhone14,2")
    assert m.csv["variant"] == "cal" and take.time.size == 1848
    assert take.audio.sample_rate == 48000 and take.audio.samples.dtype == np.int16
    assert np.array_equal(take.audio.samples, speech_like(48000, 1.5))
    assert m.audio.start_source == "frame_log_audio"
    assert m.audio.start_s == pytest.approx((19 - 20.002) / 60, abs=1e-9)
    roles = {s.role for s in m.sources}
    assert {"blendshapes_csv", "neutral_csv", "reference_video", "take.json", "frame_log.csv"} <= roles
    # The neutral pose is the mean of _neutral.csv's rows, per channel of the take.
    assert take.neutral is not None and take.neutral.shape == (61,)
    assert take.neutral[take.channel_index("jawOpen")] == pytest.approx(take.values[:3, 17].mean(), abs=1e-6)
    back = read_take(__import__("capture").write_take(take, tmp_path / "out"))
    assert back.meta.audio.start_s == m.audio.start_s and np.array_equal(back.neutral, take.neutral)


def test_audio_start_falls_back_to_video_row_then_mov_timecode(tmp_path, samples):
    only_v = "V,0,0,60,19:18:11:22.000,0\n"
    take = read_take_folder(make_take_folder(tmp_path / "a", samples, frame_log=only_v))
    assert take.meta.audio.start_source == "frame_log_video"
    assert take.meta.audio.start_s == pytest.approx((22 - 20.002) / 60, abs=1e-9)
    take = read_take_folder(make_take_folder(tmp_path / "b", samples, frame_log=""))
    assert take.meta.audio.start_source == "mov_timecode"
    assert take.meta.audio.start_s == pytest.approx((10 - 20.002) / 60, abs=1e-6)


def test_variants_and_rate_mismatch(tmp_path, samples):
    folder = make_take_folder(tmp_path, samples, rate=44100)
    raw = read_take_folder(folder, variant="raw")
    assert raw.meta.csv["variant"] == "raw" and np.all(raw.channel("jawOpen") == 0.5)
    with pytest.raises(InputError, match="no plain CSV"):
        read_take_folder(folder, variant="plain")
    audio_meta = json.loads((folder / "audio_metadata.json").read_text())
    (folder / "audio_metadata.json").write_text(json.dumps(audio_meta | {"SampleRate": 48000}))
    take = read_take_folder(folder)
    assert take.audio.sample_rate == 44100  # the file's own rate wins
    assert [r["kind"] for r in take.meta.repairs] == ["audio_rate_mismatch"]


def test_depth_only_take_is_refused_clearly(tmp_path):
    folder = tmp_path / "mha"
    folder.mkdir()
    (folder / "take.json").write_text("{}")
    (folder / "depth_data.bin").write_bytes(b"\0" * 16)
    with pytest.raises(InputError, match="MetaHuman Animator"):
        read_take_folder(folder)


def encode(
    path: Path, codec: str, samples: np.ndarray, rate: int, container: str | None = None, options=None
) -> Path:
    """Write mono 16-bit samples with an FFmpeg encoder (as a phone or editor would), into ``container``
    (default: the one the file name says) with its muxer ``options``."""
    with av.open(str(path), "w", format=container, options=options or {}) as c:
        s = c.add_stream(codec, rate=rate, layout="mono")
        fmt = s.codec_context.codec.audio_formats[0].name
        x = samples[:, 0].astype(np.float32) / 32768
        for pos in range(0, x.size, 1152):
            chunk = x[pos : pos + 1152]
            if fmt.startswith("s16"):
                chunk = (chunk * 32767).astype(np.int16)
            elif fmt.startswith("s32"):
                chunk = (chunk.astype(np.float64) * 2**31).astype(np.int32)
            frame = av.AudioFrame.from_ndarray(chunk[None, :], format=fmt, layout="mono")
            frame.sample_rate, frame.pts, frame.time_base = rate, pos, Fraction(1, rate)
            for p in s.encode(frame):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    return path


@pytest.mark.parametrize("ext,codec", [("wav", None), ("flac", None), ("mp3", "libmp3lame"), ("m4a", "aac")])
def test_csv_with_external_audio_of_any_format(tmp_path, samples, ext, codec):
    rate = 44100
    pcm = speech_like(rate, 1.0)
    path = tmp_path / f"voice.{ext}"
    if codec is None:
        import soundfile as sf

        sf.write(path, pcm, rate, subtype="PCM_16")
    else:
        encode(path, codec, pcm, rate)
    audio = read_audio(path)
    assert audio.sample_rate == rate
    decoded = audio.mono_float()
    # the encoder's priming and the padding of the last coded frame (AAC: up to 1023 samples) are cut
    assert abs(decoded.size - pcm.shape[0]) <= 32, decoded.size - pcm.shape[0]
    # The voice is there: the on/off pattern of its energy in 50 ms blocks follows the source's.
    ref = pcm[:, 0].astype(np.float32) / 32768
    block = rate // 20
    n = min(ref.size, decoded.size) // block
    e_ref = (ref[: n * block] ** 2).reshape(n, block).mean(axis=1)
    e_dec = (decoded[: n * block] ** 2).reshape(n, block).mean(axis=1)
    assert np.corrcoef(e_ref, e_dec)[0, 1] > 0.9
    take = read_csv_with_audio(samples / "livelinkface/alexdjulin_S07/S07-001.csv", path)
    assert take.meta.audio.sample_rate == rate
    assert take.meta.sources[-1].role == "external_audio"


def test_cli_imports_take_folders_found_recursively(tmp_path, samples):
    make_take_folder(tmp_path / "phone" / "takes", samples)
    proc = run_here("capture", "import", tmp_path / "phone", "-o", tmp_path / "out", "--json", check=True)
    [summary] = [json.loads(x) for x in proc.stdout.splitlines()]
    assert summary["id"] == "20241204_MySlate_166" and summary["audio_sample_rate"] == 48000
    assert summary["frames"] == 1848
    info = run_here("capture", "info", tmp_path / "phone" / "takes" / "20241204_MySlate_166", "--json")
    assert json.loads(info.stdout)["audio_start_s"] == pytest.approx((19 - 20.002) / 60, abs=1e-6)


def test_missing_audio_file_is_a_clear_error(tmp_path, samples):
    proc = run_here(
        "capture",
        "import",
        samples / "livelinkface/alexdjulin_S07/S07-001.csv",
        "--audio",
        tmp_path / "missing.wav",
        "-o",
        tmp_path / "out",
    )
    assert proc.returncode == 1 and "audio file not found" in proc.stderr and "Traceback" not in proc.stderr


def test_audio_pairing_by_frame_index_is_recorded_for_align(tmp_path, samples):
    """NeuroSync's pair puts row i with audio i/60 s although its timecodes run at 59.90 rows/s; the
    import says so, and s2a-align then places the frames by index."""
    ns = samples / "paired/neurosync-trainer-lite-testset"
    csv, wav = ns / "testset.csv", ns / "audio.wav"
    for pairing, source in (
        ("first-row", "assumed_first_csv_row"),
        ("frame-index", "paired_frame_convention"),
    ):
        out = tmp_path / pairing
        run_here("capture", "import", csv, "--audio", wav, "--audio-pairing", pairing, "-o", out, check=True)
        assert read_take(out / "testset", audio=False).meta.audio.start_source == source
    for bad in (["--audio-pairing", "frame-index"], ["--audio", wav, "--audio-pairing", "by-ear"]):
        proc = run_here("capture", "import", csv, *bad, "-o", tmp_path / "bad")
        assert (
            proc.returncode in (1, 2) and "--audio-pairing" in proc.stderr and "Traceback" not in proc.stderr
        )
