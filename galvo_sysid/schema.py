"""Reading the files the tools are given: one safe YAML loader and strict typed getters.

Every YAML file galvo_sysid reads (plant-model files, ROS parameter files, a bag's
``metadata.yaml``) goes through :func:`load_yaml`: regular files only (a FIFO, device or
socket is refused before it is opened for reading, so it cannot hang the reader), at most
:data:`MAX_FILE_BYTES` read, no aliases (a "billion laughs" alias bomb is refused before it
expands), no custom tags, no YAML 1.1 dates or base-60 numbers (``1:20`` stays text, as ROS
reads it), and numbers as ROS's parameter parser reads them (``3.564e6`` is a float, although
YAML 1.1 would read it as text). The getters of :class:`Section` then check each value's type
and range and refuse unknown keys, naming the file and the key in the error.

:func:`check_regular_file` is the same first check for files read by other libraries (a
bag's storage files).
"""

from __future__ import annotations

import errno
import math
import os
import re
import stat
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml  # type: ignore[import-untyped]  # PyYAML ships no stubs here

from galvo_sysid.errors import ConfigurationError, InvalidDataError, one_line

if TYPE_CHECKING:
    from collections.abc import Iterable

__all__ = [
    'MAX_FILE_BYTES',
    'Section',
    'check_number',
    'check_regular_file',
    'load_yaml',
    'parse_yaml',
    'read_text_file',
]

MAX_FILE_BYTES = 1_000_000
"""Largest YAML file read [bytes]."""

_MAX_NUMBER_CHARACTERS = 400
"""Longest number read (a longer one is refused: Python's integer parsing has a limit)."""

_FLOAT = re.compile(r'^[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)[eE][-+]?[0-9]+$')


class _Loader(yaml.SafeLoader):  # type: ignore[misc]
    """SafeLoader without aliases, with ROS's reading of exponent numbers."""

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise yaml.YAMLError(f'aliases are not allowed (line {event.start_mark.line + 1})')
        return super().compose_node(parent, index)


def _plain(loader: _Loader, node: Any) -> Any:
    """A YAML 1.1 date or a base-60 number (``1:20``) stays the text written, as ROS reads it."""
    return loader.construct_scalar(node)


def _number(kind: str) -> Any:
    base = getattr(yaml.SafeLoader, f'construct_yaml_{kind}')

    def construct(loader: _Loader, node: Any) -> Any:
        text = str(node.value)
        if ':' in text:  # base 60
            return loader.construct_scalar(node)
        if len(text) > _MAX_NUMBER_CHARACTERS:
            raise yaml.constructor.ConstructorError(
                None, None, f'a number of {len(text)} characters (at most '
                f'{_MAX_NUMBER_CHARACTERS})', node.start_mark)
        return base(loader, node)
    return construct


_Loader.add_implicit_resolver('tag:yaml.org,2002:float', _FLOAT, list('-+0123456789.'))
_Loader.add_constructor('tag:yaml.org,2002:timestamp', _plain)
_Loader.add_constructor('tag:yaml.org,2002:int', _number('int'))
_Loader.add_constructor('tag:yaml.org,2002:float', _number('float'))


def parse_yaml(text: str, *, source: str) -> Any:
    """Parse YAML text with the safe loader (see the module docs).

    Raises:
        ConfigurationError: Not valid YAML, an alias, or too large.
    """
    if len(text) > MAX_FILE_BYTES:
        raise ConfigurationError(f'{source}: larger than {MAX_FILE_BYTES} bytes')
    try:
        return yaml.load(text, Loader=_Loader)  # a SafeLoader subclass: safe
    except (yaml.YAMLError, ValueError) as err:
        raise ConfigurationError(f'{source}: not valid YAML: {one_line(err)}') from None
    except RecursionError:
        raise ConfigurationError(f'{source}: nested too deeply') from None


def _kind_of(mode: int) -> str:
    """What a file that is not a regular file is, for messages."""
    for test, name in ((stat.S_ISDIR, 'a directory'), (stat.S_ISFIFO, 'a FIFO'),
                       (stat.S_ISSOCK, 'a socket'), (stat.S_ISCHR, 'a character device'),
                       (stat.S_ISBLK, 'a block device')):
        if test(mode):
            return name
    return 'not a regular file'


