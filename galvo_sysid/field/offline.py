"""Offline identification of a bag: what ``galvo-sysid identify`` runs (no ROS graph).

The moves of the bag go through exactly the objects the live nodes use, in the same order:
each ``MoveSamples`` message becomes a :class:`~galvo_sysid.monitor.moves.MoveHalf`
(:mod:`galvo_sysid.interfaces.messages`), :class:`~galvo_sysid.monitor.pairing.MoveWindower`
pairs them and cuts windows of ``window_size`` moves per signed target angle,
:func:`~galvo_sysid.ident.identify.identify_window` fits each window and
:class:`~galvo_sysid.monitor.drift.DriftMonitor` judges it. At the end of the bag, every
unfinished window holding at least ``min_partial`` moves (default: half a window) is
identified too and marked partial. Moves that cannot be used are listed with the reason; the
rest is used.

The pooled estimate (the bag's plant, from all windows; the nodes have no such thing) is, for
the refined method, :func:`~galvo_sysid.ident.identify.identify_joint`: one fit of the modal model
to the identified windows at once, started from
:func:`~galvo_sysid.ident.pool.pool_results` (the inverse-variance combination of the windows'
results), several times sharper on the weakly excited third mode. It does not repeat what the
windows' fits did: it takes the moves their screening kept, and weighs each window with the
noise model its own fit estimated; windows of one signed angle and record length are one
window there (:func:`~galvo_sysid.field.pooling.joint_records`). If the joint fit fails,
the inverse-variance combination is reported instead, with the reason. For the paper
methods the pooled estimate is the inverse-variance combination.

With the refined method each window's fit starts from the result of the window two before it
(:data:`WARM_CHAINS` chains of windows, :mod:`galvo_sysid.ident.warm`: its estimate and
noise model; the first window of each chain from the model file's modes,
:func:`~galvo_sysid.ident.warm.reference_start`; afresh after a window that was not
identified, and where the start gives a fit whose cost the noise does not allow), as the sysid
node's ``warm_start`` does with the previous window of the angle: the moves usually alternate
between the signs, so this is the previous window of the same sign, another angle of the
same plant. The fit then leaves out its ARX start, band scans and first stage (about 40 % of
its time), with the same accuracy (the fits of family scanners calibrated alike either way).
``warm_start=False`` (the sysid parameter, or ``identify --no-warm-start``) fits every
window afresh.

One plant model (a model file, default the paper's scanner) is used throughout: the windower
sets aside moves of another sample period, every window and the joint fit are identified with
it, and (unless another monitor is given) the drift is judged against it. Windows whose data
do not match it (:class:`~galvo_sysid.errors.ModelMismatchError`) are listed with the reason,
and the result says plainly that the data do not match the model
(:attr:`~galvo_sysid.field.results.BagIdentification.model_mismatch`).
"""

from __future__ import annotations

import collections
import functools
from collections.abc import Mapping
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from galvo_sysid.errors import ConfigurationError, GalvoSysidError, one_line
from galvo_sysid.field.bags import BagReader
from galvo_sysid.field.jobs import fork_map, job_limit
from galvo_sysid.field.pooling import JOINT_WINDOWS, POOLINGS, _keep, _pooled
from galvo_sysid.field.results import (
    BagIdentification,
    MismatchedWindow,
    WindowResult,
    rejection_to_dict,
)
from galvo_sysid.ident.methods import METHODS
from galvo_sysid.model import model_label
from galvo_sysid.monitor.parameters import WINDOWER_PARAMETERS, defaults

if TYPE_CHECKING:
    import os
    from collections.abc import Callable

    import numpy as np
    from numpy.typing import NDArray

    from galvo_sysid.ident.commission import FrequencyResponse
    from galvo_sysid.model import PlantModel
    from galvo_sysid.monitor.drift import DriftMonitor
    from galvo_sysid.monitor.moves import Window
    from galvo_sysid.monitor.scheduler import FitOutcome

__all__ = ['WARM_CHAINS', 'identify_bag']

WARM_CHAINS = 2
"""Chains of windows whose fits start from the previous window of the chain (window i from
window i - 2): two fits at a time, whatever the number of processes, so the results do not
depend on it."""

_SYSID = defaults('sysid')
"""The sysid node's parameter defaults: :func:`identify_bag`'s defaults (one source)."""


