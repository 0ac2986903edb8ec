"""Pairing of current and encoder records by move_id, and windows of moves per target angle.

A positioning move arrives as two halves (``MoveSamples`` on ``galvo/current`` and on
``galvo/encoder``) that share a ``move_id``. :class:`MoveWindower` pairs the halves, checks
them (:mod:`~galvo_sysid.monitor.checks`), buffers the complete moves per signed target angle
and hands out a :class:`~galvo_sysid.monitor.moves.Window` every ``window_size`` moves of one
angle: what the identification averages. The sysid node and ``galvo-sysid identify`` (bags)
both use it, so both give the same windows.

Everything is decided from message stamps, never from arrival time. The windower keeps a data
clock per signal (:mod:`~galvo_sysid.monitor.clock`): the newest stamp of the current halves
it took, and of the encoder halves. A half is unpaired when its partner's clock is
``pair_timeout`` past its own stamp (that topic has moved on without it); where the partner's
topic lags behind (its messages held up, e.g. behind huge ones on the same topic) or has not
come at all, the half waits until its own topic is :data:`LATE_TOPIC` + 1 pair timeouts past
it. A half stamped more than
``time_jump`` away from its signal's clock is held apart: on its own (one stale or future
stamp) it is set aside once :data:`CONFIRM` halves of its signal in time with the clock have
come; when instead :data:`CONFIRM` halves in a row agree on its new time (a bag replay looping
back, a publisher restarted, a pause), that clock moves there and the held halves are used; a
move back in time then restarts the buffers, so that old and new moves never mix. One topic
arriving late is not a jump: each topic's stamps are judged against that topic's own.

A window holds moves of one signed target angle, sample period and record length: a move of
another length (a short first move, say) starts a window of its own. Moves that cannot be
used are set aside as :class:`~galvo_sysid.monitor.rejections.Rejection` records, one per
move, said once (the partner of a rejected half is dropped silently).

Memory is bounded: at most ``max_buffered_bytes`` bytes of samples (a quarter of it at most
for halves waiting for their partner, :mod:`~galvo_sysid.monitor.halves`, or for their stamp;
the rest for open windows, :mod:`~galvo_sysid.monitor.windows`), ``max_pending`` unpaired
halves and ``max_windows`` open windows. Beyond, the oldest waiting half is set aside, or a
window is evicted by a fair policy; a window not complete ``window_timeout`` after its first
move expires. Each of these is counted and set aside with its reason.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from galvo_sysid.monitor.checks import (
    check_settings,
    field_problem,
    pair_problem,
    period_problem,
    record_problem,
)
from galvo_sysid.monitor.clock import DataClock
from galvo_sysid.monitor.halves import SIGNALS, HalfTable
from galvo_sysid.monitor.parameters import defaults
from galvo_sysid.monitor.rejections import Rejection
from galvo_sysid.monitor.windows import WindowStore, window_key

if TYPE_CHECKING:
    from galvo_sysid.monitor.moves import MoveHalf, Window
    from galvo_sysid.monitor.windows import OpenWindow

__all__ = ['CONFIRM', 'LATE_TOPIC', 'RECENT_ANGLES', 'MoveWindower']

_DEFAULTS = defaults('sysid')
"""The sysid node's parameter defaults: the windower's defaults (one source)."""

CONFIRM = 8
"""Halves of one topic that decide about a stamp of that topic held apart: this many in a row
agreeing with it move the topic's data clock there; this many in time with the clock set it
aside."""

LATE_TOPIC = 10.0
"""Pair timeouts a half waits beyond one, by its own topic's clock, for a partner whose topic
lags behind or has not come: the sysid node flooded with 40 MB messages received one topic's
good halves up to 3.7 s late (``benchmarks/sysid_hostile_input.py``, ``topic_lag_ms_max``)."""

RECENT_ANGLES = 4096
"""Keys of evicted windows remembered (a key seen again opens a window that counts as
filling)."""


class MoveWindower:
    """Pair move halves by move_id and collect windows of moves per signed target angle.

    Pure logic, no ROS; bounded memory; decides from stamps, not from arrival time. The
    settings of :data:`~galvo_sysid.monitor.parameters.WINDOWER_PARAMETERS` are sysid node
    parameters of the same name, and their defaults are those parameters'
    (:mod:`galvo_sysid.monitor.parameters`).

    Args:
        window_size: Moves per window (>= 2).
        samples: Expected samples per record; 0 takes any length (moves of each length fill
            windows of their own).
        max_samples: Largest accepted record (an oversized array is rejected).
        min_samples: Smallest accepted record.
        pair_timeout: A half whose partner has not arrived when the partner's data clock is
            this much later [s] is rejected as unpaired (see the module docs for a partner's
            topic that lags or never came).
        time_jump: A half stamped this much [s] before or after its signal's data clock is
            held apart (see the module docs).
        angle_resolution: Target angles closer than this [deg] share a window; smaller
            magnitudes count as a zero angle.
        max_pending: Most unpaired halves held.
        max_windows: Most open windows held (the paper's schedule needs 38: 19 angles, both
            signs).
        max_buffered_bytes: Most bytes of samples held: open windows, and a quarter of it at
            most for halves waiting.
        window_timeout: A window not complete this long [s] after its first move (by stamps)
            is set aside.
        first_index: Index of the first window handed out (to continue a numbering).
        sample_period: The sample period the records must have [s] (the plant model's): a
            move of another period (relative difference over 1e-6) is set aside, the reason
            naming both periods; 0 accepts any period (moves of each period fill windows of
            their own).

    Raises:
        ConfigurationError: On an out-of-range setting.
    """

    def __init__(self, *, window_size: int = _DEFAULTS['window_size'],
                 samples: int = _DEFAULTS['samples'],
                 max_samples: int = _DEFAULTS['max_samples'], min_samples: int = 32,
                 pair_timeout: float = _DEFAULTS['pair_timeout'],
                 time_jump: float = _DEFAULTS['time_jump'], angle_resolution: float = 1e-6,
                 max_pending: int = _DEFAULTS['max_pending'],
                 max_windows: int = _DEFAULTS['max_windows'],
                 max_buffered_bytes: int = _DEFAULTS['max_buffered_bytes'],
                 window_timeout: float = _DEFAULTS['window_timeout'],
                 first_index: int = 0, sample_period: float = 0.0) -> None:
        check_settings(window_size=window_size, samples=samples, max_samples=max_samples,
                       min_samples=min_samples, pair_timeout=pair_timeout, time_jump=time_jump,
                       angle_resolution=angle_resolution, max_pending=max_pending,
                       max_windows=max_windows, max_buffered_bytes=max_buffered_bytes,
                       window_timeout=window_timeout, sample_period=sample_period)
        budget = int(max_buffered_bytes)
        self.sample_period = float(sample_period)
        self.window_size = int(window_size)
        self.samples = int(samples)
        self.max_samples = int(max_samples)
        self.min_samples = int(min_samples)
        self.pair_timeout = float(pair_timeout)
        self.time_jump = float(time_jump)
        self.angle_resolution = float(angle_resolution)
        self.max_pending = int(max_pending)
        self.max_windows = int(max_windows)
        self.max_buffered_bytes = budget
        self.window_timeout = float(window_timeout)
        self._waiting_budget = budget // 4
        self._halves = HalfTable(pair_timeout=self.pair_timeout,
                                 done_limit=max(4 * self.max_pending, 4 * self.window_size))
        self._clocks = {signal: DataClock(time_jump=self.time_jump, confirm=CONFIRM)
                        for signal in SIGNALS}
        self._open = WindowStore(window_size=self.window_size, max_windows=self.max_windows,
                                 budget=budget - budget // 4,
                                 window_timeout=self.window_timeout, recent=RECENT_ANGLES)
        self._rejections: list[Rejection] = []
        self._next_index = int(first_index)
        self.resets = 0
        """How many times confirmed stamps jumping back restarted the buffers."""
        self.moves_accepted = 0
        """Moves paired and buffered or handed out in windows (evicted ones are taken off)."""
        self.moves_rejected = 0
        """Rejections issued so far (moves set aside, plus repeated halves)."""
        self.period_mismatches = 0
        """Halves whose sample period is not :attr:`sample_period` (each move set aside once;
        its partner is counted too)."""
        self.period_mismatch: str | None = None
        """The latest reason a move was set aside for its sample period (None: never)."""
        self.stale_halves = 0
        """Halves set aside alone for a stamp far from the data clock."""
        self.refused_halves = 0
        """Halves refused before their samples were decoded (:meth:`refuse`)."""
        self.halves_evicted = 0
        """Waiting halves set aside to keep within ``max_pending`` or the byte budget."""
        self.windows_evicted = 0
        """Open windows set aside to keep within ``max_windows`` or the byte budget."""
        self.windows_expired = 0
        """Open windows set aside for not completing within ``window_timeout``."""
        self.topic_lag = 0.0
        """The most a half taken was stamped behind the other topic's clock [s]: how late one
        topic came (behind huge messages, say), which its own clock lets pass."""

    # -- state -------------------------------------------------------------------------
    @property
    def pending(self) -> int:
        """Unpaired halves held."""
        return len(self._halves)

    @property
    def held(self) -> int:
        """Halves held apart for their stamp."""
        return sum(len(c.held) for c in self._clocks.values())

    @property
    def open_windows(self) -> int:
        """Windows being filled."""
        return len(self._open)

    @property
    def buffered_samples(self) -> int:
        """Samples (current and encoder) held in open windows."""
        return self._open.nbytes // 8

    @property
    def buffered_bytes(self) -> int:
        """Bytes of samples held: open windows, unpaired halves and halves held apart."""
        return self._open.nbytes + self._halves.nbytes + self._held_bytes()

    @property
    def next_index(self) -> int:
        """Index the next window will get."""
        return self._next_index

    @property
    def newest_stamp(self) -> float:
        """The newest stamp taken, of either signal [s] (-inf before the first half)."""
        return max(c.now for c in self._clocks.values())

    def _held_bytes(self) -> int:
        return sum(c.held_bytes for c in self._clocks.values())

    def fill_levels(self) -> dict[float, int]:
        """Moves buffered in open windows, by signed target angle."""
        return self._open.fill_levels()

    def pop_rejections(self) -> list[Rejection]:
        """Return and forget the rejections since the last call."""
        out, self._rejections = self._rejections, []
        return out

    # -- input -------------------------------------------------------------------------
    def add(self, half: MoveHalf) -> list[Window]:
        """Take one half; return the windows it completed."""
        problem = self._check_half(half)
        if problem is not None:
            self._reject_half(half, problem)
            return []
        clock = self._clocks[half.signal]
        set_aside, hold = clock.judge(half.stamp)
        if set_aside:
            self._set_aside_held(clock)
        if hold:
            return self._hold(half, clock)
        return self._take(half)

    def refuse(self, half: MoveHalf, reason: str) -> None:
        """Set aside a half refused before its samples were decoded (e.g. an oversized record:
        ``half`` carries its fields without samples); counted in :attr:`refused_halves`."""  # noqa: D205, D209
        self.refused_halves += 1
        self._reject_half(half, reason)

    def expire(self, now: float | None = None) -> None:
        """Reject the unpaired halves whose partner can no longer come.

        Without ``now``, by the data clocks (see the module docs): a half whose partner's
        clock is ``pair_timeout`` past its stamp, or its own :data:`LATE_TOPIC` + 1 pair
        timeouts past it (the partner's topic lags or has not come). With ``now`` (no input
        for a while: the clocks taken on by the wall clock), every half stamped more than
        ``pair_timeout`` before it.

        Each signal's halves are examined oldest first and the scan stops at the first one
        still in time, so a half that arrived out of stamp order may wait a little longer.
        """
        for signal in SIGNALS:
            if now is not None:
                ref = now
            else:
                ref = max(self._clocks[_other(signal)].now,
                          self._clocks[signal].now - LATE_TOPIC * self.pair_timeout)
            limit = ref - self.pair_timeout
            while self._halves.waiting_for(signal):
                h = self._halves.oldest(signal)
                if h.stamp >= limit:
                    break
                self._halves.drop(h.move_id)
                self._reject_one(h.move_id, h.target_angle, h.stamp,
                                 f'unpaired after {self.pair_timeout:g} s: no '
                                 f'{_other(h.signal)} record')

    def flush(self, *, min_moves: int = 2) -> list[Window]:
        """Hand out the open windows holding at least ``min_moves`` moves (end of a bag).

        Halves held apart for their stamp are used if nothing contradicted them and they are
        ahead of the clock (the data moved on at the very end), else set aside. Windows with
        fewer moves and all unpaired halves are rejected; the windower is empty afterwards.
        """
        out: list[Window] = []
        for clock in self._clocks.values():
            if clock.uncontradicted_ahead():
                for h in clock.release():
                    out.extend(self._take(h))
        for clock in self._clocks.values():
            self._set_aside_held(clock)
        for h in self._halves.waiting():
            self._reject_one(h.move_id, h.target_angle, h.stamp,
                             f'unpaired at end of data: no {_other(h.signal)} record')
        self._halves.clear_waiting()
        for w in self._open.drain():
            if len(w.move_ids) >= max(1, int(min_moves)):
                out.append(self._emit(w, partial=True))
            else:
                self._reject_window(w, f'window of {len(w.move_ids)} move(s) incomplete at end'
                                       f' of data (fewer than {min_moves})')
        return out

    def reset(self, *, reason: str = 'reset') -> None:
        """Drop every buffered half and move (rejecting them with ``reason``)."""
        for clock in self._clocks.values():
            for h in clock.release():
                self._reject_half(h, f'discarded: {reason}')
        for h in self._halves.waiting():
            self._reject_one(h.move_id, h.target_angle, h.stamp, f'discarded: {reason}')
        for w in self._open.clear():
            self._reject_window(w, f'discarded: {reason}')
        self._halves.clear_waiting()
        self._halves.clear_done()
        for clock in self._clocks.values():
            clock.now = -math.inf
        self.resets += 1

    # -- stamps --------------------------------------------------------------------------
    def _hold(self, half: MoveHalf, clock: DataClock) -> list[Window]:
        """Hold a half apart for its stamp; use the held halves once CONFIRM agree in a row."""
        if clock.hold(half):
            return self._confirm(clock)
        self._evict_held()
        return []

    def _confirm(self, clock: DataClock) -> list[Window]:
        """The held halves agree on a new time: move the clock there and use them.

        A move back in time restarts the buffers; the other signal's halves held apart
        meanwhile (the same loop, not yet confirmed on that topic) are judged again after
        the restart, with its clock restarted too.
        """
        jump = clock.held[0].stamp - clock.now
        held = clock.release()
        again: list[MoveHalf] = []
        if jump < 0:  # a replay looping, a publisher restarted: old and new moves never mix
            for other in self._clocks.values():
                if other is not clock:
                    again.extend(other.release())
            self.reset(reason=f'time jumped back {-jump:.3g} s')
        out: list[Window] = []
        for h in held:
            out.extend(self._take(h))
        for h in again:
            out.extend(self.add(h))
        return out

    def _set_aside_held(self, clock: DataClock) -> None:
        now = clock.now
        for h in clock.release():
            where = 'behind' if h.stamp < now else 'ahead of'
            self.stale_halves += 1
            self._reject_half(h, f'stamp more than {self.time_jump:g} s {where} the data clock '
                                 f'(set aside alone)')

    def _evict_held(self) -> None:
        """Within the waiting share of the byte budget: held halves set aside, oldest first."""
        while (self.held and
               self._halves.nbytes + self._held_bytes() > self._waiting_budget):
            clock = min((c for c in self._clocks.values() if c.held),
                        key=lambda c: c.held[0].stamp)
            h = clock.pop_oldest()
            self.halves_evicted += 1
            self._reject_half(h, f'held for its stamp: evicted, more than '
                                 f'{self._waiting_budget} bytes of halves waiting')

    # -- internals ---------------------------------------------------------------------
    def _take(self, half: MoveHalf) -> list[Window]:
        """Use a half whose stamp is in time: pair it, window the move."""
        stamp = half.stamp
        self._clocks[half.signal].advance(stamp)
        lag = self._clocks[_other(half.signal)].now - stamp
        if lag > self.topic_lag:
            self.topic_lag = lag
        self.expire()
        for w, reason in self._open.expire(self.newest_stamp):
            self._reject_window(w, reason)
            self.windows_expired += 1
        mid = half.move_id
        done = self._halves.recent(mid, stamp)
        if done is not None:
            if done:  # both halves were used already: a repeat
                self._reject_repeat(half)
            # else: the partner of a move already set aside; it was said once
            return []
        partner = self._halves.get(mid)
        if partner is None:
            self._halves.put(half)
            self._limit_pending()
            return []
        if partner.signal == half.signal:
            if abs(partner.stamp - stamp) <= self.pair_timeout:
                self._reject_repeat(half)  # the first half keeps waiting for its partner
                return []
            # the same id much later (a restarted publisher): the old half is stale
            self._halves.drop(mid)
            self._reject_one(mid, partner.target_angle, partner.stamp,
                             f'unpaired: no {_other(partner.signal)} record')
            self._halves.put(half)
            self._limit_pending()
            return []
        self._halves.drop(mid)
        current, encoder = (half, partner) if half.signal == 'current' else (partner, half)
        return self._add_move(current, encoder)

    def _limit_pending(self) -> None:
        """Within max_pending and the waiting share of the byte budget (held halves first)."""
        self._evict_held()
        while self._halves and (len(self._halves) > self.max_pending or
                                self._halves.nbytes > self._waiting_budget):
            h = self._halves.drop(self._halves.oldest().move_id)
            self.halves_evicted += 1
            why = (f'more than {self.max_pending} halves waiting'
                   if len(self._halves) >= self.max_pending
                   else f'more than {self._waiting_budget} bytes of halves waiting')
            self._reject_one(h.move_id, h.target_angle, h.stamp, f'unpaired: evicted, {why}')

    def _check_half(self, half: MoveHalf) -> str | None:
        """Return why the half is unusable, or None (counting sample period mismatches)."""
        problem = field_problem(half, angle_resolution=self.angle_resolution)
        if problem is not None:
            return problem
        problem = period_problem(half, self.sample_period)
        if problem is not None:
            self.period_mismatches += 1
            self.period_mismatch = problem
            return problem
        return record_problem(half, samples=self.samples, min_samples=self.min_samples,
                              max_samples=self.max_samples)

    def _reject_half(self, half: MoveHalf, reason: str) -> None:
        mid = half.move_id
        if mid < 0:
            self._rejections.append(Rejection(mid, half.target_angle, half.stamp, reason))
            self.moves_rejected += 1
            return
        partner = self._halves.get(mid)
        stamp = half.stamp if math.isfinite(half.stamp) else (
            partner.stamp if partner is not None else self.newest_stamp)
        done = self._halves.recent(mid, stamp)
        if done is not None:
            if done:  # a broken repeat of a move already used
                self._rejections.append(Rejection(mid, half.target_angle, stamp,
                                                  f'{reason} (repeat of a used move_id)'))
                self.moves_rejected += 1
            return  # else the move was already set aside: say nothing twice
        if partner is not None:
            self._halves.drop(mid)
        angle = half.target_angle
        if partner is not None and not math.isfinite(angle):
            angle = partner.target_angle
        self._reject_one(mid, angle, stamp, reason)

    def _reject_repeat(self, half: MoveHalf) -> None:
        """A second copy of a half: reported, but the move itself is not set aside."""
        self._rejections.append(Rejection(half.move_id, half.target_angle, half.stamp,
                                          f'duplicate move_id ({half.signal} seen twice)'))
        self.moves_rejected += 1

    def _reject_one(self, move_id: int, angle: float, stamp: float, reason: str) -> None:
        self._rejections.append(Rejection(move_id, angle, stamp, reason))
        self.moves_rejected += 1
        self._mark_done(move_id, stamp, used=False)

    def _reject_window(self, w: OpenWindow, reason: str) -> None:
        for mid, stamp in zip(w.move_ids, w.stamps, strict=True):
            self._rejections.append(Rejection(mid, w.target_angle, stamp, reason))
            self.moves_rejected += 1
        self.moves_accepted -= len(w.move_ids)

    def _mark_done(self, move_id: int, stamp: float, *, used: bool) -> None:
        self._halves.mark(move_id, stamp if math.isfinite(stamp) else self.newest_stamp,
                          used=used)

    def _add_move(self, current: MoveHalf, encoder: MoveHalf) -> list[Window]:
        mid = current.move_id
        stamp = min(current.stamp, encoder.stamp)
        problem = pair_problem(current, encoder, angle_resolution=self.angle_resolution)
        if problem is not None:
            self._reject_one(mid, current.target_angle, stamp, problem)
            return []
        key = window_key(current, angle_resolution=self.angle_resolution,
                         model_period=self.sample_period)
        full = self._open.add(key, current, encoder, stamp)
        self.moves_accepted += 1
        self._mark_done(mid, stamp, used=True)
        if full is not None:
            return [self._emit(full, partial=False)]
        for w, reason in self._open.evict():
            self._reject_window(w, reason)
            self.windows_evicted += 1
        return []

    def _emit(self, w: OpenWindow, *, partial: bool) -> Window:
        index = self._next_index
        self._next_index += 1
        return w.window(index=index, partial=partial)


def _other(signal: str) -> str:
    return 'encoder' if signal == 'current' else 'current'
