"""What every ``galvo-sysid`` subcommand shares: help layout, argument types, output.

The error line (:func:`galvo_sysid.errors.one_line`) and strict JSON
(:func:`galvo_sysid.jsonsafe.json_safe`) are the package's, not the command line's.

Imports nothing heavy (no numpy): :mod:`galvo_sysid.cli.main` imports it before it limits the
BLAS threads, and every subcommand's parser is built from it.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
import time
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from galvo_sysid.errors import ConfigurationError, GalvoSysidError, one_line
from galvo_sysid.jsonsafe import json_safe

if TYPE_CHECKING:
    from collections.abc import Callable

__all__ = [
    'BAG_HELP',
    'PSI',
    'HelpFormatter',
    'Parser',
    'Progress',
    'add_subcommand',
    'bounded_int',
    'check_output',
    'finite_float',
    'guarded',
    'nonnegative_int',
    'parse_angle',
    'positive',
    'positive_at_most',
    'print_json',
]

PSI = 0.3
"""The paper's unit of target angle [deg]: ``'2psi'`` means 0.6 deg."""

BAG_HELP = 'rosbag2 bag: directory, .mcap or .db3 file'
"""Help text of a subcommand's bag argument."""


_NEGATIVE_NUMBER = re.compile(r'^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$')
"""A negative number as a command line writes it, scientific notation included."""


class Parser(argparse.ArgumentParser):
    """An argument parser that takes a negative number in scientific notation as a value.

    argparse's own pattern knows ``-1`` and ``-0.5`` but not ``-1e-6``, which it read as an
    unknown option (``--measured-current -1e-6``: "expected one argument"). Its
    sub-parsers are of this class too.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = _NEGATIVE_NUMBER


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Keep the hand-made line breaks of descriptions; show defaults that say something.

    A default is shown as ``(default: ...)`` after an option's help unless it is None, False
    or empty, or the help names it itself with ``%(default)s``.
    """

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ''
        default = action.default
        if (default is None or default is False or default == [] or default is argparse.SUPPRESS
                or '%(default)' in text or not action.option_strings):
            return text
        return f'{text} (default: %(default)s)'


def add_subcommand(subparsers: Any, name: str, *, help: str, description: str,
                   epilog: str | None = None) -> argparse.ArgumentParser:
    """Add subcommand ``name`` to an argparse subparsers object, with :class:`HelpFormatter`.

    Args:
        subparsers: What ``ArgumentParser.add_subparsers`` returned.
        name: The subcommand.
        help: One line for the main ``--help``.
        description: The subcommand's ``--help`` text (line breaks kept).
        epilog: Text after the options (examples).
    """
    parser: argparse.ArgumentParser = subparsers.add_parser(
        name, formatter_class=HelpFormatter, help=help, description=description, epilog=epilog)
    return parser


# --------------------------------------------------------------------------- argument types


def parse_angle(text: str) -> float:
    """Parse a target angle in degrees; ``'2psi'`` or ``'0.5psi'`` means multiples of 0.3 deg.

    Raises:
        argparse.ArgumentTypeError: Not a finite number.
    """
    raw = text.strip().lower()
    scale = 1.0
    if raw.endswith('psi'):
        raw, scale = raw[:-3] or '1', PSI
    try:
        value = float(raw) * scale
    except ValueError:
        msg = f'not an angle: {text!r} (degrees, or e.g. 2psi = 0.6 deg)'
        raise argparse.ArgumentTypeError(msg) from None
    if not math.isfinite(value) or value == 0:
        msg = f'angle must be finite and non-zero: {text!r}'
        raise argparse.ArgumentTypeError(msg)
    return round(value, 12)


def positive(kind: type[int] | type[float]) -> Callable[[str], Any]:
    """An argument type: a number of ``kind`` (``int`` or ``float``) above 0.

    ``'inf'`` passes as a float (e.g. ``replay --rate inf``: as fast as possible).
    """
    def parse(text: str) -> float:
        return _number(text, kind, 'a number', '> 0', lambda value: value > 0)
    parse.__name__ = kind.__name__
    return parse


