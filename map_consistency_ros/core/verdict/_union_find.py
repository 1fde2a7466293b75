"""Union-find labels of nodes joined by links (numba): regions and places joined through
their pairs or cells."""
from __future__ import annotations

import numba
import numpy as np


def _components(scan_count: int, links: np.ndarray) -> np.ndarray:
    """Union-find labels (the smallest member) of nodes joined by the rows of `links` (L, 2)."""
    return _union_find(scan_count, np.ascontiguousarray(links, dtype=np.int64).reshape(-1, 2))


@numba.njit(cache=True)
def _union_find(count: int, links: np.ndarray) -> np.ndarray:
    parent = np.arange(count)
    for row in range(links.shape[0]):
        a, b = _root(parent, links[row, 0]), _root(parent, links[row, 1])
        if a != b:
            parent[max(a, b)] = min(a, b)
    for node in range(count):
        parent[node] = _root(parent, node)
    return parent


@numba.njit(cache=True)
def _root(parent: np.ndarray, node: int) -> int:
    while parent[node] != node:
        parent[node] = parent[parent[node]]
        node = parent[node]
    return node
