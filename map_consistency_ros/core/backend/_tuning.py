"""The DCS parameter search of Mazuran et al. (ICRA 2014, Section V).

M(Phi), the average inconsistency of a DCS solution (eq. 11), is the mean pairwise measure
M_ij over the scan pairs whose polygons overlap, with the scans placed at the poses DCS finds
with parameter Phi from the graph's initial guess. Phi* = argmin M(Phi) (eq. 12) is searched
over sqrt(Phi) (Phi is a squared quantity): a grid, then golden-section refinement around the
best grid point until the Phi bracket is narrower than the tolerance or the profile is flat
there (its two inner values within `flat_tolerance` of each other). The statistical test then
says whether even the map at Phi* is consistent, its local scales fitted on the
incremental solution (the odometry chain). The result says when the search cannot be trusted
to have found a minimum: the grid's smallest M lies at an end of the range (the minimum may lie
beyond it), or the whole profile is flat (every Phi gives the same map within the measure's
noise, so Phi* is arbitrary).
"""
from __future__ import annotations

import math
import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from map_consistency_ros.core.consistency import (ConsistencyParameters, ConsistencyResult,
                                                  average_inconsistency, check_consistency)
from map_consistency_ros.core.backend._dcs import OptimizationResult, SparseSystem, optimize
from map_consistency_ros.core.geometry import (PairMeasures, ScanSet, SensorModel, candidate_pairs,
                                               pair_measures, se2)
from map_consistency_ros.core.parameters import Settings, parameter
from map_consistency_ros.core.backend._posegraph import PoseGraph

Progress = Callable[[int, int], None]
_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


@dataclass(frozen=True)
class TuningSettings(Settings):
    """Search range and resolution of the Phi search and its DCS solves.

    The range is the original optimizer tool's; its grid had 40 steps. 20 steps (0.2 apart in
    sqrt(Phi)) found the same Phi* region on eleven built graphs (Intel and Freiburg 079, 0 to
    300 false loop closures): M(Phi*) within 0.07 % of the 40-step search, the same verdict,
    the flagged scans within one and the tuned map's RMS within 2 mm, in half the evaluations.
    `sqrt_grid` spaces the grid evenly in sqrt(Phi), otherwise in Phi. `workers` DCS solves run
    at once on the grid (0: one per CPU, at most 4); each holds a few arrays of the graph's
    size, so memory is rarely the limit. `flat_tolerance`: the golden section stops once its two
    inner M values differ by less than this fraction of them (the profile is flat within its
    noise there; 0 refines to `tolerance`), and a whole profile within it is reported flat. `reuse_tolerance` (metres): a pair's M_ij is reused
    from the map it was last measured on while its scans' relative pose moves every end point by
    at most this much, which bounds the change of M_ij by the pair's valid end points times it
    (0: only unmoved pairs are reused). Each solve stops, as GTSAM's, once a step lowers the cost
    by less than `relative_tolerance` of it (the search needs M to 1e-3, not the poses to
    1e-10 m), and starts with damping `initial_damping` times the largest diagonal entry of the
    normal equations (about GTSAM's absolute 1e-5 on these graphs; the solver's default 1e-6
    takes twice the iterations).
    """

    phi_min: float = parameter(1e-6, 'smallest DCS Phi of the search', '', (1e-12, 1e6))
    phi_max: float = parameter(16.0, 'largest DCS Phi of the search', '', (1e-9, 1e9))
    grid_steps: int = parameter(20, 'grid points of the Phi search', '', (3, 10_000))
    tolerance: float = parameter(1e-4, 'the Phi search stops when its bracket is narrower', '',
                                 (1e-12, 1e3))
    sqrt_grid: bool = parameter(True, 'space the grid evenly in sqrt(Phi), else in Phi')
    iterations: int = parameter(50, 'solver iterations per DCS solve', '', (1, 10_000))
    workers: int = parameter(0, 'DCS solves at once (0: one per CPU, at most 4)', '', (0, 64))
    flat_tolerance: float = parameter(
        1e-3, 'the golden section stops once its inner M values differ by less than this '
        'fraction (0: refine to tolerance)', '', (0.0, 1.0))
    reuse_tolerance: float = parameter(
        1e-4, "a pair's M_ij is reused while its scans' relative pose moves no end point "
        'further than this', 'm', (0.0, 1.0))
    relative_tolerance: float = parameter(
        1e-10, 'a DCS solve stops once a step lowers the cost by less than this fraction', '',
        (0.0, 1.0))
    initial_damping: float = parameter(
        1e-9, "a DCS solve's first damping, times the largest normal-equation diagonal", '',
        (1e-16, 1.0))

    def __post_init__(self) -> None:
        super().__post_init__()
        # the declared bounds keep both positive; the search needs a range, not a point
        if not self.phi_min < self.phi_max:
            raise ValueError(f'need 0 < phi_min < phi_max, got {self.phi_min}, {self.phi_max}')

    def grid(self) -> np.ndarray:
        """The Phi values of the grid.

        Returns
        -------
        (grid_steps,) Phi values from phi_min to phi_max, increasing, evenly spaced in
        sqrt(Phi) when `sqrt_grid`, else in Phi.
        """
        if self.sqrt_grid:
            return np.linspace(math.sqrt(self.phi_min), math.sqrt(self.phi_max),
                               self.grid_steps) ** 2
        return np.linspace(self.phi_min, self.phi_max, self.grid_steps)


