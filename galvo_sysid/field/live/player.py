"""``replay``: a bag's move messages published with their recorded timing, optionally ``/clock``.

By default only the moves (:data:`~galvo_sysid.interfaces.topics.MOVE_TOPICS`, in any
namespace: ``/galvo/current``, ``/galvo/encoder``) are published: a bag's recorded results
(``/galvo/modal_parameters``, ``/galvo/drift``) are stale, and the nodes compute them afresh
from the moves. ``topics`` or ``all_topics`` choose others; ``remap`` renames them.
"""

from __future__ import annotations

import math
import sys
import time
from typing import TYPE_CHECKING, Any, TextIO

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.field.bags import BagError, BagReader
from galvo_sysid.field.live.graph import Stop, absolute, message_class, ros_node, say
from galvo_sysid.interfaces.topics import MOVE_TOPICS, galvo_topic

if TYPE_CHECKING:
    import os
    from collections.abc import Mapping, Sequence

__all__ = ['MAX_WAIT', 'replay']

MAX_WAIT = 3600.0
"""Longest wait for subscribers [s] (the wait is always bounded)."""

_MOVES = {t.lstrip('/') for t in MOVE_TOPICS}


def _chosen(bag: object, held: Sequence[str], topics: Sequence[str] | None,
            all_topics: bool) -> list[str]:
    """The bag's topics to publish: the moves, ``topics`` (each must be in the bag) or all."""
    if all_topics:
        return list(held)
    if topics is None:
        chosen = [t for t in held if galvo_topic(t) in _MOVES]
        if not chosen:
            msg = (f'bag {bag} holds no move topic ({", ".join(MOVE_TOPICS)}, in any '
                   f'namespace); it holds {", ".join(held) or "no topic"}: choose with '
                   '--topics or --all-topics')
            raise BagError(msg)
        return chosen
    names = list(dict.fromkeys(absolute(t) for t in topics))
    missing = [t for t in names if t not in held]
    if missing:
        msg = (f'bag {bag} holds no topic {", ".join(missing)}; it holds '
               f'{", ".join(held) or "no topic"}')
        raise BagError(msg)
    return names


def _renamed(chosen: Sequence[str], remap: Mapping[str, str] | None) -> dict[str, str]:
    """The name each chosen topic is published under (``remap``: old name -> new name)."""
    rules = {absolute(old): absolute(new) for old, new in (remap or {}).items()}
    unknown = [old for old in rules if old not in chosen]
    if unknown:
        msg = (f'remap {", ".join(unknown)}: not a topic the replay publishes (it publishes '
               f'{", ".join(chosen)})')
        raise ConfigurationError(msg)
    names = {t: rules.get(t, t) for t in chosen}
    for name in names.values():
        same = [t for t, n in names.items() if n == name]
        if len(same) > 1:
            msg = f'remap gives {" and ".join(same)} one name, {name}'
            raise ConfigurationError(msg)
    return names


def replay(bag: str | os.PathLike[str], *, rate: float = 1.0, loop: bool = False,
           clock: bool = False, clock_frequency: float = 100.0,
           topics: Sequence[str] | None = None, all_topics: bool = False,
           remap: Mapping[str, str] | None = None, wait: float = 10.0,
           log: TextIO = sys.stderr) -> int:
    """Publish a bag's messages with their recorded timing; return the number published.

    Publishers are made for the published topics only, and the replay waits (at most
    ``wait`` seconds) until each has a subscriber, then publishes anyway (saying which had
    none); ``/clock`` is not waited for.

    Args:
        bag: The bag.
        rate: Playback speed factor (2 = twice as fast); ``math.inf`` = as fast as possible.
        loop: Start over at the end until stopped.
        clock: Publish ``/clock`` (``rosgraph_msgs/Clock``) with the bag's log time, before
            each message and at ``clock_frequency`` Hz while waiting.
        clock_frequency: Rate of ``/clock`` between messages [Hz].
        topics: Publish these topics of the bag (each must be in it) instead of the moves
            (:data:`~galvo_sysid.interfaces.topics.MOVE_TOPICS`, in any namespace).
        all_topics: Publish every topic of the bag.
        remap: Publish topic ``old`` as ``new`` (``{old: new}``, like ``--remap old:=new``).
        wait: Wait at most this long [s] for each published topic to have a subscriber
            (0: not at all; at most :data:`MAX_WAIT`).
        log: Where progress lines go.

    Raises:
        BagError: The bag cannot be read, or holds none of the topics to publish.
        ConfigurationError: A type is not installed, a bad rate or wait, or a remap of a
            topic not published.
    """
    if not rate > 0:
        msg = f'rate must be positive, got {rate}'
        raise ConfigurationError(msg)
    if not 0 <= wait <= MAX_WAIT:
        msg = f'wait must be within 0..{MAX_WAIT:g} s, got {wait}'
        raise ConfigurationError(msg)
    with BagReader(bag) as reader:
        info = reader.info
        held = [t.topic for t in info.topics]
        chosen = _chosen(bag, held, topics, all_topics)
        names = _renamed(chosen, remap)
        wanted = [t for t in info.topics if t.topic in chosen]
        left_out = [t for t in held if t not in chosen]
        say(log, 'replay: publishing ' + ', '.join(
            t if names[t] == t else f'{t} as {names[t]}' for t in chosen) +
            (f' (not {", ".join(left_out)}: --topics or --all-topics publish them)'
             if left_out else ''))
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
                publishers[t.topic] = node.create_publisher(message_class(t.msgtype),
                                                            names[t.topic], qos)
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
    """Wait until each publisher has a subscriber, at most ``wait`` seconds."""
    deadline = time.monotonic() + wait
    said = False
    while not stop.is_set():
        missing = [p.topic_name for p in publishers.values() if p.get_subscription_count() == 0]
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
