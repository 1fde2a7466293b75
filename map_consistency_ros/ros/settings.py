"""The node's parameter file and parameter table, generated (no rclpy import here).

Every node parameter is a field of one of the settings groups of the configuration
(core/configuration.py, `GROUPS`); the node declares them, replay --params-file reads the same
file, and config/map_consistency.yaml is their defaults: regenerate it with

    python -m map_consistency_ros.ros.settings > config/map_consistency.yaml

and the table of docs/node.md with `--markdown`.
"""
from __future__ import annotations

import sys

from map_consistency_ros.core.configuration import GROUPS
from map_consistency_ros.core.parameters import markdown_table, yaml_document

_HEADER = '''Parameters of the map_consistency node at their defaults (docs/node.md). Generated from
the settings dataclasses: python -m map_consistency_ros.ros.settings > config/map_consistency.yaml
Load with  map_consistency_node --ros-args --params-file config/map_consistency.yaml
or         map-consistency replay BAG --params-file config/map_consistency.yaml
"/**" applies them whatever the node is renamed to. Integers are accepted for floats.'''

# (title, settings class) in the order of the parameter file
_TITLED = tuple((group.title, group.settings) for group in GROUPS)


def parameter_file() -> str:
    """The node's parameter file.

    Returns
    -------
    The text of config/map_consistency.yaml: every parameter at its default, by group.
    """
    return yaml_document(_TITLED, _HEADER)


def parameter_table() -> str:
    """The parameter table of docs/node.md.

    Returns
    -------
    The Markdown table of every parameter, by group.
    """
    return markdown_table(_TITLED)


if __name__ == '__main__':
    sys.stdout.write(parameter_table() if sys.argv[1:] == ['--markdown'] else parameter_file())
