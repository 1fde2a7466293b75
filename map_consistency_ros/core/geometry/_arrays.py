"""Arrays that grow by rows (the per-slot state of the monitor, the spatial index and the
node's markers, grown by doubling so that appending stays amortized O(1)), read-only views
of arrays that their owner may still write (a ScanSet's arrays, the monitor's caches), and
index ranges laid end to end."""
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


def spans(low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The integers of the ranges [low_k, high_k) laid end to end, without a Python loop.

    Parameters
    ----------
    low, high: (K,) integer bounds, high_k >= low_k.

    Returns
    -------
    (the integers of every range, range 0's first (S,) int64; the k of each (S,) int64).
    """
    lengths = high - low
    owner = np.repeat(np.arange(lengths.size), lengths)
    return np.repeat(low - np.cumsum(lengths) + lengths, lengths) + np.arange(owner.size), owner


def true_runs(mask: np.ndarray) -> np.ndarray:
    """The runs of consecutive True values of a boolean sequence.

    Parameters
    ----------
    mask: (N,) bool.

    Returns
    -------
    (R, 2) int64 half-open bounds [start, end) of each run, in order; (0, 2) when none.
    """
    padded = np.concatenate([[False], np.asarray(mask, dtype=bool), [False]])
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    return edges.reshape(-1, 2).astype(np.int64)
