"""A rate-limited log: hostile input cannot flood the log.

:class:`RateLimitedLog` says each line at most ``per_second`` times a second and sums up what
it held back, once that second is over.
"""

from __future__ import annotations

import collections
import threading
import time
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Callable

__all__ = ['RateLimitedLog']


class RateLimitedLog:
    """Pass at most ``per_second`` lines a second to ``sink``; sum up the rest.

    Args:
        sink: Where lines go (e.g. a ROS logger's ``warning``).
        per_second: Lines allowed per second.
        clock: Monotonic clock (for tests).
    """

    def __init__(self, sink: Callable[[str], None], *, per_second: int = 20,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._sink = sink
        self.per_second = max(1, int(per_second))
        self._clock = clock
        self._second = -1.0
        self._sent = 0
        self._held: collections.Counter[str] = collections.Counter()
        self._lock = threading.Lock()

    def __call__(self, line: str, *, key: str | None = None) -> None:
        """Say ``line`` now if allowed, else count it under ``key`` (default: the line)."""
        out: list[str] = []
        with self._lock:
            out += self._roll()
            if self._sent < self.per_second:
                self._sent += 1
                out.append(line)
            else:
                self._held[key or line] += 1
        for text in out:
            self._sink(text)

    def flush(self) -> None:
        """Say the summary of held-back lines if their second is over."""
        with self._lock:
            out = self._roll()
        for text in out:
            self._sink(text)

    def _roll(self) -> list[str]:
        now = self._clock()
        if now - self._second < 1.0:
            return []
        self._second = now
        self._sent = 0
        if not self._held:
            return []
        total = sum(self._held.values())
        top = ', '.join(f'{n} x {k}' for k, n in self._held.most_common(3))
        self._held.clear()
        return [f'{total} more similar message(s) held back in the last second: {top}']
