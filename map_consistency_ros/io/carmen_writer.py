"""CARMEN FLASER logs written from arrays, whole or not at all (io/staging.py).

The layout read by io/carmen.py: `FLASER K r_1 .. r_K x y theta odom_x odom_y odom_theta
ipc_timestamp host logger_timestamp`, the given pose in both pose slots (as the corrected logs
of the SLAM benchmarks have it). Ranges are written in their shortest exact decimal form of
their own precision, so that reading the log back gives the same values (float32 ranges, as a
LaserScan carries them, come back as the same float32 values).
"""
from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np

from map_consistency_ros.io.staging import staged


def write_flaser_log(path: str | Path, ranges: np.ndarray, poses: np.ndarray,
                     stamps: np.ndarray, comment: str = '', host: str = 'generated') -> None:
    """Write scans as FLASER records; gzip-compressed when the name ends in .gz.

    Parameters
    ----------
    path: the log to write (an existing one is replaced, its folder made if missing).
    ranges: (N, K) finite ranges in metres, float32 or float64 (written in the shortest form
        that reads back as the same value of that precision).
    poses: (N, 3) laser poses (x, y, theta), written with 6 decimals in both pose slots.
    stamps: (N,) timestamps in seconds, written with 6 decimals as both timestamps.
    comment: a first line saying where the log comes from ('#' lines are skipped by readers);
        none when empty.
    host: the host field, one word.

    Returns
    -------
    None. Raises ValueError for arrays of mismatched shapes, non-finite values or a host
    that is not one word.
    """
    ranges = np.asarray(ranges)
    if ranges.dtype != np.float32:
        ranges = ranges.astype(np.float64)
    poses = np.asarray(poses, dtype=np.float64)
    stamps = np.asarray(stamps, dtype=np.float64)
    if ranges.ndim != 2 or poses.shape != (len(ranges), 3) or stamps.shape != (len(ranges),):
        raise ValueError(f'need ranges (N, K), poses (N, 3), stamps (N,); got {ranges.shape}, '
                         f'{poses.shape}, {stamps.shape}')
    for name, values in (('ranges', ranges), ('poses', poses), ('stamps', stamps)):
        if not np.all(np.isfinite(values)):
            raise ValueError(f'{name} must be finite')
    if not host or len(host.split()) != 1:
        raise ValueError(f'host must be one word, got {host!r}')
    path = Path(path)
    opener = gzip.open if path.suffix == '.gz' else open
    with staged(path) as target, opener(target, 'wt', encoding='ascii') as stream:
        if comment:
            stream.write('# ' + ' '.join(comment.split()) + '\n')
        for scan, (x, y, theta), stamp in zip(ranges, poses, stamps):
            values = ' '.join(np.format_float_positional(value, unique=True, trim='-')
                              for value in scan)
            pose = f'{x:.6f} {y:.6f} {theta:.6f}'
            stream.write(f'FLASER {len(scan)} {values} {pose} {pose} {stamp:.6f} {host} '
                         f'{stamp:.6f}\n')
