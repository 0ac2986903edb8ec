"""Pairing of move halves and windows per target angle (galvo_sysid.monitor.pairing)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.monitor.moves import MoveHalf
from galvo_sysid.monitor.pairing import CONFIRM, MoveWindower
from galvo_sysid.monitor.rejections import summarize_rejections

N = 64
DT = 1e-5
MOVE_TIME = 0.006


def halves(move_id: int, angle: float = 0.3, *, stamp: float | None = None, n: int = N,
           period: float = DT) -> tuple[MoveHalf, MoveHalf]:
    t = move_id * MOVE_TIME if stamp is None else stamp
    base = np.arange(n, dtype=float)
    cur = MoveHalf.create('current', move_id=move_id, target_angle=angle, sample_period=period,
                          stamp=t, data=base + 1000.0 * move_id)
    enc = MoveHalf.create('encoder', move_id=move_id, target_angle=angle, sample_period=period,
                          stamp=t, data=-base - 1000.0 * move_id)
    return cur, enc


def feed(w: MoveWindower, items: list[MoveHalf]) -> list:
    out = []
    for h in items:
        out.extend(w.add(h))
    return out


def test_window_completes_with_paired_records_in_order() -> None:
    w = MoveWindower(window_size=5)
    items = []
    for i in range(5):
        c, e = halves(i)
        items += [e, c] if i % 2 else [c, e]  # either half may come first
    windows = feed(w, items)
    assert len(windows) == 1
    win = windows[0]
    assert win.index == 0
    assert win.moves == 5
    assert win.move_ids == (0, 1, 2, 3, 4)
    assert win.current.shape == (5, N)
    assert win.encoder.shape == (5, N)
    np.testing.assert_array_equal(win.current[3], np.arange(N) + 3000.0)
    np.testing.assert_array_equal(win.encoder[3], -np.arange(N) - 3000.0)
    assert win.first_stamp == pytest.approx(0.0)
    assert win.last_stamp == pytest.approx(4 * MOVE_TIME)
    assert win.target_angle == pytest.approx(0.3)
    assert not win.partial
    assert w.pending == 0
    assert w.open_windows == 0
    assert w.buffered_samples == 0
    assert w.pop_rejections() == []


def test_signed_angles_fill_separate_windows() -> None:
    w = MoveWindower(window_size=3)
    items = []
    for i in range(6):
        items += halves(i, 0.3 if i % 2 == 0 else -0.3)
    windows = feed(w, items)
    assert [(x.index, x.target_angle, x.move_ids) for x in windows] == [
        (0, 0.3, (0, 2, 4)), (1, -0.3, (1, 3, 5))]


@pytest.mark.parametrize('bad_first', [True, False])
def test_nan_move_is_rejected_once_and_window_still_completes(bad_first: bool) -> None:
    w = MoveWindower(window_size=4)
    items = []
    for i in range(5):
        c, e = halves(i)
        if i == 2:
            e = MoveHalf.create('encoder', move_id=2, target_angle=0.3, sample_period=DT,
                                stamp=e.stamp, data=np.where(np.arange(N) == 7, np.nan, 1.0))
            items += [e, c] if bad_first else [c, e]
        else:
            items += [c, e]
    windows = feed(w, items)
    assert len(windows) == 1
    assert windows[0].move_ids == (0, 1, 3, 4)
    rej = w.pop_rejections()
    assert [(r.move_id, r.reason) for r in rej] == [(2, 'NaN or Inf in encoder')]
    assert w.moves_rejected == 1


def test_bad_halves_each_say_why() -> None:
    w = MoveWindower(window_size=10, samples=N, max_samples=1000)
    base = {'sample_period': DT, 'stamp': 0.0}
    bad = [
        MoveHalf.create('current', move_id=1, target_angle=0.0, data=np.ones(N), **base),
        MoveHalf.create('current', move_id=2, target_angle=0.3, data=np.ones(N),
                        sample_period=0.0, stamp=0.0),
        MoveHalf.create('current', move_id=3, target_angle=0.3, data=np.ones(N),
                        sample_period=-1e-5, stamp=0.0),
        MoveHalf.create('current', move_id=4, target_angle=0.3, data=np.ones(0), **base),
        MoveHalf.create('current', move_id=5, target_angle=0.3, data=np.ones(5000), **base),
        MoveHalf.create('current', move_id=6, target_angle=0.3, data=np.ones(N - 1), **base),
        MoveHalf.create('current', move_id=7, target_angle=0.3, data=np.full(N, np.inf), **base),
        MoveHalf.create('current', move_id=8, target_angle=math.nan, data=np.ones(N), **base),
        MoveHalf.create('velocity', move_id=9, target_angle=0.3, data=np.ones(N), **base),
        MoveHalf.create('current', move_id=10, target_angle=0.3, data=np.ones((2, N)), **base),
        MoveHalf.create('current', move_id=11, target_angle=0.3, data=np.ones(N),
                        sample_period=DT, stamp=math.nan),
    ]
    feed(w, bad)
    reasons = {r.move_id: r.reason for r in w.pop_rejections()}
    assert set(reasons) == set(range(1, 12))
    assert reasons[1] == 'zero target angle'
    assert 'sample period' in reasons[2]
    assert 'sample period' in reasons[3]
    assert 'empty' in reasons[4]
    assert 'too long' in reasons[5]
    assert 'expected 64' in reasons[6]
    assert 'NaN or Inf' in reasons[7]
    assert 'target angle' in reasons[8]
    assert 'unknown signal' in reasons[9]
    assert 'one-dimensional' in reasons[10]
    assert 'stamp' in reasons[11]
    assert w.pending == 0


def test_current_and_encoder_of_different_lengths() -> None:
    w = MoveWindower(window_size=2)
    c, _ = halves(0)
    _, e = halves(0, n=N + 3)
    feed(w, [c, e])
    (r,) = w.pop_rejections()
    assert 'lengths differ' in r.reason
    # moves of another length fill a window of their own (no move fixes its angle's length)
    feed(w, [*halves(1), *halves(2, n=2 * N)])
    assert w.pop_rejections() == []
    assert w.open_windows == 2
    (first,) = feed(w, list(halves(3)))
    assert first.move_ids == (1, 3)
    (second,) = feed(w, list(halves(4, n=2 * N)))
    assert second.move_ids == (2, 4)
    assert second.current.shape == (2, 2 * N)


def test_duplicate_move_id() -> None:
    w = MoveWindower(window_size=3)
    c0, e0 = halves(0)
    windows = feed(w, [c0, c0, e0, e0, *halves(1), *halves(2)])
    assert len(windows) == 1
    assert windows[0].move_ids == (0, 1, 2)  # the move itself was used once
    rej = w.pop_rejections()
    assert [r.move_id for r in rej] == [0, 0]
    assert all('duplicate move_id' in r.reason for r in rej)


def test_unpaired_half_expires_by_stamp_not_arrival() -> None:
    w = MoveWindower(window_size=50, pair_timeout=0.1)
    c0, _ = halves(0, stamp=0.0)
    feed(w, [c0])
    feed(w, list(halves(1, stamp=0.05)))
    assert w.pop_rejections() == []  # within the timeout
    feed(w, list(halves(2, stamp=0.2)))
    (r,) = w.pop_rejections()
    assert r.move_id == 0
    assert 'unpaired after 0.1 s' in r.reason
    assert 'encoder' in r.reason
    assert w.pending == 0
    w.expire(10.0)
    assert w.pop_rejections() == []


def test_time_jumping_back_and_staying_back_restarts_buffers() -> None:
    w = MoveWindower(window_size=4)
    feed(w, [*halves(0, stamp=10.0), *halves(1, stamp=10.006), *halves(2, stamp=10.012)])
    c3, _ = halves(3, stamp=10.018)
    feed(w, [c3])
    assert w.open_windows == 1
    # replay loops back to the start of the bag: same ids and stamps again; each topic's
    # halves are held apart until CONFIRM of them in a row agree on the new time
    loop = [h for i in range(CONFIRM) for h in halves(i, stamp=0.5 + 0.006 * i)]
    assert feed(w, loop[:-2]) == []
    assert w.resets == 0
    assert w.held == 2 * CONFIRM - 2
    assert w.pop_rejections() == []
    windows = feed(w, loop[-2:-1])  # the current topic's CONFIRM-th: the restart
    assert w.resets == 1
    rej = w.pop_rejections()
    assert sorted(r.move_id for r in rej) == [0, 1, 2, 3]
    assert all('time jumped back' in r.reason for r in rej)
    # the held halves of both topics are the new pass: no old move mixes in
    assert len(windows) == 1
    assert windows[0].move_ids == (0, 1, 2, 3)
    assert windows[0].first_stamp == pytest.approx(0.5)
    assert windows[0].last_stamp == pytest.approx(0.518)
    assert w.held == 0
    (last,) = feed(w, loop[-1:])
    assert last.move_ids == (4, 5, 6, 7)
    assert w.resets == 1
    assert w.pop_rejections() == []


def test_a_topic_arriving_seconds_late_loses_no_move() -> None:
    """One topic held up (its halves 2.5 s late, as behind 40 MB messages on the same topic)
    is not a jump back and not unpaired: each topic's stamps are judged against its own
    clock, and a half waits while its partner's topic lags behind (LATE_TOPIC)."""
    w = MoveWindower(window_size=10)
    moves = [halves(i, stamp=100.0 + 0.05 * i) for i in range(200)]  # 20 moves/s
    lag = 50  # the encoder topic 2.5 s behind the current topic
    items = []
    for i in range(200 + lag):
        if i < 200:
            items.append(moves[i][0])
        if i >= lag:
            items.append(moves[i - lag][1])
    windows = feed(w, items)
    assert w.pop_rejections() == []
    assert (w.resets, w.stale_halves, w.pending, w.held) == (0, 0, 0, 0)
    assert [x.move_ids for x in windows] == [tuple(range(k, k + 10)) for k in range(0, 200, 10)]
    assert w.topic_lag == pytest.approx(0.05 * lag)  # how late the encoder topic came, said
    in_step = MoveWindower(window_size=10)
    feed(in_step, [h for m in moves for h in m])
    assert in_step.topic_lag == 0.0


