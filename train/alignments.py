"""Reading phone alignments: (audio file, phone segments in seconds) for every aligned utterance under the
paths given (``find_alignments``), and the phone id of every analysis frame (``frame_labels``; ``UNKNOWN``:
speech without a phone).

Read: Praat TextGrids (a ``phones`` tier, MFA's ``<speaker> - phones`` tiers, or WebMAUS's ``MAU`` tier in
SAMPA), the toolkit's JSON, Gentle's JSON, MFA 3's JSON and CSV exports, Kaldi CTM and BAS Partitur ``.par``;
TIMIT ``.phn`` and ELAN ``.eaf`` files are said not to be read (docs/train.md, "PPG extractor").
"""

from __future__ import annotations

import csv
import json
import math
import os
import stat
from pathlib import Path

import numpy as np

from capture.ctm import has_integer_phones, read_ctm, read_symbol_table
from capture.errors import InputError
from capture.paired import read_text
from capture.partitur import read_maus_phones
from capture.textgrid import TextGrid, Tier, interval_tier, read_textgrid
from capture.transfer_litter import Litter
from dataset.phones import phone_index, sampa_to_ipa, without_word_position

AUDIO_SUFFIXES = (".wav", ".flac", ".WAV", ".FLAC")
Segments = list[tuple[float, float, str]]
UNKNOWN = -100  # frame label of speech without a phone: left out of the loss and the accuracies
UNPLACED = "spn"  # segment label of speech the aligner did not place (spoken noise, as MFA writes it)
MAUS_TIER = "MAU"  # WebMAUS's phone tier (SAMPA), read when a TextGrid has no phones tier
MFA_CSV_HEADER = ["begin", "end", "label", "type", "speaker"]  # mfa align --output_format csv
NOT_READ = {".phn": "TIMIT .phn", ".eaf": "ELAN .eaf"}  # alignments of formats not read: skipped, said
# An utterance aligned in several formats (MFA's TextGrids and its JSON export of the same run) is read from
# the first of these (suffixes in any case); its other alignments are passed over, said in one line per pair
# of formats. Within one format, the first file in sorted path order wins.
FORMAT_PREFERENCE = (
    "TextGrid",
    "MFA JSON",
    "MFA CSV",
    "BAS Partitur",
    "Gentle JSON",
    "the toolkit's JSON",
    "Kaldi CTM",
)
MFA_SNAP_S = 0.02  # MFA's JSON/CSV writers move every end within 2 frames (of 10 ms) of the file's end to it
FORMATS_READ = (
    "read: Praat TextGrids with a 'phones', MFA '<speaker> - phones' or WebMAUS 'MAU' tier; the toolkit's, "
    "Gentle's and MFA's JSON; MFA's CSV; Kaldi CTM; BAS Partitur .par"
)


def _phone_id(label: str) -> int:
    """The frame label of a segment label: its phone, 0 for silence, UNKNOWN for any other."""
    if is_silence(label):
        return 0
    index = phone_index(label)
    return UNKNOWN if index is None else index


def is_silence(label: str) -> bool:
    """Labels aligners write for no speech: empty, SIL, SP, or fillers like +NSN+ and <sil>."""
    p = without_word_position(label).upper()
    return p in ("", "SIL", "SP") or p.startswith(("+", "<"))


def is_spoken_noise(label: str) -> bool:
    """Labels aligners write for speech without phones: SPN (MFA's spoken noise or unknown word), OOV
    (Gentle's unknown word, ``oov_S``)."""
    return without_word_position(label).upper() in ("SPN", "OOV")


def _utterance_audio(alignment: Path, stem: str) -> Path:
    """The audio of utterance ``stem`` of alignment JSON ``alignment``: the key names a file inside the
    JSON's folder (a relative path without ``..``), never one anywhere else on disk."""
    rel = Path(stem)
    if not rel.name or rel.is_absolute() or ".." in rel.parts:
        raise InputError(
            f"utterance key {_show(stem)} must name an audio file inside the alignment's folder "
            "(a relative path without '..')",
            alignment,
        )
    return _audio_beside(alignment.parent / rel)


