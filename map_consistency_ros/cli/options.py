"""Command-line options built from the parameters of the settings dataclasses.

`add_parameter_arguments` turns each parameter (core/parameters.py) into `--name-with-dashes`
with its description, unit, range and default in the help; only options given on the command
line land in the namespace, so they can override a parameter file (`parameter_values`).
"""
from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from typing import Any

from map_consistency_ros.core.configuration import Configuration
from map_consistency_ros.core.consistency import ConsistencyParameters
from map_consistency_ros.core.parameters import ParameterSpec, specs
from map_consistency_ros.core.verdict import ExplanationSettings
from map_consistency_ros.io.errors import InputError


def option_name(name: str) -> str:
    """The command-line option of a parameter.

    Parameters
    ----------
    name: the parameter's name (snake_case).

    Returns
    -------
    '--' and the name with dashes for underscores: alpha_min -> --alpha-min.
    """
    return '--' + name.replace('_', '-')


def _add(group, spec: ParameterSpec) -> None:
    default = spec.default if spec.kind is not tuple else ' '.join(f'{v:g}' for v in spec.default)
    help_text = f'{spec.help}; default {default!s}'.replace('%', '%%')
    common = dict(dest=spec.name, default=argparse.SUPPRESS, help=help_text)
    if spec.kind is bool:
        group.add_argument(option_name(spec.name), action=argparse.BooleanOptionalAction,
                           **common)
    elif spec.kind is tuple:
        group.add_argument(option_name(spec.name), type=float, nargs=len(spec.default),
                           metavar='V', **common)
    else:
        metavar = None if spec.choices else (spec.unit.upper() or
                                              ('N' if spec.kind is int else 'VALUE'))
        group.add_argument(option_name(spec.name), type=spec.kind,
                           choices=spec.choices or None, metavar=metavar, **common)


def add_parameter_arguments(parser, settings_class: type, title: str,
                            only: Sequence[str] | None = None,
                            skip: Sequence[str] = ()) -> None:
    """One option per parameter of `settings_class` (all, or those in `only`) in a group.

    Parameters
    ----------
    parser: the parser to add the group to.
    settings_class: a settings dataclass whose parameters (core/parameters.py) become options.
    title: the group's title in the help.
    only: the names of the parameters to add; None: every one.
    skip: names of parameters left out (the command sets them itself, or has an option of
        that name already).
    """
    group = parser.add_argument_group(title)
    for spec in specs(settings_class):
        if (only is None or spec.name in only) and spec.name not in skip:
            _add(group, spec)


def parameter_values(args: argparse.Namespace, base: dict[str, Any] | None = None
                     ) -> dict[str, Any]:
    """`base` (e.g. a parameter file's values) overridden by the options given.

    Parameters
    ----------
    args: parsed options; a parameter's option is in it only when given, every other option
        always.
    base: the values under the options; None: none.

    Returns
    -------
    A new dict name -> value: `base`, then every attribute of `args`.
    """
    values = dict(base or {})
    values.update(vars(args))
    return values


def add_test_arguments(parser: argparse.ArgumentParser) -> None:
    """Confidence levels and robustifications of the statistical test.

    Parameters
    ----------
    parser: the parser to add them to, as the group 'statistical test'.
    """
    add_parameter_arguments(parser, ConsistencyParameters, 'statistical test')


def add_verdict_arguments(parser: argparse.ArgumentParser) -> None:
    """The second stage of the verdict: misalignment or change.

    Parameters
    ----------
    parser: the parser to add them to, as the group 'verdict: misalignment or change'.
    """
    add_parameter_arguments(parser, ExplanationSettings, 'verdict: misalignment or change')


def add_sensor_arguments(parser: argparse.ArgumentParser) -> None:
    """Beam geometry where the input does not state it: --max-range, --fov, --range-min.

    Parameters
    ----------
    parser: the parser to add them to, as the group 'sensor'.
    """
    group = parser.add_argument_group('sensor')
    group.add_argument('--max-range', type=float, default=None, metavar='METRES',
                       help='usable range: longer readings count as free space up to it and are '
                            'not tested (default 8, capped by the maximum the log states)')
    add_fov_argument(group)
    group.add_argument('--range-min', type=float, default=0.0, metavar='METRES',
                       help='readings at or below this are invalid (default %(default)s)')


def check_sensor_options(args: argparse.Namespace) -> None:
    """Refuse sensor options no scanner has, naming the option (not the class they end in).

    Parameters
    ----------
    args: parsed options of `add_sensor_arguments` (max_range None when not given).

    Returns
    -------
    None. InputError ('options: --max-range must be positive, got -3') for a --max-range that
    is not a positive number, a --range-min that is negative or not below --max-range, or a
    --fov outside (0, 360] degrees.
    """
    max_range, range_min, fov = args.max_range, args.range_min, getattr(args, 'fov', None)
    if max_range is not None and not (math.isfinite(max_range) and max_range > 0):
        raise InputError('options', f'--max-range must be positive, got {max_range:g}')
    if not (math.isfinite(range_min) and range_min >= 0):
        raise InputError('options', f'--range-min must be zero or positive, got {range_min:g}')
    if max_range is not None and range_min >= max_range:
        raise InputError('options', f'--range-min ({range_min:g}) must be below --max-range '
                                    f'({max_range:g})')
    if fov is not None and not (math.isfinite(fov) and 0 < fov <= 360):
        raise InputError('options', f'--fov must be in (0, 360] degrees, got {fov:g}')


def add_fov_argument(parser) -> None:
    """--fov in degrees, for logs that do not state their beam angles.

    Parameters
    ----------
    parser: the parser or argument group to add it to.
    """
    parser.add_argument('--fov', type=float, default=None, metavar='DEGREES',
                        help='field of view of logs that do not state their beam angles '
                             '(default: PARAM laser_front_laser_resolution, else 180)')


def fov_radians(args: argparse.Namespace) -> float | None:
    """The field of view given with --fov.

    Parameters
    ----------
    args: parsed options with `fov` (degrees, None when not given).

    Returns
    -------
    The field of view in radians; None when --fov was not given.
    """
    return None if args.fov is None else math.radians(args.fov)


def configuration(args: argparse.Namespace, groups: Sequence[str],
                  base: dict[str, Any] | None = None) -> Configuration:
    """The configuration of the parsed options over `base`.

    Parameters
    ----------
    args : parsed options (the parameter options of `add_parameter_arguments` among them)
    groups : the configuration's groups the command takes from its options ('consistency',
        'explanation', ...); the others keep their defaults (an option of the command may
        share a name with a parameter of a group it does not use: --max-range)
    base : values under the options (a parameter file's)

    Returns
    -------
    The configuration; ValueError names a bad value.
    """
    return Configuration.from_values(parameter_values(args, base), groups)