@dataclass(frozen=True)
class Evaluation:
    """M(Phi) at one Phi with the optimization behind it (value inf when the solver failed)."""

    phi: float
    value: float
    optimization: OptimizationResult


@dataclass(frozen=True)
class TuningResult:
    """Phi*, M(Phi*) (m), the optimized poses (N, 3) of every vertex, every evaluated
    (Phi, M(Phi)) sorted by Phi, and the statistical test on the map (the scans) at Phi*.

    `at_bound` is 'phi_min' or 'phi_max' when the grid's smallest M lies at that end of the
    search range (None otherwise); `flat` is True when every finite M of the profile lies
    within `flat_tolerance` of the smallest (`profile_shape`)."""

    phi: float
    average_inconsistency: float
    poses: np.ndarray
    profile_phi: np.ndarray
    profile_value: np.ndarray
    consistency: ConsistencyResult
    consistent: bool
    at_bound: str | None = None
    flat: bool = False


class InconsistencyProfile:
    """Evaluates M(Phi) on one graph with its scans, caching every Phi evaluated.

    Shared across evaluations: the sparsity analysis and ordering of the normal equations, the
    scans (only their poses change) and the pair measures of the maps measured so far (pairs
    whose relative pose stayed within `reuse_tolerance` are not measured again). Every DCS solve
    starts from the graph's initial guess, so the solution at each Phi does not depend on the
    order of evaluation.

    Parameters
    ----------
    graph: the pose graph; every solve starts from its poses.
    ranges: (S, K) the scans (m): of every vertex, or of the vertices `scan_vertices`.
    model: the sensor model of the scans.
    laser_offset: (3,) the laser's pose (x, y, theta) in the vertex frame.
    settings: the search's settings (the solves' and the reuse of measures).
    scan_vertices: (S,) the vertex of each row of `ranges`, increasing; None: row i is the
        scan of vertex i (S = N). A SLAM graph holds vertices whose scans the test folded into
        a viewpoint: they are solved with the others, but M is measured on the scans given.
    """

    def __init__(self, graph: PoseGraph, ranges: np.ndarray, model: SensorModel,
                 laser_offset: np.ndarray = (0.0, 0.0, 0.0),
                 settings: TuningSettings = TuningSettings(),
                 scan_vertices: np.ndarray | None = None) -> None:
        self.graph = graph
        self.settings = settings
        self.laser_offset = np.asarray(laser_offset, dtype=np.float64)
        self.scan_vertices = _scan_vertices(scan_vertices, graph.vertex_count, len(ranges))
        self.scans = ScanSet.from_ranges(ranges, self.sensor_poses(graph.poses), model)
        self._system = SparseSystem(graph)
        self._cache: dict[float, Evaluation] = {}
        self._measured: MeasuredPairs | None = None

    def sensor_poses(self, poses: np.ndarray) -> np.ndarray:
        """The laser poses of the scans with the vertices at `poses`.

        Parameters
        ----------
        poses: (N, 3) vertex poses.

        Returns
        -------
        (S, 3) laser poses: `laser_offset` composed onto the pose of each scan's vertex.
        """
        return se2.compose(poses[self.scan_vertices], self.laser_offset)

    def scans_at(self, poses: np.ndarray) -> ScanSet:
        """The graph's scans with the vertices at `poses`.

        Parameters
        ----------
        poses: (N, 3) vertex poses (e.g. an optimization's).

        Returns
        -------
        The ScanSet of the S scans placed there.
        """
        return self.scans.with_poses(self.sensor_poses(poses))

    def evaluate(self, phi: float) -> Evaluation:
        """M(Phi) and its optimization (cached).

        Parameters
        ----------
        phi: the DCS parameter Phi (> 0).

        Returns
        -------
        The Evaluation, the same object on later calls. ValueError when the normal equations
        are singular.
        """
        return self.evaluate_many([phi])[0]

    def evaluate_many(self, phis: np.ndarray, progress: Progress | None = None,
                      done: int = 0, total: int | None = None) -> list[Evaluation]:
        """M(Phi) for each Phi: the DCS solves in parallel threads, the measures in turn.

        The measure kernel is itself parallel, so running it from several threads at once
        would only contend for the same cores.

        Parameters
        ----------
        phis: the Phi values (> 0); each new value is solved once, cached ones not again.
        progress: progress(done, total), called after each new evaluation.
        done: evaluations already counted by the caller (progress counts on from there).
        total: the total passed to progress; None: the number of new values.

        Returns
        -------
        One Evaluation per entry of `phis`, in their order. ValueError when the normal
        equations are singular.
        """
        phis = [float(phi) for phi in phis]
        new = [phi for phi in dict.fromkeys(phis) if phi not in self._cache]
        total = len(new) if total is None else total
        workers = self.settings.workers or min(4, os.cpu_count() or 1)
        with ThreadPoolExecutor(max_workers=max(1, min(workers, len(new) or 1))) as pool:
            for count, (phi, result) in enumerate(zip(new, pool.map(self._solve, new)), 1):
                self._cache[phi] = Evaluation(phi, self._value(result), result)
                if progress is not None:
                    progress(done + count, total)
        return [self._cache[phi] for phi in phis]

    def profile(self) -> tuple[np.ndarray, np.ndarray]:
        """Every evaluated (Phi, M(Phi)).

        Returns
        -------
        (phi (M,), value (M,)), sorted by Phi; value inf where the solve failed.
        """
        phis = np.array(sorted(self._cache))
        return phis, np.array([self._cache[phi].value for phi in phis])

    def best(self) -> Evaluation:
        """The best evaluation so far.

        Returns
        -------
        The evaluation with the smallest M(Phi) (the smaller Phi on ties); ValueError before
        the first.
        """
        return min(self._cache.values(), key=lambda item: (item.value, item.phi))

    def _solve(self, phi: float) -> OptimizationResult:
        settings = self.settings
        return optimize(self.graph, phi, iterations=settings.iterations, system=self._system,
                        relative_tolerance=settings.relative_tolerance,
                        initial_damping=settings.initial_damping)

    def _value(self, result: OptimizationResult) -> float:
        if not (np.isfinite(result.cost) and np.all(np.isfinite(result.poses))):
            return math.inf
        scans = self.scans_at(result.poses)
        self._measured = measure_moved(scans, candidate_pairs(scans.extents), self._measured,
                                       self.settings.reuse_tolerance)
        return average_inconsistency(self._measured.measures)


