"""Parameters defined once: on the settings dataclasses, as field metadata.

A settings field declared with `parameter(...)` carries its description, unit, range and
allowed choices. From that one definition the node declares its ROS parameters, the CLI builds
its options, `config/map_consistency.yaml` is generated and every value from any of them is
checked (`settings_from_values`). The type of a parameter is its default's; an integer is
accepted where a float is expected (YAML writes `8` for 8.0), a bool never passes as a number.
"""
from __future__ import annotations

import difflib
import math
import textwrap
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import MISSING, dataclass, field, fields
from typing import Any

_META = 'parameter'


@dataclass(frozen=True)
class ParameterSpec:
    """One parameter: its name (the dataclass field's), default and documentation."""

    name: str
    default: Any
    description: str
    unit: str = ''
    bounds: tuple[float, float] | None = None  # inclusive
    choices: tuple[str, ...] = ()

    @property
    def kind(self) -> type:
        """bool, int, float, str or tuple (a fixed-length list of floats)."""
        return type(self.default)

    @property
    def help(self) -> str:
        """One line: description, unit, range or choices."""
        text = self.description + (f' ({self.unit})' if self.unit else '')
        if self.bounds is not None:
            text += f' [{self.bounds[0]:g}, {self.bounds[1]:g}]'
        if self.choices:
            text += f' [{" | ".join(self.choices)}]'
        return text

    def check(self, value: Any) -> Any:
        """The value in the parameter's type; ValueError naming the parameter otherwise."""
        value = _typed(self, value)
        if self.bounds is not None and not self.bounds[0] <= value <= self.bounds[1]:
            raise ValueError(f'{self.name}: {value!r} is outside [{self.bounds[0]:g}, '
                             f'{self.bounds[1]:g}]')
        if self.choices and value not in self.choices:
            raise ValueError(f'{self.name}: {value!r} is not one of {", ".join(self.choices)}')
        return value


def _type_name(value: Any) -> str:
    return {bool: 'a bool', int: 'an integer', float: 'a float', str: 'a string'}.get(
        type(value), f'a {type(value).__name__}')


def _typed(spec: ParameterSpec, value: Any) -> Any:
    expected = spec.kind
    if expected is tuple:
        if (not isinstance(value, (list, tuple)) or len(value) != len(spec.default)
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                           for v in value)):
            raise ValueError(f'{spec.name}: expected a list of {len(spec.default)} numbers, '
                             f'got {value!r}')
        values = tuple(float(v) for v in value)
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f'{spec.name}: values must be finite, got {value!r}')
        return values
    if expected is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)  # documented: integers stand for floats
    if type(value) is not expected:
        raise ValueError(f'{spec.name}: expected {_type_name(spec.default)}, got '
                         f'{_type_name(value)} {value!r}')
    if expected is float and not math.isfinite(value):
        raise ValueError(f'{spec.name}: must be finite, got {value!r}')
    return value


def parameter(default: Any, description: str, unit: str = '',
              bounds: tuple[float, float] | None = None,
              choices: Sequence[str] = ()) -> Any:
    """A dataclass field that is also a user-facing parameter (see the module docstring)."""
    metadata = {_META: dict(description=description, unit=unit, bounds=bounds,
                            choices=tuple(choices))}
    return field(default=default, metadata=metadata)


def specs(settings_class: type) -> list[ParameterSpec]:
    """The parameters of a settings dataclass, in field order (fields without metadata,
    e.g. nested settings, are not parameters)."""
    found = []
    for item in fields(settings_class):
        meta = item.metadata.get(_META)
        if meta is None or item.default is MISSING:
            continue
        found.append(ParameterSpec(name=item.name, default=item.default, **meta))
    return found


def settings_from_values(settings_class: type, values: Mapping[str, Any], **extra: Any):
    """An instance of `settings_class` from the values of its parameters (others in `values`
    are ignored; missing ones take their defaults). ValueError names a bad one."""
    chosen = {spec.name: spec.check(values[spec.name])
              for spec in specs(settings_class) if spec.name in values}
    return settings_class(**chosen, **extra)


def closest_name(name: str, names: Iterable[str]) -> str | None:
    """The valid name a misspelt one most likely meant, None when nothing is close."""
    names = list(names)
    # a shortened name ('trim' for trim_largest) first: a similarity ratio of short names
    # finds unrelated ones ('strict')
    containing = sorted((known for known in names if name in known), key=len)
    if containing:
        return containing[0]
    matches = difflib.get_close_matches(name, names, n=1, cutoff=0.6)
    return matches[0] if matches else None


def unknown_names(values: Iterable[str], known: Iterable[str]) -> list[str]:
    """One warning per unknown name, naming the closest valid one."""
    known = list(known)
    warnings = []
    for name in sorted(set(values) - set(known)):
        closest = closest_name(name, known)
        hint = f'; did you mean {closest}?' if closest else ''
        warnings.append(f'unknown parameter {name!r} ignored{hint}')
    return warnings


def _yaml_value(value: Any) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, str):
        return repr(value)
    if isinstance(value, tuple):
        return '[' + ', '.join(_yaml_value(v) for v in value) + ']'
    if isinstance(value, float):
        text = repr(value)
        if 'e' in text and '.' not in text:
            # YAML 1.1 (the ROS parser) reads 1e-06 as a string, 1.0e-06 as a float
            mantissa, exponent = text.split('e')
            text = f'{mantissa}.0e{exponent}'
        return text
    return str(value)


def yaml_document(groups: Sequence[tuple[str, type]], header: str) -> str:
    """A ROS parameter file of every parameter of `groups` (title, settings class) at its
    default, one comment line each."""
    lines = [f'# {line}' if line else '#' for line in header.splitlines()]
    lines += ['/**:', '  ros__parameters:']
    for title, settings_class in groups:
        lines.append(f'    # -- {title}')
        for spec in specs(settings_class):
            lines += [f'    # {line}' for line in textwrap.wrap(spec.help, 88)]
            lines.append(f'    {spec.name}: {_yaml_value(spec.default)}')
    return '\n'.join(lines) + '\n'


def markdown_table(groups: Sequence[tuple[str, type]]) -> str:
    """The parameters of `groups` as a Markdown table (name, default, range, unit, meaning)."""
    lines = ['| name | default | range | unit | meaning |', '|---|---|---|---|---|']
    for title, settings_class in groups:
        lines.append(f'| **{title}** | | | | |')
        for spec in specs(settings_class):
            allowed = (' \\| '.join(spec.choices) if spec.choices else
                       f'{spec.bounds[0]:g} .. {spec.bounds[1]:g}' if spec.bounds else '')
            lines.append(f'| `{spec.name}` | `{_yaml_value(spec.default)}` | {allowed} | '
                         f'{spec.unit} | {spec.description} |')
    return '\n'.join(lines) + '\n'
