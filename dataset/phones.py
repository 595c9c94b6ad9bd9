"""The phone set of the toolkit's PPG: the 39 CMU/ARPAbet phones (as pocketsphinx's en-us model and
CMUdict use them) with silence first, and how the labels aligners write map onto it.

Aligners and corpora write ARPAbet in several dialects: stress digits (``AH0``), lower case, and the
TIMIT phones that the 39-phone set folds away (Lee and Hon 1989, as in the usual TIMIT 61 -> 39
mapping): ``ax`` and ``ax-h`` are ``AH``, ``axr`` is ``ER``, ``ix`` is ``IH``, ``ux`` is ``UW``, the
syllabic ``el em en eng`` are ``L M N NG``, ``nx`` is ``N``, ``hv`` is ``HH``, the flap ``dx`` is ``T``
(its commonest source in American English, as in "water"), and closures, pauses and the glottal stop
(``bcl dcl gcl pcl tcl kcl h# pau epi q``) are silence. Kaldi-based aligners (Gentle, Kaldi's own
word-position-dependent phones) end each phone with its place in the word: ``dh_B`` (begin), ``ah_I``
(inside), ``t_E`` (end), ``ah_S`` (a word of one phone); the suffix is dropped.

Montreal Forced Aligner's English IPA models (``english_mfa``, ``english_us_mfa``, ``english_uk_mfa``)
write an IPA phone set ("MFA IPA phone set", mfa-models docs/source/mfa_phone_set.md): aspirated
stops ``pʰ tʰ kʰ cʰ``, palatalised allophones before front vowels and /j/ (``c ɟ ç ʎ ɲ`` for k g h l n),
labialised ``tʷ kʷ ɡʷ``, the flap ``ɾ``, glottal ``ʔ``, dark and syllabic ``ɫ ɫ̩ m̩ n̩``, length
marks, fronted ``ʉ``, central ``ɐ`` for STRUT and glides in diphthongs (``aj aw ej ow ɔj``). ``IPA``
maps each onto the ARPAbet phone of the same articulation, as MFA's own benchmark maps them onto TIMIT
(mfa-models scripts/alignment_benchmarks/mapping_files/mfa_timit_mapping.yaml), folded as above:
allophones of a phoneme (aspirated, palatalised, labialised, unreleased, long, dental-marked
``n̪``) are that phoneme; ``ɾ`` is T and ``ʔ`` silence, as TIMIT's ``dx`` and ``q``; ``ɾ̃`` (nasal flap,
TIMIT ``nx``) is N; the dental stops ``t̪ d̪`` MFA writes for TH and DH pronounced as stops (its "dental
stopping" variants) are TH and DH, as its TIMIT mapping has them (a tongue at the teeth, for a face).
The Indian and Nigerian phones of ``english_mfa`` (and of ``english_india_mfa``, ``english_nigeria_mfa``)
by the same rule: retroflex ``ʈ ɖ`` are T and D (Indian English's /t d/), ``ʋ`` V (Indian English's /v/,
lips to teeth), the labial-velar stops ``kp ɡb`` P and B (lips closed, as a face shows them).
Vowels by quality: ``i iː`` IY, ``ɪ ɨ`` IH, ``e ej eɪ`` EY, ``ɛ ɛː`` EH, ``æ a`` AE, ``ɑ ɑː ɒ ɒː`` AA (LOT,
as CMUdict writes it), ``ɔ ɔː`` AO, ``ʌ ɐ ə`` AH, ``ɚ ɝ ɜ ɜː`` ER, ``ʊ`` UH, ``u uː ʉ ʉː`` UW, ``o ow oʊ
əw əʊ`` OW (``əw`` is British GOAT), ``aj aɪ`` AY, ``aw aʊ`` AW, ``ɔj ɔɪ`` OY. ARPAbet is tried first,
so a label that reads as both (``b``, ``aw``, ``y``) keeps its ARPAbet meaning.

Centring diphthongs (British NEAR, CURE, SQUARE: ``ɪə ʊə eə ɛə``, WebMAUS's ``I@ U@ e@``) have no phone of
their own in the 39; each is the phone of its first element, IH UH EH: that vowel is what the lips and jaw
hold, and the glide to ``ə`` is the mouth relaxing towards rest (CMUdict writes these words with the same
vowel before R: ``IH R``, ``UH R``, ``EH R``; the R is not said in non-rhotic speech and not added here).

The tap ``ɾ`` is T whichever dialect writes it: in American English it is the flap of /t d/ ("water"), in
Indian English (``english_india_mfa``) the usual /r/. By articulation they are one sound: the tongue tip
strikes the alveolar ridge once, with unrounded lips; T is the 39's phone of that place (TIMIT's flap
``dx`` folds there too), while R (``ɹ``, the approximant, tongue bunched and lips often rounded) looks
different on a face.

WebMAUS (BAS) writes its ``MAU`` tier in SAMPA / X-SAMPA: ``sampa_to_ipa`` rewrites a label in IPA
(``{`` æ, ``e`` ɛ (English SAMPA's DRESS), ``Q`` ɒ, ``V`` ʌ, ``T D S Z N`` θ ð ʃ ʒ ŋ, ``tS dZ`` tʃ dʒ,
``r\\`` ɹ, ``4`` ɾ, ``5`` ɫ, ``@`` ə, r-coloured @` 3` ɚ ɝ, ``:`` length, ``=`` syllabic, ``eI aI OI @U aU
I@ e@ U@`` diphthongs), which the table above then maps. SAMPA must be converted before ``phone_index``:
read as ARPAbet, its ``T D S Z N V`` would be other phones."""

