"""The open windows of :class:`~galvo_sysid.monitor.pairing.MoveWindower`, within a budget.

A :class:`WindowStore` holds the windows being filled, one per key (signed target angle,
sample period, record length), least recently fed first. It keeps them within a count and a
byte budget by a fair policy: first the windows that are not filling (a single move of a key
not seen lately), least recently fed first, then the least recently progressing. A key whose
window was completed or evicted lately starts as filling when it comes back, so under a flood
of distinct angles the angles that fill steadily still complete. A window not complete
``window_timeout`` after its first move (by stamps) expires.

The store only keeps the books: the windows it evicts, expires or drains are given back to the
windower, which sets their moves aside or hands them out.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from galvo_sysid.monitor.moves import Window

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from galvo_sysid.monitor.moves import MoveHalf

__all__ = ['OpenWindow', 'WindowKey', 'WindowStore', 'window_key']

WindowKey = tuple[int, int, int]
"""What moves share a window: rounded target angle, rounded log sample period, samples."""


def window_key(current: MoveHalf, *, angle_resolution: float,
               model_period: float) -> WindowKey:
    """Return the key of the window a checked move goes to.

    Args:
        current: The move's current half.
        angle_resolution: Target angles closer than this [deg] share a window.
        model_period: The sample period every move has [s] (then one key for all periods),
            or 0 (moves of each period fill windows of their own).
    """
    # with the model's period every accepted move has it (within 1e-6): one key
    span = 0 if model_period else round(math.log(current.sample_period) * 1e6)
    return (round(current.target_angle / angle_resolution), span, current.data.shape[0])


@dataclass
class OpenWindow:
    """A window being filled.

    Attributes:
        target_angle: Signed commanded rotation of the moves [deg] (the first move's).
        sample_period: Sampling period [s] (the first move's).
        samples: Samples per record.
        filling: True once the window has had a second move, or from its first when its key
            was open lately (evicted windows that are not filling go first).
        current: The moves' current records.
        encoder: The moves' encoder records.
        move_ids: The moves' ids in arrival order.
        stamps: The moves' stamps [s].
        first_stamp: Stamp of the earliest move [s] (inf while empty).
    """

    target_angle: float
    sample_period: float
    samples: int
    filling: bool
    current: list[NDArray[np.float64]] = field(default_factory=list)
    encoder: list[NDArray[np.float64]] = field(default_factory=list)
    move_ids: list[int] = field(default_factory=list)
    stamps: list[float] = field(default_factory=list)
    first_stamp: float = math.inf

    @property
    def nbytes(self) -> int:
        """Bytes of samples held (current and encoder)."""
        return 16 * self.samples * len(self.move_ids)

    def window(self, *, index: int, partial: bool) -> Window:
        """Return the moves as a :class:`~galvo_sysid.monitor.moves.Window` numbered ``index``.

        Args:
            index: The window's running number.
            partial: True when handed out before it was full.

        Returns:
            The window (records stacked in arrival order).
        """
        return Window(index=index, target_angle=self.target_angle,
                      sample_period=self.sample_period, current=np.stack(self.current),
                      encoder=np.stack(self.encoder), move_ids=tuple(self.move_ids),
                      first_stamp=min(self.stamps), last_stamp=max(self.stamps),
                      partial=partial)


class WindowStore:
    """The open windows, least recently fed first, within a count and a byte budget.

    Args:
        window_size: Moves per complete window.
        max_windows: Most open windows held.
        budget: Most bytes of samples held in open windows.
        window_timeout: A window not complete this long [s] after its first move (by stamps)
            expires.
        recent: Keys of completed or evicted windows remembered (a key seen again opens a
            window that counts as filling).
    """

    def __init__(self, *, window_size: int, max_windows: int, budget: int,
                 window_timeout: float, recent: int) -> None:
        self.window_size = window_size
        self.max_windows = max_windows
        self.budget = budget
        self.window_timeout = window_timeout
        self.recent = recent
        self.nbytes = 0
        """Bytes of samples held in open windows."""
        # open windows, least recently fed first; the keys of those not (yet) filling
        self._windows: OrderedDict[WindowKey, OpenWindow] = OrderedDict()
        self._trial: OrderedDict[WindowKey, None] = OrderedDict()
        self._recent_keys: OrderedDict[WindowKey, None] = OrderedDict()
        self._next_expiry = -math.inf

    def __len__(self) -> int:
        return len(self._windows)

    def fill_levels(self) -> dict[float, int]:
        """Moves buffered in open windows, by signed target angle."""
        out: dict[float, int] = {}
        for w in self._windows.values():
            out[w.target_angle] = out.get(w.target_angle, 0) + len(w.move_ids)
        return out

    def add(self, key: WindowKey, current: MoveHalf, encoder: MoveHalf,
            stamp: float) -> OpenWindow | None:
        """Add a checked move to the window of ``key`` (opened if need be).

        Args:
            key: The move's window key.
            current: The move's current half.
            encoder: The move's encoder half (as long as ``current``).
            stamp: The move's stamp [s].

        Returns:
            The window if the move completed it (it is no longer held), else None. The caller
            then calls :meth:`evict`.
        """
        n = current.data.shape[0]
        w = self._windows.get(key)
        if w is None:
            filling = key in self._recent_keys
            w = OpenWindow(target_angle=current.target_angle,
                           sample_period=current.sample_period, samples=n, filling=filling)
            self._windows[key] = w
            if not filling:
                self._trial[key] = None
        else:
            self._windows.move_to_end(key)
            if not w.filling:  # a second move: this angle fills
                w.filling = True
                del self._trial[key]
        w.current.append(current.data)
        w.encoder.append(encoder.data)
        w.move_ids.append(current.move_id)
        w.stamps.append(stamp)
        w.first_stamp = min(w.first_stamp, stamp)
        self.nbytes += 16 * n
        if len(w.move_ids) >= self.window_size:
            del self._windows[key]
            self._trial.pop(key, None)
            self.nbytes -= w.nbytes
            self._remember(key)
            return w
        return None

    def evict(self) -> list[tuple[OpenWindow, str]]:
        """Remove windows until within ``max_windows`` and the byte budget, fairly.

        Windows not filling go first (least recently fed first), then the least recently
        progressing.

        Returns:
            The evicted windows with why, in the order evicted.
        """
        out: list[tuple[OpenWindow, str]] = []
        while len(self._windows) > self.max_windows or (
                self.nbytes > self.budget and self._windows):
            why = (f'more than {self.max_windows} open windows'
                   if len(self._windows) > self.max_windows
                   else f'more than {self.budget} bytes in open windows')
            key = next(iter(self._trial)) if self._trial else next(iter(self._windows))
            out.append((self._remove(key), f'window evicted: {why}'))
        return out

    def expire(self, now: float) -> list[tuple[OpenWindow, str]]:
        """Remove the windows not complete ``window_timeout`` after their first move.

        Checked at most every second of data time, or a quarter of the timeout.

        Args:
            now: The data clock [s].

        Returns:
            The expired windows with why, oldest fed first.
        """
        if now < self._next_expiry:
            return []
        self._next_expiry = now + min(1.0, self.window_timeout / 4)
        oldest = now - self.window_timeout
        return [(self._remove(key), f'window expired: not complete {self.window_timeout:g} s '
                                    f'after its first move')
                for key in [k for k, w in self._windows.items() if w.first_stamp < oldest]]

    def drain(self) -> list[OpenWindow]:
        """Remove and return every open window, least recently fed first (end of data)."""
        out = [self._windows.pop(key) for key in list(self._windows)]
        self._trial.clear()
        self.nbytes = 0
        return out

    def clear(self) -> list[OpenWindow]:
        """Remove and return every open window and restart the expiry checks (a reset)."""
        out = list(self._windows.values())
        self._windows.clear()
        self._trial.clear()
        self.nbytes = 0
        self._next_expiry = -math.inf
        return out

    def _remove(self, key: WindowKey) -> OpenWindow:
        w = self._windows.pop(key)
        self._trial.pop(key, None)
        self.nbytes -= w.nbytes
        self._remember(key)
        return w

    def _remember(self, key: WindowKey) -> None:
        """A window of this key was open lately: the next one counts as filling."""
        self._recent_keys[key] = None
        self._recent_keys.move_to_end(key)
        while len(self._recent_keys) > self.recent:
            self._recent_keys.popitem(last=False)
