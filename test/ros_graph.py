"""Shared by the reliability tests over real DDS: child node processes and the test's own node.

- :class:`Proc`: a node executable (or any command) as a child process, console to a file;
  stopped by SIGINT then SIGKILL, or killed outright; its own fit children are found by
  their parent pid so nothing is left running.
- :class:`Graph`: the test's rclpy context, node and executor; ``spin_until`` waits on a
  condition with a deadline (no fixed sleeps); parameter service calls.
- :func:`move_messages`: simulated moves as ``MoveSamples`` pairs with chosen stamps.
- :func:`counters`: the ``counters: ...`` lines the sysid node logs every ``stats_period``.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest
import rclpy
from galvo_sysid_msgs.msg import MoveSamples
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from galvo_sysid.interfaces.messages import fill, fill_header, move_samples_fields

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Sequence

    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from galvo_sysid.sim.config import Move

RESULTS_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
MOVES_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)


def children(pid: int) -> list[int]:
    """Pids whose parent is ``pid``."""
    out = []
    for stat in Path('/proc').glob('[0-9]*/stat'):
        try:
            fields = stat.read_text().rsplit(')', 1)[1].split()
        except (OSError, IndexError):
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


def descendants(pid: int) -> list[int]:
    """Pids below ``pid``: its children, theirs, and so on.

    sysid's fit processes are children of its fork server.
    """
    parent_of: dict[int, int] = {}
    for stat in Path('/proc').glob('[0-9]*/stat'):
        try:
            parent_of[int(stat.parent.name)] = int(stat.read_text().rsplit(')', 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
    out: list[int] = []
    level = [pid]
    while level:
        level = [p for p, q in parent_of.items() if q in level]
        out.extend(level)
    return out


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie counts as gone)."""
    try:
        state = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != 'Z'


def rss_kib(pid: int) -> int:
    """Resident memory of one process [KiB] (0 if it is gone)."""
    try:
        for line in Path(f'/proc/{pid}/status').read_text().splitlines():
            if line.startswith('VmRSS:'):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


class Proc:
    """A child process with its console output in a file."""

    def __init__(self, argv: Sequence[str], log: Path, *, env: dict[str, str] | None = None
                 ) -> None:
        self.argv = list(argv)
        self.log = log
        self._file = log.open('w')
        self.popen = subprocess.Popen(self.argv, stdout=self._file, stderr=subprocess.STDOUT,
                                      env=env)
        self.pid = self.popen.pid
        self.known_children: set[int] = set()

    @property
    def running(self) -> bool:
        return self.popen.poll() is None

    def note_children(self) -> list[int]:
        """Remember (and return) the processes below this one now.

        E.g. sysid's fork server and fit processes.
        """
        found = descendants(self.pid)
        self.known_children.update(found)
        return found

    def stop(self, *, timeout: float = 10.0) -> int:
        """SIGINT, then SIGKILL after ``timeout``; also ends children that outlive it."""
        if self.running:
            self.note_children()
            self.popen.send_signal(signal.SIGINT)
            try:
                self.popen.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                # a hung stop: the node prints every thread's stack to its log first
                self.popen.send_signal(signal.SIGUSR1)
                with contextlib.suppress(subprocess.TimeoutExpired):
                    self.popen.wait(timeout=1.0)
                self.popen.kill()
                self.popen.wait(timeout=10)
        self._reap_children()
        if not self._file.closed:
            self._file.close()
        return self.popen.returncode

    def kill(self) -> None:
        """SIGKILL (a crash): no clean-up code runs in the process."""
        self.note_children()
        self.popen.kill()
        self.popen.wait(timeout=10)

    def _reap_children(self) -> None:
        for pid in sorted(self.known_children):
            if alive(pid):
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)

    def text(self) -> str:
        if not self._file.closed:
            self._file.flush()
        return self.log.read_text(errors='replace')


