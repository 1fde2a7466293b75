"""Laser scans placed in the world as visibility polygons (the free space each scan saw).

A scan of K beams taken at sensor pose (x, y, theta) sees the polygon V formed by the sensor
position and its end points in angular order, each beam closed at the sensor's maximum range
when it returned nothing usable. A scan covering the full circle has no sensor vertex: V is the
ring of its end points. The valid end points (real returns) are the points tested against the
other scans' polygons.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from map_consistency_ros.core.geometry import se2
from map_consistency_ros.core.geometry._arrays import read_only

FULL_CIRCLE_TOLERANCE = 1e-9


@dataclass(frozen=True)
class SensorModel:
    """Beam geometry of a 2D laser: beam k has bearing angle_min + k * angle_increment.

    A range r is valid when it is finite and range_min < r < max_range; other beams count as
    free space up to max_range. Raises ValueError for non-finite fields, angle_increment outside
    (0, pi), or max_range <= range_min or range_min < 0; `check_beam_count` (applied by every
    ScanSet) rejects beams that overlap past 2 pi.
    """

    angle_min: float
    angle_increment: float
    max_range: float
    range_min: float = 0.0

    def __post_init__(self) -> None:
        for name in ('angle_min', 'angle_increment', 'max_range', 'range_min'):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise ValueError(f'SensorModel.{name} must be finite, got {value}')
            object.__setattr__(self, name, value)
        # Neighbouring end points further apart than pi no longer bound the wedge between them.
        if not 0.0 < self.angle_increment < math.pi:
            raise ValueError(f'SensorModel.angle_increment must be in (0, pi), '
                             f'got {self.angle_increment}')
        if self.range_min < 0.0:
            raise ValueError(f'SensorModel.range_min must be >= 0, got {self.range_min}')
        if self.max_range <= self.range_min:
            raise ValueError(f'SensorModel.max_range ({self.max_range}) must exceed '
                             f'range_min ({self.range_min})')

    def is_full_circle(self, beam_count: int) -> bool:
        """Whether beam_count beams cover the whole circle (the polygon has no sensor vertex).

        Parameters
        ----------
        beam_count: K, the beams of a scan.

        Returns
        -------
        True when K * angle_increment reaches 2 pi (within FULL_CIRCLE_TOLERANCE).
        """
        return beam_count * self.angle_increment >= 2.0 * math.pi - FULL_CIRCLE_TOLERANCE

    def check_beam_count(self, beam_count: int) -> None:
        """Raise ValueError unless beam_count beams form a polygon without overlapping beams.

        Parameters
        ----------
        beam_count: K, the beams of a scan: at least 2, covering at most 2 pi (plus half a
            beam).
        """
        if beam_count < 2:
            raise ValueError(f'a scan needs at least 2 beams, got {beam_count}')
        cover = beam_count * self.angle_increment
        # Half a beam of slack admits increments rounded to float32 around a full circle.
        if cover > 2.0 * math.pi + 0.5 * self.angle_increment:
            raise ValueError(f'{beam_count} beams of {self.angle_increment} rad overlap past 2 pi '
                             f'(they cover {cover:.9f} rad); drop the repeated beams')

    def bearings(self, beam_count: int) -> np.ndarray:
        """Bearing of every beam in the sensor frame.

        Parameters
        ----------
        beam_count: K, the beams of a scan.

        Returns
        -------
        (K,) bearings in radians, angle_min + k * angle_increment.
        """
        return self.angle_min + np.arange(beam_count) * self.angle_increment


def _extents(xs: np.ndarray, ys: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """(N, 4) bounding boxes (xmin, ymin, xmax, ymax) of the polygons: end points (N, K) by
    coordinate (reduced apart: contiguous rows are several times faster) and the sensor."""
    return np.stack([np.minimum(xs.min(axis=1), poses[:, 0]),
                     np.minimum(ys.min(axis=1), poses[:, 1]),
                     np.maximum(xs.max(axis=1), poses[:, 0]),
                     np.maximum(ys.max(axis=1), poses[:, 1])], axis=1)


# the per-scan arrays of a ScanSet, derived ones included (ScanSet.from_parts)
SCAN_ARRAYS = ('sensor_poses', 'ranges', 'valid', 'endpoints', 'extents')


@dataclass(frozen=True)
class ScanSet:
    """N scans of K beams placed in the world, with their visibility polygons.

    Fields: `sensor_poses (N, 3)` world poses of the sensor, `ranges (N, K)` closed at max
    range, `valid (N, K)` which beams are real returns (test points), `model`. Derived:
    `endpoints (N, K, 2)` world end points, `extents (N, 4)` = (xmin, ymin, xmax, ymax) of each
    polygon. Arrays are read-only so that callers may cache results keyed on a ScanSet.
    Build with `ScanSet.from_ranges`.
    """

    sensor_poses: np.ndarray
    ranges: np.ndarray
    valid: np.ndarray
    model: SensorModel
    endpoints: np.ndarray = field(init=False, repr=False)
    extents: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        poses = np.ascontiguousarray(self.sensor_poses, dtype=np.float64)
        ranges = np.ascontiguousarray(self.ranges, dtype=np.float64)
        _check_shapes(ranges, poses, self.model)
        if np.shape(self.valid) != ranges.shape:
            raise ValueError(f'valid must have the shape of ranges {ranges.shape}, '
                             f'got {np.shape(self.valid)}')
        bearings = self.model.bearings(ranges.shape[1])[None, :] + poses[:, 2:3]
        xs = poses[:, 0:1] + ranges * np.cos(bearings)
        ys = poses[:, 1:2] + ranges * np.sin(bearings)
        endpoints = np.stack([xs, ys], axis=-1)
        object.__setattr__(self, 'sensor_poses', read_only(poses))
        object.__setattr__(self, 'ranges', read_only(ranges))
        object.__setattr__(self, 'valid', read_only(np.ascontiguousarray(self.valid, bool)))
        object.__setattr__(self, 'endpoints', read_only(np.ascontiguousarray(endpoints)))
        object.__setattr__(self, 'extents', read_only(_extents(xs, ys, poses)))

    @classmethod
    def from_ranges(cls, ranges: np.ndarray, sensor_poses: np.ndarray,
                    model: SensorModel) -> ScanSet:
        """Scans from raw ranges.

        Parameters
        ----------
        ranges: (N, K) ranges in metres; NaN, inf and ranges outside (range_min, max_range)
            are allowed and become non-valid beams closed at max_range.
        sensor_poses: (N, 3) world poses (x, y, theta) of the sensor, finite.
        model: the beam geometry of every scan.

        Returns
        -------
        The ScanSet of the N scans. Raises ValueError for wrong shapes, non-finite poses or
        overlapping beams.
        """
        ranges = np.asarray(ranges, dtype=np.float64)
        poses = np.asarray(sensor_poses, dtype=np.float64)
        _check_shapes(ranges, poses, model)
        with np.errstate(invalid='ignore'):
            valid = np.isfinite(ranges) & (ranges > model.range_min) & (ranges < model.max_range)
        return cls(sensor_poses=poses, ranges=np.where(valid, ranges, model.max_range),
                   valid=valid, model=model)

    def moved(self, rows: np.ndarray, transforms: np.ndarray) -> ScanSet:
        """Some scans moved rigidly: poses and end points are transformed, not recomputed from
        the ranges.

        Parameters
        ----------
        rows: (R,) rows of this set (or anything that indexes its arrays).
        transforms: (R, 3) world transforms (x, y, theta), one per row, applied as
            p -> R p + t.

        Returns
        -------
        A new ScanSet of the R moved scans, in the order of `rows`.
        """
        transforms = np.asarray(transforms, dtype=np.float64).reshape(-1, 3)
        cos, sin = np.cos(transforms[:, 2])[:, None], np.sin(transforms[:, 2])[:, None]
        poses = se2.compose(transforms, self.sensor_poses[rows])
        ends = self.endpoints[rows]
        xs = cos * ends[..., 0] - sin * ends[..., 1] + transforms[:, 0:1]
        ys = sin * ends[..., 0] + cos * ends[..., 1] + transforms[:, 1:2]
        return ScanSet.from_parts(self.model, sensor_poses=poses, ranges=self.ranges[rows],
                                  valid=self.valid[rows], endpoints=np.stack([xs, ys], axis=-1),
                                  extents=_extents(xs, ys, poses))

    def take(self, rows: np.ndarray) -> ScanSet:
        """Some scans of this set, without recomputing their geometry.

        Parameters
        ----------
        rows: rows of this set (indices or a boolean mask).

        Returns
        -------
        A new ScanSet of those scans, in the order of `rows`.
        """
        return ScanSet.from_parts(self.model, **{name: getattr(self, name)[rows]
                                                 for name in SCAN_ARRAYS})

    @classmethod
    def from_parts(cls, model: SensorModel, **arrays: np.ndarray) -> ScanSet:
        """A set from the arrays of earlier ScanSets: their geometry is taken as it is, not
        recomputed.

        Parameters
        ----------
        model: the beam geometry of the scans.
        arrays: exactly the fields of SCAN_ARRAYS, rows picked or stacked from earlier sets.

        Returns
        -------
        The ScanSet (read-only, contiguous copies where needed). Raises ValueError when the
        arrays are not exactly SCAN_ARRAYS.
        """
        if set(arrays) != set(SCAN_ARRAYS):
            raise ValueError(f'need exactly the arrays {SCAN_ARRAYS}, got {sorted(arrays)}')
        scans = object.__new__(cls)
        object.__setattr__(scans, 'model', model)
        for name in SCAN_ARRAYS:
            object.__setattr__(scans, name, read_only(np.ascontiguousarray(arrays[name])))
        return scans

    @property
    def scan_count(self) -> int:
        """N, the number of scans."""
        return int(self.ranges.shape[0])

    @property
    def full_circle(self) -> bool:
        """Whether the polygons are rings of end points without the sensor vertex."""
        return self.model.is_full_circle(self.ranges.shape[1])

    def with_poses(self, sensor_poses: np.ndarray) -> ScanSet:
        """The same scans seen from other sensor poses.

        Parameters
        ----------
        sensor_poses: (N, 3) the new world poses of the sensor, one per scan.

        Returns
        -------
        A new ScanSet, its end points and extents computed again from the ranges.
        """
        return ScanSet(sensor_poses=sensor_poses, ranges=self.ranges, valid=self.valid,
                       model=self.model)


def _check_shapes(ranges: np.ndarray, poses: np.ndarray, model: SensorModel) -> None:
    if ranges.ndim != 2:
        raise ValueError(f'ranges must be an (N, K) array, got shape {ranges.shape}')
    if poses.shape != (ranges.shape[0], 3):
        raise ValueError(f'sensor poses must be ({ranges.shape[0]}, 3) for {ranges.shape[0]} '
                         f'scans, got shape {poses.shape}')
    if not np.all(np.isfinite(poses)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(poses), axis=1))[0])
        raise ValueError(f'sensor pose of scan {bad} is not finite: {poses[bad].tolist()}')
    model.check_beam_count(ranges.shape[1])
