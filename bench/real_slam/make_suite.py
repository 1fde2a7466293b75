"""Regenerate data/real_slam/: maps of Intel and Freiburg 079 made by MRPT's SLAM, labelled.

Needs MRPT's apps and headers (Debian/Ubuntu: `apt-get install mrpt-apps mrpt-common
libmrpt-obs-dev g++`); the package itself never needs MRPT. Stages, each reading what the
previous one wrote in --work (default /tmp/real_slam_work):

  rawlog   raw bag -> text scans -> MRPT rawlog (bench/real_slam/mrpt_io.cpp, compiled here),
           one odometry increment and one time-stamped scan per raw scan
  slam     icp-slam / rbpf-slam on each rawlog (one process at a time, nice 10, time limit)
  convert  each run's keyframes (the scans its final simplemap holds, matched to raw scans by
           stamp) -> data/real_slam/<run>.log.gz; for the runs marked full_density every raw
           scan too -> <run>_full.log.gz
  label    relation errors (Kuemmerle et al. 2009) and a PNG of the points per map ->
           data/real_slam/labels.json and data/real_slam/png/
  calibrate  the same errors for the corrected reference logs, whole and thinned to keyframes
           as the SLAM runs keep them -> labels.json "reference" (grounds the thresholds)

  PYTHONPATH=. python bench/real_slam/make_suite.py --stages rawlog slam convert label calibrate

All twelve runs took about 61 min of MRPT time on a loaded 2-core machine (Intel with 30
particles alone 21 min, see labels.json slam_seconds). RBPF draws random samples, so a rerun
need not give identical maps.
"""
from __future__ import annotations

import argparse
import gzip
import json
import math
import os
import re
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from map_consistency_ros.core.geometry import se2
from map_consistency_ros.io.carmen import read_carmen_log
from map_consistency_ros.io.datasets import RawBag, match_scans, read_raw_bag, read_relations

REPO = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent
DATA = Path(os.environ.get('MAP_CONSISTENCY_DATA', '/work/shared/data'))
OUT = REPO / 'data' / 'real_slam'
MRPT_CONFIGS = Path('/usr/share/mrpt/config_files')
LOGS = {'intel': DATA / 'intel', 'fr079': DATA / 'fr079'}
REFERENCE_LOGS = {'intel': DATA / 'intel' / 'intel.gfs.log',
                  'fr079': DATA / 'fr079' / 'freiburg-079-corrected.log.gz'}
# keyframe rules of the SLAM configs: (metres, degrees) of motion between insertions
KEYFRAME_RULES = {'icp-slam': (1.2, 45.0), 'rbpf-slam': (2.0, 30.0)}
# readings at or beyond this are the logs' no-return values (81.83 / 81.91 m)
NO_RETURN = 80.0
# loop relations: the two scans were taken this far apart in time
LOOP_GAP = 30.0
# label thresholds on the loop relations' largest errors (justified in README.md)
MAX_LOOP_TRANSLATION = 0.3
MAX_LOOP_ROTATION_DEG = 4.0
# relations used for the label: both scans this close (travel, turning) to a keyframe
KEYFRAME_GAP_M = 0.25
KEYFRAME_GAP_DEG = 5.0
# a largest error this close to the limit is named borderline in the reason
BORDERLINE_M = 0.05


@dataclass(frozen=True)
class Run:
    """One SLAM run: which log, which MRPT app, which shipped config, what it overrides."""

    name: str
    log: str
    app: str
    config: str
    overrides: dict = field(default_factory=dict)
    time_limit: float = 1800.0
    full_density: bool = False


ICP_CONFIG = 'icp-slam/icp-slam_demo_classic.ini'
RBPF_CONFIG = 'rbpf-slam/gridmapping_RBPF_ICPbased_intel.ini'

