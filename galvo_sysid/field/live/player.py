"""``replay``: a bag's messages published with their recorded timing, optionally ``/clock``."""

from __future__ import annotations

import math
import sys
import time
from typing import TYPE_CHECKING, Any, TextIO

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.field.bags import BagError, BagReader
from galvo_sysid.field.live.graph import Stop, absolute, message_class, ros_node, say

if TYPE_CHECKING:
    import os
    from collections.abc import Sequence

__all__ = ['replay']


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
                  {absolute(x) for x in topics}]
        if not wanted:
            msg = f'bag {bag} holds none of the topics {list(topics or [])}'
            raise BagError(msg)
        published = 0
        with Stop() as stop, ros_node('galvo_sysid_player') as node:
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
    say(log, f'replay: published {published} messages')
    return published


def _wait_for_subscribers(publishers: dict[str, Any], wait: float, stop: Stop,
                          log: TextIO) -> None:
    deadline = time.monotonic() + wait
    said = False
    while not stop.is_set():
        missing = [t for t, p in publishers.items() if p.get_subscription_count() == 0]
        if not missing:
            return
        if time.monotonic() >= deadline:
            say(log, f'replay: no subscriber on {", ".join(missing)} after {wait:g} s; '
                      'publishing anyway')
            return
        if not said:
            say(log, f'replay: waiting up to {wait:g} s for subscribers on '
                      f'{", ".join(missing)}')
            said = True
        time.sleep(0.05)
