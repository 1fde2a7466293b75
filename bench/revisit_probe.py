"""Where a revisit meets earlier scans: what the second stage says, and an independent search.

    .venv/bin/python bench/revisit_probe.py DATASET QUERY REFERENCE [--seed S] [--maps NAME ...]

    e.g. bench/revisit_probe.py orebro 226:237 0:4 --seed 23 \
             --maps "orebro/corrected" "orebro/shift 0.3 m #0" "orebro/shift 0.1 m #1"

For each map of the whole-log suite (evaluation/whole_logs.py, 2 seams per size at `--seed`;
default: every map of DATASET) between the scans QUERY (a later visit, `first:end` rows of the
map) and REFERENCE (the earlier one):

- the second stage at default settings: the classes of the explained pairs between the two
  ranges and the median correction its registrations found for them;
- an independent search, no ICP and none of the package's geometry: the rigid motion of the
  query end points (about their centroid, a grid of +-3 deg by 0.25 deg and +-0.4 m by 2 cm)
  that puts the most of them within 5 cm of a reference end point (scipy's cKDTree), beside
  that share at no motion.

A map whose later visit is off its earlier one shows a best motion away from zero with a share
well above the share at zero, whether or not the world changed between the visits.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from map_consistency_ros.core.verdict import check_map
from map_consistency_ros.evaluation import whole_logs

DATA = Path(__file__).resolve().parents[2] / 'shared' / 'data'
INLIER = 0.05  # metres: an end point this close to a reference end point is an inlier
TURNS_DEG = np.arange(-3.0, 3.001, 0.25)
SHIFTS = np.arange(-0.4, 0.401, 0.02)


def _rows(text: str) -> slice:
    first, end = (int(value) for value in text.split(':'))
    return slice(first, end)


def best_motion(query: np.ndarray, reference: np.ndarray) -> tuple[float, tuple]:
    """(inlier share at no motion, (best share, dx, dy, turn in degrees)) of `query` end points
    (Q, 2) against `reference` end points (R, 2), turned about the query centroid."""
    tree = cKDTree(reference)
    centre = query.mean(axis=0)

    def share(dx: float, dy: float, degrees: float) -> float:
        angle = np.radians(degrees)
        cosine, sine = np.cos(angle), np.sin(angle)
        moved = (query - centre) @ np.array([[cosine, sine], [-sine, cosine]]) + centre
        distance, _ = tree.query(moved + (dx, dy), distance_upper_bound=2 * INLIER)
        return float(np.mean(distance < INLIER))

    best = max((share(dx, dy, turn), dx, dy, turn)
               for turn in TURNS_DEG for dx in SHIFTS for dy in SHIFTS)
    return share(0.0, 0.0, 0.0), best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('dataset')
    parser.add_argument('query', type=_rows, help='rows first:end of the later visit')
    parser.add_argument('reference', type=_rows, help='rows first:end of the earlier visit')
    parser.add_argument('--seed', type=int, default=7)
    parser.add_argument('--maps', nargs='*', default=None, help='suite map names; default all')
    args = parser.parse_args()
    maps = whole_logs.build(DATA, [args.dataset], 2, args.seed)
    for whole in maps:
        if args.maps and whole.name not in args.maps:
            continue
        scans, _ = whole_logs.map_scans(whole)
        assessment = check_map(scans)
        pairs = assessment.result.pairs[assessment.explained_pairs]
        query = np.zeros(scans.scan_count, dtype=bool)
        query[args.query] = True
        reference = np.zeros(scans.scan_count, dtype=bool)
        reference[args.reference] = True
        between = ((query[pairs[:, 1]] & reference[pairs[:, 0]])
                   | (query[pairs[:, 0]] & reference[pairs[:, 1]]))
        classes = {name: int(count) for name, count in assessment.class_counts().items()}
        codes = np.bincount(assessment.pair_classes[between], minlength=4)
        correction = (np.median(assessment.pair_corrections[between], axis=0) if between.any()
                      else np.full(3, np.nan))
        zero, (share, dx, dy, turn) = best_motion(
            scans.endpoints[args.query][scans.valid[args.query]],
            scans.endpoints[args.reference][scans.valid[args.reference]])
        print(f'{whole.name} ({whole.description}): {assessment.summary_line()}')
        print(f'  explained pairs between the visits: {int(between.sum())} of '
              f'{sum(classes.values())}; misaligned / minor / change / unregistered '
              f'{" / ".join(str(int(count)) for count in codes)}; median correction '
              f'({correction[0]:+.3f} m, {correction[1]:+.3f} m, '
              f'{np.degrees(correction[2]):+.2f} deg)')
        print(f'  independent search: {INLIER * 100:.0f} cm inliers {zero:.3f} at no motion, '
              f'{share:.3f} at ({dx:+.2f} m, {dy:+.2f} m, {turn:+.2f} deg) about the centroid')


if __name__ == '__main__':
    main()
