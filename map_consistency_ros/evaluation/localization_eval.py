"""Localization mode measured on the generated runs (evaluation/localization_data.py).

For every dataset folder (DATASET/manifest.json, labels/*.json) each run is judged at the
default parameters against its map, as `map-consistency localize` does, and compared with
its labels:

- **recall**: labelled episodes overlapped by a found episode (frozen labels: by a frozen
  estimate found);
- **error**: the found episode's median position error against the label's median
  translation error over the labelled scans (within 50 %), its heading against the
  label's median rotation (within 50 % or 0.5 deg);
- **start**: the found episode's first scan within 10 scans of the label's;
- **false alarms**: found episodes that overlap no labelled episode, and runs the labels
  call localized that come out mislocalized (the corrected run, 0.1 m, the outdated map);
- **changes** (outdated map): the labelled edits with a reported change within 1 m of their
  box;
- **minor**: flagged scans a correction below the tolerance explains.

Run `python -m map_consistency_ros.evaluation.localization_eval FOLDER [--datasets intel
fr079]`; prints one row per run and writes nothing.
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

from map_consistency_ros.core.geometry import ScanSet
from map_consistency_ros.core.localization import MapSurface, localize, prepare_reference
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model
from map_consistency_ros.io.occupancy_map import read_occupancy_map

ERROR_TOLERANCE = 0.5  # relative
HEADING_FLOOR_DEG = 0.5
START_TOLERANCE = 10  # scans
CHANGE_REACH = 1.0  # metres from a labelled edit's box


def evaluate_run(folder: Path, label: dict, surfaces: dict) -> dict:
    """One run judged and compared with its labels.

    Parameters
    ----------
    folder: the dataset folder.
    label: the run's labels (labels/NAME.json).
    surfaces: map name -> MapSurface, filled on demand (maps are shared by runs).

    Returns
    -------
    The row: run, outcome, labelled / found episodes, recall, error and start checks, false
    alarms, changes found, seconds.
    """
    if label['map'] not in surfaces:
        grid = read_occupancy_map(folder / label['map']).grid
        surfaces[label['map']] = MapSurface.of(prepare_reference(grid))
    log = read_carmen_log(folder / label['log'])
    scans = ScanSet.from_ranges(log.ranges, log.laser_poses, sensor_model(log))
    start = time.perf_counter()
    result = localize(scans, log.timestamps, surfaces[label['map']])
    seconds = time.perf_counter() - start
    translation = np.asarray(label['translation_error_m'])
    rotation = np.asarray(label['rotation_error_deg'])
    frozen_run = label['run'] == 'frozen'
    row = {'run': label['run'], 'outcome': result.outcome, 'labelled': len(label['episodes']),
           'found': len(result.episodes), 'frozen_found': len(result.frozen), 'recalled': 0,
           'error_ok': 0, 'start_ok': 0, 'false_alarms': 0, 'seconds': seconds,
           'errors': [], 'changes': len(result.changes),
           'minor': int(result.minor.sum())}
    for truth in label['episodes']:
        span = range(truth['first'], truth['last'] + 1)
        if frozen_run:
            hits = [f for f in result.frozen if int(f.scans[0]) <= truth['last']
                    and int(f.scans[-1]) >= truth['first']]
            if hits:
                row['recalled'] += 1
                row['start_ok'] += abs(int(hits[0].scans[0]) - truth['first']) <= START_TOLERANCE
            continue
        hits = [e for e in result.episodes
                if e.first <= truth['last'] and e.last >= truth['first']]
        if not hits:
            continue
        row['recalled'] += 1
        found = hits[0]
        true_position = float(np.median(translation[span]))
        true_heading = float(np.median(rotation[span]))
        heading = abs(math.degrees(found.heading_error))
        position_ok = abs(found.position_error - true_position) <= ERROR_TOLERANCE * true_position
        heading_ok = abs(heading - true_heading) <= max(ERROR_TOLERANCE * true_heading,
                                                        HEADING_FLOOR_DEG)
        row['error_ok'] += position_ok and heading_ok
        row['start_ok'] += abs(found.first - truth['first']) <= START_TOLERANCE
        row['errors'].append((round(found.position_error, 3), round(true_position, 3),
                              round(heading, 2), round(true_heading, 2), found.first,
                              truth['first'], found.last, truth['last']))
    if frozen_run:
        row['error_ok'] = '-'  # a frozen estimate has no one error: it grows as the robot goes
    for found in result.episodes:
        if not any(found.first <= t['last'] and found.last >= t['first']
                   for t in label['episodes']):
            row['false_alarms'] += 1
    if not label['episodes'] and result.outcome == 'mislocalized':
        row['false_alarms'] = max(row['false_alarms'], 1)
    if 'changes' in label:
        near = 0
        for edit in label['changes']:
            x0, y0, x1, y1 = edit['box_m']
            for change in result.changes:
                dx = max(x0 - change.x, 0.0, change.x - x1)
                dy = max(y0 - change.y, 0.0, change.y - y1)
                if math.hypot(dx, dy) <= CHANGE_REACH:
                    near += 1
                    break
        row['edits'] = f"{near}/{len(label['changes'])}"
    return row


def main(argv: list[str] | None = None) -> int:
    """Print the table of every run of the datasets under FOLDER.

    Parameters
    ----------
    argv: the command line (None: sys.argv).

    Returns
    -------
    0.
    """
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('folder', type=Path, help='output folder of localization_data')
    parser.add_argument('--datasets', nargs='+', default=['intel', 'fr079'])
    args = parser.parse_args(argv)
    print(f"{'dataset':8} {'run':16} {'outcome':14} {'lab':>3} {'fnd':>3} {'rec':>3} "
          f"{'err':>3} {'sta':>3} {'FA':>3} {'chg':>4} {'minor':>5} {'edits':>5} {'s':>5}  "
          'found (m, deg) vs label, first/last vs label')
    for dataset in args.datasets:
        folder = args.folder / dataset
        surfaces: dict = {}
        for path in sorted((folder / 'labels').glob('*.json')):
            label = json.loads(path.read_text())
            row = evaluate_run(folder, label, surfaces)
            print(f"{dataset:8} {row['run']:16} {row['outcome']:14} {row['labelled']:3} "
                  f"{row['found'] + row['frozen_found']:3} {row['recalled']:3} "
                  f"{row['error_ok']:>3} {row['start_ok']:3} {row['false_alarms']:3} "
                  f"{row['changes']:4} {row['minor']:5} {row.get('edits', '-'):>5} "
                  f"{row['seconds']:5.1f}  "
                  f"{row['errors']}", flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
