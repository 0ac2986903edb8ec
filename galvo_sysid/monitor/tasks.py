"""The task objects the nodes wire: the logic of the sysid and watchdog nodes, without ROS.

- :class:`SysidTask` ties a :class:`~galvo_sysid.monitor.pairing.MoveWindower` and a
  :class:`~galvo_sysid.monitor.scheduler.WindowScheduler` together: ``add(half)`` never
  blocks on a fit, rejections are reported grouped by reason through a
  :class:`~galvo_sysid.monitor.ratelog.RateLimitedLog`, counters say what happened to every
  move, and :meth:`SysidTask.health` says how identification goes (windows that do not match
  the plant model are an error, said plainly: the scanner is not the one the model
  describes).
- :class:`WatchdogTask` keeps the watchdog's state: the latest verdict of its
  :class:`~galvo_sysid.monitor.drift.DriftMonitor`, and STALE when no result came for a while.

The nodes (:mod:`galvo_sysid.nodes.sysid_node`, :mod:`galvo_sysid.nodes.watchdog_node`) only
convert messages and forward them; tests and benchmarks drive these objects directly.
"""

from __future__ import annotations

import math
import threading
import time
from collections import OrderedDict, deque
from dataclasses import replace
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.ident.measured import check_lag
from galvo_sysid.ident.warm import WarmStart
from galvo_sysid.model.files import model_label
from galvo_sysid.monitor.moves import too_long
from galvo_sysid.monitor.pairing import LATE_TOPIC, MoveWindower
from galvo_sysid.monitor.ratelog import RateLimitedLog
from galvo_sysid.monitor.rejections import summarize_rejections
from galvo_sysid.monitor.scheduler import FitOutcome, WindowScheduler
from galvo_sysid.monitor.verdict import ERROR, OK, STATUS_OK, WARN

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping

    from numpy.typing import NDArray

    from galvo_sysid.ident.result import IdentificationResult
    from galvo_sysid.monitor.drift import DriftMonitor, ModalEstimate
    from galvo_sysid.monitor.moves import MoveHalf, Window
    from galvo_sysid.monitor.verdict import DriftVerdict

__all__ = ['LATENCY_WINDOWS', 'SerializedHalf', 'SysidTask', 'WatchdogTask', 'mismatch_message']

LATENCY_WINDOWS = 200
"""Windows the sysid task's latency figures (:meth:`SysidTask.latency_ms`) are taken over."""

MAX_STARTS = 256
"""Angles (and signs, by record length) whose latest result the sysid task keeps to start their
next window from (the least recently identified forgotten beyond)."""


class SerializedHalf(Protocol):
    """A half not decoded yet, its record's length known (e.g.
    :class:`~galvo_sysid.interfaces.messages.SerializedMoveSamples`)."""  # noqa: D205, D209

    @property
    def samples(self) -> int:
        """Samples in the record."""

    def half(self, signal: str) -> MoveHalf:
        """Decode it."""

    def header_half(self, signal: str) -> MoveHalf:
        """Its fields without samples (nothing decoded)."""


def mismatch_message(reason: str, *, model_path: str | None) -> str:
    """The one line that says data do not match a model file, and what to do.

    Example: ``the data do not match model scanner.yaml: no physical mode 2 in the band ...;
    run galvo-sysid commission``.
    """
    why = ' '.join(reason.split())
    return (f'the data do not match model {model_label(model_path)}: {why}; run galvo-sysid '
            f'commission')


def _spread(seconds: NDArray[np.float64], name: str) -> dict[str, int]:
    """``{name}_median``, ``_p99`` and ``_max`` of ``seconds`` in ms (-1 each if empty)."""
    keys = (f'{name}_median', f'{name}_p99', f'{name}_max')
    if not seconds.size:
        return dict.fromkeys(keys, -1)
    median, p99 = np.percentile(seconds, [50.0, 99.0])
    return dict(zip(keys, (round(1e3 * float(median)), round(1e3 * float(p99)),
                           round(1e3 * float(seconds.max()))), strict=True))