def bounded_int(low: int, high: int) -> Callable[[str], int]:
    """An argument type: a whole number within ``low .. high``."""
    def parse(text: str) -> int:
        return int(_number(text, int, 'a whole number', f'within {low}..{high}',
                           lambda value: low <= value <= high))
    parse.__name__ = 'int'
    return parse


def positive_at_most(high: float, unit: str) -> Callable[[str], float]:
    """An argument type: a number above 0 and at most ``high`` [``unit``]."""
    def parse(text: str) -> float:
        return _number(text, float, 'a number', f'> 0 and <= {high:g} {unit}',
                       lambda value: 0 < value <= high)
    parse.__name__ = 'float'
    return parse


def nonnegative_int(text: str) -> int:
    """An argument type: a whole number, 0 or more."""
    return int(_number(text, int, 'a whole number', '>= 0', lambda value: value >= 0))


def dither_amplitude(text: str) -> float:
    """An argument type: a dither tone amplitude [A], 0 .. 0.5 (``10mA`` is read too)."""
    scale = 1.0
    if text.lower().endswith('ma'):
        text, scale = text[:-2], 1e-3
    value = _number(text, float, 'a current [A]', 'within 0..0.5 A',
                    lambda v: 0 <= v * scale <= 0.5)
    return value * scale


def finite_float(text: str) -> float:
    """An argument type: a finite number (no NaN or infinity)."""
    return _number(text, float, 'a number', 'finite', math.isfinite)


def _number(text: str, kind: type[int] | type[float], what: str, need: str,
            valid: Callable[[float], bool]) -> float:
    """``kind(text)`` if ``valid``; else the usage error ``not <what>`` or ``must be <need>``."""
    try:
        value = kind(text)
    except ValueError:
        msg = f'not {what}: {text!r}'
        raise argparse.ArgumentTypeError(msg) from None
    if not valid(value):
        msg = f'must be {need}: {text!r}'
        raise argparse.ArgumentTypeError(msg)
    return value


# --------------------------------------------------------------------------- outputs


def _bag_area(bag: str | os.PathLike[str]) -> tuple[Path, ...]:
    """What a bag argument reads: the directory, or the file and (where it lies in a bag
    directory, beside its metadata.yaml) that directory."""  # noqa: D205, D209
    path = Path(bag).expanduser().resolve()
    if path.is_file() and (path.parent / 'metadata.yaml').is_file():
        return path, path.parent
    return (path,)


def check_output(path: str | os.PathLike[str], *, reads: str | os.PathLike[str],
                 force: bool, what: str, directory: bool = False) -> Path:
    """Refuse, before any work, an output a subcommand would write where it must not.

    Never into the bag it reads (its file, its directory or anything in it); never onto a
    directory (a file output) or a file (a directory output); a file not where the directory
    above does not exist (a directory output is made with its parents); and, without
    ``force``, not over an existing file or into a directory that holds anything (bags, models
    and reports are not replaced silently).

    Args:
        path: The output (``--out FILE``, ``--save-model FILE``, ``--report DIR``).
        reads: The bag the subcommand reads.
        force: Replace an existing file, or write into a directory that holds files.
        what: The output's name in messages (``'model file'``).
        directory: The output is a directory (created if missing).

    Returns:
        The output's path.

    Raises:
        ConfigurationError: The output is refused (the message says why, and the option
            that allows replacing where one does).
    """
    out = Path(path).expanduser()
    target = out.resolve()
    for area in _bag_area(reads):
        if target == area or (area.is_dir() and area in target.parents):
            msg = f'{what} {out} would be written into the bag it reads ({reads}): choose ' \
                  f'another place'
            raise ConfigurationError(msg)
    if directory:  # made with its parents: the nearest existing one must be a directory
        above = next(p for p in (target, *target.parents) if p.exists())
        if above != target and not above.is_dir():
            raise ConfigurationError(f'{what} {out}: {above} is a file, not a directory')
        if target.exists() and not target.is_dir():
            raise ConfigurationError(f'{what} {out} exists and is not a directory')
        if target.is_dir() and any(target.iterdir()) and not force:
            msg = f'{what} {out} holds files already; give --force to write into it'
            raise ConfigurationError(msg)
        return out
    if not target.parent.is_dir():
        raise ConfigurationError(f'the directory of the {what} does not exist: {out.parent}')
    if target.is_dir():
        raise ConfigurationError(f'{what} {out} is a directory; give a file name')
    if target.exists() and not force:
        raise ConfigurationError(f'{what} {out} exists already; give --force to replace it')
    return out


