"""The one window scheduler: windows fitted off the caller's thread, in child processes.

:class:`WindowScheduler` takes windows into a bounded queue; worker threads take them out
and fit each, on the thread itself or in a pool of child processes started once, when the
scheduler is made. What became of each window (:class:`FitOutcome`) is handed to a callback
or collected for the caller to :meth:`~WindowScheduler.take`, in the order the windows came
when asked (``ordered``). Both users share it:

- the sysid node (:class:`~galvo_sysid.monitor.tasks.SysidTask`): children forked from a
  fork server (a fresh process without ROS that has imported the numerics once, so the
  children neither inherit ROS state nor import the numerics each) warmed up before the
  first window, a full queue drops its oldest window
  (the input must never wait), outcomes to a callback as they come;
- ``galvo-sysid identify`` (:func:`galvo_sysid.field.offline.identify_bag`): forked children
  (they inherit the imported numerics), a full queue makes the reader wait, outcomes in
  window order (the drift monitor judges the windows in order), so the numbers do not depend
  on the number of processes.

:func:`fit_window` is the fit both use. A fit process gets each window's records through
shared memory (:mod:`~galvo_sysid.monitor.handover`), not pickled through the pool's pipe.
"""

from __future__ import annotations

import collections
import concurrent.futures
import functools
import importlib
import math
import multiprocessing
import os
import threading
import time
from dataclasses import dataclass, field
from multiprocessing import resource_tracker
from typing import TYPE_CHECKING, Any, Literal

from galvo_sysid.errors import ConfigurationError, GalvoSysidError, ModelMismatchError, one_line
from galvo_sysid.monitor.handover import Ticket, WindowBuffer, take_window

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping
    from types import TracebackType

    from galvo_sysid.ident.result import IdentificationResult
    from galvo_sysid.model import PlantModel
    from galvo_sysid.monitor.moves import Window

__all__ = ['FitOutcome', 'WindowScheduler', 'fit_window', 'node_fit']


def fit_window(window: Window, *, method: str = 'refined', model: PlantModel | None = None,
               options: Mapping[str, Any] | None = None) -> IdentificationResult:
    """Identify one window with :func:`~galvo_sysid.ident.identify.identify_window` (picklable).

    Args:
        window: The window (its refined fit started from its ``warm_start`` if set, and
            cut short past its ``deadline`` if set).
        method: Identification method.
        model: The scanner's plant model (modes, bands, input dynamics, sample period;
            None: the paper's).
        options: Further options of ``identify_window`` (``na``, ``nb``, ...).

    Raises:
        ModelMismatchError: The window's data do not match the model.
        GalvoSysidError: Bad data or a failed fit.
    """
    from galvo_sysid.ident.identify import identify_window

    opts = dict(options or {})
    if window.deadline is not None and method == 'refined':
        opts['deadline'] = window.deadline
    return identify_window(window.current, window.encoder, sample_period=window.sample_period,
                           method=method, target_angle=window.target_angle, model=model,
                           warm_start=window.warm_start, **opts)


def node_fit(*, method: str, model: PlantModel | None, na: int,
             nb: int) -> functools.partial[IdentificationResult]:
    """The sysid node's fit of a window: :func:`fit_window` with its parameters.

    The refined fit leaves out the Cramer-Rao bound (``bound=False``): the node's
    ``ModalParameters`` do not carry it (where the fit could not weigh a window by its
    stationary noise model, the bound would need one of its own: a sixth of a fit).
    ``galvo-sysid identify`` fits with it (its JSON reports ``crlb_std``); everything else is
    the same.
    """
    options: dict[str, Any] = {'na': int(na), 'nb': int(nb)}
    if method == 'refined':
        options['bound'] = False
    return functools.partial(fit_window, method=method, model=model, options=options)


def _timed(fit: Callable[[Window], IdentificationResult],
           window: Window) -> tuple[IdentificationResult, float]:
    """``fit(window)`` and the CPU seconds it took on its thread (a fit process's only one)."""
    start = time.thread_time()
    result = fit(window)
    return result, time.thread_time() - start


def _timed_ticket(fit: Callable[[Window], IdentificationResult],
                  ticket: Ticket) -> tuple[IdentificationResult, float]:
    """In a fit process: :func:`_timed` of the window handed over in shared memory."""
    return _timed(fit, take_window(ticket))