from __future__ import annotations

import re
import unicodedata

ARPABET = (
    "SIL AA AE AH AO AW AY B CH D DH EH ER EY F G HH IH IY JH K L M N NG OW OY P R S SH T TH UH UW V W Y Z ZH"
).split()

FOLDED = {
    "AX": "AH",
    "AX-H": "AH",
    "AXR": "ER",
    "IX": "IH",
    "UX": "UW",
    "EL": "L",
    "EM": "M",
    "EN": "N",
    "ENG": "NG",
    "NX": "N",
    "HV": "HH",
    "DX": "T",
    **dict.fromkeys("BCL DCL GCL PCL TCL KCL H# PAU EPI Q".split(), "SIL"),
}

# IPA phone (diacritics below removed, except where the table names them) -> ARPAbet phone
IPA = {
    **dict.fromkeys("i iː".split(), "IY"),
    **dict.fromkeys("ɪ ɨ".split(), "IH"),
    **dict.fromkeys("e ej eɪ".split(), "EY"),
    "ɛ": "EH",
    **dict.fromkeys("æ a".split(), "AE"),
    **dict.fromkeys("ɑ ɒ".split(), "AA"),
    "ɔ": "AO",
    **dict.fromkeys("ʌ ɐ ə".split(), "AH"),
    **dict.fromkeys("ɚ ɝ ɜ".split(), "ER"),
    "ʊ": "UH",
    **dict.fromkeys("u ʉ".split(), "UW"),
    **dict.fromkeys("o ow oʊ əw əʊ".split(), "OW"),
    "ɪə": "IH",
    "ʊə": "UH",
    **dict.fromkeys("eə ɛə".split(), "EH"),
    **dict.fromkeys("aj aɪ".split(), "AY"),
    **dict.fromkeys("aw aʊ".split(), "AW"),
    **dict.fromkeys("ɔj ɔɪ".split(), "OY"),
    **dict.fromkeys("p kp".split(), "P"),
    **dict.fromkeys("b ɡb gb".split(), "B"),
    **dict.fromkeys("t ʈ".split(), "T"),
    **dict.fromkeys("d ɖ".split(), "D"),
    **dict.fromkeys("k c".split(), "K"),
    **dict.fromkeys("ɡ g ɟ".split(), "G"),
    "ɾ": "T",
    "ɾ̃": "N",
    "ʔ": "SIL",
    **dict.fromkeys("tʃ t͡ʃ".split(), "CH"),
    **dict.fromkeys("dʒ d͡ʒ".split(), "JH"),
    "f": "F",
    **dict.fromkeys("v ʋ".split(), "V"),
    **dict.fromkeys("θ t̪".split(), "TH"),
    **dict.fromkeys("ð d̪".split(), "DH"),
    "s": "S",
    "z": "Z",
    "ʃ": "SH",
    "ʒ": "ZH",
    **dict.fromkeys("h ɦ ç".split(), "HH"),
    **dict.fromkeys("m ɱ".split(), "M"),
    **dict.fromkeys("n ɲ".split(), "N"),
    "ŋ": "NG",
    **dict.fromkeys("l ɫ ʎ".split(), "L"),
    **dict.fromkeys("ɹ r ɻ".split(), "R"),
    "j": "Y",
    **dict.fromkeys("w ʍ".split(), "W"),
}