RUNS = [
    Run('intel_icp', 'intel', 'icp-slam', ICP_CONFIG, full_density=True),
    Run('fr079_icp', 'fr079', 'icp-slam', ICP_CONFIG, full_density=True),
    Run('intel_rbpf_p1', 'intel', 'rbpf-slam', RBPF_CONFIG, {'sampleSize': 1}),
    Run('fr079_rbpf_p1', 'fr079', 'rbpf-slam', RBPF_CONFIG, {'sampleSize': 1}),
    Run('intel_rbpf_p5', 'intel', 'rbpf-slam', RBPF_CONFIG, {'sampleSize': 5}),
    Run('fr079_rbpf_p5', 'fr079', 'rbpf-slam', RBPF_CONFIG, {'sampleSize': 5}),
    Run('intel_rbpf_p10', 'intel', 'rbpf-slam', RBPF_CONFIG, {'sampleSize': 10}),
    Run('fr079_rbpf_p10', 'fr079', 'rbpf-slam', RBPF_CONFIG, {'sampleSize': 10}),
    Run('intel_rbpf_p15', 'intel', 'rbpf-slam', RBPF_CONFIG, {'sampleSize': 15},
        time_limit=3600.0),
    Run('fr079_rbpf_p15', 'fr079', 'rbpf-slam', RBPF_CONFIG, {'sampleSize': 15}),
    Run('fr079_rbpf_p30', 'fr079', 'rbpf-slam', RBPF_CONFIG, {'sampleSize': 30},
        full_density=True),
    # slowest: each step registers the scan against 30 growing point maps
    Run('intel_rbpf_p30', 'intel', 'rbpf-slam', RBPF_CONFIG, {'sampleSize': 30},
        time_limit=3600.0, full_density=True),
]

# what every run overrides: no windows, no per-step images or 3D scenes
HEADLESS = {'SHOW_PROGRESS_IN_WINDOW': 0, 'SHOW_PROGRESS_3D_REAL_TIME': 0, 'SAVE_3D_SCENE': 0,
            'SAVE_MAP_IMAGES': 0, 'LOG_FREQUENCY': 1000000, 'SAVE_POSE_LOG': 0,
            'CAMERA_3DSCENE_FOLLOWS_ROBOT': 0, 'SHOW_LASER_SCANS_3D': 0, 'verbosity_level': 'INFO'}


def beam_geometry(beams: int) -> tuple[float, float]:
    """(start angle, increment): -90 deg and 180/K deg, the convention the package's CARMEN
    reader assumes for these logs' even beam counts (the bags' converter chose 180/(K-1))."""
    return -0.5 * math.pi, math.pi / beams


# ------------------------------------------------------------------------------------- rawlog

def build_helper(work: Path) -> Path:
    binary = work / 'mrpt_io'
    source = HERE / 'mrpt_io.cpp'
    if binary.exists() and binary.stat().st_mtime > source.stat().st_mtime:
        return binary
    includes = [f'-I{path}' for path in sorted(Path('/usr/include/mrpt').glob('*/include'))]
    libraries = [f'-lmrpt-{name}' for name in ('obs', 'poses', 'io', 'serialization', 'system',
                                              'core', 'math', 'rtti', 'containers', 'config',
                                              'bayes', 'tfest', 'random')]
    subprocess.run(['nice', '-n', '10', 'g++', '-O2', '-std=c++17', *includes, str(source),
                    '-o', str(binary), *libraries], check=True)
    return binary


def write_rawlog(name: str, bag: RawBag, work: Path, helper: Path) -> Path:
    odometry = bag.odometry_at(bag.scan_stamps)
    text = work / f'{name}_scans.txt'
    with open(text, 'w') as stream:
        for stamp, pose, ranges in zip(bag.scan_stamps, odometry, bag.scan_ranges):
            stream.write(f'{stamp:.6f} {pose[0]:.6f} {pose[1]:.6f} {pose[2]:.9f} {len(ranges)} '
                         + ' '.join(f'{r:.3f}' for r in ranges) + '\n')
    beams = bag.scan_ranges.shape[1]
    start, increment = beam_geometry(beams)
    aperture = increment * (beams - 1)  # MRPT spreads K beams over the aperture, ends included
    # MRPT centres the beams on the sensor's heading; turn it so the first beam is at `start`
    yaw = bag.laser_offset[2] + start + 0.5 * aperture
    rawlog = work / f'{name}.rawlog'
    subprocess.run([str(helper), 'rawlog', str(text), str(rawlog), f'{bag.laser_offset[0]:.6f}',
                    f'{bag.laser_offset[1]:.6f}', f'{yaw:.9f}', f'{aperture:.9f}',
                    f'{NO_RETURN}'], check=True)
    return rawlog


