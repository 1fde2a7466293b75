"""An internal error is exit 3 with one line on stderr naming the input, never exit 1 (an
inconsistent map); its traceback only with --debug. The same for every subcommand."""
import subprocess
import sys

import pytest

from map_consistency_ros.cli import check
from map_consistency_ros.cli.main import EXIT_INTERNAL_ERROR, main


def _fail(*_, **__):
    raise ZeroDivisionError('float division by zero\nin a kernel')


@pytest.fixture
def log(room_log):
    path, _, _ = room_log()
    return path


def _lines(text):
    return [line for line in text.splitlines() if line.strip()]


@pytest.mark.parametrize('debug', [[], ['--debug']], ids=['plain', 'debug-global'])
def test_an_internal_error_in_check_is_exit_3_with_one_line(log, monkeypatch, capsys, debug):
    monkeypatch.setattr(check, 'check_map', _fail)
    assert main([*debug, 'check', str(log), '--quiet']) == EXIT_INTERNAL_ERROR
    err = capsys.readouterr().err
    last = _lines(err)[-1]
    assert last == (f'map-consistency check: internal error on {log}: ZeroDivisionError: '
                    'float division by zero in a kernel')
    if debug:
        assert 'Traceback (most recent call last)' in err and '_fail' in err
    else:
        assert _lines(err) == [last]


def test_debug_after_the_subcommand_prints_the_traceback(log, monkeypatch, capsys):
    monkeypatch.setattr(check, 'check_map', _fail)
    assert main(['check', str(log), '--quiet', '--debug']) == EXIT_INTERNAL_ERROR
    assert 'Traceback (most recent call last)' in capsys.readouterr().err


@pytest.mark.parametrize('command, module, target', [
    (['tune', 'graph.g2o'], 'map_consistency_ros.cli.tune', 'run'),
    (['replay', 'a.bag', 'b.bag'], 'map_consistency_ros.cli.replay', 'run'),
    (['convert', 'in.log', 'out'], 'map_consistency_ros.cli.convert', 'run'),
    (['evaluate'], 'map_consistency_ros.cli.evaluate', 'run'),
    (['demo'], 'map_consistency_ros.cli.demo', 'run'),
])
def test_every_subcommand_maps_an_internal_error_to_3(command, module, target, monkeypatch,
                                                     capsys):
    import importlib
    monkeypatch.setattr(importlib.import_module(module), target, _fail)
    assert main(command) == EXIT_INTERNAL_ERROR
    (line,) = _lines(capsys.readouterr().err)
    assert line.startswith(f'map-consistency {command[0]}: internal error')
    assert ' '.join(command[1:]) in line and line.endswith('ZeroDivisionError: float division '
                                                            'by zero in a kernel')


def test_the_console_entry_point_exits_3_on_an_internal_error(log, tmp_path):
    # A real process: `check` with its registration made to fail, through the module's entry.
    script = ('import sys\n'
              'from map_consistency_ros.core.verdict import explanation\n'
              'def broken(*args, **kwargs):\n'
              '    raise RuntimeError("registration broke")\n'
              'explanation.register_submaps = broken\n'
              'from map_consistency_ros.cli.main import main\n'
              'sys.exit(main(sys.argv[1:]))\n')
    # the room fails the paper's test once half of it is displaced, so the second stage runs
    displaced = tmp_path / 'displaced.log'
    lines = log.read_text().splitlines(keepends=True)
    shifted = []
    for index, line in enumerate(lines):
        tokens = line.split()
        if index >= len(lines) // 2:
            count = int(tokens[1])
            for position in (2 + count, 5 + count):
                tokens[position] = f'{float(tokens[position]) + 0.4:.6f}'
        shifted.append(' '.join(tokens) + '\n')
    displaced.write_text(''.join(shifted))
    for debug in ([], ['--debug']):
        # every scan of the small room a viewpoint, as in test_check's displaced room
        done = subprocess.run([sys.executable, '-c', script, *debug, 'check', str(displaced),
                               '--quiet', '--viewpoint-spacing', '0'], capture_output=True,
                              text=True, timeout=300)
        assert done.returncode == EXIT_INTERNAL_ERROR, done.stderr
        lines = _lines(done.stderr)
        assert lines[-1] == (f'map-consistency check: internal error on {displaced}: '
                             'RuntimeError: registration broke')
        assert ('Traceback' in done.stderr) is bool(debug)
        if not debug:
            assert len(lines) == 1


# ---------------------------------------------------------------- nothing to judge

def test_a_log_of_one_scan_is_nothing_to_judge_exit_4(tmp_path, flaser_log, capsys,
                                                        strict_json):
    from test.conftest import rectangle_room_ranges
    from map_consistency_ros.cli.exit_codes import EXIT_NOTHING_TO_JUDGE
    poses = [[3.0, 2.0, 0.3]]
    path = tmp_path / 'one.log'
    flaser_log(path, rectangle_room_ranges(poses), poses)
    report = tmp_path / 'report.json'
    assert main(['check', str(path), '--quiet', '--report', str(report)]) == EXIT_NOTHING_TO_JUDGE
    out = capsys.readouterr().out
    assert f'{path}: NOTHING TO JUDGE: no scan has the 2 tested pairs' in out
    content = strict_json(report.read_text())
    assert content['verdict'] == 'nothing to judge'
    assert content['nothing_to_judge_reason'].startswith('no scan has')


@pytest.mark.parametrize('codes, worst', [([0, 4], 4), ([4, 1], 1), ([1, 2], 2), ([2, 3], 3),
                                          ([0, 0], 0), ([], 0), ([4], 4)])
def test_a_batch_ranks_nothing_to_judge_between_consistent_and_inconsistent(codes, worst):
    from map_consistency_ros.cli import exit_codes
    assert exit_codes.worst(codes) == worst


def test_bad_input_is_one_line_whatever_the_message_holds(log, monkeypatch, capsys):
    from map_consistency_ros.io.errors import InputError

    def _bad(*_, **__):
        raise InputError('in.yaml', 'while parsing\n  in "<unicode string>"\nexpected', 3)

    monkeypatch.setattr(check, 'judge', _bad)
    assert main(['check', str(log), '--quiet']) == 2
    assert _lines(capsys.readouterr().err) == [
        'map-consistency check: in.yaml:3: while parsing in "<unicode string>" expected']
