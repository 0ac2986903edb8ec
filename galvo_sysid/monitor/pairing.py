"""Pairing of current and encoder records by move_id, and windows of moves per target angle.

A positioning move arrives as two halves (``MoveSamples`` on ``galvo/current`` and on
``galvo/encoder``) that share a ``move_id``. :class:`MoveWindower` pairs the halves, checks
them, buffers the complete moves per signed target angle and hands out a
:class:`~galvo_sysid.monitor.moves.Window` every ``window_size`` moves of one angle: what the
identification averages. The sysid node and ``galvo-sysid identify`` (bags) both use it, so
both give the same windows.

Everything is decided from message stamps, never from arrival time: a half is unpaired when
the newest stamp seen is ``pair_timeout`` past its own, and a stamp that jumps back by more than
``time_jump`` (a bag replay looping) resets all buffers so that old and new moves never mix.

Moves that cannot be used are set aside as
:class:`~galvo_sysid.monitor.rejections.Rejection` records, one per move, said once
(the partner of a rejected half is dropped silently). Memory is bounded: at most
``max_pending`` unpaired halves, ``max_windows`` open windows and ``max_buffered_samples``
buffered samples; beyond that the oldest pending half or the least recently fed window is
evicted, and its moves are rejected with the reason.
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

__all__ = ['MoveWindower']

_DEFAULTS = defaults('sysid')
"""The sysid node's parameter defaults: the windower's defaults (one source)."""


@dataclass
class _OpenWindow:
    target_angle: float
    sample_period: float
    samples: int
    current: list[NDArray[np.float64]] = field(default_factory=list)
    encoder: list[NDArray[np.float64]] = field(default_factory=list)
    move_ids: list[int] = field(default_factory=list)
    stamps: list[float] = field(default_factory=list)


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
        samples: Expected samples per record; 0 lets the first move of each window fix it.
        max_samples: Largest accepted record (an oversized array is rejected).
        min_samples: Smallest accepted record.
        pair_timeout: A half whose partner has not arrived when the newest stamp is this
            much later [s] is rejected as unpaired.
        time_jump: A stamp this much earlier [s] than the newest seen resets all buffers.
        angle_resolution: Target angles closer than this [deg] share a window; smaller
            magnitudes count as a zero angle.
        max_pending: Most unpaired halves held.
        max_windows: Most open windows held (the paper's schedule needs 38: 19 angles, both
            signs).
        max_buffered_samples: Most samples (current and encoder together) held in open windows.
        first_index: Index of the first window handed out (to continue a numbering).
        sample_period: The sample period the records must have [s] (the plant model's): a
            move of another period (relative difference over 1e-6) is set aside, the reason
            naming both periods; 0 accepts any period.

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
                 max_buffered_samples: int = _DEFAULTS['max_buffered_samples'],
                 first_index: int = 0, sample_period: float = 0.0) -> None:
        if int(window_size) < 2:
            raise ConfigurationError(f'window_size must be >= 2, got {window_size}')
        if int(min_samples) < 1 or int(max_samples) < int(min_samples):
            raise ConfigurationError('need 1 <= min_samples <= max_samples')
        if samples and not int(min_samples) <= int(samples) <= int(max_samples):
            raise ConfigurationError(
                f'samples must be 0 or within [{min_samples}, {max_samples}], got {samples}')
        for name, value in (('pair_timeout', pair_timeout), ('time_jump', time_jump),
                            ('angle_resolution', angle_resolution)):
            if not _finite_positive(float(value)):
                raise ConfigurationError(f'{name} must be positive and finite, got {value}')
        if int(max_pending) < 1 or int(max_windows) < 1:
            raise ConfigurationError('max_pending and max_windows must be >= 1')
        if int(max_buffered_samples) < 2 * int(window_size) * int(min_samples):
            raise ConfigurationError('max_buffered_samples cannot hold one window')
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
        self.max_buffered_samples = int(max_buffered_samples)
        self._pending: OrderedDict[int, MoveHalf] = OrderedDict()
        self._windows: OrderedDict[tuple[int, int], _OpenWindow] = OrderedDict()
        # move_id -> stamp of moves recently completed or rejected (for duplicates and to
        # drop the partner of a rejected half silently); bounded like _pending.
        self._done: OrderedDict[int, tuple[float, bool]] = OrderedDict()
        self._rejections: list[Rejection] = []
        self._buffered = 0
        self._newest = -math.inf
        self._next_index = int(first_index)
        self.resets = 0
        """How many times a stamp jumping back reset the buffers."""
        self.moves_accepted = 0
        """Moves paired and buffered or handed out in windows (evicted ones are taken off)."""
        self.moves_rejected = 0
        """Rejections issued so far (moves set aside, plus repeated halves)."""
        self.period_mismatches = 0
        """Halves whose sample period is not :attr:`sample_period` (each move set aside once;
        its partner is counted too)."""
        self.period_mismatch: str | None = None
        """The latest reason a move was set aside for its sample period (None: never)."""

    # -- state -------------------------------------------------------------------------
    @property
    def pending(self) -> int:
        """Unpaired halves held."""
        return len(self._pending)

    @property
    def open_windows(self) -> int:
        """Windows being filled."""
        return len(self._windows)

    @property
    def buffered_samples(self) -> int:
        """Samples (current and encoder) held in open windows."""
        return self._buffered

    @property
    def next_index(self) -> int:
        """Index the next window will get."""
        return self._next_index

    @property
    def newest_stamp(self) -> float:
        """Newest stamp seen [s] (-inf before the first half)."""
        return self._newest

    def fill_levels(self) -> dict[float, int]:
        """Moves buffered per open window, by signed target angle."""
        return {w.target_angle: len(w.move_ids) for w in self._windows.values()}

    def pop_rejections(self) -> list[Rejection]:
        """Return and forget the rejections since the last call."""
        out, self._rejections = self._rejections, []
        return out

    # -- input -------------------------------------------------------------------------
    def add(self, half: MoveHalf) -> list[Window]:
        """Take one half; return the windows it completed (none or one)."""
        problem = self._check_half(half)
        stamp = half.stamp
        if problem is None and stamp < self._newest - self.time_jump:
            self.reset(reason=f'time jumped back {self._newest - stamp:.3g} s')
        if problem is not None:
            self._reject_half(half, problem)
            return []
        self._newest = max(self._newest, stamp)
        self.expire(self._newest)
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
            self._evict_pending()
            return []
        if partner.signal == half.signal:
            if abs(partner.stamp - stamp) <= self.pair_timeout:
                self._reject_repeat(half)  # the first half keeps waiting for its partner
                return []
            # the same id much later (a restarted publisher): the old half is stale
            del self._pending[mid]
            self._reject_one(mid, partner.target_angle, partner.stamp,
                             f'unpaired: no {_other(partner.signal)} record')
            self._pending[mid] = half
            return []
        del self._pending[mid]
        current, encoder = (half, partner) if half.signal == 'current' else (partner, half)
        return self._add_move(current, encoder)

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
            del self._pending[mid]
            self._reject_one(mid, h.target_angle, h.stamp,
                             f'unpaired after {self.pair_timeout:g} s: no '
                             f'{_other(h.signal)} record')

    def flush(self, *, min_moves: int = 2) -> list[Window]:
        """Hand out the open windows holding at least ``min_moves`` moves (end of a bag).

        Windows with fewer moves and all unpaired halves are rejected; the windower is empty
        afterwards.
        """
        out: list[Window] = []
        for mid, h in list(self._pending.items()):
            self._reject_one(mid, h.target_angle, h.stamp,
                             f'unpaired at end of data: no {_other(h.signal)} record')
        self._pending.clear()
        for key in list(self._windows):
            w = self._windows.pop(key)
            if len(w.move_ids) >= max(1, int(min_moves)):
                out.append(self._emit(w, partial=True))
            else:
                self._reject_window(w, f'window of {len(w.move_ids)} move(s) incomplete at end'
                                       f' of data (fewer than {min_moves})')
        self._buffered = 0
        return out

    def reset(self, *, reason: str = 'reset') -> None:
        """Drop every buffered half and move (rejecting them with ``reason``)."""
        for mid, h in list(self._pending.items()):
            self._reject_one(mid, h.target_angle, h.stamp, f'discarded: {reason}')
        for w in self._windows.values():
            self._reject_window(w, f'discarded: {reason}')
        self._pending.clear()
        self._windows.clear()
        self._done.clear()
        self._buffered = 0
        self._newest = -math.inf
        self.resets += 1

    # -- internals ---------------------------------------------------------------------
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
            partner.stamp if partner is not None else self._newest)
        done = self._recent(mid, stamp)
        if done is not None:
            if done:  # a broken repeat of a move already used
                self._rejections.append(Rejection(mid, half.target_angle, stamp,
                                                  f'{reason} (repeat of a used move_id)'))
                self.moves_rejected += 1
            return  # else the move was already set aside: say nothing twice
        if partner is not None:
            del self._pending[mid]
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
        self._done[move_id] = (stamp if math.isfinite(stamp) else self._newest, used)
        self._done.move_to_end(move_id)
        limit = max(4 * self.max_pending, 4 * self.window_size)
        while len(self._done) > limit:
            self._done.popitem(last=False)

    def _evict_pending(self) -> None:
        while len(self._pending) > self.max_pending:
            mid, h = self._pending.popitem(last=False)
            self._reject_one(mid, h.target_angle, h.stamp,
                             f'unpaired: evicted, more than {self.max_pending} halves waiting')

    def _key(self, angle: float, period: float) -> tuple[int, int]:
        return (round(angle / self.angle_resolution), round(math.log(period) * 1e6))

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
        key = self._key(current.target_angle, current.sample_period)
        w = self._windows.get(key)
        if w is None:
            w = _OpenWindow(target_angle=current.target_angle,
                            sample_period=current.sample_period, samples=n)
            self._windows[key] = w
        elif n != w.samples:
            self._reject_one(mid, current.target_angle, stamp,
                             f'record has {n} samples, the window {w.samples}')
            return []
        self._windows.move_to_end(key)
        w.current.append(current.data)
        w.encoder.append(encoder.data)
        w.move_ids.append(mid)
        w.stamps.append(stamp)
        self._buffered += 2 * n
        self.moves_accepted += 1
        self._mark_done(mid, stamp, used=True)
        if len(w.move_ids) >= self.window_size:
            del self._windows[key]
            self._buffered -= 2 * n * len(w.move_ids)
            return [self._emit(w, partial=False)]
        self._evict_windows()
        return []

    def _evict_windows(self) -> None:
        while len(self._windows) > self.max_windows or (
                self._buffered > self.max_buffered_samples and self._windows):
            _, w = self._windows.popitem(last=False)
            self._buffered -= 2 * w.samples * len(w.move_ids)
            why = (f'more than {self.max_windows} open windows'
                   if len(self._windows) >= self.max_windows
                   else f'more than {self.max_buffered_samples} buffered samples')
            self._reject_window(w, f'window evicted: {why}')

    def _emit(self, w: _OpenWindow, *, partial: bool) -> Window:
        index = self._next_index
        self._next_index += 1
        return Window(index=index, target_angle=w.target_angle, sample_period=w.sample_period,
                      current=np.stack(w.current), encoder=np.stack(w.encoder),
                      move_ids=tuple(w.move_ids), first_stamp=min(w.stamps),
                      last_stamp=max(w.stamps), partial=partial)


def _other(signal: str) -> str:
    return 'encoder' if signal == 'current' else 'current'