# --------------------------------------------------------------------------------------- slam

def write_config(run: Run, work: Path) -> Path:
    text = (MRPT_CONFIGS / run.config).read_text()
    values = {**HEADLESS, **run.overrides, 'rawlog_file': str(work / f'{run.log}.rawlog'),
              'logOutput_dir': str(work / run.name)}
    for key, value in values.items():
        pattern = re.compile(rf'^(\s*{re.escape(key)}\s*=).*$', re.MULTILINE)
        if pattern.search(text):
            text = pattern.sub(lambda match: f'{match.group(1)} {value}', text)
        else:  # the key belongs to the application section
            text = text.replace('[MappingApplication]', f'[MappingApplication]\n{key} = {value}',
                                1)
    path = work / f'{run.name}.ini'
    path.write_text(text)
    return path


def run_slam(run: Run, work: Path) -> dict:
    output = work / run.name
    if output.exists():
        shutil.rmtree(output)
    config = write_config(run, work)
    started = time.monotonic()
    with open(work / f'{run.name}.out', 'w') as log:
        try:
            process = subprocess.run(['nice', '-n', '10', run.app, str(config)], stdout=log,
                                     stderr=subprocess.STDOUT, timeout=run.time_limit,
                                     stdin=subprocess.DEVNULL)
            code = process.returncode
        except subprocess.TimeoutExpired:
            code = 'timeout'
    seconds = time.monotonic() - started
    simplemap = output / '_finalmap_.simplemap'
    return {'exit': code, 'seconds': round(seconds, 1), 'simplemap': simplemap.exists()}


# ------------------------------------------------------------------------------------ convert

def read_keyframes(run: Run, work: Path, helper: Path, bag: RawBag) -> tuple[np.ndarray, np.ndarray]:
    """(indices of the keyframes' raw scans, (N, 3) robot poses) from the final simplemap.

    RBPF keyframe poses are particle sets; the map is the highest-weight particle's (the
    particle whose map MRPT would use), not the weighted mean, which blends hypotheses.
    """
    dump = subprocess.run([str(helper), 'dump', str(work / run.name / '_finalmap_.simplemap')],
                          check=True, capture_output=True, text=True).stdout
    rows = np.array([[float(v) for v in line.split()] for line in dump.splitlines()])
    stamps = rows[:, 0]
    index = np.searchsorted(bag.scan_stamps, stamps)
    index = np.clip(index, 1, len(bag.scan_stamps) - 1)
    index = np.where(np.abs(bag.scan_stamps[index - 1] - stamps)
                     < np.abs(bag.scan_stamps[index] - stamps), index - 1, index)
    gap = np.abs(bag.scan_stamps[index] - stamps).max()
    if gap > 1e-4:
        raise RuntimeError(f'{run.name}: a keyframe is {gap:.6f} s from every raw scan')
    poses = rows[:, 4:7]
    return index, poses


def place_all(run: Run, work: Path, bag: RawBag, index: np.ndarray,
              poses: np.ndarray) -> np.ndarray:
    """(S, 3) robot pose of every raw scan.

    icp-slam logs its pose estimate at every step (one step per raw scan), equal to the
    keyframes' poses at the keyframes: that is used as it is. RBPF's per-step log is the
    particle mean at that time, before later resampling; there every scan gets its odometry
    corrected by the map-to-odometry transform of the final keyframes around it, interpolated
    in time (exact at the keyframes).
    """
    path = work / run.name / 'log_estimated_path.txt'
    if run.app == 'icp-slam' and path.exists():
        steps = np.loadtxt(path)
        if len(steps) == len(bag.scan_stamps):
            if np.abs(steps[index, 1:4] - poses).max() > 1e-5:
                raise RuntimeError(f'{run.name}: the step log disagrees with the keyframes')
            return steps[:, 1:4]
    odometry = bag.odometry_at(bag.scan_stamps)
    corrections = se2.compose(poses, se2.inverse(odometry[index]))
    times = bag.scan_stamps[index]
    unwrapped = corrections.copy()
    unwrapped[:, 2] = np.unwrap(unwrapped[:, 2])
    interpolated = np.stack([np.interp(bag.scan_stamps, times, unwrapped[:, axis])
                             for axis in range(3)], axis=1)
    placed = se2.compose(interpolated, odometry)
    placed[:, 2] = se2.wrap_angle(placed[:, 2])
    return placed