def check_regular_file(path: str | os.PathLike[str], *, what: str = 'file') -> Path:
    """``path`` if it is a regular file (after symbolic links), else InvalidDataError.

    Checked before a file is opened: opening a FIFO for reading blocks until a writer comes,
    and a device can be read forever.

    Raises:
        InvalidDataError: Missing, unreadable, or not a regular file (the message says what
            it is instead).
    """
    p = Path(path)
    try:
        mode = os.stat(p).st_mode
    except FileNotFoundError:
        raise InvalidDataError(f'cannot read {what} {p}: no such file') from None
    except OSError as err:
        raise InvalidDataError(f'cannot read {what} {p}: {err.strerror or err}') from None
    if not stat.S_ISREG(mode):
        raise InvalidDataError(f'cannot read {what} {p}: {_kind_of(mode)}, not a regular file')
    return p


def read_text_file(path: str | os.PathLike[str], *, what: str = 'file',
                   max_bytes: int = MAX_FILE_BYTES) -> str:
    """The UTF-8 text of a regular file of at most ``max_bytes``.

    The file is opened without blocking and checked on the open descriptor (so a FIFO or
    device put in its place after a check cannot hang or flood the reader); at most
    ``max_bytes + 1`` bytes are read, whatever size the file claims.

    Raises:
        InvalidDataError: Missing, unreadable, not a regular file, not UTF-8 text.
        ConfigurationError: Larger than ``max_bytes``.
    """
    p = check_regular_file(path, what=what)
    flags = os.O_RDONLY | getattr(os, 'O_NONBLOCK', 0) | getattr(os, 'O_CLOEXEC', 0)
    try:
        fd = os.open(p, flags)
    except OSError as err:
        raise InvalidDataError(f'cannot read {what} {p}: {err.strerror or err}') from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise InvalidDataError(f'cannot read {what} {p}: {_kind_of(mode)}, not a regular '
                                   f'file')
        chunks: list[bytes] = []
        size = 0
        while size <= max_bytes:
            chunk = os.read(fd, max_bytes + 1 - size)
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
    except OSError as err:
        if err.errno == errno.EAGAIN:  # pragma: no cover - only a non-regular file
            raise InvalidDataError(f'cannot read {what} {p}: not a regular file') from None
        raise InvalidDataError(f'cannot read {what} {p}: {err.strerror or err}') from None
    finally:
        os.close(fd)
    if size > max_bytes:
        raise ConfigurationError(f'{p}: larger than {max_bytes} bytes')
    try:
        return b''.join(chunks).decode('utf-8')
    except UnicodeDecodeError:
        raise InvalidDataError(f'cannot read {what} {p}: not a text file') from None


def load_yaml(path: str | os.PathLike[str], *, what: str = 'file') -> Any:
    """Read and parse a YAML file (regular files only, at most :data:`MAX_FILE_BYTES`).

    Raises:
        InvalidDataError: The file cannot be read (missing, not a regular file, not text).
        ConfigurationError: Not valid YAML, an alias, or too large.
    """
    return parse_yaml(read_text_file(path, what=what), source=str(Path(path)))


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
                                     f'{_short(value)}')
        if not low <= value <= high:
            raise ConfigurationError(f'{self.where}: {key} must be within {low}..{high}, got '
                                     f'{_short(value)}')
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


def _short(value: Any, limit: int = 60) -> str:
    """``repr(value)``, cut to ``limit`` characters (a value in an error line)."""
    text = repr(value)
    return text if len(text) <= limit else f'{text[:limit - 3]}...'


def check_number(value: Any, where: str, *, low: float = -math.inf, high: float = math.inf,
                 low_open: bool = False) -> float:
    """``value`` as a float if it is a finite number in range, else ConfigurationError."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigurationError(f'{where} must be a number, got {_short(value)}')
    try:
        v = float(value)
    except OverflowError:  # an integer beyond any float
        raise ConfigurationError(f'{where} must be <= {high:g}, got {_short(value)}') from None
    if not math.isfinite(v):
        raise ConfigurationError(f'{where} must be finite, got {_short(value)}')
    if (v <= low if low_open else v < low) or v > high:
        bound = f'> {low:g}' if low_open else f'>= {low:g}'
        raise ConfigurationError(f'{where} must be {bound} and <= {high:g}, got {_short(value)}')
    return v
