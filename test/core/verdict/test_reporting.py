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
