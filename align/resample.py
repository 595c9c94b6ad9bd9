"""Audio to the stage's working format: 16 kHz mono float32, without DC offset or sub-audible rumble.

The rate conversion uses python-soxr (libsoxr's "very high quality" polyphase resampler): it is a
well-kept C library, handles any ratio (44.1 kHz -> 16 kHz is 160/441, awkward for polyphase filters
built from the reduced fraction), keeps the passband flat to 0.9 of Nyquist with >140 dB stopband, and
runs at thousands of times real time, so resampling never dominates an align run. ``scipy.signal.
resample_poly`` would do for the same ratio, but needs a 441-phase filter designed per call and is
slower; soxr is also what the other speech toolkits use.

Several channels become one (``mono_mix``): the channels that carry sound at a level comparable to the
loudest are averaged (a stereo microphone pair); a channel far below the loudest (an idle input, a
second channel holding only hiss or a constant) and a channel holding a timecode signal (LTC recorded on
the second channel, docs/livelinkface-formats.md §7) are left out, since averaging them in only
scales the speech down (6 dB for one idle channel of two, 15.6 dB for dialogue on the centre of 5.1).

A DC offset (a converter's or a cheap interface's bias) and rumble below ``HIGHPASS_HZ`` (handling
noise, wind, building vibration) carry nothing of speech but enter every level-based feature (log
energy, filterbank energies of the low bands): a DC of 0.005 in the leading silence moved a model's
predicted jawOpen from 0.061 to 0.089. They are removed by a zero-phase high-pass at 16 kHz
(``remove_rumble``), which ``s2a-train predict`` uses through ``to_16k_mono`` as well.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from capture import Audio, InputError
from capture.audio_io import full_scale

from .recorded import RecordedAudio, recorded

TARGET_RATE = 16000


# A mix this far (dB) below its loudest channel has cancelled: the channels hold the same sound with
# opposite polarity (a miswired or phase-inverted stereo pair). Two independent channels mix to about
# 3 dB below the louder, so normal audio never comes near it.
CANCELLED_MIX_DB = 20.0
# A channel this far (dB) below the loudest carries no speech of its own (an idle input holding hiss, a
# constant or digital silence): it is left out of the mix. A second microphone of a pair, even one
# turned away from the speaker, stays within about 12 dB.
IDLE_CHANNEL_DB = 25.0
# Zero-phase high-pass (2nd-order Butterworth run forward and backward: 4th-order magnitude, -6 dB at the
# corner): DC and rumble out; -0.3 dB at 60 Hz, the lowest fundamental of a deep voice.
HIGHPASS_HZ = 25.0
DC_NOTE_LEVEL = 1e-3  # a DC offset from -60 dBFS up is recorded in the report (``audio_dc``)
_CHUNK = 1 << 18  # samples per block (16 s at 16 kHz): bounded memory on hour-long takes

# Linear timecode (SMPTE LTC) is a two-level square wave: 80 bits per frame in biphase-mark code, so
# 1,920-4,800 level changes per second at 24-30 fps, with (almost) every sample at one of its two levels.
# Speech never holds 80 % of its samples near its peaks, and heavily clipped vowels, which come closest,
# change sign a few hundred times per second.
TIMECODE_MIN_CROSSINGS_PER_S = 1000.0
TIMECODE_TWO_LEVEL_SHARE = 0.8
_TIMECODE_BLOCK_S = 0.1
_TIMECODE_MAX_BLOCKS = 600  # spread over the take: bounded work on hour-long takes


def _float_channels(block: np.ndarray) -> np.ndarray:
    """Recorded samples (frames x channels) as float32 in [-1, 1): each channel as ``Audio.mono_float``
    makes it of that channel alone."""
    scale = full_scale(block)
    f = block.astype(np.float32)
    if scale != 1.0:
        f /= scale
    return f


def _add64(total: float, x: np.ndarray, square: bool = False) -> float:
    """``total`` plus the float64 sum (``square``: of squares) of the float32 samples ``x``. NumPy sums a
    cast array one buffer (``np.getbufsize()`` samples) at a time, pairwise within it and in order across
    (``np.sum(.., dtype=np.float64)``, ``np.einsum``), and so does this: fed blocks of a whole number of
    buffers, the last bit is the whole array's."""
    step = np.getbufsize()
    for lo in range(0, x.size, step):
        part = x[lo : lo + step]
        if square:
            total += float(np.einsum("i,i->", part, part, dtype=np.float64))
        else:
            total += float(np.add.reduce(part, dtype=np.float64))
    return total


