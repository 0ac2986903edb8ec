"""What the live tools share: rclpy message classes, a node, QoS that matches publishers, stop.

Each tool runs one short-lived rclpy node (:func:`ros_node`) and stops cleanly on
SIGINT/SIGTERM (:class:`Stop`).
"""

from __future__ import annotations

import contextlib
import importlib
import os
import signal
import subprocess
import sys
import time
from typing import TYPE_CHECKING, Any, TextIO

from galvo_sysid.errors import ConfigurationError

if TYPE_CHECKING:
    from collections.abc import Iterator
    from types import FrameType

    from rclpy.node import Node

__all__ = [
    'TEARDOWN_TIMEOUT',
    'Stop',
    'absolute',
    'message_class',
    'node_names',
    'publisher_qos',
    'ros_node',
    'say',
    'subscription_qos',
    'teardown_deadline',
    'wait_for_publisher',
]

TEARDOWN_TIMEOUT = 10.0
"""Seconds a tool's node teardown may take before the process is killed (normally < 1 s)."""


def message_class(msgtype: str) -> Any:
    """The rclpy message class of ``pkg/msg/Name`` (imports ``pkg.msg``).

    Raises:
        ConfigurationError: The type's Python package is not installed.
    """
    parts = msgtype.split('/')
    if len(parts) == 2:  # 'pkg/Name'
        parts = [parts[0], 'msg', parts[1]]
    if len(parts) != 3 or parts[1] != 'msg':  # 'pkg/msg/Name'
        msg = f'not a message type: {msgtype!r}'
        raise ConfigurationError(msg)
    try:
        module = importlib.import_module(f'{parts[0]}.msg')
        return getattr(module, parts[2])
    except (ImportError, AttributeError):
        msg = f'message type {msgtype} is not installed (no Python module {parts[0]}.msg)'
        raise ConfigurationError(msg) from None


def absolute(topic: str) -> str:
    """A topic (or node) name taken from ``/`` (``'galvo/drift'`` -> ``'/galvo/drift'``)."""
    return topic if topic.startswith('/') else '/' + topic


def node_names(node: Node) -> set[str]:
    """The full names of the nodes on the graph (``/scanner_1/sysid``), as discovered so far."""
    return {f'{ns.rstrip("/")}/{name}' for name, ns in node.get_node_names_and_namespaces()}


class Stop:
    """SIGINT/SIGTERM set a flag that the spin loops check (clean bag close)."""

    def __init__(self) -> None:
        self.requested = False
        self._old: dict[int, Any] = {}

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        self.requested = True

    def is_set(self) -> bool:
        """Whether a stop was requested."""
        return self.requested

    def __enter__(self) -> Stop:
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._old[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)