class Graph:
    """The test's own rclpy node and the processes it started (all stopped by ``close``)."""

    def __init__(self, venv_bin: Path, tmp: Path, *, name: str = 'reliability_test') -> None:
        self.venv_bin = venv_bin
        self.tmp = tmp
        self.procs: list[Proc] = []
        self.context = Context()
        rclpy.init(context=self.context)
        self.node: Node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def start(self, exe: str, name: str, *ros_args: str, prefix: Sequence[str] = (),
              env: dict[str, str] | None = None) -> Proc:
        """Start a node executable of the venv with ``--ros-args ros_args``."""
        argv = [*prefix, str(self.venv_bin / exe), '--ros-args', *ros_args]
        proc = Proc(argv, self.tmp / f'{name}.log', env=env)
        self.procs.append(proc)
        return proc

    def run(self, argv: Sequence[str], name: str, *, env: dict[str, str] | None = None) -> Proc:
        """Start any command as a child process."""
        proc = Proc(argv, self.tmp / f'{name}.log', env=env)
        self.procs.append(proc)
        return proc

    def logs(self, tail: int = 3000) -> str:
        return '\n'.join(f'--- {p.log.name}\n{p.text()[-tail:]}' for p in self.procs)

    def spin_until(self, done: Callable[[], bool], timeout: float, what: str) -> float:
        """Spin until ``done()``; fail with the processes' logs after ``timeout``.

        Returns:
            The monotonic time at which ``done()`` was first true.
        """
        end = time.monotonic() + timeout
        while not done():
            if time.monotonic() > end:
                pytest.fail(f'timed out after {timeout} s waiting for {what}\n{self.logs()}')
            self.executor.spin_once(timeout_sec=0.02)
        return time.monotonic()

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=min(0.02, max(0.0, end - time.monotonic())))

    def _client(self, node_name: str) -> AsyncParameterClient:
        client = AsyncParameterClient(self.node, node_name)
        self.spin_until(client.services_are_ready, 30, f'{node_name} parameter services')
        return client

    def set_parameters(self, node_name: str, params: list[Parameter]) -> list[Any]:
        """Set parameters one call each (so one rejection does not hide another)."""
        client = self._client(node_name)
        return [self._call(lambda p=p: client.set_parameters([p]), f'set_parameters {p.name}')
                .results[0] for p in params]

    def set_parameters_together(self, node_name: str, params: list[Parameter]) -> list[Any]:
        """Set parameters in one request (the node's callback sees them one by one)."""
        client = self._client(node_name)
        return list(self._call(lambda: client.set_parameters(params), 'set_parameters').results)

    def _call(self, request: Callable[[], Any], what: str, *, attempts: int = 4,
              timeout: float = 5.0) -> Any:
        """Send a service request, again if no answer came (a fresh client's first request
        can be lost while the server has not yet discovered the client's response reader)."""
        for _ in range(attempts - 1):
            future = request()
            end = time.monotonic() + timeout
            while not future.done() and time.monotonic() < end:
                self.executor.spin_once(timeout_sec=0.05)
            if future.done():
                return future.result()
            future.cancel()
        future = request()
        self.spin_until(future.done, timeout, what)
        return future.result()

    def get_parameters(self, node_name: str, names: list[str]) -> dict[str, Any]:
        """Current values (plain Python) of ``names``."""
        from rclpy.parameter import parameter_value_to_python

        client = self._client(node_name)
        values = self._call(lambda: client.get_parameters(names), 'get_parameters').values
        return {n: parameter_value_to_python(v) for n, v in zip(names, values, strict=True)}

    def close(self) -> None:
        for p in self.procs:
            p.stop()
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


def move_message(move: Move, signal_name: str, *, stamp: float,
                 move_id: int | None = None) -> MoveSamples:
    """One half of a simulated move as a ``MoveSamples`` message."""
    data = move.current if signal_name == 'current' else move.encoder
    msg = fill(MoveSamples(), move_samples_fields(
        move_id=move.move_id if move_id is None else move_id, target_angle=move.target_angle,
        sample_period=move.sample_period, data=data))
    fill_header(msg, stamp=stamp)
    return msg


def move_messages(moves: Iterable[Move], *, t0: float) -> list[tuple[str, MoveSamples]]:
    """Both halves of each move (current first), stamped ``t0`` + the move's own stamp."""
    out = []
    for m in moves:
        for s in ('current', 'encoder'):
            out.append((s, move_message(m, s, stamp=t0 + m.stamp)))
    return out


_COUNTERS = re.compile(r'counters: (.*)\n')


def counters(text: str) -> list[dict[str, int]]:
    """The sysid node's logged counter lines, oldest first.

    Only complete lines count: the log is read while the node writes it, and a line cut
    short mid-write would parse as a wrong counter or not at all.
    """
    out = []
    for m in _COUNTERS.finditer(text):
        out.append({k: int(v) for k, v in (kv.split('=') for kv in m.group(1).split(', '))})
    return out


def wait_matched(graph: Graph, pubs: Iterable[Any], *, count: int = 1,
                 timeout: float = 30) -> None:
    """Wait until every publisher has at least ``count`` subscribers."""
    items = list(pubs)
    graph.spin_until(lambda: all(p.get_subscription_count() >= count for p in items), timeout,
                     'subscribers to match')


def subscriber_ids(graph: Graph, topic: str) -> set[bytes]:
    """Endpoint gids of the subscriptions on ``topic`` (a killed one stays until its lease
    runs out, so a count alone cannot tell a restarted node from the dead one)."""
    return {bytes(info.endpoint_gid) for info in
            graph.node.get_subscriptions_info_by_topic(topic)}


def wait_new_subscribers(graph: Graph, topics: Iterable[str], old: dict[str, set[bytes]], *,
                         timeout: float = 30) -> None:
    """Wait until each topic has a subscription that is not in ``old[topic]``."""
    names = list(topics)
    graph.spin_until(lambda: all(subscriber_ids(graph, t) - old.get(t, set()) for t in names),
                     timeout, f'new subscribers on {names}')


def together(venv_bin: Path, *calls: Sequence[str]) -> list[subprocess.CompletedProcess[str]]:
    """Run ``galvo-sysid`` commands side by side; their results in order."""
    procs = [subprocess.Popen([str(venv_bin / 'galvo-sysid'), *call], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for call in calls]
    out = []
    try:
        for call, proc in zip(calls, procs, strict=True):
            stdout, stderr = proc.communicate(timeout=90)
            out.append(subprocess.CompletedProcess(list(call), proc.returncode, stdout, stderr))
    finally:  # a command that hangs must not outlive the test (one spun a core for an hour)
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    return out
