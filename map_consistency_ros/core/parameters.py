"""Parameters defined once: on the settings dataclasses, as field metadata.

A settings field declared with `parameter(...)` carries its description, unit, range and
allowed choices. From that one definition the node declares its ROS parameters, the CLI builds
its options, `config/map_consistency.yaml` is generated and every value is checked: a settings
dataclass derives from `Settings`, whose `__post_init__` checks each parameter field against
its declaration, however the instance is made (`settings_from_values`, the constructor,
`dataclasses.replace`); a settings class writes by hand only the invariants that tie fields
together. The type of a parameter is its default's; an integer is accepted where a float is
expected (YAML writes `8` for 8.0), a bool never passes as a number. A choice among names is a
`Choice` enum: its members are the strings they stand for (they compare, hash, format and
serialise as them), so parameter files, reports and comparisons with plain strings are the same.
"""
from __future__ import annotations

import difflib
import functools
import math
import numbers
import textwrap
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import MISSING, dataclass, field, fields
from enum import Enum
from typing import Any

_META = 'parameter'


class Choice(str, Enum):
    """A parameter's choice among names: each member is the string it stands for.

    The str mixin makes a member equal to, hash as and serialise (JSON) as its value; `str()`
    and `format()` give the value too (Python 3.11 would give `Class.MEMBER`), so reports and
    messages read as with plain strings.
    """

    def __str__(self) -> str:
        return self.value

    def __format__(self, spec: str) -> str:
        return format(self.value, spec)


@dataclass(frozen=True)
class ParameterSpec:
    """One parameter: its name (the dataclass field's), default and documentation."""

    name: str
    default: Any
    description: str
    unit: str = ''
    bounds: tuple[float, float] | None = None  # inclusive
    choices: tuple[str, ...] = ()
    enum: type[Choice] | None = None  # a checked value becomes its member (choices: their values)

    @property
    def kind(self) -> type:
        """bool, int, float, str or tuple (a fixed-length list of floats); str for a Choice
        (the default is the member's plain string)."""
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
        """Check a value against the declaration.

        Parameters
        ----------
        value: a value given for the parameter (a YAML, ROS or command-line value, or a
            member of `enum`).

        Returns
        -------
        The value in the parameter's type (a member of `enum` for a Choice); ValueError naming
        the parameter when it has the wrong type, lies outside `bounds` or is not one of
        `choices`.
        """
        if self.enum is not None and isinstance(value, self.enum):
            return value
        value = _typed(self, value)
        if self.bounds is not None and not self.bounds[0] <= value <= self.bounds[1]:
            raise ValueError(f'{self.name}: {value!r} is outside [{self.bounds[0]:g}, '
                             f'{self.bounds[1]:g}]')
        if self.choices and value not in self.choices:
            raise ValueError(f'{self.name}: {value!r} is not one of {", ".join(self.choices)}')
        return value if self.enum is None else self.enum(value)


def _type_name(value: Any) -> str:
    return {bool: 'a bool', int: 'an integer', float: 'a float', str: 'a string'}.get(
        type(value), f'a {type(value).__name__}')


def _number(value: Any) -> bool:
    # numbers.Real takes numpy's scalars (a setting swept over an array) but not numpy's bool
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _typed(spec: ParameterSpec, value: Any) -> Any:
    expected = spec.kind
    if expected is tuple:
        if (not isinstance(value, (list, tuple)) or len(value) != len(spec.default)
                or not all(_number(v) for v in value)):
            raise ValueError(f'{spec.name}: expected a list of {len(spec.default)} numbers, '
                             f'got {value!r}')
        values = tuple(float(v) for v in value)
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f'{spec.name}: values must be finite, got {value!r}')
        return values
    if expected is float and _number(value):
        value = float(value)  # documented: integers stand for floats
    elif expected is int and isinstance(value, numbers.Integral) and not isinstance(value, bool):
        value = int(value)
    elif expected is str and isinstance(value, str):
        value = str(value)
    elif type(value) is not expected:
        raise ValueError(f'{spec.name}: expected {_type_name(spec.default)}, got '
                         f'{_type_name(value)} {value!r}')
    if expected is float and not math.isfinite(value):
        raise ValueError(f'{spec.name}: must be finite, got {value!r}')
    return value


def parameter(default: Any, description: str, unit: str = '',
              bounds: tuple[float, float] | None = None,
              choices: Sequence[str] | type[Choice] = ()) -> Any:
    """A dataclass field that is also a user-facing parameter (see the module docstring).

    Parameters
    ----------
    default: the value when none is given; its type is the parameter's (a member of
        `choices` when that is a Choice enum)
    description, unit: the documentation (help texts, the parameter file, docs/node.md)
    bounds: inclusive range of a number
    choices: the allowed strings, or a Choice enum whose members are

    Returns
    -------
    A dataclasses field carrying the declaration as metadata.
    """
    enum = choices if isinstance(choices, type) and issubclass(choices, Choice) else None
    if enum is not None:
        default = enum(default)
        choices = tuple(member.value for member in enum)
    metadata = {_META: dict(description=description, unit=unit, bounds=bounds,
                            choices=tuple(choices), enum=enum)}
    return field(default=default, metadata=metadata)


