"""`map-consistency`: offline consistency checks, DCS tuning, bag replay and conversion.

Each subcommand lives in its own module of this package with `add_arguments(parser)` and
`run(args) -> int`. Exit codes: 0 consistent (or success), 1 inconsistent, 2 bad input.
"""
from __future__ import annotations

import argparse
import importlib
import importlib.machinery
import importlib.util
import sys
from importlib.metadata import PackageNotFoundError, version

from map_consistency_ros.io.errors import InputError

EXIT_BAD_INPUT = 2

# (subcommand, module, one-line help)
SUBCOMMANDS = [
    ('check', 'check', 'test a CARMEN log (scans at the logged poses) for consistency'),
    ('demo', 'demo', 'replay the demo bag bundled with the package (Intel lab, 290 scans)'),
    ('replay', 'replay', 'a ROS 1 / ROS 2 bag through the live monitor: the verdict'),
    ('convert', 'convert', 'CARMEN log -> rosbag2 with /scan, /trajectory, /constraints'),
    ('evaluate', 'evaluate', 'compare the test with the Hähnel baseline on a labelled suite of real maps'),
    ('tune', 'tune', 'find the DCS parameter Phi giving the most consistent map of a pose graph'),
    ('batch', 'batch', 'many logs, graphs and bags into one table, locally or on a Dask cluster'),
]


def _version() -> str:
    try:
        return version('map_consistency_ros')
    except PackageNotFoundError:  # run from a source tree that was never installed
        return 'unknown (not installed)'


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser of every subcommand, or only `command`'s options with the others listed: their
    modules (numpy, numba, scipy, matplotlib, rosbags behind them) are then not imported."""
    parser = argparse.ArgumentParser(
        prog='map-consistency',
        description=__doc__.split('\n\n')[0],
        epilog='Exit codes: 0 consistent / success, 1 inconsistent map, 2 bad input. '
               'The live ROS 2 node is a separate command: map_consistency_node --ros-args '
               '--params-file config/map_consistency.yaml (topics, services, parameters: '
               'docs/node.md). Every subcommand takes --help.',
    )
    parser.add_argument('--version', action='version', version=f'%(prog)s {_version()}')
    commands = parser.add_subparsers(dest='command', metavar='COMMAND', required=True)
    for name, module_name, help_text in SUBCOMMANDS:
        if command is not None and name != command:
            commands.add_parser(name, help=help_text)
            continue
        module = importlib.import_module(f'map_consistency_ros.cli.{module_name}')
        sub = commands.add_parser(name, help=help_text, description=module.__doc__,
                                  formatter_class=argparse.RawDescriptionHelpFormatter)
        module.add_arguments(sub)
        sub.set_defaults(run=module.run)
    return parser


def _spare_numba_the_scipy_linalg_import() -> None:
    """Load scipy.linalg.cython_blas by itself, before numba's first compilation imports it.

    Numba checks at that compilation whether BLAS is there by importing
    scipy.linalg.cython_blas, which runs all of scipy.linalg first (scipy's array-API layer,
    numpy.f2py, docstring parsing), though no kernel here calls BLAS: the first call of a
    cached kernel took a median 0.47 s that way and 0.25 s after this function (2026-12-04).
    The module needs nothing from its package, so it is loaded alone from the same file and
    found by name (numba's BLAS calls, `from scipy.linalg import cython_blas`), not as an
    attribute of scipy.linalg, which still imports normally where it is used (tune). Any
    import error leaves the import to numba.
    """
    name = 'scipy.linalg.cython_blas'
    if name in sys.modules or 'scipy.linalg' in sys.modules:
        return
    try:
        package = importlib.util.find_spec('scipy.linalg')  # imports scipy, not scipy.linalg
        spec = importlib.machinery.PathFinder.find_spec(name, package.submodule_search_locations)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    except (ImportError, AttributeError):  # no scipy, or a layout without this file
        sys.modules.pop(name, None)


def _command_of(argv: list[str]) -> str:
    """The subcommand named on the command line ('' for none: only the overview is needed)."""
    return next((argument for argument in argv if not argument.startswith('-')), '')


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser(_command_of(argv)).parse_args(argv)
    _spare_numba_the_scipy_linalg_import()
    try:
        return args.run(args)
    except InputError as error:
        print(f'map-consistency {args.command}: {error}', file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as error:
        print(f'map-consistency {args.command}: {error.filename or ""}: {error.strerror or error}',
              file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print('interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
