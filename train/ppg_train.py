"""Training the 64-dim bottleneck PPG extractor (``dataset.bottleneck.BottleneckPPG``) on speech with
phone alignments, written with ``save_bottleneck`` for ``s2a-dataset build --ppg bottleneck``.

Alignments come as Praat TextGrids beside their audio (same stem; the simulator writes them beside its
takes; tier ``phones``, or MFA's ``<speaker> - phones`` tiers of a file with several speakers, whose
phones spoken over another speaker's are unknown, said; empty label = silence), as a JSON file
mapping audio stems to ``{"words": [{"phones": [{"phone", "start", "end"}]}]}`` (the LibriVox
sample), or as Gentle's JSON beside its audio (``{"transcript", "words": [{"case", "start", "end",
"phones": [{"phone", "duration"}]}]}``: each word's phones follow each other from its start; words Gentle
did not find in the audio have no time: the stretch between the found words around them is unknown,
said; JSON whose words have no ``case`` is not Gentle's and is passed over). Also read: MFA 3's JSON and
CSV exports beside their audio (``--output_format json``: ``{"tiers": {"phones": {"entries": [[start, end,
label]]}}}``; ``csv``: ``Begin,End,Label,Type,Speaker`` rows, other CSV passed over), read as its
TextGrids; Kaldi CTM phone alignments (capture/ctm.py: one file for many utterances, each the audio file of
its id in the CTM's folder or below; integer ids named by the ``phones.txt`` beside it); WebMAUS's
TextGrid ``MAU`` tier and BAS Partitur ``.par`` (capture/partitur.py), in SAMPA, rewritten in IPA. TIMIT
``.phn`` and ELAN ``.eaf`` files are said not to be read. Phone labels are ARPAbet in
any case, stress digits and Kaldi word-position suffixes (``dh_B``) dropped, TIMIT phones folded, or the
IPA phones of MFA's English models (dataset/phones.py); labels outside these are unknown (with a warning).

Frames are labelled with a phone, silence (SIL), or UNKNOWN: speech no phone can be given to. The
cross-entropy, the held-out accuracy and the chance level leave UNKNOWN frames out (``ignore_index``), so
the PPG is never taught to call speech silence. Silence is what the formats write for no speech: an
empty interval or a stretch no segment covers (pauses between words), ``sil``, ``sp`` (MFA's and Kaldi's
short pause), ``<sil>`` and the recogniser's fillers (``+NSN+``). UNKNOWN is speech: MFA's ``spn``
(spoken noise: a word outside the dictionary or speech it could not transcribe, aligned as one unit),
Gentle's ``oov`` (a word it found in the audio but has no pronunciation for), the stretch of words Gentle
did not find in the audio, phones two speakers say at once, and labels outside the phone set.
Features are the dataset's own log-mel filter banks on its 20 ms grid; frame ``k`` (centre
``k · 20 ms``) takes the phone spanning that instant.

Without alignments (``labels="pocketsphinx"``), speech is labelled by phone-loop recognition with the
English acoustic model bundled in the ``pocketsphinx`` package (``dataset.ppg.PocketsphinxExtractor``):
take folders and audio files are decoded whole and cut at silences into pieces of about ``PIECE_S``.
The bottleneck then learns to reproduce a recogniser trained on far more speech than any dataset here,
on the dataset's own voices and recording conditions, in any language (its labels are English phones).
"""

from __future__ import annotations

import math
import os
import tempfile
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from align.resample import to_16k_mono
from capture import find_takes, read_audio, read_take
from capture.command import progress, warn
from capture.errors import InputError
from capture.importer import AUDIO_SUFFIXES as SPEECH_SUFFIXES
from capture.transfer_litter import Litter
from dataset.bottleneck import CHECKPOINT_FORMAT, BottleneckConfig, BottleneckPPG, load_plain, save_bottleneck
from dataset.features import FeatureSettings, spectral_features
from dataset.phones import phone_index
from dataset.ppg import PocketsphinxExtractor

from .alignments import (
    UNKNOWN,
    Segments,
    files_under,
    find_alignments,
    frame_labels,
    is_silence,
    is_spoken_noise,
)
from .checkpoint import write_atomically

MISMATCH_S = 0.5  # alignment and audio lengths may differ by this much without a warning
LABELS = ("alignments", "pocketsphinx")
PIECE_S = 10.0  # decoded speech is cut into pieces of about this length (at silences) for the held-out split


def find_speech(paths: list[str | Path], warnings: list[str] | None = None) -> list[Path]:
    """Take folders and audio files under ``paths`` (an audio file inside a take folder is its take's);
    operating-system and transfer litter (``._X.wav``, ``__MACOSX``, ...) is left out, one line per kind
    appended to ``warnings``."""
    found: list[Path] = []
    litter = Litter()
    for p in map(Path, paths):
        if not p.exists():
            raise InputError("not found", p)
        if litter.skips(p):
            continue
        if p.is_file():
            found.append(p)
            continue
        takes = find_takes([p])  # none from a recycle bin or a zip's __MACOSX (find_takes passes them over)
        inside = {t.resolve() for t in takes}
        loose = [
            f
            for f in files_under(p, litter)
            if f.suffix.lower() in SPEECH_SUFFIXES  # the audio files s2a-capture import --pair-audio pairs
            and not inside.intersection(f.resolve().parents)
        ]
        found += takes + loose
    if warnings is not None:
        warnings += litter.lines()
    unique = list(dict.fromkeys(f.resolve() for f in found))
    if not unique:
        raise InputError("no take folders or audio files found", paths[0])
    return unique