def _level_of(total: float, squares: float, frames: int) -> float:
    """RMS about the mean (a DC offset is no sound) of ``frames`` samples summing to ``total``, their
    squares to ``squares``."""
    n = max(frames, 1)
    mean, square = total / n, squares / n
    return math.sqrt(max(square - mean * mean, 0.0))


def looks_like_timecode(x: np.ndarray, rate: int, scale: float = 1.0) -> bool:
    """True when the samples ``x`` (one channel at ``rate`` Hz, full scale ``scale``) hold a timecode
    signal (LTC) rather than sound: in most of the 0.1 s blocks that are not silent, at least
    ``TIMECODE_TWO_LEVEL_SHARE`` of the samples sit near one of two levels, evenly split between them,
    and the signal changes level at least ``TIMECODE_MIN_CROSSINGS_PER_S`` times a second."""
    block, pick = _timecode_blocks(x.size, rate)
    if pick.size == 0:
        return False
    return _two_levels(x[: (pick[-1] + 1) * block].reshape(-1, block)[pick], rate, scale)


def _timecode_blocks(frames: int, rate: int) -> tuple[int, np.ndarray]:
    """The samples per 0.1 s block of ``looks_like_timecode`` and the numbers of the blocks it looks
    at: at most ``_TIMECODE_MAX_BLOCKS`` spread over ``frames`` samples."""
    block = max(int(rate * _TIMECODE_BLOCK_S), 64)
    nb = frames // block
    if nb == 0:
        return block, np.zeros(0, np.int64)
    return block, np.unique(np.linspace(0, nb - 1, min(nb, _TIMECODE_MAX_BLOCKS)).astype(np.int64))


_TIMECODE_ROWS = 64  # 0.1 s blocks judged at a time: the float64 arrays of all 600 took 100 MB at 48 kHz


def _two_levels(rows: np.ndarray, rate: int, scale: float = 1.0) -> bool:
    """``looks_like_timecode``'s verdict on its 0.1 s blocks ``rows`` (blocks x samples, full scale
    ``scale``), judged ``_TIMECODE_ROWS`` at a time (each block on its own: the same verdict)."""
    width = rows.shape[1]
    active_count = two_level_count = 0
    for lo in range(0, rows.shape[0], _TIMECODE_ROWS):
        b = rows[lo : lo + _TIMECODE_ROWS].astype(np.float64) / scale
        lo_level, hi_level = np.percentile(b, [1.0, 99.0], axis=1)
        half = (hi_level - lo_level) / 2.0
        d = b - ((hi_level + lo_level) / 2.0)[:, None]
        active = half > 1e-3  # above -60 dBFS: a timecode signal is recorded far louder
        near = np.mean(np.abs(d) >= 0.6 * half[:, None], axis=1)
        up = np.mean(d > 0, axis=1)
        crossings = np.count_nonzero(np.diff(np.signbit(d), axis=1), axis=1) / (width / rate)
        two_level = (
            active
            & (near >= TIMECODE_TWO_LEVEL_SHARE)
            & (up > 0.3)
            & (up < 0.7)
            & (crossings >= TIMECODE_MIN_CROSSINGS_PER_S)
        )
        active_count += int(np.count_nonzero(active))
        two_level_count += int(np.count_nonzero(two_level))
    return active_count > 0 and two_level_count >= 0.5 * active_count


def _channels_text(ks: list[int]) -> str:
    """'channel 2' or 'channels 1, 3 and 4' (``ks`` count from 0)."""
    names = [str(k + 1) for k in ks]
    if len(names) == 1:
        return f"channel {names[0]}"
    return f"channels {', '.join(names[:-1])} and {names[-1]}"


