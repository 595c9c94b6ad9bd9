"""Curves: chosen channels of takes and predictions over time on one axis, the speech waveform and its
voice-activity segments beneath (the paper's Figure 1). Matplotlib with the Agg backend; PNG or SVG.

Speech segments come from, in order: the take's own align report (aligned takes carry the segments
VAD found), else align's VAD (silero-vad's bundled model, nothing downloaded), else, only when align's
VAD cannot run, an energy threshold, which the figure labels as a fallback.
"""

from __future__ import annotations

import math
import re
import warnings
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from capture import Audio
from capture.atomic import atomic_write
from capture.channels import CHANNEL_SETS, canonical, channel_set, is_known
from capture.errors import InputError

from .output import writing
from .render import MOVING_MOUTH, Animation, holds_channel, most_moving_mouth

VAD_METHODS = ("auto", "silero", "webrtc", "energy", "none")


def _index(name: str) -> int:
    from capture.channels import ARKIT61

    return ARKIT61.index(canonical(name))


def curve(anim: Animation, name: str) -> np.ndarray | None:
    """Values of channel ``name`` (canonical when a Live Link channel) over ``anim``'s frames; None when
    its take has no such channel."""
    if not holds_channel(anim, name):
        return None
    return anim.others[name] if name in anim.others else anim.weights[:, _index(name)]


def selected_channels(spec: str, anims: Sequence[Animation]) -> tuple[list[str], list[str]]:
    """The channels ``--channels`` names that the inputs hold: a set name (those of the set any input
    holds) or a comma list of Live Link channels (any spelling) and of the inputs' other channels (a
    rig's own controls, by their exact names), each held by at least one input; and the channels named
    more than once (``jawOpen,JawOpen``), which are drawn once."""
    is_set = spec.strip().lower() in CHANNEL_SETS
    repeated: list[str] = []
    if is_set:
        names = [n for n in channel_set(spec) if any(holds_channel(a, n) for a in anims)]
        missing = [] if names else [spec.strip()]
    else:
        names = [canonical(n) if is_known(n) else n for n in (p.strip() for p in spec.split(",")) if n]
        if not names:
            raise InputError(f"empty channel selection {spec!r}")
        repeated = list(dict.fromkeys(n for n in names if names.count(n) > 1))
        names = list(dict.fromkeys(names))  # in the order first named
        missing = [n for n in names if not any(holds_channel(a, n) for a in anims)]
    if missing:
        what = f"a channel of set {missing[0]!r}" if is_set else f"channel {missing[0]!r}"
        raise InputError(
            f"no input holds {what}{_rig_controls(anims)}; name channels of the inputs, or a set "
            f"({', '.join(CHANNEL_SETS)})"
        )
    return names, repeated


def _rig_controls(anims: Sequence[Animation]) -> str:
    """' (they hold N rig controls: a, b, ...)' when the inputs hold channels that are not Live Link's."""
    others = sorted({n for a in anims for n in a.others})
    if not others:
        return ""
    more = ", ..." if len(others) > 5 else ""
    return f" (they hold {len(others)} rig controls: {', '.join(others[:5])}{more})"


DEFAULT_CHANNEL = "jawOpen"


def default_channel(anims: Sequence[Animation]) -> tuple[str, str | None]:
    """The channel plotted when none is named: jawOpen, and None. When no input holds jawOpen (a rig's
    export without it, which was an error that did not say jawOpen was only the default), the mouth
    channel that moves most, lips parting first (``most_moving_mouth``), and a note saying so."""
    if any(holds_channel(a, DEFAULT_CHANNEL) for a in anims):
        return DEFAULT_CHANNEL, None
    mouth = most_moving_mouth(anims)
    if mouth is None:
        raise InputError(
            f"no input holds {DEFAULT_CHANNEL}, the default channel, and no mouth channel of theirs moves"
            f"{_rig_controls(anims)}: give --channels, channels of the inputs or a set "
            f"({', '.join(CHANNEL_SETS)})"
        )
    return mouth, (
        f"no input holds {DEFAULT_CHANNEL}, the default channel: plotted {mouth}, {MOVING_MOUTH}; give "
        "--channels to choose"
    )


def audio_frames(audio: Audio, size: int, tail: bool = False) -> Iterator[np.ndarray]:
    """The mono float32 samples of ``audio`` (``Audio.mono_float``) as rows of ``size``, in order, the last
    partial row left out (with ``tail``: last, as a row of its own length): a block of the file at a time
    (all of them as float, and copies, took 2.5 GB for two hours at 16 kHz)."""
    from align.resample import in_rows, mono_blocks

    return in_rows(mono_blocks(audio), size, tail)