def test_a_topic_that_stops_leaves_its_partners_unpaired_after_late_topic() -> None:
    """Where the encoder topic stops, or never comes, the current halves wait until the
    current topic is LATE_TOPIC + 1 pair timeouts past them, and are then set aside as
    unpaired (each said); where it goes on without a move's half, one pair timeout after."""
    from galvo_sysid.monitor.pairing import LATE_TOPIC

    waited = (LATE_TOPIC + 1) * 0.5
    for first in (10, 0):  # the encoder stops after 10 moves; it never comes
        w = MoveWindower(window_size=1000, pair_timeout=0.5)
        feed(w, [h for i in range(first) for h in halves(i, stamp=0.1 * i)])
        assert w.pop_rejections() == []
        feed(w, [halves(i, stamp=0.1 * i)[0] for i in range(first, 200)])
        rej = w.pop_rejections()
        assert rej
        assert all('unpaired after 0.5 s: no encoder record' in r.reason for r in rej)
        assert max(r.stamp for r in rej) < 0.1 * 199 - waited + 1e-9
        assert w.pending == pytest.approx(waited / 0.1, abs=1.5)
    # the topic goes on without move 3's encoder half: unpaired one pair timeout after
    w = MoveWindower(window_size=1000, pair_timeout=0.5)
    feed(w, [h for i in range(20) for h in halves(i, stamp=0.1 * i)
             if (i, h.signal) != (3, 'encoder')])
    (r,) = w.pop_rejections()
    assert r.move_id == 3
    assert w.pending == 0


