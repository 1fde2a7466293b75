"""`map-consistency localize RUN --map REFERENCE`: exit codes, the report's keys, the plot,
bad input in one line."""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from map_consistency_ros.cli.main import main
from map_consistency_ros.core.geometry import se2
from map_consistency_ros.core.localization import UNKNOWN, OccupancyGrid
from map_consistency_ros.io.carmen_writer import write_flaser_log
from map_consistency_ros.io.occupancy_map import write_occupancy_map

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'core' / 'localization'))
from test_pipeline import path, room, simulate  # noqa: E402

FULL_CIRCLE = ['--fov', '360']


@pytest.fixture(scope='module')
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp('localize')
    truth = path()
    ranges = simulate(room(), truth)
    stamps = np.arange(len(truth), dtype=float)
    write_occupancy_map(folder / 'map.yaml', room())
    grid = room()
    write_occupancy_map(folder / 'blank.yaml', OccupancyGrid(
        cells=np.full(grid.cells.shape, UNKNOWN, np.int8), resolution=grid.resolution,
        origin=grid.origin))
    write_flaser_log(folder / 'good.log', ranges, truth, stamps)
    estimate = truth.copy()
    estimate[30:60] = se2.compose(np.array([0.0, 0.4, math.radians(3.0)]), truth[30:60])
    write_flaser_log(folder / 'kidnapped.log', ranges, estimate, stamps)
    return folder


def test_a_localized_run_exits_0(files, tmp_path, capsys, strict_json):
    report, plot = tmp_path / 'r.json', tmp_path / 'r.png'
    code = main(['localize', str(files / 'good.log'), '--map', str(files / 'map.yaml'),
                 *FULL_CIRCLE, '--report', str(report), '--plot', str(plot)])
    out = capsys.readouterr().out
    assert code == 0, out
    assert 'localized' in out
    data = strict_json(report.read_text())
    assert data['localized'] is True and data['episodes'] == [] and data['frozen'] == []
    assert {'changes', 'parameters', 'outcome'} <= set(data)
    assert data['parameters']['consistency']['alpha'] == 0.01
    assert data['parameters']['localization']['max_translation'] == 1.5
    assert plot.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'


def test_a_kidnapped_run_exits_1_with_its_episode(files, tmp_path, capsys, strict_json):
    report = tmp_path / 'r.json'
    code = main(['localize', str(files / 'kidnapped.log'), '--map', str(files / 'map.yaml'),
                 *FULL_CIRCLE, '--report', str(report)])
    out = capsys.readouterr().out
    assert code == 1, out
    assert 'mislocalized: records 3' in out
    data = strict_json(report.read_text())
    assert data['localized'] is False and len(data['episodes']) == 1
    episode = data['episodes'][0]
    assert {'first', 'last', 'position_error_m', 'heading_error_deg'} <= set(episode)
    assert abs(episode['first'] - 30) <= 3 and abs(episode['last'] - 59) <= 3
    assert episode['heading_error_deg'] == pytest.approx(-3.0, abs=1.0)


def test_a_map_that_knows_nothing_exits_4(files, capsys):
    code = main(['localize', str(files / 'good.log'), '--map', str(files / 'blank.yaml'),
                 *FULL_CIRCLE])
    assert code == 4
    assert 'nothing to judge' in capsys.readouterr().out


def test_a_mapping_run_is_a_reference_too(files, capsys):
    code = main(['localize', str(files / 'kidnapped.log'), '--map', str(files / 'good.log'),
                 *FULL_CIRCLE])
    assert code == 1, capsys.readouterr().out


def _one_line_error(capsys, name: str) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and 'Traceback' not in err and name in err
    return err


def test_a_missing_map_exits_2(files, tmp_path, capsys):
    code = main(['localize', str(files / 'good.log'), '--map', str(tmp_path / 'none.yaml')])
    assert code == 2
    _one_line_error(capsys, 'none.yaml')


def test_a_map_with_a_bad_resolution_exits_2(files, tmp_path, capsys):
    text = (files / 'map.yaml').read_text()
    bad = tmp_path / 'bad.yaml'
    lines = [('resolution: -1' if line.startswith('resolution') else line)
             for line in text.splitlines()]
    bad.write_text('\n'.join(lines).replace('image: map.pgm', f'image: {files / "map.pgm"}'))
    code = main(['localize', str(files / 'good.log'), '--map', str(bad)])
    assert code == 2
    assert 'resolution' in _one_line_error(capsys, 'bad.yaml')


def test_an_empty_run_exits_2(files, tmp_path, capsys):
    empty = tmp_path / 'empty.log'
    empty.write_text('')
    code = main(['localize', str(empty), '--map', str(files / 'map.yaml')])
    assert code == 2
    _one_line_error(capsys, 'empty.log')


def test_the_test_and_localization_parameters_are_options_checked_as_everywhere(tmp_path,
                                                                                capsys):
    from map_consistency_ros.cli.main import main
    # the parameters' own checks (core/parameters.py), one line naming the option's parameter
    assert main(['localize', str(tmp_path / 'run.log'), '--map', str(tmp_path / 'map.yaml'),
                 '--alpha', '0.7']) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and 'alpha' in error[0] and '0.7' in error[0]
    assert main(['localize', str(tmp_path / 'run.log'), '--map', str(tmp_path / 'map.yaml'),
                 '--max-translation', '-1']) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and 'max_translation' in error[0]


def test_a_bad_sensor_option_is_one_line_naming_the_option(tmp_path, capsys):
    from map_consistency_ros.cli.main import main
    assert main(['localize', str(tmp_path / 'run.log'), '--map', str(tmp_path / 'map.yaml'),
                 '--max-range', '-3']) == 2
    assert capsys.readouterr().err.strip() == (
        'map-consistency localize: options: --max-range must be positive, got -3')
