"""Command-line options shared by the subcommands that run the consistency test."""
from __future__ import annotations

import argparse
import math

from map_consistency_ros.core.consistency import ConsistencyParameters

_DEFAULTS = ConsistencyParameters()


def add_test_arguments(parser: argparse.ArgumentParser) -> None:
    """Confidence levels and robustifications of the statistical test."""
    group = parser.add_argument_group('statistical test')
    group.add_argument('--alpha', type=float, default=_DEFAULTS.alpha,
                       help='level of the pairwise test (default %(default)s)')
    group.add_argument('--binomial-alpha', type=float, default=_DEFAULTS.binomial_alpha,
                       help="level of the cascaded per-scan test, the paper's alpha' "
                            '(default %(default)s)')
    group.add_argument('--failure-probability', type=float,
                       default=_DEFAULTS.failure_probability,
                       help='probability that one pairwise test fails by chance '
                            '(default %(default)s)')
    group.add_argument('--local-alpha', type=float, default=_DEFAULTS.local_alpha,
                       help='level used to fit each scan\'s noise scale on its temporal '
                            'neighbours (default %(default)s)')
    group.add_argument('--local-window', type=int, default=_DEFAULTS.local_window,
                       help='temporal neighbours that fit a scan\'s noise scale '
                            '(default %(default)s)')
    group.add_argument('--min-points', type=int, default=_DEFAULTS.min_points,
                       help='pairs with fewer inconsistent end points are not tested '
                            '(default %(default)s)')
    group.add_argument('--trim', type=int, default=_DEFAULTS.trim_largest,
                       help='largest distances of a pair dropped before its test '
                            '(default %(default)s)')
    group.add_argument('--flag-window', type=int, default=_DEFAULTS.flag_window,
                       help='keep a flagged scan only if another flagged scan is within this '
                            'many indices; 0 keeps all (default %(default)s)')


def add_sensor_arguments(parser: argparse.ArgumentParser) -> None:
    """Beam geometry where the input does not state it."""
    group = parser.add_argument_group('sensor')
    group.add_argument('--max-range', type=float, default=None, metavar='METRES',
                       help='usable range: longer readings count as free space up to it and are '
                            'not tested (default 8, capped by the maximum the log states)')
    add_fov_argument(group)
    group.add_argument('--range-min', type=float, default=0.0, metavar='METRES',
                       help='readings at or below this are invalid (default %(default)s)')


def add_fov_argument(parser) -> None:
    """--fov in degrees, for logs that do not state their beam angles (parser or group)."""
    parser.add_argument('--fov', type=float, default=None, metavar='DEGREES',
                        help='field of view of logs that do not state their beam angles '
                             '(default: PARAM laser_front_laser_resolution, else 180)')


def fov_radians(args: argparse.Namespace) -> float | None:
    return None if args.fov is None else math.radians(args.fov)


def parameters_from_args(args: argparse.Namespace) -> ConsistencyParameters:
    """ConsistencyParameters from the parsed options (ValueError names a bad one)."""
    return ConsistencyParameters(
        alpha=args.alpha, local_alpha=args.local_alpha,
        failure_probability=args.failure_probability, binomial_alpha=args.binomial_alpha,
        local_window=args.local_window, min_points=args.min_points,
        trim_largest=args.trim, flag_window=args.flag_window)