def mono_mix(audio: Audio | RecordedAudio) -> tuple[np.ndarray, dict[str, Any] | None]:
    """Mono float32 samples of ``audio`` and ``None`` when all its channels are averaged; otherwise the
    samples and a note (``audio_mix`` of the align report; channels count from 1) saying what was done:

    - ``channels_left_out``: channels holding a timecode signal, and channels more than
      ``IDLE_CHANNEL_DB`` below the loudest (idle), are left out; the others are averaged;
    - ``louder_channel``: the average of the channels kept is more than ``CANCELLED_MIX_DB`` below the
      loudest of them (phase-inverted copies cancel to silence): that channel alone is used.

    The channels are measured and mixed a block at a time (``mix_blocks``): the float32 copies of
    every channel of an hour at 48 kHz stereo took 1.4 GB."""
    source = recorded(audio)
    mix = _Mix(None, None) if source.channels < 2 else _mix_of(source)
    return gathered(mix_blocks(source, mix, _CHUNK), np.empty(source.frames, np.float32)), mix.note


def gathered(blocks: Iterable[np.ndarray], out: np.ndarray) -> np.ndarray:
    """``out``, with ``blocks`` written into it one after another from its start (the rest as it was)."""
    at = 0
    for block in blocks:
        out[at : at + block.size] = block
        at += block.size
    return out


@dataclass
class _Mix:
    """How several channels become one: ``used`` (from 0) averaged, or all of them as ``mono_float``
    averages them (None); ``note`` as ``mono_mix`` says."""

    used: list[int] | None
    note: dict[str, Any] | None


def mix_blocks(source: RecordedAudio, mix: _Mix, size: int) -> Iterator[np.ndarray]:
    """The mono float32 samples of ``mix`` of ``source``'s channels, ``size`` frames at a time."""
    if mix.used is None:
        yield from source.mono_blocks(size)
        return
    for block in source.blocks(size):
        f = _float_channels(block)
        x = np.ascontiguousarray(f[:, mix.used[0]])  # a copy: never the caller's samples
        for k in mix.used[1:]:
            x += f[:, k]
        if len(mix.used) > 1:
            x /= len(mix.used)
        yield x


def _channel_measures(source: RecordedAudio) -> tuple[list[bool], list[float]]:
    """Per channel of ``source``: whether it holds a timecode signal (``looks_like_timecode``) and its
    level (RMS about the mean), measured in one pass through its blocks."""
    n, frames = source.channels, source.frames
    sums, squares = [0.0] * n, [0.0] * n
    width, pick = _timecode_blocks(frames, source.sample_rate)
    starts = pick * width
    seen = np.zeros((n, pick.size, width), source.dtype)  # the 0.1 s blocks the timecode test looks at
    lo = 0
    for block in source.blocks(_CHUNK):
        f = _float_channels(block)
        for k in range(n):
            c = np.ascontiguousarray(f[:, k])
            sums[k], squares[k] = _add64(sums[k], c), _add64(squares[k], c, square=True)
        hi = lo + f.shape[0]
        for i in range(int(np.searchsorted(starts + width, lo, "right")), int(np.searchsorted(starts, hi))):
            at = int(starts[i])
            a, b = max(at, lo), min(at + width, hi)
            seen[:, i, a - at : b - at] = block[a - lo : b - lo].T
        lo = hi
    # judged as float32 in [-1, 1) (each channel as the whole channel's float32 copy held it)
    timecode = [
        bool(pick.size) and _two_levels(_float_channels(seen[k]), source.sample_rate) for k in range(n)
    ]
    return timecode, [_level_of(sums[k], squares[k], frames) for k in range(n)]


def _mix_level(source: RecordedAudio, used: list[int]) -> float:
    """The level (RMS about the mean) of the average of the channels ``used``."""
    total = squares = 0.0
    for x in mix_blocks(source, _Mix(used, None), _CHUNK):
        total, squares = _add64(total, x), _add64(squares, x, square=True)
    return _level_of(total, squares, source.frames)


