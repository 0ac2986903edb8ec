"""Messages as plain data and as YAML, the way ``ros2 topic echo`` prints them (no rclpy)."""

from __future__ import annotations

import math
from typing import Any

from galvo_sysid.errors import ConfigurationError

__all__ = ['field_path', 'format_yaml', 'message_to_dict', 'select_field']


def message_to_dict(message: Any) -> Any:
    """Convert an rclpy (or rosbags) message to plain dicts, lists and scalars."""
    fields = getattr(message, 'get_fields_and_field_types', None)
    if fields is not None:
        return {name: message_to_dict(getattr(message, name)) for name in fields()}
    if hasattr(message, '__msgtype__') and hasattr(message, '__dataclass_fields__'):
        return {name: message_to_dict(getattr(message, name))
                for name in message.__dataclass_fields__ if name != '__msgtype__'}
    if isinstance(message, bytes):
        return message[0] if len(message) == 1 else list(message)
    tolist = getattr(message, 'tolist', None)  # numpy arrays and scalars, array.array
    if tolist is not None:
        return tolist()
    if isinstance(message, list | tuple):
        return [message_to_dict(x) for x in message]
    return message


def _yaml_scalar(value: Any) -> str:
    if value is None:
        return 'null'
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        if math.isnan(value):
            return '.nan'
        if math.isinf(value):
            return '.inf' if value > 0 else '-.inf'
        return repr(value)
    if isinstance(value, int):
        return str(value)
    text = str(value)
    return "'" + text.replace("'", "''") + "'"


def _yaml_lines(value: Any, indent: int) -> list[str]:
    pad = '  ' * indent
    lines: list[str] = []
    if isinstance(value, dict):
        for key, item in value.items():
            if isinstance(item, dict) and item:
                lines.append(f'{pad}{key}:')
                lines.extend(_yaml_lines(item, indent + 1))
            elif isinstance(item, list) and item:
                lines.append(f'{pad}{key}:')
                lines.extend(_yaml_lines(item, indent))
            elif isinstance(item, list | dict):
                lines.append(f'{pad}{key}: {"[]" if isinstance(item, list) else "{}"}')
            else:
                lines.append(f'{pad}{key}: {_yaml_scalar(item)}')
    elif isinstance(value, list):
        for item in value:
            if isinstance(item, dict) and item:
                sub = _yaml_lines(item, indent + 1)
                lines.append(f'{pad}- {sub[0].lstrip()}')
                lines.extend(sub[1:])
            else:
                lines.append(f'{pad}- {_yaml_scalar(item)}')
    else:
        lines.append(f'{pad}{_yaml_scalar(value)}')
    return lines


def format_yaml(value: Any) -> str:
    """Block-style YAML of plain data, as ``ros2 topic echo`` prints messages."""
    return '\n'.join(_yaml_lines(value, 0))


def field_path(text: str) -> list[str]:
    """The parts of a field path (``'header.stamp.sec'``, ``'natural_frequencies.0'``).

    Raises:
        ConfigurationError: An empty path or part.
    """
    parts = text.split('.')
    if not text or any(not p for p in parts):
        msg = f'not a field path: {text!r} (names joined by dots, e.g. header.stamp)'
        raise ConfigurationError(msg)
    return parts


def select_field(data: Any, path: list[str], *, known_only: bool = False) -> Any:
    """One field of a message as plain data (:func:`message_to_dict`): ``path`` names a
    field of each nested message in turn; a whole number picks an element of a list.

    Args:
        data: The message as plain data.
        path: The parts of the path (:func:`field_path`).
        known_only: Check only what ``data`` can tell (a message type's default instance,
            whose lists are empty): an element beyond a list's end ends the check.

    Raises:
        ConfigurationError: No such field (the fields there are named), an index into
            something that is not a list, or (unless ``known_only``) beyond its end.
    """  # noqa: D205
    value = data
    for i, part in enumerate(path):
        where = '.'.join(path[:i]) or 'the message'
        if isinstance(value, dict):
            if part not in value:
                msg = (f'{where} has no field {part!r} (fields: {", ".join(value) or "none"})')
                raise ConfigurationError(msg)
            value = value[part]
        elif isinstance(value, list):
            if not part.lstrip('-').isdigit():
                msg = f'{where} is a list: select an element by its index, not {part!r}'
                raise ConfigurationError(msg)
            index = int(part)
            if not -len(value) <= index < len(value):
                if known_only:
                    return None
                msg = f'{where} has {len(value)} elements, no element {index}'
                raise ConfigurationError(msg)
            value = value[index]
        else:
            msg = f'{where} is a single value, it has no field {part!r}'
            raise ConfigurationError(msg)
    return value
