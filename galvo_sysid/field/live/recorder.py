"""``record``: topics of the live graph into a new bag, raw, as published."""

from __future__ import annotations

import contextlib
import sys
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TextIO

from galvo_sysid.field.bags import BagWriteError, BagWriter
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
        counts: Messages received per topic.
        types: Message type per topic.
        seconds: Recording time [s].
        kept: Messages in the bag (all received ones, unless writing failed).
        error: Why the recording stopped early (a failed write, e.g. a full disk; the bag
            is closed with what was written before), or None.
    """

    counts: dict[str, int] = field(default_factory=dict)
    types: dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0
    kept: int = 0
    error: BagWriteError | None = None


def record(out: str | os.PathLike[str], *, topics: Sequence[str] = GALVO_TOPICS,
           all_topics: bool = False, duration: float | None = None, storage: str = 'mcap',
           flush_interval: float = 1.0, log: TextIO = sys.stderr,
           ready: Callable[[], None] | None = None) -> RecordSummary:
    """Record topics of the live graph into a new bag until ``duration`` or Ctrl-C.

    What survives a crash: messages reach the bag's file at least every ``flush_interval``
    seconds; a killed recording keeps them (``galvo-sysid bag recover`` finishes the bag).
    A failed write (a full disk) stops the recording: the bag is closed with what was
    written before and :attr:`RecordSummary.error` says what happened.

    Topics are subscribed as soon as they have a publisher in the graph (also late ones),
    raw, with a QoS that matches the publishers (transient local when all offer it, so the
    last ``ModalParameters`` is caught; best effort when a publisher is best effort).

    Args:
        out: Bag directory to create.
        topics: Topics to record (absolute or relative to ``/``).
        all_topics: Record every topic except :data:`HIDDEN_TOPICS` instead.
        duration: Stop after this many seconds; None records until SIGINT/SIGTERM.
        storage: ``'mcap'`` or ``'sqlite3'``.
        flush_interval: Longest time a received message waits in memory [s].
        log: Where progress lines go.
        ready: Called once subscriptions may be made (for tests).

    Raises:
        BagExistsError: ``out`` exists.
        BagWriteError: The bag cannot be created.
        ConfigurationError: A topic's type is not installed.
    """
    wanted = {absolute(t) for t in topics}
    summary = RecordSummary()
    writer = BagWriter(out, storage=storage, flush_interval=flush_interval)
    writer.open()
    try:
        with Stop() as stop, ros_node('galvo_sysid_recorder') as node:
            import rclpy

            subscriptions: list[Any] = []
            clock = node.get_clock()

            def make_callback(topic: str) -> Callable[[bytes], None]:
                def callback(data: bytes) -> None:
                    if writer.error is not None:
                        return
                    summary.counts[topic] += 1
                    with contextlib.suppress(BagWriteError):  # kept in writer.error: stop
                        writer.write_raw(topic, clock.now().nanoseconds, data)
                return callback

            waiting: set[str] = set()

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
                        if topic not in waiting:
                            say(log, f'record: {topic} has subscribers only: waiting for a '
                                     f'publisher (its QoS)')
                            waiting.add(topic)
                        continue
                    reliable, transient = offered
                    try:  # discovery tells no history depth (rclpy: unknown, 0): so stored
                        writer.add_topic(topic, msgtype, reliable=reliable,
                                         transient_local=transient, depth=None)
                    except BagWriteError:  # kept in writer.error: stop
                        return
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
            while not stop.is_set() and writer.error is None:
                now = time.monotonic()
                if duration is not None and now - start >= duration:
                    break
                if now >= next_discovery:
                    discover()
                    next_discovery = now + 0.25
                rclpy.spin_once(node, timeout_sec=0.05)
                with contextlib.suppress(BagWriteError):  # kept in writer.error: stop
                    writer.tick()
            summary.seconds = time.monotonic() - start
    finally:
        with contextlib.suppress(BagWriteError):  # kept in writer.error
            writer.close()
        summary.kept = writer.kept
        summary.error = writer.error
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
