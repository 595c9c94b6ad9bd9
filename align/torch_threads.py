"""A torch thread count for one block of work, given back afterwards.

Model inference in the pipeline (the silero VAD, the PPG extractors) runs on one intra-op thread: PPG
features are then bit-identical from run to run (reductions split over threads add in another order),
and the VAD of parallel take workers does not oversubscribe the cores. Setting that for the whole process
would leak into the caller, e.g. ``s2a-train predict`` computes features and then runs its model, which
should use every thread the user gave it.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def torch_threads(n: int | None = 1) -> Iterator[None]:
    """Run the block with torch's intra-op thread count at ``n`` (None: leave it), and give the caller
    its previous count back on exit, also on an exception and whatever the block set (``silero_vad``
    pins one thread when imported). Nested uses compose. Not for threads running torch concurrently:
    the count is process-wide."""
    import torch

    previous = torch.get_num_threads()
    if n is not None and n != previous:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        if torch.get_num_threads() != previous:
            torch.set_num_threads(previous)
