"""align: speech and face on one clock. Measures the audio↔face offset (timecodes, sync events,
claps, content), corrects drift, trims silence by VAD, and writes 16 kHz audio with frames on a uniform
grid, one aligned take per segment."""

# capture, imported first, guards the imports of a stage command against Ctrl-C (capture.import_guard); the
# guard ends once the command's own module (cli.py) has imported, after this package's imports.
import capture.import_guard  # noqa: F401  # isort: skip

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
