"""Robust rigid registration of two submaps of laser end points (point-to-line ICP).

The second stage of the consistency verdict (explanation.py) asks of every failed pair whether a
small rigid correction of one side relative to the other explains its failure. This module
answers the geometric half: it registers the end points of a query submap (a few consecutive
scans) onto the surfaces of a reference submap and returns the correction with its covariance.

- Reference surfaces: every valid end point whose two beam neighbours are valid and close
  carries the normal of the line through them; the reference submap is thinned to one point per
  `voxel` cell so that walls seen by many scans do not dominate.
- Association: the nearest reference point within a gate, found in a uniform grid; the residual
  is the point-to-line distance along that point's normal. Gates shrink from coarse to fine so
  that corrections of a few decimetres converge while the final fit only uses close matches.
- Robustness: at every iteration the `trim` fraction of largest residuals is left out (people,
  moved objects, no-return beams are outliers of a rigid fit).
- Uncertainty: covariance sigma^2 H^-1 of the Gauss-Newton solution, with sigma from the kept
  residuals. A corridor leaves H nearly singular along its axis, so the covariance says that a
  slide along it is not determined.

A correction (tx, ty, theta) acts on the query side as p -> R(theta) (p - c) + c + t, with c the
centroid of the query points: the parametrisation keeps rotation and translation uncorrelated.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

# Neighbouring end points further apart than this do not describe one surface.
SURFACE_GAP = 0.25


@dataclass(frozen=True)
class RegistrationSettings:
    """Gates, iterations and robustness of the point-to-line ICP."""

    gates: tuple[float, ...] = (0.5, 0.25, 0.12)  # metres, coarse to fine association gates
    iterations: int = 8  # Gauss-Newton steps per gate at most
    trim: float = 0.3  # fraction of largest residuals left out of each step
    voxel: float = 0.05  # metres: reference submaps keep one point per cell this size
    query_spacing: float = 0.1  # metres: query submaps keep one point per cell this size
    min_matches: int = 12  # fewer matched query points leave a correction undetermined

    def __post_init__(self) -> None:
        if not self.gates or any(not (gate > 0.0 and math.isfinite(gate)) for gate in self.gates):
            raise ValueError(f'gates must be positive finite metres, got {self.gates}')
        if list(self.gates) != sorted(self.gates, reverse=True):
            raise ValueError(f'gates must shrink from coarse to fine, got {self.gates}')
        if self.iterations < 1 or self.min_matches < 4:
            raise ValueError('iterations must be >= 1 and min_matches >= 4')
        if not 0.0 <= self.trim < 0.9:
            raise ValueError(f'trim must be in [0, 0.9), got {self.trim}')
        if self.voxel <= 0.0 or self.query_spacing <= 0.0:
            raise ValueError('voxel and query_spacing must be positive')


@dataclass(frozen=True)
class SurfacePoints:
    """End points of N scans flattened: scan k owns rows offsets[k]:offsets[k + 1].

    `points (M, 2)` world end points, `normals (M, 2)` unit surface normals (zero where a point
    has none: such points can be matched as queries but not as references).
    """

    points: np.ndarray
    normals: np.ndarray
    offsets: np.ndarray


@dataclass(frozen=True)
class Registrations:
    """Results of T registrations (query side corrected onto reference side)."""

    corrections: np.ndarray  # (T, 3) tx, ty, theta about `centroids`
    centroids: np.ndarray  # (T, 2) centroid c of each query submap
    covariances: np.ndarray  # (T, 3, 3) of the corrections; inf where undetermined
    matched: np.ndarray  # (T,) query points matched within the finest gate at the solution
    determined: np.ndarray  # (T,) bool: enough matches and a regular normal matrix

    def world_transforms(self) -> np.ndarray:
        """The corrections as world transforms.

        Returns
        -------
        (T, 3) world transforms (x, y, theta), p -> R p + (x, y): the same motions as the
        corrections about `centroids`.
        """
        theta = self.corrections[:, 2]
        cos, sin = np.cos(theta), np.sin(theta)
        cx, cy = self.centroids[:, 0], self.centroids[:, 1]
        x = self.corrections[:, 0] + cx - (cos * cx - sin * cy)
        y = self.corrections[:, 1] + cy - (sin * cx + cos * cy)
        return np.stack([x, y, theta], axis=1)


def surface_points(endpoints: np.ndarray, valid: np.ndarray) -> SurfacePoints:
    """Valid end points with normals from their beam neighbours.

    Parameters
    ----------
    endpoints: (N, K, 2) world end points of N scans of K beams, metres.
    valid: (N, K) which beams are real returns.

    Returns
    -------
    The SurfacePoints of the valid end points, scan by scan in beam order.
    """
    valid = np.ascontiguousarray(valid, dtype=np.bool_)
    offsets = np.zeros(valid.shape[0] + 1, dtype=np.int64)
    np.cumsum(valid.sum(axis=1), out=offsets[1:])
    points, normals = _surface_arrays(np.ascontiguousarray(endpoints, dtype=np.float64), valid,
                                      offsets)
    return SurfacePoints(points=points, normals=normals, offsets=offsets)


@numba.njit(cache=True, parallel=True, nogil=True)
def _surface_arrays(endpoints: np.ndarray, valid: np.ndarray, offsets: np.ndarray) -> tuple:
    """The valid end points flattened scan by scan, (M, 2), and their unit normals (M, 2): of
    the line through the two beam neighbours, zero where either is invalid or further than
    SURFACE_GAP (no one surface)."""
    scans, beams = valid.shape
    points = np.empty((offsets[-1], 2))
    normals = np.zeros((offsets[-1], 2))
    for scan in numba.prange(scans):
        row = offsets[scan]
        for beam in range(beams):
            if not valid[scan, beam]:
                continue
            x, y = endpoints[scan, beam, 0], endpoints[scan, beam, 1]
            points[row, 0], points[row, 1] = x, y
            if 0 < beam < beams - 1 and valid[scan, beam - 1] and valid[scan, beam + 1]:
                bx, by = endpoints[scan, beam - 1, 0], endpoints[scan, beam - 1, 1]
                ax, ay = endpoints[scan, beam + 1, 0], endpoints[scan, beam + 1, 1]
                length = math.hypot(ax - bx, ay - by)
                if (math.hypot(bx - x, by - y) < SURFACE_GAP
                        and math.hypot(ax - x, ay - y) < SURFACE_GAP and length > 1e-9):
                    normals[row, 0] = -(ay - by) / length
                    normals[row, 1] = (ax - bx) / length
            row += 1
    return points, normals


@numba.njit(cache=True)
def _thin(points: np.ndarray, normals: np.ndarray, cell: float, need_normal: bool):
    """One point per `cell` square (the first in order), optionally only points with normals."""
    count = points.shape[0]
    keys = np.empty(count, dtype=np.int64)
    usable = np.zeros(count, dtype=np.bool_)
    for index in range(count):
        if need_normal and normals[index, 0] == 0.0 and normals[index, 1] == 0.0:
            keys[index] = 0
            continue
        usable[index] = True
        cx = np.int64(math.floor(points[index, 0] / cell)) + (1 << 30)
        cy = np.int64(math.floor(points[index, 1] / cell)) + (1 << 30)
        keys[index] = (cx << 31) | cy
    order = np.argsort(keys, kind='mergesort')
    keep = np.zeros(count, dtype=np.bool_)
    previous = np.int64(-1)
    for position in range(count):
        index = order[position]
        if usable[index] and keys[index] != previous:
            keep[index] = True
            previous = keys[index]
    return points[keep], normals[keep]


@numba.njit(cache=True)
def point_grid(points: np.ndarray, cell: float, margin: float):
    """Counting-sort grid of points, for `nearest_point`.

    Parameters
    ----------
    points: (M, 2) points, metres; M >= 1.
    cell: the side of a square cell, metres.
    margin: the grid reaches this far beyond the points' bounding box on every side, metres.

    Returns
    -------
    (x0, y0, nx, ny, starts, items): the grid's origin (its lowest corner), its cells along x
    and y, per-cell start offsets (nx * ny + 1,) into `items` (cell (cx, cy) has key
    cx * ny + cy), and `items` (M,), the point indices grouped by cell.
    """
    x0 = points[:, 0].min() - margin
    y0 = points[:, 1].min() - margin
    nx = int((points[:, 0].max() + margin - x0) / cell) + 1
    ny = int((points[:, 1].max() + margin - y0) / cell) + 1
    cell_of = np.empty(points.shape[0], dtype=np.int64)
    starts = np.zeros(nx * ny + 1, dtype=np.int64)
    for index in range(points.shape[0]):
        cx = int((points[index, 0] - x0) / cell)
        cy = int((points[index, 1] - y0) / cell)
        cell_of[index] = cx * ny + cy
        starts[cell_of[index] + 1] += 1
    for position in range(nx * ny):
        starts[position + 1] += starts[position]
    fill = starts[:-1].copy()
    items = np.empty(points.shape[0], dtype=np.int64)
    for index in range(points.shape[0]):
        items[fill[cell_of[index]]] = index
        fill[cell_of[index]] += 1
    return x0, y0, nx, ny, starts, items


@numba.njit(cache=True)
def nearest_point(points: np.ndarray, x0: float, y0: float, nx: int, ny: int, cell: float,
                  starts: np.ndarray, items: np.ndarray, px: float, py: float, gate: float) -> int:
    """The nearest point to p within a gate.

    Parameters
    ----------
    points: (M, 2) the points the grid was built on.
    x0, y0, nx, ny, cell, starts, items: the grid (point_grid) and its cell size.
    px, py: the position p, metres.
    gate: the largest distance of a match, metres; strictly closer points only.

    Returns
    -------
    The index of the nearest point in `points`, -1 where none.
    """
    # only the cells the gate's square touches: at fine gates one to four, not nine
    low_x = max(int(math.floor((px - gate - x0) / cell)), 0)
    high_x = min(int(math.floor((px + gate - x0) / cell)) + 1, nx)
    low_y = max(int(math.floor((py - gate - y0) / cell)), 0)
    high_y = min(int(math.floor((py + gate - y0) / cell)) + 1, ny)
    best, best2 = -1, gate * gate
    for gx in range(low_x, high_x):
        for gy in range(low_y, high_y):
            key = gx * ny + gy
            for position in range(starts[key], starts[key + 1]):
                index = items[position]
                dx, dy = points[index, 0] - px, points[index, 1] - py
                distance2 = dx * dx + dy * dy
                if distance2 < best2:
                    best, best2 = index, distance2
    return best


@numba.njit(cache=True)
def _associate(reference: np.ndarray, normals: np.ndarray, grid: tuple, cell: float,
               query: np.ndarray, cx: float, cy: float, tx: float, ty: float, theta: float,
               gate: float, residuals: np.ndarray, jacobians: np.ndarray) -> int:
    """Point-to-line residuals and Jacobians of the query points matched within `gate` at the
    correction (tx, ty, theta); returns how many matched."""
    x0, y0, nx, ny, starts, items = grid
    cos, sin = math.cos(theta), math.sin(theta)
    matched = 0
    for index in range(query.shape[0]):
        ox, oy = query[index, 0] - cx, query[index, 1] - cy
        rx, ry = cos * ox - sin * oy, sin * ox + cos * oy
        px, py = rx + cx + tx, ry + cy + ty
        near = nearest_point(reference, x0, y0, nx, ny, cell, starts, items, px, py, gate)
        if near < 0:
            continue
        normal_x, normal_y = normals[near, 0], normals[near, 1]
        residuals[matched] = (normal_x * (px - reference[near, 0])
                              + normal_y * (py - reference[near, 1]))
        jacobians[matched, 0] = normal_x
        jacobians[matched, 1] = normal_y
        jacobians[matched, 2] = normal_y * rx - normal_x * ry
        matched += 1
    return matched


@numba.njit(cache=True)
def _normal_equations(residuals: np.ndarray, jacobians: np.ndarray, matched: int, trim: float,
                      hessian: np.ndarray, gradient: np.ndarray) -> tuple:
    """H and g of the matched rows without the `trim` fraction of largest |residual|; returns
    the rows kept and their sum of squares."""
    magnitude = np.abs(residuals[:matched])
    rank = min(int((1.0 - trim) * matched), matched - 1)
    limit = np.partition(magnitude, rank)[rank]  # linear time: a full sort dominated a step
    hessian[:, :] = 0.0
    gradient[:] = 0.0
    kept, square = 0, 0.0
    for row in range(matched):
        if magnitude[row] > limit:
            continue
        kept += 1
        square += residuals[row] * residuals[row]
        for a in range(3):
            gradient[a] += jacobians[row, a] * residuals[row]
            for b in range(3):
                hessian[a, b] += jacobians[row, a] * jacobians[row, b]
    return kept, square


@numba.njit(cache=True)
def symmetric_inverse(matrix: np.ndarray, out: np.ndarray) -> float:
    """The inverse of a symmetric 3 x 3 matrix by its cofactors.

    In closed form because numba's np.linalg goes through LAPACK: a copy and a call per 3 x 3,
    and at the first call an import of all of scipy.linalg.

    Parameters
    ----------
    matrix: (3, 3) symmetric (only its upper triangle is read).
    out: (3, 3) float array that receives the inverse (the adjugate when the determinant is 0).

    Returns
    -------
    The determinant.
    """
    a, b, c = matrix[0, 0], matrix[0, 1], matrix[0, 2]
    d, e, f = matrix[1, 1], matrix[1, 2], matrix[2, 2]
    out[0, 0] = d * f - e * e
    out[0, 1] = out[1, 0] = c * e - b * f
    out[0, 2] = out[2, 0] = b * e - c * d
    out[1, 1] = a * f - c * c
    out[1, 2] = out[2, 1] = b * c - a * e
    out[2, 2] = a * d - b * b
    determinant = a * out[0, 0] + b * out[0, 1] + c * out[0, 2]
    if determinant != 0.0:
        out /= determinant
    return determinant


@numba.njit(cache=True)
def _register_one(reference: np.ndarray, normals: np.ndarray, query: np.ndarray,
                  gates: np.ndarray, iterations: int, trim: float, min_matches: int,
                  out_correction: np.ndarray, out_covariance: np.ndarray) -> tuple:
    # Cells of half the coarsest gate: a lookup scans 5 x 5 cells at first, 3 x 3 later.
    cell = 0.5 * gates[0]
    grid = point_grid(reference, cell, gates[0])
    cx, cy = query[:, 0].mean(), query[:, 1].mean()
    tx, ty, theta = 0.0, 0.0, 0.0
    residuals = np.empty(query.shape[0])
    jacobians = np.empty((query.shape[0], 3))
    hessian, inverse = np.zeros((3, 3)), np.zeros((3, 3))
    gradient = np.zeros(3)
    kept, square, matched = 0, 0.0, 0
    for stage in range(gates.size):
        for step_index in range(iterations):
            matched = _associate(reference, normals, grid, cell, query, cx, cy, tx, ty, theta,
                                 gates[stage], residuals, jacobians)
            if matched < min_matches:
                kept = matched
                break
            kept, square = _normal_equations(residuals, jacobians, matched, trim, hessian,
                                             gradient)
            if abs(symmetric_inverse(hessian, inverse)) < 1e-12:
                break
            step = -(inverse @ gradient)
            tx += step[0]
            ty += step[1]
            theta += step[2]
            # Millimetres and hundredths of a degree are far below any tolerance of a map.
            if abs(step[0]) + abs(step[1]) < 1e-3 and abs(step[2]) < 2e-4:
                break
    out_correction[0], out_correction[1], out_correction[2] = tx, ty, theta
    determined = kept >= min_matches and abs(symmetric_inverse(hessian, inverse)) > 1e-12
    if determined:
        out_covariance[:, :] = square / max(kept - 3, 1) * inverse
    else:
        out_covariance[:, :] = np.inf
    return cx, cy, matched, determined


@numba.njit(cache=True, parallel=True, nogil=True)
def _thin_ranges(points: np.ndarray, normals: np.ndarray, offsets: np.ndarray,
                 ranges: np.ndarray, cell: float, need_normal: bool):
    """Every submap (scan range) of `ranges` (R, 2) thinned once: submap r owns rows
    starts[r]:starts[r] + counts[r] of the returned points and normals."""
    sizes = np.empty(ranges.shape[0], dtype=np.int64)
    for row in range(ranges.shape[0]):
        sizes[row] = offsets[ranges[row, 1]] - offsets[ranges[row, 0]]
    starts = np.zeros(ranges.shape[0], dtype=np.int64)
    starts[1:] = np.cumsum(sizes)[:-1]
    total = int(sizes.sum())
    out_points = np.empty((total, 2))
    out_normals = np.empty((total, 2))
    counts = np.zeros(ranges.shape[0], dtype=np.int64)
    for row in numba.prange(ranges.shape[0]):
        first, last = offsets[ranges[row, 0]], offsets[ranges[row, 1]]
        kept, kept_normals = _thin(points[first:last], normals[first:last], cell, need_normal)
        begin = starts[row]
        out_points[begin:begin + kept.shape[0]] = kept
        out_normals[begin:begin + kept.shape[0]] = kept_normals
        counts[row] = kept.shape[0]
    return out_points, out_normals, starts, counts


@numba.njit(cache=True, parallel=True, nogil=True)
def _register_tasks(references: tuple, queries: tuple, reference_of_task: np.ndarray,
                    query_of_task: np.ndarray, gates: np.ndarray, iterations: int, trim: float,
                    min_matches: int):
    reference_points, reference_normals, reference_starts, reference_counts = references
    query_points, _, query_starts, query_counts = queries
    total = reference_of_task.size
    corrections = np.zeros((total, 3))
    centroids = np.zeros((total, 2))
    covariances = np.full((total, 3, 3), np.inf)
    matched = np.zeros(total, dtype=np.int64)
    determined = np.zeros(total, dtype=np.bool_)
    for task in numba.prange(total):
        r, q = reference_of_task[task], query_of_task[task]
        if reference_counts[r] < min_matches or query_counts[q] < min_matches:
            continue
        r0, q0 = reference_starts[r], query_starts[q]
        cx, cy, fine, ok = _register_one(
            reference_points[r0:r0 + reference_counts[r]],
            reference_normals[r0:r0 + reference_counts[r]],
            query_points[q0:q0 + query_counts[q]], gates, iterations, trim, min_matches,
            corrections[task], covariances[task])
        centroids[task, 0], centroids[task, 1] = cx, cy
        matched[task], determined[task] = fine, ok
    return corrections, centroids, covariances, matched, determined


def register_submaps(surfaces: SurfacePoints, tasks: np.ndarray,
                     settings: RegistrationSettings | None = None) -> Registrations:
    """Register query submaps onto reference submaps, one per row of `tasks`.

    Parameters
    ----------
    surfaces: the end points and normals of N scans (surface_points).
    tasks: (T, 4) rows (r0, r1, q0, q1): the scans r0:r1 of `surfaces` are the reference,
        q0:q1 the query.
    settings: the ICP's settings; None for the defaults.

    Returns
    -------
    The Registrations of the T tasks, in order (undetermined, with infinite covariance, where
    a submap holds fewer than min_matches points). Raises ValueError for rows outside the
    scans or empty ranges.
    """
    settings = settings or RegistrationSettings()
    tasks = np.ascontiguousarray(tasks, dtype=np.int64).reshape(-1, 4)
    scans = surfaces.offsets.size - 1
    if tasks.size and (tasks.min() < 0 or tasks.max() > scans
                       or np.any(tasks[:, 1] <= tasks[:, 0]) or np.any(tasks[:, 3] <= tasks[:, 2])):
        raise ValueError(f'registration tasks must be non-empty scan ranges within [0, {scans}]')
    # Tasks share submaps (a block of scans against several others): thin each one once.
    reference_ranges, reference_of_task = np.unique(tasks[:, :2], axis=0, return_inverse=True)
    query_ranges, query_of_task = np.unique(tasks[:, 2:], axis=0, return_inverse=True)
    references = _thin_ranges(surfaces.points, surfaces.normals, surfaces.offsets,
                              np.ascontiguousarray(reference_ranges), settings.voxel, True)
    queries = _thin_ranges(surfaces.points, surfaces.normals, surfaces.offsets,
                           np.ascontiguousarray(query_ranges), settings.query_spacing, False)
    corrections, centroids, covariances, matched, determined = _register_tasks(
        references, queries, reference_of_task.reshape(-1), query_of_task.reshape(-1),
        np.asarray(settings.gates, dtype=np.float64), settings.iterations, settings.trim,
        settings.min_matches)
    return Registrations(corrections=corrections, centroids=centroids, covariances=covariances,
                         matched=matched, determined=determined)


def register_onto_points(reference_points: np.ndarray, reference_normals: np.ndarray,
                         surfaces: SurfacePoints, queries: np.ndarray,
                         settings: RegistrationSettings | None = None) -> Registrations:
    """Register query submaps onto one fixed reference surface that is no scan (a map's points).

    The reference of `register_submaps` is a submap of scans; here it is given as points with
    normals (the occupied cells of a map, one point per cell, so not thinned again). Each
    query sees only the reference points within the coarsest gate of its bounding box, the
    same ICP (`_register_one`) runs on every query.

    Parameters
    ----------
    reference_points: (M, 2) reference surface points, metres.
    reference_normals: (M, 2) their unit normals (zero where a point has none: it is not
        matched).
    surfaces: the end points and normals of N scans (surface_points).
    queries: (T, 2) rows (q0, q1): the scans q0:q1 of `surfaces` are a query submap.
    settings: the ICP's settings; None for the defaults.

    Returns
    -------
    The Registrations of the T queries onto the reference, in order (undetermined, with
    infinite covariance, where a query or its part of the reference holds fewer than
    min_matches points). Raises ValueError for rows outside the scans, empty ranges or
    reference arrays of different shapes.
    """
    settings = settings or RegistrationSettings()
    queries = np.ascontiguousarray(queries, dtype=np.int64).reshape(-1, 2)
    reference_points = np.ascontiguousarray(reference_points, dtype=np.float64).reshape(-1, 2)
    reference_normals = np.ascontiguousarray(reference_normals, dtype=np.float64).reshape(-1, 2)
    if reference_points.shape != reference_normals.shape:
        raise ValueError('reference points and normals must have the same shape')
    scans = surfaces.offsets.size - 1
    if queries.size and (queries.min() < 0 or queries.max() > scans
                         or np.any(queries[:, 1] <= queries[:, 0])):
        raise ValueError(f'query submaps must be non-empty scan ranges within [0, {scans}]')
    usable = np.any(reference_normals != 0.0, axis=1)
    reference_points, reference_normals = reference_points[usable], reference_normals[usable]
    query_ranges, query_of_task = np.unique(queries, axis=0, return_inverse=True)
    thinned = _thin_ranges(surfaces.points, surfaces.normals, surfaces.offsets,
                           np.ascontiguousarray(query_ranges), settings.query_spacing, False)
    points, _, starts, counts = thinned
    # each query's own crop of the reference: the bounding box of its points and a gate
    crops, crop_normals, crop_counts = [], [], np.zeros(len(query_ranges), dtype=np.int64)
    reach = settings.gates[0]
    for row in range(len(query_ranges)):
        own = points[starts[row]:starts[row] + counts[row]]
        if own.shape[0] == 0:
            continue
        low, high = own.min(axis=0) - reach, own.max(axis=0) + reach
        inside = np.all((reference_points >= low) & (reference_points <= high), axis=1)
        crops.append(reference_points[inside])
        crop_normals.append(reference_normals[inside])
        crop_counts[row] = int(inside.sum())
    crop_starts = np.zeros(len(query_ranges), dtype=np.int64)
    crop_starts[1:] = np.cumsum(crop_counts)[:-1]
    references = (np.concatenate(crops) if crops else np.zeros((0, 2)),
                  np.concatenate(crop_normals) if crops else np.zeros((0, 2)),
                  crop_starts, crop_counts)
    index = np.arange(len(query_ranges), dtype=np.int64)
    corrections, centroids, covariances, matched, determined = _register_tasks(
        references, thinned, index, index, np.asarray(settings.gates, dtype=np.float64),
        settings.iterations, settings.trim, settings.min_matches)
    take = query_of_task.reshape(-1)
    return Registrations(corrections=corrections[take], centroids=centroids[take],
                         covariances=covariances[take], matched=matched[take],
                         determined=determined[take])
