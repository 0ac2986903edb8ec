"""The pairing table of :class:`~galvo_sysid.monitor.pairing.MoveWindower`, by move_id.

A :class:`HalfTable` holds the halves waiting for their partner, oldest first per signal
(each topic's halves in the order they came), with the bytes of samples they take, and
remembers the moves recently done (used, or set aside) with their stamp: a half of a move done
within ``pair_timeout`` of its stamp is a repeat, or the partner of a half set aside, which is
dropped silently. The windower decides what to do with them.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from galvo_sysid.monitor.moves import MoveHalf

__all__ = ['SIGNALS', 'HalfTable']

SIGNALS = ('current', 'encoder')
"""The two halves of a move, by the topic they come on."""


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
        self._waiting: dict[str, OrderedDict[int, MoveHalf]] = {
            signal: OrderedDict() for signal in SIGNALS}
        # move_id -> stamp of moves recently completed or rejected (for duplicates and to
        # drop the partner of a rejected half silently), and whether it was used
        self._done: OrderedDict[int, tuple[float, bool]] = OrderedDict()

    # -- waiting halves ------------------------------------------------------------------
    def __len__(self) -> int:
        return sum(len(w) for w in self._waiting.values())

    def get(self, move_id: int) -> MoveHalf | None:
        """The half of ``move_id`` waiting, or None."""
        for waiting in self._waiting.values():
            half = waiting.get(move_id)
            if half is not None:
                return half
        return None

    def put(self, half: MoveHalf) -> None:
        """Let a half wait for its partner (the newest of its signal)."""
        self._waiting[half.signal][half.move_id] = half
        self.nbytes += half.data.nbytes

    def drop(self, move_id: int) -> MoveHalf:
        """Stop waiting for the partner of ``move_id``'s half and return that half."""
        for waiting in self._waiting.values():
            if move_id in waiting:
                h = waiting.pop(move_id)
                self.nbytes -= h.data.nbytes
                return h
        raise KeyError(move_id)

    def waiting_for(self, signal: str) -> int:
        """How many halves of ``signal`` wait."""
        return len(self._waiting[signal])

    def oldest(self, signal: str | None = None) -> MoveHalf:
        """The half of ``signal`` (None: of either, the earlier stamped) waiting longest;
        some must be waiting."""  # noqa: D205, D209
        if signal is not None:
            return next(iter(self._waiting[signal].values()))
        heads = [next(iter(w.values())) for w in self._waiting.values() if w]
        return min(heads, key=lambda h: h.stamp)

    def waiting(self) -> list[MoveHalf]:
        """The waiting halves, by stamp."""
        return sorted((h for w in self._waiting.values() for h in w.values()),
                      key=lambda h: h.stamp)

    def clear_waiting(self) -> None:
        """Forget every waiting half."""
        for waiting in self._waiting.values():
            waiting.clear()
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
