"""``topic hz``: the rate of a live topic over a window of messages (like ``ros2 topic hz``)."""

from __future__ import annotations

import math
import sys
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, TextIO

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.field.live.graph import (
    Stop,
    absolute,
    message_class,
    ros_node,
    say,
    subscription_qos,
    wait_for_publisher,
)

__all__ = ['RateStats', 'RateWindow', 'topic_hz']


@dataclass(frozen=True)
class RateStats:
    """The rate over a window of arrival intervals.

    Attributes:
        rate: Messages per second: 1 / the mean interval.
        min_interval: Shortest interval [s].
        max_interval: Longest interval [s].
        std_dev: Standard deviation of the intervals [s].
        window: Messages the intervals span (intervals + 1).
        received: Messages received in all.
    """

    rate: float
    min_interval: float
    max_interval: float
    std_dev: float
    window: int
    received: int

    def text(self) -> str:
        """The two lines ``ros2 topic hz`` prints."""
        return (f'average rate: {self.rate:.3f}\n'
                f'\tmin: {self.min_interval:.3f}s max: {self.max_interval:.3f}s '
                f'std dev: {self.std_dev:.5f}s window: {self.window}')


class RateWindow:
    """Arrival times of a topic's messages, the last ``size`` intervals kept.

    Args:
        size: Intervals kept (``ros2 topic hz -w``; its default 10,000).

    Raises:
        ConfigurationError: ``size`` below 1.
    """

    def __init__(self, size: int = 10_000) -> None:
        if size < 1:
            msg = f'window must hold at least 1 interval, got {size}'
            raise ConfigurationError(msg)
        self.intervals: deque[float] = deque(maxlen=size)
        self.last: float | None = None
        self.received = 0

    def add(self, t: float) -> None:
        """One message arrived at time ``t`` [s] (monotonic)."""
        if self.last is not None:
            self.intervals.append(t - self.last)
        self.last = t
        self.received += 1

    def stats(self) -> RateStats | None:
        """The rate over the window, or None before two messages."""
        n = len(self.intervals)
        if n == 0:
            return None
        mean = sum(self.intervals) / n
        std = math.sqrt(sum((x - mean) ** 2 for x in self.intervals) / n)
        return RateStats(rate=1.0 / mean if mean > 0 else math.inf,
                         min_interval=min(self.intervals), max_interval=max(self.intervals),
                         std_dev=std, window=n + 1, received=self.received)


def topic_hz(topic: str, *, window: int = 10_000, count: int | None = None,
             duration: float | None = None, timeout: float | None = None,
             period: float = 1.0, out: TextIO = sys.stdout, log: TextIO = sys.stderr) -> int:
    """Print a live topic's rate every ``period`` seconds until Ctrl-C, ``count`` or
    ``duration``, then once more at the end.

    The subscription is raw (no message is decoded), best effort and volatile, so it matches
    any publisher, never slows a reliable one down and gets no stored (transient-local)
    messages in a burst; under a load that loses messages the rate shown is what arrived.
    Times are arrival times.

    Args:
        topic: Topic name (relative names are taken from ``/``).
        window: Intervals the rate is taken over (the last ones).
        count: Stop after this many messages.
        duration: Stop this many seconds after subscribing.
        timeout: Give up when no publisher or no message came within this many seconds
            (exit code 1).
        period: Seconds between the printed rates.
        out: Where the rates go.
        log: Where status lines go.

    Returns:
        Exit code: 0; 1 when fewer than two messages came (no rate), or on ``timeout``.

    Raises:
        ConfigurationError: The topic's type is not installed.
    """  # noqa: D205
    import rclpy

    name = absolute(topic)
    start = time.monotonic()
    rates = RateWindow(window)
    with Stop() as stop, ros_node('galvo_sysid_hz') as node:
        found = wait_for_publisher(node, name, tool='hz', stop=stop, start=start,
                                   timeout=timeout, log=log)
        if found is None:
            return 0 if stop.is_set() else 1
        msgtype = found[0]

        def callback(_: Any) -> None:
            rates.add(time.monotonic())

        node.create_subscription(message_class(msgtype), name, callback,
                                 subscription_qos(reliable=False, transient_local=False,
                                                   depth=100), raw=True)
        subscribed = time.monotonic()
        next_print = subscribed + period
        printed = 0
        while not stop.is_set():
            rclpy.spin_once(node, timeout_sec=0.02)
            now = time.monotonic()
            if count is not None and rates.received >= count:
                break
            if duration is not None and now - subscribed >= duration:
                break
            if rates.received == 0 and timeout is not None and now - start > timeout:
                say(log, f'hz: no message on {name} within {timeout:g} s')
                return 1
            if now >= next_print:
                next_print = now + period
                stats = rates.stats()
                if stats is not None and stats.received > printed:
                    out.write(stats.text() + '\n')
                    out.flush()
                    printed = stats.received
    stats = rates.stats()
    if stats is None:
        say(log, f'hz: {rates.received} message(s) on {name}: no rate')
        return 1
    if stats.received > printed:
        out.write(stats.text() + '\n')
        out.flush()
    return 0
