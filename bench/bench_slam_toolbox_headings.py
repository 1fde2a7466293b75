"""Heading errors of slam_toolbox's two pose sources on the Intel lab data (docs/slam_bridges.md).

    PYTHONPATH=. python bench/bench_slam_toolbox_headings.py [--data ../shared/data]

A back-end is emulated on the Intel corrected log the way slam_toolbox's mapper works (as in
test/core/test_graph_bridge.py): each accepted scan is chained onto the previous one by the
true step plus scan-matching-like noise, gets the next node id and one `pose` message / node
event with its pose then; every 50 scans the graph (sequential edges and the real loop closures
of Kuemmerle et al.'s relations) is optimized, moving many nodes at once. Sources compared:

- slam_toolbox_graph (core/pose_graph_bridge.py): node events, and a PoseGraph with every node's
  pose after each optimization (slam_toolbox publishes one after each loop closure);
- slam_toolbox (core/graph_bridge.py, markers): `pose` messages and a position-only marker
  snapshot every 10 scans, headings recovered from the neighbourhoods' rigid motion;
- first-seen: each node's `pose` message heading, never corrected.

Errors |heading - truth| in degrees at every marker snapshot, over every node in it, against two
truths: the corrected log's heading (the map's truth) and the emulated back-end's own estimate
(what the source should reproduce). A last case puts the log's own poses in the back-end: the
dead-reckoned chain (1 cm / 0.11 degree steps) is corrected in one loop closure onto the
corrected log, so the back-end is the truth and only the source errs. Prints a table; `--json`
writes the numbers.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from map_consistency_ros.core.geometry import se2
from map_consistency_ros.core.backend import PoseGraph, optimize
from map_consistency_ros.core.live import PoseGraphBridge, SlamToolboxBridge
from map_consistency_ros.io.datasets import BuildSettings, build_dataset

OPTIMIZE_EVERY = 50
SNAPSHOT_EVERY = 10
NOISE = {'1 cm / 0.11 deg': (0.01, 0.002), '2 cm / 0.29 deg': (0.02, 0.005)}


def emulate(truth, loops, sigma_xy, sigma_theta, seed=1):
    """[(first_seen (N, 3), [(scan count, back-end estimate (V, 3), optimized)], ...)]: every
    node's first pose, and the back-end's estimate after each scan that ends a snapshot or an
    optimization."""
    rng = np.random.default_rng(seed)
    count = len(truth)
    noise = np.column_stack([rng.normal(0.0, sigma_xy, (count - 1, 2)),
                             rng.normal(0.0, sigma_theta, count - 1)])
    steps = se2.relative(truth[:-1], truth[1:]) + noise
    loop = loops.is_loop_closure
    step_information = np.diag([sigma_xy ** -2, sigma_xy ** -2, sigma_theta ** -2])
    edge_from = np.concatenate([np.arange(count - 1), loops.edge_from[loop]])
    edge_to = np.concatenate([np.arange(1, count), loops.edge_to[loop]])
    measurements = np.concatenate([steps, loops.measurements[loop]])
    information = np.concatenate([np.tile(step_information, (count - 1, 1, 1)),
                                  loops.information[loop]])
    estimate = truth[:1].copy()
    first_seen = [estimate[0].copy()]
    moments = []
    for vertex in range(1, count + 1):
        optimized = False
        if vertex > 1:
            estimate = np.vstack([estimate, se2.compose(estimate[-1], steps[vertex - 2])])
            if vertex % OPTIMIZE_EVERY == 0:
                keep = (edge_from < vertex) & (edge_to < vertex)
                fixed = np.zeros(vertex, dtype=bool)
                fixed[0] = True
                estimate = np.asarray(optimize(PoseGraph(
                    poses=estimate, edge_from=edge_from[keep], edge_to=edge_to[keep],
                    measurements=measurements[keep], information=information[keep],
                    fixed=fixed), None).poses)
                optimized = True
            first_seen.append(estimate[-1].copy())
        if optimized or vertex % SNAPSHOT_EVERY == 0 or vertex == count:
            moments.append((vertex, estimate.copy(), optimized))
    return np.array(first_seen), moments


def heading_errors(stamps, truth, first_seen, moments):
    """Per source: (errors against the log, errors against the back-end), degrees."""
    markers, graph = SlamToolboxBridge(), PoseGraphBridge()
    sent = 0
    errors = {name: ([], []) for name in ('slam_toolbox_graph', 'slam_toolbox (markers)',
                                          'first-seen')}
    graph_stamp = 0.0
    for vertex, estimate, optimized in moments:
        for node in range(sent, vertex):
            markers.add_pose(stamps[node], first_seen[node])
            graph.add_node(node, stamps[node], first_seen[node])
        sent = vertex
        if optimized:  # a loop closure: its event, then the graph slam_toolbox publishes after
            graph_stamp += 1.0
            graph.loop_closure(graph_stamp)
            graph.update_graph(np.arange(vertex), estimate, graph_stamp + 0.5)
        if not (vertex % SNAPSHOT_EVERY == 0 or vertex == len(stamps)):
            continue
        markers.update_vertices(np.arange(vertex), estimate[:, :2])
        for name, poses in (('slam_toolbox_graph', graph.keyframes()[1]),
                            ('slam_toolbox (markers)', markers.keyframes()[1]),
                            ('first-seen', first_seen[:vertex])):
            against_log, against_backend = errors[name]
            against_log.append(_degrees(poses, truth[:vertex]))
            against_backend.append(_degrees(poses, estimate))
    return {name: (np.concatenate(log), np.concatenate(backend))
            for name, (log, backend) in errors.items()}


def _degrees(poses, truth):
    return np.degrees(np.abs(se2.wrap_angle(poses[:, 2] - truth[:, 2])))


def _stats(values):
    return {'median': float(np.median(values)), 'p95': float(np.percentile(values, 95)),
            'max': float(values.max())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--data', type=Path,
                        default=Path(__file__).resolve().parents[2] / 'shared' / 'data')
    parser.add_argument('--json', type=Path, help='write the numbers here')
    args = parser.parse_args()
    intel = args.data / 'intel'
    built = build_dataset(intel / 'intel.gfs.log', intel / 'intel.relations',
                          intel / 'intel.orig.bag', BuildSettings())
    truth = np.asarray(built.laser.robot_poses)
    stamps = np.asarray(built.laser.timestamps)
    results = {}
    print(f'Intel, {len(truth)} scans: |heading - truth| in degrees, median / p95 / max over '
          'every node of every marker snapshot')
    print('| step noise | source | against the corrected log | against the back-end |')
    print('|---|---|---|---|')
    for label, (sigma_xy, sigma_theta) in NOISE.items():
        first_seen, moments = emulate(truth, built.graph, sigma_xy, sigma_theta)
        for name, (log, backend) in heading_errors(stamps, truth, first_seen, moments).items():
            results[f'{label}: {name}'] = {'log': _stats(log), 'backend': _stats(backend)}
            cells = [' / '.join(f'{value:.2f}' for value in _stats(errors).values())
                     for errors in (log, backend)]
            print(f'| {label} | {name} | {cells[0]} | {cells[1]} |')
    rng = np.random.default_rng(1)
    sigma_xy, sigma_theta = NOISE['1 cm / 0.11 deg']
    noise = np.column_stack([rng.normal(0.0, sigma_xy, (len(truth) - 1, 2)),
                             rng.normal(0.0, sigma_theta, len(truth) - 1)])
    chained = se2.chain(truth[0], se2.relative(truth[:-1], truth[1:]) + noise)
    label = 'one correction onto the log, 1 cm'
    for name, (log, backend) in heading_errors(stamps, truth, chained,
                                               [(len(truth), truth, True)]).items():
        results[f'{label}: {name}'] = {'log': _stats(log), 'backend': _stats(backend)}
        cell = ' / '.join(f'{value:.2f}' for value in _stats(log).values())
        print(f'| {label} | {name} | {cell} | (the same) |')
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == '__main__':
    main()