def _scan_vertices(scan_vertices: np.ndarray | None, count: int, scans: int) -> np.ndarray:
    """The vertex of each scan (all of them when None); ValueError unless increasing
    vertex indices, one per scan."""
    if scan_vertices is None:
        if scans != count:
            raise ValueError(f'{scans} scans for {count} vertices')
        return np.arange(count)
    vertices = np.asarray(scan_vertices, dtype=np.int64).reshape(-1)
    if vertices.size != scans:
        raise ValueError(f'{scans} scans but {vertices.size} scan vertices')
    if vertices.size and (vertices[0] < 0 or vertices[-1] >= count
                          or np.any(np.diff(vertices) <= 0)):
        raise ValueError(f'scan vertices must be increasing indices in 0..{count - 1}')
    return vertices


@dataclass(frozen=True)
class MeasuredPairs:
    """Measures of sorted candidate pairs (P, 2), with the relative sensor pose (P, 3) of scan j
    in scan i's frame at which each was measured."""

    measures: PairMeasures
    relative: np.ndarray


def measure_moved(scans: ScanSet, pairs: np.ndarray, previous: MeasuredPairs | None,
                  tolerance: float) -> MeasuredPairs:
    """The measures of `pairs` on `scans`, measuring only the pairs that are new or whose end
    points moved by more than `tolerance` relative to each other since `previous`.

    With A = (t, theta) the pose of j's sensor in i's, an end point of j within range r of its
    sensor moves in i's frame by at most |dt| + |dtheta| r, one of i by at most
    |dt| + |dtheta| (|t| + r): the larger bound decides. Reused pairs keep the relative pose
    they were measured at, so reuse never drifts.

    Parameters
    ----------
    scans: the scans, placed on the map to measure.
    pairs: (P, 2) scan index pairs (i < j), sorted (as candidate_pairs gives them).
    previous: the measures of an earlier map of the same scans; None: measure every pair.
    tolerance: the largest movement (m) of an end point at which a pair is reused.

    Returns
    -------
    The MeasuredPairs of `pairs`, in their order, keeping no largest distances.
    """
    poses = scans.sensor_poses
    relative = se2.relative(poses[pairs[:, 0]], poses[pairs[:, 1]])
    stale = np.ones(len(pairs), dtype=bool)
    sums, counts = np.zeros(len(pairs)), np.zeros(len(pairs), dtype=np.int64)
    if previous is not None and len(previous.measures.pairs) and len(pairs):
        count = scans.scan_count
        known = previous.measures.pairs[:, 0] * count + previous.measures.pairs[:, 1]
        keys = pairs[:, 0] * count + pairs[:, 1]
        rows = np.minimum(np.searchsorted(known, keys), len(known) - 1)
        found = known[rows] == keys
        then = previous.relative[rows]
        reach = float(scans.ranges.max())
        moved = (np.hypot(*(relative[:, :2] - then[:, :2]).T)
                 + np.abs(se2.wrap_angle(relative[:, 2] - then[:, 2]))
                 * (np.hypot(*then[:, :2].T) + reach))
        reuse = found & (moved <= tolerance)
        stale = ~reuse
        sums[reuse] = previous.measures.distance_sum[rows[reuse]]
        counts[reuse] = previous.measures.point_count[rows[reuse]]
        relative[reuse] = then[reuse]
    measures = pair_measures(scans, pairs[stale], keep_largest=0)
    sums[stale], counts[stale] = measures.distance_sum, measures.point_count
    return MeasuredPairs(PairMeasures(pairs=pairs, distance_sum=sums, point_count=counts,
                                       largest=np.zeros((len(pairs), 0))), relative)


