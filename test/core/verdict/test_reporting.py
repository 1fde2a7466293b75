"""Report text: joining the JSON text of two report parts."""
import json

import numpy as np
import pytest

from map_consistency_ros.core.verdict import joined_json, to_json


def test_joined_parts_are_the_text_of_the_merged_report():
    verdict = {'verdict': 'inconsistent', 'misaligned_scans': np.array([1.5, 2.25]),
               'misalignments': [{'scans': (1, 2), 'dx_m': np.float64(0.1)}],
               'local_distortion_m': float('nan'), 'text': 'a "quoted", {braced} value'}
    figures = {'updates': 3, 'timing': {'monitor_s': 0.002}, 'phi': None}
    text = joined_json(to_json(verdict), to_json(figures))
    assert text == to_json({**verdict, **figures})
    assert list(json.loads(text)) == list(verdict) + list(figures)
    assert joined_json('{}', to_json(figures)) == to_json(figures)
    assert joined_json(to_json(verdict), '{}') == to_json(verdict)
    assert joined_json('{}', '{}') == '{}'


@pytest.mark.parametrize('first, second', [('[1]', '{}'), ('{}', '"a"'), ('{"a": 1', '{}')])
def test_only_objects_are_joined(first, second):
    with pytest.raises(ValueError, match='two JSON objects'):
        joined_json(first, second)


def _region(correction, centroid, registered=True):
    from map_consistency_ros.core.verdict import Misalignment
    return Misalignment(scans=np.array([5, 6, 7]), reference_scans=np.array([0, 1, 2]),
                        correction=np.array(correction, dtype=float),
                        correction_std=np.zeros(3), displacement=0.3, pairs=10,
                        registered=registered, centroid=np.array(centroid, dtype=float))


def test_a_region_states_its_correction_where_it_is():
    # turned 2 degrees about the world origin, 40 m away: the world dx, dy are metres, the
    # region itself moves by the turn's arc there
    turn = np.radians(2.0)
    region = _region([0.0, 0.0, turn], [40.0, 0.0])
    np.testing.assert_allclose(region.shift_at_centroid,
                               [40.0 * (np.cos(turn) - 1.0), 40.0 * np.sin(turn)])
    moved = _region([0.3, -0.1, 0.0], [40.0, 0.0])
    np.testing.assert_allclose(moved.shift_at_centroid, [0.3, -0.1])
    assert np.all(np.isnan(_region([np.nan] * 3, [1.0, 2.0], False).shift_at_centroid))


def test_regions_that_move_alike_are_grouped():
    from map_consistency_ros.core.verdict import regions_alike
    shift = [0.3, 0.0, 0.0]
    regions = (_region(shift, [0.0, 0.0]), _region([0.0, 0.0, 0.02], [20.0, 0.0]),
               _region([0.32, 0.01, 0.0], [30.0, 5.0]), _region([np.nan] * 3, [1.0, 1.0], False))
    # the turned one moves its own centroid 0.4 m up, 0.4 m from where the shift puts it
    assert regions_alike(regions, 0.1) == [[0, 2]]
    assert regions_alike(regions, 0.01) == []
