"""`map-consistency tune`: the three input forms, outputs, exit codes and bad input."""

import re

import numpy as np
import pytest

from map_consistency_ros.cli.main import main
from map_consistency_ros.io.g2o import read_g2o, write_g2o

FAST = ['--grid-steps', '3', '--tolerance', '2', '--iterations', '30', '--quiet']


@pytest.fixture(scope='module')
def built(shared_data, tmp_path_factory):
    """`tune --build` on every 30th Intel scan with false loops: its exit code, outputs, graph."""
    out = tmp_path_factory.mktemp('tune')
    intel = shared_data / 'intel'
    code = main(['tune', '--build', str(intel / 'intel.gfs.log'), str(intel / 'intel.relations'),
                 str(intel / 'intel.orig.bag'), '--stride', '30', '--false-loops', '5',
                 '--save-graph', str(out / 'graph.g2o'), '--report', str(out / 'tune.json'),
                 '--profile-plot', str(out / 'profile.png'), '--maps-plot',
                 str(out / 'maps.png'), *FAST])
    return code, out


def test_build_form_writes_graph_report_and_figures(strict_json, built):
    code, out = built
    report = strict_json((out / 'tune.json').read_text())
    assert code == (0 if report['verdict'] == 'consistent' else 1)
    profile = report['profile']
    best = int(np.argmin(profile['average_inconsistency']))
    assert report['phi'] == pytest.approx(profile['phi'][best])
    assert report['average_inconsistency'] == pytest.approx(profile['average_inconsistency'][best])
    assert len(report['poses']) == read_g2o(out / 'graph.g2o').graph.vertex_count == 31
    assert 'average_inconsistency' in report['baseline_phi_1']
    for figure in ('profile.png', 'maps.png'):
        assert (out / figure).read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'


def test_graph_form_gives_the_same_answer_as_the_build_form(strict_json, built, capsys):
    _, out = built
    code = main(['tune', str(out / 'graph.g2o'), '--report', str(out / 'again.json'), *FAST])
    first = strict_json((out / 'tune.json').read_text())
    again = strict_json((out / 'again.json').read_text())
    assert again['phi'] == pytest.approx(first['phi'], rel=1e-12)
    np.testing.assert_allclose(again['poses'], first['poses'], atol=1e-9)
    assert code == (0 if again['verdict'] == 'consistent' else 1)
    printed = capsys.readouterr().out
    assert 'Phi* =' in printed and 'M(1)' in printed


def test_scans_form_takes_the_scans_from_a_carmen_log(strict_json, built, tmp_path):
    _, out = built
    content = read_g2o(out / 'graph.g2o')
    log = tmp_path / 'scans.log'
    lines = []
    for ranges, pose, stamp in zip(content.laser.ranges, content.laser.robot_poses,
                                   content.laser.timestamps):
        values = ' '.join(f'{value:g}' for value in ranges)
        pose_text = ' '.join(f'{value:.9f}' for value in pose)
        lines.append(f'FLASER {len(ranges)} {values} {pose_text} {pose_text} {stamp} h {stamp}')
    log.write_text('\n'.join(lines) + '\n')
    bare = tmp_path / 'bare.g2o'
    write_g2o(bare, type(content)(graph=content.graph, vertex_ids=content.vertex_ids))
    code = main(['tune', str(bare), '--scans', str(log), '--report', str(tmp_path / 'r.json'),
                 *FAST])
    report = strict_json((tmp_path / 'r.json').read_text())
    assert code in (0, 1) and len(report['poses']) == 31


@pytest.mark.parametrize('arguments, message', [
    ([], 'give either GRAPH or --build'),
    (['--grid-steps', '1'], 'grid_steps: 1 is outside [3, 10000]'),
])
def test_bad_arguments_exit_2(built, capsys, arguments, message):
    _, out = built
    graph = [] if not arguments else [str(out / 'graph.g2o')]
    assert main(['tune', *graph, *arguments]) == 2
    assert message in capsys.readouterr().err


def test_graph_without_scans_or_with_a_wrong_log_exits_2(built, tmp_path, capsys):
    _, out = built
    content = read_g2o(out / 'graph.g2o')
    bare = tmp_path / 'bare.g2o'
    write_g2o(bare, type(content)(graph=content.graph, vertex_ids=content.vertex_ids))
    assert main(['tune', str(bare), *FAST]) == 2
    assert 'no ROBOTLASER1 lines' in capsys.readouterr().err
    log = tmp_path / 'one.log'
    log.write_text('FLASER 3 1 1 1 0 0 0 0 0 0 1.0 h 1.0\n')
    assert main(['tune', str(bare), '--scans', str(log), *FAST]) == 2
    assert '1 laser records for 31 vertices' in capsys.readouterr().err
    broken = tmp_path / 'broken.g2o'
    broken.write_text('VERTEX_SE2 0 0 0\n')
    assert main(['tune', str(broken), *FAST]) == 2
    assert f'{broken}:1: VERTEX_SE2 needs 4 fields' in capsys.readouterr().err


def test_the_summary_gives_m_in_metres_the_paths_written_and_what_a_failing_map_means(
        strict_json, built, tmp_path, capsys):
    _, out = built
    written = [tmp_path / 'tune.json', tmp_path / 'profile.png']
    code = main(['tune', str(out / 'graph.g2o'), '--report', str(written[0]),
                 '--profile-plot', str(written[1]), *FAST])
    printed = capsys.readouterr().out
    report = strict_json(written[0].read_text())
    assert f'M(Phi*)               {report["average_inconsistency"]:.6g} m ' in printed
    assert f'  report                {written[0]}' in printed
    assert f'  profile plot          {written[1]}' in printed
    assert ('look for a wrong loop closure' in printed) == (code == 1)


