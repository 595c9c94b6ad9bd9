"""Speaker style (``speaker_style = true``): the model is told whose face it animates.

People articulate differently (how far the jaw opens, how much the lips round), and a dataset pooled
from several speakers teaches a model their average unless it knows who speaks. As VOCA and
FaceFormer condition on the training subject, the utterance's speaker enters as a one-hot vector
appended to the prosody input at every frame:

- the **styles** are the speakers of the training samples (sorted), recorded in the run's inputs;
- an utterance of one of them gets its one-hot; any other speaker (a held-out speaker, audio given to
  ``predict`` without ``--speaker``) gets the **mean style**, 1/n in every column;
- ``style_dropout``: while training, a window's style is replaced by the mean style with this
  probability, so that the mean style is an input the model has learned, not only an average of
  inputs it has seen.

A linear first layer turns the one-hot into a learned per-speaker vector (an embedding), so every
system of the model table takes it without a change, ridge regression included. An ensemble whose
members trained on different speakers maps the union of their styles onto each member's
(``member_style_map``).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from capture.errors import InputError

MEAN = "mean"  # the style name that asks for the mean style


def style_rows(
    speakers: Sequence[str], styles: Sequence[str], override: str | None = None, dropout: float = 0.0
) -> torch.Tensor:
    """(len(speakers), len(styles)) float32 style vectors: each speaker's one-hot (``override``, when
    given, for every row; ``MEAN`` or an unknown name gives the mean style), each row replaced by the
    mean style with probability ``dropout`` (global torch generator, so a resumed run draws the same)."""
    n = len(styles)
    rows = torch.full((len(speakers), n), 1.0 / n)
    index = {s: i for i, s in enumerate(styles)}
    for b, speaker in enumerate(speakers):
        name = speaker if override is None else override
        if name != MEAN and name in index:
            rows[b] = 0.0
            rows[b, index[name]] = 1.0
    if dropout > 0:
        dropped = torch.rand(len(speakers)) < dropout
        rows[dropped] = 1.0 / n
    return rows


def member_style_map(union: Sequence[str], member: Sequence[str]) -> torch.Tensor:
    """(len(union), len(member)) matrix taking a style vector over ``union`` to one over ``member``: a
    speaker the member knows keeps its one-hot, any other becomes the member's mean style (so the
    union's mean style becomes the member's mean style)."""
    out = torch.full((len(union), len(member)), 1.0 / len(member))
    index = {s: i for i, s in enumerate(member)}
    for i, speaker in enumerate(union):
        if speaker in index:
            out[i] = 0.0
            out[i, index[speaker]] = 1.0
    return out


def check_style(styles: Sequence[str], style: str | None) -> None:
    """Refuse a chosen ``style`` that is not one of the run's ``styles`` or ``MEAN`` (``None``, each
    utterance's own, is always fine)."""
    if style is None:
        return
    if not styles:
        raise InputError("the run has no speaker styles (it was trained without speaker_style)", "--style")
    if style != MEAN and style not in styles:
        raise InputError(f"unknown style {style!r}: the run has {', '.join(styles)} (or {MEAN})", "--style")
