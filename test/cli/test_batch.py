"""`map-consistency batch`: each input judged as check / replay would, the table, the exit
code, the HTML page, and the same table from a Dask cluster as from the local pool."""
import csv
import json
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from map_consistency_ros import pool
from map_consistency_ros.cli import batch, check
from map_consistency_ros.cli.main import main

DEMO_BAG = 'intel_demo.mcap'


EVERY_SCAN = ('--viewpoint-spacing', '0')


def _first_line(capsys) -> str:
    return capsys.readouterr().out.splitlines()[0]


def test_each_input_is_judged_as_check_and_replay_judge_it(room_log, displaced_room_log,
                                                           tmp_path, capsys):
    consistent, _, _ = room_log()
    displaced = displaced_room_log()
    bag = Path(batch.__file__).parents[1] / 'data' / DEMO_BAG
    corrupt = tmp_path / 'corrupt.log'
    corrupt.write_text('FLASER 3 1.0 2.0\n')
    table, page = tmp_path / 'out' / 'table.csv', tmp_path / 'page'
    # every scan a viewpoint: the room's lap (10 m) is shorter than the local window
    code = main(['batch', str(consistent), str(displaced), str(bag), str(corrupt),
                 str(tmp_path / 'nothing*.bag'), '--workers', '1', '--quiet', *EVERY_SCAN,
                 '--csv', str(table), '--json', str(tmp_path / 'table.json'),
                 '--html', str(page)])
    capsys.readouterr()
    assert code == batch.EXIT_BAD_INPUT  # bad inputs outrank the inconsistent map
    rows = json.loads((tmp_path / 'table.json').read_text())['maps']
    assert [row['verdict'] for row in rows] == ['consistent', 'inconsistent', 'consistent',
                                                'bad input', 'bad input']
    assert [row['kind'] for row in rows] == ['carmen log', 'carmen log', 'ros2 bag',
                                             'carmen log', 'missing']
    assert 'truncated FLASER record' in rows[3]['error']
    assert 'no such file' in rows[4]['error']
    # the summary lines are check's and replay's, word for word
    for row, command in zip(rows[:3], ('check', 'check', 'replay')):
        expected = main([command, row['input'], '--quiet', *EVERY_SCAN])
        assert row['exit_code'] == expected
        assert _first_line(capsys) == f'{row["input"]}: {row["summary_line"]}'
    (region,) = rows[1]['regions']
    assert region['number'] == 1
    assert region['scans'][0] >= 30 and region['reference_scans'][1] < 30
    assert region['displacement_m'] == pytest.approx(0.4, abs=0.05)
    assert rows[2]['scans'] == 290 and rows[2]['changed_places'] > 0
    with open(table, newline='') as stream:
        cells = list(csv.DictReader(stream))
    assert [cell['verdict'] for cell in cells] == [row['verdict'] for row in rows]
    assert cells[1]['regions'].startswith('#1 ') and ' scans between 0 and ' in cells[1]['regions']
    assert 'shifted 0.39 m' in cells[1]['regions']
    index = (page / 'index.html').read_text()
    for number, row in enumerate(rows[:3]):
        slug = batch._slug(number, row['input'])
        for suffix in ('.png', '.thumb.png'):
            assert (page / 'maps' / f'{slug}{suffix}').read_bytes()[:4] == b'\x89PNG'
            assert f'maps/{slug}{suffix}' in index
        report = json.loads((page / 'maps' / f'{slug}.json').read_text())
        assert report['verdict'] == row['verdict'] and f'maps/{slug}.json' in index
    assert index.count('<tr data-index=') == len(rows)
    assert json.loads((page / 'batch.json').read_text())['maps'] == rows


def test_folders_and_patterns_are_searched_and_each_input_listed_once(room_log, tmp_path):
    first, _, _ = room_log(name='a.log')
    (tmp_path / 'notes.txt').write_text('not a map')
    bag_folder = tmp_path / 'run' / 'bag'
    bag_folder.mkdir(parents=True)
    (bag_folder / 'metadata.yaml').write_text('rosbag2_bagfile_information: {}')
    (bag_folder / 'bag_0.mcap').write_bytes(b'')
    found = batch.find_inputs([str(tmp_path), str(tmp_path / '*.log'), str(first)])
    assert found == [(str(first), batch.CARMEN), (str(bag_folder), batch.ROS2_BAG)]


