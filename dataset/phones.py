"""The phone set of the toolkit's PPG: the 39 CMU/ARPAbet phones (as pocketsphinx's en-us model and
CMUdict use them) with silence first, and how labels of other ARPAbet dialects map onto it.

Aligners and corpora write ARPAbet in several dialects: stress digits (``AH0``), lower case, and the
TIMIT phones that the 39-phone set folds away (Lee and Hon 1989, as in the usual TIMIT 61 -> 39
mapping): ``ax`` and ``ax-h`` are ``AH``, ``axr`` is ``ER``, ``ix`` is ``IH``, ``ux`` is ``UW``, the
syllabic ``el em en eng`` are ``L M N NG``, ``nx`` is ``N``, ``hv`` is ``HH``, the flap ``dx`` is ``T``
(its commonest source in American English, as in "water"), and closures, pauses and the glottal stop
(``bcl dcl gcl pcl tcl kcl h# pau epi q``) are silence."""

from __future__ import annotations

import re

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


def phone_index(label: str) -> int | None:
    """Index in ``ARPABET`` of an aligner's phone label (any case, stress digits dropped, TIMIT phones
    folded); None for a label that is no ARPAbet phone."""
    p = re.sub(r"\d", "", label.strip()).upper()
    p = FOLDED.get(p, p)
    return ARPABET.index(p) if p in ARPABET else None
