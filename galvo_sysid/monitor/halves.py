"""The pairing table of :class:`~galvo_sysid.monitor.pairing.MoveWindower`, by move_id.

A :class:`HalfTable` holds the halves waiting for their partner, oldest first, with the bytes
of samples they take, and remembers the moves recently done (used, or set aside) with their
stamp: a half of a move done within ``pair_timeout`` of its stamp is a repeat, or the partner
of a half set aside, which is dropped silently. The windower decides what to do with them.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from galvo_sysid.monitor.moves import MoveHalf

__all__ = ['HalfTable']


class HalfTable:
    """Halves waiting for their partner, and moves recently done, by move_id.

    Args:
        pair_timeout: A move done is recognised by a half stamped within this [s] of it.
        done_limit: Moves done remembered (the oldest are forgotten).

    Attributes:
        nbytes: Bytes of samples of the waiting halves.
    """

    def __init__(self, *, pair_timeout: float, done_limit: int) -> None:
        self.pair_timeout = pair_timeout
        self.done_limit = done_limit
        self.nbytes = 0
        self._waiting: OrderedDict[int, MoveHalf] = OrderedDict()
        # move_id -> stamp of moves recently completed or rejected (for duplicates and to
        # drop the partner of a rejected half silently), and whether it was used
        self._done: OrderedDict[int, tuple[float, bool]] = OrderedDict()

    # -- waiting halves ------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self._waiting)

    def get(self, move_id: int) -> MoveHalf | None:
        """The half of ``move_id`` waiting, or None."""
        return self._waiting.get(move_id)

    def put(self, half: MoveHalf) -> None:
        """Let a half wait for its partner (the newest)."""
        self._waiting[half.move_id] = half
        self.nbytes += half.data.nbytes

    def drop(self, move_id: int) -> MoveHalf:
        """Stop waiting for the partner of ``move_id``'s half and return that half."""
        h = self._waiting.pop(move_id)
        self.nbytes -= h.data.nbytes
        return h

    def oldest(self) -> MoveHalf:
        """The half waiting longest (some must be waiting)."""
        return next(iter(self._waiting.values()))

    def waiting(self) -> list[MoveHalf]:
        """The waiting halves, oldest first."""
        return list(self._waiting.values())

    def clear_waiting(self) -> None:
        """Forget every waiting half."""
        self._waiting.clear()
        self.nbytes = 0

    # -- moves done ----------------------------------------------------------------------
    def recent(self, move_id: int, stamp: float) -> bool | None:
        """True/False if the move was recently used/set aside (stamp within pair_timeout)."""
        entry = self._done.get(move_id)
        if entry is None:
            return None
        if not math.isfinite(entry[0]):
            # set aside before any stamp was known (a first half without a finite stamp):
            # recognise its partner by move_id alone, and from then on by the partner's stamp
            if math.isfinite(stamp):
                self._done[move_id] = (stamp, entry[1])
            return entry[1]
        if not abs(entry[0] - stamp) <= self.pair_timeout:
            return None
        return entry[1]

    def mark(self, move_id: int, stamp: float, *, used: bool) -> None:
        """Remember a move as done at ``stamp`` [s]: used, or set aside."""
        self._done[move_id] = (stamp, used)
        self._done.move_to_end(move_id)
        while len(self._done) > self.done_limit:
            self._done.popitem(last=False)

    def clear_done(self) -> None:
        """Forget the moves done."""
        self._done.clear()