def _mix_of(source: RecordedAudio) -> _Mix:
    """How ``mono_mix`` mixes the channels of ``source`` (two or more)."""
    n = source.channels
    timecode, levels = _channel_measures(source)
    sound = [k for k in range(n) if not timecode[k]]
    if not sound:  # nothing but timecode: nothing to hear, the speech check reports it
        return _Mix(None, None)
    loud = max(sound, key=lambda k: levels[k])
    if levels[loud] <= 0:  # all silent: the silence check reports it
        return _Mix(None, None)
    left_out: list[dict[str, Any]] = []
    used: list[int] = []
    for k in range(n):
        if timecode[k]:
            left_out.append({"channel": k + 1, "reason": "timecode"})
        elif levels[k] < levels[loud] * 10 ** (-IDLE_CHANNEL_DB / 20):
            below = 20.0 * math.log10(levels[loud] / levels[k]) if levels[k] > 0 else None
            left_out.append(
                {
                    "channel": k + 1,
                    "reason": "idle",
                    "below_loudest_db": None if below is None else round(below, 1),
                }
            )
        else:
            used.append(k)
    dropped = ""
    if left_out:
        parts = [
            f"channel {d['channel']} ("
            + (
                "a timecode signal (LTC), not sound"
                if d["reason"] == "timecode"
                else "idle: "
                + (
                    "silent"
                    if d["below_loudest_db"] is None
                    else f"{d['below_loudest_db']:.1f} dB below channel {loud + 1}"
                )
            )
            + ")"
            for d in left_out
        ]
        dropped = f"{', '.join(parts)} left out of the mix"
    if len(used) > 1:
        mix = _mix_level(source, used)
        below_db = 20.0 * math.log10(levels[loud] / mix) if mix > 0 else None  # None: the mix is silent
        if below_db is None or below_db > CANCELLED_MIX_DB:
            how = (
                "the mix is silent"
                if below_db is None
                else f"the mix is {below_db:.1f} dB below channel {loud + 1}"
            )
            which = f"{n} audio channels" if len(used) == n else f"audio {_channels_text(used)}"
            note: dict[str, Any] = {
                "kind": "audio_mix",
                "method": "louder_channel",
                "channel": loud + 1,
                "channels": n,
                "used_channels": [loud + 1],
                "mix_below_channel_db": None if below_db is None else round(below_db, 1),
                "message": f"the {which} cancel when mixed ({how}; phase-inverted copies?): channel "
                f"{loud + 1} alone is used" + (f"; {dropped}" if dropped else ""),
            }
            if left_out:
                note["left_out"] = left_out
            return _Mix([loud], note)
    if not left_out:
        return _Mix(used, None)
    kept = _channels_text(used) + (" alone is" if len(used) == 1 else " are averaged and")
    note = {
        "kind": "audio_mix",
        "method": "channels_left_out",
        "channels": n,
        "used_channels": [k + 1 for k in used],
        "left_out": left_out,
        "message": f"{dropped}: {kept} used",
    }
    if len(used) == 1:
        note["channel"] = used[0] + 1
    return _Mix(used, note)


def _highpass() -> np.ndarray:
    """``remove_rumble``'s high-pass at ``HIGHPASS_HZ`` as second-order sections."""
    from scipy.signal import butter  # here: scipy.signal adds 0.5 s to every command's start

    return butter(2, HIGHPASS_HZ, btype="highpass", fs=TARGET_RATE, output="sos")


