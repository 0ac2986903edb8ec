"""Live ROS 2 tools behind ``galvo-sysid record``, ``replay`` and ``echo`` (rclpy).

They stand in for ``ros2 bag record``, ``ros2 bag play`` and ``ros2 topic echo`` where
ros2cli/rosbag2 are not installed (a pip-only machine); the bags are standard rosbag2.

- :func:`record` subscribes *raw* (serialized bytes, exactly as published) to topics of the
  live graph, with the message type and QoS taken from the publishers, and stores them with
  their definitions (:class:`~galvo_sysid.field.bags.BagWriter`); log time = receive time.
- :func:`replay` publishes a bag's serialized messages with their recorded timing scaled by
  a rate, after waiting for subscribers, optionally with ``/clock`` for ``use_sim_time``.
- :func:`echo` prints a live topic's messages as YAML (or JSON lines), type found from the
  graph.

Each returns a process exit code and stops cleanly on SIGINT/SIGTERM (Ctrl-C).
"""

from __future__ import annotations

import contextlib
import importlib
import json
import math
import signal
import sys
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TextIO

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.field.bags import GALVO_TOPICS, BagError, BagReader, BagWriter

if TYPE_CHECKING:
    import os
    from collections.abc import Callable, Iterator, Sequence
    from types import FrameType

    from rclpy.node import Node

__all__ = [
    'HIDDEN_TOPICS',
    'RecordSummary',
    'echo',
    'format_yaml',
    'message_class',
    'message_to_dict',
    'record',
    'replay',
]

HIDDEN_TOPICS = frozenset({'/rosout', '/parameter_events'})
"""Topics ``record --all`` leaves out (every node has them)."""


# --------------------------------------------------------------------------- helpers


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


def _absolute(topic: str) -> str:
    return topic if topic.startswith('/') else '/' + topic


class _Stop:
    """SIGINT/SIGTERM set a flag that the spin loops check (clean bag close)."""

    def __init__(self) -> None:
        self.requested = False
        self._old: dict[int, Any] = {}

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        self.requested = True

    def is_set(self) -> bool:
        """Whether a stop was requested."""
        return self.requested

    def __enter__(self) -> _Stop:
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._old[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)


@contextlib.contextmanager
def _ros_node(name: str) -> Iterator[Node]:
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        node = rclpy.create_node(name, start_parameter_services=False)
        yield node
    finally:
        if node is not None:
            node.destroy_node()
        with contextlib.suppress(Exception):
            rclpy.shutdown()


def _publisher_qos(node: Node, topic: str) -> tuple[bool, bool] | None:
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


def _subscription_qos(*, reliable: bool, transient_local: bool, depth: int) -> Any:
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=(DurabilityPolicy.TRANSIENT_LOCAL if transient_local
                    else DurabilityPolicy.VOLATILE))


def _say(stream: TextIO, text: str) -> None:
    stream.write(text + '\n')
    stream.flush()


# --------------------------------------------------------------------------- record


@dataclass
class RecordSummary:
    """What :func:`record` stored.

    Attributes:
        counts: Messages per topic.
        types: Message type per topic.
        seconds: Recording time [s].
    """

    counts: dict[str, int] = field(default_factory=dict)
    types: dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0