def test_reused_move_id_long_after_is_a_new_move() -> None:
    w = MoveWindower(window_size=2, pair_timeout=0.5)
    feed(w, [*halves(0, stamp=0.0), *halves(1, stamp=0.01)])
    later = [h for i in range(CONFIRM) for h in halves(i, stamp=5.0 + 0.01 * i)]
    # 5 s later: held apart until CONFIRM halves of each topic agree, then used
    windows = feed(w, later)
    assert [x.move_ids for x in windows] == [(i, i + 1) for i in range(0, CONFIRM, 2)]
    assert w.pop_rejections() == []


def test_memory_bounded_under_many_distinct_angles() -> None:
    w = MoveWindower(window_size=100, max_windows=16)
    for i in range(5000):
        feed(w, list(halves(i, angle=0.001 * (i + 1))))
        assert w.open_windows <= 16
    rej = w.pop_rejections()
    assert len(rej) == 5000 - 16
    assert all('window evicted' in r.reason for r in rej)
    assert w.moves_accepted == 16


def test_memory_bounded_when_encoder_never_comes() -> None:
    w = MoveWindower(window_size=100, max_pending=50, pair_timeout=1e9)
    for i in range(1000):
        c, _ = halves(i)
        w.add(c)
        assert w.pending <= 50
    rej = w.pop_rejections()
    assert len(rej) == 950
    assert 'evicted' in rej[0].reason


