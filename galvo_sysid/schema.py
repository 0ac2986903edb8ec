"""Reading the files the tools are given: one safe YAML loader and strict typed getters.

Every YAML file galvo_sysid reads (plant-model files, ROS parameter files) goes through
:func:`load_yaml`: at most :data:`MAX_FILE_BYTES`, no aliases (a "billion laughs" alias bomb
is refused before it expands), no custom tags, and numbers as ROS's parameter parser reads
them (``3.564e6`` is a float, although YAML 1.1 would read it as text). The getters of
:class:`Section` then check each value's type and range and refuse unknown keys, naming the
file and the key in the error.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml  # type: ignore[import-untyped]  # PyYAML ships no stubs here

from galvo_sysid.errors import ConfigurationError, InvalidDataError, one_line

if TYPE_CHECKING:
    import os
    from collections.abc import Iterable

__all__ = ['MAX_FILE_BYTES', 'Section', 'check_number', 'load_yaml', 'parse_yaml']

MAX_FILE_BYTES = 1_000_000
"""Largest YAML file read [bytes]."""

_FLOAT = re.compile(r'^[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)[eE][-+]?[0-9]+$')


class _Loader(yaml.SafeLoader):  # type: ignore[misc]
    """SafeLoader without aliases, with ROS's reading of exponent numbers."""

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise yaml.YAMLError(f'aliases are not allowed (line {event.start_mark.line + 1})')
        return super().compose_node(parent, index)


_Loader.add_implicit_resolver('tag:yaml.org,2002:float', _FLOAT, list('-+0123456789.'))


def parse_yaml(text: str, *, source: str) -> Any:
    """Parse YAML text with the safe loader (see the module docs).

    Raises:
        ConfigurationError: Not valid YAML, an alias, or too large.
    """
    if len(text) > MAX_FILE_BYTES:
        raise ConfigurationError(f'{source}: larger than {MAX_FILE_BYTES} bytes')
    try:
        return yaml.load(text, Loader=_Loader)  # a SafeLoader subclass: safe
    except yaml.YAMLError as err:
        raise ConfigurationError(f'{source}: not valid YAML: {one_line(err)}') from None
    except RecursionError:
        raise ConfigurationError(f'{source}: nested too deeply') from None


def load_yaml(path: str | os.PathLike[str], *, what: str = 'file') -> Any:
    """Read and parse a YAML file (regular files only, at most :data:`MAX_FILE_BYTES`).

    Raises:
        InvalidDataError: The file cannot be read (missing, not a regular file, not text).
        ConfigurationError: Not valid YAML, an alias, or too large.
    """
    p = Path(path)
    try:
        if not p.is_file():
            raise InvalidDataError(f'cannot read {what} {p}: not a regular file'
                                   if p.exists() else f'cannot read {what} {p}: no such file')
        if p.stat().st_size > MAX_FILE_BYTES:
            raise ConfigurationError(f'{p}: larger than {MAX_FILE_BYTES} bytes')
        text = p.read_text(encoding='utf-8')
    except OSError as err:
        raise InvalidDataError(f'cannot read {what} {p}: {err.strerror or err}') from None
    except UnicodeDecodeError:
        raise InvalidDataError(f'cannot read {what} {p}: not a text file') from None
    return parse_yaml(text, source=str(p))


class Section:
    """A mapping read from a file, with typed getters that name the place of an error.

    Args:
        data: The parsed value (must be a mapping).
        where: Its place, e.g. ``'model.yaml: mechanics'``.
        keys: The keys allowed; others are refused (None: any).

    Raises:
        ConfigurationError: Not a mapping, or unknown keys.
    """

    def __init__(self, data: Any, where: str, *, keys: Iterable[str] | None = None) -> None:
        if not isinstance(data, Mapping):
            raise ConfigurationError(f'{where}: expected a mapping, got {_kind(data)}')
        self.data = data
        self.where = where
        if keys is not None:
            unknown = sorted(str(k) for k in data if k not in set(keys))
            if unknown:
                raise ConfigurationError(f'{where}: unknown key(s) {unknown}; allowed: '
                                         f'{sorted(keys)}')

    def __contains__(self, key: str) -> bool:
        return key in self.data

    def _get(self, key: str, default: Any) -> Any:
        if key not in self.data:
            if default is _REQUIRED:
                raise ConfigurationError(f'{self.where}: {key!r} is missing')
            return default
        return self.data[key]

    def number(self, key: str, default: Any = None, *, low: float = -math.inf,
               high: float = math.inf, low_open: bool = False) -> float:
        """A finite number within [low, high] (``(low, high]`` with ``low_open``)."""
        value = self._get(key, _REQUIRED if default is None else default)
        return check_number(value, f'{self.where}: {key}', low=low, high=high,
                            low_open=low_open)

    def integer(self, key: str, default: int | None = None, *, low: int = 0,
                high: int = 2**62) -> int:
        """A whole number within [low, high] (a float with a fraction is refused)."""
        value = self._get(key, _REQUIRED if default is None else default)
        if isinstance(value, bool) or not isinstance(value, int | float) or (
                isinstance(value, float) and not value.is_integer()):
            raise ConfigurationError(f'{self.where}: {key} must be a whole number, got '
                                     f'{value!r}')
        if not low <= value <= high:
            raise ConfigurationError(f'{self.where}: {key} must be within {low}..{high}, got '
                                     f'{value!r}')
        return int(value)

    def text(self, key: str, default: str | None = None, *, max_length: int = 10_000) -> str:
        """A string of at most ``max_length`` characters."""
        value = self._get(key, _REQUIRED if default is None else default)
        if not isinstance(value, str):
            raise ConfigurationError(f'{self.where}: {key} must be text, got {_kind(value)}')
        if len(value) > max_length:
            raise ConfigurationError(f'{self.where}: {key} longer than {max_length} characters')
        return value

    def section(self, key: str, *, keys: Iterable[str] | None = None,
                optional: bool = False) -> Section | None:
        """A nested mapping (None if ``optional`` and absent or null)."""
        if optional and self.data.get(key) is None:
            return None
        return Section(self._get(key, _REQUIRED), f'{self.where}: {key}', keys=keys)

    def items(self, key: str, *, max_items: int, optional: bool = True) -> list[Any]:
        """A list of at most ``max_items`` entries (empty if ``optional`` and absent)."""
        value = self._get(key, [] if optional else _REQUIRED)
        if value is None and optional:
            return []
        if not isinstance(value, list):
            raise ConfigurationError(f'{self.where}: {key} must be a list, got {_kind(value)}')
        if len(value) > max_items:
            raise ConfigurationError(f'{self.where}: {key} has {len(value)} entries, at most '
                                     f'{max_items}')
        return value


_REQUIRED: Any = object()


def _kind(value: Any) -> str:
    return 'nothing' if value is None else type(value).__name__


def check_number(value: Any, where: str, *, low: float = -math.inf, high: float = math.inf,
                 low_open: bool = False) -> float:
    """``value`` as a float if it is a finite number in range, else ConfigurationError."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigurationError(f'{where} must be a number, got {value!r}')
    v = float(value)
    if not math.isfinite(v):
        raise ConfigurationError(f'{where} must be finite, got {value!r}')
    if (v <= low if low_open else v < low) or v > high:
        bound = f'> {low:g}' if low_open else f'>= {low:g}'
        raise ConfigurationError(f'{where} must be {bound} and <= {high:g}, got {value!r}')
    return v