def tune_dcs(graph: PoseGraph, ranges: np.ndarray, model: SensorModel,
             laser_offset: np.ndarray = (0.0, 0.0, 0.0),
             settings: TuningSettings = TuningSettings(),
             parameters: ConsistencyParameters = ConsistencyParameters(),
             progress: Progress | None = None,
             profile: InconsistencyProfile | None = None,
             scan_vertices: np.ndarray | None = None) -> TuningResult:
    """Find Phi* = argmin M(Phi) on [phi_min, phi_max] and test the map at Phi*.

    Parameters
    ----------
    graph: the pose graph; every solve starts from its poses.
    ranges: (S, K) the scans (m): of every vertex, or of the vertices `scan_vertices`.
    model: the sensor model of the scans.
    laser_offset: (3,) the laser's pose (x, y, theta) in the vertex frame.
    settings: the search's settings.
    parameters: the statistical test's parameters, with which the map at Phi* is tested
        (its local scales fitted on the odometry chain).
    progress: progress(done, total), called after each evaluation; the total is the grid,
        the refinement's estimate and the test.
    profile: an InconsistencyProfile built on the same graph, scans and settings, to share
        evaluations with the caller (e.g. to look at Phi = 1 afterwards without solving
        again); None: a new one.
    scan_vertices: (S,) the vertex of each scan, increasing (InconsistencyProfile); None:
        one scan per vertex.

    Returns
    -------
    The TuningResult: `poses` those of every vertex, the test on the S scans. ValueError when
    the graph cannot be solved (no edge constrains the free vertices).
    """
    profile = profile or InconsistencyProfile(graph, ranges, model, laser_offset, settings,
                                              scan_vertices)
    grid = settings.grid()
    refinements = _refinement_steps(grid, settings)
    total = len(grid) + refinements + 1
    values = [item.value for item in profile.evaluate_many(grid, progress, 0, total)]
    _golden_section(profile, grid, int(np.argmin(values)), settings, progress, len(grid), total)
    best = profile.best()
    reference = profile.scans_at(graph.odometry_chain())
    consistency = check_consistency(profile.scans_at(best.optimization.poses),
                                    parameters, reference_scans=reference)
    if progress is not None:
        progress(total, total)
    phis, values = profile.profile()
    at_bound, flat = profile_shape(phis, values, settings)
    return TuningResult(phi=best.phi, average_inconsistency=best.value,
                        poses=best.optimization.poses, profile_phi=phis, profile_value=values,
                        consistency=consistency, consistent=consistency.consistent,
                        at_bound=at_bound, flat=flat)


