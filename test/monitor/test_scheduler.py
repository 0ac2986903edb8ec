"""The one window scheduler (galvo_sysid.monitor.scheduler): off-thread fits, child
processes started once, a bounded queue, outcomes in window order when asked."""

from __future__ import annotations

import functools
import os
import threading
import time

import numpy as np
import pytest
from monitor_fakes import Collector, fake_result, slow_fit, window

from galvo_sysid.errors import ConfigurationError, ModelMismatchError
from galvo_sysid.ident import IdentificationResult
from galvo_sysid.model import relative_errors
from galvo_sysid.monitor.moves import Window
from galvo_sysid.monitor.scheduler import FitOutcome, WindowScheduler
from galvo_sysid.sim.simulator import GalvoSimulator


def test_fitter_runs_off_the_callers_thread_and_reports_failures() -> None:
    done = Collector()
    done.expected = 5
    fitter = WindowScheduler(functools.partial(slow_fit, delay=0.1), done, queue_size=10)
    t = time.monotonic()
    for i in range(5):
        assert fitter.submit(window(i)) == []
    assert time.monotonic() - t < 0.25  # submitting never waits for a fit (5 x 0.1 s)
    assert done.event.wait(10)
    fitter.close()
    by_index = {o.window.index: o for o in done.items}
    assert [o.window.index for o in done.items] == [0, 1, 2, 3, 4]  # in order
    assert by_index[0].result is not None
    assert by_index[0].fit_time >= 0.09
    assert by_index[3].result is None
    assert by_index[3].error == 'no physical mode 2 in its band'
    assert by_index[4].error == 'unexpected RuntimeError: boom'
    assert (fitter.fitted, fitter.failed, fitter.dropped) == (3, 2, 0)


def test_fitter_drops_the_oldest_window_when_its_queue_is_full() -> None:
    done = Collector()
    done.expected = 3
    fitter = WindowScheduler(functools.partial(slow_fit, delay=0.3), done, queue_size=2)
    dropped = []
    for i in (0, 1, 2, 5, 6):
        dropped += fitter.submit(window(i))
        time.sleep(0.01)
    assert done.event.wait(10)
    fitter.close()
    assert [w.index for w in dropped] == [1, 2]
    assert [o.window.index for o in done.items] == [0, 5, 6]
    assert fitter.dropped == 2


def test_fit_in_a_child_process_on_simulated_moves() -> None:
    sim = GalvoSimulator(seed=3)
    cur, enc = [], []
    for move in sim.moves(angles=[0.9], moves_per_angle=100):
        if move.target_angle > 0:
            cur.append(move.current)
            enc.append(move.encoder)
    w = Window(index=0, target_angle=0.9, sample_period=1e-5, current=np.array(cur),
               encoder=np.array(enc), move_ids=tuple(range(50)), first_stamp=0.0,
               last_stamp=0.3)
    from galvo_sysid.monitor.scheduler import fit_window

    done = Collector()
    done.expected = 1
    fitter = WindowScheduler(fit_window, done, processes=1)
    fitter.submit(w)
    assert done.event.wait(60)
    fitter.close()
    (outcome,) = done.items
    assert outcome.error is None
    assert outcome.result is not None
    err = relative_errors(outcome.result.model)
    assert abs(err['omega_1']) < 0.002
    assert abs(err['omega_2']) < 0.002
    assert abs(err['k0']) < 0.02
    assert outcome.result.moves == 50


def test_fit_window_uses_the_model() -> None:
    from galvo_sysid.monitor.scheduler import fit_window
    from galvo_sysid.sim.family import random_scanner

    scanner = random_scanner(35)
    sim = GalvoSimulator(config=scanner.config, seed=4)
    moves = [m for m in sim.moves(angles=[0.3], moves_per_angle=40) if m.target_angle > 0]
    w = Window(index=0, target_angle=0.3, sample_period=scanner.model.sample_period,
               current=np.array([m.current for m in moves]),
               encoder=np.array([m.encoder for m in moves]), move_ids=tuple(range(20)),
               first_stamp=0.0, last_stamp=1.0)
    r = fit_window(w, model=scanner.model)
    assert r.n_modes == 2
    truth = scanner.model.parameters()
    got = r.model.parameters()
    for name in ('k0', 'omega_1', 'omega_2'):
        assert abs(got[name] / truth[name] - 1) < 0.01, name
    with pytest.raises(ModelMismatchError, match='sample period'):
        fit_window(w)  # the paper's model: another scanner