def test_an_unexpected_error_is_an_internal_error_and_the_batch_goes_on(room_log,
                                                                          displaced_room_log,
                                                                          tmp_path, monkeypatch,
                                                                          capsys):
    consistent, _, _ = room_log()
    displaced = displaced_room_log()
    judge = check.judge

    def failing(args):
        if args.log == displaced:
            raise ZeroDivisionError('a bug')
        return judge(args)

    monkeypatch.setattr(check, 'judge', failing)
    code = main(['batch', str(displaced), str(consistent), '--workers', '1', '--quiet',
                 '--json', str(tmp_path / 't.json')])
    assert code == batch.EXIT_INTERNAL_ERROR == 3
    rows = json.loads((tmp_path / 't.json').read_text())['maps']
    assert rows[0]['verdict'] == 'internal error'
    assert rows[0]['error'].startswith('internal error: ZeroDivisionError: a bug')
    assert rows[1]['verdict'] == 'consistent'
    assert 'internal error: ZeroDivisionError' in capsys.readouterr().out


def test_a_worker_that_dies_is_reported_for_its_item_and_the_others_finish():
    # eval is importable in any worker; the second item ends its worker process
    items = ['1 + 1', '__import__("os")._exit(7)', '2 * 3', '4 - 1']
    results = pool.run_all(eval, items, workers=2)
    assert results[0] == 2 and results[2:] == [6, 3]
    assert isinstance(results[1], pool.WorkerDied)


def _without_runtimes(path):
    rows = json.loads(path.read_text())['maps']
    for row in rows:
        row.pop('runtime_seconds')
    return rows


def test_dask_cluster_gives_the_table_of_the_local_pool(shared_data, tmp_path):
    import dask
    from distributed import LocalCluster

    extra = shared_data / 'carmen_corrected_extra'
    corrupt = tmp_path / 'corrupt.log.gz'
    corrupt.write_bytes((extra / 'orebro-corrected.log.gz').read_bytes()[:5000])
    inputs = [str(extra / 'orebro-corrected.log.gz'), str(corrupt),
              str(extra / 'freiburg-101-corrected.log.gz')]
    local, remote = tmp_path / 'local.json', tmp_path / 'dask.json'
    assert main(['batch', *inputs, '--workers', '2', '--quiet', '--json', str(local)]) == 2
    # a task on a worker that dies is given up at once, not retried on the others
    with dask.config.set({'distributed.scheduler.allowed-failures': 0}):
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                               dashboard_address=None)
    try:
        code = main(['batch', *inputs, '--scheduler', cluster.scheduler_address, '--quiet',
                     '--json', str(remote)])
        died = pool.run_all(eval, ['1 + 1', '__import__("os")._exit(7)'],
                            scheduler=cluster.scheduler_address)
    finally:
        cluster.close()
    assert code == 2
    rows = _without_runtimes(local)
    assert _without_runtimes(remote) == rows
    assert [row['verdict'] for row in rows] == ['consistent', 'bad input', 'consistent']
    assert [row['scans'] for row in rows] == [237, None, 281]
    assert died[0] == 2 and isinstance(died[1], pool.WorkerDied)


def test_a_scheduler_address_that_cannot_be_used_is_bad_input(room_log, capsys):
    path, _, _ = room_log()
    assert main(['batch', str(path), '--scheduler', 'not an address', '--quiet']) == 2
    assert 'map-consistency batch: --scheduler not an address: ' in capsys.readouterr().err


def test_no_map_at_all_is_bad_input(tmp_path, capsys):
    (tmp_path / 'notes.txt').write_text('not a map')
    assert main(['batch', str(tmp_path), '--quiet']) == 2
    assert 'no logs, graphs or bags found' in capsys.readouterr().err


