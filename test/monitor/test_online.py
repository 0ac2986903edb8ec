"""The sysid and watchdog logic without ROS (galvo_sysid.monitor.online)."""

from __future__ import annotations

import functools
import threading
import time

import numpy as np
import pytest

from galvo_sysid.errors import IdentificationError, ModelMismatchError
from galvo_sysid.ident.identify import IdentificationResult
from galvo_sysid.model import REFERENCE_MODEL, relative_errors
from galvo_sysid.monitor.drift import (
    ERROR,
    MISMATCH,
    OK,
    STALE,
    STATUS_MISMATCH,
    WARN,
    DriftMonitor,
)
from galvo_sysid.monitor.online import (
    FitOutcome,
    RateLimitedLog,
    SysidTask,
    WatchdogTask,
    WindowFitter,
)
from galvo_sysid.monitor.pairing import MoveHalf, Window
from galvo_sysid.sim.simulator import GalvoSimulator

M = REFERENCE_MODEL


def fake_result(angle: float = 0.3, moves: int = 2, omega_scale: float = 1.0,
                ) -> IdentificationResult:
    return IdentificationResult(
        target_angle=angle, moves=moves, input_delay=1.6e-5, lag_time_constant=6e-6,
        k0=M.k0, residues=M.residues,
        natural_frequencies=tuple(w * omega_scale for w in M.natural_frequencies),
        damping_ratios=M.damping_ratios, k0_std=0.0, residues_std=(0.0,) * 3,
        natural_frequencies_std=(0.0,) * 3, damping_ratios_std=(0.0,) * 3,
        fit_percent=95.0, method='refined')


def window(index: int, moves: int = 2) -> Window:
    return Window(index=index, target_angle=0.3, sample_period=1e-5,
                  current=np.zeros((moves, 64)), encoder=np.zeros((moves, 64)),
                  move_ids=tuple(range(moves)), first_stamp=0.0, last_stamp=1.0)


class Collector:
    def __init__(self) -> None:
        self.items: list[FitOutcome] = []
        self.event = threading.Event()
        self.expected = 0

    def __call__(self, outcome: FitOutcome) -> None:
        self.items.append(outcome)
        if len(self.items) >= self.expected:
            self.event.set()


def slow_fit(w: Window, *, delay: float = 0.05) -> IdentificationResult:
    time.sleep(delay)
    if w.index == 3:
        raise IdentificationError('no physical mode 2 in its band')
    if w.index == 4:
        raise RuntimeError('boom')
    return fake_result(moves=w.moves)


def test_fitter_runs_off_the_callers_thread_and_reports_failures() -> None:
    done = Collector()
    done.expected = 5
    fitter = WindowFitter(functools.partial(slow_fit, delay=0.1), done, queue_size=10)
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
    fitter = WindowFitter(functools.partial(slow_fit, delay=0.3), done, queue_size=2)
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
    from galvo_sysid.monitor.online import fit_window

    done = Collector()
    done.expected = 1
    fitter = WindowFitter(fit_window, done, processes=1)
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


def halves_of(sim: GalvoSimulator, angles: list[float], moves_per_angle: int) -> list[MoveHalf]:
    out = []
    for m in sim.moves(angles=angles, moves_per_angle=moves_per_angle):
        for sig, data in (('current', m.current), ('encoder', m.encoder)):
            out.append(MoveHalf(sig, m.move_id, m.target_angle, m.sample_period, m.stamp, data))
    return out


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
    warnings: list[str] = []
    task = SysidTask(lambda w: fake_result(), lambda o: None, warn=warnings.append,
                     windower={'window_size': 10, 'pair_timeout': 0.05})
    h = halves_of(GalvoSimulator(seed=1), [0.3], 2)[0]
    task.add(h)
    task.tick()
    assert warnings == []
    time.sleep(0.1)
    task.tick()
    task.close()
    assert len(warnings) == 1
    assert 'unpaired after 0.05 s: no encoder record' in warnings[0]


def test_rate_limited_log_sums_up_a_flood() -> None:
    lines: list[str] = []
    now = [0.0]
    log = RateLimitedLog(lines.append, per_second=3, clock=lambda: now[0])
    for i in range(10):
        log(f'bad move {i}', key='bad move')
    assert lines == ['bad move 0', 'bad move 1', 'bad move 2']
    now[0] = 1.5
    log.flush()
    assert lines[-1] == '7 more similar message(s) held back in the last second: 7 x bad move'
    log('next')
    assert lines[-1] == 'next'


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


def test_fit_window_uses_the_model() -> None:
    from galvo_sysid.monitor.online import fit_window
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


def test_watchdog_task_passes_the_status_on() -> None:
    task = WatchdogTask(DriftMonitor())
    v = task.on_result(fake_result(), window_index=0, status=STATUS_MISMATCH,
                       status_message='the data do not match model x.yaml: residual')
    assert v.level == MISMATCH
    assert 'x.yaml: residual' in v.message
    assert task.poll()[0].level == MISMATCH