def record(out: str | os.PathLike[str], *, topics: Sequence[str] = GALVO_TOPICS,
           all_topics: bool = False, duration: float | None = None, storage: str = 'mcap',
           log: TextIO = sys.stderr,
           ready: Callable[[], None] | None = None) -> RecordSummary:
    """Record topics of the live graph into a new bag until ``duration`` or Ctrl-C.

    Topics are subscribed as soon as they have a publisher in the graph (also late ones),
    raw, with a QoS that matches the publishers (transient local when all offer it, so the
    last ``ModalParameters`` is caught; best effort when a publisher is best effort).

    Args:
        out: Bag directory to create.
        topics: Topics to record (absolute or relative to ``/``).
        all_topics: Record every topic except :data:`HIDDEN_TOPICS` instead.
        duration: Stop after this many seconds; None records until SIGINT/SIGTERM.
        storage: ``'mcap'`` or ``'sqlite3'``.
        log: Where progress lines go.
        ready: Called once subscriptions may be made (for tests).

    Raises:
        BagExistsError: ``out`` exists.
        ConfigurationError: A topic's type is not installed.
    """
    wanted = {_absolute(t) for t in topics}
    summary = RecordSummary()
    writer = BagWriter(out, storage=storage)
    writer.open()
    try:
        with _Stop() as stop, _ros_node('galvo_sysid_recorder') as node:
            import rclpy

            subscriptions: list[Any] = []
            clock = node.get_clock()

            def make_callback(topic: str) -> Callable[[bytes], None]:
                def callback(data: bytes) -> None:
                    writer.write_raw(topic, clock.now().nanoseconds, data)
                    summary.counts[topic] += 1
                return callback

            def discover() -> None:
                for topic, types in node.get_topic_names_and_types():
                    if topic in summary.types:
                        continue
                    if not (topic in wanted or (all_topics and topic not in HIDDEN_TOPICS)):
                        continue
                    if len(types) != 1:
                        _say(log, f'record: skipping {topic}: several types {types}')
                        summary.types[topic] = ''
                        continue
                    msgtype = types[0]
                    offered = _publisher_qos(node, topic)
                    if offered is None:  # known from a subscriber only: wait for a publisher
                        continue
                    reliable, transient = offered
                    writer.add_topic(topic, msgtype, reliable=reliable,
                                     transient_local=transient)
                    _check_hash(node, topic, msgtype, writer, log)
                    qos = _subscription_qos(reliable=reliable, transient_local=transient,
                                            depth=10000)
                    summary.types[topic] = msgtype
                    summary.counts[topic] = 0
                    subscriptions.append(node.create_subscription(
                        message_class(msgtype), topic, make_callback(topic), qos, raw=True))
                    _say(log, f'record: subscribed to {topic} [{msgtype}]')

            start = time.monotonic()
            next_discovery = start
            if ready is not None:
                ready()
            while not stop.is_set():
                now = time.monotonic()
                if duration is not None and now - start >= duration:
                    break
                if now >= next_discovery:
                    discover()
                    next_discovery = now + 0.25
                rclpy.spin_once(node, timeout_sec=0.05)
            summary.seconds = time.monotonic() - start
    finally:
        writer.close()
    for topic in sorted(wanted - set(summary.types)):
        _say(log, f'record: {topic} never appeared in the graph')
    summary.types = {k: v for k, v in summary.types.items() if v}
    return summary


def _check_hash(node: Node, topic: str, msgtype: str, writer: BagWriter, log: TextIO) -> None:
    """Warn when the live publishers' type hash differs from the stored definition's."""
    ours = writer.typestore.hash_rihs01(msgtype)
    for info in node.get_publishers_info_by_topic(topic):
        theirs = getattr(info, 'topic_type_hash', None)
        text = str(theirs) if theirs is not None else ''
        if text.startswith('RIHS01_') and text != ours:
            _say(log, f'record: warning: {topic} publisher type hash {text} differs from the '
                      f'stored definition {ours}; readers may fail to decode it')
            return


# --------------------------------------------------------------------------- replay


def replay(bag: str | os.PathLike[str], *, rate: float = 1.0, loop: bool = False,
           clock: bool = False, clock_frequency: float = 100.0,
           topics: Sequence[str] | None = None, wait: float = 10.0,
           log: TextIO = sys.stderr) -> int:
    """Publish a bag's messages with their recorded timing; return the number published.

    Args:
        bag: The bag.
        rate: Playback speed factor (2 = twice as fast); ``math.inf`` = as fast as possible.
        loop: Start over at the end until stopped.
        clock: Publish ``/clock`` (``rosgraph_msgs/Clock``) with the bag's log time, before
            each message and at ``clock_frequency`` Hz while waiting.
        clock_frequency: Rate of ``/clock`` between messages [Hz].
        topics: Only these topics (default: all in the bag).
        wait: Wait at most this long [s] for every topic to have a subscriber.
        log: Where progress lines go.

    Raises:
        BagError: The bag cannot be read.
        ConfigurationError: A type is not installed, or a bad rate.
    """
    if not rate > 0:
        msg = f'rate must be positive, got {rate}'
        raise ConfigurationError(msg)
    with BagReader(bag) as reader:
        info = reader.info
        wanted = [t for t in info.topics if topics is None or t.topic in
                  {_absolute(x) for x in topics}]
        if not wanted:
            msg = f'bag {bag} holds none of the topics {list(topics or [])}'
            raise BagError(msg)
        published = 0
        with _Stop() as stop, _ros_node('galvo_sysid_player') as node:
            from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

            publishers: dict[str, Any] = {}
            for t in wanted:
                history = HistoryPolicy.KEEP_LAST if t.transient_local else HistoryPolicy.KEEP_ALL
                qos = QoSProfile(
                    history=history,
                    depth=100, reliability=ReliabilityPolicy.RELIABLE,
                    durability=(DurabilityPolicy.TRANSIENT_LOCAL if t.transient_local
                                else DurabilityPolicy.VOLATILE))
                publishers[t.topic] = node.create_publisher(message_class(t.msgtype), t.topic,
                                                            qos)
            clock_pub: Any = None
            if clock:
                clock_pub = node.create_publisher(
                    message_class('rosgraph_msgs/msg/Clock'), '/clock',
                    QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))
            _wait_for_subscribers(publishers, wait, stop, log)
            clock_period = 1.0 / clock_frequency if clock_frequency > 0 else math.inf

            def publish_clock(ns: int) -> None:
                if clock_pub is not None:
                    from builtin_interfaces.msg import Time

                    sec, nanosec = divmod(ns, 1_000_000_000)
                    clock_pub.publish(clock_pub.msg_type(clock=Time(sec=sec, nanosec=nanosec)))

            while not stop.is_set():
                start_wall: float | None = None
                start_log = 0
                for raw in reader.raw_messages([t.topic for t in wanted]):
                    if start_wall is None:
                        start_wall, start_log = time.monotonic(), raw.timestamp
                    if math.isfinite(rate):
                        due = start_wall + (raw.timestamp - start_log) * 1e-9 / rate
                        while not stop.is_set() and (left := due - time.monotonic()) > 0:
                            pause = min(left, clock_period)
                            time.sleep(pause)
                            if clock_pub is not None and due - time.monotonic() > 0:
                                elapsed = (time.monotonic() - start_wall) * rate
                                publish_clock(start_log + round(elapsed * 1e9))
                    if stop.is_set():
                        break
                    publish_clock(raw.timestamp)
                    publishers[raw.topic].publish(raw.data)
                    published += 1
                if not loop or start_wall is None:
                    break
            from rclpy.duration import Duration

            for pub in publishers.values():
                pub.wait_for_all_acked(Duration(seconds=5))
    _say(log, f'replay: published {published} messages')
    return published