@contextlib.contextmanager
def ros_node(name: str) -> Iterator[Node]:
    """A node of a freshly initialised rclpy, shut down at the end; no rclpy signal handlers,
    no ROS arguments from the command line."""  # noqa: D205, D209
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from galvo_sysid import bounded_dds_memory

    bounded_dds_memory()  # before the participant exists: record takes whatever is sent
    # no command-line arguments for rcl: it would take the tool's own (replay --remap
    # OLD:=NEW) for ROS remapping rules of this node
    rclpy.init(args=[name], signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        node = rclpy.create_node(name, start_parameter_services=False)
        yield node
    finally:
        with teardown_deadline(TEARDOWN_TIMEOUT):
            if node is not None:
                node.destroy_node()
            with contextlib.suppress(Exception):
                rclpy.shutdown()


# cat ends when the pipe closes; only timeout's own 124 (time is up) kills (no timeout
# program: 127, the tool goes on without a deadline, silently)
_WATCHDOG = ('timeout "$1" cat >/dev/null 2>&1; [ $? -eq 124 ] || exit 0;'
             ' echo "$2" >&2; kill -9 "$3"')


@contextlib.contextmanager
def teardown_deadline(seconds: float) -> Iterator[None]:
    """Kill this process, with a one-line message, if the block outlasts ``seconds``.

    The middleware's teardown can hang (a DDS participant that never finishes deleting,
    seen once under load: ``destroy_node`` spinning for an hour). It may hold the GIL there,
    so no Python thread or signal handler would run; the watchdog is a separate ``sh``
    that waits on a pipe from this process. When the block ends the pipe closes and the
    watchdog exits; so does it when this process dies in any other way (no stale PID is
    ever killed). Standard output and error are flushed first, so what the tool printed
    is complete either way.
    """
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    message = (f'galvo-sysid: error: the ROS middleware did not shut down within {seconds:g} s;'
               ' killed (the output above is complete)')
    try:
        watchdog = subprocess.Popen(
            ['/bin/sh', '-c', _WATCHDOG, 'watchdog', f'{seconds:g}', message, str(os.getpid())],
            stdin=subprocess.PIPE, stdout=subprocess.DEVNULL)
    except OSError:  # no sh or timeout here: tear down without a deadline
        yield
        return
    try:
        yield
    finally:
        if watchdog.stdin is not None:
            watchdog.stdin.close()
        with contextlib.suppress(subprocess.TimeoutExpired):
            watchdog.wait(timeout=1.0)


def publisher_qos(node: Node, topic: str) -> tuple[bool, bool] | None:
    """(reliable, transient local) that match every publisher of a live topic.

    A subscription asking for more than a publisher offers does not match it, so reliable
    and transient local are asked for only when all publishers offer them (then a late
    subscriber still gets a transient-local topic's last messages). None while the topic
    has no publisher (it may be known from a subscriber only).
    """
    from rclpy.qos import DurabilityPolicy, ReliabilityPolicy

    infos = node.get_publishers_info_by_topic(topic)
    if not infos:
        return None
    reliable = all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in infos)
    transient = all(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos)
    return reliable, transient


def subscription_qos(*, reliable: bool, transient_local: bool, depth: int) -> Any:
    """A keep-last subscription QoS (see :func:`publisher_qos` for what matches)."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=(DurabilityPolicy.TRANSIENT_LOCAL if transient_local
                    else DurabilityPolicy.VOLATILE))


def say(stream: TextIO, text: str) -> None:
    """Write one progress line and flush it (the tools run for long)."""
    stream.write(text + '\n')
    stream.flush()


def wait_for_publisher(node: Node, name: str, *, tool: str, stop: Stop, start: float,
                       timeout: float | None, log: TextIO) -> tuple[str, bool, bool] | None:
    """Wait until a live topic has a publisher: its type and the QoS that matches it.

    A topic known only from subscribers does not count (its QoS comes from publishers).
    Says once what it waits for (``<tool>: waiting for a publisher on /x...``).

    Args:
        node: Our node.
        name: The absolute topic name.
        tool: The tool's name, first word of the lines said.
        stop: Ends the wait early.
        start: When the tool started (``time.monotonic()``): ``timeout`` counts from there.
        timeout: Give up after this many seconds (None: wait until stopped).
        log: Where the lines go.

    Returns:
        ``(type, reliable, transient_local)``, or None when stopped or timed out (then said:
        ``<tool>: topic /x did not appear within S s``).
    """
    said: set[str] = set()  # the waiting lines said (each once)
    while not stop.is_set():
        types = dict(node.get_topic_names_and_types()).get(name)
        offered = publisher_qos(node, name) if types else None
        if types and offered is not None:  # a publisher, not only other subscribers
            return types[0], offered[0], offered[1]
        elapsed = time.monotonic() - start
        if timeout is not None and elapsed > timeout:
            say(log, f'{tool}: topic {name} did not appear within {timeout:g} s')
            return None
        if types and 'subscribers' not in said:
            say(log, f'{tool}: waiting for a publisher on {name} (it has subscribers only)...')
            said.add('subscribers')
        elif not said and elapsed > 1.0:
            say(log, f'{tool}: waiting for a publisher on {name}...')
            said.add('publisher')
        time.sleep(0.1)
    return None
