"""Parameters on the settings dataclasses: types, ranges, names, the generated YAML; the one
configuration built from them."""
import json
import math
from dataclasses import fields, replace

import numpy as np
import pytest
import yaml

from map_consistency_ros.core.backend import TuningSettings
from map_consistency_ros.core import configuration
from map_consistency_ros.core.configuration import (PARAMETER_NAMES, Configuration, ExecutorKind,
                                                    NodeSettings, Reliability, unknown_parameters)
from map_consistency_ros.core.consistency import ConsistencyParameters
from map_consistency_ros.core.live import FeedSettings, MonitorSettings, PoseSource
from map_consistency_ros.core.verdict import PAIR_CLASSES, PairClass
from map_consistency_ros.core.parameters import (closest_name, settings_from_values, specs,
                                                 unknown_names, yaml_document)

GROUPS = (('test', ConsistencyParameters), ('monitor', MonitorSettings),
          ('tuning', TuningSettings), ('feed', FeedSettings))


def test_every_field_that_is_a_parameter_is_documented():
    for _, group in GROUPS:
        for spec in specs(group):
            assert spec.description and spec.help.startswith(spec.description)
            assert spec.check(spec.default) == spec.default
    # every field of every group is a parameter: no group holds another group's settings
    # (a second copy of its parameters)
    for group in configuration.GROUPS:
        assert [spec.name for spec in specs(group.settings)] == [
            item.name for item in fields(group.settings)]


def test_integers_stand_for_floats_and_nothing_else_passes():
    made = settings_from_values(MonitorSettings, {'move_tolerance': 1, 'max_buffered_scans': 10})
    assert made.move_tolerance == 1.0 and isinstance(made.move_tolerance, float)
    with pytest.raises(ValueError, match="alpha: expected a float, got a string '0.01'"):
        settings_from_values(ConsistencyParameters, {'alpha': '0.01'})
    with pytest.raises(ValueError, match='min_points: expected an integer, got a float 2.5'):
        settings_from_values(ConsistencyParameters, {'min_points': 2.5})
    with pytest.raises(ValueError, match='expected a float, got a bool'):
        settings_from_values(ConsistencyParameters, {'alpha': True})
    with pytest.raises(ValueError, match='must be finite'):
        settings_from_values(MonitorSettings, {'move_tolerance': math.inf})


def test_ranges_choices_and_lists():
    with pytest.raises(ValueError, match=r'alpha: 0.7 is outside \[1e-300, 0.5\]'):
        settings_from_values(ConsistencyParameters, {'alpha': 0.7})
    with pytest.raises(ValueError, match='pose_source: .tf. is not one of path, odometry'):
        settings_from_values(FeedSettings, {'pose_source': 'tf'})
    assert settings_from_values(MonitorSettings, {'laser_offset': [1, 0.5, 0]}).laser_offset == (
        1.0, 0.5, 0.0)
    with pytest.raises(ValueError, match='expected a list of 3 numbers'):
        settings_from_values(MonitorSettings, {'laser_offset': [1.0, 2.0]})


def test_unknown_names_name_the_closest_valid_one():
    known = [spec.name for spec in specs(ConsistencyParameters)]
    assert closest_name('trim', known) == 'trim_largest'
    assert unknown_names(['alhpa', 'alpha', 'zzz'], known) == [
        "unknown parameter 'alhpa' ignored; did you mean alpha?",
        "unknown parameter 'zzz' ignored"]


def test_yaml_document_reads_back_as_the_defaults():
    document = yaml.safe_load(yaml_document(GROUPS, 'header\n\nlines'))
    values = document['/**']['ros__parameters']
    for _, group in GROUPS:
        for spec in specs(group):
            default = list(spec.default) if isinstance(spec.default, tuple) else spec.default
            assert values[spec.name] == default and type(values[spec.name]) is type(default), \
                spec.name


