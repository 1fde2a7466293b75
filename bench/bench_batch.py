"""`map-consistency batch` of the five corrected logs and their displaced copies: the local
process pool against a Dask LocalCluster on this machine, each map's cost beside `check`.

    .venv/bin/python bench/bench_batch.py [--workers 2] [--seams 1] [--out DIR] [--no-html]

The maps are files, as a user would give them: each corrected log (Freiburg 079 every 5th
scan, as evaluation/whole_logs.py, since its window counts scans) and copies with everything
after a random seam turned by 1, 2, 5 degrees or shifted by 0.1, 0.3 m (whole_logs'
displacements), written as CARMEN logs (PARAM lines kept, for the beam geometry). Every map is
checked by `map-consistency check` as a whole process (wall time, and the test time it
prints), then all maps by `batch --workers N` and by `batch --scheduler` on a
LocalCluster(N workers, 1 thread each, processes), both as whole processes. The tables of the
two batches must agree but for the runtimes. Then `batch --html` of the corrected logs and one
copy each, and a screenshot of its index page in headless Chromium (Debian's `chromium`).
"""
from __future__ import annotations

import argparse
import gzip
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from map_consistency_ros.evaluation.suite import CORRECTED_LOGS
from map_consistency_ros.evaluation.whole_logs import displaced_maps
from map_consistency_ros.io.carmen import read_carmen_log

TREE = Path(__file__).resolve().parents[1]
DATA = TREE.parent / 'shared' / 'data'
COMMAND = [sys.executable, '-m', 'map_consistency_ros.cli.main']


def _lines(path: Path) -> list[str]:
    opener = gzip.open if path.suffix == '.gz' else open
    with opener(path, 'rt', encoding='utf-8', errors='replace') as stream:
        return stream.read().splitlines()