def test_memory_bounded_by_buffered_bytes() -> None:
    # windows get three quarters of the budget: here 1.5 windows of 100 moves
    budget = 4 * 16 * 100 * N // 2
    w = MoveWindower(window_size=100, max_buffered_bytes=budget, max_windows=64,
                     max_samples=N)
    for i in range(400):
        feed(w, list(halves(i, angle=0.3 * (1 + i % 4))))
        assert 8 * w.buffered_samples <= budget * 3 // 4
        assert w.buffered_bytes <= budget
    assert any('bytes in open windows' in r.reason for r in w.pop_rejections())
    assert w.windows_evicted > 0


def test_flush_hands_out_partial_windows_and_rejects_the_rest() -> None:
    w = MoveWindower(window_size=100)
    items = [h for i in range(10) for h in halves(i, 0.3)]
    items += [h for i in range(10, 12) for h in halves(i, 0.6)]
    items.append(halves(12, 0.9)[0])
    feed(w, items)
    windows = w.flush(min_moves=5)
    assert [(x.target_angle, x.moves, x.partial) for x in windows] == [(0.3, 10, True)]
    rej = w.pop_rejections()
    assert sorted(r.move_id for r in rej) == [10, 11, 12]
    assert w.open_windows == 0
    assert w.pending == 0


@pytest.mark.parametrize('kwargs', [
    {'window_size': 1}, {'window_size': -5}, {'pair_timeout': 0.0},
    {'pair_timeout': math.nan}, {'time_jump': -1.0}, {'samples': 10},
    {'min_samples': 0}, {'max_pending': 0}, {'max_buffered_bytes': 10},
    {'max_buffered_bytes': 100_000, 'max_samples': 10_000}, {'window_timeout': 0.0},
])
def test_bad_configuration(kwargs: dict) -> None:
    with pytest.raises(ConfigurationError):
        MoveWindower(**kwargs)


def test_summarize_rejections_groups_by_reason() -> None:
    w = MoveWindower(window_size=10)
    for i in range(8):
        c, e = halves(i)
        e = MoveHalf.create('encoder', move_id=i, target_angle=0.3, sample_period=DT,
                            stamp=e.stamp, data=np.full(N, np.nan))
        feed(w, [c, e])
    feed(w, [MoveHalf.create('current', move_id=99, target_angle=0.0, sample_period=DT,
                             stamp=1.0, data=np.ones(N))])
    lines = summarize_rejections(w.pop_rejections())
    assert lines == ['8 moves set aside (ids 0, 1, 2, 3, 4, ... 7; 0.3 deg): NaN or Inf in encoder',
                     '1 move set aside (id 99; 0 deg): zero target angle']


float_values = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                         st.sampled_from([0.0, 0.3, -0.3, 1e-5, -1e-5]))
arrays = st.one_of(
    st.integers(0, 80).map(lambda n: np.linspace(0.0, 1.0, n)),
    st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=70).map(np.array),
    st.just(np.zeros((3, 40))),
)
half_strategy = st.builds(
    MoveHalf.create, st.sampled_from(['current', 'encoder', 'current', 'encoder', 'x']),
    move_id=st.integers(-3, 12), target_angle=float_values, sample_period=float_values,
    stamp=st.one_of(st.floats(-10, 10), st.just(math.nan), st.just(math.inf)), data=arrays)


