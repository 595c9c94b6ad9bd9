"""A session's audio read a span at a time (``SessionAudio.read``) from the logs a killed or damaged
recorder leaves: written by the real writers (``AudioLog``), then damaged byte-wise."""

from __future__ import annotations

import numpy as np
import pytest

from capture.audio_capture import CHUNK_S, AudioLog, index_audio_log
from capture.errors import InputError

RATE = 44100
CHUNK = int(RATE * CHUNK_S)


def chunk_samples(c: int, version: int = 0) -> np.ndarray:
    """Chunk ``c``'s stereo samples, each its own (``version``: other samples at the same index)."""
    k = np.arange(c * CHUNK, (c + 1) * CHUNK) * 7 + version * 1001
    return np.stack([k % 65521 - 32760, k % 30011 - 15000], axis=1).astype(np.int16)


def write_log(path, chunks: list[tuple[int, int]]) -> None:
    """An audio log of the chunks (index, version) in that order, stamped on a 1 s clock origin."""
    log = AudioLog(path, fsync=False)
    log.format = {"sample_rate": RATE, "channels": 2, "subtype": "PCM_16"}  # a writer appending too
    if not path.stat().st_size > 8:
        log.start(RATE, 2, "PCM_16", "test")
    for c, version in chunks:
        log.add_chunk(c * CHUNK, 10**9 + c * CHUNK * 10**9 // RATE, chunk_samples(c, version))
    log.close()


def test_spans_of_a_damaged_out_of_order_log_are_the_samples_its_valid_chunks_hold(tmp_path):
    # 40 chunks written out of order, four twice, chunk 9 again later with other samples (the later wins),
    # a byte of chunk 20's samples flipped (its record fails its checksum: silence), and a torn tail; then
    # a writer appends chunks 40-44 after the index was made. Every span read is what the valid chunks hold.
    rng = np.random.default_rng(3)
    order = [(int(c), 0) for c in rng.permutation(40)] + [(3, 0), (10, 0), (11, 0), (39, 0), (9, 1)]
    path = tmp_path / "audio.log"
    write_log(path, order)
    data = bytearray(path.read_bytes())
    record = 8 + 17 + CHUNK * 4  # header, chunk head, samples
    at = len(data) - (len(order) - order.index((20, 0))) * record  # records all of one size
    assert data[at + 9 : at + 17] == (20 * CHUNK).to_bytes(8, "little")  # its first sample's index
    data[at + 5000] ^= 0x40
    path.write_bytes(bytes(data[:-3000]))  # the last chunk (9, version 1) torn
    audio, report = index_audio_log(path)
    write_log(path, [(c, 0) for c in range(40, 45)])  # the log still growing
    expected = np.concatenate([chunk_samples(c) for c in range(40)])
    expected[20 * CHUNK : 21 * CHUNK] = 0
    assert report["torn_tail"]["reason"] == "incomplete_record" and len(report["log_damage"]) == 1
    assert audio.frames == 40 * CHUNK and report["gaps"] == [{"at_sample": 20 * CHUNK, "samples": CHUNK}]
    assert np.array_equal(audio.read().samples, expected)
    for lo, hi in [(0, 1), (CHUNK - 1, CHUNK + 1), (9 * CHUNK + 5, 21 * CHUNK + 3), (39 * CHUNK, 40 * CHUNK)]:
        assert np.array_equal(audio.read(lo, hi).samples, expected[lo:hi])
    # chunk 9 rewritten later in the file, not torn: the later one's samples
    write_log(tmp_path / "again.log", [(c, 0) for c in range(12)] + [(9, 1)])
    again, _ = index_audio_log(tmp_path / "again.log")
    assert np.array_equal(again.read(9 * CHUNK, 10 * CHUNK).samples, chunk_samples(9, 1))


def test_a_log_changed_since_it_was_indexed_is_an_error_not_other_samples(tmp_path):
    # The samples of an indexed chunk overwritten in place (the log copied over, another recorder's log
    # moved there): read the offsets it had indexed and returned the new bytes as the session's audio.
    path = tmp_path / "audio.log"
    write_log(path, [(c, 0) for c in range(10)])
    audio, _ = index_audio_log(path)
    data = bytearray(path.read_bytes())
    data[len(data) // 2 : len(data) // 2 + 4] = b"\x00\x7f\x00\x7f"
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match="changed since it was indexed"):
        audio.read(4 * CHUNK, 6 * CHUNK)
    path.write_bytes(bytes(data[: len(data) // 3]))  # or cut short
    with pytest.raises(InputError, match="changed since it was indexed"):
        audio.read(8 * CHUNK, 9 * CHUNK)
