"""The map's DiagnosticStatus: an honest level and the figures behind it."""
from __future__ import annotations

from dataclasses import dataclass

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

from map_consistency_ros.core.live import ScanCounts

STATUS_NAME = 'map_consistency: map'
# The key of each ScanCounts field: what became of every scan received (docs/node.md,
# Diagnostics; received == the sum of the others, core/live/_scan_counts.py)
SCAN_KEYS = {'received': 'scans received', 'keyframes': 'keyframes', 'folded': 'folded scans',
             'waiting': 'waiting scans', 'passed_over': 'passed-over scans',
             'lost_in_queue': 'scans lost in the queue',
             'pushed_out': 'scans pushed out of the buffer', 'unplaced': 'unplaced scans',
             'rejected': 'rejected scans', 'earlier_sessions': 'scans of earlier sessions'}


@dataclass(frozen=True)
class MonitorHealth:
    """What the node knows about its map and inputs at one instant."""

    buffered_scans: int
    overlapping_pairs: int
    tested_pairs: int
    failed_pairs: int
    inconsistent_scans: int
    unmatched_poses: int
    consistent: bool | None  # None before the first verdict
    update_latency: float | None  # seconds of the last update that changed the map
    phi: float | None  # tuned DCS Phi, None before a retune
    input_problems: int  # bad messages since start
    recent_problem: str  # the last bad message if it is recent, else ''
    seconds_since_input: float | None  # None when nothing arrived yet, on the node's clock
    stale_timeout: float
    queued_scans: int = 0  # received, not yet applied by the worker (the node is behind)
    # what became of every scan received, balanced; `keyframes` is this one's keyframes
    scans: ScanCounts = ScanCounts()
    middleware_lost: int = 0  # scans the middleware reported lost: never received
    gap_scans: int = 0  # scans missing from the stamp sequence (an estimate)
    # poses of this session's estimate whose scans never came (older than the newest scan)
    poses_without_scan: int = 0
    resets: int = 0
    last_reset: str = ''
    verdict: str = ''  # the summary line of both stages, '' before the first verdict
    misaligned_scans: int = 0
    misaligned_regions: int = 0
    changed_places: int = 0
    starting: bool = False  # the compiled kernels are still loading; inputs queue meanwhile
    start_failure: str = ''  # why the kernels failed to load: nothing is monitored
    # why the last explanation failed ('' after a success): the verdict shown is older
    explanation_failure: str = ''
    # the verdict is "nothing to judge": too few tested pairs (never OK, never consistent)
    nothing_to_judge: bool = False
    # keyframes of the map the verdict judged (its pair counts are that map's); None before
    judged_keyframes: int | None = None

    @property
    def keyframes(self) -> int:
        """Keyframes of the current map."""
        return self.scans.keyframes

    @property
    def loss(self) -> str:
        """What was lost since the last reset, '' when nothing was."""
        parts = []
        scans = self.scans
        if scans.lost:
            where = ', '.join(f'{count} {words}' for count, words in (
                (scans.lost_in_queue, "in the node's full queue"),
                (scans.pushed_out, 'pushed out of its full buffer before a pose came'),
                (scans.unplaced, 'without a pose around them')) if count)
            parts.append(f'{scans.lost} scans lost ({where})')
        if self.middleware_lost:
            parts.append(f'{self.middleware_lost} scans lost by the middleware')
        if self.poses_without_scan:
            parts.append(f'{self.poses_without_scan} keyframe poses name scans never received')
        return ', '.join(parts)


def not_monitoring(failure: str) -> str:
    """What the node says (log, diagnostics, services) when its kernels failed to load.

    Parameters
    ----------
    failure: why loading failed ('ExceptionName: message').

    Returns
    -------
    One line: 'not monitoring: loading the compiled kernels failed (<failure>)'.
    """
    return f'not monitoring: loading the compiled kernels failed ({failure})'