def _room_graph(room_log, path):
    """The room of `room_log` as a g2o graph: a vertex per scan at its logged pose, odometry
    edges, and each scan as a ROBOTLASER1 line (180 beams over 180 degrees, laser at the robot)."""
    from map_consistency_ros.core.geometry import se2
    _, poses, ranges = room_log()
    lines = []
    for index, (pose, scan) in enumerate(zip(poses, ranges)):
        numbers = ' '.join(f'{value:.9f}' for value in pose)
        lines.append(f'VERTEX_SE2 {index} {numbers}')
        lines.append(f'ROBOTLASER1 0 {-np.pi / 2:.9f} {np.pi:.9f} {np.pi / 180:.9f} 80 0.01 0 '
                     f'{scan.size} ' + ' '.join(f'{r:.4f}' for r in scan) +
                     f' 0 {numbers} {numbers} 0 0 0 0 0 {index * 0.2:.3f} host {index * 0.2:.3f}')
    for index in range(len(poses) - 1):
        step = ' '.join(f'{value:.9f}' for value in se2.relative(poses[index], poses[index + 1]))
        lines.append(f'EDGE_SE2 {index} {index + 1} {step} 100 0 0 100 0 1000')
    path.write_text('\n'.join(lines) + '\n')
    return path


def test_a_graph_with_scans_is_judged_at_its_vertex_poses_as_check_judges_it(room_log,
                                                                               tmp_path, capsys):
    log, _, _ = room_log()
    graph = _room_graph(room_log, tmp_path / 'room.g2o')
    code = main(['batch', str(graph), str(log), '--workers', '1', '--quiet',
                 '--json', str(tmp_path / 't.json')])
    assert code == 0
    rows = json.loads((tmp_path / 't.json').read_text())['maps']
    assert [row['kind'] for row in rows] == ['g2o graph', 'carmen log']
    # the same 19 viewpoints of the room's 40 scans, read from the graph and from the log
    assert rows[0]['scans'] == rows[1]['scans'] == 19
    capsys.readouterr()
    assert main(['check', str(graph), '--quiet']) == 0
    assert _first_line(capsys) == f'{graph}: {rows[0]["summary_line"]}'
    assert rows[0]['summary_line'] == rows[1]['summary_line']


def _chromium() -> str:
    """The headless browser the page test drives: Debian's chromium (`bootstrap.py test`
    installs it where apt-get can) or Ubuntu's chromium-browser."""
    for name in ('chromium', 'chromium-browser'):
        found = shutil.which(name)
        if found:
            return found
    raise FileNotFoundError('no chromium or chromium-browser on PATH: the HTML page test needs '
                            'a headless Chromium (apt-get install -y chromium)')


def _rendered(url: str) -> str:
    """The DOM of `url` after its scripts ran, as headless Chromium serializes it."""
    done = subprocess.run([_chromium(), '--headless', '--no-sandbox', '--disable-gpu',
                           '--virtual-time-budget=2000', '--dump-dom', url],
                          capture_output=True, text=True, timeout=120, check=True)
    return done.stdout


class _Rows(HTMLParser):
    """The table's rows as the browser left them: (input, verdict, runtime, hidden) in order."""

    def __init__(self):
        super().__init__()
        self.rows, self.counts, self.cell, self.title = [], {}, None, ''
        self._in_title = False

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == 'tr' and 'data-index' in attrs:
            self.rows.append({'verdict': attrs['data-verdict'], 'hidden': 'hidden' in attrs})
        elif tag == 'td' and self.rows and attrs.get('data-column') in ('input',
                                                                        'runtime_seconds'):
            self.rows[-1][attrs['data-column']] = attrs.get('data-value', '')
        elif tag == 'b' and attrs.get('id', '').startswith('count-'):
            self.cell = attrs['id'][len('count-'):]
        elif tag == 'h1':
            self._in_title = True

    def handle_endtag(self, tag):
        if tag == 'h1':
            self._in_title = False

    def handle_data(self, data):
        if self.cell is not None:
            self.counts[self.cell] = int(data)
            self.cell = None
        elif self._in_title:
            self.title += data


def _view(index: Path, fragment: str = '') -> _Rows:
    parsed = _Rows()
    parsed.feed(_rendered(index.resolve().as_uri() + fragment))
    return parsed


