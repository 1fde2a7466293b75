"""Every overlapping pair of the flagged scans, for the second stage.

The monitor measures a new viewpoint against at most `max_partners` earlier ones (the nearest
of each earlier visit of its place), which bounds the cost of an update. The paper's test can
flag a scan on that sample, but the second stage weighs the evidence: it registers the
submaps around the failed pairs and asks whether their corrections agree. On a sample it can
find agreement that every pair of those scans refutes, and the verdict then moves with the
budget (docs/node.md, "Viewpoints and a budget per keyframe"). So before the second stage
runs, the pairs of every flagged scan that the budget left out are measured at the snapshot's
poses and tested with the snapshot's scales, as `check` measures and tests them, and so are
those of every scan they flag in turn: the explanation then sees what `check` would see around
the scans it explains, whatever the budget.

Invariant: the completed result holds every pair of the snapshot's result, unchanged in
measure, and every pair with a scan flagged by the snapshot's test or by the completed one
whose extents overlap and that has end points to test (the monitor keeps no pair without,
and neither does this). The pairs of the last completion are kept, by keyframe id and with the
poses they were measured at, so that the next explanation measures only what is new or moved
(a live map changes a little between explanations).
"""
from __future__ import annotations

import numpy as np

from map_consistency_ros.core.consistency import (ConsistencyParameters, ConsistencyResult,
                                                  evaluate_pairs, robust_sums)
from map_consistency_ros.core.geometry import PairMeasures, ScanSet, candidate_pairs, measure_pairs
from map_consistency_ros.core.live._pair_cache import pair_keys


class FlaggedPairs:
    """The pairs the budget left out around flagged scans, measured once per pose."""

    def __init__(self) -> None:
        self._keys = np.zeros(0, dtype=np.int64)  # pair_keys of keyframe ids, sorted
        self._poses = np.zeros((0, 6))  # both scans' poses when measured
        self._sums = np.zeros((0, 4))  # M_ij, n_ij, trimmed M_ij, trimmed n_ij

    def complete(self, scans: ScanSet, ids: np.ndarray,
                 result: ConsistencyResult) -> ConsistencyResult:
        """The first stage's result with every pair of its flagged scans measured and tested.

        A scan's added pairs can flag a partner the budget kept quiet; its pairs are added in
        turn, until no scan is newly flagged (the flags only grow, so this ends, at the latest
        with every pair of the map).

        Parameters
        ----------
        scans: the snapshot's N scans placed at their poses, in the rows of `result`.
        ids: (N,) their keyframe ids (stable across snapshots).
        result: the first stage's result on them (the budgeted pairs), with its parameters.

        Returns
        -------
        `result` itself when no scan is flagged or none of their pairs with end points is
        missing; else the pairwise and cascaded tests on its pairs and the added ones, with
        its scales.
        """
        flagged = result.inconsistent
        if not flagged.any():
            return result
        ids = np.asarray(ids, dtype=np.int64)
        candidates = candidate_pairs(scans.extents)
        # measured already: in the result, or earlier in this completion (with or without points)
        measured = np.isin(pair_keys(candidates[:, 0], candidates[:, 1]),
                           pair_keys(result.pairs[:, 0], result.pairs[:, 1]))
        looked_up, added = [], []
        completed = result
        while True:
            rows = np.flatnonzero(~measured & (flagged[candidates[:, 0]]
                                               | flagged[candidates[:, 1]]))
            if rows.size == 0:
                break
            measured[rows] = True
            pairs = candidates[rows]
            keys, poses = _keys_and_poses(scans, ids, pairs)
            sums = self._look_up(scans, pairs, keys, poses, result.parameters)
            looked_up.append((keys, poses, sums))
            # as the monitor keeps them: pairs without points say nothing
            evidence = sums[:, 1] > 0
            if not evidence.any():
                break
            added.append((pairs[evidence], sums[evidence]))
            completed = _with_pairs(result, added)
            grown = flagged | completed.inconsistent
            if np.array_equal(grown, flagged):
                break
            flagged = grown
        self._keep(looked_up)
        return completed

    def _look_up(self, scans: ScanSet, pairs: np.ndarray, keys: np.ndarray, poses: np.ndarray,
                 parameters: ConsistencyParameters) -> np.ndarray:
        """(P, 4) M_ij, n_ij and their trimmed sums of `pairs` (rows; `keys` and `poses` as
        _keys_and_poses gives them): from the kept pairs where both scans are where they were
        when measured, else measured now."""
        sums = np.empty((pairs.shape[0], 4))
        found = np.zeros(pairs.shape[0], dtype=bool)
        if self._keys.size:
            at = np.minimum(np.searchsorted(self._keys, keys), self._keys.size - 1)
            found = (self._keys[at] == keys) & np.all(self._poses[at] == poses, axis=1)
            sums[found] = self._sums[at[found]]
        new = np.flatnonzero(~found)
        if new.size:
            measures = measure_pairs(scans, pairs[new], parameters.trim_largest)
            trimmed_sum, trimmed_count = robust_sums(measures, parameters.trim_largest)
            sums[new] = np.column_stack([measures.distance_sum, measures.point_count,
                                         trimmed_sum, trimmed_count])
        return sums

    def _keep(self, looked_up: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> None:
        """The pairs of this completion (keys, poses, sums) become the kept ones (the last
        explanation's)."""
        if not looked_up:
            return
        keys, poses, sums = (np.concatenate(part) for part in zip(*looked_up))
        order = np.argsort(keys)
        self._keys, self._poses, self._sums = keys[order], poses[order], sums[order]


def _keys_and_poses(scans: ScanSet, ids: np.ndarray,
                    pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each pair's key by keyframe ids (pair_keys, as the monitor's pair cache keys slots)
    and both scans' poses, (P,) and (P, 6)."""
    keys = pair_keys(ids[pairs[:, 0]], ids[pairs[:, 1]])
    poses = np.concatenate([scans.sensor_poses[pairs[:, 0]],
                            scans.sensor_poses[pairs[:, 1]]], axis=1)
    return keys, poses


def _with_pairs(result: ConsistencyResult,
                added: list[tuple[np.ndarray, np.ndarray]]) -> ConsistencyResult:
    """The tests of `result`'s pairs and the added ones (pairs, sums), with its scales."""
    pairs = np.concatenate([result.pairs, *(pairs for pairs, _ in added)])
    sums = np.concatenate([sums for _, sums in added])
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))  # pairs sorted (i, j), as check has them
    distance_sum = np.concatenate([result.distance_sum, sums[:, 0]])[order]
    point_count = np.concatenate([result.point_count, sums[:, 1].astype(np.int64)])[order]
    trimmed_sum = np.concatenate([result.trimmed_sum, sums[:, 2]])[order]
    trimmed_count = np.concatenate([result.trimmed_count, sums[:, 3].astype(np.int64)])[order]
    # the robust sums are given: the largest distances are not needed again
    measures = PairMeasures(pairs=pairs[order], distance_sum=distance_sum,
                            point_count=point_count, largest=np.zeros((order.size, 0)))
    return evaluate_pairs(measures, result.scales, result.scan_count, result.parameters,
                          robust=(trimmed_sum, trimmed_count))