def write_carmen(path: Path, bag: RawBag, index: np.ndarray, robot: np.ndarray, note: str) -> None:
    """ROBOTLASER1 records (stated beam geometry) of raw scans `index` at robot poses `robot`;
    timestamps are the raw scans' stamps, so the relations' stamps find them."""
    beams = bag.scan_ranges.shape[1]
    start, increment = beam_geometry(beams)
    laser = se2.compose(robot, np.broadcast_to(bag.laser_offset, robot.shape))
    with gzip.open(path, 'wt', compresslevel=9) as stream:
        stream.write(f'# {note}\n')
        for scan, pose, laser_pose in zip(index, robot, laser):
            stamp = bag.scan_stamps[scan]
            ranges = ' '.join(f'{r:.2f}' for r in bag.scan_ranges[scan])
            stream.write(
                f'ROBOTLASER1 0 {start:.6f} {math.pi:.6f} {increment:.9f} {NO_RETURN:g} 0.01 0 '
                f'{beams} {ranges} 0 {laser_pose[0]:.4f} {laser_pose[1]:.4f} {laser_pose[2]:.6f} '
                f'{pose[0]:.4f} {pose[1]:.4f} {pose[2]:.6f} 0 0 0 0 0 '
                f'{stamp:.6f} real_slam {stamp:.6f}\n')


# -------------------------------------------------------------------------------------- label

def near_keyframes(bag: RawBag, index: np.ndarray) -> np.ndarray:
    """(S,) whether each raw scan is within KEYFRAME_GAP_M of travel and KEYFRAME_GAP_DEG of
    turning (raw odometry) of the keyframe before or after it."""
    odometry = bag.odometry_at(bag.scan_stamps)
    travel = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(odometry[:, :2], axis=0).T))])
    heading = np.unwrap(odometry[:, 2])
    following = np.searchsorted(index, np.arange(len(travel)))
    near = np.zeros(len(travel), bool)
    for neighbour in (following - 1, following):
        keyframe = index[np.clip(neighbour, 0, len(index) - 1)]
        near |= ((np.abs(travel - travel[keyframe]) <= KEYFRAME_GAP_M)
                 & (np.degrees(np.abs(heading - heading[keyframe])) <= KEYFRAME_GAP_DEG))
    return near


def relation_errors(relations: np.ndarray, stamps: np.ndarray, poses: np.ndarray,
                    near: np.ndarray) -> dict:
    """Kuemmerle et al.'s errors: per relation, estimated displacement between the poses at its
    two stamps against the relation's; translation (m) and |rotation| (deg).

    Summaries over all relations, over the loop relations (stamps more than LOOP_GAP s apart)
    and over the keyframe loop relations (loop relations whose two scans are `near` a
    keyframe), the label's basis: elsewhere the pose is the keyframes' correction interpolated
    along odometry, whose error alone (measured on the corrected reference logs thinned to the
    same keyframe spacing) reaches 0.4-1.0 m and 6.5 deg at the 95th percentile.
    """
    lookup = {round(s, 4): i for i, s in enumerate(stamps)}
    first = np.array([lookup[round(t, 4)] for t in relations[:, 0]])
    second = np.array([lookup[round(t, 4)] for t in relations[:, 1]])
    estimated = se2.compose(se2.inverse(poses[first]), poses[second])
    error = se2.compose(se2.inverse(relations[:, 2:5]), estimated)
    translation = np.hypot(error[:, 0], error[:, 1])
    rotation = np.degrees(np.abs(se2.wrap_angle(error[:, 2])))
    loop = np.abs(relations[:, 1] - relations[:, 0]) > LOOP_GAP

    def summary(mask):
        t, r = translation[mask], rotation[mask]
        return {'count': int(mask.sum()),
                'translation_m': {'mean': round(float(t.mean()), 4),
                                  'std': round(float(t.std()), 4),
                                  'p95': round(float(np.percentile(t, 95)), 4),
                                  'max': round(float(t.max()), 4)},
                'rotation_deg': {'mean': round(float(r.mean()), 3),
                                 'std': round(float(r.std()), 3),
                                 'p95': round(float(np.percentile(r, 95)), 3),
                                 'max': round(float(r.max()), 3)},
                'over_0.3m': int(np.sum(t > 0.3)), 'over_1m': int(np.sum(t > 1.0))}

    return {'all': summary(np.ones(len(relations), bool)), 'loop': summary(loop),
            'keyframe_loop': summary(loop & near[first] & near[second])}


