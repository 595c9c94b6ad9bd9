"""What fuzzing the live logs and the audio/take readers found, each fixed: checksummed records with
content no recorder writes (and ones forged in a packet's values, which a sender chooses) are log damage,
an audio chunk's sample index cannot make room for hours of silence, a live take keeps its sender's
declared rate through lost packets, audio whose channel count changes mid-stream decodes, and a take
folder whose ``frames.npz`` holds an unparsable .npy header is a clear error."""

from __future__ import annotations

import io
import json
import struct
import zipfile
import zlib

import numpy as np
import pytest
from live_helpers import record_packets, synthetic_take

from capture import build_takes, read_take
from capture.audio_capture import AudioLog, index_audio_log
from capture.audio_io import decode_with_pyav
from capture.errors import InputError
from capture.livelink import frame_block, header_bytes
from capture.record_log import INVALID_RECORD, RECORD_HEADER, RecordType, encode_record
from capture.take import write_take

DEVICE = "5904AA4B-AD9D-43E5-98AB-89AAEB8AB277"
START = 10 * 3600 * 60  # 10:00:00 at 60 fps
VALUES_AT = RECORD_HEADER.size + 1 + 2 + 8 + 16 + 1  # a FRAME record's offset of the packet's 244 value bytes


def _packet(frame: int, marker: float = 0.0, values: bytes | None = None) -> bytes:
    v = np.full(61, 0.25, np.float32)
    v[0] = marker
    block = frame_block(frame, 0.0, 60, 1, v)
    if values is not None:  # raw value bytes, as any Live Link sender may send
        block = block[: len(block) - len(values)] + values
    return header_bytes(DEVICE, "iPhone") + block


def _forged(payload: bytes) -> bytes:
    """Value bytes holding a checksummed record and, after it, what looks like a record header."""
    record = encode_record(payload) + struct.pack("<II", 1, 0) + bytes([RecordType.FRAME])
    return record + bytes(244 - len(record))


@pytest.mark.parametrize("damage", ["torn", "checksum"])
def test_a_record_forged_in_a_packets_values_is_never_read(tmp_path, damage):
    # A STREAM record that renames the stream (valid JSON: only the resync can keep it out) in one packet.
    forged = _forged(b"\x02" + json.dumps({"stream": 0, "device": "EVIL", "subject": "x"}).encode())
    packets = [_packet(START + i, i) for i in range(120)] + [_packet(START + 120, values=forged)]
    packets += [_packet(START + 121 + i, 121 + i) for i in range(30)]
    rec = record_packets(tmp_path, damage, packets)
    log = rec.session_dir / "frames.log"
    data = bytearray(log.read_bytes())
    record = data.index(forged[:40]) - VALUES_AT  # the hostile packet's FRAME record
    if damage == "torn":  # a crash cut the log 40 bytes past the forged record
        data = data[: data.index(forged[:40]) + 80]
    else:  # a flipped bit in its checksum: the records after it are read again
        data[record + 4] ^= 0x01
    log.write_bytes(bytes(data))
    (line,) = build_takes(rec.session_dir, tmp_path / "out")
    take = read_take(line["path"])
    assert take.meta.device == DEVICE and line["frames"] - line["dropped_frames"] == (
        120 if damage == "torn" else 150
    )
    stretch = line["torn_tail"] if damage == "torn" else line["log_damage"][0]
    assert stretch["offset"] == record and len(line.get("log_damage", [])) == (damage != "torn")


def test_records_with_content_no_recorder_writes_are_counted_as_damage(tmp_path):
    rec = record_packets(tmp_path, "odd", [_packet(START + i, i) for i in range(30)])
    bad = [
        b"\x02" + b"1",  # STREAM whose JSON is no object
        b"\x02" + b'{"stream": "0", "device": "EVIL"}',  # a stream id that is no number
        b"\x02" + b'{"stream": 70000}',  # not 16-bit
        b"\x02" + b'{"device": "EVIL"}',  # no stream id
        b"\x01" + b'{"clock": 5}',  # SESSION
        b"\x01" + b'{"clock": {"origin_ns": "x"}}',
        b"\x01" + b'{"clock": {"origin_ns": 1180591620717411303424}}',  # 2**70: no int64 of ns
        b"\x04" + b'{"bad_header": "many"}',  # REJECTS
        b"\x08" + b"[1]",  # END
        b"\x09" + b'{"kind": 3}',  # NOTE
        b"\x09" + b"\x80\xff",  # not UTF-8
        b"\x09" + b"[" * 100_000,  # nested past the recursion limit
        b"\x05" + b"\x00",  # SYNC without its arrival time
        b"\x03" + bytes(10),  # FRAME of another size
    ]
    with open(rec.session_dir / "frames.log", "ab") as f:
        f.write(b"".join(encode_record(p) for p in bad))
    (line,) = build_takes(rec.session_dir, tmp_path / "out")
    assert line["frames"] == 30 and read_take(line["path"]).meta.device == DEVICE
    assert [d["reason"] for d in line["log_damage"]] == [INVALID_RECORD] * len(bad)
    assert sum(d["bytes_discarded"] for d in line["log_damage"]) == sum(
        RECORD_HEADER.size + len(p) for p in bad
    )