def test_direct_construction_is_checked_against_the_declared_bounds():
    """The constructor and dataclasses.replace check as settings_from_values does."""
    with pytest.raises(ValueError, match=r'alpha: 0.7 is outside \[1e-300, 0.5\]'):
        ConsistencyParameters(alpha=0.7)
    with pytest.raises(ValueError, match=r'move_tolerance: 11.0 is outside \[0, 10\]'):
        replace(MonitorSettings(), move_tolerance=11.0)
    with pytest.raises(ValueError, match=r'keyframe_distance: -1.0 is outside'):
        FeedSettings(keyframe_distance=-1.0)
    with pytest.raises(ValueError, match=r'grid_steps: 2 is outside \[3, 10000\]'):
        TuningSettings(grid_steps=2)
    with pytest.raises(ValueError, match='expected an integer, got a float 2.5'):
        ConsistencyParameters(min_points=2.5)
    with pytest.raises(ValueError, match='stale_timeout: must be finite'):
        NodeSettings(stale_timeout=math.nan)
    # stored in the parameter's type: numpy scalars (a sweep over an array), ints for floats
    made = ConsistencyParameters(alpha=np.float64(0.02), viewpoint_spacing=0,
                                 min_points=np.int64(5))
    assert type(made.alpha) is float and made.alpha == 0.02
    assert type(made.viewpoint_spacing) is float and type(made.min_points) is int
    assert MonitorSettings(laser_offset=[1, 0, 0]).laser_offset == (1.0, 0.0, 0.0)
    # an invariant between fields stays a check of its own
    with pytest.raises(ValueError, match='phi_min < phi_max'):
        TuningSettings(phi_min=2.0, phi_max=1.0)


def test_choices_are_enums_that_read_as_their_strings():
    settings = FeedSettings(pose_source='odometry')
    assert settings.pose_source is PoseSource.ODOMETRY and settings.single_poses
    assert settings.pose_source == 'odometry' and f'{settings.pose_source}' == 'odometry'
    assert {'odometry': 1}[settings.pose_source] == 1
    assert json.dumps({PairClass.CHANGE: settings.pose_source}) == '{"change": "odometry"}'
    assert FeedSettings().pose_source is PoseSource.PATH
    with pytest.raises(ValueError, match='pose_source: .tf. is not one of path, odometry'):
        FeedSettings(pose_source='tf')
    # the parameter itself is a plain string: the parameter file, ROS and the options take it
    (spec,) = [spec for spec in specs(FeedSettings) if spec.name == 'pose_source']
    assert type(spec.default) is str and spec.default == 'path' and spec.kind is str
    assert spec.choices == tuple(member.value for member in PoseSource)
    assert NodeSettings(executor='multi_threaded').executor is ExecutorKind.MULTI_THREADED
    assert NodeSettings().scan_reliability is Reliability.BEST_EFFORT
    assert PAIR_CLASSES == (PairClass.MISALIGNED, PairClass.MINOR, PairClass.CHANGE,
                            PairClass.UNREGISTERED) == ('misaligned', 'minor', 'change',
                                                        'unregistered')


def test_configuration_from_values():
    config = Configuration.from_values({'alpha': 0.02, 'move_tolerance': 4, 'pose_source': 'pose',
                                        'executor': 'multi_threaded', 'grid_steps': 7,
                                        'not_a_parameter': object()})
    assert config.consistency.alpha == 0.02 and config.monitor.move_tolerance == 4.0
    assert config.feed.pose_source is PoseSource.POSE
    assert config.node.executor is ExecutorKind.MULTI_THREADED
    assert config.tuning.grid_steps == 7
    assert Configuration() == Configuration.from_values({})
    # the flat values go back in, in the order of the parameter file, choices as strings
    values = config.values()
    assert list(values) == list(PARAMETER_NAMES)
    assert type(values['pose_source']) is str and values['pose_source'] == 'pose'
    assert Configuration.from_values(values) == config
    with pytest.raises(ValueError, match=r'max_range: 0.0 is outside \[0.1, 1000\]'):
        Configuration.from_values({'max_range': 0.0})
    # only the groups named take values: another command's option of the same name is not one
    assert Configuration.from_values({'max_range': None, 'alpha': 0.02},
                                     ('consistency',)).consistency.alpha == 0.02
    with pytest.raises(ValueError, match='no settings group feeds'):
        Configuration.from_values({}, ('feeds',))


def test_configuration_groups_and_unknown_names():
    groups = configuration.GROUPS
    assert [group.name for group in groups] == ['feed', 'monitor', 'consistency', 'explanation',
                                                'tuning', 'node']
    assert [group.settings for group in groups][-1] is NodeSettings
    assert len(set(PARAMETER_NAMES)) == len(PARAMETER_NAMES)  # a name is one parameter
    assert unknown_parameters(['stale_timout', 'alpha', 'use_sim_time'],
                              foreign=('use_sim_time',)) == [
        "unknown parameter 'stale_timout' ignored; did you mean stale_timeout?"]
