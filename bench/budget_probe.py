"""Does the live verdict depend on the partner budget? Real logs streamed, against `check`.

    .venv/bin/python bench/budget_probe.py [--logs intel-native] [--cases corrected turn1 ...]
                                           [--budgets 50 30 300] [--loss 0.022]
                                           [--seeds 0 1 2]

Each map is a corrected log, or a copy with everything after half of its travel turned by 1, 2
or 5 degrees or shifted by 0.1 or 0.3 m (`evaluation/density.py`'s displacement). With
`--loss`, each seed drops that share of the scans at random, as the node loses some of a raw
stream under load (1-2 % of Intel at its native rate in `bench_node_load.py`). The kept scans
are streamed through the live pipeline (a Path of the poses every 10 scans, the node's
defaults but `max_partners`; 0: every overlapping pair) and the final snapshot explained, once
per budget; beside them, `check`'s path on the very same keyframes (every overlapping pair,
the batch test). Printed per map and budget: the verdict and each misaligned region (RMS
metres, keyframes, reference keyframes, pairs); where the verdicts differ, the pairs that
touch the regions found, how many failed and how many scans are flagged there, per budget and
in `check`.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the streamed logs of the node bench
from bench_node_load import DATA, LOGS as STREAMED, REPO  # noqa: E402

sys.path.insert(0, str(REPO))
LOGS = {**STREAMED,
        'fr101': DATA / 'carmen_corrected_extra' / 'freiburg-101-corrected.log.gz',
        'belgioioso': DATA / 'carmen_corrected_extra' / 'belgioioso-corrected.log.gz',
        'orebro': DATA / 'carmen_corrected_extra' / 'orebro-corrected.log.gz'}
CASES = {'corrected': (0.0, 0.0), 'turn1': (1.0, 0.0), 'turn2': (2.0, 0.0),
         'turn5': (5.0, 0.0), 'shift0.1': (0.0, 0.1), 'shift0.3': (0.0, 0.3)}


def stream(stamps, poses, ranges, model, keep: np.ndarray, budget: int):
    """The live pipeline after the kept scans and a Path every 10 scans: (verdict, config)."""
    from map_consistency_ros.core.configuration import Configuration
    from map_consistency_ros.core.live import KeyframeEstimate, Scan
    from map_consistency_ros.core.live.pipeline import LivePipeline
    config = Configuration.from_values({'max_partners': budget})
    pipeline = LivePipeline(config.consistency, config.monitor, config.feed, config.explanation)
    for k in range(stamps.size):
        if keep[k]:
            pipeline.apply(Scan(stamp=float(stamps[k]), ranges=ranges[k], model=model))
        if (k + 1) % 10 == 0 or k + 1 == stamps.size:
            pipeline.apply(KeyframeEstimate(stamps=stamps[:k + 1], poses=poses[:k + 1]))
    return pipeline.explain(pipeline.evaluate()), config


def describe(assessment) -> str:
    verdict = 'CONSISTENT' if assessment.consistent else 'INCONSISTENT'
    regions = '; '.join(
        f'{m.displacement:.3f} m, keyframes {m.scans.min()}-{m.scans.max()} ({m.scans.size}) '
        f'against {m.reference_scans.min()}-{m.reference_scans.max()}, {m.pairs} pairs'
        for m in assessment.misalignments)
    return verdict + (f': {regions}' if regions else '')


def evidence(result, low: int, high: int) -> str:
    """Pairs touching keyframes low..high, the failed ones, and the keyframes flagged there."""
    touching = ((result.pairs >= low) & (result.pairs <= high)).any(axis=1)
    flagged = np.count_nonzero(result.inconsistent[low:high + 1])
    return (f'{int(touching.sum())} pairs touch keyframes {low}-{high}, '
            f'{int((result.failed & touching).sum())} failed; {flagged} flagged there')


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--logs', nargs='+', choices=sorted(LOGS), default=['intel-native'])
    parser.add_argument('--cases', nargs='+', choices=list(CASES), default=['corrected'])
    parser.add_argument('--budgets', type=int, nargs='+', default=[50, 30, 300])
    parser.add_argument('--loss', type=float, default=0.0)
    parser.add_argument('--seeds', type=int, nargs='+', default=[0])
    args = parser.parse_args()

    from map_consistency_ros.core.consistency import check_consistency
    from map_consistency_ros.core.verdict import explain
    from map_consistency_ros.evaluation.density import displaced, pivot
    from map_consistency_ros.io.carmen import read_carmen_log, sensor_model

    agree = total = 0
    for name in args.logs:
        log = read_carmen_log(LOGS[name])
        model = sensor_model(log)
        order = np.argsort(log.timestamps, kind='stable')
        stamps, true_poses = log.timestamps[order], log.laser_poses[order]
        ranges = log.ranges[order]
        if not np.all(np.diff(stamps) > 0.0):  # Belgioioso and Orebro stamp every scan alike
            stamps = np.arange(stamps.size) * 0.2  # in file order, as a driver would
        start, centre = pivot(true_poses, stamps)
        for case in args.cases:
            poses, _ = displaced(true_poses, stamps, start, centre, *CASES[case])
            for seed in args.seeds if args.loss > 0.0 else [None]:
                keep = (np.ones(stamps.size, dtype=bool) if seed is None else
                        np.random.default_rng(seed).random(stamps.size) >= args.loss)
                label = f'{name} {case}' + ('' if seed is None else
                                            f', seed {seed}: {int((~keep).sum())} scans lost')
                print(label, flush=True)
                verdicts, results = {}, {}
                for budget in args.budgets:
                    verdict, config = stream(stamps, poses, ranges, model, keep, budget)
                    verdicts[budget], results[budget] = verdict.assessment, verdict.snapshot.result
                    print(f'  max_partners {budget:>4}: {verdict.snapshot.keyframe_count} '
                          f'keyframes, {describe(verdict.assessment)}', flush=True)
                batch = check_consistency(verdict.scans, config.consistency)
                expected = explain(verdict.scans, batch, config.explanation)
                print(f'  check on the same keyframes: {describe(expected)}', flush=True)
                same = [a.consistent == expected.consistent for a in verdicts.values()]
                agree, total = agree + sum(same), total + len(same)
                regions = [m for a in verdicts.values() for m in a.misalignments]
                if not all(same) and regions:
                    low = min(int(m.scans.min()) for m in regions)
                    high = max(int(m.scans.max()) for m in regions)
                    for budget, result in results.items():
                        print(f'    max_partners {budget:>4}: {evidence(result, low, high)}')
                    print(f'    check:             {evidence(batch, low, high)}', flush=True)
    print(f'verdicts as check gives them: {agree} of {total}')


if __name__ == '__main__':
    main()