def test_audio_log_records_with_content_no_recorder_writes_are_counted_as_damage(tmp_path):
    path = tmp_path / "audio.log"
    log = AudioLog(path, fsync=False)
    log.start(16000, 1, "PCM_16", "test")
    chunk = np.arange(1600, dtype=np.int16)[:, None]
    for k in range(10):
        log.add_chunk(k * 1600, 10**12 + k * 10**8, chunk)
    head = struct.Struct("<BQq")
    log.writer.put(encode_record(head.pack(RecordType.AUDIO, 2**55, 10**12 + 10**9) + chunk.tobytes()))
    log.writer.put(encode_record(head.pack(RecordType.AUDIO, 3036696896, 10**12 + 10**9) + chunk.tobytes()))
    log.writer.put(encode_record(head.pack(RecordType.AUDIO, 16000, 10**12 + 10**9) + b"\x00" * 3))
    log.writer.put(encode_record(b"\x06" + b'{"sample_rate": 16000, "channels": "1", "subtype": "PCM_16"}'))
    log.writer.put(encode_record(b"\x06" + b"\xff"))
    log.writer.put(encode_record(b"\x09" + b"7"))
    log.close()
    logged, report = index_audio_log(path)
    audio = logged.read()
    assert audio.frames == 16000 and audio.sample_rate == 16000 and logged.first_ns == 10**12
    assert np.array_equal(audio.samples[1600:3200, 0], chunk[:, 0])
    assert [d["reason"] for d in report["log_damage"]] == [INVALID_RECORD] * 6 and not report["gaps"]


def test_a_live_take_keeps_its_declared_rate_through_lost_packets(tmp_path):
    # 60 fps declared, 2 of every 5 packets lost: the median frame step is 2 frames (30 fps).
    sent = [i for i in range(180) if i % 5 in (0, 1, 3)]
    rec = record_packets(tmp_path, "lossy", [_packet(START + i, i) for i in sent])
    (line,) = build_takes(rec.session_dir, tmp_path / "out")
    take = read_take(line["path"])
    assert take.meta.fps == 60.0 and line["frames"] == sent[-1] + 1
    assert line["dropped_frames"] == sent[-1] + 1 - len(sent)
    tracked = take.frame_status == 0
    assert np.array_equal(take.values[tracked, 0], np.array(sent, np.float32))
    np.testing.assert_allclose(take.time[tracked], np.array(sent) / 60, atol=1e-9)
    assert [r["kind"] for r in take.meta.repairs] == ["rate_below_declared"]
    # a sender that steadily sends every other frame number of its declared 60 fps is a 30 fps take
    rec = record_packets(tmp_path, "every2", [_packet(START + 2 * i, i) for i in range(60) if i != 30])
    (line,) = build_takes(rec.session_dir, tmp_path / "out2")
    assert read_take(line["path"]).meta.fps == 30.0 and line["frames"] == 60 and line["dropped_frames"] == 1
    # review: a sender declaring 60 that sends 24 frames/s with sub-frame times is off the 60 fps grid: its
    # own rate, no DROPPED rows between its frames
    v = np.full(61, 0.25, np.float32)
    times = [START + i * 2.5 for i in range(96)]
    packets = [header_bytes(DEVICE, "iPhone") + frame_block(int(t), t % 1, 60, 1, v) for t in times]
    rec = record_packets(tmp_path, "film", packets)
    (line,) = build_takes(rec.session_dir, tmp_path / "out3")
    assert read_take(line["path"]).meta.fps == 24.0 and line["frames"] == 96 and line["dropped_frames"] == 0