class SysidTask:
    """The sysid node's logic: pair, window, fit off-thread, count and report.

    Args:
        fit: ``fit(window) -> IdentificationResult`` (see
            :class:`~galvo_sysid.monitor.scheduler.WindowScheduler`).
        on_result: Called with each :class:`~galvo_sysid.monitor.scheduler.FitOutcome` (on a
            worker thread).
        warn: Where warnings go (rate limited by the task).
        windower: Keyword arguments of :class:`~galvo_sysid.monitor.pairing.MoveWindower`
            (``sample_period``: the model's, so moves of another scanner are set aside).
        queue_size: Windows waiting for a fit at most.
        processes: Child processes for the fits (0: fit on a worker thread).
        warnings_per_second: Most warning lines a second.
        warm_start: Start each window's refined fit from the latest result of its angle and
            record length, or of its sign where the angle has none yet, or from
            ``reference`` where neither has (:mod:`galvo_sysid.ident.warm`).
        reference: The start of a window without an earlier result of its angle or sign
            (:func:`~galvo_sysid.ident.warm.reference_start`: the model file's modes), used
            while the latest finished window did not fail or mismatch; None: such a window
            is fitted afresh.
        model_path: The plant-model file the fits use ('' or None: the packaged paper
            model), for the messages.
        fit_budget: Seconds from a window's completion past which its refined fit leaves out
            what it can do without (the weak modes' band profiles, reported unresolved; see
            :class:`~galvo_sysid.ident.refine.RefineOptions`' ``deadline``); 0: no budget.
        measured_lag: The current halves are the coil current measured when the encoder is
            read, behind an amplifier lag of this time constant [s]: each window is made into
            the held current that drives it (:meth:`~galvo_sysid.monitor.moves.Window.held`)
            before its fit; None: they are the command.

    Raises:
        ConfigurationError: A bad ``measured_lag`` (for the windower's sample period).
    """

    def __init__(self, fit: Callable[[Window], IdentificationResult],
                 on_result: Callable[[FitOutcome], None], *, warn: Callable[[str], None],
                 windower: Mapping[str, Any] | None = None, queue_size: int = 8,
                 processes: int = 0, warnings_per_second: int = 20,
                 warm_start: bool = True, model_path: str | None = None,
                 fit_budget: float = 0.0, measured_lag: float | None = None,
                 reference: WarmStart | None = None) -> None:
        self.windower = MoveWindower(**dict(windower or {}))
        self.measured_lag = None if measured_lag is None else check_lag(
            measured_lag, self.windower.sample_period or None)
        self._warn = RateLimitedLog(warn, per_second=warnings_per_second)
        self._on_result = on_result
        self.model_path = model_path or ''
        self.fitter = WindowScheduler(fit, self._done, queue_size=queue_size,
                                      processes=processes)
        self.halves_received = 0
        self.windows_completed = 0
        self._latencies: deque[float] = deque(maxlen=LATENCY_WINDOWS)
        self._fit_cpu: deque[float] = deque(maxlen=LATENCY_WINDOWS)
        self._waits: deque[float] = deque(maxlen=LATENCY_WINDOWS)
        self._last_input = time.monotonic()
        self._lock = threading.Lock()
        self.last_mismatch: str | None = None
        """Why the latest window that did not match the model did not (None: none so far)."""
        self.latest_mismatched = False
        """Whether the latest finished window did not match the model."""
        self.warm_start = bool(warm_start)
        self.windows_warm = 0
        """Windows identified by a fit started from an earlier result (of their angle, or
        of their sign) or from ``reference``."""
        self.fit_budget = float(fit_budget)
        self.windows_cut_short = 0
        """Windows whose fit passed its budget and left out the weak modes' profiles."""
        self._starts: OrderedDict[tuple[int, int], WarmStart] = OrderedDict()
        # the latest result of each sign and record length: where an angle has none yet
        self._by_sign: OrderedDict[tuple[int, int], WarmStart] = OrderedDict()
        self.reference = reference
        self._reference_usable = True  # False from a failed or mismatched window on

    def add(self, half: MoveHalf) -> list[Window]:
        """Take one half; queue the windows it completed (returned) and report rejections."""
        self.halves_received += 1
        self._last_input = time.monotonic()
        resets = self.windower.resets
        windows = self.windower.add(half)
        if self.windower.resets != resets:
            self._warn('stamps jumped back and stayed back (a bag replay looping?): buffers '
                       'reset', key='time jump')
            self.clear_starts()
        self._report()
        for w in windows:
            self.windows_completed += 1
            if self.measured_lag is not None:
                w = w.held(self.measured_lag)
            for old in self.fitter.submit(self._started(w)):
                self._warn(f'window {old.index} ({old.target_angle:g} deg, {old.moves} moves) '
                           'dropped: identification queue full (fits slower than input)',
                           key='queue full')
        return windows

    def clear_starts(self) -> None:
        """Forget the results the next windows would start from (the next fit of each angle
        starts from ``reference``, or searches afresh): after a reset, or new window or fit
        settings."""  # noqa: D205, D209
        with self._lock:
            self._starts.clear()
            self._by_sign.clear()

    def _start_key(self, w: Window) -> tuple[int, int]:
        return (round(w.target_angle / self.windower.angle_resolution), w.current.shape[-1])

    @staticmethod
    def _sign_key(w: Window) -> tuple[int, int]:
        return (1 if w.target_angle > 0 else -1, w.current.shape[-1])

    def _started(self, w: Window) -> Window:
        """``w`` with the start its fit takes (the latest result of its angle; for an angle
        without one yet, the latest of its sign and record length: another angle of the same
        plant, as ``galvo-sysid identify``'s warm chains start; for a sign without one either,
        ``reference`` unless the latest finished window failed or mismatched), if any, and its
        deadline (``fit_budget`` from now), if any."""  # noqa: D205, D209
        if self.fit_budget > 0:
            w = replace(w, deadline=time.monotonic() + self.fit_budget)
        if not self.warm_start:
            return w
        with self._lock:
            start = self._starts.get(self._start_key(w))
            if start is None:
                start = self._by_sign.get(self._sign_key(w))
            if start is None and self._reference_usable:
                start = self.reference
        return w if start is None else replace(w, warm_start=start)

    def set_aside(self, text: str) -> None:
        """Report a message that could not even be converted (counted as one rejection)."""
        self.windower.moves_rejected += 1
        self._warn(f'message set aside: {text}', key='bad message')

    def add_serialized(self, msg: SerializedHalf, *, signal: str) -> list[Window]:
        """Take one half still serialized: its record's length is judged before any sample
        is decoded (an oversized record is refused without ever being built), then it is
        decoded and taken like :meth:`add`."""  # noqa: D205, D209
        limit = self.windower.max_samples
        if msg.samples > limit:
            self.refuse(msg.header_half(signal), too_long(signal, msg.samples, limit))
            return []
        return self.add(msg.half(signal))

    def refuse(self, half: MoveHalf, reason: str) -> None:
        """Set aside a half refused before its samples were decoded (an oversized record:
        ``half`` has its fields, no samples), reported like every rejection."""  # noqa: D205, D209
        self.halves_received += 1
        self._last_input = time.monotonic()
        self.windower.refuse(half, reason)
        self._report()

    def tick(self) -> None:
        """Call periodically: expire unpaired halves when input has paused, flush the log.

        While no input arrives, the data clocks are assumed to advance at least as fast as
        the wall clock; a pause in all input is no sign that a partner is missing (huge
        messages in flight hold up both topics for seconds), so a waiting half is given as
        long as a lagging partner's topic is (:data:`~galvo_sysid.monitor.pairing.LATE_TOPIC`
        + 1 pair timeouts): a half whose partner never comes is reported within
        ``(LATE_TOPIC + 1) * pair_timeout`` (wall) seconds.
        """
        idle = time.monotonic() - self._last_input
        w = self.windower
        if w.pending and idle > (LATE_TOPIC + 1) * w.pair_timeout:
            w.expire(w.newest_stamp + idle - LATE_TOPIC * w.pair_timeout)
            self._report()
        self._warn.flush()

    def _report(self) -> None:
        rejections = self.windower.pop_rejections()
        if rejections:
            for line in summarize_rejections(rejections):
                self._warn(line, key=line.split(': ', 1)[-1])

    def mismatch_text(self, reason: str) -> str:
        """The line saying the data do not match this task's model (:func:`mismatch_message`)."""
        return mismatch_message(reason, model_path=self.model_path)

    @staticmethod
    def _keep(starts: OrderedDict[tuple[int, int], WarmStart], key: tuple[int, int],
              start: WarmStart) -> None:
        """Keep ``start`` under ``key``, the least recently kept forgotten beyond
        :data:`MAX_STARTS`."""  # noqa: D205, D209
        starts[key] = start
        starts.move_to_end(key)
        while len(starts) > MAX_STARTS:
            starts.popitem(last=False)

    def _done(self, outcome: FitOutcome) -> None:
        w = outcome.window
        key = self._start_key(w)
        with self._lock:
            latency = outcome.queued + outcome.fit_time
            self._latencies.append(latency)
            if math.isfinite(outcome.fit_cpu):
                self._fit_cpu.append(outcome.fit_cpu)
                self._waits.append(max(latency - outcome.fit_cpu, 0.0))
            start = None if outcome.result is None else WarmStart.from_result(outcome.result)
            if start is not None:
                self._keep(self._starts, key, start)
                self._keep(self._by_sign, self._sign_key(w), start)
            else:  # a failed or mismatched window: the next of its angle searches afresh
                self._starts.pop(key, None)
                self._by_sign.pop(self._sign_key(w), None)
            self._reference_usable = outcome.result is not None
            if outcome.result is not None:
                self.windows_warm += outcome.result.warm_started
                self.windows_cut_short += outcome.result.cut_short
                self.latest_mismatched = False
            elif outcome.mismatch:
                self.latest_mismatched = True
                self.last_mismatch = outcome.error or 'unknown reason'
        if outcome.mismatch:
            self._warn(f'window {w.index} ({w.target_angle:g} deg, {w.moves} moves) not '
                       f'identified: {self.mismatch_text(outcome.error or "")}',
                       key='model mismatch')
        elif outcome.error is not None:
            self._warn(f'window {w.index} ({w.target_angle:g} deg, {w.moves} moves) not '
                       f'identified: {outcome.error}', key='fit failed')
        elif outcome.result is not None and outcome.result.cut_short:
            self._warn(f'window {w.index} ({w.target_angle:g} deg) fit cut short at its budget '
                       f'of {1e3 * self.fit_budget:.0f} ms: its weakly excited modes were not '
                       f'profiled and are reported unresolved', key='cut short')
        self._on_result(outcome)

    def stats(self) -> dict[str, int]:
        """Counters: halves received, moves accepted/rejected (and of those, halves of
        another sample period than the model's, halves refused before decoding, halves set
        aside for their stamp, waiting halves evicted), windows identified (and of those,
        by a fit started from an earlier result, and by a fit cut short at
        its budget) / failed / not matching the model / dropped, open windows evicted /
        expired, resets, queue, bytes of samples buffered, the most one topic came late
        behind the other [ms], and :meth:`latency_ms`."""  # noqa: D205, D209
        w = self.windower
        f = self.fitter
        return {'halves_received': self.halves_received, 'moves_accepted': w.moves_accepted,
                'moves_rejected': w.moves_rejected,
                'halves_period_mismatched': w.period_mismatches,
                'halves_refused': w.refused_halves, 'halves_stale': w.stale_halves,
                'halves_evicted': w.halves_evicted, 'pending_halves': w.pending,
                'held_halves': w.held, 'open_windows': w.open_windows,
                'windows_completed': self.windows_completed,
                'windows_identified': f.fitted, 'windows_warm_started': self.windows_warm,
                'windows_cut_short': self.windows_cut_short,
                'windows_failed': f.failed,
                'windows_mismatched': f.mismatched, 'windows_dropped': f.dropped,
                'windows_waiting': f.waiting, 'windows_evicted': w.windows_evicted,
                'windows_expired': w.windows_expired, 'resets': w.resets,
                'buffered_bytes': w.buffered_bytes,
                'topic_lag_ms_max': round(1e3 * w.topic_lag), **self.latency_ms()}

    def latency_ms(self) -> dict[str, int]:
        """Latency from a window's completion to the end of its fit, the CPU time of the
        fit itself (where it ran), and per window the latency less that CPU time [ms]: the
        wait for a fit process, the hand-over to it and back, and the time the fit waited for
        a CPU (``wait_ms``; a machine short of CPU shows there, a slow fit in ``fit_cpu_ms``).
        Each as median, 99th percentile and largest over the last :data:`LATENCY_WINDOWS`
        windows finished (the CPU and wait over those identified; -1 each before the
        first)."""  # noqa: D205, D209
        with self._lock:
            latencies = np.array(self._latencies, dtype=float)
            cpu = np.array(self._fit_cpu, dtype=float)
            waits = np.array(self._waits, dtype=float)
        return {**_spread(latencies, 'latency_ms'), **_spread(cpu, 'fit_cpu_ms'),
                **_spread(waits, 'wait_ms')}

    def health(self, since: Mapping[str, int], *,
               now: Mapping[str, int] | None = None) -> tuple[int, str]:
        """How identification goes between the counters ``since`` and ``now``.

        Args:
            since: Counters of an earlier :meth:`stats` (the last report's).
            now: Counters now (default: :meth:`stats`).

        Returns:
            ``(level, message)``: ERROR (2) when windows did not match the model since then
            or the latest window did not (or moves came with another sample period than the
            model's), saying so with the reason; WARN (1) when moves were set aside or windows
            failed or were dropped since then; else OK (0) with the windows identified.
        """
        now = self.stats() if now is None else now
        # (counters of a windower replaced by new settings start again: never below 0)
        new = {k: max(0, now[k] - since.get(k, 0)) for k in
               ('moves_rejected', 'windows_failed', 'windows_dropped', 'windows_identified',
                'windows_mismatched', 'halves_period_mismatched')}
        with self._lock:
            latest, why = self.latest_mismatched, self.last_mismatch
        period = self.windower.period_mismatch
        if new['halves_period_mismatched'] and period is not None:
            return ERROR, (f'moves set aside since the last report: '
                           f'{self.mismatch_text(period)}')
        if new['windows_mismatched'] or latest:
            count = new['windows_mismatched']
            lead = f'{count} window(s) not identified since the last report: ' if count else \
                'the latest window was not identified: '
            return ERROR, lead + self.mismatch_text(why or 'unknown reason')
        trouble = [f'{new["moves_rejected"]} move(s) set aside'] if new['moves_rejected'] else []
        if new['windows_failed']:
            trouble.append(f'{new["windows_failed"]} window(s) not identified (fit failed)')
        if new['windows_dropped']:
            trouble.append(f'{new["windows_dropped"]} window(s) dropped (fits too slow)')
        if trouble:
            return WARN, '; '.join(trouble) + ' since the last report'
        return OK, (f'{now["windows_identified"]} windows identified, {now["moves_accepted"]} '
                    f'moves used')

    def close(self, *, timeout: float = 5.0) -> None:
        """Finish the queued fits (up to ``timeout``) and stop the workers."""
        self.fitter.close(timeout=timeout)