def energy_segments(audio: Audio, min_silence_s: float = 0.3) -> list[tuple[float, float]]:
    """Speech-like stretches by frame energy: 20 ms frames above the 20th-percentile level + 15 dB."""
    hop = max(1, int(audio.sample_rate * 0.02))
    power = [np.mean(f.astype(np.float64) ** 2, axis=1) for f in audio_frames(audio, hop)]
    e = 10 * np.log10(np.concatenate([np.zeros(0), *power]) + 1e-10)
    if e.size == 0:
        return []
    flags = e > np.percentile(e, 20) + 15.0
    from align.vad import runs_to_segments

    return runs_to_segments(flags, hop / audio.sample_rate, min_silence_s, 0.1)


def speech_segments(anim: Animation, method: str = "auto") -> tuple[list[tuple[float, float]], str]:
    """Speech segments of ``anim``'s audio in take time (s), and where they come from (a label)."""
    if anim.audio is None or method == "none":
        return [], ""
    take = anim.take
    report = (take.meta.extra.get("align") if take is not None else None) or {}
    if method == "auto" and report.get("speech_segments") is not None:
        return [(float(a), float(b)) for a, b in report["speech_segments"]], "speech (align report)"
    if method in ("auto", "silero", "webrtc"):
        detector = "silero" if method == "auto" else method
        try:
            from align.resample import check_speech_rate, to_16k_passes
            from align.vad import check_detector, vad_gain
            from align.vad import speech_segments as vad_segments

            check_speech_rate(anim.audio.sample_rate)
            check_detector(detector)
        except (ImportError, InputError) as exc:  # the detector cannot run: the energy threshold, or said
            if method != "auto":
                raise InputError(f"--vad {method} is not available here: {exc}") from None
        else:
            # align's 16 kHz audio, a block at a time: a pass for its level, another for the detector (the
            # audio unreadable, or its file rewritten since it was read, is an error of its own)
            passes = to_16k_passes(anim.audio)
            gain = vad_gain(passes())
            segs = vad_segments(passes(), detector, gain)
            off = anim.audio_start_s
            return [(a + off, b + off) for a, b in segs], f"speech ({detector} VAD)"
    segs = energy_segments(anim.audio)
    off = anim.audio_start_s
    fallback = ", fallback: no VAD model" if method == "auto" else ""  # --vad energy: asked for
    return [(a + off, b + off) for a, b in segs], f"loud (energy threshold{fallback})"


# Fonts with Chinese, Japanese and Korean characters, as common systems install them: matplotlib's own
# DejaVu Sans has none, and take names and titles are often written in them.
CJK_FONTS = (
    "Noto Sans CJK JP",
    "Noto Sans CJK SC",
    "Source Han Sans",
    "WenQuanYi Zen Hei",
    "Microsoft YaHei",
    "PingFang SC",
    "Hiragino Sans",
    "Arial Unicode MS",
)
_MISSING_GLYPH = re.compile(r"Glyph (?P<code>\d+) .* missing from font")


@contextmanager
def labels_in_any_script(plt: Any) -> Iterator[list[str]]:
    """Inside, text falls back to an installed font that has its characters (CJK_FONTS after DejaVu
    Sans); yields the list it fills with the characters still drawn as boxes (matplotlib warns once per
    glyph and draw: those warnings become that list; other warnings pass)."""
    from matplotlib import font_manager

    installed = {f.name for f in font_manager.fontManager.ttflist}
    families = ["DejaVu Sans"] + [f for f in CJK_FONTS if f in installed]
    undrawable: list[str] = []
    with plt.rc_context({"font.family": families}), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield undrawable
    for w in caught:
        m = _MISSING_GLYPH.search(str(w.message))
        if m is None:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        else:
            char = chr(int(m["code"]))
            if char not in undrawable:
                undrawable.append(char)


