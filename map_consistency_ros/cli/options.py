"""Command-line options shared by the subcommands that run the consistency test."""
from __future__ import annotations

import argparse
import math

import dataclasses

from map_consistency_ros.core.consistency import ConsistencyParameters
from map_consistency_ros.core.explanation import ExplanationSettings

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


def _field_help(field: dataclasses.Field) -> str:
    metadata = field.metadata
    unit = f' [{metadata["unit"]}]' if metadata.get('unit') else ''
    bounds = metadata.get('range')
    span = f', {bounds[0]:g} to {bounds[1]:g}' if bounds else ''
    return f'{metadata["description"]}{unit} (default %(default)s{span})'


def add_verdict_arguments(parser: argparse.ArgumentParser) -> None:
    """The second stage (misalignment or change), one option per ExplanationSettings field."""
    group = parser.add_argument_group('verdict: misalignment or change')
    for field in dataclasses.fields(ExplanationSettings):
        flag = '--' + field.name.replace('_', '-')
        if field.type in ('bool', bool):
            group.add_argument(flag, action='store_true', help=_field_help(field))
        else:
            kind = int if isinstance(field.default, int) else float
            group.add_argument(flag, type=kind, default=field.default, help=_field_help(field))


def explanation_from_args(args: argparse.Namespace) -> ExplanationSettings:
    """ExplanationSettings from the parsed options (ValueError names a bad one)."""
    return ExplanationSettings(**{field.name: getattr(args, field.name)
                                  for field in dataclasses.fields(ExplanationSettings)})