def test_a_flat_profile_and_a_minimum_at_the_end_of_the_range_are_warned_about(
        strict_json, built, tmp_path, capsys):
    _, out = built
    # within a tolerance of 1 every profile is flat: Phi* is then arbitrary
    main(['tune', str(out / 'graph.g2o'), '--flat-tolerance', '1',
          '--report', str(tmp_path / 'flat.json'), *FAST])
    warnings = capsys.readouterr().err.splitlines()
    assert len(warnings) == 1 and 'warning: M(Phi) is flat' in warnings[0]
    assert str(out / 'graph.g2o') in warnings[0]
    report = strict_json((tmp_path / 'flat.json').read_text())
    assert report['flat_profile'] is True and report['warnings'] == [
        warnings[0].split('warning: ', 1)[1]]
    # this graph's M falls up to Phi = 6: a range ending at 2 holds its minimum at the end
    main(['tune', str(out / 'graph.g2o'), '--phi-max', '2', *FAST])
    warnings = capsys.readouterr().err.splitlines()
    assert len(warnings) == 1 and 'lies at the upper end of the search (--phi-max 2)' \
        in warnings[0]


@pytest.mark.parametrize('keep', ['none', 'odometry'])
def test_a_graph_without_edges_or_loop_closures_is_refused_in_one_line(built, tmp_path, capsys,
                                                                        keep):
    """Needs the graph policy of core/backend (tuning_problem) in tune's input reading."""
    _, out = built
    lines = []
    for line in (out / 'graph.g2o').read_text().splitlines():
        fields = line.split()
        if fields and fields[0] == 'EDGE_SE2' and (
                keep == 'none' or abs(int(fields[1]) - int(fields[2])) != 1):
            continue
        lines.append(line)
    graph = tmp_path / f'{keep}.g2o'
    graph.write_text('\n'.join(lines) + '\n')
    assert main(['tune', str(graph), *FAST]) == 2
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1 and str(graph) in error
    assert 'singular' not in error
    if keep == 'none':
        assert re.search(r'\b(no|0) (edges?|constraints?)\b', error)
    else:
        assert 'no loop closure' in error


def _corrupted(path, tmp_path, name, change):
    """A copy of the graph file at `path` with `change(lines)` applied to its lines."""
    lines = path.read_text().splitlines()
    change(lines)
    copy = tmp_path / f'{name}.g2o'
    copy.write_text('\n'.join(lines) + '\n')
    return copy


def _edit_edge(lines, field, value):
    """The fourth edge's field `field` (0: the tag) set to `value`; its line number."""
    edge = [k for k, line in enumerate(lines) if line.startswith('EDGE_SE2')][3]
    tokens = lines[edge].split()
    tokens[field] = value
    lines[edge] = ' '.join(tokens)
    return edge + 1


def _crossing(line, split):
    """Whether `line` is an edge between vertices on either side of `split`."""
    if not line.startswith('EDGE_SE2'):
        return False
    first, second = (int(token) for token in line.split()[1:3])
    return (first <= split) != (second <= split)


@pytest.mark.parametrize('name, change, message', [
    ('vertex_1e300', lambda lines: lines.__setitem__(
        next(k for k, line in enumerate(lines) if line.startswith('VERTEX_SE2 5 ')),
        'VERTEX_SE2 5 1e300 0 0'),
     'vertex pose x 1e+300 is beyond 100000 m'),  # refused where it is read
    ('edge_1e300', lambda lines: _edit_edge(lines, 3, '1e300'),
     'EDGE_SE2 has a measurement beyond 100000'),
    ('information_1e300', lambda lines: [_edit_edge(lines, field, '1e300') for field in (6, 9)],
     'EDGE_SE2 has information entries beyond 1e+12'),
    ('odometry_only', lambda lines: lines.__init__(
        [line for line in list(lines) if not line.startswith('EDGE_SE2')
         or abs(int(line.split()[1]) - int(line.split()[2])) == 1]),
     'cannot tune this graph honestly: no loop closure among the constraints'),
    ('disconnected', lambda lines: lines.__init__(
        [line for line in list(lines) if not _crossing(line, 15)]),
     'cannot tune this graph honestly: the constraints split the 31 poses into 2 '
     'disconnected parts'),
])
def test_graphs_that_cannot_be_tuned_honestly_exit_2_naming_the_file(built, tmp_path, capsys,
                                                                      name, change, message):
    """Absurd numbers, no loop closure, parts: the node's retune refuses the same graphs."""
    _, out = built
    broken = _corrupted(out / 'graph.g2o', tmp_path, name, change)
    assert main(['tune', str(broken), *FAST]) == 2
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1
    assert message in error
    if message.startswith('EDGE_SE2'):  # a bad number: the line it is read from
        line = _edit_edge((out / 'graph.g2o').read_text().splitlines(), 0, 'EDGE_SE2')
        assert error.startswith(f'map-consistency tune: {broken}:{line}: {message}')
    elif message.startswith('vertex'):
        line = 1 + next(k for k, text in enumerate(broken.read_text().splitlines())
                        if text.startswith('VERTEX_SE2 5 '))
        assert error.startswith(f'map-consistency tune: {broken}:{line}: {message}')
    else:  # the graph as a whole
        assert error.startswith(f'map-consistency tune: {broken}: cannot tune')