def label(errors: dict) -> tuple[str, str]:
    basis = errors['keyframe_loop']
    t, r = basis['translation_m']['max'], basis['rotation_deg']['p95']
    stated = (f'{basis["count"]} keyframe loop relations: largest translational error {t:.3f} m '
              f'(limit {MAX_LOOP_TRANSLATION} m; {basis["over_0.3m"]} over 0.3 m, '
              f'{basis["over_1m"]} over 1 m), 95th-percentile rotational error {r:.2f} deg '
              f'(limit {MAX_LOOP_ROTATION_DEG} deg)')
    if abs(t - MAX_LOOP_TRANSLATION) <= BORDERLINE_M:
        stated = f'borderline ({BORDERLINE_M} m from the limit): {stated}'
    if t <= MAX_LOOP_TRANSLATION and r <= MAX_LOOP_ROTATION_DEG:
        return 'consistent', stated
    return 'inconsistent', stated


def render(path: Path, bag: RawBag, index: np.ndarray, robot: np.ndarray, title: str) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    beams = bag.scan_ranges.shape[1]
    start, increment = beam_geometry(beams)
    angles = start + increment * np.arange(beams)
    laser = se2.compose(robot, np.broadcast_to(bag.laser_offset, robot.shape))
    ranges = bag.scan_ranges[index].astype(float)
    valid = ranges < 20.0
    heading = laser[:, 2:3] + angles
    x = (laser[:, 0:1] + ranges * np.cos(heading))[valid]
    y = (laser[:, 1:2] + ranges * np.sin(heading))[valid]
    figure, axes = plt.subplots(figsize=(10, 10))
    axes.scatter(x, y, s=0.05, c='k', linewidths=0)
    axes.plot(robot[:, 0], robot[:, 1], 'r-', lw=0.4)
    axes.set_aspect('equal')
    axes.set_title(title)
    figure.savefig(path, dpi=150)
    plt.close(figure)


def thin(poses: np.ndarray, metres: float, degrees: float) -> np.ndarray:
    """Indices kept by an insertion rule: a pose once it moved `metres` or turned `degrees`
    from the last kept one (the first is kept)."""
    kept = [0]
    for i in range(1, len(poses)):
        step = se2.compose(se2.inverse(poses[kept[-1]][None]), poses[i][None])[0]
        if math.hypot(step[0], step[1]) >= metres or abs(math.degrees(step[2])) >= degrees:
            kept.append(i)
    return np.array(kept)


def calibrate(bags: dict) -> dict:
    """Relation errors of the corrected reference logs (consistent maps), whole and thinned
    by each SLAM's keyframe rule, placed and measured exactly as the SLAM maps are."""
    reference = {}
    for name, bag in bags.items():
        log = read_carmen_log(REFERENCE_LOGS[name])
        index = match_scans(log, bag)
        relations = read_relations(LOGS[name] / f'{name}.relations')
        rules = {'whole': None, **KEYFRAME_RULES}
        for rule, thresholds in rules.items():
            kept = np.arange(len(index)) if thresholds is None else thin(log.robot_poses,
                                                                        *thresholds)
            run = Run(f'{name}_reference', name, 'reference', REFERENCE_LOGS[name].name)
            placed = place_all(run, Path('/nonexistent'), bag, index[kept],
                               log.robot_poses[kept])
            errors = relation_errors(relations, bag.scan_stamps, placed,
                                     near_keyframes(bag, index[kept]))
            reference[f'{name}/{rule}'] = {'keyframes': int(len(kept)), 'relation_errors': errors,
                                           'label': label(errors)[0]}
            print(f'reference {name} {rule}: {label(errors)[1]}', flush=True)
    return reference