# X-SAMPA (a superset of SAMPA) -> IPA: every symbol of WebMAUS's English sets and the ASCII capitals, so no
# SAMPA label is left to read as an ARPAbet phone; the longest symbol is taken first
_XSAMPA = {
    **dict(zip("ABCDEFGHIJKLMNOPQRSTUVWXYZ", "ɑβçðɛɱɣɥɪɲɬʎɯŋɔʋɒʁʃθʊʌʍχʏʒ")),
    **dict(zip("@{}123456789&?", "əæʉɨøɜɾɫɐɤɵœɶʔ")),
    "@`": "ɚ", "3`": "ɝ", "t`": "ʈ", "d`": "ɖ", "n`": "ɳ", "s`": "ʂ", "z`": "ʐ", "r`": "ɽ",
    "r\\": "ɹ", "R\\": "ʀ", "?\\": "ʕ", "tS": "tʃ", "dZ": "dʒ", ":": "ː", ":\\": "ˑ", "=": "\u0329",
    "_h": "ʰ", "_w": "ʷ", "_j": "ʲ", "'": "ʲ", "_0": "\u0325", "~": "\u0303", "`": "\u02de",
    # English SAMPA (Wells; WebMAUS eng-GB, eng-AU) writes DRESS "e" ("bed" b e d), as IPA writes RP's: the
    # vowel of EH, not of FACE (eI, EY)
    "e": "ɛ", "eI": "eɪ",
}  # fmt: skip
_XSAMPA_SYMBOL = re.compile("|".join(map(re.escape, sorted(_XSAMPA, key=len, reverse=True))))


def sampa_to_ipa(label: str) -> str:
    """An (X-)SAMPA phone label (WebMAUS's ``MAU`` tier) in IPA: ``tS`` -> ``tʃ``, ``{`` -> ``æ``, ``I@`` ->
    ``ɪə``, English DRESS ``e`` -> ``ɛ``. Pauses and markers in angle brackets (``<p:>``) and the other
    lower-case letters are kept."""
    if label.strip().startswith("<"):
        return label
    return _XSAMPA_SYMBOL.sub(lambda m: _XSAMPA[m.group()], label)


# marks that make an allophone of the phone they follow: aspirated, labialised, palatalised, long,
# half-long, syllabic (below and above), unreleased, dental, non-syllabic, ejective, voiceless, raised,
# lowered, nasalised vowel
_ALLOPHONE_MARKS = re.compile("[ʰʷʲːˑ\u0329\u030d\u031a\u032a\u032fʼ\u0325\u030a\u031d\u031e\u0303]")
_WORD_POSITION = re.compile(r"_[BIES]$", re.IGNORECASE)


def without_word_position(label: str) -> str:
    """``label`` stripped, less a Kaldi word-position suffix (``dh_B`` -> ``dh``, ``oov_S`` -> ``oov``)."""
    return _WORD_POSITION.sub("", label.strip())


def _ipa(label: str) -> str | None:
    """The ARPAbet phone of an IPA phone label, or None."""
    label = unicodedata.normalize("NFC", label)
    if label in IPA:  # the few the table names with their diacritic (t̪ d̪ ɾ̃)
        return IPA[label]
    return IPA.get(
        unicodedata.normalize("NFC", _ALLOPHONE_MARKS.sub("", unicodedata.normalize("NFD", label)))
    )


def phone_index(label: str) -> int | None:
    """Index in ``ARPABET`` of an aligner's phone label (ARPAbet in any case, stress digits and word
    position dropped, TIMIT phones folded; else an IPA phone of MFA's English models); None for a label
    that is neither."""
    label = without_word_position(label)
    p = re.sub(r"\d", "", label).upper()
    p = FOLDED.get(p, p)
    if p not in ARPABET:
        p = _ipa(label)
    return ARPABET.index(p) if p is not None else None
