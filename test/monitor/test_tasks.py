"""The task objects the nodes wire, without ROS (galvo_sysid.monitor.tasks)."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import pytest
from monitor_fakes import Collector, fake_result, halves_of, window

from galvo_sysid.errors import ModelMismatchError
from galvo_sysid.ident import IdentificationResult
from galvo_sysid.ident.warm import WarmStart
from galvo_sysid.monitor.drift import DriftMonitor
from galvo_sysid.monitor.moves import MoveHalf, Window
from galvo_sysid.monitor.scheduler import FitOutcome
from galvo_sysid.monitor.tasks import SysidTask, WatchdogTask, mismatch_message
from galvo_sysid.monitor.verdict import ERROR, MISMATCH, OK, STALE, STATUS_MISMATCH, WARN
from galvo_sysid.sim.simulator import GalvoSimulator


def test_sysid_task_windows_rejections_and_counters() -> None:
    warnings: list[str] = []
    done = Collector()
    done.expected = 2
    task = SysidTask(lambda w: fake_result(w.target_angle, w.moves), done,
                     warn=warnings.append, windower={'window_size': 10})
    items = halves_of(GalvoSimulator(seed=1), [0.3], 22)
    bad = items[7]  # encoder of move 3
    items[7] = MoveHalf(bad.signal, bad.move_id, bad.target_angle, bad.sample_period,
                        bad.stamp, np.full(bad.data.shape, np.nan))
    for h in items:
        task.add(h)
    assert done.event.wait(10)
    task.close()
    assert sorted(o.window.target_angle for o in done.items) == [-0.3, 0.3]
    minus = next(o.window for o in done.items if o.window.target_angle < 0)
    assert 3 not in minus.move_ids  # move 3 is a return move (-0.3 deg)
    assert minus.moves == 10
    assert minus.move_ids[:3] == (1, 5, 7)
    assert warnings == ['1 move set aside (id 3; -0.3 deg): NaN or Inf in encoder']
    stats = task.stats()
    assert stats['halves_received'] == 44
    assert stats['moves_rejected'] == 1
    assert stats['windows_completed'] == 2
    assert stats['windows_identified'] == 2
    assert stats['moves_accepted'] == 21


def test_sysid_task_says_unpaired_halves_when_input_pauses() -> None:
    """With no input at all, a waiting half is set aside (and said) once the pause is as
    long as a lagging partner topic is waited for, LATE_TOPIC + 1 pair timeouts; a partner
    held up for less (both topics stalled behind huge messages) still pairs."""
    from galvo_sysid.monitor.pairing import LATE_TOPIC

    warnings: list[str] = []
    task = SysidTask(lambda w: fake_result(), lambda o: None, warn=warnings.append,
                     windower={'window_size': 10, 'pair_timeout': 0.05})
    wait = (LATE_TOPIC + 1) * 0.05
    halves = halves_of(GalvoSimulator(seed=1), [0.3], 2)
    current = [h for h in halves if h.signal == 'current']
    encoder = [h for h in halves if h.signal == 'encoder']
    task.add(current[0])
    time.sleep(0.5 * wait)  # ten pair timeouts of no input: the partner may still come
    task.tick()
    assert task.windower.pending == 1
    task.add(encoder[0])
    assert task.windower.pending == 0
    assert task.windower.moves_rejected == 0
    task.add(current[1])
    task.tick()
    assert warnings == []
    time.sleep(wait + 0.05)
    task.tick()
    task.close()
    assert task.windower.moves_rejected == 1
    assert len(warnings) == 1
    assert 'unpaired after 0.05 s: no encoder record' in warnings[0]


def test_watchdog_task_goes_stale_and_recovers() -> None:
    now = [0.0]
    task = WatchdogTask(DriftMonitor(), stale_timeout=5.0, clock=lambda: now[0])
    verdict, became = task.poll()
    assert verdict.level == STALE
    assert 'yet' in verdict.message
    assert not became
    now[0] = 6.0
    verdict, became = task.poll()
    assert (verdict.level, became) == (STALE, True)
    assert task.poll()[1] is False  # said once
    assert task.on_result(fake_result(), window_index=0).level == OK
    now[0] = 8.0
    verdict, became = task.poll()
    assert (verdict.level, became) == (OK, False)
    now[0] = 11.5
    verdict, became = task.poll()
    assert (verdict.level, became) == (STALE, True)
    assert '5.5 s' in verdict.message
    assert task.on_result(fake_result(omega_scale=0.95), window_index=1).level == ERROR
    assert task.poll()[0].level == ERROR
    assert task.windows_judged == 2
    with pytest.raises(Exception, match='stale_timeout'):
        WatchdogTask(DriftMonitor(), stale_timeout=0.0)


class Clock:
    """A settable clock for the tasks (seconds)."""

    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def test_watchdog_task_is_stale_exactly_once_stale_timeout_has_passed() -> None:
    """The claim "STALE after stale_timeout without a result" at the task itself: a poll
    just before the timeout is not STALE, one just after is, since the start and since the
    last result (the injected clock makes the boundary exact; the node's timer adds at most
    one publish period, the next test)."""
    rng = np.random.default_rng(16)
    for _ in range(50):
        timeout = float(np.exp(rng.uniform(np.log(0.05), np.log(1e3))))
        start = float(rng.uniform(0.0, 1e4))
        now = Clock(start)
        task = WatchdogTask(DriftMonitor(), stale_timeout=timeout, clock=now)
        eps = 1e-9 * (start + 3 * timeout)  # far above rounding, far below a timer period
        now.t = start + timeout - eps
        verdict, became = task.poll()
        assert (verdict.level, became) == (STALE, False)  # nothing yet, not said yet
        assert 'yet' in verdict.message
        now.t = start + timeout + eps
        assert task.poll()[1] is True
        last = now.t = now.t + float(rng.uniform(0.0, timeout))
        task.on_result(fake_result(), window_index=0)
        now.t = last + timeout - eps
        verdict, became = task.poll()
        assert (verdict.level, became) == (OK, False), timeout
        now.t = last + timeout + eps
        verdict, became = task.poll()
        assert (verdict.level, became) == (STALE, True), timeout
        assert f'for {timeout:.1f} s' in verdict.message


def test_watchdog_task_polled_by_a_timer_says_stale_within_one_publish_period() -> None:
    """The node polls the task every 1 / publish_rate s (publish_rate in (0, 10], its
    parameter range): after a silence of stale_timeout, STALE is reported by the first poll
    past it, never earlier, never a poll later, and said once per silence. Results arrive at
    random, with silences shorter and longer than the timeout (seeded cases)."""
    rng = np.random.default_rng(1616)
    said_total = 0
    for _ in range(100):
        timeout = float(np.exp(rng.uniform(np.log(0.05), np.log(20.0))))
        period = 1.0 / float(rng.uniform(0.1, 10.0))
        gaps = timeout * np.exp(rng.uniform(np.log(0.05), np.log(4.0), size=12))
        results = float(rng.uniform(0.0, 3 * timeout)) + np.cumsum(gaps)
        polls = float(rng.uniform(0.0, period)) + period * np.arange(
            int((results[-1] + 2 * timeout) / period) + 2)
        events = sorted([(float(t), 'poll') for t in polls]
                        + [(float(t), 'result') for t in results])
        now = Clock(0.0)
        task = WatchdogTask(DriftMonitor(), stale_timeout=timeout, clock=now)
        last = 0.0  # the start counts as the last result until the first one
        said = False
        for t, kind in events:
            now.t = t
            if kind == 'result':
                task.on_result(fake_result(), window_index=0)
                last, said = t, False
                continue
            verdict, became = task.poll()
            timed_out = t - last > timeout
            case = (timeout, period, t - last)
            assert (verdict.level == STALE) == (timed_out or task.last_verdict is None), case
            assert became == (timed_out and not said), case
            if became:  # by the first poll past the timeout: within one publish period
                assert timeout < t - last <= timeout + period, case
                said = True
                said_total += 1
    assert said_total > 100  # silences longer than the timeout happened, and were said


def test_windows_of_another_scanner_are_counted_as_mismatches_and_said_plainly() -> None:
    from galvo_sysid.sim.family import random_scanner

    scanner = random_scanner(35)  # 2 modes, 13.3 us: not the paper's scanner
    sim = GalvoSimulator(config=scanner.config, seed=2)
    warnings: list[str] = []
    done = Collector()
    done.expected = 2

    def fit(w: Window) -> IdentificationResult:
        if w.target_angle > 0:
            raise ModelMismatchError('no physical mode 2 in the band 5e4..9e4 rad/s')
        return fake_result(w.target_angle, w.moves)

    task = SysidTask(fit, done, warn=warnings.append, model_path='scanners/s35.yaml',
                     windower={'window_size': 5, 'sample_period': scanner.model.sample_period})
    assert task.health({}) == (OK, '0 windows identified, 0 moves used')
    for h in halves_of(sim, [0.3], 10):
        task.add(h)
    assert done.event.wait(10)
    task.close()
    plus = next(o for o in done.items if o.window.target_angle > 0)
    assert plus.mismatch
    assert plus.result is None
    assert plus.error == 'no physical mode 2 in the band 5e4..9e4 rad/s'
    stats = task.stats()
    assert (stats['windows_identified'], stats['windows_mismatched'],
            stats['windows_failed']) == (1, 1, 0)
    text = ('the data do not match model scanners/s35.yaml: no physical mode 2 in the band '
            '5e4..9e4 rad/s; run galvo-sysid commission')
    assert any(w.endswith(text) for w in warnings), warnings
    assert task.health({}) == (ERROR, f'1 window(s) not identified since the last report: '
                                      f'{text}')
    # nothing new since then, and the latest window (-0.3 deg, the last to complete) was
    # identified: OK
    assert task.health(task.stats()) == (OK, '1 windows identified, 10 moves used')
    # the latest window did not match: ERROR until a window is identified again
    task._done(FitOutcome(window(7), None, 'a residual 40 times the noise', 0.0, 0.0,
                          mismatch=True))
    since = task.stats()
    assert task.health(since)[1].startswith('the latest window was not identified: the data '
                                            'do not match model scanners/s35.yaml: a residual')
    task._done(FitOutcome(window(8), fake_result(), None, 0.0, 0.0))
    assert task.health(since)[0] == OK


def test_moves_of_another_sample_period_make_identification_health_an_error() -> None:
    from galvo_sysid.sim.family import random_scanner

    scanner = random_scanner(35)
    task = SysidTask(lambda w: fake_result(), lambda o: None, warn=lambda line: None,
                     windower={'window_size': 5, 'sample_period': 1e-5}, model_path='')
    before = task.stats()
    for h in halves_of(GalvoSimulator(config=scanner.config, seed=2), [0.3], 4):
        task.add(h)
    task.close()
    level, message = task.health(before)
    assert level == ERROR
    assert message == ("moves set aside since the last report: the data do not match model "
                       "paper_table1 (packaged): the data's sample period 1.33e-05 s differs "
                       "from the model's 1e-05 s; run galvo-sysid commission")
    # failed fits and set-aside moves of the right period only warn
    warn_task = SysidTask(lambda w: fake_result(), lambda o: None, warn=lambda line: None)
    warn_task.fitter.failed = 1
    assert warn_task.health({})[0] == WARN
    warn_task.close()


def test_watchdog_task_passes_the_status_on() -> None:
    task = WatchdogTask(DriftMonitor())
    v = task.on_result(fake_result(), window_index=0, status=STATUS_MISMATCH,
                       status_message='the data do not match model x.yaml: residual')
    assert v.level == MISMATCH
    assert 'x.yaml: residual' in v.message
    assert task.poll()[0].level == MISMATCH


def test_mismatch_message_names_the_model_file_and_the_way_out() -> None:
    assert mismatch_message('no physical mode 2\n  in the band', model_path='s.yaml') == (
        'the data do not match model s.yaml: no physical mode 2 in the band; run galvo-sysid '
        'commission')
    assert 'model paper_table1 (packaged)' in mismatch_message('x', model_path='')


# -- issue 12, defect 3: sizes checked before decoding -----------------------------------------

class _Serialized:
    """A half still serialized: its length known, decoding it fails the test."""

    def __init__(self, half: MoveHalf, samples: int) -> None:
        self._half = half
        self.samples = samples

    def half(self, signal: str) -> MoveHalf:
        if self.samples > 64:
            raise AssertionError('an oversized record was decoded')
        return self._half

    def header_half(self, signal: str) -> MoveHalf:
        h = self._half
        return MoveHalf(signal, h.move_id, h.target_angle, h.sample_period, h.stamp,
                        np.zeros(0))


def test_oversized_serialized_half_is_refused_without_being_decoded() -> None:
    warnings: list[str] = []
    done = Collector()
    done.expected = 1
    task = SysidTask(lambda w: fake_result(w.target_angle, w.moves), done,
                     warn=warnings.append, windower={'window_size': 2, 'max_samples': 64})
    base = np.arange(64.0)
    try:
        for mid in range(3):
            for signal in ('current', 'encoder'):
                half = MoveHalf(signal, mid, 0.3, 1e-5, 100.0 + 0.01 * mid, base + mid)
                # move 1's current claims 5,000,000 samples: refused, its encoder dropped
                samples = 5_000_000 if (mid, signal) == (1, 'current') else 64
                task.add_serialized(_Serialized(half, samples), signal=signal)
        assert done.event.wait(10)
    finally:
        task.close()
    assert [o.window.move_ids for o in done.items] == [(0, 2)]
    stats = task.stats()
    assert stats['halves_refused'] == 1
    assert stats['halves_received'] == 6
    assert stats['moves_rejected'] == 1
    assert warnings == ['1 move set aside (id 1; 0.3 deg): current record too long '
                        '(5000000 > 64 samples), refused before decoding']


def test_serialized_cdr_of_5m_doubles_is_refused_in_constant_memory() -> None:
    import tracemalloc

    from galvo_sysid.field.bags.definitions import galvo_typestore
    from galvo_sysid.interfaces.messages import read_move_samples
    from galvo_sysid.interfaces.topics import MOVE_SAMPLES

    store = galvo_typestore()
    types = store.types
    header = types['std_msgs/msg/Header'](stamp=types['builtin_interfaces/msg/Time'](
        sec=100, nanosec=0), frame_id='')
    raw = bytes(store.serialize_cdr(types[MOVE_SAMPLES](
        header=header, move_id=1, target_angle=0.3, sample_period=1e-5,
        data=np.full(5_000_000, 0.1)), MOVE_SAMPLES))
    task = SysidTask(lambda w: fake_result(), lambda o: None, warn=lambda line: None)
    try:
        tracemalloc.start()
        try:
            task.add_serialized(read_move_samples(raw), signal='current')
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
    finally:
        task.close()
    assert peak < 1_000_000  # the 40 MB of samples were never decoded
    assert task.stats()['halves_refused'] == 1
    assert task.windower.buffered_bytes == 0


# -- what the mutation run of tools/mutate.py found untested (docs/mutation.md) -------------

def test_a_message_that_cannot_be_converted_is_one_rejection_and_said() -> None:
    warnings: list[str] = []
    task = SysidTask(lambda w: fake_result(), lambda o: None, warn=warnings.append)
    task.set_aside('not a MoveSamples message')
    task.close()
    assert task.stats()['moves_rejected'] == 1
    assert warnings == ['message set aside: not a MoveSamples message']


def test_health_counters_of_a_replaced_windower_never_go_below_zero() -> None:
    """A windower replaced by new settings counts from 0 again: fewer than at the last report
    is nothing new, not a negative number of problems."""
    task = SysidTask(lambda w: fake_result(), lambda o: None, warn=lambda line: None)
    since = dict(task.stats(), moves_rejected=5, windows_failed=2, windows_dropped=1,
                 windows_identified=3, windows_mismatched=1, halves_period_mismatched=4)
    task.close()
    assert task.health(since) == (OK, '0 windows identified, 0 moves used')


def test_moves_of_another_sample_period_are_an_error_only_in_the_report_that_saw_them() -> None:
    from galvo_sysid.sim.family import random_scanner

    task = SysidTask(lambda w: fake_result(), lambda o: None, warn=lambda line: None,
                     windower={'window_size': 5, 'sample_period': 1e-5})
    before = task.stats()
    for h in halves_of(GalvoSimulator(config=random_scanner(35).config, seed=2), [0.3], 4):
        task.add(h)
    task.close()
    assert task.health(before)[0] == ERROR
    assert task.health(task.stats())[0] == OK


def test_warnings_beyond_the_rate_are_summed_up_by_reason() -> None:
    from galvo_sysid.monitor.ratelog import RateLimitedLog

    warnings: list[str] = []
    now = [0.0]
    task = SysidTask(lambda w: fake_result(), lambda o: None, warn=warnings.append,
                     windower={'window_size': 10})
    task._warn = RateLimitedLog(warnings.append, per_second=1, clock=lambda: now[0])
    items = halves_of(GalvoSimulator(seed=1), [0.3], 6)
    for i in (3, 7, 11):  # encoders of moves 1, 3 and 5 (return moves, -0.3 deg)
        items[i] = MoveHalf(items[i].signal, items[i].move_id, items[i].target_angle,
                            items[i].sample_period, items[i].stamp,
                            np.full(items[i].data.shape, np.nan))
    for h in items:
        task.add(h)
    now[0] = 1.5
    task.tick()
    task.close()
    assert warnings == ['1 move set aside (id 1; -0.3 deg): NaN or Inf in encoder',
                        '2 more similar message(s) held back in the last second: '
                        '2 x NaN or Inf in encoder']


def test_sysid_task_reports_the_latency_of_its_windows() -> None:
    """Median, 99th percentile and largest time from a window's completion to its fit's end
    (issue 17: the latency distribution on /diagnostics), over the last 200 windows."""
    task = SysidTask(lambda w: fake_result(), lambda o: None, warn=lambda _: None)
    assert task.stats()['latency_ms_p99'] == -1  # nothing finished yet
    assert task.stats()['fit_cpu_ms_p99'] == -1
    assert task.stats()['wait_ms_max'] == -1
    for i, seconds in enumerate([0.010, 0.020, 0.030, 0.040, 1.0]):
        task._done(FitOutcome(window(i), fake_result(), None, queued=seconds / 2,
                              fit_time=seconds / 2, fit_cpu=seconds / 4))
    task._done(FitOutcome(window(5), None, 'failed', queued=0.0, fit_time=2.0))  # no CPU
    stats = task.stats()
    task.close()
    assert stats['latency_ms_median'] == 35
    assert stats['latency_ms_max'] == 2000
    assert stats['latency_ms_p99'] == round(float(np.percentile([10, 20, 30, 40, 1000, 2000],
                                                                99)))
    assert (stats['fit_cpu_ms_median'], stats['fit_cpu_ms_max']) == (8, 250)  # 7.5 rounds up
    # each window's latency less its own fit's CPU (3/4 of it here), not of the spreads
    assert (stats['wait_ms_median'], stats['wait_ms_max']) == (22, 750)  # 22.5 rounds down
    for i in range(300):  # only the last 200 count
        task._done(FitOutcome(window(i), fake_result(), None, queued=0.0, fit_time=0.005,
                              fit_cpu=0.004))
    assert task.latency_ms() == {'latency_ms_median': 5, 'latency_ms_p99': 5,
                                 'latency_ms_max': 5, 'fit_cpu_ms_median': 4,
                                 'fit_cpu_ms_p99': 4, 'fit_cpu_ms_max': 4,
                                 'wait_ms_median': 1, 'wait_ms_p99': 1, 'wait_ms_max': 1}


def test_the_scheduler_measures_each_fits_cpu_time_where_it_runs() -> None:
    """A fit's CPU time is measured on the thread or in the child process that runs it: a
    fit that burns about 60 ms of CPU reports that, one that sleeps 60 ms next to none; a
    failed fit reports none (nan)."""
    import math

    from galvo_sysid.monitor.scheduler import WindowScheduler

    for processes in (0, 1):
        with WindowScheduler(_burn_or_sleep, processes=processes, warm_up=False) as fits:
            for w in (window(0), window(1), window(2)):
                fits.submit(w)
            fits.close(timeout=60)
            done = {o.window.index: o for o in fits.take()}
        assert done[0].fit_cpu > 0.04, done[0]
        assert done[1].fit_cpu < 0.02, done[1]
        assert done[1].fit_time >= 0.06
        assert done[2].result is None
        assert math.isnan(done[2].fit_cpu)


def _burn_or_sleep(w: Window) -> IdentificationResult:
    """Window 0: 60 ms of CPU; window 1: 60 ms asleep; window 2: fails (picklable)."""
    from galvo_sysid.errors import IdentificationError

    if w.index == 2:
        raise IdentificationError('made to fail')
    if w.index == 1:
        time.sleep(0.06)
        return fake_result()
    start = time.thread_time()  # 60 ms of this thread's CPU, however busy the machine is
    while time.thread_time() - start < 0.06:
        pass
    return fake_result()



def _warm_task(*, warm_start: bool = True) -> tuple[SysidTask, Collector, list[Window]]:
    """A task whose fit records each window as it came and returns a result of its own per
    window (its frequencies scaled by the window's index)."""
    seen: list[Window] = []
    done = Collector()

    def fit(w: Window) -> IdentificationResult:
        seen.append(w)
        if w.index == 2:  # the third window (the first +0.3 deg one of round 2)
            raise ModelMismatchError('no physical mode 2 in its band')
        return replace(fake_result(w.target_angle, w.moves, omega_scale=1 + 0.01 * w.index),
                       warm_started=w.warm_start is not None)

    task = SysidTask(fit, done, warn=lambda _: None, windower={'window_size': 10},
                     warm_start=warm_start)
    return task, done, seen


def _rounds(task: SysidTask, done: Collector, rounds: int, *, clear: bool = False) -> None:
    """Windows of +-0.3 deg, one of each sign per round, each round's fits done before the
    next round's moves come (so the next windows can start from them); with ``clear``, the
    task forgets its starts before each round."""
    items = halves_of(GalvoSimulator(seed=4), [0.3], 20 * rounds)
    for r in range(rounds):
        if clear:
            task.clear_starts()  # what the node does when window or fit settings change
        done.event.clear()
        done.expected = 2 * (r + 1)
        for h in items[40 * r: 40 * (r + 1)]:
            task.add(h)
        assert done.event.wait(10)


def test_each_window_starts_from_the_latest_result_of_its_angle() -> None:
    """The sysid node's warm start: a window's fit starts from the latest result of its own
    signed angle; a window that failed or did not match leaves the next one of its angle to
    search afresh; the fits that kept their start are counted."""
    task, done, seen = _warm_task()
    _rounds(task, done, 3)
    stats = task.stats()
    task.close()
    by_index = {w.index: w for w in seen}
    assert sorted(by_index) == [0, 1, 2, 3, 4, 5]
    assert by_index[0].warm_start is None
    assert by_index[1].warm_start is None
    results = {o.window.index: o.result for o in done.items}
    for later, earlier in ((3, 1),):  # -0.3 deg: round 2 starts from round 1
        assert by_index[later].target_angle == by_index[earlier].target_angle
        assert by_index[later].warm_start == WarmStart.from_result(results[earlier])
    plus = [i for i in by_index if by_index[i].target_angle > 0]
    assert plus == [0, 2, 4]
    assert by_index[2].warm_start == WarmStart.from_result(results[0])
    assert by_index[4].warm_start is None  # window 2 did not match: afresh
    minus5 = by_index[5].warm_start
    assert minus5 == WarmStart.from_result(results[3])
    assert stats['windows_warm_started'] == 2  # windows 3 and 5 (2 did not match)
    assert stats['windows_identified'] == 5


def test_warm_start_off_or_forgotten_means_every_fit_searches_afresh() -> None:
    task, done, seen = _warm_task(warm_start=False)
    _rounds(task, done, 2)
    task.close()
    assert all(w.warm_start is None for w in seen)
    assert task.stats()['windows_warm_started'] == 0

    task, done, seen = _warm_task()
    _rounds(task, done, 2, clear=True)
    task.close()
    assert [w.warm_start for w in seen] == [None] * 4


def test_a_sign_without_a_result_starts_from_the_model_until_a_window_fails() -> None:
    """With a ``reference`` (the node's: its model file's modes), a window of a sign without
    an earlier result starts from it instead of searching afresh; after a window that failed
    or did not match, such a window searches afresh until a window is identified again."""
    from galvo_sysid.ident.warm import reference_start
    from galvo_sysid.model import PAPER_MODEL

    seen: list[Window] = []
    done = Collector()

    def fit(w: Window) -> IdentificationResult:
        seen.append(w)
        if w.index in (2, 3):  # both windows of round 2
            raise ModelMismatchError('no physical mode 2 in its band')
        return fake_result(w.target_angle, w.moves, omega_scale=1 + 0.01 * w.index)

    reference = reference_start(PAPER_MODEL)
    assert reference.model == PAPER_MODEL.modal
    assert reference.noise_model is None
    task = SysidTask(fit, done, warn=lambda _: None, windower={'window_size': 10},
                     reference=reference)
    _rounds(task, done, 4, clear=True)
    task.close()
    by_index = {w.index: w for w in seen}
    assert sorted(by_index) == list(range(8))
    assert by_index[0].warm_start is reference
    assert by_index[1].warm_start is reference
    assert by_index[2].warm_start is reference  # the starts were forgotten: the model's
    assert by_index[4].warm_start is None  # the latest window did not match: afresh
    assert by_index[6].warm_start is reference  # identified again since
    assert by_index[7].warm_start is reference


def test_a_fit_budget_gives_each_window_its_deadline_and_counts_the_fits_cut_short() -> None:
    """``fit_budget_ms`` (issue 17, a bound on each window's fit): a window's deadline is its
    completion plus the budget, set when it is handed to the fits; a fit that says it was cut
    short is counted and said once per reason; without a budget no window has a deadline."""
    seen: list[tuple[Window, float]] = []
    lines: list[str] = []
    done = Collector()

    def fit(w: Window) -> IdentificationResult:
        seen.append((w, time.monotonic()))
        return replace(fake_result(w.target_angle, w.moves), cut_short=w.index % 2 == 1)

    task = SysidTask(fit, done, warn=lines.append, windower={'window_size': 10},
                     fit_budget=0.25)
    before = time.monotonic()
    done.expected = 4
    for h in halves_of(GalvoSimulator(seed=4), [0.3], 40):
        task.add(h)
    assert done.event.wait(10)
    stats = task.stats()
    task.close()
    assert len(seen) == 4
    for w, fitted_at in seen:
        assert w.deadline is not None
        assert before + 0.25 <= w.deadline <= fitted_at + 0.25
    assert stats['windows_cut_short'] == 2
    assert stats['windows_identified'] == 4
    cut = [line for line in lines if 'cut short' in line]
    assert cut
    assert 'budget of 250 ms' in cut[0]
    assert 'reported unresolved' in cut[0]

    seen.clear()
    task = SysidTask(fit, Collector(), warn=lambda _: None, windower={'window_size': 10})
    for h in halves_of(GalvoSimulator(seed=4), [0.3], 20):
        task.add(h)
    task.close()
    assert seen
    assert all(w.deadline is None for w, _ in seen)


def test_an_angle_without_a_result_starts_from_the_latest_of_its_sign() -> None:
    """The first window of an angle starts from the latest result of its sign and record
    length (another angle of the same plant, as identify's warm chains start), where there is
    one; a window that did not match leaves the next window of its sign, of whatever angle
    without a result of its own, to search afresh."""
    seen: list[Window] = []
    done = Collector()

    def fit(w: Window) -> IdentificationResult:
        seen.append(w)
        if w.index == 4:  # the first +0.9 deg window
            raise ModelMismatchError('no physical mode 2 in its band')
        return fake_result(w.target_angle, w.moves, omega_scale=1 + 0.01 * w.index)

    task = SysidTask(fit, done, warn=lambda _: None, windower={'window_size': 10})
    results: dict[int, IdentificationResult] = {}
    sim = GalvoSimulator(seed=4)
    for k, angle in enumerate((0.3, 0.6, 0.9, 1.2)):  # one window of each sign per angle
        done.event.clear()
        done.expected = 2 * (k + 1)
        for h in halves_of(sim, [angle], 20):
            task.add(h)
        assert done.event.wait(10)
        results.update({o.window.index: o.result for o in done.items
                        if o.result is not None})
    task.close()
    by_index = {w.index: w for w in seen}
    assert [round(by_index[i].target_angle, 1) for i in range(8)] == [
        0.3, -0.3, 0.6, -0.6, 0.9, -0.9, 1.2, -1.2]
    assert by_index[0].warm_start is None
    assert by_index[1].warm_start is None
    assert by_index[2].warm_start == WarmStart.from_result(results[0])  # +0.6 from +0.3
    assert by_index[3].warm_start == WarmStart.from_result(results[1])  # -0.6 from -0.3
    assert by_index[4].warm_start == WarmStart.from_result(results[2])
    assert by_index[5].warm_start == WarmStart.from_result(results[3])
    assert by_index[6].warm_start is None  # +0.9 did not match: its sign starts afresh
    assert by_index[7].warm_start == WarmStart.from_result(results[5])


def test_the_starts_kept_are_bounded_by_angles_and_by_record_lengths() -> None:
    """Results kept to start later windows from are at most MAX_STARTS per kind (angles; signs
    by record length), the least recently identified forgotten: windows of ever new angles or
    record lengths cannot grow the task's memory."""
    from galvo_sysid.monitor.tasks import MAX_STARTS

    task = SysidTask(lambda w: fake_result(), lambda o: None, warn=lambda _: None)
    n = MAX_STARTS + 40
    for i in range(n):
        w = Window(index=i, target_angle=0.3 + 0.01 * i, sample_period=1e-5,
                   current=np.zeros((2, 64 + i)), encoder=np.zeros((2, 64 + i)),
                   move_ids=(0, 1), first_stamp=0.0, last_stamp=1.0)
        task._done(FitOutcome(w, fake_result(), None, queued=0.0, fit_time=0.0))
    task.close()
    assert len(task._starts) == MAX_STARTS
    assert len(task._by_sign) == MAX_STARTS
    newest = (1, 64 + n - 1)
    assert newest in task._by_sign
    assert (1, 64) not in task._by_sign  # the oldest forgotten


def test_a_measured_current_is_made_held_before_the_fit() -> None:
    # current: measured: each window reaches the fit as the held current behind the coil
    # current (a sample shorter, the encoder too); a lag the sample period cannot take is
    # refused when the task is made
    from galvo_sysid.errors import ConfigurationError
    from galvo_sysid.ident.measured import held_current

    done = Collector()
    done.expected = 1
    task = SysidTask(lambda w: fake_result(w.target_angle, w.moves), done,
                     warn=lambda _: None, windower={'window_size': 10, 'sample_period': 1e-5},
                     measured_lag=6e-6)
    items = halves_of(GalvoSimulator(seed=1), [0.3], 20)
    raw = [w for h in items for w in task.add(h)]
    assert done.event.wait(10)
    task.close()
    fitted = done.items[0].window
    original = next(w for w in raw if w.index == fitted.index)
    assert fitted.current.shape == (10, original.current.shape[1] - 1)
    np.testing.assert_array_equal(
        fitted.current, held_current(original.current, sample_period=1e-5, lag=6e-6))
    np.testing.assert_array_equal(fitted.encoder, original.encoder[:, :-1])
    with pytest.raises(ConfigurationError, match='above 20'):
        SysidTask(lambda w: fake_result(), lambda o: None, warn=lambda _: None,
                  windower={'sample_period': 1e-5}, measured_lag=1e-3)
