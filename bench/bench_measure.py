"""Time candidate pairs + all pair measures on the full Intel log, with references side by side.

    .venv/bin/python bench/bench_measure.py [--shapely-pairs 2000] [--repeat 5]

Routes: the angular-index kernel (pair_measures), the naive O(K^2) numba kernel
(pair_measures_naive) and shapely (prepared polygons, contains_xy, boundary distance; timed on
a random subset of pairs and extrapolated). Then the full consistency test, and the kernel's
growth with the beams per scan (ranges resampled to K = 180, 360, 720 over the same FOV).
Timings are after JIT warm-up, median of --repeat runs, on however many cores numba uses.
"""
from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np
import shapely

from map_consistency_ros.core.consistency import check_consistency
from map_consistency_ros.core.geometry import (ScanSet, SensorModel, candidate_pairs,
                                               pair_measures, pair_measures_naive)
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model

INTEL = Path(__file__).resolve().parents[2] / 'shared' / 'data' / 'intel' / 'intel.gfs.log'


@dataclass(frozen=True)
class Timing:
    """Median wall and process CPU seconds (all threads; steadier on a shared machine)."""

    wall: float
    cpu: float

    def scaled(self, factor: float) -> 'Timing':
        return Timing(self.wall * factor, self.cpu * factor)

    def __add__(self, other: 'Timing') -> 'Timing':
        return Timing(self.wall + other.wall, self.cpu + other.cpu)


def median_time(function, repeat: int, warm_up: bool = True) -> tuple[Timing, object]:
    """Median timing of `repeat` calls (after one warm-up call) and the last result."""
    result = function() if warm_up else None
    walls, cpus = [], []
    for _ in range(repeat):
        start, start_cpu = time.perf_counter(), time.process_time()
        result = function()
        walls.append(time.perf_counter() - start)
        cpus.append(time.process_time() - start_cpu)
    return Timing(float(np.median(walls)), float(np.median(cpus))), result


