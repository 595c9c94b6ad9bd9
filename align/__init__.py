"""align: speech and face on one clock. Measures the audio↔face offset (timecodes, sync events,
claps, content), corrects drift, trims silence by VAD, and writes 16 kHz audio with frames on a uniform
grid, one aligned take per segment."""

from .aligner import align_take, align_with_report, is_aligned
from .batch import align_folder, align_takes
from .grid import INTERPOLATED
from .options import AlignOptions

__all__ = [
    "AlignOptions",
    "INTERPOLATED",
    "align_folder",
    "align_take",
    "align_takes",
    "align_with_report",
    "is_aligned",
]