# ---------------------------------------------------------------------------------------- main

def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--stages', nargs='+', default=['rawlog', 'slam', 'convert', 'label'],
                        choices=['rawlog', 'slam', 'convert', 'label', 'calibrate'])
    parser.add_argument('--runs', nargs='*', default=None, help='run names (default: all)')
    parser.add_argument('--work', type=Path, default=Path('/tmp/real_slam_work'))
    args = parser.parse_args(argv)
    runs = [run for run in RUNS if args.runs is None or run.name in args.runs]
    args.work.mkdir(parents=True, exist_ok=True)
    OUT.mkdir(parents=True, exist_ok=True)
    helper = build_helper(args.work)
    bags = {name: read_raw_bag(LOGS[name] / f'{name}.orig.bag') for name in {r.log for r in runs}}
    if 'rawlog' in args.stages:
        for name, bag in bags.items():
            write_rawlog(name, bag, args.work, helper)
    status_path = args.work / 'slam_status.json'
    status = json.loads(status_path.read_text()) if status_path.exists() else {}
    if 'slam' in args.stages:
        for run in runs:
            status[run.name] = run_slam(run, args.work)
            print(run.name, status[run.name], flush=True)
            status_path.write_text(json.dumps(status, indent=1))
    labels_path = OUT / 'labels.json'
    labels = json.loads(labels_path.read_text()) if labels_path.exists() else {'maps': {}}
    for run in runs:
        if not status.get(run.name, {}).get('simplemap'):
            print(f'{run.name}: no final map, skipped', file=sys.stderr)
            continue
        bag = bags[run.log]
        index, poses = read_keyframes(run, args.work, helper, bag)
        placed = place_all(run, args.work, bag, index, poses)
        settings = {'app': run.app, 'config': run.config, 'overrides': run.overrides,
                    'mrpt': '2.5.8 (Debian bookworm)'}
        variants = {run.name: (index, poses)}
        if run.full_density:
            variants[f'{run.name}_full'] = (np.arange(len(bag.scan_stamps)), placed)
        for name, (scans, robot) in variants.items():
            if 'convert' in args.stages:
                write_carmen(OUT / f'{name}.log.gz', bag, scans, robot,
                             f'{run.log} mapped by MRPT {run.app} ({run.config}, {run.overrides}); '
                             f'{"every raw scan" if name.endswith("_full") else "keyframes"}')
            if 'label' in args.stages:
                errors = relation_errors(read_relations(LOGS[run.log] / f'{run.log}.relations'),
                                         bag.scan_stamps, placed, near_keyframes(bag, index))
                verdict, reason = label(errors)
                (OUT / 'png').mkdir(exist_ok=True)
                render(OUT / 'png' / f'{name}.png', bag, scans, robot,
                       f'{name}: {verdict}')
                labels['maps'][name] = {
                    'file': f'{name}.log.gz', 'log': run.log, 'slam': settings,
                    'scans': int(len(scans)), 'density': 'full' if name.endswith('_full')
                    else 'keyframes', 'slam_seconds': status[run.name]['seconds'],
                    'relation_errors': errors, 'label': verdict, 'reason': reason,
                    'borderline': reason.startswith('borderline')}
                print(name, verdict, reason, flush=True)
    if 'calibrate' in args.stages:
        labels['reference'] = calibrate({name: bags.get(name) or read_raw_bag(
            LOGS[name] / f'{name}.orig.bag') for name in LOGS})
    if 'label' in args.stages or 'calibrate' in args.stages:
        labels['rule'] = (
            f'consistent when, over the keyframe loop relations (stamps > {LOOP_GAP:g} s apart, '
            f'both scans within {KEYFRAME_GAP_M} m of travel and {KEYFRAME_GAP_DEG:g} deg of '
            f'turning of a keyframe), the largest translational error is <= '
            f'{MAX_LOOP_TRANSLATION} m and the 95th-percentile rotational error <= '
            f'{MAX_LOOP_ROTATION_DEG:g} deg; errors per Kuemmerle et al. 2009 on the map\'s robot '
            'poses at the relations\' raw-scan stamps (see README.md)')
        labels_path.write_text(json.dumps(labels, indent=1, sort_keys=True) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
