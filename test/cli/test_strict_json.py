"""Reports are strict JSON: a value that does not exist (the correction of a region beyond
local registration) is null, never NaN, which jq, JavaScript and Go reject."""
import math

import numpy as np
import pytest

from map_consistency_ros.cli.main import main
from map_consistency_ros.core.verdict import reporting, to_json
from map_consistency_ros.evaluation.suite import displace
from map_consistency_ros.io import carmen

SCANS = 290  # the first 290 Intel scans: a loop through the building


def test_non_finite_numbers_become_null(strict_json):
    report = {'python': math.nan, 'numpy': np.float64(np.inf), 'float32': np.float32(-np.inf),
              'array': np.array([1.5, np.nan]), 'nested': [{'x': np.degrees(np.nan)}],
              'kept': np.int64(3)}
    assert strict_json(to_json(report)) == {'python': None, 'numpy': None, 'float32': None,
                                            'array': [1.5, None], 'nested': [{'x': None}],
                                            'kept': 3}


def test_a_non_finite_number_that_slips_past_plain_is_refused(monkeypatch):
    monkeypatch.setattr(reporting, 'plain', lambda value: value)  # a conversion gone wrong
    with pytest.raises(ValueError, match='not JSON compliant'):
        reporting.to_json({'x': math.nan})


def test_a_region_beyond_local_registration_is_reported_with_null_corrections(
        shared_data, tmp_path, strict_json, flaser_log):
    # The second half of the loop shifted by 2 m: further than registration reaches.
    log = carmen.read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    poses = displace(log.laser_poses[:SCANS], 150, SCANS, 0.0, np.array([2.0, 0.0]))
    path = tmp_path / 'shifted.log'
    flaser_log(path, log.ranges[:SCANS], poses, period=0.1, decimals=3)
    out = tmp_path / 'report.json'
    assert main(['check', str(path), '--max-range', '8', '--quiet', '--report', str(out)]) == 1
    text = out.read_text()
    assert 'NaN' not in text and 'Infinity' not in text
    report = strict_json(text)
    beyond = [region for region in report['misalignments'] if not region['registered']]
    assert beyond, report['summary_line']
    for region in beyond:
        for key in ('dx_m', 'dy_m', 'dtheta_deg', 'std_dx_m', 'std_dy_m', 'std_dtheta_deg',
                    'displacement_m'):
            assert region[key] is None
        assert region['scans'] and region['pairs'] > 0