def _adts(channels: int, seconds: float = 0.5) -> bytes:
    import av

    out = io.BytesIO()
    with av.open(out, "w", format="adts") as container:
        stream = container.add_stream("aac", rate=16000, layout="mono" if channels == 1 else "stereo")
        samples = np.sin(np.arange(int(16000 * seconds)) / 10).astype(np.float32)
        frame = av.AudioFrame.from_ndarray(
            np.tile(samples, (channels, 1)), format="fltp", layout=stream.layout.name
        )
        frame.sample_rate = 16000
        for packet in [*stream.encode(frame), *stream.encode(None)]:
            container.mux(packet)
    return out.getvalue()


def test_audio_whose_channel_count_changes_mid_stream_is_mixed_to_the_first_layout(tmp_path):
    path = tmp_path / "mono_then_stereo.aac"
    path.write_bytes(_adts(1) + _adts(2))
    repairs: list = []
    audio = decode_with_pyav(path, repairs=repairs)
    assert audio.samples.shape[1] == 1 and audio.frames > 16000 * 0.9
    (changed,) = [r for r in repairs if r["kind"] == "channels_changed"]
    assert "1 channel(s)" in changed["message"]


def test_a_frames_npz_member_with_an_unparsable_npy_header_is_a_clear_error(tmp_path):
    folder = write_take(synthetic_take(30), tmp_path)
    npz = folder / "frames.npz"
    with zipfile.ZipFile(npz) as z:
        members = {name: z.read(name) for name in z.namelist()}
    header = b"{'descr': '|u1', 'fortran_order': False, 'shape': (30,"  # the bracket is never closed
    header += b" " * (-(10 + len(header) + 1) % 64) + b"\n"
    members["frame_status.npy"] = b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header + bytes(30)
    with zipfile.ZipFile(npz, "w") as z:
        for name, data in members.items():
            z.writestr(name, data)
    with pytest.raises(InputError, match="frames are unreadable") as err:
        read_take(folder)
    assert str(npz) in str(err.value)


def test_resync_reads_on_after_a_damaged_record_whose_header_lies(tmp_path):
    # A torn FRAME record, then a recorder that appended to the same log: the records after the torn
    # one start inside the length its header claims and are all read.
    rec = record_packets(tmp_path, "again", [_packet(START + i, i) for i in range(40)])
    log = rec.session_dir / "frames.log"
    data = log.read_bytes()
    frame = RECORD_HEADER.pack(272, zlib.crc32(b"x"))  # a FRAME header whose payload was never written
    log.write_bytes(data + frame + bytes([RecordType.FRAME]) + bytes(20) + data[8:])
    (line,) = build_takes(rec.session_dir, tmp_path / "out")
    assert line["frames"] - line["dropped_frames"] == 40 and line["duplicates"] == 40
    assert line["log_damage"][0]["bytes_discarded"] == 29


@pytest.mark.parametrize(("hours", "ppm", "overflows"), [(3, 200, 0), (6, -100, 0), (0.5, 0, 30)])
def test_a_long_drifting_recording_with_dropped_input_keeps_every_audio_chunk(hours, ppm, overflows):
    """Review: the clock check judged drift from sample 0 against the median chunk, so the first chunks of
    a 3 h recording at 200 ppm (and every chunk before 3 s of input overflows) were thrown away."""
    from capture.audio_capture import _placeable

    class Rejects:
        count = 0

        def reject(self, *_args):
            self.count += 1

    body = bytes(2 * 4800)  # 0.1 s of 16-bit mono at 48 kHz, one object for every chunk
    n = int(hours * 36000)
    chunks, index = [], 0
    for k in range(n):
        if overflows and k and k % (n // overflows) == 0:
            index -= 4800  # 0.1 s of input the sound card dropped: the index does not count it
        stamp = 10**18 + int(k * 0.1 * (1 + ppm * 1e-6) * 1e9)
        chunks.append((max(index, 0), stamp, body, (0, 0)))
        index += 4800
    rejects = Rejects()
    fmt = {"subtype": "PCM_16", "channels": 1, "sample_rate": 48000}
    assert len(_placeable(chunks, fmt, rejects)) == n and rejects.count == 0
    chunks.insert(7, (10**12, chunks[7][1], body, (0, 0)))  # a forged index: a week of room
    assert len(_placeable(chunks, fmt, rejects)) == n and rejects.count == 1
