"""The data clock of :class:`~galvo_sysid.monitor.pairing.MoveWindower`, and stamps held apart.

The clock is the newest stamp of the halves taken. A half stamped more than ``time_jump``
away from it is held apart, not used. The halves that come next decide about the held ones:
``confirm`` of them in a row agreeing with the held stamps move the clock there (the held
halves are then used); ``confirm`` in time with the clock set the held halves aside. A
:class:`DataClock` keeps these books; the windower uses or sets aside the halves it releases.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from galvo_sysid.monitor.moves import MoveHalf

__all__ = ['DataClock']


class DataClock:
    """The data clock and the halves held apart for their stamp.

    Args:
        time_jump: A half stamped this much [s] before or after the clock is held apart.
        confirm: Halves that decide about the held ones (see the module docs).

    Attributes:
        now: The newest stamp taken [s] (-inf before the first half and after a restart).
        held: The halves held apart, oldest first.
        held_bytes: Bytes of samples in :attr:`held`.
    """

    def __init__(self, *, time_jump: float, confirm: int) -> None:
        self.time_jump = time_jump
        self.confirm = confirm
        self.now = -math.inf
        self.held: list[MoveHalf] = []
        self.held_bytes = 0
        self._held_clock = -math.inf  # the newest held stamp
        self._run = 0  # halves in a row agreeing with the held ones
        self._against = 0  # halves in time with the clock since the first was held

    def judge(self, stamp: float) -> tuple[bool, bool]:
        """Decide about a checked half stamped ``stamp``, counting it for the held halves.

        Args:
            stamp: The half's stamp [s] (finite).

        Returns:
            Whether the held halves are to be set aside first (:meth:`release`), and whether
            the half is to be held apart (:meth:`hold`) rather than taken.
        """
        clock = self.now
        in_time = clock == -math.inf or abs(stamp - clock) <= self.time_jump
        if self.held:
            near = abs(stamp - self._held_clock)
            if near <= self.time_jump and (not in_time or near < abs(stamp - clock)):
                return False, True
            if not in_time:  # far from both: the held halves were not the new time either
                return True, True
            self._run = 0
            self._against += 1
            return self._against >= self.confirm, False
        return False, not in_time

    def hold(self, half: MoveHalf) -> bool:
        """Hold a half apart for its stamp; return True once ``confirm`` agree in a row."""
        self.held.append(half)
        self.held_bytes += half.data.nbytes
        self._held_clock = max(self._held_clock, half.stamp)
        self._run += 1
        return self._run >= self.confirm

    def pop_oldest(self) -> MoveHalf:
        """Stop holding the oldest held half and return it (to evict it)."""
        h = self.held.pop(0)
        self.held_bytes -= h.data.nbytes
        return h

    def uncontradicted_ahead(self) -> bool:
        """True if halves are held, none came against them and they are ahead of the clock."""
        return bool(self.held) and self._against == 0 and self._held_clock > self.now

    def release(self) -> list[MoveHalf]:
        """Stop holding every held half and return them, oldest first."""
        held, self.held = self.held, []
        self.held_bytes = 0
        self._held_clock = -math.inf
        self._run = self._against = 0
        return held

    def advance(self, stamp: float) -> None:
        """Take a stamp in time: the clock moves to it if it is newer."""
        self.now = max(self.now, stamp)