@settings(max_examples=300, deadline=None)
@given(st.lists(half_strategy, max_size=60))
def test_arbitrary_halves_never_raise_and_stay_bounded(items: list[MoveHalf]) -> None:
    w = MoveWindower(window_size=2, min_samples=4, max_samples=64, max_pending=5, max_windows=3,
                     max_buffered_bytes=4 * 16 * 64 * 3)
    for h in items:
        for win in w.add(h):
            assert win.current.shape == win.encoder.shape
            assert win.current.shape[0] == 2
            assert np.isfinite(win.current).all()
            assert np.isfinite(win.encoder).all()
            assert win.sample_period > 0
            assert abs(win.target_angle) > 0
        assert w.pending <= 5
        assert w.open_windows <= 3
        assert w.buffered_bytes <= 4 * 16 * 64 * 3
    for r in w.pop_rejections():
        assert isinstance(r.reason, str)
        assert r.reason
    w.flush(min_moves=1)
    summarize_rejections(w.pop_rejections())


def test_lost_messages_windows_complete_from_the_moves_that_arrived() -> None:
    # a best-effort link loses 10 % of the messages: every move missing a half is set aside
    # once (unpaired), the windows fill up with the complete moves
    rng = np.random.default_rng(7)
    w = MoveWindower(window_size=20, pair_timeout=0.05)
    windows = []
    lost = set()
    for i in range(120):
        for h in halves(i):
            if rng.random() < 0.1:
                lost.add(i)
                continue
            windows += w.add(h)
    w.expire(1e9)
    rej = w.pop_rejections()
    assert {r.move_id for r in rej} <= lost
    assert all('unpaired' in r.reason for r in rej)
    used = [m for win in windows for m in win.move_ids]
    assert not set(used) & lost
    assert len(used) == len(set(used))
    assert all(win.moves == 20 for win in windows)
    complete = 120 - len(lost)
    assert len(windows) == complete // 20  # one angle: one window per 20 complete moves
    assert w.moves_accepted == complete


def test_windower_parameters_are_the_sysid_nodes() -> None:
    import inspect

    from galvo_sysid.monitor.parameters import SYSID_PARAMETERS, WINDOWER_PARAMETERS

    declared = {p.name: p.default for p in SYSID_PARAMETERS}
    assert set(WINDOWER_PARAMETERS) <= set(declared)
    assert set(WINDOWER_PARAMETERS) <= set(inspect.signature(MoveWindower).parameters)
    defaults = MoveWindower()
    for name in WINDOWER_PARAMETERS:
        assert getattr(defaults, name) == declared[name], name


def test_moves_of_another_sample_period_than_the_models_are_set_aside_once_each() -> None:
    w = MoveWindower(window_size=3, sample_period=DT)
    items: list[MoveHalf] = []
    for i in range(3):
        items += halves(i)
    for i in range(3, 6):  # another scanner: 13.3 us
        c, e = halves(i, period=13.3e-6)
        items += [e, c] if i % 2 else [c, e]
    items += halves(6, period=DT * (1 + 1e-9))  # the same period up to rounding: used
    windows = feed(w, items)
    assert [x.move_ids for x in windows] == [(0, 1, 2)]
    rejections = w.pop_rejections()
    assert [r.move_id for r in rejections] == [3, 4, 5]  # one per move, partner silent
    reason = rejections[0].reason
    assert reason == "the data's sample period 1.33e-05 s differs from the model's 1e-05 s"
    assert {r.reason for r in rejections} == {reason}
    assert w.period_mismatch == reason
    assert w.moves_rejected == 3
    assert summarize_rejections(rejections) == [
        f'3 moves set aside (ids 3, 4, 5; 0.3 deg): {reason}']
    assert w.fill_levels() == {0.3: 1}  # move 6
    # without an expected period any period is taken (as before)
    free = MoveWindower(window_size=3)
    assert len(feed(free, [h for i in range(3) for h in halves(i, period=13.3e-6)])) == 1
    with pytest.raises(ConfigurationError, match='sample_period'):
        MoveWindower(sample_period=-1e-5)