def profile_shape(phis: np.ndarray, values: np.ndarray, settings: TuningSettings
                  ) -> tuple[str | None, bool]:
    """Whether a search's minimum can be trusted: where the grid puts it, and whether the
    profile is flat.

    The profile is flat when all its finite values lie within `flat_tolerance` of the
    smallest (`_flat`, the golden section's own stopping rule): the differences are then of the
    order of the measure's own noise (pairs entering and leaving the overlap as poses move by
    millimetres), so no Phi makes the map measurably more consistent than another.

    Parameters
    ----------
    phis: (M,) the evaluated Phi values (the grid's among them).
    values: (M,) M(Phi) at each (inf where the solve failed).
    settings: the search's settings (its grid, its flat tolerance).

    Returns
    -------
    (at_bound, flat): at_bound 'phi_min' or 'phi_max' when the smallest finite M of the grid
    lies at that end of the grid (the minimum may lie beyond the range), None otherwise or
    when the profile is flat (then no point is a minimum); flat as above (False with fewer
    than two finite values).
    """
    phis, values = np.asarray(phis, dtype=np.float64), np.asarray(values, dtype=np.float64)
    finite = values[np.isfinite(values)]
    flat = finite.size >= 2 and _flat(finite, settings.flat_tolerance)
    grid = settings.grid()
    on_grid = np.array([values[np.argmin(np.abs(phis - phi))] if phis.size else math.inf
                        for phi in grid])
    if flat or not np.isfinite(on_grid).any():
        return None, flat
    best = int(np.argmin(on_grid))
    at_bound = 'phi_min' if best == 0 else 'phi_max' if best == len(grid) - 1 else None
    return at_bound, flat


def _bracket(grid: np.ndarray, index: int, settings: TuningSettings) -> tuple[float, float]:
    """Search coordinates (sqrt(Phi) or Phi) of the grid points on either side of `index`."""
    low, high = grid[max(index - 1, 0)], grid[min(index + 1, len(grid) - 1)]
    return (math.sqrt(low), math.sqrt(high)) if settings.sqrt_grid else (low, high)


