"""ROS 2 parameter files (`--params-file` YAML) as a dict of one node's parameters."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from map_consistency_ros.io.errors import InputError


def read_parameter_file(path: str | Path, node_name: str = 'map_consistency') -> dict[str, Any]:
    """The `ros__parameters` of `node_name` (or of the wildcard `/**`) in a ROS 2 parameter
    file, later entries overriding earlier ones as rcl does.

    Parameters
    ----------
    path: the YAML file, as given to `--ros-args --params-file`.
    node_name: the node whose entry is read, with or without a leading '/'; entries of other
        nodes are ignored.

    Returns
    -------
    Parameter name -> value as YAML gives it; nested mappings become dotted names
    ('a: {b: 1}' gives 'a.b'). Empty when the file has no entry for the node. Raises InputError
    for an unreadable file, a file that is not YAML or has no node names at the top, or a
    matching entry without a `ros__parameters` mapping.
    """
    import yaml
    path = Path(path)
    try:
        document = yaml.safe_load(path.read_text())
    except OSError as error:
        raise InputError(str(path), error.strerror or str(error)) from None
    except yaml.YAMLError as error:
        raise InputError(str(path), f'not YAML ({str(error).splitlines()[0]})') from None
    if not isinstance(document, dict):
        raise InputError(str(path), 'not a ROS 2 parameter file (no node names at the top)')
    values: dict[str, Any] = {}
    for key, entry in document.items():
        if str(key).lstrip('/') not in ('**', node_name):
            continue
        if not isinstance(entry, dict) or not isinstance(entry.get('ros__parameters'), dict):
            raise InputError(str(path), f'{key}: expected a ros__parameters mapping')
        values.update(_flatten(entry['ros__parameters']))
    return values


def _flatten(mapping: dict, prefix: str = '') -> dict[str, Any]:
    # nested mappings are dotted names in ROS 2
    flat = {}
    for key, value in mapping.items():
        name = f'{prefix}{key}'
        if isinstance(value, dict):
            flat.update(_flatten(value, name + '.'))
        else:
            flat[name] = value
    return flat