def plot_curves(
    anims: Sequence[Animation],
    out: str | Path,
    channels: str | None = None,
    vad: str = "auto",
    start_s: float | None = None,
    end_s: float | None = None,
    width_in: float = 10.0,
    title: str | None = None,
) -> dict:
    """Write the figure to ``out`` (.png or .svg); returns what was drawn.

    Times are seconds after each animation's first frame plus its ``offset_s`` (how predictions line
    up with the recording they come from; an aligned segment sits at its place in its parent take).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    if out.suffix.lower() not in (".png", ".svg"):
        raise InputError("the plot is written as .png or .svg", out)
    if not anims:
        raise InputError("nothing to plot")
    fallback = None
    if channels is None:
        channels, fallback = default_channel(anims)
    names, repeated = selected_channels(channels, anims)
    for flag, v in (("--start", start_s), ("--end", end_s)):
        if v is not None and not math.isfinite(v):
            raise InputError(f"{flag} must be a number of seconds, not {v}")
    if start_s is not None and end_s is not None and start_s >= end_s:
        raise InputError(f"--start {start_s:g} s must come before --end {end_s:g} s")
    times = [a.time - a.t0 + a.offset_s for a in anims]
    lo = start_s if start_s is not None else -math.inf
    hi = end_s if end_s is not None else math.inf
    if not any(((t >= lo) & (t <= hi)).any() for t in times):
        first, last = min(float(t[0]) for t in times), max(float(t[-1]) for t in times)
        raise InputError(
            f"--start/--end hold no frame: the inputs span {first:.3f}..{last:.3f} s (after the first frame)"
        )
    with labels_in_any_script(plt) as undrawable:
        voice = next((a for a in anims if a.audio is not None), None)
        rows = len(names) + (1 if voice is not None else 0)
        ratios = [2.0] * len(names) + ([1.2] if voice is not None else [])
        fig, axes = plt.subplots(
            rows,
            1,
            sharex=True,
            figsize=(width_in, 1.6 * sum(ratios) / 2 + 0.8),
            gridspec_kw={"height_ratios": ratios},
            squeeze=False,
        )
        axes = axes[:, 0]
        colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        t_max = 0.0
        handles: dict[int, Any] = {}  # one legend entry per input, from whichever row draws it
        for r, name in enumerate(names):
            ax = axes[r]
            for i, a in enumerate(anims):
                t = a.time - a.t0 + a.offset_s
                t_max = max(t_max, float(t[-1]))
                values = curve(a, name)
                if values is not None:
                    marker = (
                        "o" if t.size == 1 else None
                    )  # one frame is a point: a line through it is not drawn
                    (line,) = ax.plot(
                        t, values, color=colors[i % len(colors)], lw=1.2, marker=marker, ms=4, label=a.label
                    )
                    handles.setdefault(i, line)
            ax.set_ylabel(name, rotation=0, ha="right", va="center")
            ax.grid(alpha=0.3)
        shown = [handles[i] for i in sorted(handles)]
        axes[0].legend(handles=shown, loc="upper right", fontsize="small", ncol=min(len(shown), 4))
        silent = [a.label for i, a in enumerate(anims) if i not in handles]
        segments: list[tuple[float, float]] = []
        vad_label = ""
        if voice is not None:
            ax = axes[-1]
            sr = voice.audio.sample_rate
            step = max(1, voice.audio.frames // 20000)  # enough points for the envelope, few for the SVG
            lows, highs = [np.zeros(0, np.float32)], [np.zeros(0, np.float32)]
            peak = 0.0  # of every sample: the last few, left out of the envelope, too
            for block in audio_frames(voice.audio, step, tail=True):
                peak = max(peak, float(np.abs(block).max(initial=0.0)))
                if block.shape[1] == step:
                    lows.append(block.min(axis=1))
                    highs.append(block.max(axis=1))
            low, high = np.concatenate(lows), np.concatenate(highs)
            tt = voice.audio_start_s - voice.t0 + voice.offset_s + np.arange(low.size) * step / sr
            ax.fill_between(tt, low, high, color="0.35", lw=0)
            t_max = max(t_max, float(tt[-1]) if tt.size else 0.0)
            segments, vad_label = speech_segments(voice, vad)
            for j, (a, b) in enumerate(segments):
                ax.axvspan(
                    a - voice.t0 + voice.offset_s,
                    b - voice.t0 + voice.offset_s,
                    color="tab:green",
                    alpha=0.25,
                    lw=0,
                    label=vad_label if j == 0 else None,
                )
            ax.set_ylabel(f"speech\n{voice.label}", rotation=0, ha="right", va="center")
            if segments:
                ax.legend(loc="upper right", fontsize="small")
            lim = peak or 1.0
            ax.set_ylim(-lim * 1.05, lim * 1.05)
            ax.set_yticks([])
        axes[-1].set_xlabel("time (s)")
        left = start_s if start_s is not None else 0.0
        right = end_s if end_s is not None else t_max
        if right <= left:  # one frame and no audio: a frame period either side of it, not an empty range
            pad = 1.0 / max(a.fps for a in anims)
            left, right = left - pad, right + pad
        axes[-1].set_xlim(left, right)
        if title:
            fig.suptitle(title)
        fig.tight_layout()
        try:
            with writing(out, "plot"), atomic_write(out) as f:
                fig.savefig(f, dpi=100, format=out.suffix[1:].lower())
        finally:
            plt.close(fig)
    return {
        "output": str(out),
        "inputs": [a.label for a in anims],
        "inputs_without_these_channels": silent,  # drawn nowhere: they hold none of the channels
        "channels": names,
        "channel_note": fallback,  # what was plotted instead of the default channel, and why
        "repeated_channels": repeated,  # named more than once in --channels, drawn once
        "undrawable_characters": "".join(undrawable),  # in labels, no installed font has them: boxes
        "duration_s": round(t_max, 6),
        "speech_segments": [[round(a, 4), round(b, 4)] for a, b in segments],
        "audio_file": str(voice.audio_file) if voice is not None and voice.audio_file else None,
        "vad": vad_label or None,
    }