def write_maps(folder: Path, seams: int, seed: int) -> list[Path]:
    """Every map of the bench as a CARMEN log in `folder`; the paths, corrected logs first."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for dataset in CORRECTED_LOGS:
        lines = _lines(DATA / CORRECTED_LOGS[dataset])
        params = [line for line in lines if line.startswith('PARAM ')]
        flaser = [line.split() for line in lines if line.startswith('FLASER ')]
        for number, whole in enumerate(displaced_maps(dataset, DATA, seams, seed)):
            name = re.sub(r'[^A-Za-z0-9.]+', '_', whole.name.split('/', 1)[1]).strip('_')
            path = folder / f'{dataset}_{number:02d}_{name}.log'
            records = []
            for index, pose in zip(whole.scan_indices, whole.poses):
                tokens = list(flaser[index])
                beams = int(tokens[1])
                text = [f'{value:.6f}' for value in pose]
                tokens[2 + beams:2 + beams + 6] = text + text  # laser pose, odometry slot
                records.append(' '.join(tokens))
            path.write_text('\n'.join(params + records) + '\n')
            written = read_carmen_log(path)
            assert np.allclose(written.laser_poses, whole.poses, atol=2e-6), path
            paths.append(path)
    return paths


def run(arguments: list[str]) -> tuple[float, subprocess.CompletedProcess]:
    started = time.perf_counter()
    done = subprocess.run([*COMMAND, *arguments], cwd=TREE, capture_output=True, text=True,
                          env=dict(os.environ, PYTHONPATH=str(TREE)))
    return time.perf_counter() - started, done


def check_costs(paths: list[Path]) -> dict[str, tuple[float, float, int]]:
    """path -> (wall seconds of `check PATH --quiet`, its printed test time, exit code)."""
    costs = {}
    for path in paths:
        wall, done = run(['check', str(path), '--quiet'])
        test = re.search(r'test time\s+([0-9.]+) s', done.stdout)
        costs[str(path)] = (wall, float(test.group(1)) if test else float('nan'),
                            done.returncode)
    return costs


def batch(paths: list[Path], output: Path, extra: list[str]) -> tuple[float, int, list[dict]]:
    wall, done = run(['batch', *map(str, paths), '--quiet', '--json', str(output), *extra])
    if done.returncode not in (0, 1):
        sys.stderr.write(done.stdout + done.stderr)
    return wall, done.returncode, json.loads(output.read_text())['maps']


def dask_batch(paths: list[Path], output: Path, workers: int) -> tuple[float, int, list[dict]]:
    from distributed import LocalCluster
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                           dashboard_address=None)
    try:
        return batch(paths, output, ['--scheduler', cluster.scheduler_address])
    finally:
        cluster.close()


def screenshot(page: Path, picture: Path) -> bool:
    """A PNG of `page` from headless Chromium; False when no Chromium is installed."""
    browser = shutil.which('chromium') or shutil.which('chromium-browser')
    if browser is None:
        return False
    with tempfile.TemporaryDirectory(prefix='bench-batch-chromium-') as profile:
        process = subprocess.Popen(
            [browser, '--headless', '--no-sandbox', '--disable-gpu',
             '--disable-background-networking', '--no-first-run', f'--user-data-dir={profile}',
             '--hide-scrollbars', '--window-size=1600,2400', f'--screenshot={picture}',
             page.resolve().as_uri()],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            process.wait(timeout=120)
        finally:
            if process.poll() is None:
                process.kill()
                process.wait()
    return picture.is_file()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--workers', type=int, default=2)
    parser.add_argument('--seams', type=int, default=1, help='copies per displacement size')
    parser.add_argument('--seed', type=int, default=7)
    parser.add_argument('--out', type=Path, default=None,
                        help='keep the maps, tables, HTML page and screenshot here')
    parser.add_argument('--no-html', action='store_true')
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix='bench-batch-') as scratch:
        out = args.out or Path(scratch)
        maps = out / 'maps'
        maps.mkdir(parents=True, exist_ok=True)
        paths = write_maps(maps, args.seams, args.seed)
        # the first process fills numba's cache: no timed run pays for compilation
        run(['check', str(paths[0]), '--quiet'])
        checks = check_costs(paths)
        local_wall, local_code, local = batch(paths, out / 'local.json',
                                              ['--workers', str(args.workers)])
        dask_wall, dask_code, remote = dask_batch(paths, out / 'dask.json', args.workers)
        same = ([{k: v for k, v in row.items() if k != 'runtime_seconds'} for row in local] ==
                [{k: v for k, v in row.items() if k != 'runtime_seconds'} for row in remote])
        print(f'{len(paths)} maps, {args.workers} workers, {os.cpu_count()} cores')
        print(f'{"map":<44} {"scans":>5} {"verdict":<12} {"check wall":>10} {"check test":>10} '
              f'{"local":>7} {"dask":>7}')
        for row, other in zip(local, remote):
            wall, test, code = checks[row['input']]
            agree = '' if code == row['exit_code'] else '  (check disagrees)'
            print(f'{Path(row["input"]).name:<44} {row["scans"] or 0:>5} {row["verdict"]:<12} '
                  f'{wall:>9.2f}s {test:>9.2f}s {row["runtime_seconds"]:>6.2f}s '
                  f'{other["runtime_seconds"]:>6.2f}s{agree}')
        total_check = sum(cost[0] for cost in checks.values())
        print(f'check, one process per map, one after the other: {total_check:.1f} s wall')
        print(f'batch --workers {args.workers}: {local_wall:.1f} s wall (exit {local_code}); '
              f'sum of per-map runtimes {sum(r["runtime_seconds"] for r in local):.1f} s')
        print(f'batch --scheduler (LocalCluster {args.workers} x 1 thread): {dask_wall:.1f} s '
              f'wall, cluster start and stop excluded (exit {dask_code}); sum of per-map '
              f'runtimes {sum(r["runtime_seconds"] for r in remote):.1f} s')
        print(f'tables equal but for runtimes: {same}')
        if not args.no_html:
            chosen = [path for path in paths if re.search(r'_0[01]_', path.name)]
            page = out / 'html'
            wall, code, _ = batch(chosen, out / 'html.json',
                                  ['--workers', str(args.workers), '--html', str(page)])
            print(f'batch --html of {len(chosen)} maps: {wall:.1f} s wall, {page / "index.html"}')
            picture = out / 'index.png'
            if screenshot(page / 'index.html', picture):
                print(f'screenshot of the page: {picture}')
            else:
                print('no chromium: no screenshot')


if __name__ == '__main__':
    main()
