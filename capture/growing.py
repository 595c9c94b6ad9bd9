"""Rows of numbers written block after block into one array whose final length is only estimated (a
CSV's rows from its bytes, an audio stream's samples from its declared duration): the values are held
once, not as a list of parts joined at the end (twice, at the peak)."""

from __future__ import annotations

import numpy as np


class GrowingRows:
    """A 2-D array (rows x columns) allocated for an estimate and grown or trimmed in place (``resize``):
    NumPy reallocates, and a large array's pages are remapped, not copied; rows an estimate allocates but
    nothing writes cost no memory (``np.empty``), while rows a growth adds are zeroed by NumPy. When
    something else holds a view of the array (a debugger's or tracer's view of a frame's locals) it is
    copied instead, so that the array given back is never a view keeping a larger one alive."""

    def __init__(self, rows: int, columns: int, dtype: np.dtype | type) -> None:
        self.array = np.empty((rows, columns), dtype)

    def __len__(self) -> int:
        return len(self.array)

    def resize(self, rows: int) -> None:
        try:
            self.array.resize((rows, self.array.shape[1]))
        except ValueError:
            kept = min(rows, len(self.array))
            copy = np.empty((rows, self.array.shape[1]), self.array.dtype)
            copy[:kept] = self.array[:kept]
            self.array = copy
