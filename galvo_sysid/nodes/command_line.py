"""The command line of the three node executables: ``--help`` without ROS, then the node.

``galvo_driver``, ``sysid`` and ``watchdog`` (the console scripts, installed where ``ros2 run``
looks) start here. ``-h`` or ``--help`` among the arguments that are not ROS arguments prints
the node's usage, made from the one parameter registry
(:data:`galvo_sysid.monitor.parameters.NODE_PARAMETERS`: names, defaults, ranges) and the
topic table (:data:`galvo_sysid.interfaces.topics.NODE_TOPICS`), and exits 0 before rclpy is
imported. Anything else goes to the node module's ``main``: rclpy reads ``--ros-args ...``
as always. ROS arguments are those after ``--ros-args`` up to ``--`` or the end, so
``sysid --ros-args -r __ns:=/a -- --help`` asks for help and ``sysid --ros-args --help`` is
left to rcl (which refuses it).
"""

from __future__ import annotations

import importlib
import json
import sys
import textwrap
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from galvo_sysid.field.launcher import NODE_MODULES
from galvo_sysid.interfaces.topics import NODE_TOPICS
from galvo_sysid.monitor.parameters import DECLARED_MODES, NODE_PARAMETERS

if TYPE_CHECKING:
    from collections.abc import Sequence

    from galvo_sysid.monitor.parameters import ParamSpec

__all__ = ['NODES', 'NodeCommand', 'galvo_driver', 'print_help', 'sysid', 'usage', 'wants_help',
           'watchdog']

WIDTH = 100
"""Width the usage is wrapped to [characters]."""


@dataclass(frozen=True)
class NodeCommand:
    """One node executable: its module, with ``main(args) -> exit code``, and what it does.

    The modules' one table is :data:`galvo_sysid.field.launcher.NODE_MODULES`.
    """

    module: str
    summary: str
    config: str
    note: str = ''


NODES = {
    'galvo_driver': NodeCommand(
        NODE_MODULES['galvo_driver'],
        'a simulated galvano scanner (the plant of the model file, closed loop) doing '
        "positioning moves, published live; the plant's drift, steps and effects can be set "
        'while it runs.',
        'driver.yaml'),
    'sysid': NodeCommand(
        NODE_MODULES['sysid'],
        'online identification: pairs current and encoder halves by move_id, fits every '
        'window_size moves of one target angle (in child processes) and publishes the modal '
        'parameters with their standard deviations.',
        'sysid.yaml'),
    'watchdog': NodeCommand(
        NODE_MODULES['watchdog'],
        'judges each identified window against the reference model (drift verdict and '
        'diagnostics OK / WARN / ERROR / STALE / MISMATCH).',
        'watchdog.yaml',
        note=f'A model with more than {DECLARED_MODES} modes gets tolerances.k<i>, '
             f'tolerances.omega_<i> and tolerances.zeta_<i> of its further modes declared at '
             f'start-up (optional, as those of modes 1-{DECLARED_MODES}).'),
}
"""The node executables by node name (also the executable's name)."""


def wants_help(args: Sequence[str]) -> bool:
    """Whether ``-h``/``--help`` is among ``args[1:]`` outside the ROS arguments.

    Args:
        args: The command line with the program name first (``sys.argv``).
    """
    ros = False
    for arg in args[1:]:
        if arg == '--ros-args':
            ros = True
        elif arg == '--' and ros:
            ros = False
        elif not ros and arg in ('-h', '--help'):
            return True
    return False