# -- issue 12: one bad stamp, a short first move, a flood of angles, expiry, byte budget -------

def _stream(moves: int, *, angles: tuple[float, ...] = (0.3, -0.3, 1.5, -1.5), t0: float = 100.0,
            n: int = N) -> list[MoveHalf]:
    """Good moves, the angles in turn, stamps advancing (both halves, current first)."""
    return [h for i in range(moves)
            for h in halves(i, angles[i % len(angles)], stamp=t0 + i * MOVE_TIME, n=n)]


@pytest.mark.parametrize('stamp', [0.0, 1e6, 99.0, 103.0])
def test_one_stale_stamp_sets_aside_its_half_only(stamp: float) -> None:
    """Issue 12, defect 4: a half stamped far from the others (every 150th message) used to
    reset every buffer (0 windows); now only it is set aside, every window completes."""
    w = MoveWindower(window_size=20)
    items = _stream(160)
    bad = []
    for k, at in enumerate(range(150, len(items), 150)):
        stale = halves(10**9 + k, 0.3, stamp=stamp)[0]
        items.insert(at + k, stale)
        bad.append(stale.move_id)
    windows = feed(w, items)
    assert len(windows) == 160 // 20  # every good move in a full window
    assert sorted(m for x in windows for m in x.move_ids) == list(range(160))
    rej = w.pop_rejections()
    assert sorted(r.move_id for r in rej) == bad
    where = 'behind' if stamp < 100 else 'ahead of'
    assert {r.reason for r in rej} == {
        f'stamp more than 1 s {where} the data clock (set aside alone)'}
    assert w.resets == 0
    assert w.stale_halves == len(bad)
    assert w.held == 0


def test_a_pair_of_stale_halves_and_a_stale_partner_are_set_aside_once() -> None:
    w = MoveWindower(window_size=10)
    items = _stream(40, angles=(0.3,))
    c, e = halves(500, 0.3, stamp=3.0)  # both halves of one move stamped 97 s early
    items[20:20] = [c, e]
    lone_good_partner = halves(501, 0.3, stamp=100.1)[1]
    items[30:30] = [lone_good_partner, halves(501, 0.3, stamp=2.0)[0]]  # its current: stale
    windows = feed(w, items)
    assert len(windows) == 4
    rej = w.pop_rejections()
    assert sorted(r.move_id for r in rej) == [500, 501]  # one rejection per move
    assert w.resets == 0
    assert w.pending == 0


def test_a_stale_flood_interleaved_never_moves_the_clock() -> None:
    # as many stale halves as good ones, in turn: none is ever CONFIRM in a row
    w = MoveWindower(window_size=10)
    items = []
    for k, h in enumerate(_stream(60, angles=(0.3,))):
        items.append(h)
        items.append(halves(10**6 + k, 0.3, stamp=5.0 + 1e-3 * k)[k % 2])
    windows = feed(w, items)
    assert [x.moves for x in windows] == [10] * 6
    assert w.resets == 0
    assert w.stale_halves == 120 - w.held


def test_a_pause_moves_the_clock_forward_without_losing_a_move() -> None:
    w = MoveWindower(window_size=10)
    items = _stream(15, angles=(0.3,)) + [
        h for i in range(15, 30) for h in halves(i, 0.3, stamp=200.0 + i * MOVE_TIME)]
    windows = feed(w, items)  # 100 s later: held until CONFIRM halves agree, then used
    assert [x.move_ids for x in windows] == [tuple(range(k, k + 10)) for k in (0, 10, 20)]
    assert w.pop_rejections() == []
    assert w.resets == 0


