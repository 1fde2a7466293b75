"""The map status: each level for the situation that calls for it, and the key-values."""
from __future__ import annotations

import dataclasses
import pathlib

import pytest
from diagnostic_msgs.msg import DiagnosticStatus

from map_consistency_ros.core.live import ScanCounts
from map_consistency_ros.ros.diagnostics import SCAN_KEYS, MonitorHealth, map_status, status_level

REPO = pathlib.Path(__file__).resolve().parents[2]
SCANS = ScanCounts(received=130, keyframes=120, folded=7, waiting=3)
HEALTHY = MonitorHealth(scans=SCANS, buffered_scans=3, overlapping_pairs=900, tested_pairs=700,
                        failed_pairs=4, inconsistent_scans=0, unmatched_poses=1, consistent=True,
                        update_latency=0.0042, phi=None, input_problems=0, recent_problem='',
                        seconds_since_input=0.3, stale_timeout=5.0,
                        verdict='CONSISTENT: no misalignment above 0.10 m; 2 changed places '
                                '(people, moved objects)', changed_places=2)
BROKEN = {'consistent': False, 'misaligned_regions': 1, 'misaligned_scans': 7,
          'verdict': 'INCONSISTENT: 1 misaligned region (largest 0.31 m, 1.5 deg); 2 changed '
                     'places (people, moved objects)'}

# one keyframe, the rest folded: never OK, never ERROR (nothing was found wrong either)
NOTHING = {'consistent': False, 'nothing_to_judge': True,
           'verdict': 'NOTHING TO JUDGE: only 1 scan has the 2 tested pairs the test needs to '
                      'flag a scan (1 tested pairs in all; a verdict needs 6 such scans)'}


@pytest.mark.parametrize('changes, level, words', [
    ({}, DiagnosticStatus.OK, 'map CONSISTENT: no misalignment above 0.10 m; 2 changed places '
                              '(people, moved objects) (120 scans)'),
    ({'recent_problem': 'scan: empty'}, DiagnosticStatus.WARN, 'bad input: scan: empty'),
    ({'consistent': None, 'scans': ScanCounts()}, DiagnosticStatus.WARN, 'no keyframe yet'),
    (BROKEN, DiagnosticStatus.ERROR, 'map INCONSISTENT: 1 misaligned region (largest 0.31 m'),
    ({**BROKEN, 'seconds_since_input': 9.0}, DiagnosticStatus.STALE,
     'no input for 9.0 s'),
    ({'seconds_since_input': None, 'consistent': None}, DiagnosticStatus.STALE,
     'no scan or trajectory received yet'),
    ({'scans': dataclasses.replace(SCANS, received=142, lost_in_queue=9, pushed_out=3)},
     DiagnosticStatus.WARN, "objects) (120 scans); 12 scans lost (9 in the node's full queue, "
                            '3 pushed out of its full buffer before a pose came)'),
    ({'middleware_lost': 4}, DiagnosticStatus.WARN, '4 scans lost by the middleware'),
    ({'poses_without_scan': 3}, DiagnosticStatus.WARN,
     '3 keyframe poses name scans never received'),
    ({**BROKEN, 'scans': dataclasses.replace(SCANS, received=132, unplaced=2)},
     DiagnosticStatus.ERROR, 'objects); 2 scans lost (2 without a pose around them)'),
    # passed over, rejected, earlier sessions: no loss (bad input warns on its own)
    ({'scans': dataclasses.replace(SCANS, received=160, passed_over=10, rejected=10,
                                   earlier_sessions=10)}, DiagnosticStatus.OK, '(120 scans)'),
    ({'gap_scans': 40}, DiagnosticStatus.OK, 'map CONSISTENT: '),  # an estimate
    ({'starting': True, 'seconds_since_input': None, 'consistent': None}, DiagnosticStatus.WARN,
     'starting: compiling the kernels or loading them from the cache (nothing received yet)'),
    ({'starting': True, 'queued_scans': 40, 'consistent': None}, DiagnosticStatus.WARN,
     'starting: compiling the kernels or loading them from the cache (40 scans queued)'),
    ({'starting': True, 'start_failure': 'OSError: cache unreadable', 'queued_scans': 7,
      'consistent': None}, DiagnosticStatus.ERROR,
     'not monitoring: loading the compiled kernels failed (OSError: cache unreadable); '
     '7 scans queued unprocessed'),
    ({'consistent': None}, DiagnosticStatus.WARN, 'no verdict yet (120 scans)'),
    ({'explanation_failure': 'explanation failed: MemoryError: '},
     DiagnosticStatus.WARN, 'objects) (120 scans); explanation failed: MemoryError'),
    ({'consistent': None, 'explanation_failure': 'explanation failed: MemoryError: '},
     DiagnosticStatus.WARN, 'no verdict yet (120 scans); explanation failed: MemoryError'),
    ({**BROKEN, 'explanation_failure': 'explanation failed: ValueError: x'},
     DiagnosticStatus.ERROR, 'objects); explanation failed: ValueError: x'),
    (NOTHING, DiagnosticStatus.WARN, 'map NOTHING TO JUDGE: only 1 scan has'),
])
def test_levels(changes, level, words):
    got_level, message = status_level(dataclasses.replace(HEALTHY, **changes))
    assert got_level == level
    assert words in message


def test_key_values_carry_the_figures():
    status = map_status(dataclasses.replace(HEALTHY, phi=0.125, input_problems=2), '/mc')
    values = {kv.key: kv.value for kv in status.values}
    assert status.hardware_id == '/mc' and status.level == DiagnosticStatus.OK
    assert values['keyframes'] == '120' and values['overlapping pairs'] == '900'
    assert values['failed pairs'] == '4' and values['inconsistent scans'] == '0'
    assert values['misaligned regions'] == '0' and values['changed places'] == '2'
    assert values['update latency (ms)'] == '4.2'
    assert values['ready'] == 'yes'
    assert values['second stage failure'] == 'none'
    assert {kv.key: kv.value for kv in map_status(
        dataclasses.replace(HEALTHY, starting=True), '/mc').values}['ready'] == 'no'
    assert {kv.key: kv.value for kv in map_status(
        dataclasses.replace(HEALTHY, starting=True, start_failure='boom'),
        '/mc').values}['ready'] == 'failed'
    assert values['phi'] == '0.125000'
    assert values['input problems'] == '2' and values['last input problem'] == 'none'
    unknown = {kv.key: kv.value for kv in map_status(
        dataclasses.replace(HEALTHY, update_latency=None), '/mc').values}
    assert unknown['update latency (ms)'] == 'n/a' and unknown['phi'] == 'n/a'
    reset = {kv.key: kv.value for kv in map_status(dataclasses.replace(
        HEALTHY, resets=1, last_reset='~/reset service', queued_scans=4), '/mc').values}
    assert reset['resets'] == '1' and reset['last reset'] == '~/reset service'
    assert reset['queued scans'] == '4' and reset['scans pushed out of the buffer'] == '0'
    assert [values[key] for key in SCAN_KEYS.values()] == ['130', '120', '7', '3'] + ['0'] * 6


def test_every_scan_count_has_a_key_and_the_docs_define_every_key():
    assert list(SCAN_KEYS) == [field.name for field in dataclasses.fields(ScanCounts)]
    docs = (REPO / 'docs' / 'node.md').read_text()
    keys = [kv.key for kv in map_status(HEALTHY, '/mc').values]
    assert len(set(keys)) == len(keys)
    assert [key for key in keys if f'`{key}`' not in docs] == []