def _to_phi(coordinate: float, settings: TuningSettings) -> float:
    return coordinate * coordinate if settings.sqrt_grid else coordinate


def _refinement_steps(grid: np.ndarray, settings: TuningSettings) -> int:
    """Golden-section steps needed for the widest bracket around a grid point."""
    widest = max(grid[min(k + 1, len(grid) - 1)] - grid[max(k - 1, 0)] for k in range(len(grid)))
    return max(0, math.ceil(math.log(settings.tolerance / widest) / math.log(_GOLDEN)))


def _golden_section(profile: InconsistencyProfile, grid: np.ndarray, index: int,
                    settings: TuningSettings, progress: Progress | None, done: int,
                    total: int) -> None:
    """Shrink the bracket around grid[index] by golden sections until its Phi width < tolerance
    or its two inner values agree within the flat tolerance.

    M(Phi) is only pointwise evaluable and need not be smooth: the section keeps the side
    holding the smaller value, one new evaluation per step.
    """
    low, high = _bracket(grid, index, settings)

    def values(*coordinates: float) -> list[float]:
        nonlocal done
        evaluations = profile.evaluate_many(
            [_to_phi(coordinate, settings) for coordinate in coordinates], progress, done, total)
        done += len(coordinates)
        return [item.value for item in evaluations]

    inner_low = high - _GOLDEN * (high - low)
    inner_high = low + _GOLDEN * (high - low)
    # The first two are independent: their solves run side by side.
    value_low, value_high = values(inner_low, inner_high)
    while (_to_phi(high, settings) - _to_phi(low, settings) >= settings.tolerance
           and not _flat(np.array([value_low, value_high]), settings.flat_tolerance)):
        if value_low <= value_high:
            high, inner_high, value_high = inner_high, inner_low, value_low
            inner_low = high - _GOLDEN * (high - low)
            value_low, = values(inner_low)
        else:
            low, inner_low, value_low = inner_low, inner_high, value_high
            inner_high = low + _GOLDEN * (high - low)
            value_high, = values(inner_high)


def _flat(values: np.ndarray, tolerance: float) -> bool:
    """Whether M values agree within `tolerance` of the smallest (all finite): the one
    definition of a flat profile, for the golden section's stop and the search's warning."""
    return bool(np.all(np.isfinite(values))
                and values.max() - values.min() <= tolerance * values.min())


def search_findings(result: TuningResult, settings: TuningSettings,
                    name: Callable[[str], str] = str) -> list[str]:
    """What a user should know before trusting Phi*: a minimum at an end of the search range,
    or a profile so flat that Phi* is arbitrary (`tune` prints them, the node's retune answers
    with them).

    Parameters
    ----------
    result: the search's result (its at_bound and flat findings).
    settings: the search's settings (its range and flat tolerance).
    name: how the caller names a setting (an option '--phi-max', a node parameter 'phi_max').

    Returns
    -------
    One sentence per finding; none when Phi* is a minimum inside the range.
    """
    findings = []
    if result.flat:
        finite = result.profile_value[np.isfinite(result.profile_value)]
        findings.append(
            f'M(Phi) is flat: {finite.min():.6g} m to {finite.max():.6g} m over Phi '
            f'{settings.phi_min:g} to {settings.phi_max:g} (within {name("flat_tolerance")} '
            f'{settings.flat_tolerance:g} of the smallest): no Phi makes the map measurably '
            'more consistent, so Phi* is arbitrary; DCS has little to downweight in this graph')
    if result.at_bound == 'phi_min':
        findings.append(
            f'Phi* = {result.phi:.6g} lies at the lower end of the search ({name("phi_min")} '
            f'{settings.phi_min:g}): a smaller Phi may give a smaller M; search lower with '
            f'{name("phi_min")}')
    elif result.at_bound == 'phi_max':
        findings.append(
            f'Phi* = {result.phi:.6g} lies at the upper end of the search ({name("phi_max")} '
            f'{settings.phi_max:g}): a larger Phi may give a smaller M; search higher with '
            f'{name("phi_max")}')
    return findings
