"""Online identification without ROS: the logic of the sysid node as plain task objects.

- :class:`WindowFitter` fits windows off the caller's thread: a bounded queue drained by
  worker threads, each fit optionally in a child process (no GIL contention with the
  thread that takes the input). A full queue drops its oldest window, said once.
- :class:`RateLimitedLog` says each line at most ``per_second`` times a second and sums up
  what it held back, so hostile input cannot flood the log.
- :class:`WatchdogTask` keeps the watchdog's state: the latest verdict of its
  :class:`~galvo_sysid.monitor.drift.DriftMonitor`, and STALE when no result came for a while.
- :class:`SysidTask` ties a :class:`~galvo_sysid.monitor.pairing.MoveWindower` and a
  :class:`WindowFitter` together: ``add(half)`` never blocks on a fit, rejections are
  reported grouped by reason, counters say what happened to every move, and
  :meth:`SysidTask.health` says how identification goes (windows that do not match the plant
  model are an error, said plainly: the scanner is not the one the model describes).

The sysid node (:mod:`galvo_sysid.nodes.sysid_node`) only converts messages and forwards
them; tests and benchmarks drive these objects directly.
"""

from __future__ import annotations

import collections
import concurrent.futures
import multiprocessing
import os
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from galvo_sysid.errors import ConfigurationError, GalvoSysidError, ModelMismatchError
from galvo_sysid.model.files import model_label
from galvo_sysid.monitor.drift import ERROR, OK, STATUS_OK, WARN
from galvo_sysid.monitor.pairing import MoveWindower, summarize_rejections

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping

    from galvo_sysid.ident.identify import IdentificationResult
    from galvo_sysid.model import PlantModel
    from galvo_sysid.monitor.drift import DriftMonitor, DriftVerdict, ModalEstimate
    from galvo_sysid.monitor.pairing import MoveHalf, Window

__all__ = [
    'FitOutcome',
    'RateLimitedLog',
    'SysidTask',
    'WatchdogTask',
    'WindowFitter',
    'fit_window',
    'mismatch_message',
]


def fit_window(window: Window, *, method: str = 'refined', model: PlantModel | None = None,
               options: Mapping[str, Any] | None = None) -> IdentificationResult:
    """Identify one window with :func:`~galvo_sysid.ident.identify.identify_window` (picklable).

    Args:
        window: The window.
        method: Identification method.
        model: The scanner's plant model (modes, bands, input dynamics, sample period;
            None: the paper's).
        options: Further options of ``identify_window`` (``na``, ``nb``, ...).

    Raises:
        ModelMismatchError: The window's data do not match the model.
        GalvoSysidError: Bad data or a failed fit.
    """
    from galvo_sysid.ident.identify import identify_window

    return identify_window(window.current, window.encoder, sample_period=window.sample_period,
                           method=method, target_angle=window.target_angle, model=model,
                           **dict(options or {}))


def mismatch_message(reason: str, *, model_path: str | None) -> str:
    """The one line that says data do not match a model file, and what to do.

    Example: ``the data do not match model scanner.yaml: no physical mode 2 in the band ...;
    run galvo-sysid commission``.
    """
    why = ' '.join(reason.split())
    return (f'the data do not match model {model_label(model_path)}: {why}; run galvo-sysid '
            f'commission')


def _child_init(parent: int) -> None:
    """Set up a fit process: leave Ctrl-C to the parent, and die with it.

    The parent shuts its children down on Ctrl-C; if it is killed outright (SIGKILL), a
    watcher thread notices the new parent pid and ends the child, so no orphan is left.
    """
    import os
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(0)

    threading.Thread(target=watch, name='parent-watch', daemon=True).start()


def _warm_up() -> bool:
    """Import the numerics and run one small fit in a child before the first window arrives.

    The first fit in a fresh process pays for imports and first-call set-up (~0.5 s);
    without this the first window's result would come that much later.
    """
    import numpy as np

    from galvo_sysid.ident.identify import identify_window
    from galvo_sysid.model import REFERENCE_MODEL, TAU, InputDynamics, simulate

    k = np.arange(256, dtype=float)
    pulse = np.where(k < 8, 0.0, np.where(k < 58, 1.0, np.where(k < 108, -1.0, 0.0)))
    u = np.tile(pulse, (4, 1)) + 1e-3 * np.random.default_rng(0).standard_normal((4, 256))
    y = simulate(REFERENCE_MODEL, InputDynamics(), u, sample_period=TAU)
    try:
        identify_window(u, y, sample_period=TAU)
    except Exception:  # the warm-up only primes caches; its result does not matter
        return False
    return True