def remove_rumble(
    x: np.ndarray, out: np.ndarray | None = None, tick: Callable[[], None] | None = None
) -> np.ndarray:
    """``x`` (16 kHz float samples) through the zero-phase high-pass at ``HIGHPASS_HZ``: its DC offset and
    sub-audible rumble removed, as float32. Run forward from the steady state of the first sample (a DC
    offset leaves no transient at the start), then backward from rest, in blocks of ``_CHUNK``. ``out``:
    a float32 array of ``x``'s size to write into (``x`` itself: filtered in place, no second copy of an
    hour of audio); None: a new one. ``tick``: called after each block of each pass."""
    n = x.size
    y = np.empty(n, np.float32) if out is None else out
    if n == 0:  # the mean of nothing is nan, with numpy's warnings
        return y
    if n < 64:
        y[:] = np.ascontiguousarray(x - np.mean(x, dtype=np.float64), dtype=np.float32)
        return y
    from scipy.signal import sosfilt, sosfilt_zi

    sos = _highpass()
    zi = sosfilt_zi(sos) * float(x[0])
    for lo in range(0, n, _CHUNK):  # each block is read (as float64) before its place in y is written
        part, zi = sosfilt(sos, np.asarray(x[lo : lo + _CHUNK], dtype=np.float64), zi=zi)
        y[lo : lo + _CHUNK] = part
        if tick is not None:
            tick()
    zi = np.zeros_like(zi)
    for hi in range(n, 0, -_CHUNK):
        lo = max(0, hi - _CHUNK)
        part, zi = sosfilt(sos, y[lo:hi][::-1].astype(np.float64), zi=zi)
        y[lo:hi] = part[::-1]
        if tick is not None:
            tick()
    return y


# Samples after a block that ``rumble_removed`` runs the backward pass over before the block, from rest:
# the high-pass forgets where it started in a time constant of 144 samples (9 ms at 25 Hz); after 57 of
# them what is left of the start is 1e-25 of the signal, far below float32's (or float64's) precision.
RUMBLE_MARGIN = 1 << 13


def rumble_removed(blocks: Iterable[np.ndarray]) -> Iterator[np.ndarray]:
    """``remove_rumble`` of the 16 kHz samples given in ``blocks`` (in order, any lengths), given a block of
    ``_CHUNK`` samples at a time (the last shorter), never all of them at once. The forward pass runs on
    from block to block as remove_rumble's does; the backward pass, which starts at the end, runs over
    each block from ``RUMBLE_MARGIN`` samples after it, from rest (overlap-save): the samples are
    remove_rumble's to float precision, those of the last block and its margin exactly."""
    from scipy.signal import sosfilt, sosfilt_zi

    blocks = iter(blocks)
    start: list[np.ndarray] = [np.zeros(0, np.float32)]
    while sum(b.size for b in start) < 64 and (block := next(blocks, None)) is not None:
        start.append(block)
    first = np.concatenate(start)
    if first.size < 64:  # remove_rumble takes the mean off so few samples
        if first.size:
            yield remove_rumble(first)
        return
    sos = _highpass()
    zi = sosfilt_zi(sos) * float(first[0])
    ahead = np.zeros(0, np.float32)  # filtered forward, not yet backward
    for block in itertools.chain([first], blocks):
        part, zi = sosfilt(sos, np.asarray(block, dtype=np.float64), zi=zi)
        ahead = np.concatenate([ahead, part], dtype=np.float32)  # cast as joined: one copy
        while ahead.size >= _CHUNK + RUMBLE_MARGIN:
            yield _backward(sos, ahead[: _CHUNK + RUMBLE_MARGIN])[:_CHUNK]
            ahead = ahead[_CHUNK:]
    if ahead.size:
        yield _backward(sos, ahead)  # from the end, as remove_rumble starts it


