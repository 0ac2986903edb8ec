"""Parameter values as ``ros2 param`` reads and prints them, and parameter files (no rclpy).

A value is a ``(kind, value)`` pair: ``kind`` one of :data:`KINDS` (the
``rcl_interfaces/msg/ParameterType`` of the same index), ``value`` plain Python.

- :func:`parse_value`: the text given to ``param set``, read as ``ros2 param set`` reads it
  (a YAML scalar or list: ``true``, ``100``, ``2.5``, ``[0.3, 0.6]``, ``refined``; a list
  mixing types, or anything else, is the text itself), with numbers as ROS's parameter
  parser reads them (``1e-6`` is a float, as on the command line ``-p NAME:=VALUE``); then
  fitted to the parameter's declared kind when one is known: an integer for a floating-point
  parameter becomes a float (``2`` for ``2.0``), whole numbers in a floating-point list too,
  and any text for a text parameter stays the text (``"[]"``, ``123``).
- :func:`format_value`, :func:`value_line`: a value as ``param get`` prints it.
- :func:`parameters_yaml`: a node's parameters as a ``--params-file``
  (``/node: ros__parameters: {...}``, names split at dots into nested mappings).
"""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING, Any

from galvo_sysid.errors import ConfigurationError

if TYPE_CHECKING:
    from collections.abc import Mapping

__all__ = [
    'KINDS',
    'format_value',
    'parameters_yaml',
    'parse_value',
    'value_line',
]

KINDS = ('not set', 'boolean', 'integer', 'double', 'string', 'byte array', 'boolean array',
         'integer array', 'double array', 'string array')
"""The kinds of parameter value, indexed by ``rcl_interfaces/msg/ParameterType`` code."""

_LABELS = {'boolean': 'Boolean value is:', 'integer': 'Integer value is:',
           'double': 'Double value is:', 'string': 'String value is:',
           'byte array': 'Byte values are:', 'boolean array': 'Boolean values are:',
           'integer array': 'Integer values are:', 'double array': 'Double values are:',
           'string array': 'String values are:'}
"""What ``ros2 param get`` prints before a value of each kind."""


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _kind_of(value: Any, text: str) -> tuple[str, Any]:
    """The kind ``ros2 param set`` gives a YAML value (rclpy's ``get_parameter_value``)."""
    if isinstance(value, bool):
        return 'boolean', value
    if isinstance(value, int):
        return 'integer', value
    if isinstance(value, float):
        return 'double', value
    if isinstance(value, list):
        for kind, item in (('boolean array', bool), ('integer array', int),
                           ('double array', float), ('string array', str)):
            if all(type(v) is item for v in value):  # an empty list: a boolean array
                return kind, list(value)
        return 'string', text
    if isinstance(value, str):
        return 'string', value
    return 'string', text  # null, a mapping: the text as written


def parse_value(text: str, *, declared: str | None = None) -> tuple[str, Any]:
    """The value ``text`` stands for (see the module docs), as ``(kind, value)``.

    Args:
        text: What the user typed (``2.5``, ``[0.3, 0.6]``, ``refined``...).
        declared: The parameter's declared kind (one of :data:`KINDS`), if known; ``'not
            set'`` (a dynamically typed parameter) or None: no fitting.
    """
    from galvo_sysid.schema import parse_yaml

    try:
        value = parse_yaml(text, source='value')
    except ConfigurationError:  # not YAML: the text itself, as ros2 param takes it
        value = text
    kind, out = _kind_of(value, text)
    if declared == 'string' and kind != 'string':
        return 'string', text
    if declared == 'double' and kind == 'integer':
        try:
            return 'double', float(out)
        except OverflowError:  # beyond any float: let the node say so
            return kind, out
    if declared == 'double array' and isinstance(value, list) and value and \
            all(_is_number(v) for v in value):
        try:
            return 'double array', [float(v) for v in value]
        except OverflowError:
            return kind, out
    return kind, out


def _scalar(value: Any) -> str:
    """One value as YAML that ROS's parameter parser reads back the same (text quoted)."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return '.nan'
        if math.isinf(value):
            return '.inf' if value > 0 else '-.inf'
        return repr(value)
    return json.dumps(str(value), ensure_ascii=False)  # a YAML double-quoted scalar


def format_value(kind: str, value: Any) -> str:
    """A value as ``param get`` prints it: what ``param set`` reads back as the same value."""
    if kind == 'not set':
        return ''
    if isinstance(value, list | tuple):
        return '[' + ', '.join(_scalar(v) for v in value) + ']'
    if isinstance(value, str):  # as typed, unless it would read back as something else
        kind_back, back = parse_value(value)
        return value if kind_back == 'string' and back == value and value else _scalar(value)
    return _scalar(value)


def value_line(kind: str, value: Any, *, hide_type: bool = False) -> str:
    """The line ``param get`` prints: ``Double value is: 2.5`` (``ros2 param get``'s
    labels; ``Parameter not set.`` for a declared parameter without value), or the value
    alone with ``hide_type``."""  # noqa: D205, D209
    if kind == 'not set':
        return 'Parameter not set.'
    text = format_value(kind, value)
    return text if hide_type else f'{_LABELS.get(kind, kind + ":")} {text}'


def _nest(values: Mapping[str, Any]) -> dict[str, Any]:
    """``{'a.b': 1, 'c': 2}`` as ``{'a': {'b': 1}, 'c': 2}``; a name whose prefix is itself a
    parameter stays flat below its parent (``a.b`` beside a parameter ``a``)."""  # noqa: D205, D209
    tree: dict[str, Any] = {}
    for name in sorted(values):
        parts = name.split('.')
        where = tree
        for i, part in enumerate(parts[:-1]):
            sub = where.get(part)
            if sub is None:
                sub = where[part] = {}
            elif not isinstance(sub, dict):  # 'a' is a parameter: keep 'a.b' whole
                parts = [*parts[:i], '.'.join(parts[i:])]
                break
            where = sub
        where[parts[-1]] = values[name]
    return tree


def _lines(tree: Mapping[str, Any], indent: int) -> list[str]:
    pad = '  ' * indent
    out: list[str] = []
    for key, value in tree.items():
        name = key if key.replace('_', 'a').replace('.', 'a').isalnum() else json.dumps(key)
        if isinstance(value, dict):
            out.append(f'{pad}{name}:')
            out.extend(_lines(value, indent + 1))
        elif isinstance(value, list | tuple):
            out.append(f'{pad}{name}: [' + ', '.join(_scalar(v) for v in value) + ']')
        else:
            out.append(f'{pad}{name}: {_scalar(value)}')
    return out


def parameters_yaml(node: str, values: Mapping[str, Any]) -> str:
    r"""A node's parameters as a ROS 2 parameter file (what ``ros2 param dump`` prints).

    Args:
        node: The node's full name (``/sysid``, ``/scanner_1/sysid``): the file's section.
        values: Parameter values by name (parameters without a value left out by the
            caller: a parameter file cannot say "not set").

    Returns:
        ``/node:\n  ros__parameters:\n    name: value ...`` with names in order, nested at
        dots, text double-quoted (so ``"1e-6"`` stays text), floats with a point or an
        exponent (``2.0``: a float for ROS too), ``.nan``/``.inf``.
    """
    lines = [f'{node}:', '  ros__parameters:']
    body = _lines(_nest(values), 2)
    if not body:
        lines[-1] += ' {}'
    return '\n'.join(lines + body) + '\n'