def late_first_fit(w: Window) -> IdentificationResult:
    """Earlier windows take longer: they finish after later ones (module level: picklable)."""
    time.sleep(0.05 * (6 - w.index % 6))
    if w.index == 2:
        raise ModelMismatchError('no physical mode 2 in the band\n  (5e4..9e4 rad/s)')
    return fake_result(moves=os.getpid())  # moves: which process fitted it


def test_outcomes_in_window_order_from_forked_children_started_once() -> None:
    with WindowScheduler(late_first_fit, processes=3, queue_size=3, when_full='wait',
                         ordered=True, start_method='fork', warm_up=False) as scheduler:
        got: list[FitOutcome] = []
        for i in range(12):
            assert scheduler.submit(window(i)) == []  # 'wait': nothing dropped
            assert scheduler.waiting <= 3
            got += scheduler.take()
        scheduler.close(timeout=None)
        got += scheduler.take()
    assert [o.window.index for o in got] == list(range(12))
    pids = {o.result.moves for o in got if o.result is not None}
    assert len(pids) <= 3  # the same children all along
    assert os.getpid() not in pids
    (bad,) = [o for o in got if o.result is None]
    assert bad.mismatch
    assert bad.error == 'no physical mode 2 in the band (5e4..9e4 rad/s)'
    assert isinstance(bad.exception, ModelMismatchError)  # for callers' own words
    assert (scheduler.fitted, scheduler.mismatched, scheduler.failed, scheduler.dropped) == \
        (11, 1, 0, 0)


def test_unordered_outcomes_come_as_they_finish() -> None:
    done = Collector()
    done.expected = 6
    scheduler = WindowScheduler(late_first_fit, done, processes=3, queue_size=6,
                                start_method='fork', warm_up=False)
    for i in range(6):
        scheduler.submit(window(i))
    assert done.event.wait(10)
    scheduler.close()
    assert sorted(o.window.index for o in done.items) == list(range(6))
    assert [o.window.index for o in done.items] != list(range(6))  # 0 takes longest


def test_a_dropped_window_does_not_hold_up_the_ordered_outcomes() -> None:
    done = Collector()
    done.expected = 2
    scheduler = WindowScheduler(functools.partial(slow_fit, delay=0.3), done, queue_size=1,
                                ordered=True)
    dropped = []
    for i in (0, 1, 2, 5):
        dropped += scheduler.submit(window(i))
        time.sleep(0.01)
    assert done.event.wait(10)
    scheduler.close()
    assert [w.index for w in dropped] == [1, 2]
    assert [o.window.index for o in done.items] == [0, 5]


def test_a_full_queue_makes_the_caller_wait_when_asked() -> None:
    scheduler = WindowScheduler(functools.partial(slow_fit, delay=0.1), queue_size=1,
                                when_full='wait', ordered=True)
    t = time.monotonic()
    for i in (0, 1, 2):
        assert scheduler.submit(window(i)) == []
    assert time.monotonic() - t >= 0.09  # the third waited for the first fit
    scheduler.close()
    assert [o.window.index for o in scheduler.take()] == [0, 1, 2]
    late = window(5)
    assert scheduler.submit(late)[0] is late  # closed: taken no more


def test_leaving_on_an_error_drops_the_queued_windows() -> None:
    started = threading.Event()

    def fit(w: Window) -> IdentificationResult:
        started.set()
        time.sleep(0.2)
        return fake_result()

    scheduler = WindowScheduler(fit, queue_size=10)

    def interrupted() -> None:
        with scheduler:
            for i in range(5):
                scheduler.submit(window(i))
            assert started.wait(5)
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        interrupted()
    assert scheduler.fitted == 1  # the fit under way finished, the 4 queued were let go
    assert [o.window.index for o in scheduler.take()] == [0]