def _speech(source: Path) -> np.ndarray | None:
    """16 kHz mono samples of an audio file or of a take folder's audio (None: the take has none)."""
    if source.is_dir():
        take = read_take(source)
        return None if take.audio is None else to_16k_mono(take.audio, str(source))
    return to_16k_mono(read_audio(source), str(source))


def pieces_at_silences(
    segments: Segments, duration: float, piece_s: float = PIECE_S
) -> list[tuple[float, float]]:
    """(start, end) s of consecutive pieces covering ``duration``, about ``piece_s`` long each, cut in
    the middle of the silence nearest each multiple (at the multiple itself when none is near)."""
    middles = [(a + b) / 2 for a, b, label in segments if is_silence(label)]
    cuts = [0.0]
    while duration - cuts[-1] > 1.5 * piece_s:
        target = cuts[-1] + piece_s
        near = [m for m in middles if cuts[-1] + 0.5 * piece_s < m < cuts[-1] + 1.5 * piece_s]
        cuts.append(min(near, key=lambda m: abs(m - target)) if near else target)
    cuts.append(duration)
    return list(zip(cuts[:-1], cuts[1:]))


def decoded_utterances(paths: list[str | Path], warnings: list[str], say: Callable[[str], None] = progress):
    """(name, 16 kHz audio, phone segments) pieces of every take folder and audio file under ``paths``,
    labelled by pocketsphinx phone-loop recognition; takes without audio are skipped (``warnings``)."""
    decoder = PocketsphinxExtractor()
    out = []
    for source in find_speech(paths, warnings):
        audio = _speech(source)
        if audio is None:
            warnings.append(f"{source}: take has no audio: skipped")
            continue
        segs = [(a * 0.01, (b + 1) * 0.01, unit) for unit, a, b in decoder.segments(audio)]
        for k, (a, b) in enumerate(pieces_at_silences(segs, audio.size / 16000)):
            piece = audio[int(round(a * 16000)) : int(round(b * 16000))]
            inside = [(max(s, a) - a, min(e, b) - a, u) for s, e, u in segs if min(e, b) > max(s, a)]
            out.append((f"{source.name}#{k}", piece, inside))
        say(f"ppg: {source}: {audio.size / 16000:.1f} s decoded into {len(segs)} segments")
    return out