def files_under(folder: Path, litter: Litter) -> list[Path]:
    """The files in and below ``folder``, sorted, less operating-system and transfer litter (``._X.wav``,
    anything under ``__MACOSX`` or ``$RECYCLE.BIN``), which is counted in ``litter``."""
    files = []
    for f in sorted(folder.rglob("*")):
        here = folder
        for part in f.relative_to(folder).parts:
            here = here / part
            if litter.skips(here):  # the topmost litter folder is counted, not each file in it
                break
        else:
            if f.is_file():
                files.append(f)
    return files


def _audio_of(path: Path) -> list[Path]:
    """The audio file named as ``path`` (the first of ``AUDIO_SUFFIXES``) in a list; [] for none."""
    return [p for p in map(path.with_suffix, AUDIO_SUFFIXES) if p.is_file()][:1]


def _audio_beside(path: Path) -> Path:
    if audio := _audio_of(path):
        return audio[0]
    raise InputError("no audio file (.wav, .flac) with the same name", path)


def _show(value: object) -> str:
    text = json.dumps(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _seconds(value: object, where: str, path: Path) -> float:
    seconds = math.nan
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        try:
            seconds = float(value)
        except OverflowError:  # an integer literal too long for a float (1e400 written out)
            pass
    if not math.isfinite(seconds):
        raise InputError(f"{where} must be a finite number of seconds, found {_show(value)}", path)
    return seconds


def _read_json(path: Path) -> tuple[object, str | None]:
    """The JSON document in ``path`` (UTF-8, UTF-16 or UTF-32 text as ``capture.paired.read_text``
    reads it), or None and why it could not be read."""
    try:
        text = read_text(path)
    except InputError as exc:  # its message names the file (and line): the reason alone is wanted here
        where = f"{exc.path}" + (f":{exc.line}" if exc.line is not None else "") + ": "
        return None, str(exc).removeprefix(where)
    try:
        return json.loads(text), None
    except json.JSONDecodeError as exc:
        return None, f"not valid JSON ({exc.msg} at line {exc.lineno}, column {exc.colno})"
    except ValueError as exc:  # an integer of more digits than Python converts (4300)
        return None, f"not readable JSON ({exc})"
    except RecursionError:
        return None, "nested too deeply to read"


def _json_segments(words: object, stem: str, path: Path) -> tuple[Segments, list[str]]:
    """Phone segments of one JSON utterance, and where each comes from (for messages)."""
    if not isinstance(words, list):
        raise InputError(f"utterance {stem!r}: 'words' must be a list, found {_show(words)}", path)
    segs: Segments = []
    names: list[str] = []
    for i, word in enumerate(words):
        where = f"utterance {stem!r} word {i}"
        if not isinstance(word, dict):
            raise InputError(f"{where}: expected an object with 'phones', found {_show(word)}", path)
        phones = word.get("phones", [])
        if not isinstance(phones, list):
            raise InputError(f"{where}: 'phones' must be a list, found {_show(phones)}", path)
        for k, ph in enumerate(phones):
            at = f"{where} phone {k}"
            if not isinstance(ph, dict):
                raise InputError(f"{at}: expected an object with phone, start, end, found {_show(ph)}", path)
            for key in ("phone", "start", "end"):
                if key not in ph:
                    raise InputError(f"{at}: no {key!r}", path)
            if not isinstance(ph["phone"], str):
                raise InputError(f"{at}: 'phone' must be a string, found {_show(ph['phone'])}", path)
            start, end = (
                _seconds(ph["start"], f"{at}: 'start'", path),
                _seconds(ph["end"], f"{at}: 'end'", path),
            )
            segs.append((start, end, ph["phone"]))
            names.append(at)
    return segs, names


def _is_gentle(data: dict) -> bool:
    """Whether a JSON document is Gentle's: a ``words`` list whose words say their ``case`` (every word
    Gentle writes does). Other JSON with a ``words`` list (a speech-to-text service's transcript beside
    its audio) is no alignment, passed over as before."""
    words = data.get("words")
    return isinstance(words, list) and any(isinstance(w, dict) and "case" in w for w in words)


def _gentle_segments(words: list, path: Path) -> tuple[Segments, list[str], int]:
    """Phone segments of a Gentle alignment (``words`` of its JSON), where each comes from, and how many
    words have no time (Gentle's ``"not-found-in-audio"``): they were said between the found words around
    them, so that stretch (from the start or to the end of the audio for words first or last) is one
    UNPLACED segment."""
    segs: Segments = []
    names: list[str] = []
    untimed = 0
    unplaced_from: float | None = None  # end of the found word before words not found (0: none before)
    reached = 0.0
    for i, word in enumerate(words):
        where = f"word {i}"
        if not isinstance(word, dict):
            raise InputError(
                f"{where}: expected an object with case, start, phones, found {_show(word)}", path
            )
        if word.get("case") == "not-found-in-audio" or "start" not in word:
            untimed += 1
            if unplaced_from is None:
                unplaced_from = reached
            continue
        phones = word.get("phones")
        if not isinstance(phones, list):
            raise InputError(f"{where}: 'phones' must be a list, found {_show(phones)}", path)
        t = _seconds(word["start"], f"{where}: 'start'", path)
        if unplaced_from is not None and unplaced_from < t:
            segs.append((unplaced_from, t, UNPLACED))
            names.append(f"the words not found before {where}")
        unplaced_from = None
        for k, ph in enumerate(phones):
            at = f"{where} phone {k}"
            if not (isinstance(ph, dict) and isinstance(ph.get("phone"), str) and "duration" in ph):
                raise InputError(f"{at}: expected an object with phone and duration, found {_show(ph)}", path)
            # to the microsecond: a sum of decimal durations is off by float error at the phone boundaries
            # (Gentle's fall on 10 ms, where every other 20 ms frame centre lies)
            end = round(t + _seconds(ph["duration"], f"{at}: 'duration'", path), 6)
            segs.append((t, end, ph["phone"]))
            names.append(at)
            t = end
        reached = max(reached, t)
    if unplaced_from is not None:
        segs.append((unplaced_from, math.inf, UNPLACED))
        names.append("words not found at the end")
    return segs, names, untimed


def _check_segments(segs: Segments, names: list[str], path: Path) -> None:
    """Refuse negative times, segments ending before they start, and overlapping segments."""
    reached, previous = 0.0, ""
    for k in sorted(range(len(segs)), key=lambda k: segs[k][0]):
        start, end, _ = segs[k]
        if start < 0:
            raise InputError(f"{names[k]} starts at a negative time ({start} s)", path)
        if end < start:
            raise InputError(f"{names[k]} ends before it starts ({start} > {end} s)", path)
        if start < reached - 1e-6:
            raise InputError(
                f"{names[k]} ({start}-{end} s) overlaps {previous} (to {reached} s); phones must not overlap",
                path,
            )
        if end >= reached:
            reached, previous = end, names[k]


def _spoken_over(segs: Segments, speakers: list[str]) -> set[int]:
    """Indices of the segments that overlap a segment of another speaker (crosstalk: no one phone
    labels those frames)."""
    over: set[int] = set()
    active: list[int] = []
    for k in sorted(range(len(segs)), key=lambda k: segs[k][0]):
        active = [j for j in active if segs[j][1] > segs[k][0] + 1e-6]
        for j in active:
            if speakers[j] != speakers[k]:
                over |= {j, k}
        active.append(k)
    return over


def _phone_tiers(grid: TextGrid) -> tuple[list[Tier], bool]:
    """A grid's phone tiers (``phones``, MFA's ``<speaker> - phones``, else WebMAUS's ``MAU``) and whether
    their labels are SAMPA (the ``MAU`` tier's)."""
    try:
        return grid.speaker_tiers("phones"), False
    except InputError:
        if any(t.name == MAUS_TIER for t in grid.tiers):
            return [grid.tier(MAUS_TIER)], True
        raise


def _grid_segments(grid: TextGrid, path: Path, warnings: list[str]) -> Segments:
    """Phone segments of a grid's phone tier, or of its speakers' (MFA's ``<speaker> - phones``): each
    speaker's silence left out, phones spoken over another speaker's made UNPLACED, and the tiers'
    silence after the last phone kept; SAMPA labels in IPA. Point tiers and crosstalk are added to
    ``warnings``."""
    tiers, sampa = _phone_tiers(grid)
    segs, names, speakers = [], [], []
    for tier in tiers:
        if tier.kind != "IntervalTier":  # no phones: reported as such in train_ppg
            warnings.append(f"{path}: tier {tier.name!r} is a point tier ({tier.kind}), not intervals")
        tier_segs = [(iv.xmin, iv.xmax, sampa_to_ipa(iv.text) if sampa else iv.text) for iv in tier.intervals]
        tier_names = [f"tier {tier.name!r} interval {k + 1}" for k in range(len(tier_segs))]
        _check_segments(tier_segs, tier_names, path)
        for seg, name in zip(tier_segs, tier_names):
            # one speaker's silence spans the others' speech: their phones alone are kept
            if len(tiers) == 1 or not is_silence(seg[2]):
                segs.append(seg)
                names.append(name)
                speakers.append(tier.name)
    crosstalk = _spoken_over(segs, speakers)
    if crosstalk:
        first = names[min(crosstalk, key=lambda k: segs[k][0])]
        warnings.append(
            f"{path}: {len(crosstalk)} phones overlap another speaker's (the first: {first}): their "
            "stretch of audio is unknown, left out of training"
        )
        segs = [(a, b, UNPLACED) if k in crosstalk else (a, b, x) for k, (a, b, x) in enumerate(segs)]
    last, end = max((b for _, b, _ in segs), default=0.0), max(t.xmax for t in tiers)
    if end > last:  # the tiers' silence after the last phone, left out above: where they end
        segs.append((last, end, ""))
    return segs


def _grid_of(tiers: dict[str, Segments], start: float, end: float | None, path: Path) -> TextGrid:
    """A grid of interval tiers from ``(start, end, label)`` segments (gaps silent), over ``start`` to
    ``end`` (None: the last segment's end), read from ``path``."""
    end = max([b for segs in tiers.values() for _, b, _ in segs], default=start) if end is None else end
    grid = TextGrid(
        start, end, [interval_tier(name, sorted(segs), start, end) for name, segs in tiers.items()]
    )
    grid.path = str(path)
    return grid


def _is_mfa_json(data: dict) -> bool:
    """Whether JSON is MFA's (``tiers``: an object of tiers, each an object with ``entries``); other JSON
    with a ``tiers`` field (a settings file) is no alignment."""
    tiers = data.get("tiers")
    return (
        isinstance(tiers, dict)
        and bool(tiers)
        and all(isinstance(t, dict) and "entries" in t for t in tiers.values())
    )


def _mfa_json_grid(data: dict, path: Path) -> tuple[TextGrid, int]:
    """The grid of MFA's JSON (``mfa align --output_format json``): ``{"start", "end", "tiers": {name:
    {"type": "interval", "entries": [[start, end, label], ...]}}}``, tiers named as in its
    TextGrids; and how many phones were mended (``_unsnapped``)."""
    tiers: dict[str, Segments] = {}
    for name, tier in data["tiers"].items():
        entries = tier.get("entries") if isinstance(tier, dict) else None
        if not isinstance(entries, list):
            raise InputError(
                f"tier {name!r}: expected an object with an 'entries' list, found {_show(tier)}", path
            )
        tiers[name] = []
        for k, entry in enumerate(entries):
            where = f"tier {name!r} entry {k}"
            if not (isinstance(entry, list) and len(entry) == 3 and isinstance(entry[2], str)):
                raise InputError(f"{where}: expected [start, end, label], found {_show(entry)}", path)
            a, b = _seconds(entry[0], f"{where}: start", path), _seconds(entry[1], f"{where}: end", path)
            tiers[name].append((a, b, entry[2]))
    start = _seconds(data.get("start", 0), "'start'", path)
    end = _seconds(data["end"], "'end'", path) if "end" in data else None
    unsnapped = 0
    for name in tiers:
        if name == "phones" or name.endswith(" - phones"):  # the tiers read (words' times are not checked)
            tiers[name], n = _unsnapped(tiers[name], end)
            unsnapped += n
            _check_segments(tiers[name], [f"tier {name!r} entry {k}" for k in range(len(tiers[name]))], path)
    return _grid_of(tiers, start, end, path), unsnapped


def _unsnapped(segs: Segments, end: float | None) -> tuple[Segments, int]:
    """MFA's phones as its TextGrid writer leaves them, and how many were mended: its JSON and CSV writers
    move the end of every interval within ``MFA_SNAP_S`` of the file's end (``end``; None: the last end) to
    that end, its TextGrid writer only the last interval's, so a phone before a last phone shorter than
    that overlaps it. Such a phone ends again where the next begins."""
    end = max((b for _, b, _ in segs), default=0.0) if end is None else end
    segs, mended = list(segs), 0
    order = sorted(range(len(segs)), key=lambda k: segs[k][0])
    for k, j in zip(order, order[1:]):
        a, b, label = segs[k]
        begin = segs[j][0]
        if abs(b - end) < 1e-6 and a < begin < b and end - begin < MFA_SNAP_S + 1e-6:
            segs[k] = (a, begin, label)
            mended += 1
    return segs, mended


def _is_mfa_csv(path: Path) -> bool | str:
    """Whether a CSV file starts with the header of MFA's (``Begin,End,Label,Type,Speaker``); other CSV
    (a Live Link Face take's) is no alignment. A CSV that cannot be read (no permission, a dangling link,
    a folder or a FIFO of that name: opened without waiting for a writer) is why, as text."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as exc:
        return exc.strerror or str(exc)
    with open(fd, "rb") as f:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return "not a regular file"
        try:
            head = f.read(200).decode("utf-8-sig", errors="replace").splitlines()
        except OSError as exc:
            return exc.strerror or str(exc)
    return bool(head) and [c.strip().lower() for c in head[0].split(",")] == MFA_CSV_HEADER


def _mfa_csv_grid(path: Path) -> tuple[TextGrid, int]:
    """The grid of MFA's CSV (``mfa align --output_format csv``: a row per word and phone, ``Type``
    ``words`` or ``phones``): a ``phones`` tier, or ``<speaker> - phones`` for each of several speakers; and
    how many phones were mended (``_unsnapped``)."""
    by_speaker: dict[str, Segments] = {}
    lines: dict[str, list[str]] = {}  # each speaker's phones' line numbers, to name them in messages
    rows = csv.reader(read_text(path).splitlines())
    next(rows)
    for number, row in enumerate(rows, start=2):
        if not row:
            continue
        if len(row) != 5:
            raise InputError(f"expected Begin,End,Label,Type,Speaker, found {len(row)} fields", path, number)
        if row[3].strip().lower() != "phones":
            continue
        a, b = (
            _seconds(_number_or_text(v), f"line {number}: {k}", path) for v, k in zip(row, ("Begin", "End"))
        )
        by_speaker.setdefault(row[4], []).append((a, b, row[2]))
        lines.setdefault(row[4], []).append(f"line {number}")
    end, unsnapped = max((b for segs in by_speaker.values() for _, b, _ in segs), default=0.0), 0
    for speaker, segs in by_speaker.items():
        by_speaker[speaker], n = _unsnapped(segs, end)
        unsnapped += n
        _check_segments(by_speaker[speaker], lines[speaker], path)
    several = len(by_speaker) > 1
    tiers = {f"{s} - phones" if several else "phones": segs for s, segs in by_speaker.items()}
    return _grid_of(tiers, 0.0, None, path), unsnapped


def _number_or_text(text: str) -> object:
    try:
        return float(text)
    except ValueError:
        return text


def _ctm_utterances(path: Path, warnings: list[str]) -> list[tuple[Path, Segments]]:
    """(audio, phone segments) of each utterance of a Kaldi CTM: its audio is the file named by the
    utterance id in the CTM's folder or below (for a CTM of one utterance, also the audio of the CTM's own
    name beside it). Integer phone ids are named by the ``phones.txt`` beside it. Utterances without
    one audio file are left out, and a CTM whose labels are mostly not phones (words) is skipped: said in
    ``warnings``."""
    utterances = read_ctm(path)
    if has_integer_phones(utterances):
        table_path = path.parent / "phones.txt"
        if not table_path.is_file():
            warnings.append(
                f"{path}: the phones are Kaldi's integer ids and no phones.txt lies beside it (copy the "
                "lang folder's phones.txt there, or name them with utils/int2sym.pl -f 5 phones.txt): skipped"
            )
            return []
        table = read_symbol_table(table_path)
        utterances = {u: [(a, b, table.get(x, x)) for a, b, x in segs] for u, segs in utterances.items()}
    spoken = [
        x for segs in utterances.values() for *_, x in segs if not (is_silence(x) or is_spoken_noise(x))
    ]
    not_phones = [x for x in spoken if phone_index(x) is None]
    if 2 * len(not_phones) > len(spoken):  # a CTM of words (an ASR's output), not of phones
        examples = ", ".join(map(repr, list(dict.fromkeys(not_phones))[:3]))
        warnings.append(f"{path}: most labels are not phones (e.g. {examples}): a CTM of words? skipped")
        return []
    below: dict[str, list[Path]] | None = None  # audio files in and below the CTM's folder, by stem
    found, missing, several = [], [], []
    for utt, segs in utterances.items():
        _check_segments(segs, [f"utterance {utt!r} phone {k}" for k in range(len(segs))], path)
        plain = Path(utt).name == utt and utt not in ("..", ".")  # no folder in it: the audio beside the CTM
        matches = (
            [p for p in (path.parent / (utt + s) for s in AUDIO_SUFFIXES) if p.is_file()][:1] if plain else []
        )
        if not matches:
            if below is None:
                below = {}
                for f in files_under(path.parent, Litter()):
                    if f.suffix in AUDIO_SUFFIXES:
                        below.setdefault(f.stem, []).append(f)
            matches = below.get(utt, [])
        if not matches and len(utterances) == 1:
            matches = _audio_of(path)
        if len(matches) == 1:
            found.append((matches[0], segs))
        else:
            (several if matches else missing).append(utt)
    for utts, why in (
        (missing, "have no audio file (.wav, .flac) of that name"),
        (several, "match audio files in several folders"),
    ):
        if utts:
            warnings.append(
                f"{path}: {len(utts)} of {len(utterances)} utterances {why} in {path.parent} or below "
                f"(e.g. {', '.join(map(repr, utts[:3]))}): left out"
            )
    return found


def find_alignments(
    paths: list[str | Path], warnings: list[str] | None = None
) -> list[tuple[Path, Segments]]:
    """(audio file, phone segments in seconds) for every aligned utterance under ``paths``, in the order
    first found. Files given twice (also through a folder and a file in it) are read once; an utterance
    aligned twice is read from the alignment of the first format in ``FORMAT_PREFERENCE``; ``warnings``
    collects what is skipped or mended."""
    warnings = [] if warnings is None else warnings
    found: dict[Path, tuple[Path, Segments, Path, str]] = {}  # by audio: (audio, segments, source, format)
    seen_files: set[Path] = set()
    repeated = 0
    litter = Litter()
    # files of a format not read, by suffix (each file once, however often named): one line per format
    not_read: dict[str, dict[Path, Path]] = {}
    passed: dict[Path, list[tuple[Path, str]]] = {}  # by audio: (source, format) of alignments passed over
    unsnapped: list[tuple[Path, int]] = []  # MFA JSON/CSV files with phones mended, and how many

    def add(audio: Path, segs: Segments, source: Path, form: str) -> None:
        key, new = audio.resolve(), (audio, segs, source, form)
        if key not in found:
            found[key] = new
            return
        kept, over = found[key], new  # ties: the first found (in sorted path order) is kept
        if FORMAT_PREFERENCE.index(form) < FORMAT_PREFERENCE.index(kept[3]):
            kept, over = over, kept
        found[key] = kept  # in the place of the first found: the held-out utterances stay where they were
        passed.setdefault(key, []).append((over[2], over[3]))

    def mfa(grid_and_mended: tuple[TextGrid, int], f: Path, form: str) -> None:
        grid, mended = grid_and_mended
        if mended:
            unsnapped.append((f, mended))
        add(_audio_beside(f), _grid_segments(grid, f, warnings), f, form)

    for p in map(Path, paths):
        if not p.exists():
            raise InputError("not found", p)
        if litter.skips(p):
            continue
        files = files_under(p, litter) if p.is_dir() else [p]
        for f in files:
            kind = f.suffix.lower()
            if kind in NOT_READ:
                not_read.setdefault(kind, {}).setdefault(f.resolve(), f)
                continue
            if kind not in (".textgrid", ".json", ".ctm", ".par", ".csv"):
                continue
            if kind == ".csv":
                mfa_csv = _is_mfa_csv(f)
                if isinstance(mfa_csv, str):  # a take's CSV, say, that cannot be read: never the run's end
                    warnings.append(
                        f"{f}: cannot be read ({mfa_csv}) to tell whether it is MFA's CSV: passed over"
                    )
                if mfa_csv is not True:
                    continue
            if f.resolve() in seen_files:
                repeated += 1
                continue
            seen_files.add(f.resolve())
            if kind == ".textgrid":
                add(_audio_beside(f), _grid_segments(read_textgrid(f), f, warnings), f, "TextGrid")
                continue
            if kind == ".csv":
                mfa(_mfa_csv_grid(f), f, "MFA CSV")
                continue
            if kind == ".ctm":
                for audio, segs in _ctm_utterances(f, warnings):
                    add(audio, segs, f, "Kaldi CTM")
                continue
            if kind == ".par":
                segs = [(a, b, sampa_to_ipa(x)) for a, b, x in read_maus_phones(f)]
                if not segs:
                    warnings.append(f"{f}: no MAU tier (a BAS Partitur's phone segmentation): skipped")
                    continue
                _check_segments(segs, [f"MAU segment {k + 1}" for k in range(len(segs))], f)
                add(_audio_beside(f), segs, f, "BAS Partitur")
                continue
            data, problem = _read_json(f)
            if problem is not None:  # an alignment or not, a file the user gave is never dropped silently
                warnings.append(f"{f}: {problem}: skipped")
                continue
            if not isinstance(data, dict):
                continue
            if _is_mfa_json(data):  # MFA's JSON for the audio beside it
                mfa(_mfa_json_grid(data, f), f, "MFA JSON")
                continue
            if _is_gentle(data):  # Gentle's output for the audio beside it
                segs, names, untimed = _gentle_segments(data["words"], f)
                _check_segments(segs, names, f)
                if untimed:
                    warnings.append(
                        f"{f}: {untimed} of {len(data['words'])} words have no time (Gentle did not find "
                        "them in the audio): their stretch of audio is unknown, left out of training"
                    )
                add(_audio_beside(f), segs, f, "Gentle JSON")
                continue
            for stem, utt in data.items():
                if not (isinstance(utt, dict) and "words" in utt):
                    continue
                segs, names = _json_segments(utt["words"], stem, f)
                _check_segments(segs, names, f)
                add(_utterance_audio(f, stem), segs, f, "the toolkit's JSON")
    for kind, files in not_read.items():
        more = f" and {len(files) - 1} more" if len(files) > 1 else ""
        warnings.append(
            f"{next(iter(files.values()))}{more}: {NOT_READ[kind]} alignments are not read ({FORMATS_READ}): "
            "skipped"
        )
    if repeated:
        warnings.append(
            f"--data names {repeated} file(s) more than once (also through their folder): each is read once"
        )
    twice: dict[tuple[str, str], list[Path]] = {}  # (format used, format passed over): sources passed over
    for key, others in passed.items():
        for source, form in others:
            twice.setdefault((found[key][3], form), []).append(source)
    for (used, over), sources in twice.items():
        n = f"{len(sources):,} utterance{'s have' if len(sources) > 1 else ' has'}"
        if used == over:
            how = f"two {used} alignments: the first in path order used, the other"
        else:
            how = f"alignments in two formats: {used} used, {over}"
        warnings.append(f"{n} {how} passed over (e.g. {sources[0]})")
    if unsnapped:
        more = (
            f" and {len(unsnapped) - 1} more file{'s' if len(unsnapped) > 2 else ''}"
            if len(unsnapped) > 1
            else ""
        )
        warnings.append(
            f"{unsnapped[0][0]}{more}: {sum(n for _, n in unsnapped)} phones end at the file's end over the "
            f"last phone (MFA's JSON and CSV export moves every end within {MFA_SNAP_S * 1000:.0f} ms of the "
            "end to it): they end where the next phone begins, as in MFA's TextGrids"
        )
    warnings += litter.lines()
    if not found:
        skipped = f"; {warnings[-1]}" if warnings else ""  # why the one file given gave nothing
        raise InputError(f"no phone alignments found ({FORMATS_READ}){skipped}", paths[0])
    return [(audio, segs) for audio, segs, *_ in found.values()]


def frame_labels(segments: Segments, n_frames: int, hop_s: float) -> np.ndarray:
    """Phone id per analysis frame (centre ``k · hop_s`` s): SIL outside every segment, UNKNOWN in
    speech without a phone."""
    labels = np.zeros(n_frames, np.int64)
    t = np.arange(n_frames) * hop_s
    for start, end, label in segments:
        labels[(t >= start) & (t < end)] = _phone_id(label)
    return labels