def _wait_for_subscribers(publishers: dict[str, Any], wait: float, stop: _Stop,
                          log: TextIO) -> None:
    deadline = time.monotonic() + wait
    said = False
    while not stop.is_set():
        missing = [t for t, p in publishers.items() if p.get_subscription_count() == 0]
        if not missing:
            return
        if time.monotonic() >= deadline:
            _say(log, f'replay: no subscriber on {", ".join(missing)} after {wait:g} s; '
                      'publishing anyway')
            return
        if not said:
            _say(log, f'replay: waiting up to {wait:g} s for subscribers on '
                      f'{", ".join(missing)}')
            said = True
        time.sleep(0.05)


# --------------------------------------------------------------------------- echo


def echo(topic: str, *, once: bool = False, as_json: bool = False,
         timeout: float | None = None, out: TextIO = sys.stdout,
         log: TextIO = sys.stderr) -> int:
    """Print a live topic's messages (YAML documents, or one JSON object per line).

    The type is found from the graph (waits for the topic to appear); the QoS matches the
    publishers, so a transient-local topic's last message is printed at once.

    Args:
        topic: Topic name (relative names are taken from ``/``).
        once: Exit after the first message.
        as_json: One JSON object per line instead of YAML.
        timeout: Give up after this many seconds without any message (exit code 1).
        out: Where messages go.
        log: Where status lines go.

    Returns:
        Process exit code: 0, or 1 on timeout.

    Raises:
        ConfigurationError: The topic's type is not installed.
    """
    import rclpy

    name = _absolute(topic)
    start = time.monotonic()
    count = 0
    with _Stop() as stop, _ros_node('galvo_sysid_echo') as node:
        msgtype = None
        offered = None
        said = False
        while not stop.is_set():
            types = dict(node.get_topic_names_and_types()).get(name)
            offered = _publisher_qos(node, name) if types else None
            if types and offered is not None:  # a publisher, not only other subscribers
                msgtype = types[0]
                break
            elapsed = time.monotonic() - start
            if timeout is not None and elapsed > timeout:
                _say(log, f'echo: topic {name} did not appear within {timeout:g} s')
                return 1
            if not said and elapsed > 1.0:
                _say(log, f'echo: waiting for a publisher on {name}...')
                said = True
            time.sleep(0.1)
        if msgtype is None or offered is None:
            return 0
        reliable, transient = offered

        def callback(message: Any) -> None:
            nonlocal count
            count += 1
            data = message_to_dict(message)
            if as_json:
                out.write(json.dumps(data) + '\n')
            else:
                out.write(format_yaml(data) + '\n---\n')
            out.flush()

        node.create_subscription(message_class(msgtype), name, callback,
                                 _subscription_qos(reliable=reliable, transient_local=transient,
                                                   depth=100))
        while not stop.is_set() and not (once and count):
            rclpy.spin_once(node, timeout_sec=0.1)
            if count == 0 and timeout is not None and time.monotonic() - start > timeout:
                _say(log, f'echo: no message on {name} within {timeout:g} s')
                return 1
    return 0
