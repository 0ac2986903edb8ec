"""Pairing of current and encoder records by move_id, and windows of moves per target angle.

A positioning move arrives as two halves (``MoveSamples`` on ``galvo/current`` and on
``galvo/encoder``) that share a ``move_id``. :class:`MoveWindower` pairs the halves, checks
them, buffers the complete moves per signed target angle and hands out a
:class:`~galvo_sysid.monitor.moves.Window` every ``window_size`` moves of one angle: what the
identification averages. The sysid node and ``galvo-sysid identify`` (bags) both use it, so
both give the same windows.

Everything is decided from message stamps, never from arrival time. The windower keeps a data
clock, the newest stamp of the halves it took. A half is unpaired when the clock is
``pair_timeout`` past its own stamp. A half stamped more than ``time_jump`` away from the
clock is held apart, not used: on its own (one stale or future stamp) it is set aside with
its reason once :data:`CONFIRM` halves in time with the clock have come, and nothing else is
touched; when instead :data:`CONFIRM` halves in a row agree on its new time (a bag replay
looping back, a publisher restarted, a pause), the clock moves there and the held halves are
used; a move back in time then restarts the buffers, so that old and new moves never mix.

A window holds moves of one signed target angle, sample period and record length: a move of
another length (a short first move, say) starts a window of its own instead of fixing the
length of its angle's window. Moves that cannot be used are set aside as
:class:`~galvo_sysid.monitor.rejections.Rejection` records, one per move, said once (the
partner of a rejected half is dropped silently).

Memory is bounded in bytes and counts: at most ``max_buffered_bytes`` bytes of samples in all
(a quarter of it at most for halves waiting for their partner or for their stamp to be
confirmed, the rest for open windows), ``max_pending`` unpaired halves and ``max_windows``
open windows. Beyond, the oldest waiting half is set aside, or a window is evicted by a fair
policy: first the windows that are not filling (a single move of an angle not seen lately),
least recently fed first, then the least recently progressing. An angle whose window was
evicted lately starts as filling when it comes back, so under a flood of distinct angles the
angles that fill steadily still complete. A window not complete ``window_timeout`` after its
first move (by stamps) expires. Each of these is counted and set aside with its reason.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.monitor.moves import SIGNALS, MoveHalf, Window
from galvo_sysid.monitor.parameters import defaults
from galvo_sysid.monitor.rejections import Rejection

if TYPE_CHECKING:
    from numpy.typing import NDArray

__all__ = ['CONFIRM', 'RECENT_ANGLES', 'MoveWindower']

_DEFAULTS = defaults('sysid')
"""The sysid node's parameter defaults: the windower's defaults (one source)."""

CONFIRM = 8
"""Halves that decide about a stamp held apart: this many in a row agreeing with it move the
data clock there; this many in time with the clock set it aside."""

RECENT_ANGLES = 4096
"""Keys of evicted windows remembered (a key seen again opens a window that counts as
filling)."""

_Key = tuple[int, int, int]


@dataclass
class _OpenWindow:
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


def _finite_positive(value: float) -> bool:
    return math.isfinite(value) and value > 0


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
        pair_timeout: A half whose partner has not arrived when the data clock is this much
            later [s] is rejected as unpaired.
        time_jump: A half stamped this much [s] before or after the data clock is held apart
            (see the module docs).
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
        if int(window_size) < 2:
            raise ConfigurationError(f'window_size must be >= 2, got {window_size}')
        if int(min_samples) < 1 or int(max_samples) < int(min_samples):
            raise ConfigurationError('need 1 <= min_samples <= max_samples')
        if samples and not int(min_samples) <= int(samples) <= int(max_samples):
            raise ConfigurationError(
                f'samples must be 0 or within [{min_samples}, {max_samples}], got {samples}')
        for name, value in (('pair_timeout', pair_timeout), ('time_jump', time_jump),
                            ('angle_resolution', angle_resolution),
                            ('window_timeout', window_timeout)):
            if not _finite_positive(float(value)):
                raise ConfigurationError(f'{name} must be positive and finite, got {value}')
        if int(max_pending) < 1 or int(max_windows) < 1:
            raise ConfigurationError('max_pending and max_windows must be >= 1')
        budget = int(max_buffered_bytes)
        smallest = int(samples) or int(min_samples)
        if budget - budget // 4 < 16 * int(window_size) * smallest:
            raise ConfigurationError(f'max_buffered_bytes ({budget}) cannot hold one window '
                                     f'of {window_size} moves of {smallest} samples')
        if budget // 4 < 16 * int(max_samples):
            raise ConfigurationError(f'max_buffered_bytes ({budget}) cannot hold a waiting '
                                     f'pair of the largest records ({max_samples} samples): a '
                                     f'quarter of it must')
        period = float(sample_period)
        if not (period == 0 or _finite_positive(period)):
            raise ConfigurationError(f'sample_period must be 0 or positive and finite, got '
                                     f'{sample_period}')
        self.sample_period = period
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
        self._window_budget = budget - budget // 4
        self._pending: OrderedDict[int, MoveHalf] = OrderedDict()
        self._pending_bytes = 0
        # halves held apart for their stamp, and how the halves since decided about them
        self._held: list[MoveHalf] = []
        self._held_bytes = 0
        self._held_clock = -math.inf
        self._held_run = 0  # halves in a row agreeing with the held ones
        self._held_against = 0  # halves in time with the clock since the first was held
        # open windows, least recently fed first; the keys of those not (yet) filling
        self._windows: OrderedDict[_Key, _OpenWindow] = OrderedDict()
        self._trial: OrderedDict[_Key, None] = OrderedDict()
        self._window_bytes = 0
        self._recent_keys: OrderedDict[_Key, None] = OrderedDict()
        self._next_expiry = -math.inf
        # move_id -> stamp of moves recently completed or rejected (for duplicates and to
        # drop the partner of a rejected half silently); bounded like _pending.
        self._done: OrderedDict[int, tuple[float, bool]] = OrderedDict()
        self._rejections: list[Rejection] = []
        self._clock = -math.inf
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

    # -- state -------------------------------------------------------------------------
    @property
    def pending(self) -> int:
        """Unpaired halves held."""
        return len(self._pending)

    @property
    def held(self) -> int:
        """Halves held apart for their stamp."""
        return len(self._held)

    @property
    def open_windows(self) -> int:
        """Windows being filled."""
        return len(self._windows)

    @property
    def buffered_samples(self) -> int:
        """Samples (current and encoder) held in open windows."""
        return self._window_bytes // 8

    @property
    def buffered_bytes(self) -> int:
        """Bytes of samples held: open windows, unpaired halves and halves held apart."""
        return self._window_bytes + self._pending_bytes + self._held_bytes

    @property
    def next_index(self) -> int:
        """Index the next window will get."""
        return self._next_index

    @property
    def newest_stamp(self) -> float:
        """The data clock: newest stamp taken [s] (-inf before the first half)."""
        return self._clock

    def fill_levels(self) -> dict[float, int]:
        """Moves buffered in open windows, by signed target angle."""
        out: dict[float, int] = {}
        for w in self._windows.values():
            out[w.target_angle] = out.get(w.target_angle, 0) + len(w.move_ids)
        return out

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
        stamp = half.stamp
        clock = self._clock
        in_time = clock == -math.inf or abs(stamp - clock) <= self.time_jump
        if self._held:
            near = abs(stamp - self._held_clock)
            if near <= self.time_jump and (not in_time or near < abs(stamp - clock)):
                return self._hold(half)
            if not in_time:  # far from both: the held halves were not the new time either
                self._set_aside_held()
                return self._hold(half)
            self._held_run = 0
            self._held_against += 1
            if self._held_against >= CONFIRM:
                self._set_aside_held()
        elif not in_time:
            return self._hold(half)
        return self._take(half)

    def refuse(self, half: MoveHalf, reason: str) -> None:
        """Set aside a half refused before its samples were decoded (e.g. an oversized record:
        ``half`` carries its fields without samples); counted in :attr:`refused_halves`."""  # noqa: D205, D209
        self.refused_halves += 1
        self._reject_half(half, reason)

    def expire(self, now: float) -> None:
        """Reject the unpaired halves whose stamp is more than ``pair_timeout`` before ``now``.

        Halves are examined oldest first and the scan stops at the first one still in time,
        so a half that arrived out of stamp order may wait a little longer.
        """
        limit = now - self.pair_timeout
        while self._pending:
            mid, h = next(iter(self._pending.items()))
            if h.stamp >= limit:
                break
            self._drop_pending(mid)
            self._reject_one(mid, h.target_angle, h.stamp,
                             f'unpaired after {self.pair_timeout:g} s: no '
                             f'{_other(h.signal)} record')

    def _expire_windows(self, now: float) -> None:
        """Reject the windows not complete ``window_timeout`` after their first move (checked
        at most every second of data time, or a quarter of the timeout)."""  # noqa: D205, D209
        if now < self._next_expiry:
            return
        self._next_expiry = now + min(1.0, self.window_timeout / 4)
        oldest = now - self.window_timeout
        for key in [k for k, w in self._windows.items() if w.first_stamp < oldest]:
            self._remove_window(key, f'window expired: not complete '
                                     f'{self.window_timeout:g} s after its first move')
            self.windows_expired += 1

    def flush(self, *, min_moves: int = 2) -> list[Window]:
        """Hand out the open windows holding at least ``min_moves`` moves (end of a bag).

        Halves held apart for their stamp are used if nothing contradicted them and they are
        ahead of the clock (the data moved on at the very end), else set aside. Windows with
        fewer moves and all unpaired halves are rejected; the windower is empty afterwards.
        """
        out: list[Window] = []
        if self._held and self._held_against == 0 and self._held_clock > self._clock:
            held = self._release_held()
            for h in held:
                out.extend(self._take(h))
        self._set_aside_held()
        for mid, h in list(self._pending.items()):
            self._reject_one(mid, h.target_angle, h.stamp,
                             f'unpaired at end of data: no {_other(h.signal)} record')
        self._pending.clear()
        self._pending_bytes = 0
        for key in list(self._windows):
            w = self._windows.pop(key)
            if len(w.move_ids) >= max(1, int(min_moves)):
                out.append(self._emit(w, partial=True))
            else:
                self._reject_window(w, f'window of {len(w.move_ids)} move(s) incomplete at end'
                                       f' of data (fewer than {min_moves})')
        self._trial.clear()
        self._window_bytes = 0
        return out

    def reset(self, *, reason: str = 'reset') -> None:
        """Drop every buffered half and move (rejecting them with ``reason``)."""
        for h in self._release_held():
            self._reject_half(h, f'discarded: {reason}')
        for mid, h in list(self._pending.items()):
            self._reject_one(mid, h.target_angle, h.stamp, f'discarded: {reason}')
        for w in self._windows.values():
            self._reject_window(w, f'discarded: {reason}')
        self._pending.clear()
        self._pending_bytes = 0
        self._windows.clear()
        self._trial.clear()
        self._window_bytes = 0
        self._done.clear()
        self._clock = -math.inf
        self._next_expiry = -math.inf
        self.resets += 1

    # -- stamps --------------------------------------------------------------------------
    def _hold(self, half: MoveHalf) -> list[Window]:
        """Hold a half apart for its stamp; use the held halves once CONFIRM agree in a row."""
        self._held.append(half)
        self._held_bytes += half.data.nbytes
        self._held_clock = max(self._held_clock, half.stamp)
        self._held_run += 1
        if self._held_run >= CONFIRM:
            return self._confirm()
        while self._held and self._pending_bytes + self._held_bytes > self._waiting_budget:
            h = self._held.pop(0)
            self._held_bytes -= h.data.nbytes
            self.halves_evicted += 1
            self._reject_half(h, f'held for its stamp: evicted, more than '
                                 f'{self._waiting_budget} bytes of halves waiting')
        return []

    def _confirm(self) -> list[Window]:
        """The held halves agree on a new time: move the clock there and use them."""
        jump = self._held[0].stamp - self._clock
        held = self._release_held()
        if jump < 0:  # a replay looping, a publisher restarted: old and new moves never mix
            self.reset(reason=f'time jumped back {-jump:.3g} s')
        out: list[Window] = []
        for h in held:
            out.extend(self._take(h))
        return out

    def _release_held(self) -> list[MoveHalf]:
        held, self._held = self._held, []
        self._held_bytes = 0
        self._held_clock = -math.inf
        self._held_run = self._held_against = 0
        return held

    def _set_aside_held(self) -> None:
        clock = self._clock
        for h in self._release_held():
            where = 'behind' if h.stamp < clock else 'ahead of'
            self.stale_halves += 1
            self._reject_half(h, f'stamp more than {self.time_jump:g} s {where} the data clock '
                                 f'(set aside alone)')

    # -- internals ---------------------------------------------------------------------
    def _take(self, half: MoveHalf) -> list[Window]:
        """Use a half whose stamp is in time: pair it, window the move."""
        stamp = half.stamp
        self._clock = max(self._clock, stamp)
        self.expire(self._clock)
        self._expire_windows(self._clock)
        mid = half.move_id
        done = self._recent(mid, stamp)
        if done is not None:
            if done:  # both halves were used already: a repeat
                self._reject_repeat(half)
            # else: the partner of a move already set aside; it was said once
            return []
        partner = self._pending.get(mid)
        if partner is None:
            self._pending[mid] = half
            self._pending_bytes += half.data.nbytes
            self._limit_pending()
            return []
        if partner.signal == half.signal:
            if abs(partner.stamp - stamp) <= self.pair_timeout:
                self._reject_repeat(half)  # the first half keeps waiting for its partner
                return []
            # the same id much later (a restarted publisher): the old half is stale
            self._drop_pending(mid)
            self._reject_one(mid, partner.target_angle, partner.stamp,
                             f'unpaired: no {_other(partner.signal)} record')
            self._pending[mid] = half
            self._pending_bytes += half.data.nbytes
            self._limit_pending()
            return []
        self._drop_pending(mid)
        current, encoder = (half, partner) if half.signal == 'current' else (partner, half)
        return self._add_move(current, encoder)

    def _drop_pending(self, mid: int) -> MoveHalf:
        h = self._pending.pop(mid)
        self._pending_bytes -= h.data.nbytes
        return h

    def _limit_pending(self) -> None:
        """Within max_pending and the waiting share of the byte budget (held halves first)."""
        while self._held and self._pending_bytes + self._held_bytes > self._waiting_budget:
            h = self._held.pop(0)
            self._held_bytes -= h.data.nbytes
            self.halves_evicted += 1
            self._reject_half(h, f'held for its stamp: evicted, more than '
                                 f'{self._waiting_budget} bytes of halves waiting')
        while self._pending and (len(self._pending) > self.max_pending or
                                 self._pending_bytes > self._waiting_budget):
            mid = next(iter(self._pending))
            h = self._drop_pending(mid)
            self.halves_evicted += 1
            why = (f'more than {self.max_pending} halves waiting'
                   if len(self._pending) >= self.max_pending
                   else f'more than {self._waiting_budget} bytes of halves waiting')
            self._reject_one(mid, h.target_angle, h.stamp, f'unpaired: evicted, {why}')

    def _check_half(self, half: MoveHalf) -> str | None:
        """Return why the half is unusable, or None."""
        if half.signal not in SIGNALS:
            return f'unknown signal {half.signal!r}'
        if half.move_id < 0:
            return 'negative move_id'
        if not math.isfinite(half.stamp):
            return f'non-finite stamp in {half.signal}'
        if not math.isfinite(half.target_angle):
            return f'non-finite target angle in {half.signal}'
        if abs(half.target_angle) < self.angle_resolution:
            return 'zero target angle'
        if not _finite_positive(half.sample_period):
            return f'bad sample period {half.sample_period!r} s in {half.signal}'
        expected = self.sample_period
        if expected and abs(half.sample_period - expected) > 1e-6 * expected:
            self.period_mismatches += 1
            self.period_mismatch = (f"the data's sample period {half.sample_period:.6g} s "
                                    f"differs from the model's {expected:.6g} s")
            return self.period_mismatch
        data = half.data
        if data.ndim != 1:
            return f'{half.signal} record is not one-dimensional'
        n = data.shape[0]
        if n == 0:
            return f'empty {half.signal} record'
        if n > self.max_samples:
            return f'{half.signal} record too long ({n} > {self.max_samples} samples)'
        if n < self.min_samples:
            return f'{half.signal} record too short ({n} < {self.min_samples} samples)'
        if self.samples and n != self.samples:
            return f'{half.signal} record has {n} samples, expected {self.samples}'
        if not np.isfinite(data).all():
            return f'NaN or Inf in {half.signal}'
        return None

    def _recent(self, move_id: int, stamp: float) -> bool | None:
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

    def _reject_half(self, half: MoveHalf, reason: str) -> None:
        mid = half.move_id
        if mid < 0:
            self._rejections.append(Rejection(mid, half.target_angle, half.stamp, reason))
            self.moves_rejected += 1
            return
        partner = self._pending.get(mid)
        stamp = half.stamp if math.isfinite(half.stamp) else (
            partner.stamp if partner is not None else self._clock)
        done = self._recent(mid, stamp)
        if done is not None:
            if done:  # a broken repeat of a move already used
                self._rejections.append(Rejection(mid, half.target_angle, stamp,
                                                  f'{reason} (repeat of a used move_id)'))
                self.moves_rejected += 1
            return  # else the move was already set aside: say nothing twice
        if partner is not None:
            self._drop_pending(mid)
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

    def _reject_window(self, w: _OpenWindow, reason: str) -> None:
        for mid, stamp in zip(w.move_ids, w.stamps, strict=True):
            self._rejections.append(Rejection(mid, w.target_angle, stamp, reason))
            self.moves_rejected += 1
        self.moves_accepted -= len(w.move_ids)

    def _mark_done(self, move_id: int, stamp: float, *, used: bool) -> None:
        self._done[move_id] = (stamp if math.isfinite(stamp) else self._clock, used)
        self._done.move_to_end(move_id)
        limit = max(4 * self.max_pending, 4 * self.window_size)
        while len(self._done) > limit:
            self._done.popitem(last=False)

    def _key(self, angle: float, period: float, samples: int) -> _Key:
        # with the model's period every accepted move has it (within 1e-6): one key
        span = 0 if self.sample_period else round(math.log(period) * 1e6)
        return (round(angle / self.angle_resolution), span, samples)

    def _add_move(self, current: MoveHalf, encoder: MoveHalf) -> list[Window]:
        mid = current.move_id
        stamp = min(current.stamp, encoder.stamp)
        problem = None
        n = current.data.shape[0]
        if encoder.data.shape[0] != n:
            problem = (f'current and encoder lengths differ ({n} and '
                       f'{encoder.data.shape[0]} samples)')
        elif abs(current.target_angle - encoder.target_angle) >= self.angle_resolution:
            problem = (f'current and encoder disagree on target angle '
                       f'({current.target_angle:g} and {encoder.target_angle:g} deg)')
        elif abs(current.sample_period - encoder.sample_period) > \
                1e-9 * current.sample_period:
            problem = 'current and encoder disagree on sample period'
        if problem is not None:
            self._reject_one(mid, current.target_angle, stamp, problem)
            return []
        key = self._key(current.target_angle, current.sample_period, n)
        w = self._windows.get(key)
        if w is None:
            filling = key in self._recent_keys
            w = _OpenWindow(target_angle=current.target_angle,
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
        w.move_ids.append(mid)
        w.stamps.append(stamp)
        w.first_stamp = min(w.first_stamp, stamp)
        self._window_bytes += 16 * n
        self.moves_accepted += 1
        self._mark_done(mid, stamp, used=True)
        if len(w.move_ids) >= self.window_size:
            del self._windows[key]
            self._trial.pop(key, None)
            self._window_bytes -= w.nbytes
            self._remember(key)
            return [self._emit(w, partial=False)]
        self._evict_windows()
        return []

    def _evict_windows(self) -> None:
        """Within max_windows and the windows' share of the byte budget, fairly: windows not
        filling first (least recently fed first), then the least recently progressing."""  # noqa: D205, D209
        while len(self._windows) > self.max_windows or (
                self._window_bytes > self._window_budget and self._windows):
            why = (f'more than {self.max_windows} open windows'
                   if len(self._windows) > self.max_windows
                   else f'more than {self._window_budget} bytes in open windows')
            key = next(iter(self._trial)) if self._trial else next(iter(self._windows))
            self._remove_window(key, f'window evicted: {why}')
            self.windows_evicted += 1

    def _remove_window(self, key: _Key, reason: str) -> None:
        w = self._windows.pop(key)
        self._trial.pop(key, None)
        self._window_bytes -= w.nbytes
        self._remember(key)
        self._reject_window(w, reason)

    def _remember(self, key: _Key) -> None:
        """A window of this key was open lately: the next one counts as filling."""
        self._recent_keys[key] = None
        self._recent_keys.move_to_end(key)
        while len(self._recent_keys) > RECENT_ANGLES:
            self._recent_keys.popitem(last=False)

    def _emit(self, w: _OpenWindow, *, partial: bool) -> Window:
        index = self._next_index
        self._next_index += 1
        return Window(index=index, target_angle=w.target_angle, sample_period=w.sample_period,
                      current=np.stack(w.current), encoder=np.stack(w.encoder),
                      move_ids=tuple(w.move_ids), first_stamp=min(w.stamps),
                      last_stamp=max(w.stamps), partial=partial)


def _other(signal: str) -> str:
    return 'encoder' if signal == 'current' else 'current'
