"""Pairing of move halves and windows per target angle (galvo_sysid.monitor.pairing)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from galvo_sysid.monitor.moves import MoveHalf
from galvo_sysid.monitor.pairing import CONFIRM, MoveWindower

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
