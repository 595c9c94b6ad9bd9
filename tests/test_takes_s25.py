"""Takes from other phones, app versions and tools, each made here from the documented formats
(formats doc §2-§3; never by our own writer) and imported as a collector would, with ``s2a-capture
import``: a take folder whose every file a transfer renamed (``take (1).json``), a zip made on Windows
with folder members named ``X\\``, and a ``.mov`` whose audio is AAC or Apple Lossless."""

from __future__ import annotations

import csv
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from capture import read_take
from tests.conftest import run_cli, run_here

SECONDS = 4
TIMECODE = "10:13:39:01"  # the first row of the sample CSV, whole frames at 60 fps
PREFIX = "Interview_3_iPhone"


def write_mov(path: Path, audio: np.ndarray, rate: int, codec: str = "pcm_s16le") -> None:
    """A reference video as the app's (formats doc §3): JPEG frames at 60 fps, mono audio, a start
    timecode; written with PyAV directly."""
    import av

    with av.open(str(path), "w", format="mov") as c:
        c.metadata["timecode"] = TIMECODE
        video = c.add_stream("mjpeg", rate=60)
        video.width, video.height, video.pix_fmt = 32, 16, "yuvj420p"
        sound = c.add_stream(codec, rate=rate)
        sound.layout = "mono"
        if codec == "alac":
            sound.format = "s16p"
        for i in range(int(len(audio) / rate * 60)):
            frame = av.VideoFrame.from_ndarray(np.full((16, 32, 3), i % 256, np.uint8), format="rgb24")
            frame = frame.reformat(format="yuvj420p")
            frame.pts = i
            c.mux(video.encode(frame))
        size, fmt = sound.codec_context.frame_size or 1024, sound.codec_context.format.name
        for start in range(0, len(audio), size):
            block = audio[start : start + size][None, :]
            block = (block / 32768).astype(np.float32) if fmt == "fltp" else block
            frame = av.AudioFrame.from_ndarray(block, format=fmt, layout="mono")
            frame.sample_rate, frame.pts = rate, start
            c.mux(sound.encode(frame))
        c.mux(video.encode(None))
        c.mux(sound.encode(None))


def app_take_folder(samples: Path, folder: Path, codec: str = "pcm_s16le") -> Path:
    """A take folder of the app's ARKit mode (formats doc §3): the first seconds of the real paired
    sample as ``<prefix>.csv`` and the ``.mov``'s audio, take.json, frame_log.csv, the metadata JSON and
    a thumbnail."""
    pair = samples / "paired" / "neurosync-trainer-lite-testset"
    folder.mkdir(parents=True)
    with open(pair / "testset.csv", newline="") as f:
        rows = list(csv.reader(f))[: 1 + 60 * SECONDS]
    (folder / f"{PREFIX}.csv").write_text("".join(",".join(r) + "\n" for r in rows))
    audio, rate = sf.read(pair / "audio.wav", dtype="int16")
    write_mov(folder / f"{PREFIX}.mov", audio[: rate * SECONDS], rate, codec)
    take = {"frames": 60 * SECONDS, "appVersion": "1.4.2 (build 120)", "slate": "Interview", "take": 3}
    take |= {"calibrated": False, "subject": "iPhone", "identifier": "20250110_Interview_3"}
    take |= {"date": "2025-01-10T10:13:39Z", "version": 1, "deviceModel": "iPhone14,2"}
    (folder / "take.json").write_text(json.dumps(take))
    (folder / "video_metadata.json").write_text(json.dumps({"FrameRate": 60, "Quality": "high"}))
    (folder / "audio_metadata.json").write_text(json.dumps({"SampleRate": 44100, "ChannelsPerFrame": 1}))
    (folder / "thumbnail.jpg").write_bytes(b"\xff\xd8\xff\xd9")
    # an A row 0.5 s (30 frames) after the first V row: where the audio starts on the take clock
    log = ["A,0,0,44100,10:13:39:31,0"] + [
        f"V,{i},{i},60,10:13:{39 + (1 + i) // 60}:{(1 + i) % 60:02d},0" for i in range(120)
    ]
    (folder / "frame_log.csv").write_text("\n".join(log) + "\n")
    return folder


def imported(out: Path) -> Path:
    (folder,) = [p for p in out.iterdir() if (p / "meta.json").is_file()]
    return folder