@dataclass(frozen=True)
class FitOutcome:
    """What became of one window.

    Attributes:
        window: The window (its arrays included).
        result: The identification result, or None if the fit failed.
        error: Why the fit failed (None on success).
        queued: Seconds the window waited in the queue.
        fit_time: Seconds the fit took.
        mismatch: The fit failed because the data do not match the plant model
            (:class:`~galvo_sysid.errors.ModelMismatchError`; ``error`` says why).
    """

    window: Window
    result: IdentificationResult | None
    error: str | None
    queued: float
    fit_time: float
    mismatch: bool = False


_STOP = object()


class WindowFitter:
    """Fit windows on worker threads (optionally each fit in a child process).

    Args:
        fit: ``fit(window) -> IdentificationResult``; must be picklable (a module-level
            function or a :func:`functools.partial` of one) when ``processes > 0``.
        on_done: Called with each :class:`FitOutcome`, on a worker thread.
        queue_size: Windows waiting at most; beyond, the oldest is dropped.
        processes: 0 fits on the worker thread itself; N > 0 uses N worker threads, each
            handing its fit to a pool of N child processes (spawned, so no ROS state is
            inherited).
    """

    def __init__(self, fit: Callable[[Window], IdentificationResult],
                 on_done: Callable[[FitOutcome], None], *, queue_size: int = 8,
                 processes: int = 0) -> None:
        if int(queue_size) < 1:
            raise ConfigurationError(f'queue_size must be >= 1, got {queue_size}')
        if not 0 <= int(processes) <= 64:
            raise ConfigurationError(f'processes must be within [0, 64], got {processes}')
        self._fit = fit
        self._on_done = on_done
        self.queue_size = int(queue_size)
        self.processes = int(processes)
        self._queue: collections.deque[tuple[Window, float] | object] = collections.deque()
        self._cond = threading.Condition()
        self._pool: concurrent.futures.ProcessPoolExecutor | None = None
        if self.processes:
            self._pool = self._new_pool()
            for _ in range(self.processes):  # busy workers make the pool start the next one
                self._pool.submit(_warm_up)
        self.fitted = 0
        """Windows identified."""
        self.failed = 0
        """Windows whose fit failed (not counting mismatches)."""
        self.mismatched = 0
        """Windows whose data do not match the plant model."""
        self.dropped = 0
        """Windows dropped because the queue was full."""
        self._closed = False
        self._threads = [threading.Thread(target=self._run, name=f'galvo-fit-{i}', daemon=True)
                         for i in range(max(1, self.processes))]
        for t in self._threads:
            t.start()

    def _new_pool(self) -> concurrent.futures.ProcessPoolExecutor:
        return concurrent.futures.ProcessPoolExecutor(
            max_workers=self.processes, mp_context=multiprocessing.get_context('spawn'),
            initializer=_child_init, initargs=(os.getpid(),))

    def set_fit(self, fit: Callable[[Window], IdentificationResult]) -> None:
        """Use ``fit`` for the windows taken from the queue from now on."""
        self._fit = fit

    @property
    def waiting(self) -> int:
        """Windows in the queue."""
        with self._cond:
            return sum(1 for item in self._queue if item is not _STOP)

    def submit(self, window: Window) -> list[Window]:
        """Queue a window; return the windows dropped to make room (oldest first)."""
        dropped: list[Window] = []
        with self._cond:
            if self._closed:
                return [window]
            self._queue.append((window, time.monotonic()))
            while len(self._queue) > self.queue_size:
                old = self._queue.popleft()
                if isinstance(old, tuple):
                    dropped.append(old[0])
            self.dropped += len(dropped)
            self._cond.notify()
        return dropped

    def close(self, *, timeout: float = 5.0) -> None:
        """Stop the workers after the windows already queued (waits up to ``timeout``)."""
        with self._cond:
            if self._closed:
                return
            self._closed = True
            self._queue.extend([_STOP] * len(self._threads))
            self._cond.notify_all()
        end = time.monotonic() + timeout
        for t in self._threads:
            t.join(max(0.0, end - time.monotonic()))
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._queue:
                    self._cond.wait()
                item = self._queue.popleft()
            if not isinstance(item, tuple):
                return
            window, queued_at = item
            start = time.monotonic()
            result, error, mismatch = self._fit_one(window)
            end = time.monotonic()
            with self._cond:
                if result is not None:
                    self.fitted += 1
                elif mismatch:
                    self.mismatched += 1
                else:
                    self.failed += 1
            try:
                self._on_done(FitOutcome(window, result, error, start - queued_at, end - start,
                                         mismatch=mismatch))
            except Exception:  # a failing callback must not stop the worker
                import traceback

                traceback.print_exc()

    def _fit_one(self, window: Window
                 ) -> tuple[IdentificationResult | None, str | None, bool]:
        """(result, why it failed, whether the data do not match the model)."""
        try:
            if self._pool is None:
                return self._fit(window), None, False
            try:
                return self._pool.submit(self._fit, window).result(), None, False
            except concurrent.futures.process.BrokenProcessPool:
                with self._cond:  # a child died: start a new pool for the next windows
                    if not self._closed:
                        self._pool = self._new_pool()
                return None, 'identification process died', False
        except ModelMismatchError as err:
            return None, ' '.join(str(err).split()), True
        except GalvoSysidError as err:
            return None, str(err), False
        except Exception as err:  # keep the node alive, say what happened
            return None, f'unexpected {type(err).__name__}: {err}', False


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