def train_ppg(
    paths: list[str | Path],
    out: str | Path,
    steps: int = 300,
    seed: int = 0,
    window: int = 200,
    batch_size: int = 8,
    lr: float = 1e-3,
    say: Callable[[str], None] = progress,
    labels: str = "alignments",
) -> dict[str, Any]:
    """Train a BottleneckPPG on every aligned utterance under ``paths`` (``labels="pocketsphinx"``: on
    every take folder and audio file, labelled by phone-loop recognition) and save it to ``out``. Every
    tenth utterance (at least one when there are two or more) is held out for the frame accuracy.
    Utterances without any phone frame are skipped; this and other doubts about the alignments are
    printed as warnings (``warn``: stderr, named by the running command) and listed in the summary."""
    if labels not in LABELS:
        raise InputError(f"--labels must be one of {', '.join(LABELS)}, not {labels!r}")
    if steps < 1:
        raise InputError(f"--steps must be at least 1 (got {steps})")
    if not 0 <= seed < 2**63:
        raise InputError(f"--seed must be between 0 and 2**63 - 1 (got {seed})")
    out = Path(out)
    _check_writable(out)
    settings = FeatureSettings()
    warnings: list[str] = []
    if labels == "pocketsphinx":
        sources = decoded_utterances(paths, warnings, say)
        all_segments = [segs for *_, segs in sources]
    else:
        aligned = find_alignments(paths, warnings)
        all_segments = [segs for _, segs in aligned]
        # read one at a time: a large corpus need not fit in memory as audio
        sources = ((str(path), to_16k_mono(read_audio(path), str(path)), segs) for path, segs in aligned)
    unknown = Counter(
        label.strip()
        for segs in all_segments
        for *_, label in segs
        if not (is_silence(label) or is_spoken_noise(label)) and phone_index(label) is None
    )
    if unknown:
        examples = ", ".join(repr(u) for u, _ in unknown.most_common(5))
        warnings.append(
            f"{sum(unknown.values())} phone segments have labels outside ARPAbet: unknown, left out of "
            f"training ({len(unknown)} different, e.g. {examples})"
        )
    utts = []
    for audio_path, audio, segs in sources:
        fbank = spectral_features(audio, settings)["fbank"]
        ids = frame_labels(segs, len(fbank), settings.hop_s)
        if not (ids > 0).any():
            warnings.append(
                f"{audio_path}: no phone frames (labels all silence or outside ARPAbet, or no segment "
                "inside the audio): skipped"
            )
            continue
        seconds, end = len(audio) / 16000, max(b for _, b, _ in segs if b < math.inf)
        if abs(end - seconds) > MISMATCH_S:
            warnings.append(
                f"{audio_path}: the alignment ends at {end:.2f} s but the audio is {seconds:.2f} s long "
                "(is it the audio that was aligned?)"
            )
        utts.append((torch.from_numpy(fbank), torch.from_numpy(ids)))
    for w in warnings:
        warn(w)
    if not utts:
        if labels == "pocketsphinx":
            raise InputError("pocketsphinx recognised no phones in the audio (silence or noise?)", paths[0])
        raise InputError(
            "no phone frames in the alignments: every label is silence or outside ARPAbet, or lies "
            "past the end of its audio",
            paths[0],
        )
    held = set(range(0, len(utts), 10)) if len(utts) > 1 else set()
    train = [u for i, u in enumerate(utts) if i not in held] or utts
    val = [u for i, u in enumerate(utts) if i in held]
    frames = sum(len(u[1]) for u in train)
    say(
        f"ppg: {len(utts)} utterances ({frames * settings.hop_s / 60:.1f} min for training, "
        f"{len(val)} held out)"
    )
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    model = BottleneckPPG(BottleneckConfig(n_mels=settings.n_mels))
    opt = torch.optim.AdamW(model.parameters(), lr=lr)
    for step in range(steps):
        xs, ys = [], []
        picks = rng.integers(0, len(train), batch_size)
        length = min(window, *(len(train[j][1]) for j in picks))  # crops of one length, no padding
        for j in picks:
            x, y = train[j]
            s = int(rng.integers(0, len(y) - length + 1))
            xs.append(x[s : s + length])
            ys.append(y[s : s + length])
        if all(bool((y == UNKNOWN).all()) for y in ys):  # no frame to learn from (a loss of 0 / 0)
            continue
        _, logits = model(torch.stack(xs))
        loss = F.cross_entropy(
            logits.reshape(-1, logits.shape[-1]), torch.stack(ys).reshape(-1), ignore_index=UNKNOWN
        )
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        if (step + 1) % 50 == 0:
            say(f"ppg step {step + 1}: cross-entropy {loss.item():.3f}")
    model.eval()
    # beside -o under a hidden name, renamed over it once complete: a full disk leaves no truncated
    # checkpoint, and an existing one at -o stays as it was (a one-line error names the file)
    write_atomically(out, lambda tmp: save_bottleneck(model, tmp), "the checkpoint")
    return {
        "checkpoint": str(out),
        "utterances": len(utts),
        "train_frames": frames,
        "steps": steps,
        "train_accuracy": _accuracy(model, train),
        "val_accuracy": _accuracy(model, val) if val else None,
        "majority_accuracy": _majority(train, val or train),
        "warnings": warnings,
    }


def _check_writable(out: Path) -> None:
    """Refuse an output path the checkpoint cannot be written to before training, not after."""
    if out.is_dir():
        raise InputError("is a folder; -o names the checkpoint file to write (e.g. ppg.pt)", out)
    if out.exists():  # replaced only when it is an earlier PPG checkpoint (never a run's best.pt, say)
        if not os.access(out, os.R_OK):
            raise InputError("exists and cannot be read, so it cannot be told to be a PPG checkpoint", out)
        try:
            payload = load_plain(out, "PPG checkpoint")
        except InputError:
            payload = None
        if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
            raise InputError("exists and is not a PPG checkpoint: choose another -o, or remove it first", out)
    existing = next(p for p in out.parents if p.exists())
    if not existing.is_dir():
        raise InputError(f"cannot write the checkpoint: {existing} is a file, not a folder", out)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out.parent):
            pass
    except OSError as exc:
        raise InputError(f"cannot write the checkpoint: {exc.strerror or exc}", out) from None


@torch.no_grad()
def _accuracy(model: BottleneckPPG, utts) -> float:
    """Frame accuracy over the frames with a label (UNKNOWN frames left out)."""
    hit = n = 0
    for x, y in utts:
        _, logits = model(x.unsqueeze(0))
        known = y != UNKNOWN
        hit += int((logits[0].argmax(-1) == y)[known].sum())
        n += int(known.sum())
    return hit / max(n, 1)


def _majority(train, evaluate) -> float:
    """Frame accuracy of always answering the most frequent training phone (the chance level), over the
    frames with a label."""
    ys = torch.cat([y for _, y in train])
    top = int(ys[ys != UNKNOWN].bincount().argmax())
    ys = torch.cat([y for _, y in evaluate])
    ys = ys[ys != UNKNOWN]
    return float((ys == top).float().mean()) if len(ys) else 0.0