@pytest.mark.parametrize(('kwargs', 'match'), [
    ({'queue_size': 0}, 'queue_size'),
    ({'processes': -1}, 'processes'),
    ({'when_full': 'block'}, 'when_full'),
    ({'start_method': 'thread'}, 'start_method'),
])
def test_bad_settings(kwargs: dict, match: str) -> None:
    with pytest.raises(ConfigurationError, match=match):
        WindowScheduler(fake_result, **kwargs)


def test_the_node_fit_leaves_out_only_the_bound() -> None:
    """The sysid node's fit: the refined fit without the Cramer-Rao bound it never publishes,
    otherwise the same call as ``galvo-sysid identify`` makes."""
    from galvo_sysid.model import PSI, TAU
    from galvo_sysid.monitor.moves import Window
    from galvo_sysid.monitor.scheduler import fit_window, node_fit
    from galvo_sysid.sim.simulator import simulate_window

    refined = node_fit(method='refined', model=None, na=15, nb=15)
    assert refined.func is fit_window
    assert refined.keywords['options'] == {'na': 15, 'nb': 15, 'bound': False}
    paper = node_fit(method='paper-A', model=None, na=12, nb=14)
    assert paper.keywords == {'method': 'paper-A', 'model': None,
                              'options': {'na': 12, 'nb': 14}}
    cur, enc = simulate_window(PSI, moves=20, seed=2)
    win = Window(index=0, target_angle=PSI, current=cur, encoder=enc, sample_period=TAU,
                 move_ids=tuple(range(20)), first_stamp=0.0, last_stamp=1.0)
    by_node = refined(win)
    offline = fit_window(win, options={'na': 15, 'nb': 15})
    assert by_node.crlb_std == {}
    assert offline.crlb_std
    assert by_node.model == offline.model
    assert by_node.std_by_name() == offline.std_by_name()


def test_a_windows_deadline_reaches_the_refined_fit_and_no_other() -> None:
    """A window's ``deadline`` (the sysid node's ``fit_budget_ms``) is passed to the refined
    fit, which past it is cut short; the paper methods, which have no stage to leave out, fit
    the window as without it (no unknown option)."""
    from dataclasses import replace

    from galvo_sysid.model import TAU
    from galvo_sysid.monitor.scheduler import fit_window, node_fit
    from galvo_sysid.sim.simulator import simulate_window

    cur, enc = simulate_window(2.1, moves=100, seed=3)
    win = Window(index=0, target_angle=2.1, current=cur, encoder=enc, sample_period=TAU,
                 move_ids=tuple(range(100)), first_stamp=0.0, last_stamp=1.0)
    past = replace(win, deadline=time.monotonic() - 1.0)
    refined = node_fit(method='refined', model=None, na=15, nb=15)
    assert not refined(win).cut_short
    cut = refined(past)
    assert cut.cut_short
    assert cut.resolved == (True, True, False)
    paper = node_fit(method='paper-A', model=None, na=15, nb=15)
    assert paper(past) == paper(win)
    assert fit_window(replace(win, deadline=time.monotonic() + 600)) == fit_window(win)


def test_a_blocking_take_waits_for_an_outcome_and_not_when_nothing_is_left() -> None:
    """``take(block=True)`` (``identify_bag``'s warm chains wait on it): it returns as soon as
    an outcome is there, in order, and at once with nothing when no window is queued or being
    fitted (a dropped window is not waited for)."""
    with WindowScheduler(slow_fit, queue_size=1, ordered=True) as fitter:
        assert fitter.take(block=True) == []
        start = time.monotonic()
        fitter.submit(window(0))
        (first,) = fitter.take(block=True)
        assert first.window.index == 0
        assert time.monotonic() - start >= 0.04  # slow_fit takes 50 ms
        fitter.submit(window(1))
        dropped = fitter.submit(window(2))  # window 1 still queued, or already fitting
        got = [o.window.index for o in fitter.take(block=True)]
        while len(got) < 2 - len(dropped):
            got += [o.window.index for o in fitter.take(block=True)]
        assert got == [i for i in (1, 2) if i not in [w.index for w in dropped]]
        assert fitter.take(block=True) == []


def test_the_warm_up_fit_succeeds() -> None:
    """The fit each child runs before the first window goes all the way (until 2026-11-28 it
    ended in a model mismatch, its last steps never warmed)."""
    from galvo_sysid.monitor.scheduler import _warm_up

    assert _warm_up() is True