def _show(value: Any) -> str:
    """A value as a parameter file or ``-p NAME:=VALUE`` writes it (a float with its point)."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list | tuple):
        return '[' + ', '.join(_show(v) for v in value) + ']'
    return repr(value)


def _kind(spec: ParamSpec) -> str:
    default = spec.default
    if default is None:
        return 'number, optional'
    if isinstance(default, list | tuple):
        item = default[0] if default else 0.0
        return f'list of {_kind_of(item)}s'
    return _kind_of(default)


def _kind_of(value: Any) -> str:
    if isinstance(value, bool):
        return 'boolean'
    return {int: 'integer', float: 'float', str: 'text'}.get(type(value), 'value')


def _number(spec: ParamSpec, value: float) -> str:
    whole = isinstance(spec.default, int) or (
        isinstance(spec.default, list | tuple) and spec.default
        and isinstance(spec.default[0], int))
    return str(int(value)) if whole and float(value).is_integer() else f'{value:g}'


def _range(spec: ParamSpec) -> str:
    """The values a parameter takes, as :meth:`ParamSpec.check` checks them."""
    if spec.choices:
        return 'one of ' + ', '.join(spec.choices)
    low, high = spec.low, spec.high
    if low is None and high is None:
        return ''
    if low is not None and high is not None and not spec.exclusive_low:
        text = f'{_number(spec, low)}..{_number(spec, high)}'
    elif low is not None:
        text = f'{">" if spec.exclusive_low else ">="} {_number(spec, low)}'
        if high is not None:
            text += f' and <= {_number(spec, high)}'
    else:
        text = f'<= {_number(spec, high or 0)}'
    if spec.zero_off:
        text = f'0 (off) or {text}'
    if isinstance(spec.default, list | tuple):
        most = spec.max_length
        count = f'{spec.min_length}..{most}' if most is not None else f'{spec.min_length} or more'
        text = f'{count} values, each {text}'
    return text


def _parameter(spec: ParamSpec) -> list[str]:
    facts = [_kind(spec), *(x for x in (_range(spec),) if x)]
    if spec.read_only:
        facts.append('read-only: set at start-up')
    default = '(not set)' if spec.default is None else _show(spec.default)
    head = textwrap.wrap(f'{spec.name} = {default}   ({", ".join(facts)})', WIDTH - 2,
                         subsequent_indent='    ', break_on_hyphens=False)
    body = textwrap.wrap(spec.description, WIDTH - 6, break_on_hyphens=False)
    return [*(f'  {line}' for line in head), *(f'      {line}' for line in body)]


def _topics(title: str, items: Sequence[tuple[str, str]], width: int) -> list[str]:
    return [f'  {title if i == 0 else "":<11} {t:<{width}}  {m}'
            for i, (t, m) in enumerate(items)]


def usage(node: str, *, prog: str | None = None) -> str:
    """The ``--help`` text of a node executable.

    Args:
        node: ``'galvo_driver'``, ``'sysid'`` or ``'watchdog'``.
        prog: The program name shown (default: ``node``).

    Raises:
        KeyError: Unknown node.
    """
    command = NODES[node]
    prog = prog or node
    topics = NODE_TOPICS[node]
    width = max(len(t) for t, _ in (*topics.subscribes, *topics.publishes))
    lines = [
        f'usage: {prog} [-h] [--ros-args [-p NAME:=VALUE] [--params-file FILE] '
        f'[-r __ns:=/NAMESPACE] ...]',
        '',
        *textwrap.wrap(f'{node}: {command.summary}', WIDTH),
        '',
        'options:',
        '  -h, --help   show this help and exit (before ROS starts)',
        '  --ros-args   ROS arguments as for every ROS 2 node (-p, --params-file, -r, --log-level)',
        '',
        'topics (relative names: -r __ns:=/scanner_1 gives /scanner_1/galvo/...):',
        *_topics('subscribes', topics.subscribes, width),
        *_topics('publishes', topics.publishes, width),
        '',
        *textwrap.wrap(
            f'parameters (-p NAME:=VALUE or --params-file FILE; a file with all of them and their '
            f'defaults: config/{command.config}, installed in share/galvo_sysid/config):',
            WIDTH),
    ]
    for spec in NODE_PARAMETERS[node]:
        lines += _parameter(spec)
    if command.note:
        lines += textwrap.wrap(command.note, WIDTH, initial_indent='  ', subsequent_indent='  ')
    lines += [
        '',
        'examples:',
        f'  {prog} --ros-args --params-file config/{command.config}',
        f'  {prog} --ros-args -r __ns:=/scanner_1 -p model:=scanner.yaml',
        f'  ros2 run galvo_sysid {node} --ros-args ...    (a full ROS 2 install)',
        '  galvo-sysid launch --namespace scanner_1      (driver, sysid and watchdog together)',
    ]
    return '\n'.join(lines) + '\n'


def print_help(node: str, args: Sequence[str]) -> bool:
    """Print the usage if ``args`` ask for it (:func:`wants_help`); return whether it did."""
    if not wants_help(args):
        return False
    prog = args[0].rsplit('/', 1)[-1] if args and args[0] else node
    if prog.endswith('.py') or prog == '-m':  # python -m galvo_sysid.nodes.<module>
        prog = node
    sys.stdout.write(usage(node, prog=prog))
    return True


def _run(node: str) -> int:
    if print_help(node, sys.argv):
        return 0
    module = importlib.import_module(NODES[node].module)
    code: int = module.main(sys.argv)
    return code


def galvo_driver() -> int:
    """Console script ``galvo_driver``."""
    return _run('galvo_driver')


def sysid() -> int:
    """Console script ``sysid``."""
    return _run('sysid')


def watchdog() -> int:
    """Console script ``watchdog``."""
    return _run('watchdog')
