"""``galvo-sysid launch``: the driver, sysid and watchdog nodes as child processes, stopped as one.

The stand-in for ``ros2 launch galvo_sysid monitor.launch.py`` where the ``launch`` package is
not installed: the same nodes with the same arguments (:func:`node_commands`, see
``launch/monitor.launch.py``). Plain processes, no rclpy: each child is a node module run by
this Python (``python -m galvo_sysid.nodes.sysid_node --ros-args ...``), so it runs the same
galvo_sysid as the launcher.

:func:`supervise` runs any such set of commands:

- The children run in a process group of their own: a terminal's Ctrl-C reaches only the
  launcher, which passes it on once (a node given two SIGINTs may not stop cleanly). On Linux
  a child also gets SIGTERM if the launcher dies without stopping it (``PR_SET_PDEATHSIG``).
- SIGINT or SIGTERM to the launcher stops them: SIGINT to every child still running, SIGTERM
  to those still running ``stop_timeout`` seconds later, SIGKILL after as long again; another
  SIGINT or SIGTERM meanwhile moves on to the next signal at once.
- A child that ends by itself is said in one line (exit code, or the signal that ended it);
  the others keep running, as ``ros2 launch`` does. The launcher ends when they all have.
- Exit code: 0 when every child ended with 0 (stopped by the first SIGINT, or done, e.g. a
  driver with ``cycles`` and ``exit_when_done``), else 1.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, TextIO

from galvo_sysid.errors import ConfigurationError

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping, Sequence
    from types import FrameType

__all__ = ['LAUNCH_ARGUMENTS', 'NODE_MODULES', 'STOP_TIMEOUT', 'Command', 'node_commands',
           'normalize_namespace', 'parse_params_file', 'supervise']

NODE_MODULES = {
    'galvo_driver': 'galvo_sysid.nodes.driver_node',
    'sysid': 'galvo_sysid.nodes.sysid_node',
    'watchdog': 'galvo_sysid.nodes.watchdog_node',
}
"""The nodes launched, in start order (node name = executable name), and their modules."""

LAUNCH_ARGUMENTS = ('namespace', 'model', 'driver', 'params_file',
                    *(f'{node}_params_file' for node in NODE_MODULES))
"""The arguments of ``launch/monitor.launch.py``; ``galvo-sysid launch`` takes the same as
options: ``--namespace``, ``--model``, ``--no-driver``, ``--params-file [NODE=]FILE``."""

STOP_TIMEOUT = 10.0
"""Seconds a child has after SIGINT before SIGTERM (and after SIGTERM before SIGKILL)."""

_NAMESPACE = re.compile(r'^(/[A-Za-z_][A-Za-z0-9_]*)+$')


@dataclass(frozen=True)
class Command:
    """One child process: a name for the messages and its command line."""

    name: str
    argv: tuple[str, ...]


def normalize_namespace(namespace: str) -> str:
    """``'scanner_1'`` or ``'/scanner_1'`` as ``'/scanner_1'``; ``''`` or ``'/'`` as ``''``.

    Raises:
        ConfigurationError: Not a valid ROS namespace.
    """
    text = namespace.strip()
    if text in ('', '/'):
        return ''
    text = '/' + text.strip('/')
    if not _NAMESPACE.match(text):
        msg = (f'namespace {namespace!r} is not a ROS namespace (names of letters, digits and '
               f'_, not starting with a digit, separated by /)')
        raise ConfigurationError(msg)
    return text


def parse_params_file(text: str) -> tuple[str, str]:
    """``'FILE'`` (for every node) or ``'NODE=FILE'`` (for one) as ``(node or '', file)``.

    Raises:
        ConfigurationError: An unknown node name, or no file.
    """
    node, sep, path = text.partition('=')
    if not sep or node not in NODE_MODULES:
        if sep and re.fullmatch(r'\w+', node):
            msg = f'unknown node {node!r} in {text!r}; nodes: {", ".join(NODE_MODULES)}'
            raise ConfigurationError(msg)
        node, path = '', text
    if not path:
        msg = f'no parameter file in {text!r}'
        raise ConfigurationError(msg)
    return node, path


def node_commands(*, namespace: str = '', model: str = '', driver: bool = True,
                  params_files: Sequence[tuple[str, str]] = (),
                  python: str = sys.executable) -> list[Command]:
    """The node processes of a launch, as ``launch/monitor.launch.py`` starts them.

    Each node gets, after ``--ros-args``: the namespace (``-r __ns:=``), the parameter files
    meant for every node (node ``''``) and then its own, in the order given (a later file
    wins), then ``-p model:=`` when a model file is given (it wins over the files).

    Args:
        namespace: The scanner's namespace (``''``: none).
        model: The plant-model file for all three nodes (``''``: the nodes' ``model``
            parameter as the files or the defaults set it).
        driver: Start the simulated scanner too (no: the moves come from a real one).
        params_files: ``(node, file)``, node ``''`` for every node (:func:`parse_params_file`).
        python: The interpreter that runs the node modules.

    Raises:
        ConfigurationError: A bad namespace or node name.
    """
    ns = normalize_namespace(namespace)
    for node, _ in params_files:
        if node and node not in NODE_MODULES:
            msg = f'unknown node {node!r}; nodes: {", ".join(NODE_MODULES)}'
            raise ConfigurationError(msg)
    out = []
    for node, module in NODE_MODULES.items():
        if node == 'galvo_driver' and not driver:
            continue
        ros = [*(('-r', f'__ns:={ns}') if ns else ())]
        for only in ('', node):
            ros += [x for who, path in params_files if who == only
                    for x in ('--params-file', path)]
        if model:
            ros += ['-p', f'model:={json.dumps(model)}']  # quoted: always text to rcl's YAML
        out.append(Command(node, (python, '-m', module, '--ros-args', *ros)))
    return out


def _die_with_parent() -> None:  # pragma: no cover - runs in the child between fork and exec
    """Ask Linux to send this process SIGTERM when its parent ends (``PR_SET_PDEATHSIG``)."""
    import ctypes

    with contextlib.suppress(Exception):
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM, 0, 0, 0)


def _ended(code: int) -> str:
    if code < 0:
        with contextlib.suppress(ValueError):
            return f'was ended by {signal.Signals(-code).name}'
        return f'was ended by signal {-code}'
    return f'exited with code {code}'


def _signal(proc: subprocess.Popen[bytes], sig: signal.Signals) -> None:
    """SIGINT and SIGTERM to the child (a node stops its own children); SIGKILL to its whole
    process group (its children too)."""  # noqa: D205, D209
    with contextlib.suppress(OSError):
        if sig == signal.SIGKILL:
            os.killpg(proc.pid, sig)
        else:
            proc.send_signal(sig)


class _Signals:
    """SIGINT and SIGTERM counted (and handled) while the children run."""

    def __init__(self) -> None:
        self.count = 0
        self._old: dict[int, Callable[[int, FrameType | None], object] | int | None] = {}

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        self.count += 1

    def __enter__(self) -> _Signals:
        for s in (signal.SIGINT, signal.SIGTERM):
            self._old[s] = signal.signal(s, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        for s, old in self._old.items():
            signal.signal(s, old)


def supervise(commands: Sequence[Command], *, stop_timeout: float = STOP_TIMEOUT,
              out: TextIO | None = None, label: str = 'galvo-sysid launch',
              env: Mapping[str, str] | None = None, poll: float = 0.05) -> int:
    """Run ``commands`` as child processes until they end or a signal stops them.

    Call from the main thread (it handles SIGINT and SIGTERM while it runs). The children
    share this process's stdout and stderr (the nodes' log lines name the node); this
    function's own lines go to ``out`` (default stderr), each starting with ``label``. See
    the module docs for the stopping and the exit code.

    Args:
        commands: The children, started in this order.
        stop_timeout: Seconds after SIGINT before SIGTERM, and after SIGTERM before SIGKILL.
        out: Where the launcher's own lines go.
        label: The start of those lines.
        env: The children's environment (default: this process's).
        poll: Seconds between looks at the children.

    Returns:
        The exit code: 0 when every child ended with 0, else 1.
    """
    stream = sys.stderr if out is None else out

    def say(text: str) -> None:
        stream.write(f'{label}: {text}\n')
        stream.flush()

    procs: dict[str, subprocess.Popen[bytes]] = {}
    codes: dict[str, int] = {}
    failed = False
    stage = 0  # signals sent so far: 0 none, 1 SIGINT, 2 SIGTERM, 3 SIGKILL
    with _Signals() as signals:
        try:
            for c in commands:
                if signals.count:
                    break
                procs[c.name] = subprocess.Popen(
                    c.argv, process_group=0, env=None if env is None else dict(env),
                    preexec_fn=_die_with_parent if sys.platform == 'linux' else None)
            say('started ' + ', '.join(f'{n} (pid {p.pid})' for n, p in procs.items()))
            deadline = float('inf')
            while len(codes) < len(procs):
                for name, p in procs.items():
                    code = p.poll()
                    if code is None or name in codes:
                        continue
                    codes[name] = code
                    if stage == 0:  # by itself
                        failed |= code != 0
                        say(f'{name} {_ended(code)}' + ('' if code == 0 else
                                                         ' (its output is above)'))
                    elif code != 0 and not (stage == 1 and code == -signal.SIGINT):
                        failed = True
                        say(f'{name} {_ended(code)} while stopping')
                if len(codes) == len(procs):
                    break
                if signals.count > stage or time.monotonic() > deadline:
                    stage = min(3, max(stage + 1, signals.count))
                    sig = (signal.SIGINT, signal.SIGTERM, signal.SIGKILL)[stage - 1]
                    running = [n for n in procs if n not in codes]
                    if stage > 1:
                        failed = True
                        say(f'{", ".join(running)} still running: sending {sig.name}')
                    for n in running:
                        _signal(procs[n], sig)
                    deadline = time.monotonic() + stop_timeout if stage < 3 else float('inf')
                time.sleep(poll)
        finally:
            for p in procs.values():  # never leave a child (or one of its own) behind
                if p.poll() is None:
                    _signal(p, signal.SIGKILL)
                    p.wait()
                with contextlib.suppress(OSError):  # what it left in its group, if anything
                    os.killpg(p.pid, signal.SIGKILL)
    if stage and not failed:
        say('stopped: ' + ', '.join(procs))
    return 1 if failed or not procs else 0
