"""``record``: topics of the live graph into a new bag, raw, as published."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TextIO

from galvo_sysid.field.bags import BagWriter
from galvo_sysid.field.live.graph import (
    Stop,
    absolute,
    message_class,
    publisher_qos,
    ros_node,
    say,
    subscription_qos,
)
from galvo_sysid.interfaces.topics import GALVO_TOPICS

if TYPE_CHECKING:
    import os
    from collections.abc import Callable, Sequence

    from rclpy.node import Node

__all__ = ['HIDDEN_TOPICS', 'RecordSummary', 'record']

HIDDEN_TOPICS = frozenset({'/rosout', '/parameter_events'})
"""Topics ``record --all`` leaves out (every node has them)."""


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
    wanted = {absolute(t) for t in topics}
    summary = RecordSummary()
    writer = BagWriter(out, storage=storage)
    writer.open()
    try:
        with Stop() as stop, ros_node('galvo_sysid_recorder') as node:
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
                        say(log, f'record: skipping {topic}: several types {types}')
                        summary.types[topic] = ''
                        continue
                    msgtype = types[0]
                    offered = publisher_qos(node, topic)
                    if offered is None:  # known from a subscriber only: wait for a publisher
                        continue
                    reliable, transient = offered
                    writer.add_topic(topic, msgtype, reliable=reliable,
                                     transient_local=transient)
                    _check_hash(node, topic, msgtype, writer, log)
                    qos = subscription_qos(reliable=reliable, transient_local=transient,
                                            depth=10000)
                    summary.types[topic] = msgtype
                    summary.counts[topic] = 0
                    subscriptions.append(node.create_subscription(
                        message_class(msgtype), topic, make_callback(topic), qos, raw=True))
                    say(log, f'record: subscribed to {topic} [{msgtype}]')

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
        say(log, f'record: {topic} never appeared in the graph')
    summary.types = {k: v for k, v in summary.types.items() if v}
    return summary


def _check_hash(node: Node, topic: str, msgtype: str, writer: BagWriter, log: TextIO) -> None:
    """Warn when the live publishers' type hash differs from the stored definition's."""
    ours = writer.typestore.hash_rihs01(msgtype)
    for info in node.get_publishers_info_by_topic(topic):
        theirs = getattr(info, 'topic_type_hash', None)
        text = str(theirs) if theirs is not None else ''
        if text.startswith('RIHS01_') and text != ours:
            say(log, f'record: warning: {topic} publisher type hash {text} differs from the '
                      f'stored definition {ours}; readers may fail to decode it')
            return