def test_short_first_move_does_not_block_its_angle() -> None:
    """Issue 12, defect 8: a 40-sample first move used to fix its window's length, and the
    99 good moves of its angle were set aside ("record has 512 samples, the window 40")."""
    w = MoveWindower(window_size=25, min_samples=32)
    items = [*halves(10**6, 0.3, stamp=99.0, n=40), *_stream(200, n=512)]
    windows = feed(w, items)
    assert sorted(x.target_angle for x in windows) == sorted([0.3, -0.3, 1.5, -1.5] * 2)
    assert all(x.current.shape == (25, 512) for x in windows)
    assert w.pop_rejections() == []
    assert w.fill_levels() == {0.3: 1}  # the short move waits in a window of its own
    leftovers = w.flush(min_moves=2)
    assert leftovers == []
    (r,) = w.pop_rejections()
    assert r.move_id == 10**6
    assert 'incomplete at end of data' in r.reason


def test_flood_of_distinct_angles_does_not_starve_filling_angles() -> None:
    """Issue 12, defect 9: 20 moves of distinct target angles per good move used to evict
    every good window before it completed (0 of 45); windows not filling go first now."""
    w = MoveWindower(window_size=25, max_windows=64)
    windows = []
    flood_id = 10**6
    for i, h in enumerate(_stream(400)):
        windows += w.add(h)
        if i % 2:
            for _ in range(20):
                flood_id += 1
                angle = 0.3 + 1e-3 * (flood_id % 100_000) + 1e-5
                for f in halves(flood_id, angle, stamp=h.stamp):
                    windows += w.add(f)
                assert w.open_windows <= 64
    good = [x for x in windows if x.target_angle in (0.3, -0.3, 1.5, -1.5)]
    # 100 moves per angle, the first of each lost to the flood: 3 full windows per angle
    assert len(good) == len(windows) == 4 * 3
    assert all(x.moves == 25 for x in good)
    assert w.fill_levels()[0.3] == 24
    rej = w.pop_rejections()
    assert {r.reason for r in rej} == {'window evicted: more than 64 open windows'}
    assert sorted(r.move_id for r in rej if r.move_id < 10**6) == [0, 1, 2, 3]


def test_filling_windows_compete_by_last_progress() -> None:
    # more filling angles than max_windows: the least recently progressing one goes
    w = MoveWindower(window_size=10, max_windows=2)
    feed(w, [*halves(0, 0.3), *halves(1, 0.3), *halves(2, 0.6), *halves(3, 0.6)])
    # a new angle's first move goes first (not filling yet); when it comes again it fills
    # and the least recently progressing angle (0.6) goes
    feed(w, [*halves(4, 0.3), *halves(5, 0.9), *halves(6, 0.9)])
    assert w.fill_levels() == {0.3: 3, 0.9: 1}
    assert [r.move_id for r in w.pop_rejections()] == [5, 2, 3]


def test_a_window_not_complete_in_time_expires() -> None:
    w = MoveWindower(window_size=10, window_timeout=0.5)
    feed(w, [*halves(0, 0.9, stamp=100.0), *halves(1, 0.9, stamp=100.1)])
    feed(w, [h for i in range(2, 90) for h in halves(i, 0.3, stamp=100.0 + 0.01 * i)])
    assert 0.9 not in w.fill_levels()
    assert w.windows_expired == 1
    expired = [r for r in w.pop_rejections() if 'expired' in r.reason]
    assert sorted(r.move_id for r in expired) == [0, 1]
    assert expired[0].reason == 'window expired: not complete 0.5 s after its first move'


def test_byte_budget_bounds_waiting_halves_and_windows() -> None:
    budget = 4 * 16 * 10 * N  # a quarter (40 records of N samples) for halves waiting
    w = MoveWindower(window_size=10, max_samples=4 * N, max_buffered_bytes=budget,
                     max_pending=10_000, pair_timeout=1e6)
    rng = np.random.default_rng(3)
    for i in range(2000):
        kind = rng.integers(0, 3)
        angle = float(rng.choice([0.3, 0.6, 0.9, 1.2, 1.5]))
        if kind == 0:  # a lone half of the largest size (its partner never comes)
            w.add(halves(10**6 + i, angle, stamp=100.0 + 1e-4 * i, n=4 * N)[0])
        else:
            feed(w, list(halves(i, angle, stamp=100.0 + 1e-4 * i)))
        assert w.buffered_bytes <= budget
        assert 16 * N * sum(w.fill_levels().values()) <= budget - budget // 4
    reasons = {r.reason for r in w.pop_rejections()}
    assert f'unpaired: evicted, more than {budget // 4} bytes of halves waiting' in reasons
    assert w.halves_evicted > 0


