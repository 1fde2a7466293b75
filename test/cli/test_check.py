"""`map-consistency check`: exit codes, outputs, and bad input without tracebacks."""
import csv
import subprocess
import sys

import numpy as np
import pytest

from map_consistency_ros.cli.main import main
from map_consistency_ros.core.geometry import viewpoint_rows


def test_consistent_room_exits_0_and_writes_outputs(strict_json, room_log, tmp_path, capsys):
    path, poses, _ = room_log()
    report, plot, pairs = tmp_path / 'r.json', tmp_path / 'map.png', tmp_path / 'pairs.csv'
    code = main(['check', str(path), '--quiet', '--report', str(report), '--plot', str(plot),
                 '--pairs-csv', str(pairs)])
    out = capsys.readouterr().out
    assert code == 0, out
    # 40 scans 0.26 m and 0.16 rad apart: about every second one is a viewpoint (0.4 m)
    assert 'CONSISTENT' in out and 'scans                 19' in out
    assert 'viewpoints            19 of 40 laser records' in out
    data = strict_json(report.read_text())
    assert data['verdict'] == 'consistent'
    assert data['scans']['id'] == viewpoint_rows(poses, 0.4, 0.4).tolist()
    assert data['laser_records'] == 40 and min(np.diff(data['scans']['id'])) == 2
    assert data['sensor_model']['angle_min'] == pytest.approx(-np.pi / 2)
    assert data['sensor_model']['angle_increment'] == pytest.approx(np.pi / 180)
    assert data['sensor_model']['max_range'] == 8.0 and data['sensor_model']['range_min'] == 0.0
    assert data['parameters']['alpha'] == 0.01
    assert plot.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    rows = list(csv.DictReader(pairs.open()))
    assert rows and set(rows[0]) == {'i', 'j', 'M_ij', 'n_ij', 'psi_ij', 'failed'}
    assert all(int(row['n_ij']) > 0 for row in rows)
    assert data['summary']['overlapping_pairs'] == len(rows)


def test_displaced_room_exits_1_and_names_scans(strict_json, displaced_room_log, tmp_path,
                                                capsys):
    # One and a half laps, the second half logged 0.4 m off: it revisits the first (the second
    # stage needs independent registrations of the displaced stretch against what it revisits).
    path = displaced_room_log(name='room.log')
    explain, report = tmp_path / 'pairs.png', tmp_path / 'r.json'
    # The room's lap is 10 m, shorter than the local window of 40 viewpoints 0.4 m apart:
    # every scan is a viewpoint here, as the keyframes of a log of a large building are.
    code = main(['check', str(path), '--quiet', '--explain', str(explain), '--report',
                 str(report), '--viewpoint-spacing', '0', '--viewpoint-turn', '0'])
    out = capsys.readouterr().out
    assert code == 1
    assert 'INCONSISTENT: 1 misaligned region (largest 0.' in out
    # numbered, and its correction stated where it is: a shift of the room's 0.4 m
    assert 'misaligned region #1  ' in out and ' scans between ' in out
    assert 'shifted 0.39 m and turned ' in out and ' at its centroid (x ' in out
    content = strict_json(report.read_text())
    assert content['distorted'] is False and 0.0 <= content['local_distortion_m'] < 0.1
    (region,) = content['misalignments']
    assert min(region['scans']) >= 30 and max(region['reference_scans']) < 30
    assert region['number'] == 1 and region['moves_alike_with'] == []
    assert region['shift_at_centroid_m'] == pytest.approx(0.4, abs=0.015)
    assert region['shift_at_centroid_dx_m'] == pytest.approx(-0.4, abs=0.015)
    # the explained classes and the failed pairs not explained add up to the failed pairs
    assert (sum(content['explained_pairs'].values()) + content['failed_pairs_not_explained']
            == content['summary']['failed_pairs'])
    # The correction moves the displaced half back.
    assert region['dx_m'] == pytest.approx(-0.4, abs=0.01)
    assert region['dy_m'] == pytest.approx(0.0, abs=0.01)
    assert region['displacement_m'] == pytest.approx(0.4, abs=0.01)
    assert explain.read_bytes()[:4] == b'\x89PNG'


def test_alpha_option_reaches_the_report(strict_json, room_log, tmp_path):
    path, _, _ = room_log()
    report = tmp_path / 'r.json'
    main(['check', str(path), '--quiet', '--alpha', '0.2', '--fov', '180', '--max-range', '6',
          '--report', str(report)])
    data = strict_json(report.read_text())
    assert data['parameters']['alpha'] == 0.2
    assert data['sensor_model']['max_range'] == 6.0


@pytest.mark.parametrize('content,message', [
    ('FLASER 3 1.0 2.0\n', 'bad.log:1: truncated FLASER record'),
    ('FLASER 3 1.0 x 3.0 0 0 0 0 0 0 1 h 1\n', "bad.log:1: non-numeric range 'x'"),
    ('', 'bad.log: no FLASER or ROBOTLASER1'),
])
def test_bad_logs_exit_2_with_one_line(tmp_path, capsys, content, message):
    path = tmp_path / 'bad.log'
    path.write_text(content)
    assert main(['check', str(path), '--quiet']) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1