@functools.cache
def _specs(settings_class: type) -> tuple[ParameterSpec, ...]:
    found = []
    for item in fields(settings_class):
        meta = item.metadata.get(_META)
        if meta is None or item.default is MISSING:
            continue
        # a Choice's default is its plain string: the parameter file, the ROS parameter and
        # the option's default are strings
        default = item.default.value if meta['enum'] is not None else item.default
        found.append(ParameterSpec(name=item.name, default=default, **meta))
    return tuple(found)


def specs(settings_class: type) -> list[ParameterSpec]:
    """The parameters of a settings dataclass, in field order (a field declared without
    `parameter(...)` is no parameter).

    Parameters
    ----------
    settings_class: a dataclass whose parameter fields are declared with `parameter(...)`

    Returns
    -------
    One ParameterSpec per parameter field.
    """
    return list(_specs(settings_class))


class Settings:
    """Base of the settings dataclasses: every parameter field is checked against its
    declaration when an instance is made, and stored in its parameter's type (8 -> 8.0 for a
    float, a list -> a tuple, a string -> its Choice member). A subclass that checks more (an
    invariant between fields) calls `super().__post_init__()` first."""

    def __post_init__(self) -> None:
        for spec in _specs(type(self)):
            # frozen dataclasses: the typed value replaces the given one
            object.__setattr__(self, spec.name, spec.check(getattr(self, spec.name)))


def settings_from_values(settings_class: type, values: Mapping[str, Any], **extra: Any):
    """An instance of `settings_class` from the values of its parameters.

    Parameters
    ----------
    settings_class: a settings dataclass (see `Settings`)
    values: name -> value; names that are not parameters of the class are ignored, missing
        parameters take their defaults
    extra: further constructor arguments (fields that are not parameters)

    Returns
    -------
    The instance; ValueError names the first bad value (the class checks them: `Settings`).
    """
    chosen = {spec.name: values[spec.name] for spec in _specs(settings_class)
              if spec.name in values}
    return settings_class(**chosen, **extra)


def closest_name(name: str, names: Iterable[str]) -> str | None:
    """The valid name a misspelt one most likely meant.

    Parameters
    ----------
    name: the misspelt name.
    names: the valid names.

    Returns
    -------
    The shortest valid name containing `name`, else the closest by difflib's similarity (at
    least 0.6); None when nothing is close.
    """
    names = list(names)
    # a shortened name ('trim' for trim_largest) first: a similarity ratio of short names
    # finds unrelated ones ('strict')
    containing = sorted((known for known in names if name in known), key=len)
    if containing:
        return containing[0]
    matches = difflib.get_close_matches(name, names, n=1, cutoff=0.6)
    return matches[0] if matches else None


def unknown_names(values: Iterable[str], known: Iterable[str]) -> list[str]:
    """One warning per unknown name, naming the closest valid one.

    Parameters
    ----------
    values: the names given (a parameter file's, the command line's).
    known: the valid names.

    Returns
    -------
    The warnings, one line each, sorted by the unknown name; empty when every name is known.
    """
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
    """A ROS parameter file of every parameter of `groups` at its default.

    Parameters
    ----------
    groups: (title, settings class) pairs, in the order of the file.
    header: text of the file's opening comment (one comment line per line).

    Returns
    -------
    The YAML text (`/**: ros__parameters:`), each parameter under its help text as comment.
    """
    lines = [f'# {line}' if line else '#' for line in header.splitlines()]
    lines += ['/**:', '  ros__parameters:']
    for title, settings_class in groups:
        lines.append(f'    # -- {title}')
        for spec in specs(settings_class):
            lines += [f'    # {line}' for line in textwrap.wrap(spec.help, 88)]
            lines.append(f'    {spec.name}: {_yaml_value(spec.default)}')
    return '\n'.join(lines) + '\n'


def markdown_table(groups: Sequence[tuple[str, type]]) -> str:
    """The parameters of `groups` as a Markdown table.

    Parameters
    ----------
    groups: (title, settings class) pairs; each title opens its group's rows.

    Returns
    -------
    The table's text, columns name, default, range, unit, meaning.
    """
    lines = ['| name | default | range | unit | meaning |', '|---|---|---|---|---|']
    for title, settings_class in groups:
        lines.append(f'| **{title}** | | | | |')
        for spec in specs(settings_class):
            allowed = (' \\| '.join(spec.choices) if spec.choices else
                       f'{spec.bounds[0]:g} .. {spec.bounds[1]:g}' if spec.bounds else '')
            lines.append(f'| `{spec.name}` | `{_yaml_value(spec.default)}` | {allowed} | '
                         f'{spec.unit} | {spec.description} |')
    return '\n'.join(lines) + '\n'