class SysidTask:
    """The sysid node's logic: pair, window, fit off-thread, count and report.

    Args:
        fit: ``fit(window) -> IdentificationResult`` (see :class:`WindowFitter`).
        on_result: Called with each :class:`FitOutcome` (on a worker thread).
        warn: Where warnings go (rate limited by the task).
        windower: Keyword arguments of :class:`~galvo_sysid.monitor.pairing.MoveWindower`
            (``sample_period``: the model's, so moves of another scanner are set aside).
        queue_size: Windows waiting for a fit at most.
        processes: Child processes for the fits (0: fit on a worker thread).
        warnings_per_second: Most warning lines a second.
        model_path: The plant-model file the fits use ('' or None: the packaged paper
            model), for the messages.
    """

    def __init__(self, fit: Callable[[Window], IdentificationResult],
                 on_result: Callable[[FitOutcome], None], *, warn: Callable[[str], None],
                 windower: Mapping[str, Any] | None = None, queue_size: int = 8,
                 processes: int = 0, warnings_per_second: int = 20,
                 model_path: str | None = None) -> None:
        self.windower = MoveWindower(**dict(windower or {}))
        self._warn = RateLimitedLog(warn, per_second=warnings_per_second)
        self._on_result = on_result
        self.model_path = model_path or ''
        self.fitter = WindowFitter(fit, self._done, queue_size=queue_size, processes=processes)
        self.halves_received = 0
        self.windows_completed = 0
        self._last_input = time.monotonic()
        self._lock = threading.Lock()
        self.last_mismatch: str | None = None
        """Why the latest window that did not match the model did not (None: none so far)."""
        self.latest_mismatched = False
        """Whether the latest finished window did not match the model."""

    def add(self, half: MoveHalf) -> list[Window]:
        """Take one half; queue the windows it completed (returned) and report rejections."""
        self.halves_received += 1
        self._last_input = time.monotonic()
        resets = self.windower.resets
        windows = self.windower.add(half)
        if self.windower.resets != resets:
            self._warn('stamps jumped back (a bag replay looping?): buffers reset',
                       key='time jump')
        self._report()
        for w in windows:
            self.windows_completed += 1
            for old in self.fitter.submit(w):
                self._warn(f'window {old.index} ({old.target_angle:g} deg, {old.moves} moves) '
                           'dropped: identification queue full (fits slower than input)',
                           key='queue full')
        return windows

    def set_aside(self, text: str) -> None:
        """Report a message that could not even be converted (counted as one rejection)."""
        self.windower.moves_rejected += 1
        self._warn(f'message set aside: {text}', key='bad message')

    def tick(self) -> None:
        """Call periodically: expire unpaired halves when input has paused, flush the log.

        While no input arrives, the data clock is assumed to advance at least as fast as
        the wall clock, so a half whose partner never comes is reported within
        ``pair_timeout`` (wall) seconds.
        """
        idle = time.monotonic() - self._last_input
        w = self.windower
        if w.pending and idle > w.pair_timeout:
            w.expire(w.newest_stamp + idle)
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

    def _done(self, outcome: FitOutcome) -> None:
        w = outcome.window
        with self._lock:
            if outcome.result is not None:
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
        self._on_result(outcome)

    def stats(self) -> dict[str, int]:
        """Counters: halves received, moves accepted/rejected (and of those, halves of
        another sample period than the model's), windows identified / failed / not matching
        the model / dropped, resets, queue."""  # noqa: D205, D209
        w = self.windower
        f = self.fitter
        return {'halves_received': self.halves_received, 'moves_accepted': w.moves_accepted,
                'moves_rejected': w.moves_rejected,
                'halves_period_mismatched': w.period_mismatches, 'pending_halves': w.pending,
                'open_windows': w.open_windows, 'windows_completed': self.windows_completed,
                'windows_identified': f.fitted, 'windows_failed': f.failed,
                'windows_mismatched': f.mismatched, 'windows_dropped': f.dropped,
                'windows_waiting': f.waiting, 'resets': w.resets}

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
