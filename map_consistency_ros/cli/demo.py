"""Replay the demo bag bundled with the package through the live monitor.

The demo bag holds the first 290 scans of the Intel Research Lab with their corrected poses
(/scan, /trajectory, /constraints, as a SLAM stack publishes them). The replay feeds them to
the same monitor the node runs and writes report.json, map.png, psi.png and pairs.csv into
--output.
"""
from __future__ import annotations

import argparse
from importlib import resources
from pathlib import Path

from map_consistency_ros.cli import main as cli_main

DEMO_BAG = 'intel_demo.mcap'


def demo_bag_path() -> Path:
    """Path of the bundled demo bag inside the installed package."""
    return Path(str(resources.files('map_consistency_ros') / 'data' / DEMO_BAG))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--output', type=Path, default=Path('out/demo'),
                        help='folder for the report and figures (default %(default)s)')
    parser.add_argument('--quiet', action='store_true', help='no progress bar')


def run(args: argparse.Namespace) -> int:
    out = args.output
    replay = ['replay', str(demo_bag_path()), '--report', str(out / 'report.json'),
              '--plot', str(out / 'map.png'), '--stats-plot', str(out / 'psi.png'),
              '--pairs-csv', str(out / 'pairs.csv')]
    replay_args = cli_main.build_parser('replay').parse_args(replay + (['--quiet'] if args.quiet else []))
    return replay_args.run(replay_args)
