"""Arrays that grow by rows: the per-slot state of the monitor, the spatial index and the
node's markers, grown by doubling so that appending stays amortized O(1)."""
from __future__ import annotations

import numpy as np


def with_rows(array: np.ndarray, rows: int, fill: float = 0) -> np.ndarray:
    """A new array of `rows` rows that starts with `array`'s (cut if longer); the added rows
    hold `fill`."""
    grown = np.full((rows, *array.shape[1:]), fill, dtype=array.dtype)
    kept = min(rows, len(array))
    grown[:kept] = array[:kept]
    return grown