def test_refused_half_is_set_aside_with_its_partner_once() -> None:
    w = MoveWindower(window_size=2)
    c, e = halves(7)
    w.refuse(MoveHalf.create('current', move_id=7, target_angle=0.3, sample_period=DT,
                             stamp=c.stamp, data=np.zeros(0)), 'current record too long')
    assert feed(w, [e, *halves(8), *halves(9)])[0].move_ids == (8, 9)
    (r,) = w.pop_rejections()
    assert (r.move_id, r.reason) == (7, 'current record too long')
    assert w.refused_halves == 1
    assert w.pending == 0


def test_counters_start_at_zero_and_count_every_rejection_once() -> None:
    """The counters the sysid node reports (moves_rejected, halves_evicted, windows_evicted)
    start at 0 and move by one per event; moves_rejected equals the rejections said."""
    w = MoveWindower(window_size=3, max_pending=2, max_windows=1)
    counters = ('moves_rejected', 'moves_accepted', 'halves_evicted', 'windows_evicted',
                'windows_expired', 'refused_halves', 'stale_halves', 'period_mismatches',
                'resets')
    assert {c: getattr(w, c) for c in counters} == dict.fromkeys(counters, 0)
    said = []
    feed(w, list(halves(-1)))  # a negative move_id: each half set aside alone
    said += w.pop_rejections()
    assert [r.reason for r in said] == ['negative move_id'] * 2
    assert w.moves_rejected == 2
    feed(w, [halves(i)[0] for i in range(1, 5)])  # 4 unpaired currents, room for 2
    new = w.pop_rejections()
    assert [(r.move_id, r.reason) for r in new] == [
        (1, 'unpaired: evicted, more than 2 halves waiting'),
        (2, 'unpaired: evicted, more than 2 halves waiting')]
    assert (w.halves_evicted, w.moves_rejected) == (2, 4)
    said += new
    c3, e3 = halves(3)
    feed(w, [e3, c3])  # the current of move 3 again: a duplicate, said once
    new = w.pop_rejections()
    assert [r.reason for r in new] == ['duplicate move_id (current seen twice)']
    assert w.moves_rejected == 5
    said += new
    feed(w, [halves(4)[1], *halves(5, -0.3)])  # room for one window: one is evicted
    new = w.pop_rejections()
    assert [(r.move_id, r.reason.split(':')[0]) for r in new] == [(5, 'window evicted')]
    assert (w.windows_evicted, w.moves_accepted) == (1, 2)
    said += new
    assert w.moves_rejected == len(said) == 6


def test_flush_uses_halves_held_ahead_and_sets_aside_contradicted_ones() -> None:
    """At the end of data, the halves each topic held apart for a stamp ahead of its clock,
    which nothing contradicted (the data moved on at the very end), are used; a stale move
    that halves in time contradicted is set aside, said once."""
    w = MoveWindower(window_size=100)
    feed(w, [h for i in range(5) for h in halves(i, stamp=10.0 + 0.01 * i)])
    feed(w, [h for i in range(5, 8) for h in halves(i, stamp=20.0 + 0.01 * i)])  # after a pause
    assert w.held == 6  # fewer than CONFIRM of each topic: not confirmed yet
    (win,) = w.flush(min_moves=2)
    assert win.move_ids == tuple(range(8))
    assert w.pop_rejections() == []

    w = MoveWindower(window_size=100)
    feed(w, [h for i in range(5) for h in halves(i, stamp=10.0 + 0.01 * i)])
    feed(w, list(halves(5, stamp=0.0)))  # a stale move
    feed(w, [h for i in range(6, 8) for h in halves(i, stamp=10.0 + 0.01 * i)])  # in time
    assert w.held == 2
    (win,) = w.flush(min_moves=2)
    assert win.move_ids == (0, 1, 2, 3, 4, 6, 7)
    (r,) = w.pop_rejections()
    assert r.move_id == 5
    assert 'behind the data clock' in r.reason