def test_the_html_page_counts_sorts_and_filters_in_a_browser(room_log, displaced_room_log,
                                                             tmp_path, capsys):
    consistent, _, _ = room_log()
    displaced = displaced_room_log()
    corrupt = tmp_path / 'corrupt.log'
    corrupt.write_text('FLASER 3 1.0 2.0\n')
    page = tmp_path / 'page'
    code = main(['batch', str(consistent), str(displaced), str(corrupt),
                 str(tmp_path / 'missing.log'), '--workers', '1', '--quiet', *EVERY_SCAN,
                 '--alpha', '0.05', '--html', str(page)])
    assert code == batch.EXIT_BAD_INPUT
    printed = capsys.readouterr().out.splitlines()
    assert re.fullmatch(r'4 inputs in [0-9.]+ s: 2 maps judged \(1 consistent, 1 inconsistent\), '
                        r'2 bad inputs', printed[-2])
    index = page / 'index.html'
    shown = _view(index)
    assert shown.title == 'map consistency: 4 inputs: 2 maps judged (1 consistent, ' \
                          '1 inconsistent), 2 bad inputs'
    assert shown.counts == {'consistent': 1, 'inconsistent': 1, 'nothing-to-judge': 0,
                            'bad-input': 2, 'internal-error': 0}
    inputs = [str(consistent), str(displaced), str(corrupt), str(tmp_path / 'missing.log')]
    assert [row['input'] for row in shown.rows] == inputs
    assert not any(row['hidden'] for row in shown.rows)
    # sorted by runtime, shortest first: the inputs read in no time before the maps judged
    by_runtime = _view(index, '#sort=runtime_seconds').rows
    runtimes = [float(row['runtime_seconds']) for row in by_runtime]
    assert runtimes == sorted(runtimes) and by_runtime[-1] != shown.rows[-1]
    assert {row['input'] for row in by_runtime[2:]} == set(inputs[:2])
    by_input = _view(index, '#sort=-input').rows
    assert [row['input'] for row in by_input] == sorted(inputs, reverse=True)
    # filtered: a verdict's box unchecked, or a text the row does not hold
    hidden = _view(index, '#hide=bad-input').rows
    assert [row['hidden'] for row in hidden] == [False, False, True, True]
    texts = _view(index, '#filter=DISPLACED').rows
    assert [row['hidden'] for row in texts] == [True, False, True, True]
    text = index.read_text()
    given = re.search(r'<table class="parameters">(.*?)</table>', text).group(1)
    assert re.findall(r'<td>(\w+)</td><td>([^<]*)</td>', given) == [('alpha', '0.05'),
                                                                  ('viewpoint_spacing', '0.0')]
    assert re.search(r'map_consistency_ros \S+, \d{4}-\d\d-\d\d \d\d:\d\d UTC', text)
    assert 'http' not in text.replace('http-equiv', '')  # nothing fetched from a network
    # thumbnails of several rows fit on a screen
    from PIL import Image
    for thumbnail in sorted((page / 'maps').glob('*.thumb.png')):
        with Image.open(thumbnail) as picture:
            assert picture.height == batch.THUMBNAIL_HEIGHT


def test_a_thumbnail_shows_the_first_misaligned_region_or_the_whole_map(displaced_room_log,
                                                                        room_log):
    args = batch._namespace('check', str(displaced_room_log()), dict(viewpoint_spacing=0.0))
    judgement = check.judge(args)
    scans, assessment = judgement.scans, judgement.assessment
    (region,) = assessment.misalignments
    box = batch._region_box(scans, assessment)
    moved = scans.endpoints[region.scans][scans.valid[region.scans]]
    assert box[0] < moved[:, 0].min() and box[2] > moved[:, 0].max()
    assert box[2] - box[0] <= np.ptp(moved[:, 0]) + 2 * max(2.0, 0.1 * np.ptp(moved, axis=0).max())
    whole = batch._namespace('check', str(room_log()[0]), dict(viewpoint_spacing=0.0))
    assert batch._region_box(check.judge(whole).scans, check.judge(whole).assessment) is None


def test_one_input_is_counted_in_the_singular_and_runtimes_are_kept_to_the_millisecond(
        room_log, tmp_path, capsys):
    path, _, _ = room_log()
    table = tmp_path / 'table.csv'
    assert main(['batch', str(path), '--workers', '1', '--quiet', '--csv', str(table)]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert re.fullmatch(r'1 input in [0-9.]+ s: 1 map judged \(1 consistent\)', printed[-2])
    with open(table, newline='') as stream:
        (row,) = csv.DictReader(stream)
    assert re.fullmatch(r'\d+(\.\d{1,3})?', row['runtime_seconds'])
    assert main(['batch', str(tmp_path / 'absent.log'), '--quiet']) == 2
    assert re.fullmatch(r'1 input in [0-9.]+ s: 0 maps judged, 1 bad input',
                        capsys.readouterr().out.splitlines()[-1])
