"""Parameters on the settings dataclasses: types, ranges, names, the generated YAML."""
import math

import pytest
import yaml

from map_consistency_ros.core.backend import TuningSettings
from map_consistency_ros.core.consistency import ConsistencyParameters
from map_consistency_ros.core.live import FeedSettings, MonitorSettings
from map_consistency_ros.core.parameters import (closest_name, settings_from_values, specs,
                                                 unknown_names, yaml_document)

GROUPS = (('test', ConsistencyParameters), ('monitor', MonitorSettings),
          ('tuning', TuningSettings), ('feed', FeedSettings))


def test_every_field_that_is_a_parameter_is_documented():
    for _, group in GROUPS:
        for spec in specs(group):
            assert spec.description and spec.help.startswith(spec.description)
            assert spec.check(spec.default) == spec.default
    # nested settings are not parameters
    assert 'parameters' not in {spec.name for spec in specs(TuningSettings)}


def test_integers_stand_for_floats_and_nothing_else_passes():
    made = settings_from_values(MonitorSettings, {'cell_size': 8, 'max_buffered_scans': 10})
    assert made.cell_size == 8.0 and isinstance(made.cell_size, float)
    with pytest.raises(ValueError, match="alpha: expected a float, got a string '0.01'"):
        settings_from_values(ConsistencyParameters, {'alpha': '0.01'})
    with pytest.raises(ValueError, match='min_points: expected an integer, got a float 2.5'):
        settings_from_values(ConsistencyParameters, {'min_points': 2.5})
    with pytest.raises(ValueError, match='expected a float, got a bool'):
        settings_from_values(ConsistencyParameters, {'alpha': True})
    with pytest.raises(ValueError, match='must be finite'):
        settings_from_values(MonitorSettings, {'cell_size': math.inf})


def test_ranges_choices_and_lists():
    with pytest.raises(ValueError, match=r'alpha: 0.7 is outside \[1e-09, 0.5\]'):
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
