"""The append-only record log: round trip, torn tails at every cut, corruption, and arrival_s in takes."""

from __future__ import annotations

import errno
import time

import numpy as np
import pytest
from live_helpers import synthetic_take

from capture import InputError, read_take, write_take
from capture.record_log import MAGIC, LogReader, LogWriter, RecordType, encode_record


def _write_log(path, payloads):
    w = LogWriter(path, fsync=False)
    for p in payloads:
        w.buffer += encode_record(p)
    w.close()


def test_round_trip_and_torn_tail_at_every_cut(tmp_path):
    rng = np.random.default_rng(1)
    payloads = [bytes([RecordType.NOTE]) + rng.bytes(int(rng.integers(1, 300))) for _ in range(40)]
    log = tmp_path / "a.log"
    _write_log(log, payloads)
    reader = LogReader(log, block_bytes=64)  # small blocks: records straddle block ends
    assert [bytes(p) for p in reader] == payloads
    assert reader.torn_tail is None
    data = log.read_bytes()
    ends = np.cumsum([len(MAGIC)] + [8 + len(p) for p in payloads])
    cut_log = tmp_path / "cut.log"
    for cut in range(len(MAGIC), len(data), 7):
        cut_log.write_bytes(data[:cut])
        reader = LogReader(cut_log, block_bytes=100)
        got = [bytes(p) for p in reader]
        whole = int(np.searchsorted(ends, cut, side="right")) - 1  # records wholly before the cut
        assert got == payloads[:whole]
        if cut in ends:
            assert reader.torn_tail is None
        else:
            assert reader.torn_tail is not None and reader.torn_tail.offset == ends[whole]


def test_reading_resumes_after_a_damaged_record(tmp_path):
    payloads = [bytes([RecordType.NOTE]) + bytes([i]) * 50 for i in range(10)]
    log = tmp_path / "b.log"
    _write_log(log, payloads)
    data = bytearray(log.read_bytes())
    sixth = len(MAGIC) + 5 * 59
    data[sixth + 20] ^= 0xFF  # a bit flip inside the 6th record's payload
    log.write_bytes(bytes(data) + b"\x00" * 100)  # and a zeroed tail (a power loss)
    reader = LogReader(log, block_bytes=64)
    assert [bytes(p) for p in reader] == payloads[:5] + payloads[6:]
    (damage,) = reader.skipped
    assert damage.to_json() == {"offset": sixth, "bytes_discarded": 59, "reason": "checksum"}
    assert reader.torn_tail.to_json() == {"offset": len(data), "bytes_discarded": 100, "reason": "bad_length"}


