"""`map-consistency evaluate` end to end on a small real suite, and its bad-input paths."""

import numpy as np
import pytest

from map_consistency_ros.cli.evaluate import false_alarm_lines
from map_consistency_ros.cli.main import main
from map_consistency_ros.core.consistency import ConsistencyParameters, check_consistency
from map_consistency_ros.evaluation.runner import map_scans
from map_consistency_ros.evaluation.suite import SuiteParameters, build_suite

SMALL = ['evaluate', '--datasets', 'orebro', '--part-size', '60', '--alphas', '0.01', '1e-9',
         '--binomial-alphas', '0.01', '--local-alphas', '0.05',
         '--flag-windows', '0', '4', '--quantiles', '0', '0.05', '--two-stage-alphas', '0.01',
         '--tolerances', '0.05', '0.1', '--seams', '1', '--workers', '1', '--quiet']


def test_evaluate_writes_the_write_up(strict_json, shared_data, tmp_path, capsys):
    doc = tmp_path / 'docs' / 'evaluation.md'
    assert main([*SMALL, '--data', str(shared_data), '--doc', str(doc)]) == 0
    printed = capsys.readouterr().out
    assert 'our frontier dominates the baseline\'s:' in printed
    assert '| orebro | 237 |' in printed
    text = doc.read_text()
    for heading in ('## Result', '## Suite', '## Consistent maps the test flags',
                    '## Inconsistent maps the test misses', '## Pareto frontiers', '## Runtime',
                    '## Whole logs at default settings', '| two-stage verdict (defaults) |'):
        assert heading in text
    assert '](figures/evaluation_pareto.png)' in text
    assert (tmp_path / 'docs' / 'figures' / 'evaluation_pareto.png').stat().st_size > 10000
    results = strict_json((tmp_path / 'docs' / 'figures' / 'evaluation.json').read_text())
    assert [row[:4] for row in results['ours']['rows']] == [
        [0.01, 0.01, 0.05, 0], [0.01, 0.01, 0.05, 4], [1e-9, 0.01, 0.05, 0], [1e-9, 0.01, 0.05, 4]]
    assert {row[0] for row in results['baseline']['rows']} == {0.0, 0.05}
    assert len(results['maps']) == 20
    assert results['runtimes'][0]['scan_count'] == 237
    assert [row[:2] for row in results['two_stage']['rows']] == [[0.01, 0.05], [0.01, 0.1]]
    # orebro whole, and one copy per displacement size (no graph is built for it)
    whole = results['whole_logs']
    assert [item['name'] for item in whole][:2] == ['orebro/corrected', 'orebro/rotation 1 deg #0']
    assert len(whole) == 6 and whole[0]['displacement'] < 1e-9
    assert all(item['displacement'] > 0.0 for item in whole[1:])


@pytest.mark.parametrize('extra, message', [
    (['--alphas', '1.5'], 'alpha: 1.5 is outside [1e-300, 0.5]'),
    (['--quantiles', '2'], 'quantile'),
    (['--workers', '0'], '--workers'),
    (['--flag-windows', '-1'], 'flag_window: -1 is outside [0, 1000]'),
    (['--part-size', '3'], 'part_size'),
    (['--data', '/nonexistent/folder'], 'no such file'),
])
def test_bad_input_exits_2_with_one_line(shared_data, tmp_path, capsys, extra, message):
    argv = [*SMALL, '--data', str(shared_data), '--doc', str(tmp_path / 'e.md'), *extra]
    assert main(argv) == 2
    error = capsys.readouterr().err
    assert message in error
    assert error.count('\n') == 1
    assert not (tmp_path / 'e.md').exists()


def test_false_alarms_are_listed_with_their_worst_pair(shared_data, tmp_path):
    maps = build_suite(shared_data, SuiteParameters(part_size=60), ['orebro'])[:5]
    strict = ConsistencyParameters(alpha=0.2, binomial_alpha=0.2, failure_probability=0.001)
    flagged = np.array([True] * len(maps))
    figure = tmp_path / 'figures' / 'false_alarm.png'
    lines = false_alarm_lines(maps, flagged, strict, None, figure)
    scans = map_scans(maps[0], None)
    result = check_consistency(scans, strict)
    assert not result.consistent  # so strict a setting flags the real corrected part
    worst = np.nanargmax(np.where(result.failed, result.statistic, -np.inf))
    i, j = result.pairs[worst]
    assert lines[2].startswith(f'| {maps[0].name} | {int(result.inconsistent.sum())} | '
                               f'{result.failed_pair_count} | {i}-{j} |')
    assert len(lines) == 5  # header, rule, the one corrected map, blank, figure
    assert figure.stat().st_size > 10000