def test_a_take_folder_whose_every_file_a_transfer_renamed_imports_with_its_app_files(samples, tmp_path):
    """AirDrop or Finder receiving a take where its names are taken adds `` (1)`` to every file: the
    take's ``frame_log (1).csv`` is no second blendshape CSV, and its ``take (1).json`` and log are read
    (the old code refused the folder: two plain CSVs, none named after the take)."""
    folder = app_take_folder(samples, tmp_path / "20250110_Interview_3")
    for p in list(folder.iterdir()):
        p.rename(folder / f"{p.stem} (1){p.suffix}")
    proc = run_cli("capture", "import", folder, "-o", tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    take = read_take(imported(tmp_path / "out"))
    assert take.meta.id == "20250110_Interview_3" and take.meta.device == "iPhone14,2"
    roles = {s.role: Path(s.path).name for s in take.meta.sources}
    assert roles["take.json"] == "take (1).json" and roles["frame_log.csv"] == "frame_log (1).csv"
    assert take.audio is not None and take.meta.audio.start_source == "frame_log_audio"
    assert take.meta.audio.start_s == pytest.approx((31 - 1.936) / 60, abs=1e-3)  # first row: 39:01.936
    proc = run_cli("align", tmp_path / "out", "-o", tmp_path / "aligned")
    assert proc.returncode == 0, proc.stderr


def test_a_windows_zip_with_folder_members_named_with_backslashes_imports(samples, tmp_path):
    """A zip whose members, folders too, a Windows tool named with ``\\`` (``Takes\\T\\``): a folder
    member is a folder (the old code unpacked it as an empty file, and the take's files then "clashed
    with another member of that name")."""
    folder = app_take_folder(samples, tmp_path / "20250110_Interview_3")
    archive = tmp_path / "takes.zip"
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as z:
        for name in ("Takes\\", "Takes\\20250110_Interview_3\\"):
            member = zipfile.ZipInfo(name)
            member.create_system, member.external_attr = 0, 0x10  # MS-DOS, directory attribute
            z.writestr(member, b"")
        for p in sorted(folder.iterdir()):
            member = zipfile.ZipInfo(f"Takes\\20250110_Interview_3\\{p.name}")
            member.create_system, member.external_attr = 0, 0x20
            z.writestr(member, p.read_bytes(), zipfile.ZIP_DEFLATED)
    proc = run_here("capture", "import", archive, "-o", tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    take = read_take(imported(tmp_path / "out"))
    assert take.meta.id == "20250110_Interview_3" and take.audio is not None
    assert take.meta.audio.start_source == "frame_log_audio"


@pytest.mark.parametrize("codec", ["aac", "alac"])
def test_a_mov_whose_audio_is_aac_or_apple_lossless_keeps_its_timing(samples, tmp_path, codec):
    """44.1 kHz mono AAC or Apple Lossless in the ``.mov`` (another app version or a re-encode) reads
    as the PCM one does: same rate, same start, the same samples where they line up (already so)."""
    pcm = run_here(
        "capture", "import", app_take_folder(samples, tmp_path / "pcm" / "T"), "-o", tmp_path / "a"
    )
    other = app_take_folder(samples, tmp_path / codec / "T", codec)
    coded = run_here("capture", "import", other, "-o", tmp_path / "b")
    assert pcm.returncode == 0 and coded.returncode == 0, pcm.stderr + coded.stderr
    a, b = read_take(imported(tmp_path / "a")), read_take(imported(tmp_path / "b"))
    assert b.audio.sample_rate == 44100 and b.meta.audio.start_s == a.meta.audio.start_s
    x, y = a.audio.samples[4410:88200].ravel(), b.audio.samples[4410:88200].ravel()
    assert np.corrcoef(x, y)[0, 1] > 0.99  # no encoder delay left in (1,024 samples would decorrelate)


def test_an_audio2face_export_saved_as_windows_unicode_text_imports(samples, tmp_path):
    """An Audio2Face export re-saved by a Windows tool as "Unicode" (UTF-16 with its mark, CRLF; e.g.
    PowerShell 5's ``Out-File``) reads as the UTF-8 one (the old code: "not a JSON file ('utf-8' codec
    can't decode byte 0xff ...)")."""
    with open(samples / "paired" / "neurosync-trainer-lite-testset" / "testset.csv", newline="") as f:
        header, *rows = list(csv.reader(f))[: 1 + 60]
    names = [n[0].lower() + n[1:] for n in header[2:54]]
    export = {"exportFps": 30.0, "numPoses": 52, "numFrames": len(rows), "facsNames": names}
    export["weightMat"] = [[float(v) for v in r[2:54]] for r in rows]
    text = json.dumps(export, indent=4).replace("\n", "\r\n")
    (tmp_path / "line01_bsweight.json").write_bytes(text.encode("utf-16"))
    sf.write(tmp_path / "line01.wav", np.zeros(16000 * 2, np.float32), 16000)
    args = ["--matrix", tmp_path / "line01_bsweight.json", "--audio", tmp_path / "line01.wav"]
    proc = run_here("capture", "import", *args, "-o", tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    take = read_take(imported(tmp_path / "out"))
    assert take.meta.fps == 30 and take.values.shape == (60, 52)
    assert take.values[:, take.meta.channels.index("jawOpen")] == pytest.approx(
        [float(r[2 + header[2:].index("JawOpen")]) for r in rows], abs=1e-6
    )
