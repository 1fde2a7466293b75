"""The one configuration: every settings group, built once and passed down.

`Configuration` holds one settings dataclass per group (its fields, in the order of the
parameter file). The node builds it from its ROS parameters, `replay` from a parameter file
and its options, `check` and `tune` from their options, each with `Configuration.from_values`;
the pieces of the program take the groups they need (`config.feed`, `config.tuning`, ...).
Every value is checked against its declaration (core/parameters.py) when its group is made.

`GROUPS` lists the groups with their titles: the node declares its parameters from it, and
config/map_consistency.yaml and the table of docs/node.md are generated from it
(ros/settings.py). `NodeSettings` is defined here, beside the others, although only the node
(ros/node.py) reads it: it is plain data (queue depths, periods, QoS choices), and a parameter
file and replay check its values as they check every other group's.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, fields
from typing import Any, NamedTuple

from map_consistency_ros.core.backend import TuningSettings
from map_consistency_ros.core.consistency import ConsistencyParameters
from map_consistency_ros.core.live import FeedSettings, MonitorSettings
from map_consistency_ros.core.parameters import (Choice, ParameterSpec, Settings, parameter,
                                                 settings_from_values, specs, unknown_names)
from map_consistency_ros.core.verdict import ExplanationSettings


class Reliability(Choice):
    """Reliability of the node's scan subscription (NodeSettings.scan_reliability)."""

    BEST_EFFORT = 'best_effort'
    RELIABLE = 'reliable'


class ExecutorKind(Choice):
    """How the node takes its messages (NodeSettings.executor)."""

    EVENTS = 'events'
    MULTI_THREADED = 'multi_threaded'


@dataclass(frozen=True)
class NodeSettings(Settings):
    """The map_consistency node's own settings (ros/node.py is their only reader): its scan
    subscription, periods, timeouts, outputs, threads and executor; ROS concerns, not the
    monitor's."""

    frame_id: str = parameter('', 'frame of the markers; empty: the trajectory\'s frame, '
                                  'else "map"')
    scan_queue_depth: int = parameter(
        1000, 'depth of the scan subscription: scans the middleware holds while the node is '
        'busy (a loop closure)', '', (1, 100_000))
    scan_reliability: Reliability = parameter(
        Reliability.BEST_EFFORT, 'reliability of the scan subscription; best_effort matches '
        'every publisher (sensor-data QoS), reliable makes reliable publishers resend',
        choices=Reliability)
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
    executor: ExecutorKind = parameter(
        ExecutorKind.EVENTS, "how the node takes its messages: 'events' (rclpy's C++ events "
        "executor, a fraction of the Python work per message) or 'multi_threaded' (rclpy's Python "
        'executor); services are answered on threads of their own either way',
        choices=ExecutorKind)


def _group(title: str, settings_class: type) -> Any:
    # a group of Configuration: its title heads its part of the parameter file
    return field(default_factory=settings_class, metadata={_TITLE: title})


_TITLE = 'title'


@dataclass(frozen=True)
class Configuration:
    """Every setting of the program, one checked settings dataclass per group.

    `Configuration()` is the defaults; `Configuration.from_values(values)` takes the
    parameters' values by name (a parameter file, options, ROS parameters). The DCS retune
    judges its maps with the statistical test's parameters, `consistency`: `tuning` holds the
    search's own parameters only.
    """

    feed: FeedSettings = _group('input and keyframes', FeedSettings)
    monitor: MonitorSettings = _group('monitor', MonitorSettings)
    consistency: ConsistencyParameters = _group('statistical test', ConsistencyParameters)
    explanation: ExplanationSettings = _group('verdict: misalignment or change',
                                              ExplanationSettings)
    tuning: TuningSettings = _group('DCS retune', TuningSettings)
    node: NodeSettings = _group('node', NodeSettings)

    @classmethod
    def from_values(cls, values: Mapping[str, Any],
                    groups: Iterable[str] | None = None) -> Configuration:
        """The configuration of the parameters' values.

        Parameters
        ----------
        values: parameter name -> value; names that are no parameter are ignored (warn
            about them with `unknown_parameters`), missing parameters take their defaults
        groups: the names of the groups that take their values from `values` (default:
            all); the others keep their defaults (a command whose options share a name with a
            parameter of a group it does not use, e.g. check's --max-range)

        Returns
        -------
        The configuration; ValueError names the first bad value ('alpha: 0.7 is outside
        [...]').
        """
        taking = {group.name for group in GROUPS} if groups is None else set(groups)
        unknown = taking - {group.name for group in GROUPS}
        if unknown:
            raise ValueError(f'no settings group {", ".join(sorted(unknown))}')
        made = {}
        for group in GROUPS:  # in order: the first bad value named is the file's first
            given = values if group.name in taking else {}
            if given:
                made[group.name] = settings_from_values(group.settings, given)
        return cls(**made)

    def values(self) -> dict[str, Any]:
        """Every parameter's value by name: what `from_values` takes back.

        Returns
        -------
        parameter name -> value, in the order of the parameter file (a Choice as its plain
        string).
        """
        return {spec.name: _plain(getattr(getattr(self, group.name), spec.name))
                for group in GROUPS for spec in specs(group.settings)}


def _plain(value: Any) -> Any:
    return value.value if isinstance(value, Choice) else value


class Group(NamedTuple):
    """A settings group of Configuration."""

    name: str  # the Configuration field
    title: str  # heads the group in the parameter file and the docs
    settings: type  # its settings dataclass


# in the order of the parameter file
GROUPS = tuple(Group(item.name, item.metadata[_TITLE], item.default_factory)
               for item in fields(Configuration))
PARAMETERS: tuple[ParameterSpec, ...] = tuple(spec for group in GROUPS
                                              for spec in specs(group.settings))
PARAMETER_NAMES = tuple(spec.name for spec in PARAMETERS)


def unknown_parameters(names: Iterable[str], foreign: Iterable[str] = ()) -> list[str]:
    """One warning per name that is no parameter, naming the closest valid one.

    Parameters
    ----------
    names: the names given (a parameter file's, the node's overrides)
    foreign: names that are valid there without being ours (rclpy's use_sim_time)

    Returns
    -------
    The warnings ("unknown parameter 'alhpa' ignored; did you mean alpha?"), sorted by name.
    """
    return unknown_names(names, PARAMETER_NAMES + tuple(foreign))
