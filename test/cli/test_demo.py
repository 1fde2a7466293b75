"""`map-consistency demo`: the bundled bag replays and writes its outputs."""

from map_consistency_ros.cli.main import main


def test_demo_replays_the_bundled_bag(strict_json, tmp_path, capsys):
    code = main(['demo', '--output', str(tmp_path), '--quiet'])
    out = capsys.readouterr().out
    report = strict_json((tmp_path / 'report.json').read_text())
    assert code == (0 if report['verdict'] == 'consistent' else 1)
    # 290 keyframes, those within 0.4 m and 0.4 rad of the previous one folded into it
    viewpoints = report['summary']['scans']
    assert viewpoints + report['replay']['scan_counts']['folded'] == 290 and viewpoints > 250
    assert 'intel_demo.mcap' in out and f'scans                 {viewpoints}' in out
    for name in ('map.png', 'psi.png', 'pairs.csv'):
        assert (tmp_path / name).stat().st_size > 0


def test_demo_catches_its_wrong_loop_closure_named_by_laser_records(strict_json, tmp_path,
                                                                     capsys):
    assert main(['demo', '--output', str(tmp_path), '--quiet']) == 0  # both verdicts expected
    out = capsys.readouterr().out
    assert 'one wrong loop closure (scan 268 seen from scan 30 0.6 m and 4 deg off)' in out
    broken = strict_json((tmp_path / 'wrong_loop_closure' / 'report.json').read_text())
    assert broken['verdict'] == 'inconsistent' and broken['misalignments']
    assert 'the corrected map passes and the wrong loop closure is caught' in out
