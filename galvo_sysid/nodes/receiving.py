"""A node's input taken in batches: many messages for each wait of the executor.

rclpy's executor takes one message of each ready subscription each time it waits, and a wait
costs more than handling a ``MoveSamples``: at 1,000 moves/s (2,000 messages a second) the
sysid node's own process used about half a CPU, most of it the executor
(``benchmarks/sysid_load.py`` says where the CPU goes). A :class:`BatchReceiver` lets the
callbacks of a few subscriptions take what else waits themselves: the first message wakes the
executor, the next ones gather for ``gather`` seconds, then the callback takes them, the
subscriptions in turn (one message of each per round, as the executor takes them, so neither
input runs ahead of the other), at most ``limit`` per wake-up (timers and services run
between batches). A message is handled ``gather`` seconds later at most.
"""

from __future__ import annotations

import functools
import time
from typing import TYPE_CHECKING, Any

from rclpy.exceptions import InvalidHandle

if TYPE_CHECKING:
    from collections.abc import Callable

    from rclpy.node import Node
    from rclpy.qos import QoSProfile
    from rclpy.subscription import Subscription

__all__ = ['GATHER', 'LIMIT', 'BatchReceiver', 'take_waiting']

GATHER = 0.005
"""Seconds the messages gather after the first one woke the executor (see the module docs)."""

LIMIT = 256
"""Most messages a wake-up takes after the first."""


def take_waiting(sub: Subscription) -> Any | None:
    """The next message waiting on ``sub`` (bytes for a raw subscription), or None.

    What the executor takes before it calls the subscription's callback.
    """
    try:
        with sub.handle:
            taken = sub.handle.take_message(sub.msg_type, sub.raw)
    except InvalidHandle:  # destroyed meanwhile: nothing more to take
        return None
    return None if taken is None else taken[0]


class BatchReceiver:
    """Subscriptions whose messages are taken in batches, in turn (see the module docs).

    Args:
        gather: Seconds the messages gather after the first (0: take only what waits).
        limit: Most messages a wake-up takes after the first.

    Attributes:
        wakeups: Callbacks the executor made (one per batch).
        taken: Messages handled in all.
    """

    def __init__(self, *, gather: float = GATHER, limit: int = LIMIT) -> None:
        self.gather = gather
        self.limit = limit
        self._inputs: list[tuple[Subscription | None, Callable[[Any], None]]] = []
        self.wakeups = 0
        self.taken = 0

    def subscribe(self, node: Node, msg_type: Any, topic: str, handle: Callable[[Any], None],
                  qos: QoSProfile, *, raw: bool = False) -> Subscription:
        """Create a subscription of ``node`` whose messages go to ``handle``, in batches."""
        index = len(self._inputs)
        self._inputs.append((None, handle))
        sub = node.create_subscription(msg_type, topic,
                                       functools.partial(self._on_message, index), qos,
                                       raw=raw)
        self._inputs[index] = (sub, handle)
        return sub

    def _on_message(self, index: int, msg: Any) -> None:
        self.wakeups += 1
        self.taken += 1
        self._inputs[index][1](msg)
        if self.gather > 0:
            time.sleep(self.gather)
        self.drain(first=index + 1)

    def drain(self, *, first: int = 0) -> int:
        """Handle the messages waiting, one of each subscription per round from the
        ``first``-th on, at most ``limit``; return how many."""  # noqa: D205, D209
        count = len(self._inputs)
        done = 0
        while done < self.limit:
            before = done
            for k in range(count):
                sub, handle = self._inputs[(first + k) % count]
                msg = None if sub is None or done >= self.limit else take_waiting(sub)
                if msg is not None:
                    handle(msg)
                    done += 1
                    del msg  # before the next is taken: one message in memory at a time
            if done == before:
                break
        self.taken += done
        return done
