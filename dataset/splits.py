"""Splits by take or by speaker, never by window.

NeuroSync splits overlapping windows at random, so neighbouring windows of one take land in train and
test; here a whole recording (``--split-by take``: an aligned take together with the other segments
align cut from the same raw take) or a whole speaker (``--split-by speaker``: the held-out speaker
split for cross-speaker evaluation) goes to one split. Pinned takes, recordings or speakers
(``--test``, ``--val``) go first; the rest are ordered by a seeded hash of their id (stable when takes
are added) and taken while they bring each split closer to its fraction of the total duration. A split
with a fraction above 0 that no group brings closer (every free group is over twice its target) gets
the shortest free group. Train always keeps at least one (pins that leave it none are an error).
"""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass, field
from typing import Any

from capture.errors import InputError

SPLITS = ("train", "val", "test")


@dataclass(frozen=True)
class SplitRule:
    """How takes are split. Fractions are of total audio duration."""

    by: str = "take"
    val_fraction: float = 0.1
    test_fraction: float = 0.1
    seed: int = 0
    val: tuple[str, ...] = field(default_factory=tuple)
    test: tuple[str, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        if self.by not in ("take", "speaker"):
            raise InputError(f"--split-by must be take or speaker, not {self.by!r}")
        for name, f in (("--val-fraction", self.val_fraction), ("--test-fraction", self.test_fraction)):
            if not 0.0 <= f < 1.0:
                raise InputError(f"{name} must be in [0, 1), got {f}")
        if self.val_fraction + self.test_fraction >= 1.0:
            raise InputError("--val-fraction + --test-fraction must be below 1")
        both = set(self.val) & set(self.test)
        if both:
            raise InputError(f"pinned to both val and test: {', '.join(sorted(both))}")

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["val"], d["test"] = sorted(self.val), sorted(self.test)
        return d


def _order(seed: int, name: str) -> str:
    """A name's place in the seeded shuffle: the sha256 of its bytes (a name not UTF-8 by its own bytes)."""
    return hashlib.sha256(f"{seed}:{name}".encode("utf-8", "surrogateescape")).hexdigest()


def speaker_key(name: str) -> str:
    """What identifies a speaker: the name without case or extra spacing (``Anna`` and ``anna `` typed
    on two phones are one person; the build merges such spellings, and pins match them)."""
    return " ".join(name.split()).casefold()


def pinned_groups(
    takes: dict[str, tuple[str, float]],
    rule: SplitRule,
    recordings: dict[str, str] | None = None,
    assumed: set[str] | None = None,
) -> tuple[dict[str, str], dict[str, str]]:
    """``({take id: its group}, {pinned group: split})``: the groups a split keeps together (a
    recording's takes by take, a speaker's by speaker) and those that ``--val``/``--test`` pin. A pin
    names a take or recording exactly (two takes may differ only in case) or a speaker in any case
    or spacing (``speaker_key``). ``assumed`` holds the takes whose speaker no ``meta.subject`` names:
    theirs is a recording id, matched exactly as take ids are (``Take1`` and ``take1`` are two)."""
    recording = {t: (recordings or {}).get(t) or t for t in takes}
    group_of = {t: (recording[t] if rule.by == "take" else spk) for t, (spk, _) in takes.items()}
    assumed = assumed or set()

    def pinned_by(t: str, spk: str, pins: tuple[str, ...]) -> bool:
        """Whether ``pins`` name take ``t`` of speaker ``spk``: by take, recording or speaker."""
        if t in pins or recording[t] in pins:
            return True
        return spk in pins if t in assumed else speaker_key(spk) in {speaker_key(p) for p in pins}

    for pinned in (*rule.val, *rule.test):
        if not any(pinned_by(t, spk, (pinned,)) for t, (spk, _) in takes.items()):
            take_ids = set(takes) | set(recording.values())
            near = sorted(t for t in take_ids if t.casefold() == pinned.casefold())
            hint = f" (take ids match exactly, case included: {near[0]!r}?)" if near else ""
            raise InputError(f"pinned take or speaker {pinned!r} is not among the inputs{hint}")
    split_of_group: dict[str, str] = {}
    for split, pinned in (("test", rule.test), ("val", rule.val)):
        for t, (spk, _) in takes.items():
            if pinned_by(t, spk, pinned):
                g = group_of[t]
                if split_of_group.get(g, split) != split:
                    raise InputError(f"{g!r} is pinned to both val and test (via take, recording or speaker)")
                split_of_group[g] = split
    return group_of, split_of_group


def assign_splits(
    takes: dict[str, tuple[str, float]],
    rule: SplitRule,
    recordings: dict[str, str] | None = None,
    assumed: set[str] | None = None,
) -> dict[str, str]:
    """``{take id: split}`` for ``takes`` = ``{take id: (speaker id, duration in s)}``; ``recordings``
    maps a take id to the recording it was cut from (by default each take is its own); ``assumed``: the
    takes whose speaker is assumed (see ``pinned_groups``)."""
    group_of, split_of_group = pinned_groups(takes, rule, recordings, assumed)
    durations: dict[str, float] = {}
    for t, (_, dur) in takes.items():
        durations[group_of[t]] = durations.get(group_of[t], 0.0) + dur
    total = sum(durations.values())
    free = sorted((g for g in durations if g not in split_of_group), key=lambda g: _order(rule.seed, g))
    for split, fraction in (("test", rule.test_fraction), ("val", rule.val_fraction)):
        have = sum(durations[g] for g, s in split_of_group.items() if s == split)
        target = fraction * total
        if have == 0 and fraction > 0 and len(free) > 1:
            # the first group (in seeded order) that brings the empty split closer to its target, else
            # the shortest: one long recording must not turn a 10 % split into most of the data
            closer = [g for g in free if durations[g] < 2 * target]
            g = closer[0] if closer else min(free, key=lambda g: durations[g])
            free.remove(g)
            split_of_group[g] = split
            have = durations[g]
        while free and len(free) > 1 and have < target and fraction > 0:
            # take a group only if it brings the split closer to its target
            g = free[0]
            if abs(have + durations[g] - target) > abs(have - target):
                break
            free.pop(0)
            split_of_group[g] = split
            have += durations[g]
    if durations and not free:  # the fractions never take the last group, but pins may
        unit = "speaker" if rule.by == "speaker" else "recording"
        raise InputError(
            f"--val/--test pin all {len(durations)} {unit}(s) of the inputs: none is left for the training "
            "split; pin fewer"
        )
    for g in free:
        split_of_group[g] = "train"
    return {t: split_of_group[group_of[t]] for t in takes}