class WatchdogTask:
    """The watchdog's logic: judge each result, and say STALE when results stop coming.

    Args:
        monitor: The drift monitor judging each result.
        stale_timeout: Seconds without a result (or since start) after which the state is
            STALE.
        clock: Monotonic clock [s] (for tests).
    """

    def __init__(self, monitor: DriftMonitor, *, stale_timeout: float = 5.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if not (stale_timeout > 0 and stale_timeout < float('inf')):
            raise ConfigurationError(f'stale_timeout must be positive, got {stale_timeout}')
        self.monitor = monitor
        self.stale_timeout = float(stale_timeout)
        self._clock = clock
        self._start = clock()
        self._last_time: float | None = None
        self.last_verdict: DriftVerdict | None = None
        self.windows_judged = 0
        self._stale = False

    @property
    def age(self) -> float | None:
        """Seconds since the last result (None before the first)."""
        return None if self._last_time is None else self._clock() - self._last_time

    def on_result(self, result: ModalEstimate, *, window_index: int, status: int = STATUS_OK,
                  status_message: str = '') -> DriftVerdict:
        """Judge a result (its ``status`` not OK: MISMATCH); the state is fresh again."""
        verdict = self.monitor.assess(result, window_index=window_index, status=status,
                                      status_message=status_message)
        self.last_verdict = verdict
        self._last_time = self._clock()
        self.windows_judged += 1
        self._stale = False
        return verdict

    def poll(self) -> tuple[DriftVerdict, bool]:
        """The verdict to report now, and whether the state just turned STALE.

        Before the first result the state is STALE ('no identification result yet'); the
        transition is reported once ``stale_timeout`` has passed since start.
        """
        now = self._clock()
        since = self._start if self._last_time is None else self._last_time
        index = -1 if self.last_verdict is None else self.last_verdict.window_index
        timed_out = now - since > self.stale_timeout
        became = timed_out and not self._stale
        if timed_out:
            self._stale = True
        if self.last_verdict is None or timed_out:
            return self.monitor.stale(window_index=max(index, 0), age=self.age), became
        return self.last_verdict, False