def _child_init(parent: int, served: bool) -> None:
    """Set up a fit process: leave Ctrl-C to the parent, die with it, reuse freed memory.

    The parent shuts its children down on Ctrl-C; if it is killed outright (SIGKILL), a
    watcher thread notices and ends the child, so no orphan is left. A spawned or forked
    child (``served`` false) sees its parent's pid change (also when it starts after the
    parent died); a child of the fork server sees the server go (it ends when the parent's
    end of its pipe closes, but the children hold that pipe too) or the parent die (its
    pid gone or a zombie: :func:`_dead`).
    """
    import signal

    from galvo_sysid import keep_freed_memory

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    keep_freed_memory()  # a new child does not inherit the parent's setting
    server = os.getppid() if served else parent

    def alive() -> bool:
        if os.getppid() != server:
            return False
        return not (served and _dead(parent))

    def watch() -> None:
        while alive():
            time.sleep(0.5)
        os._exit(0)

    threading.Thread(target=watch, name='parent-watch', daemon=True).start()


def _dead(pid: int) -> bool:
    """Whether process ``pid`` has ended.

    Gone, or a zombie its parent has not reaped yet (``/proc/PID/stat``; where there is no
    ``/proc``, only gone).
    """
    try:
        with open(f'/proc/{pid}/stat', 'rb') as f:
            stat = f.read()
    except FileNotFoundError:
        return True
    except OSError:  # no /proc here
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        except PermissionError:  # there, under another user
            return False
        return False
    return stat[stat.rfind(b')') + 2:][:1] in (b'Z', b'X')  # the state after "(comm)"


_PRELOAD = ['galvo_sysid.monitor.scheduler', 'galvo_sysid.ident.identify']
"""What the fork server imports once for all its children (the fits' numerics)."""


def _started() -> bool:
    """Nothing: makes the pool start its children now (a forked pool starts them all)."""
    return True