def test_outputs_appear_all_or_none(room_log, tmp_path, capsys):
    path, _, _ = room_log()
    out = tmp_path / 'out'
    (out / 'map.png').mkdir(parents=True)  # the figure cannot be written: a folder is there
    assert main(['check', str(path), '--quiet', '--report', str(out / 'r.json'), '--plot',
                 str(out / 'map.png'), '--pairs-csv', str(out / 'new' / 'pairs.csv')]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert str(out / 'map.png') in line
    assert sorted(p.name for p in out.rglob('*')) == ['map.png']  # no report, no new folder


def test_missing_file_and_bad_option_exit_2(tmp_path, room_log, capsys):
    assert main(['check', str(tmp_path / 'absent.log')]) == 2
    assert 'absent.log: no such file' in capsys.readouterr().err
    path, _, _ = room_log()
    assert main(['check', str(path), '--alpha', '1.5']) == 2
    assert 'alpha: 1.5 is outside' in capsys.readouterr().err


def test_console_script_prints_no_traceback(tmp_path):
    path = tmp_path / 'bad.log'
    path.write_text('FLASER 3 1.0 2.0\n')
    done = subprocess.run([sys.executable, '-m', 'map_consistency_ros.cli.main', 'check',
                           str(path)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert 'Traceback' not in done.stderr and 'truncated FLASER' in done.stderr


def test_every_keeps_record_positions_in_outputs(strict_json, room_log, tmp_path):
    path, _, _ = room_log()
    report, pairs = tmp_path / 'r.json', tmp_path / 'pairs.csv'
    assert main(['check', str(path), '--quiet', '--every', '3', '--report', str(report),
                 '--pairs-csv', str(pairs)]) == 0
    data = strict_json(report.read_text())
    assert data['scans']['id'] == list(range(0, 40, 3)) and data['every'] == 3
    ids = {int(row[key]) for row in csv.DictReader(pairs.open()) for key in ('i', 'j')}
    assert ids and all(index % 3 == 0 for index in ids)
    assert main(['check', str(path), '--every', '0']) == 2


@pytest.mark.parametrize('option,value,message', [
    ('--misalignment-tolerance', '-1', 'misalignment_tolerance: -1.0 is outside [0, 10]'),
    ('--gross-fraction', '1.5', 'gross_fraction: 1.5 is outside [0.01, 0.99]'),
    ('--block', '0', 'block: 0 is outside [1, 1000]'),
])
def test_bad_verdict_options_exit_2_with_one_line(room_log, capsys, option, value, message):
    path, _, _ = room_log()
    assert main(['check', str(path), '--quiet', option, value]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1


def test_the_same_real_map_at_two_densities_gets_the_same_verdict(strict_json, shared_data,
                                                                   tmp_path):
    """Freiburg 079 recorded scan by scan (0.1 m apart) and every 5th scan (0.5 m): the same
    viewpoints' worth of map, the same verdict and about the same number of viewpoints."""
    log = shared_data / 'fr079' / 'freiburg-079-corrected.log.gz'
    reports = {}
    for every in (1, 5):
        report = tmp_path / f'every{every}.json'
        assert main(['check', str(log), '--quiet', '--every', str(every),
                     '--report', str(report)]) == 0
        reports[every] = strict_json(report.read_text())
    dense, sparse = reports[1], reports[5]
    assert dense['verdict'] == sparse['verdict'] == 'consistent'
    assert dense['laser_records'] == 4791
    # 4,791 records become about as many viewpoints as the 959 of every 5th scan
    assert 0.8 < dense['summary']['scans'] / sparse['summary']['scans'] < 1.5
    assert dense['misalignments'] == sparse['misalignments'] == []


def _one_line(capsys) -> str:
    (line,) = capsys.readouterr().err.splitlines()
    return line


def test_bad_inputs_and_sensor_options_are_named_in_one_line(room_log, tmp_path, capsys):
    path, _, _ = room_log()
    assert main(['check', str(tmp_path), '--quiet']) == 2
    assert _one_line(capsys) == (f'map-consistency check: {tmp_path}: is a folder; check takes '
                                 'one log or .g2o graph (batch takes folders)')
    for option, value, message in (('--max-range', '-3', '--max-range must be positive, got -3'),
                                   ('--range-min', '-1', '--range-min must be zero or positive, '
                                                         'got -1'),
                                   ('--fov', '400', '--fov must be in (0, 360] degrees, got 400')):
        assert main(['check', str(path), '--quiet', option, value]) == 2
        assert _one_line(capsys) == f'map-consistency check: options: {message}'
    graph = tmp_path / 'bare.g2o'
    graph.write_text('VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n'
                     'EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n')
    assert main(['check', str(graph), '--quiet']) == 2
    assert _one_line(capsys) == (f'map-consistency check: {graph}: the graph carries no laser '
                                 'data (ROBOTLASER1 lines)')


def test_an_output_that_cannot_be_written_is_named_by_its_option(room_log, tmp_path, capsys):
    path, _, _ = room_log()
    (tmp_path / 'afile').write_text('')
    figure = tmp_path / 'afile' / 'map.png'
    assert main(['check', str(path), '--quiet', '--plot', str(figure)]) == 2
    assert _one_line(capsys) == f'map-consistency check: --plot {figure}: Not a directory'
