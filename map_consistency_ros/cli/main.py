"""`map-consistency`: offline consistency checks, DCS tuning, bag replay and conversion.

Each subcommand lives in its own module of this package with `add_arguments(parser)` and
`run(args) -> int`. Exit codes (cli/exit_codes.py): 0 consistent (or success), 1 inconsistent,
2 bad input, 3 an internal error (a fault of this program, never a verdict: a pipeline must not
read it as "inconsistent"), 4 nothing to judge.
"""
from __future__ import annotations

import argparse
import importlib
import importlib.machinery
import importlib.util
import sys
import traceback
from pathlib import Path
from importlib.metadata import PackageNotFoundError, version

from map_consistency_ros.cli.exit_codes import EXIT_BAD_INPUT, EXIT_INTERNAL_ERROR
from map_consistency_ros.cli.exit_codes import HELP as EXIT_CODES
from map_consistency_ros.io.errors import InputError

_DEBUG_HELP = 'on an internal error (exit 3), print its traceback too'

# (subcommand, module, one-line help)
SUBCOMMANDS = [
    ('check', 'check', 'test a CARMEN log (scans at the logged poses) for consistency'),
    ('demo', 'demo', 'replay the demo bag bundled with the package (Intel lab, 290 scans)'),
    ('replay', 'replay', 'a ROS 1 / ROS 2 bag through the live monitor: the verdict'),
    ('convert', 'convert', 'CARMEN log -> rosbag2 with /scan, /trajectory, /constraints'),
    ('evaluate', 'evaluate', 'compare the test with the Hähnel baseline on a labelled suite of real maps'),
    ('tune', 'tune', 'find the DCS parameter Phi giving the most consistent map of a pose graph'),
    ('batch', 'batch', 'many logs, graphs and bags into one table, locally or on a Dask cluster'),
    ('localize', 'localize', "judge a localizer's poses against a fixed map (localization mode)"),
    ('warm-up', 'warm_up', 'compile the kernels into the cache once after installing'),
]


def package_version() -> str:
    """The installed package's version, for --version and the pages that say what made them.

    Returns
    -------
    The version string; 'unknown (not installed)' when run from a source tree that was never
    installed.
    """
    try:
        return version('map_consistency_ros')
    except PackageNotFoundError:  # run from a source tree that was never installed
        return 'unknown (not installed)'


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser of every subcommand, or only `command`'s options with the others listed: their
    modules (numpy, numba, scipy, matplotlib, rosbags behind them) are then not imported.

    Parameters
    ----------
    command: the subcommand whose options are needed; None: every subcommand's; a name that
        is none ('': no subcommand given): only the overview.

    Returns
    -------
    The parser of `map-consistency`. A parsed subcommand sets `run`, its module's run, and
    `inputs`, the names of its positional arguments.
    """
    parser = argparse.ArgumentParser(
        prog='map-consistency',
        description=__doc__.split('\n\n')[0],
        epilog=f'{EXIT_CODES} The live ROS 2 node is a separate command: map_consistency_node '
               '--ros-args --params-file config/map_consistency.yaml (topics, services, '
               'parameters: docs/node.md). Every subcommand takes --help.',
    )
    parser.add_argument('--version', action='version', version=f'%(prog)s {package_version()}')
    parser.add_argument('--debug', action='store_true', help=_DEBUG_HELP)
    commands = parser.add_subparsers(dest='command', metavar='COMMAND', required=True)
    for name, module_name, help_text in SUBCOMMANDS:
        if command is not None and name != command:
            commands.add_parser(name, help=help_text)
            continue
        module = importlib.import_module(f'map_consistency_ros.cli.{module_name}')
        sub = commands.add_parser(name, help=help_text, description=module.__doc__,
                                  epilog=EXIT_CODES,
                                  formatter_class=argparse.RawDescriptionHelpFormatter)
        module.add_arguments(sub)
        # global, and taken after the subcommand too (SUPPRESS: absent here leaves the global)
        sub.add_argument('--debug', action='store_true', default=argparse.SUPPRESS,
                         help=_DEBUG_HELP)
        # the positional arguments name the input in the line of an internal error
        sub.set_defaults(run=module.run, inputs=[action.dest for action in sub._actions
                                                 if not action.option_strings])
    return parser


def _spare_numba_the_scipy_linalg_import() -> None:
    """Load scipy.linalg.cython_blas by itself, before numba's first compilation imports it.

    Numba checks at that compilation whether BLAS is there by importing
    scipy.linalg.cython_blas, which runs all of scipy.linalg first (scipy's array-API layer,
    numpy.f2py, docstring parsing), though no kernel here calls BLAS: that import is most of
    the first call of a cached kernel (docs/benchmarks.md, bench_check).
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
    """The `map-consistency` command: parse the arguments and run the subcommand.

    Parameters
    ----------
    argv: the arguments after the program name; None: sys.argv[1:].

    Returns
    -------
    The exit code: the subcommand's (0 consistent or success, 1 inconsistent, 4 nothing to
    judge); 2 for bad
    input (InputError, OSError: one line on stderr; argparse exits 2 itself on bad options);
    3 for an internal error (one line on stderr naming the input, the traceback with
    --debug); 130 when interrupted.
    """
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser(_command_of(argv)).parse_args(argv)
    _spare_numba_the_scipy_linalg_import()
    try:
        return args.run(args)
    except InputError as error:
        # one line, whatever a library put in the message: a pipeline greps it
        print(f'map-consistency {args.command}: {_one_line(error)}', file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as error:
        print(f'map-consistency {args.command}: {_named_path(args, error.filename)}: '
              f'{_one_line(error.strerror or error)}', file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print('interrupted', file=sys.stderr)
        return 130
    except Exception as error:  # noqa: BLE001 - any other exception is a fault of this program
        if args.debug:
            traceback.print_exc()
        print(f'map-consistency {args.command}: internal error{_on_input(args)}: '
              f'{type(error).__name__}: {_one_line(error)}', file=sys.stderr)
        return EXIT_INTERNAL_ERROR


def _on_input(args: argparse.Namespace) -> str:
    """' on INPUT' for the positional arguments of the subcommand ('' for none)."""
    names = []
    for dest in args.inputs:
        value = getattr(args, dest, None)
        names.extend(str(item) for item in (value if isinstance(value, list) else [value])
                     if item is not None)
    return f' on {" ".join(names)}' if names else ''


def _named_path(args: argparse.Namespace, filename) -> str:
    """The path of a file error, after the option that named it or whose folder holds it
    ('--plot out/map.png'): after the verdict, a bare path would not say which output failed."""
    if filename is None:
        return ''
    path = Path(filename)
    for dest, value in vars(args).items():
        if dest in args.inputs or not isinstance(value, (str, Path)) or dest == 'command':
            continue
        given = Path(value)
        if path == given or given in path.parents:
            return f'--{dest.replace("_", "-")} {filename}'
    return str(filename)


def _one_line(error: BaseException) -> str:
    return ' '.join(str(error).split()) or 'no message'


if __name__ == '__main__':
    sys.exit(main())