def _backward(sos: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``y`` (float32) through the high-pass ``sos`` backward in time from rest, as float32."""
    from scipy.signal import sosfilt

    part = sosfilt(sos, y[::-1].astype(np.float64), zi=np.zeros((sos.shape[0], 2)))[0]
    return part[::-1].astype(np.float32)


def in_rows(blocks: Iterable[np.ndarray], size: int, tail: bool = False) -> Iterator[np.ndarray]:
    """Samples given in ``blocks`` (1-D, any lengths) as rows of ``size``, in order, a block's rows at a
    time: the last partial row left out (with ``tail``: last, as a row of its own length)."""
    rest = np.zeros(0, np.float32)
    for block in blocks:
        x = np.concatenate([rest, block]) if rest.size else block  # a block in one piece: no copy
        n = x.size // size
        yield x[: n * size].reshape(n, size)
        rest = x[n * size :]
    if tail and rest.size:
        yield rest.reshape(1, rest.size)


def mono_blocks(audio: Audio | RecordedAudio) -> Iterator[np.ndarray]:
    """``audio.mono_float()`` in blocks of ``_CHUNK`` frames: the same float32 samples (mono_float works
    frame by frame), without an hour of them at the file's rate in memory at once."""
    return recorded(audio).mono_blocks(_CHUNK)


def sum64(blocks: Iterable[np.ndarray]) -> float:
    """The float64 sum of float32 samples given in blocks of a whole number of NumPy buffers (the last
    may be shorter), bit for bit ``np.sum(all, dtype=np.float64)`` (``_add64``). A DC offset is
    subtracted from every sample: its last bit matters."""
    total = 0.0
    for block in blocks:
        total = _add64(total, block)
    return total


def mono_mean(audio: Audio | RecordedAudio) -> float:
    """``np.mean(audio.mono_float(), dtype=np.float64)`` (the mean of nothing: nan) without a float32
    copy of all the audio at its own rate: 635 MB for an hour at 44.1 kHz."""
    return sum64(mono_blocks(audio)) / audio.frames if audio.frames else math.nan


def _resampled(blocks: Iterable[np.ndarray], rate: int, frames: int) -> np.ndarray:
    """The float32 samples of ``blocks`` (``frames`` of them at ``rate`` Hz) at ``TARGET_RATE``, resampled
    as ``soxr.resample`` does it (libsoxr streams: the same samples, block by block)."""
    if rate == TARGET_RATE:
        return gathered(blocks, np.empty(frames, np.float32))
    y = np.empty(round(frames * TARGET_RATE / rate) + 16, np.float32)  # soxr gives the rounded length
    at = 0
    for part in _resampled_blocks(blocks, rate):
        y, at = _put(y, at, part)
    if at < y.size:
        y.resize(at, refcheck=False)  # shrunk where it lies: no copy
    return y


def _resampled_blocks(blocks: Iterable[np.ndarray], rate: int) -> Iterator[np.ndarray]:
    """``_resampled``'s samples a block at a time, as libsoxr gives them."""
    if rate == TARGET_RATE:
        yield from blocks
        return
    import soxr

    stream = soxr.ResampleStream(rate, TARGET_RATE, 1, dtype="float32", quality="VHQ")
    for block in blocks:
        yield stream.resample_chunk(block, last=False)
    yield stream.resample_chunk(np.zeros(0, np.float32), last=True)


def _put(y: np.ndarray, at: int, part: np.ndarray) -> tuple[np.ndarray, int]:
    """``part`` written into ``y`` from ``at`` (``y`` grown when it is too short); (``y``, the new end)."""
    if at + part.size > y.size:
        y = np.concatenate([y[:at], np.zeros(at + part.size - y.size + (1 << 16), np.float32)])
    y[at : at + part.size] = part
    return y, at + part.size


class _Work:
    """The blocks of ``to_16k_mono``'s work, counted for ``on_block``: the mean and the resampling go
    through the input's blocks, the filter's two passes through the output's."""

    def __init__(self, frames: int, rate: int, on_block: Callable[[int, int], None] | None):
        out = round(frames * TARGET_RATE / rate)
        self.total = 2 * -(-frames // _CHUNK) + (2 * -(-out // _CHUNK) if out >= 64 else 0)
        self.done, self.on_block = 0, on_block
        if on_block is not None:  # said as the work begins: its rate is timed from here
            on_block(0, self.total)

    def tick(self) -> None:
        self.done = min(self.done + 1, self.total)
        if self.on_block is not None:
            self.on_block(self.done, self.total)

    def through(self, blocks: Iterable[np.ndarray]) -> Iterator[np.ndarray]:
        for block in blocks:
            yield block
            self.tick()

    def finish(self) -> None:
        if self.on_block is not None and self.done < self.total:
            self.on_block(self.total, self.total)


def to_16k_mono(
    audio: Audio | RecordedAudio,
    path: str | None = None,
    notes: list[dict[str, Any]] | None = None,
    on_block: Callable[[int, int], None] | None = None,
) -> np.ndarray:
    """The audio as mono float32 samples at 16 kHz (values in [-1, 1)), the channels mixed by
    ``mono_mix`` and the DC offset and rumble removed by ``remove_rumble``. With ``notes``, the mix's
    note (``kind`` ``audio_mix``) and, when the mix held a DC offset of at least ``DC_NOTE_LEVEL``, a note
    on it (``kind`` ``audio_dc``) are appended. ``on_block(done, total)``: called after each block of
    work (the mean, the resampling and the filter's two passes go ``_CHUNK`` samples at a time), so that
    an hour of audio can say how far it has come (and once with 0 done as it begins). ``audio`` may be
    a ``RecordedAudio`` reading the take's file: mono is then never whole in memory at its own rate, and
    several channels only while they are mixed."""
    rate, frames, blocks = _mono_source(audio, path, notes)
    work = _Work(frames, rate, on_block)
    dc = sum64(work.through(blocks())) / max(frames, 1)
    y = _resampled(work.through(_off(blocks(), dc)), rate, frames)
    remove_rumble(y, out=y, tick=work.tick)
    work.finish()
    if notes is not None and abs(dc) >= DC_NOTE_LEVEL:
        db = 20.0 * math.log10(abs(dc))
        notes.append(
            {
                "kind": "audio_dc",
                "dc_offset": round(dc, 6),
                "dc_offset_dbfs": round(db, 1),
                "highpass_hz": HIGHPASS_HZ,
                "message": f"the audio holds a DC offset of {dc:+.4f} ({db:.1f} dBFS): removed, with any "
                f"rumble below {HIGHPASS_HZ:g} Hz, by a zero-phase high-pass",
            }
        )
    return y


def to_16k_passes(
    audio: Audio | RecordedAudio, path: str | None = None
) -> Callable[[], Iterator[np.ndarray]]:
    """``to_16k_mono``'s samples without all of them in memory: a function that gives them in blocks, in
    order, each call a new pass through the audio (read, mixed, resampled and filtered again a block at
    a time: ``rumble_removed``), the same samples to float precision. Its DC offset is measured here,
    in a pass of its own."""
    rate, frames, blocks = _mono_source(audio, path, None)
    dc = sum64(blocks()) / max(frames, 1)
    return lambda: rumble_removed(_resampled_blocks(_off(blocks(), dc), rate))


def _mono_source(
    audio: Audio | RecordedAudio, path: str | None, notes: list[dict[str, Any]] | None
) -> tuple[int, int, Callable[[], Iterator[np.ndarray]]]:
    """The rate, the frame count and the mono float32 samples of ``audio`` (a pass through them, ``_CHUNK``
    frames a block, each call), its channels mixed by ``mono_mix``'s rule, whose note is appended to
    ``notes``; audio too slow for speech is an ``InputError``."""
    source = recorded(audio)
    if source.channels == 1:  # mono: read block by block from the recorded samples, never whole as float32
        note = None

        def blocks() -> Iterator[np.ndarray]:
            return source.mono_blocks(_CHUNK)
    else:  # the channels measured, then mixed, block by block: never whole at their own rate
        mix = _mix_of(source)
        note = mix.note

        def blocks() -> Iterator[np.ndarray]:
            return mix_blocks(source, mix, _CHUNK)

    if note is not None and notes is not None:
        notes.append(note)
    check_speech_rate(source.sample_rate, path)
    return source.sample_rate, source.frames, blocks


def check_speech_rate(rate: int, path: str | None = None) -> None:
    """An ``InputError`` for audio at ``rate`` Hz: too low for speech below 8 kHz."""
    if rate < 8000:
        raise InputError(f"audio sample rate {rate} Hz is too low for speech (need ≥ 8 kHz)", path)


def _off(blocks: Iterable[np.ndarray], dc: float) -> Iterable[np.ndarray]:
    """``blocks`` with the DC offset ``dc`` taken off: before resampling, which would ring on the step
    from 0 at the start."""
    return (b - np.float32(dc) for b in blocks) if dc != 0.0 else blocks