def shapely_measures(scans: ScanSet, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """M_ij and n_ij the straightforward way: one prepared shapely polygon per scan."""
    polygons = []
    for index in range(scans.scan_count):
        ring = scans.endpoints[index]
        if not scans.full_circle:
            ring = np.vstack([scans.sensor_poses[index, :2], ring])
        polygon = shapely.Polygon(ring)
        shapely.prepare(polygon)
        polygons.append((polygon, polygon.boundary))
    sums, counts = np.zeros(len(pairs)), np.zeros(len(pairs), dtype=np.int64)
    for row, (i, j) in enumerate(pairs):
        for polygon_scan, point_scan in ((i, j), (j, i)):
            polygon, boundary = polygons[polygon_scan]
            points = scans.endpoints[point_scan][scans.valid[point_scan]]
            inside = points[shapely.contains_xy(polygon, points[:, 0], points[:, 1])]
            sums[row] += shapely.distance(boundary, shapely.points(inside)).sum()
            counts[row] += len(inside)
    return sums, counts


def resampled(scans: ScanSet, beams: int) -> ScanSet:
    """The same scans with `beams` beams over the same FOV (linear in range, nearest validity)."""
    old = scans.ranges.shape[1]
    span = (old - 1) * scans.model.angle_increment
    model = SensorModel(scans.model.angle_min, span / (beams - 1), scans.model.max_range,
                        scans.model.range_min)
    where = np.linspace(0.0, old - 1.0, beams)
    ranges = np.array([np.interp(where, np.arange(old), row) for row in scans.ranges])
    valid = scans.valid[:, np.rint(where).astype(int)]
    return ScanSet.from_ranges(np.where(valid, ranges, np.inf), scans.sensor_poses, model)


def candidates_and_measures(scans: ScanSet):
    return pair_measures(scans, candidate_pairs(scans.extents))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--log', type=Path, default=INTEL)
    parser.add_argument('--shapely-pairs', type=int, default=2000)
    parser.add_argument('--repeat', type=int, default=5)
    args = parser.parse_args()

    log = read_carmen_log(args.log)
    scans = ScanSet.from_ranges(log.ranges, log.laser_poses, sensor_model(log))
    print(f'{args.log.name}: {scans.scan_count} scans x {scans.ranges.shape[1]} beams, '
          f'max range {scans.model.max_range} m; numba threads: {numba.get_num_threads()}')

    candidate_time, pairs = median_time(lambda: candidate_pairs(scans.extents), args.repeat)
    fast_time, fast = median_time(lambda: pair_measures(scans, pairs), args.repeat)
    naive_time, naive = median_time(lambda: pair_measures_naive(scans, pairs), 1)
    subset = np.random.default_rng(0).choice(len(pairs), min(args.shapely_pairs, len(pairs)),
                                             replace=False)
    shapely_part, (shapely_sums, shapely_counts) = median_time(
        lambda: shapely_measures(scans, pairs[subset]), 1, warm_up=False)
    shapely_time = shapely_part.scaled(len(pairs) / len(subset))

    print(f'\ncandidate pairs: {len(pairs)} in {candidate_time.wall * 1e3:.1f} ms; '
          f'{int((fast.point_count > 0).sum())} pairs overlap, '
          f'{int(fast.point_count.sum())} inconsistent points, sum M_ij = '
          f'{fast.distance_sum.sum():.3f} m')
    print(f'{"route":<56}{"wall s":>8}{"cpu s":>8}{"x kernel (cpu)":>16}')
    total = candidate_time + fast_time
    for name, timing in (('candidates + angular-index kernel', total),
                         ('candidates + naive O(K^2) numba kernel', candidate_time + naive_time),
                         (f'candidates + shapely (extrapolated from {len(subset)} pairs)',
                          candidate_time + shapely_time)):
        print(f'{name:<56}{timing.wall:>8.3f}{timing.cpu:>8.3f}{timing.cpu / total.cpu:>16.1f}')
    agreement = np.max(np.abs(fast.distance_sum[subset] - shapely_sums)
                       / np.maximum(shapely_sums, 1e-12))
    print(f'agreement: naive max |dM| = {np.abs(fast.distance_sum - naive.distance_sum).max():.1e}'
          f' m, n_ij equal: {np.array_equal(fast.point_count, naive.point_count)}; '
          f'shapely subset max rel dM = {agreement:.1e}, n_ij equal: '
          f'{np.array_equal(fast.point_count[subset], shapely_counts)}')

    check_time, _ = median_time(lambda: check_consistency(scans), args.repeat)
    print(f'\nfull test, check_consistency(default parameters): {check_time.wall:.3f} s wall, '
          f'{check_time.cpu:.3f} s cpu (target <= 0.2 s wall, issue 13)')

    print('\nbeams per scan (resampled ranges, same FOV), candidates + measures, cpu seconds:')
    print(f'{"K":>5}{"kernel":>9}{"x K=180":>9}{"K log K":>9}{"K^2":>7}{"naive":>9}{"x K=180":>9}')
    base = None
    for beams in (180, 360, 720):
        sized = resampled(scans, beams)
        kernel, _ = median_time(lambda: candidates_and_measures(sized), args.repeat)
        naive_part, _ = median_time(lambda: pair_measures_naive(sized, pairs[subset]), 1)
        base = base or (kernel.cpu, naive_part.cpu)
        growth = beams / 180
        print(f'{beams:>5}{kernel.cpu:>9.3f}{kernel.cpu / base[0]:>9.2f}'
              f'{growth * math.log(beams) / math.log(180):>9.2f}{growth ** 2:>7.1f}'
              f'{naive_part.cpu * len(pairs) / len(subset):>9.2f}{naive_part.cpu / base[1]:>9.2f}')
    print('(naive column: all pairs, extrapolated from the shapely subset)')


if __name__ == '__main__':
    main()
