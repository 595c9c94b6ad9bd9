"""Reading the live recorder's log (what `recover` and the end of `listen` do): one hour of one phone
at 60 fps, clean and damaged, against reading and checksumming the same bytes in one pass."""

from __future__ import annotations

import tempfile
import zlib
from pathlib import Path

import numpy as np

from benchmarks.figure import Figure, best_time
from capture.record_log import LogReader, LogWriter, RecordType, encode_record

FRAME_PAYLOAD = 1 + 2 + 8 + 261  # type, stream id, arrival ns, the packet's frame block


def write_log(path: Path, frames: int) -> None:
    rng = np.random.default_rng(0)
    writer = LogWriter(path, fsync=False)
    for i in range(frames):
        writer.buffer += encode_record(bytes([RecordType.FRAME]) + rng.bytes(FRAME_PAYLOAD - 1))
        if i % 6000 == 5999:  # the recorder hands over a buffer every 0.1 s; every 100 s is enough here
            writer.flush()
    writer.close()


def read_all(path: Path) -> int:
    return sum(1 for _ in LogReader(path))


def raw_pass(path: Path) -> int:
    """The reference: the file's bytes read in 1 MiB blocks and CRC-32'd, no parsing."""
    crc = 0
    with open(path, "rb") as f:
        while block := f.read(1 << 20):
            crc = zlib.crc32(block, crc)
    return crc


def run(quick: bool = False) -> list[Figure]:
    frames = 21_600 if quick else 216_000  # 6 min / 1 hour at 60 fps
    with tempfile.TemporaryDirectory() as tmp:
        clean = Path(tmp) / "clean.log"
        write_log(clean, frames)
        data = bytearray(clean.read_bytes())
        mb = len(data) / 1e6
        mid = len(data) // 2
        data[mid : mid + (1 << 20)] = bytes(1 << 20)  # a zeroed MiB in the middle
        data += np.random.default_rng(1).bytes(len(data) // 2)  # and garbage after the end
        damaged = Path(tmp) / "damaged.log"
        damaged.write_bytes(bytes(data))
        reader = LogReader(damaged)
        kept = sum(1 for _ in reader)
        assert read_all(clean) == frames and len(reader.skipped) == 1 and reader.torn_tail is not None
        ref = best_time(lambda: raw_pass(clean))
        t_clean = best_time(lambda: read_all(clean))
        t_damaged = best_time(lambda: read_all(damaged))
        hours = frames / 60 / 3600
        return [
            Figure(
                f"recorder log read, {hours:g} h at 60 fps ({mb:.0f} MB)",
                mb / t_clean,
                "MB/s",
                "one read + CRC-32 pass",
                mb / ref,
                higher_is_better=True,
                note=f"{t_clean:.2f} s, {frames / t_clean / 60:,.0f}x real time",
            ),
            Figure(
                f"damaged log read: 1 MiB zeroed mid-log + {mb / 2:.0f} MB of garbage after the end",
                len(data) / 1e6 / t_damaged,
                "MB/s",
                "one read + CRC-32 pass",
                mb / ref,
                higher_is_better=True,
                note=f"{t_damaged:.2f} s; {kept:,} of {frames:,} frames kept",
            ),
        ]
