"""Arrays that grow by rows (the per-slot state of the monitor, the spatial index and the
node's markers, grown by doubling so that appending stays amortized O(1)), and read-only views
of arrays that their owner may still write (a ScanSet's arrays, the monitor's caches)."""
from __future__ import annotations

import numpy as np


def with_rows(array: np.ndarray, rows: int, fill: float = 0) -> np.ndarray:
    """A new array of `rows` rows that starts with `array`'s (cut if longer).

    Parameters
    ----------
    array: (N, ...) the rows to keep; it is not changed.
    rows: the number of rows of the new array.
    fill: the value of the added rows (cast to `array`'s dtype).

    Returns
    -------
    A new (rows, ...) array of `array`'s dtype: its first min(rows, N) rows are `array`'s, the
    others hold `fill`.
    """
    grown = np.full((rows, *array.shape[1:]), fill, dtype=array.dtype)
    kept = min(rows, len(array))
    grown[:kept] = array[:kept]
    return grown


def read_only(array: np.ndarray) -> np.ndarray:
    """A view of `array` that cannot be written through; `array` itself keeps its flags.

    Parameters
    ----------
    array: any array.

    Returns
    -------
    A new view of the same memory with `writeable` False.
    """
    view = array.view()
    view.setflags(write=False)
    return view