def _warm_up() -> bool:
    """Import the numerics and run one small fit in a child before the first window arrives.

    The first fit in a fresh process pays for imports and first-call set-up (~0.5 s; in a
    child of the fork server, the pages it first writes); without this the first window's
    result would come that much later. The fit is of the paper's scanner, noise added, with
    its own model, and succeeds (True); until 2026-11-28 it was fitted with a model lacking
    the data's delay and ended in a mismatch before its last steps.
    """
    import numpy as np

    from galvo_sysid.ident.identify import identify_window
    from galvo_sysid.model import PAPER_MODEL, TAU, simulate

    rng = np.random.default_rng(0)
    k = np.arange(256, dtype=float)
    pulse = np.where(k < 8, 0.0, np.where(k < 58, 1.0, np.where(k < 108, -1.0, 0.0)))
    u = np.tile(pulse, (4, 1)) + 1e-3 * rng.standard_normal((4, 256))
    y = (simulate(PAPER_MODEL.modal, PAPER_MODEL.dynamics, u, sample_period=TAU)
         + 1e-7 * rng.standard_normal((4, 256)))
    try:
        identify_window(u, y, sample_period=TAU, model=PAPER_MODEL)
    except Exception:  # the warm-up only primes caches (test_scheduler checks it succeeds)
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
        exception: The exception the fit raised (None on success), for callers that word
            the failure their own way.
        fit_cpu: CPU seconds the fit itself took, where it ran (nan if it failed);
            ``fit_time`` less this is the hand-over to and from a fit process and the time
            the fit waited for a CPU.
    """

    window: Window
    result: IdentificationResult | None
    error: str | None
    queued: float
    fit_time: float
    mismatch: bool = False
    exception: BaseException | None = field(default=None, compare=False, repr=False)
    fit_cpu: float = field(default=math.nan, compare=False)


_STOP = object()


class WindowScheduler:
    """Fit windows on worker threads, each fit optionally in a child process.

    Args:
        fit: ``fit(window) -> IdentificationResult``; must be picklable (a module-level
            function or a :func:`functools.partial` of one) when ``processes > 0``.
        on_done: Called with each :class:`FitOutcome`, on a worker thread, one at a time;
            None: outcomes are kept for :meth:`take`.
        queue_size: Windows waiting at most.
        processes: 0 fits on one worker thread; N > 0 uses N worker threads, each handing
            its fit to one pool of N child processes, started here.
        when_full: What :meth:`submit` does with a full queue: ``'drop'`` the oldest window
            waiting (returned), or ``'wait'`` for room.
        ordered: Hand the outcomes on in the order the windows were submitted (a dropped
            window is skipped); else as the fits finish.
        start_method: How the children start: ``'forkserver'`` (forked from a fresh server
            process that imported the numerics once: no ROS state inherited, no import per
            child), ``'spawn'`` (a fresh interpreter each) or ``'fork'`` (they inherit the
            caller's imported modules; only without ROS).
        warm_up: Run one small fit in each child at start (the first window's fit then pays
            no start-up cost).

    Raises:
        ConfigurationError: An out-of-range setting.
    """

    def __init__(self, fit: Callable[[Window], IdentificationResult],
                 on_done: Callable[[FitOutcome], None] | None = None, *, queue_size: int = 8,
                 processes: int = 0, when_full: Literal['drop', 'wait'] = 'drop',
                 ordered: bool = False,
                 start_method: Literal['forkserver', 'spawn', 'fork'] = 'forkserver',
                 warm_up: bool = True) -> None:
        if int(queue_size) < 1:
            raise ConfigurationError(f'queue_size must be >= 1, got {queue_size}')
        if not 0 <= int(processes) <= 1024:
            raise ConfigurationError(f'processes must be within [0, 1024], got {processes}')
        if when_full not in ('drop', 'wait'):
            raise ConfigurationError(f"when_full must be 'drop' or 'wait', got {when_full!r}")
        if start_method not in ('forkserver', 'spawn', 'fork'):
            raise ConfigurationError(f"start_method must be 'forkserver', 'spawn' or 'fork', "
                                     f'got {start_method!r}')
        self._fit = fit
        self._on_done = on_done
        self.queue_size = int(queue_size)
        self.processes = int(processes)
        self.when_full = when_full
        self.ordered = bool(ordered)
        self._start_method = start_method
        self._queue: collections.deque[tuple[int, Window, float] | object] = \
            collections.deque()
        self._cond = threading.Condition()
        self._deliver = threading.Lock()
        self._next_seq = 0  # sequence number of the next window submitted
        self._due = 0  # sequence number of the next outcome to hand on (ordered)
        # finished outcomes not yet handed on, by sequence number (None: dropped; a dropped
        # window was queued, so a window after it is still to finish and hands it on)
        self._finished: dict[int, FitOutcome | None] = {}
        self._ready: collections.deque[FitOutcome] = collections.deque()
        self._outstanding = 0  # windows queued or fitting whose outcome is not handed on yet
        self.fitted = 0
        """Windows identified."""
        self.failed = 0
        """Windows whose fit failed (not counting mismatches)."""
        self.mismatched = 0
        """Windows whose data do not match the plant model."""
        self.dropped = 0
        """Windows dropped because the queue was full."""
        self._closed = False
        self._pool: concurrent.futures.ProcessPoolExecutor | None = None
        # the fits' numerics, and the classes the children's outcomes are unpickled into,
        # imported now rather than at the first window (in the sysid node under 1,000 moves/s
        # that import made its first windows 0.8 s late instead of 0.2)
        importlib.import_module('galvo_sysid.ident.identify')
        if self.processes:  # children first: a forked pool starts them all at its first task
            # the tracker of the windows' shared memory (handover), shared by the children:
            # started before they are (a forked child would otherwise start its own)
            resource_tracker.ensure_running()
            self._pool = self._new_pool()
            for _ in range(self.processes):  # busy children make the pool start the next one
                self._pool.submit(_warm_up if warm_up else _started)
        self._threads = [threading.Thread(target=self._run, name=f'galvo-fit-{i}', daemon=True)
                         for i in range(max(1, self.processes))]
        for t in self._threads:
            t.start()

    def _new_pool(self) -> concurrent.futures.ProcessPoolExecutor:
        context = multiprocessing.get_context(self._start_method)
        if self._start_method == 'forkserver':  # before the server starts (once a process)
            context.set_forkserver_preload(_PRELOAD)
        return concurrent.futures.ProcessPoolExecutor(
            max_workers=self.processes, mp_context=context,
            initializer=_child_init,
            initargs=(os.getpid(), self._start_method == 'forkserver'))

    def __enter__(self) -> WindowScheduler:
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 traceback: TracebackType | None) -> None:
        """Close: finish the queued windows, or on an exception drop them."""
        self.close(timeout=None, cancel=kind is not None)

    def set_fit(self, fit: Callable[[Window], IdentificationResult]) -> None:
        """Use ``fit`` for the windows taken from the queue from now on."""
        self._fit = fit

    @property
    def waiting(self) -> int:
        """Windows in the queue."""
        with self._cond:
            return sum(1 for item in self._queue if item is not _STOP)

    def submit(self, window: Window) -> list[Window]:
        """Queue a window; return the windows dropped to make room (oldest first).

        With ``when_full='wait'`` nothing is dropped: a full queue makes this wait for room.
        A closed scheduler takes nothing: ``[window]``.
        """
        dropped: list[Window] = []
        with self._cond:
            if self.when_full == 'wait':
                while len(self._queue) >= self.queue_size and not self._closed:
                    self._cond.wait()
            if self._closed:
                return [window]
            self._queue.append((self._next_seq, window, time.monotonic()))
            self._next_seq += 1
            self._outstanding += 1
            while len(self._queue) > self.queue_size:
                old = self._queue.popleft()
                if isinstance(old, tuple):
                    dropped.append(old[1])
                    self._finished[old[0]] = None
            self.dropped += len(dropped)
            self._outstanding -= len(dropped)
            self._cond.notify_all()
        return dropped

    def take(self, *, block: bool = False) -> list[FitOutcome]:
        """The outcomes finished since the last call (without ``on_done``), in order if
        ``ordered``; with ``block``, wait until there is one, unless no window is queued or
        being fitted."""  # noqa: D205, D209
        with self._cond:
            while block and not self._ready and self._outstanding > 0:
                self._cond.wait()
            out = list(self._ready)
            self._ready.clear()
        return out

    def close(self, *, timeout: float | None = 5.0, cancel: bool = False) -> None:
        """Stop the workers after the windows already queued, and the children.

        Args:
            timeout: Seconds to wait for the workers at most (None: until done).
            cancel: Drop the windows still queued instead of fitting them.
        """
        with self._cond:
            if self._closed:
                return
            self._closed = True
            if cancel:
                self._outstanding -= sum(1 for item in self._queue if isinstance(item, tuple))
                self._queue.clear()
            self._queue.extend([_STOP] * len(self._threads))
            self._cond.notify_all()
        end = None if timeout is None else time.monotonic() + timeout
        for t in self._threads:
            t.join(None if end is None else max(0.0, end - time.monotonic()))
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)

    def _run(self) -> None:
        buffer = WindowBuffer()  # this thread's windows to the fit processes
        try:
            self._serve(buffer)
        finally:
            buffer.close()

    def _serve(self, buffer: WindowBuffer) -> None:
        while True:
            with self._cond:
                while not self._queue:
                    self._cond.wait()
                item = self._queue.popleft()
                self._cond.notify_all()  # room for a waiting submit
            if not isinstance(item, tuple):
                return
            seq, window, queued_at = item
            start = time.monotonic()
            result, error, mismatch, exception, cpu = self._fit_one(window, buffer)
            end = time.monotonic()
            outcome = FitOutcome(window, result, error, start - queued_at, end - start,
                                 mismatch=mismatch, exception=exception, fit_cpu=cpu)
            with self._cond:
                if result is not None:
                    self.fitted += 1
                elif mismatch:
                    self.mismatched += 1
                else:
                    self.failed += 1
                self._finished[seq] = outcome
            self._hand_on()

    def _hand_on(self) -> None:
        """Hand on the outcomes due (in order if ``ordered``), one caller at a time."""
        with self._deliver:  # taken before collecting: batches go out in the order collected
            with self._cond:
                due: list[FitOutcome] = []
                if self.ordered:
                    while self._due in self._finished:
                        outcome = self._finished.pop(self._due)
                        self._due += 1
                        if outcome is not None:
                            due.append(outcome)
                else:
                    due = [o for o in self._finished.values() if o is not None]
                    self._finished.clear()
                self._outstanding -= len(due)
                if self._on_done is None:
                    self._ready.extend(due)
                    self._cond.notify_all()  # a blocking take
                    return
            for outcome in due:
                try:
                    self._on_done(outcome)
                except Exception:  # a failing callback must not stop the worker
                    import traceback

                    traceback.print_exc()

    def _fit_one(self, window: Window, buffer: WindowBuffer) -> tuple[
            IdentificationResult | None, str | None, bool, BaseException | None, float]:
        """(result, why it failed, whether the data do not match the model, the exception,
        the fit's CPU seconds). A fit process gets the window's records through ``buffer``
        (:mod:`~galvo_sysid.monitor.handover`), or whole where that cannot be had."""  # noqa: D205, D209
        nan = math.nan
        try:
            if self._pool is None:
                return self._ok(*_timed(self._fit, window))
            try:
                ticket = buffer.put(window)
                future = (self._pool.submit(_timed, self._fit, window) if ticket is None
                          else self._pool.submit(_timed_ticket, self._fit, ticket))
                return self._ok(*future.result())
            except concurrent.futures.process.BrokenProcessPool as err:
                with self._cond:  # a child died: start a new pool for the next windows
                    if not self._closed:
                        self._pool = self._new_pool()
                return None, 'identification process died', False, err, nan
        except ModelMismatchError as err:
            return None, one_line(err), True, err, nan
        except GalvoSysidError as err:
            return None, str(err), False, err, nan
        except Exception as err:  # keep the node alive, say what happened
            return None, f'unexpected {type(err).__name__}: {err}', False, err, nan

    @staticmethod
    def _ok(result: IdentificationResult, cpu: float) -> tuple[
            IdentificationResult, None, bool, None, float]:
        return result, None, False, None, cpu