# --------------------------------------------------------------------------- running


def guarded(where: str, call: Callable[[], int]) -> int:
    """Run a subcommand's ``call()`` and return its exit code; bad input ends in one line.

    Whatever bad input can raise, from galvo_sysid or from a library deep below it, becomes
    ``<where>: error: <message>`` on stderr and exit code 1, never a traceback:
    :class:`~galvo_sysid.errors.GalvoSysidError` and ``OSError`` (unwritable output, full disk,
    ...) with their message; ``ValueError``, ``ArithmeticError`` and ``RecursionError`` (a
    numerics library refusing a value the checks let through) with their type's name too;
    ``MemoryError`` as such. Ctrl-C ends in ``<where>: interrupted`` and exit code 130.
    NumPy's ``RuntimeWarning`` lines (overflow, division by zero in a hostile record, which
    the checks then refuse or set aside in words of their own) are not printed.

    Args:
        where: The command as the error line names it (``galvo-sysid identify``).
        call: Runs the subcommand, returns its exit code.
    """
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore', RuntimeWarning)
            return int(call())
    except (GalvoSysidError, OSError) as err:
        print(f'{where}: error: {one_line(err)}', file=sys.stderr)
    except MemoryError:
        print(f'{where}: error: out of memory (the input is too large for this machine)',
              file=sys.stderr)
    except (ValueError, ArithmeticError, RecursionError) as err:
        print(f'{where}: error: {type(err).__name__}: {one_line(err)}', file=sys.stderr)
    except KeyboardInterrupt:
        print(f'{where}: interrupted', file=sys.stderr)
        return 130
    return 1


# --------------------------------------------------------------------------- output


def print_json(value: Any) -> None:
    """Print ``value`` on stdout as one line of strict JSON (NaN and infinity as null)."""
    json.dump(json_safe(value), sys.stdout, allow_nan=False)
    sys.stdout.write('\n')


class Progress:
    """A one-line progress bar on a TTY, drawn only when a run takes a while.

    Call it with ``(done, total)`` messages; :meth:`close` clears the line.

    Args:
        stream: Where the bar goes (drawn only if it is a terminal).
        label: Word before the bar (the subcommand).
        enabled: False draws nothing (e.g. with ``--json``).
        delay: Seconds before the first drawing (a short run draws nothing).
    """

    def __init__(self, stream: TextIO, label: str, *, enabled: bool,
                 delay: float = 0.5) -> None:
        self.stream = stream
        self.label = label
        self.enabled = enabled and stream.isatty()
        self.delay = delay
        self.start = time.monotonic()
        self.last = 0.0
        self.drawn = False

    def __call__(self, done: int, total: int) -> None:
        """Redraw the bar for ``done`` of ``total`` messages (at most ten times a second)."""
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self.start < self.delay or (now - self.last < 0.1 and done < total):
            return
        self.last = now
        frac = done / total if total else 1.0
        width = 30
        bar = '#' * round(frac * width)
        self.stream.write(f'\r{self.label} [{bar:<{width}}] {100 * frac:3.0f} % '
                          f'({done}/{total} messages, {now - self.start:.1f} s)')
        self.stream.flush()
        self.drawn = True

    def close(self) -> None:
        """Clear the bar's line if it was drawn."""
        if self.drawn:
            self.stream.write('\r\033[K')
            self.stream.flush()
