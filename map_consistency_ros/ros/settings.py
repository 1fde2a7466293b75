"""The node's own settings and the groups of parameters it declares (no rclpy import here).

Every node parameter is a field of one of the settings dataclasses in NODE_GROUPS; the node
declares them, replay --params-file reads the same file, and config/map_consistency.yaml is
their defaults: regenerate it with

    python -m map_consistency_ros.ros.settings > config/map_consistency.yaml

and the table of docs/node.md with `--markdown`.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass

from map_consistency_ros.core.backend import TuningSettings
from map_consistency_ros.core.consistency import ConsistencyParameters
from map_consistency_ros.core.live import FeedSettings, MonitorSettings
from map_consistency_ros.core.parameters import markdown_table, parameter, specs, yaml_document
from map_consistency_ros.core.verdict import ExplanationSettings

RELIABILITIES = ('best_effort', 'reliable')
EXECUTORS = ('events', 'multi_threaded')


@dataclass(frozen=True)
class NodeSettings:
    """Topics, outputs and timing of the node (ROS concerns, not the monitor's)."""

    frame_id: str = parameter('', 'frame of the markers; empty: the trajectory\'s frame, '
                                  'else "map"')
    scan_queue_depth: int = parameter(
        1000, 'depth of the scan subscription: scans the middleware holds while the node is '
        'busy (a loop closure)', '', (1, 100_000))
    scan_reliability: str = parameter(
        'best_effort', 'reliability of the scan subscription; best_effort matches every '
        'publisher (sensor-data QoS), reliable makes reliable publishers resend',
        choices=RELIABILITIES)
    stale_timeout: float = parameter(5.0, 'diagnostics turn STALE after this long without '
                                          'input, on the node\'s clock', 's', (0.1, 3600.0))
    diagnostics_period: float = parameter(1.0, 'period of /diagnostics', 's', (0.05, 60.0))
    warning_period: float = parameter(5.0, 'a bad-input warning per topic at most this often',
                                      's', (0.0, 3600.0))
    max_marker_pairs: int = parameter(
        50, 'failed pairs whose points are drawn, largest statistic first (each point is a '
        'Python object to build and send)', '', (0, 100_000))
    service_timeout: float = parameter(60.0, 'longest wait of a service for the worker', 's',
                                       (0.1, 3600.0))
    explanation_period: float = parameter(
        1.0, 'the verdict\'s second stage (misalignment or change) runs on a thread of its '
        'own, on the newest map, at most this often (at once on ~/check); first-stage updates '
        'never wait for it', 's',
        (0.0, 3600.0))
    update_threads: int = parameter(
        1, "threads of the first stage's compiled kernels; the SLAM stack, the middleware and "
        'the second stage share the cores, and a kernel split across busy cores waits for its '
        'slowest part; 0: every core',
        '', (0, 1024))
    executor: str = parameter(
        'events', "how the node takes its messages: 'events' (rclpy's C++ events executor, "
        "a fraction of the Python work per message) or 'multi_threaded' (rclpy's Python "
        'executor); services are answered on threads of their own either way',
        choices=EXECUTORS)


# (title, settings class) in the order of the parameter file
NODE_GROUPS = (('input and keyframes', FeedSettings), ('monitor', MonitorSettings),
               ('statistical test', ConsistencyParameters),
               ('verdict: misalignment or change', ExplanationSettings),
               ('DCS retune', TuningSettings),
               ('node', NodeSettings))
PARAMETER_NAMES = tuple(spec.name for _, group in NODE_GROUPS for spec in specs(group))

_HEADER = '''Parameters of the map_consistency node at their defaults (docs/node.md). Generated from
the settings dataclasses: python -m map_consistency_ros.ros.settings > config/map_consistency.yaml
Load with  map_consistency_node --ros-args --params-file config/map_consistency.yaml
or         map-consistency replay BAG --params-file config/map_consistency.yaml
"/**" applies them whatever the node is renamed to. Integers are accepted for floats.'''


def parameter_file() -> str:
    """The text of config/map_consistency.yaml."""
    return yaml_document(NODE_GROUPS, _HEADER)


def parameter_table() -> str:
    """The parameter table of docs/node.md."""
    return markdown_table(NODE_GROUPS)


if __name__ == '__main__':
    sys.stdout.write(parameter_table() if sys.argv[1:] == ['--markdown'] else parameter_file())