def identify_bag(bag: str | os.PathLike[str], *, method: str = _SYSID['method'],
                 window_size: int = _SYSID['window_size'], min_partial: int | None = None,
                 namespace: str | None = None, monitor: DriftMonitor | None = None,
                 na: int = _SYSID['na'], nb: int = _SYSID['nb'],
                 windower: Mapping[str, Any] | None = None,
                 jobs: int = 1, pooling: str | None = None,
                 joint_windows: int = JOINT_WINDOWS, model: PlantModel | None = None,
                 model_path: str = '',
                 progress: Callable[[int, int], None] | None = None,
                 response_windows: int = 0,
                 warm_start: bool = _SYSID['warm_start'],
                 measured_lag: float | None = None) -> BagIdentification:
    """Identify every window of moves in a bag (see the module docs for the path taken).

    Args:
        bag: The bag (directory, ``.mcap`` or ``.db3``).
        method: One of :data:`~galvo_sysid.ident.methods.METHODS`; default: the sysid
            node's parameter ``method`` (``'refined'``).
        window_size: Moves per window; default: the sysid node's ``window_size`` (100).
        min_partial: Smallest unfinished window identified at the end; default half a window.
        namespace: Scanner namespace when the bag holds several.
        monitor: Drift monitor (default: reference = the model, default tolerances).
        na: ARX order of A[q] (paper pipeline, also the refined fit's start); default: the
            sysid node's parameter ``na``.
        nb: ARX order of B[q]; default: the sysid node's ``nb``.
        windower: Further :class:`~galvo_sysid.monitor.pairing.MoveWindower` settings, as the
            sysid node's parameters of
            :data:`~galvo_sysid.monitor.parameters.WINDOWER_PARAMETERS` (``window_size`` here
            is overridden by the argument).
        jobs: Windows fitted in parallel by this many forked processes (1: on one thread of
            this process; at most :func:`~galvo_sysid.field.jobs.job_limit`), by
            :class:`~galvo_sysid.monitor.scheduler.WindowScheduler`, the sysid node's. The
            results do not depend on it: each window's fit is the same function call, and
            the outcomes come back in window order (the drift monitor judges the windows in
            order, the lists keep their order). The joint fit's large scans are then shared
            between as many processes (:func:`~galvo_sysid.field.jobs.fork_map`: the same fit).
        pooling: ``'joint'`` (default for ``'refined'``) or ``'inverse-variance'`` (default,
            and the only choice, for the paper methods); see the module docs.
        joint_windows: Windows held for the joint fit at most (memory): beyond, the oldest
            window of the target angle holding the most is let go, so every angle stays in.
        model: The scanner's plant model (default: the paper's): the sample period the
            moves must have, what every window and the joint fit identify.
        model_path: Its file, for the messages ('': the packaged paper model).
        progress: Called as ``progress(messages_done, messages_total)`` while reading.
        response_windows: Identified windows (the first ones with the first one's record
            length) whose moves give the measured frequency response of the result (0: none;
            for the plot).
        warm_start: Start each refined fit from the window two before (see the module docs);
            default: the sysid node's ``warm_start``.
        measured_lag: The bag's current is the coil current measured when the encoder is
            read, behind an amplifier lag of this time constant [s]: each window's current
            is made into the held current that drives it, a sample shorter
            (:func:`galvo_sysid.ident.measured.held_current`), before anything else; None:
            the current is the command.

    Raises:
        BagError: Missing, corrupt or truncated bag, no galvo topics, wrong topic type.
        ConfigurationError: Unknown method or bad window settings.
    """
    from galvo_sysid.ident.measured import check_lag
    from galvo_sysid.ident.warm import WarmStart, reference_start
    from galvo_sysid.model import PAPER_MODEL
    from galvo_sysid.monitor.drift import DriftMonitor
    from galvo_sysid.monitor.pairing import MoveWindower
    from galvo_sysid.monitor.scheduler import WindowScheduler, fit_window

    plant = PAPER_MODEL if model is None else model
    if measured_lag is not None:
        measured_lag = check_lag(measured_lag, plant.sample_period)

    if method not in METHODS:
        msg = f'unknown method {method!r}; choose one of {", ".join(METHODS)}'
        raise ConfigurationError(msg)
    min_moves = window_size // 2 if min_partial is None else int(min_partial)
    if min_moves < 2:  # an average needs two moves
        msg = f'min_partial must be >= 2, got {min_moves}' if min_partial is not None else (
            f'window_size must be >= 4 (half a window, the smallest unfinished one identified, '
            f'needs 2 moves), got {window_size}')
        raise ConfigurationError(msg)
    if int(jobs) < 1:
        msg = f'jobs must be >= 1, got {jobs}'
        raise ConfigurationError(msg)
    jobs = min(int(jobs), job_limit()[0])  # more processes than CPUs or memory only cost
    pooling = ('joint' if method == 'refined' else 'inverse-variance') if pooling is None \
        else pooling
    if pooling not in POOLINGS or (pooling == 'joint' and method != 'refined'):
        msg = (f'pooling {pooling!r} is not possible with method {method!r}; choose '
               f'{"one of " + ", ".join(POOLINGS) if method == "refined" else "inverse-variance"}')
        raise ConfigurationError(msg)
    if int(joint_windows) < 1:
        msg = f'joint_windows must be >= 1, got {joint_windows}'
        raise ConfigurationError(msg)
    kept: list[Window] = []  # the joint fit's windows
    settings = {k: v for k, v in dict(windower or {}).items() if k in WINDOWER_PARAMETERS}
    settings['window_size'] = window_size
    settings['sample_period'] = plant.sample_period
    pairer = MoveWindower(**settings)
    judge = DriftMonitor(reference=plant.modal, reference_name=model_label(model_path)) \
        if monitor is None else monitor
    rejected: list[dict[str, Any]] = []
    mismatched: list[MismatchedWindow] = []
    # the sysid node's fit function (nodes/sysid_node.py: SysidNode._fit_function), with the
    # Cramer-Rao bound, which the node leaves out (its messages do not carry it)
    fit = functools.partial(fit_window, method=method, model=plant,
                            options={'na': int(na), 'nb': int(nb)})
    windows: list[WindowResult] = []
    spectra: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []
    # where each window's set-aside moves go in `rejected`: where they went when each window
    # was fitted as soon as it completed (so the list does not depend on the timing)
    marks: dict[int, int] = {}
    late: list[tuple[int, list[dict[str, Any]]]] = []
    chained = bool(warm_start) and method == 'refined'
    held: collections.deque[Window] = collections.deque()  # waiting for their chain
    busy: set[int] = set()  # chains with a window being fitted
    # chain -> the start of its next window: at first the model's; none after a failure
    starts: dict[int, WarmStart] = dict.fromkeys(range(WARM_CHAINS), reference_start(plant))

    def handle(outcome: FitOutcome) -> None:
        """Judge one window's outcome (called in window order)."""
        window = outcome.window
        err = outcome.exception
        if chained:
            chain = window.index % WARM_CHAINS
            busy.discard(chain)
            start = None if outcome.result is None else WarmStart.from_result(outcome.result)
            if start is None:  # the next window of the chain starts afresh
                starts.pop(chain, None)
            else:
                starts[chain] = start
        if outcome.result is None:
            if outcome.mismatch:  # said plainly: the scanner is another one
                why = one_line(err) if err is not None else outcome.error or ''
                mismatched.append(MismatchedWindow(window.index, window.target_angle,
                                                   window.moves, why))
                reason = f'window {window.index} does not match the model: {why}'
            else:  # like the sysid node: a failed fit loses its window only
                text = _failure(err, outcome.error)
                reason = f'window {window.index} not identified: {text}'
            late.append((marks.pop(window.index), [
                {'move_id': mid, 'target_angle': window.target_angle, 'stamp': None,
                 'reason': reason} for mid in window.move_ids]))
            return
        screened = outcome.result.set_aside
        late.append((marks.pop(window.index), [
            {'move_id': window.move_ids[i], 'target_angle': window.target_angle, 'stamp': None,
             'reason': f'window {window.index}: move set aside by the screening: {why}'}
            for i, why in screened]))
        verdict = judge.assess(outcome.result, window_index=window.index)
        windows.append(WindowResult(window.index, window.target_angle, window.partial,
                                    window.first_stamp, window.last_stamp, outcome.result,
                                    verdict))
        if pooling == 'joint':
            _keep(kept, window, limit=int(joint_windows),
                  set_aside=[i for i, _ in outcome.result.set_aside])
        if len(spectra) < response_windows and window.moves >= 3 and (
                not spectra or spectra[0][0].shape[1] == window.current.shape[1]):
            spectra.append((window.current, window.encoder))

    # the children are forked: they inherit the imported numerics (no ROS in this process;
    # the scheduler imports the fits' before it starts them)
    with WindowScheduler(fit, processes=int(jobs) if int(jobs) > 1 else 0,
                         queue_size=int(jobs), when_full='wait', ordered=True,
                         start_method='fork', warm_up=False) as scheduler:

        def submit(window: Window) -> None:
            if measured_lag is not None:
                window = window.held(measured_lag)
            marks[window.index] = len(rejected)
            if chained:  # in window order, each once the window before it in its chain is done
                held.append(window)
                pump(limit=WARM_CHAINS)
            else:
                scheduler.submit(window)
            for outcome in scheduler.take():
                handle(outcome)

        def pump(*, limit: int) -> None:
            """Hand the held windows whose chain is free to the fits, in window order; wait
            for a chain while more than ``limit`` windows are held (the reader goes on
            meanwhile)."""  # noqa: D205, D209
            while held:
                for outcome in scheduler.take():
                    handle(outcome)
                chain = held[0].index % WARM_CHAINS
                if chain not in busy:
                    busy.add(chain)
                    scheduler.submit(replace(held.popleft(), warm_start=starts.get(chain)))
                elif len(held) <= limit:
                    return
                else:
                    for outcome in scheduler.take(block=True):
                        handle(outcome)

        with BagReader(bag) as reader:
            current, encoder = reader.galvo_topics(namespace=namespace)
            info = reader.info
            total = sum(t.count for t in info.topics if t.topic in {current, encoder})
            done = 0  # messages read (what the report counts, not what the bag claims)
            for done, (_, completed, unread) in enumerate(
                    reader.feed(pairer, namespace=namespace), start=1):
                if unread is not None:
                    rejected.append(unread.to_dict())
                for window in completed:
                    submit(window)
                rejected.extend(rejection_to_dict(r) for r in pairer.pop_rejections())
                if progress is not None:
                    progress(done, total)
        for window in pairer.flush(min_moves=min_moves):
            submit(window)
        pump(limit=0)
        rejected.extend(rejection_to_dict(r) for r in pairer.pop_rejections())
        scheduler.close(timeout=None)
        for outcome in scheduler.take():
            handle(outcome)
    rejected = _insert(rejected, late)
    # the window fits' processes are gone: the joint fit's large scans go to as many
    # (forked now, with the data of the joint fit in place)
    pooled, used, note, n_pooled = _pooled(
        windows, kept, pooling=pooling, model=plant,
        map_windows=functools.partial(fork_map, processes=jobs) if jobs > 1 else None)
    why = mismatched[0].reason if mismatched else pairer.period_mismatch
    return BagIdentification(info=info, method=method, window_size=window_size,
                             windows=tuple(windows), pooled=pooled, rejected=tuple(rejected),
                             moves=done / 2, pooling=used if windows else '',
                             pooled_windows=n_pooled,
                             pooling_note=note, model=model_path, mismatched=tuple(mismatched),
                             model_mismatch=why, reference=judge.reference,
                             reference_name=judge.reference_name,
                             sample_period=plant.sample_period, dynamics=plant.dynamics,
                             measured_lag=measured_lag,
                             warn_fraction=judge.warn_fraction,
                             response=_response(spectra, plant.sample_period))


def _response(spectra: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
              sample_period: float) -> FrequencyResponse | None:
    """The measured frequency response of the kept windows (None without any)."""
    if not spectra:
        return None
    from galvo_sysid.ident.commission import frequency_response

    try:
        return frequency_response(spectra, sample_period=sample_period)
    except GalvoSysidError:
        return None


def _failure(err: BaseException | None, error: str | None) -> str:
    """Why a window's fit failed, one line (the exception's type when unexpected)."""
    if err is None:
        return error or 'unknown reason'
    if isinstance(err, GalvoSysidError):
        return one_line(err)
    return f'unexpected {type(err).__name__}: {one_line(err)}'


def _insert(items: list[dict[str, Any]], late: list[tuple[int, list[dict[str, Any]]]],
            ) -> list[dict[str, Any]]:
    """``items`` with each ``(position, more)`` of ``late`` (positions ascending) inserted."""
    out: list[dict[str, Any]] = []
    start = 0
    for position, more in late:
        out.extend(items[start:position])
        out.extend(more)
        start = position
    out.extend(items[start:])
    return out
