"""Whether the tested pairs of a map can support a verdict at all.

A CONSISTENT verdict is earned only where the test could have failed the map. The smallest
failure the verdict reports is a misaligned region: `min_region_scans` consecutive viewpoints
that disagree with as many reference viewpoints. A viewpoint takes part in such a finding only
when the cascaded test can flag it, i.e. when it has at least `flaggable_pairs` tested pairs:
the fewest r with nu-hat(r) < r, so that r failed pairs out of r exceed the critical count
(2 at the default failure probability 0.015 and level 0.01; with one pair even a failure is
within chance). A map with fewer than 2 x `min_region_scans` flaggable viewpoints (6 at the
defaults) holds no region and its reference that the test could have found: whatever passed,
nothing was judged. Such a map is reported as "nothing to judge", never as consistent: a pose
estimate that stopped (every scan at one pose), a single scan, scans that hit nothing, a stretch
without overlaps.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from map_consistency_ros.core.consistency import ConsistencyResult, statistics


@dataclass(frozen=True)
class Evidence:
    """What a map's tested pairs can support."""

    flaggable_scans: int  # scans with at least `flaggable_pairs` tested pairs
    flaggable_pairs: int  # tested pairs a scan needs before the cascaded test can flag it
    needed_scans: int  # flaggable scans a verdict needs
    tested_pairs: int

    @property
    def sufficient(self) -> bool:
        """Whether the test could have found the smallest failure the verdict reports."""
        return self.flaggable_scans >= self.needed_scans

    def reason(self) -> str:
        """Why the map cannot be judged, in one clause.

        Returns
        -------
        e.g. 'only 1 scan has the 2 tested pairs the test needs to flag it (a verdict needs
        6): nothing overlaps enough to be tested'.
        """
        scans = self.flaggable_scans
        has = 'scan has' if scans <= 1 else 'scans have'
        return (f'{"no" if scans == 0 else f"only {scans}"} {has} the {self.flaggable_pairs} '
                f'tested pairs the test needs to flag a scan ({self.tested_pairs} tested pairs '
                f'in all; a verdict needs {self.needed_scans} such scans)')


def flaggable_pair_count(probability: float, alpha: float, limit: int = 10_000) -> int:
    """The fewest tested pairs with which a scan can fail its cascaded test.

    Parameters
    ----------
    probability: the chance that one pairwise test fails by chance.
    alpha: the level of the cascaded (binomial) test.
    limit: the largest count searched.

    Returns
    -------
    The smallest r >= 1 with nu-hat(r) < r (r failed pairs of r then flag the scan); `limit`
    when none below it does.
    """
    trials = np.arange(1, limit + 1)
    possible = np.flatnonzero(statistics.binomial_critical_count(trials, probability, alpha)
                              < trials)
    return int(trials[possible[0]]) if possible.size else limit


def evidence(result: ConsistencyResult, min_region_scans: int) -> Evidence:
    """How much of the map the test could have failed.

    Parameters
    ----------
    result: the paper's test on the map.
    min_region_scans: the viewpoints a misaligned region holds on each side (the smallest
        failure the verdict reports).

    Returns
    -------
    The Evidence; `sufficient` tells whether a verdict is earned.
    """
    parameters = result.parameters
    needed_pairs = flaggable_pair_count(parameters.failure_probability, parameters.binomial_alpha)
    flaggable = int(np.count_nonzero(result.overlap_counts >= needed_pairs))
    return Evidence(flaggable_scans=flaggable, flaggable_pairs=needed_pairs,
                    needed_scans=2 * min_region_scans, tested_pairs=result.tested_pair_count)
