"""DCS solve and full Phi search on the built Intel graph, beside GTSAM solving the same graph.

    .venv/bin/python bench/bench_dcs.py [--false-loops 100] [--repeat 3] [--grid-steps 40]
                                         [--tolerance 1e-4] [--skip-tune]

The graph: Intel corrected log + relations + raw bag (io.datasets), with --false-loops random
false loop closures. For Phi = 1 and plain least squares, both solvers start from the same
initial guess: ours (sparse LM, numba linearisation, SuperLU in symmetric mode) and GTSAM 4.3
(LevenbergMarquardtOptimizer, DCS robust noise on the loop closures, default tolerances with
the relative one tightened to 1e-10), ours under the same stopping rule (relative decrease
1e-10, absolute 2e-5 on our cost, twice GTSAM's error) with the tuning's initial damping, and
ours by its default step criterion. Wall times are the best of --repeat runs after a warm-up;
the per-iteration figure divides by each solver's own iteration count. Then one full tune
(grid + golden section + the final test) with its share spent in the solver.
"""
from __future__ import annotations

import argparse
import importlib.util
import time
from pathlib import Path

import gtsam
import numpy as np

from map_consistency_ros.core.backend import (InconsistencyProfile, PoseGraph, SparseSystem,
                                              TuningSettings, optimize, tune_dcs)
from map_consistency_ros.core.geometry import se2
from map_consistency_ros.io.carmen import sensor_model
from map_consistency_ros.io.datasets import BuildSettings, build_dataset

ROOT = Path(__file__).resolve().parents[1]
INTEL = ROOT.parent / 'shared' / 'data' / 'intel'


def _load_oracle():
    """The tests' GTSAM formulation (test/core/backend/test_dcs.py), so both agree."""
    path = ROOT / 'test' / 'core' / 'backend' / 'test_dcs.py'
    spec = importlib.util.spec_from_file_location('dcs_oracle', path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


ORACLE = _load_oracle()
GTSAM_ABSOLUTE = gtsam.LevenbergMarquardtParams().getAbsoluteErrorTol()


def best_of(function, repeat: int) -> tuple[float, object]:
    """Shortest wall time of `repeat` calls after a warm-up call, and the last result."""
    result = function()
    best = np.inf
    for _ in range(repeat):
        start = time.perf_counter()
        result = function()
        best = min(best, time.perf_counter() - start)
    return best, result


def gtsam_solve(graph: PoseGraph, phi: float | None) -> tuple[np.ndarray, int]:
    """GTSAM's LM on the same problem: optimized poses and its iteration count."""
    factors, values = ORACLE.gtsam_problem(graph, phi)
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-10)
    params.setMaxIterations(200)
    optimizer = gtsam.LevenbergMarquardtOptimizer(factors, values, params)
    result = optimizer.optimize()
    poses = np.array([[result.atPose2(i).x(), result.atPose2(i).y(), result.atPose2(i).theta()]
                      for i in range(graph.vertex_count)])
    return poses, optimizer.iterations()


def compare_solvers(graph: PoseGraph, phi: float | None, repeat: int) -> float:
    """Print both solvers' times on one Phi; return our time per iteration in seconds."""
    system = SparseSystem(graph)
    theirs_time, (poses, theirs_iterations) = best_of(lambda: gtsam_solve(graph, phi), repeat)
    theirs_per_iteration = theirs_time / max(theirs_iterations, 1)
    label = 'least squares' if phi is None else f'Phi = {phi:g}'
    print(f'{label}: GTSAM {theirs_time * 1e3:8.1f} ms, {theirs_iterations:3d} it, '
          f'{theirs_per_iteration * 1e3:6.2f} ms/it')
    same_rule = dict(relative_tolerance=1e-10, absolute_tolerance=2.0 * GTSAM_ABSOLUTE,
                     initial_damping=TuningSettings().initial_damping)
    per_iteration = np.inf
    for name, options in (("ours, GTSAM's stopping rule", same_rule),
                          ('ours, step criterion', {})):
        ours_time, ours = best_of(lambda: optimize(graph, phi, iterations=200, system=system,
                                                   **options), repeat)
        difference = poses - ours.poses
        difference[:, 2] = se2.wrap_angle(difference[:, 2])
        per_iteration = min(per_iteration, ours_time / ours.iterations)
        print(f'  {name:<28} {ours_time * 1e3:8.1f} ms, {ours.iterations:3d} it, '
              f'{ours_time / ours.iterations * 1e3:6.2f} ms/it | x GTSAM '
              f'{ours_time / theirs_time:5.2f} (solve), '
              f'{ours_time / ours.iterations / theirs_per_iteration:5.2f} (per it) | max pose '
              f'difference {np.abs(difference).max():.1e}')
    return per_iteration


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--false-loops', type=int, default=100)
    parser.add_argument('--repeat', type=int, default=3)
    parser.add_argument('--grid-steps', type=int, default=TuningSettings().grid_steps)
    parser.add_argument('--tolerance', type=float, default=TuningSettings().tolerance)
    parser.add_argument('--skip-tune', action='store_true')
    args = parser.parse_args()
    content = build_dataset(INTEL / 'intel.gfs.log', INTEL / 'intel.relations',
                            INTEL / 'intel.orig.bag',
                            BuildSettings(false_loop_closures=args.false_loops))
    graph = content.graph
    print(f'Intel graph: {graph.vertex_count} vertices, {graph.edge_count} edges '
          f'({int(graph.is_loop_closure.sum())} loop closures, {args.false_loops} false)')
    per_iteration = min(compare_solvers(graph, phi, args.repeat) for phi in (1.0, None, 0.1))
    if args.skip_tune:
        return
    settings = TuningSettings(grid_steps=args.grid_steps, tolerance=args.tolerance)
    model = sensor_model(content.laser)
    profile = InconsistencyProfile(graph, content.scan_ranges(), model, content.laser_offset,
                                   settings)
    start = time.perf_counter()
    result = tune_dcs(graph, content.scan_ranges(), model, content.laser_offset, settings,
                      profile=profile)
    elapsed = time.perf_counter() - start
    evaluations = len(result.profile_phi)
    solver_iterations = sum(profile.evaluate(phi).optimization.iterations
                            for phi in result.profile_phi)
    print(f'full tune: {elapsed:.1f} s for {evaluations} evaluations '
          f'({elapsed / evaluations:.2f} s each, {solver_iterations} solver iterations in all); '
          f'Phi* = {result.phi:.4g}, M(Phi*) = {result.average_inconsistency:.4f}, '
          f'{"consistent" if result.consistent else "inconsistent"} '
          f'({int(result.consistency.inconsistent.sum())} scans flagged)')
    print(f'  at {per_iteration * 1e3:.1f} ms per solver iteration the solves are about '
          f'{100 * per_iteration * solver_iterations / elapsed:.0f}% of the tune; the rest is '
          f'the pair measures of each map and the final test')


if __name__ == '__main__':
    main()