def status_level(health: MonitorHealth) -> tuple[bytes, str]:
    """The level of the map's status and its message.

    Parameters
    ----------
    health: what the node knows about its map and inputs now.

    Returns
    -------
    (level, message): ERROR when the node could not start, WARN while it starts, STALE
    without recent input, ERROR for an inconsistent map, WARN for no verdict yet, nothing to
    judge (too few tested pairs), lost input,
    a failed second stage or a recent bad message, OK otherwise.
    """
    if health.start_failure:
        return DiagnosticStatus.ERROR, (f'{not_monitoring(health.start_failure)}; '
                                        f'{health.queued_scans} scans queued unprocessed')
    if health.starting:
        received = ('nothing received yet' if health.seconds_since_input is None
                    else f'{health.queued_scans} scans queued')
        return DiagnosticStatus.WARN, f'starting: compiling the kernels or loading them from the cache ({received})'
    if health.seconds_since_input is None:
        return DiagnosticStatus.STALE, 'no scan or trajectory received yet'
    if health.seconds_since_input > health.stale_timeout:
        return DiagnosticStatus.STALE, (f'no input for {health.seconds_since_input:.1f} s '
                                        f'(stale after {health.stale_timeout:g} s)')
    problems = f'; {health.loss}' if health.loss else ''
    if health.explanation_failure:
        problems += f'; {health.explanation_failure}'
    if health.nothing_to_judge:
        return DiagnosticStatus.WARN, f'map {health.verdict}{problems}'
    if health.consistent is False:
        return DiagnosticStatus.ERROR, f'map {health.verdict}{problems}'
    if health.consistent is None:
        if health.keyframes:  # the first explanation runs, or failed
            return DiagnosticStatus.WARN, f'no verdict yet ({health.keyframes} scans){problems}'
        return DiagnosticStatus.WARN, (f'no keyframe yet: no trajectory pose matches a '
                                       f'scan{problems}')
    if problems:
        return DiagnosticStatus.WARN, f'map {health.verdict} ({health.keyframes} scans){problems}'
    if health.recent_problem:
        return DiagnosticStatus.WARN, f'map {health.verdict}; bad input: {health.recent_problem}'
    return DiagnosticStatus.OK, f'map {health.verdict} ({health.keyframes} scans)'


def _optional(value: float | None, scale: float = 1.0, digits: int = 3) -> str:
    return 'n/a' if value is None else f'{value * scale:.{digits}f}'


def map_status(health: MonitorHealth, hardware_id: str) -> DiagnosticStatus:
    """The DiagnosticStatus of the map with the design's key-values.

    Parameters
    ----------
    health: what the node knows about its map and inputs now.
    hardware_id: the status's hardware_id (the node's fully qualified name).

    Returns
    -------
    The status named STATUS_NAME, with the level and message of `status_level` and a
    key-value per figure of `health` ('n/a' for a figure not known yet).
    """
    level, message = status_level(health)
    values = {
        'ready': 'failed' if health.start_failure else ('no' if health.starting else 'yes'),
        **{key: str(getattr(health.scans, name)) for name, key in SCAN_KEYS.items()},
        'queued scans': str(health.queued_scans),
        'buffered scans': str(health.buffered_scans),
        'scans lost by the middleware': str(health.middleware_lost),
        'poses without scan': str(health.poses_without_scan),
        'judged keyframes': _optional(health.judged_keyframes, digits=0),
        'overlapping pairs': str(health.overlapping_pairs),
        'tested pairs': str(health.tested_pairs),
        'failed pairs': str(health.failed_pairs),
        'inconsistent scans': str(health.inconsistent_scans),
        'misaligned scans': str(health.misaligned_scans),
        'misaligned regions': str(health.misaligned_regions),
        'changed places': str(health.changed_places),
        'unmatched poses': str(health.unmatched_poses),
        'update latency (ms)': _optional(health.update_latency, 1e3, 1),
        'phi': _optional(health.phi, digits=6),
        'input problems': str(health.input_problems),
        'last input problem': health.recent_problem or 'none',
        'seconds since input': _optional(health.seconds_since_input, digits=1),
        'scans missing from stamps': str(health.gap_scans),
        'resets': str(health.resets),
        'last reset': health.last_reset or 'none',
        'second stage failure': health.explanation_failure or 'none',
    }
    return DiagnosticStatus(level=level, name=STATUS_NAME, message=message,
                            hardware_id=hardware_id,
                            values=[KeyValue(key=k, value=v) for k, v in values.items()])