@pytest.mark.parametrize("where", ["length", "zeros", "garbage"])
def test_damage_mid_file_costs_only_the_records_it_hits(tmp_path, where):
    rng = np.random.default_rng(7)
    payloads = [bytes([RecordType.FRAME]) + rng.bytes(271) for _ in range(400)]
    log = tmp_path / "c.log"
    _write_log(log, payloads)
    data = bytearray(log.read_bytes())
    at = len(MAGIC) + 100 * 280
    if where == "length":  # a length field claims more than the rest of the file
        data[at : at + 4] = (len(data)).to_bytes(4, "little")
        lost = [100]
    elif where == "zeros":  # a zeroed 4 KiB block, as a failing disk returns
        data[at + 17 : at + 17 + 4096] = bytes(4096)
        lost = list(range(100, 100 + (17 + 4096) // 280 + 1))
    else:  # random bytes spliced in (another writer's data)
        data[at:at] = rng.bytes(10_000)
        lost = []
    log.write_bytes(bytes(data))
    reader = LogReader(log, block_bytes=1000)
    got = [bytes(p) for p in reader]
    assert got == [p for i, p in enumerate(payloads) if i not in lost]
    assert reader.torn_tail is None and len(reader.skipped) == 1 and reader.skipped[0].offset == at


def test_not_a_log(tmp_path):
    p = tmp_path / "x.log"
    p.write_bytes(b"hello world, not a log")
    with pytest.raises(InputError, match="not a recorder log"):
        list(LogReader(p))
    p.write_bytes(MAGIC[:3])  # killed while writing the magic
    reader = LogReader(p)
    assert list(reader) == [] and reader.torn_tail is not None


def test_take_arrival_times_round_trip(tmp_path):
    take = synthetic_take(50)
    take.arrival_s = np.where(np.arange(50) % 7 == 3, np.nan, np.arange(50) / 60 + 12.5)
    back = read_take(write_take(take, tmp_path))
    assert np.array_equal(back.arrival_s, take.arrival_s, equal_nan=True)
    take.arrival_s = None
    assert read_take(write_take(take, tmp_path)).arrival_s is None
    with pytest.raises(InputError, match="arrival_s"):
        type(take)(take.meta, take.time, take.values, take.frame_status, arrival_s=np.zeros(3))


def test_a_pattern_that_mimics_headers_is_searched_cheaply(tmp_path, monkeypatch):
    """4 MB of a repeating pattern whose every 4th offset reads as a long record followed by another:
    the search checksums within its budget, and still finds every real record after it."""
    import zlib

    import capture.record_log as rl

    payloads = [bytes([RecordType.FRAME]) + bytes([i]) * 271 for i in range(40)]
    log = tmp_path / "p.log"
    _write_log(log, payloads)
    data = bytearray(log.read_bytes())
    at = len(MAGIC) + 20 * 280
    data[at:at] = b"\x03\x00\x08\x00" * (1 << 20)
    log.write_bytes(bytes(data))
    checked = []

    class CountingZlib:
        @staticmethod
        def crc32(payload, *args):
            checked.append(len(payload))
            return zlib.crc32(payload, *args)

    monkeypatch.setattr(rl, "zlib", CountingZlib)
    reader = LogReader(log)
    assert [bytes(p) for p in reader] == payloads and len(reader.skipped) == 1
    # a bounded multiple of the bytes searched, not a megabyte per candidate (196 GB before the budget)
    assert sum(checked) <= (rl.RESYNC_BUDGET + 1) * len(data) + rl.RESYNC_MAX_BYTES


def test_a_write_that_runs_out_of_memory_is_counted_and_the_writer_goes_on(tmp_path, monkeypatch):
    """Joining the records that wait can fail for memory; the writer thread must neither die (every later
    record lost, nothing reported) nor tear the log."""
    records = [encode_record(bytes([RecordType.NOTE]) + bytes([i]) * 50) for i in range(3)]
    log = LogWriter(tmp_path / "a.log", fsync=False)
    real_write, calls = log._write, []

    def first_write_out_of_memory(data: bytes) -> None:
        calls.append(len(data))
        if len(calls) == 1:
            raise MemoryError()
        real_write(data)

    monkeypatch.setattr(log, "_write", first_write_out_of_memory)
    log.put(records[0])
    while not calls:
        time.sleep(0.01)
    log.put(records[1])
    log.put(records[2])
    log.close()
    assert log.dropped_bytes == len(records[0]) and log.failed_writes == 1
    assert log.error is not None and log.error.errno == errno.ENOMEM
    assert [bytes(p) for p in LogReader(tmp_path / "a.log")] == [bytes(r[8:]) for r in records[1:]]


def test_a_failed_last_sync_is_never_reported_as_nothing_lost(tmp_path, monkeypatch):
    """Review: writes that failed once and were retried, then a failed fsync at close, was 'nothing lost'."""
    import capture.record_log as record_log

    log = LogWriter(tmp_path / "a.log", fsync=False)
    log.error, log.failed_writes = OSError(errno.ENOSPC, "No space left on device"), 1  # retried since
    real_fsync = record_log.os.fsync

    def fsync_fails(fd):
        raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(record_log.os, "fsync", fsync_fails)
    log.put(encode_record(bytes([RecordType.NOTE]) + b"x"))
    log.close()
    monkeypatch.setattr(record_log.os, "fsync", real_fsync)
    assert not log.lost_nothing
    assert log.failure("recorder log") == (
        "writing the recorder log failed (1 failed writes, 0 bytes not on disk, the last sync to disk "
        "failed): No space left on device"
    )
