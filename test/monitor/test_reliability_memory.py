"""Memory stays bounded under hostile input (issue 7, "Bad input").

- 100,000 moves with distinct target angles through the sysid node's logic (SysidTask, default
  windower limits): at most ``max_windows`` open windows, every eviction set aside and said
  (rate-limited), allocations flat once the cap is reached;
- a publisher that never sends the encoder half (100,000 current halves), with stamps
  advancing (halves expire after ``pair_timeout``) and with a frozen stamp (the
  ``max_pending`` cap evicts the oldest): pending halves capped, each said once;
- records of the largest accepted size: ``max_buffered_bytes`` caps the bytes held;
- the real sysid node over DDS flooded with distinct angles and lone current halves: its
  counters stay within the caps, its resident memory does not grow with the flood, evictions
  are logged, and a good window sent afterwards is identified from all its moves.
"""

from __future__ import annotations

import math
import time
import tracemalloc
from typing import TYPE_CHECKING

import numpy as np
import pytest
from galvo_sysid_msgs.msg import ModalParameters, MoveSamples
from ros_graph import MOVES_QOS, RESULTS_QOS, Graph, counters, move_messages, rss_kib, wait_matched

from galvo_sysid.errors import InvalidDataError
from galvo_sysid.interfaces.messages import fill, fill_header, move_samples_fields
from galvo_sysid.model import REFERENCE_MODEL
from galvo_sysid.monitor.moves import MoveHalf
from galvo_sysid.monitor.pairing import LATE_TOPIC, MoveWindower
from galvo_sysid.monitor.scheduler import FitOutcome
from galvo_sysid.monitor.tasks import SysidTask
from galvo_sysid.sim.simulator import GalvoSimulator

if TYPE_CHECKING:
    from collections.abc import Iterator

    from galvo_sysid.ident.result import IdentificationResult
    from galvo_sysid.monitor.moves import Window

N = 512
DT = 1e-5
MOVE_TIME = 0.00606
BASE = np.arange(N, dtype=float)


def _no_fit(window: Window) -> IdentificationResult:
    raise InvalidDataError('not fitted in this test')


class Sink:
    """Collects warning lines (what the node would log)."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def __call__(self, line: str) -> None:
        self.lines.append(line)


def _distinct_angle_moves(start: int, stop: int) -> Iterator[tuple[MoveHalf, MoveHalf]]:
    for i in range(start, stop):
        angle = 1e-3 * (i + 1) * (1 if i % 2 else -1)  # 100,000 distinct signed angles
        stamp = 100.0 + i * MOVE_TIME
        yield (MoveHalf('current', i, angle, DT, stamp, BASE + i),
               MoveHalf('encoder', i, angle, DT, stamp, BASE - i))


def test_100000_distinct_target_angles_stay_capped() -> None:
    sink = Sink()
    outcomes: list[FitOutcome] = []
    task = SysidTask(_no_fit, outcomes.append, warn=sink, warnings_per_second=20)
    cap = task.windower.max_windows
    total = 100_000
    try:
        for cur, enc in _distinct_angle_moves(0, total):
            task.add(cur)
            task.add(enc)
            assert task.windower.open_windows <= cap
        stats = task.stats()
        assert stats['open_windows'] == cap
        assert stats['moves_accepted'] == cap  # only the moves still buffered
        assert stats['moves_rejected'] == total - cap  # every evicted move set aside
        assert stats['windows_completed'] == 0
        assert task.windower.buffered_samples == 2 * N * cap
        assert task.windower.pending == 0
        # said, and said in bounded volume: the warnings are rate limited and summed up
        evicted = [x for x in sink.lines if f'window evicted: more than {cap} open windows' in x]
        assert evicted
        assert len(sink.lines) < 1000

        # allocations are flat once the caps are reached: 20,000 more moves traced, the first
        # 10,000 to renew every bounded store (the recent move_ids: 4 max_pending), then
        # compared with the next 10,000
        tracemalloc.start()
        try:
            more = _distinct_angle_moves(total, total + 20_000)
            for k, (cur, enc) in enumerate(more):
                task.add(cur)
                task.add(enc)
                if k == 10_000:
                    before = tracemalloc.get_traced_memory()[0]
            after = tracemalloc.get_traced_memory()[0]
        finally:
            tracemalloc.stop()
        one_window = 2 * N * 8
        assert after - before < 20 * one_window, (before, after)
    finally:
        task.close(timeout=5.0)
    assert outcomes == []


@pytest.mark.parametrize('stamps', ['advancing', 'frozen'])
def test_encoder_half_never_sent(stamps: str) -> None:
    w = MoveWindower()
    total = 100_000
    said: dict[int, int] = {}
    reasons: set[str] = set()
    for i in range(total):
        stamp = 100.0 + (i * MOVE_TIME if stamps == 'advancing' else 0.0)
        w.add(MoveHalf('current', i, 0.3, DT, stamp, BASE))
        assert w.pending <= w.max_pending
        for r in w.pop_rejections():
            said[r.move_id] = said.get(r.move_id, 0) + 1
            reasons.add(r.reason.split(' ')[0] + ' ' + r.reason.split(' ')[1])
    if stamps == 'advancing':  # stamps say the partner is late: set aside after LATE_TOPIC + 1
        # pair timeouts by the current topic's own clock (the encoder topic has not come)
        assert w.pending <= math.ceil((LATE_TOPIC + 1) * w.pair_timeout / MOVE_TIME) + 1
        assert reasons == {'unpaired after'}
    else:  # no time passes by the stamps: the max_pending cap evicts the oldest
        assert w.pending == w.max_pending
        assert reasons == {'unpaired: evicted,'}
    assert len(said) == total - w.pending
    assert set(said.values()) == {1}  # each said once
    w.flush()
    assert len(w.pop_rejections()) == w.max_pending if stamps == 'frozen' else True


def test_largest_records_are_capped_by_buffered_bytes() -> None:
    big = 65536
    budget = 4 * 16 * big * 10  # open windows: 30 moves of the largest records
    w = MoveWindower(window_size=100, max_buffered_bytes=budget)
    data = np.zeros(big)
    for i in range(60):
        angle = 0.3 * (1 + i % 3)
        w.add(MoveHalf('current', i, angle, DT, 100.0 + i * 0.7, data))
        w.add(MoveHalf('encoder', i, angle, DT, 100.0 + i * 0.7, data))
        assert w.buffered_bytes <= budget
    reasons = {r.reason for r in w.pop_rejections()}
    assert any('bytes in open windows' in r for r in reasons), reasons


# -- the real node over DDS --------------------------------------------------------------


def test_sysid_node_memory_bounded_under_a_hostile_flood(graph: Graph) -> None:
    ns = '/hostile'
    max_windows, max_pending = 16, 50
    results: list[ModalParameters] = []
    graph.node.create_subscription(ModalParameters, f'{ns}/galvo/modal_parameters',
                                   results.append, RESULTS_QOS)
    pubs = {s: graph.node.create_publisher(MoveSamples, f'{ns}/galvo/{s}', MOVES_QOS)
            for s in ('current', 'encoder')}
    sysid = graph.start('sysid', 'sysid', '-r', f'__ns:={ns}', '-p', 'window_size:=10',
                        '-p', f'max_windows:={max_windows}', '-p', f'max_pending:={max_pending}',
                        '-p', 'fit_processes:=0', '-p', 'stats_period:=0.5',
                        '-p', 'pair_timeout:=0.5')
    wait_matched(graph, pubs.values())
    graph.spin_until(lambda: len(counters(sysid.text())) >= 1, 20, 'first counters')
    rss_start = rss_kib(sysid.pid)

    # the flood: 3,000 moves of distinct angles and 3,000 lone current halves, 512 samples
    # each (9,000 messages, 37 MB of samples if all were kept), stamps frozen so that the
    # lone halves are only ever evicted by the cap; paced at about 2,000 messages/s
    msgs = {s: fill(MoveSamples(), move_samples_fields(
        move_id=0, target_angle=0.1, sample_period=DT, data=BASE)) for s in pubs}
    flood = 3000
    start = time.monotonic()
    for i in range(flood):
        for s, pub in pubs.items():
            msg = msgs[s]
            msg.move_id = i
            msg.target_angle = 1e-3 * (i + 1)
            fill_header(msg, stamp=100.0)
            pub.publish(msg)
        lone = msgs['current']
        lone.move_id = 10_000_000 + i
        pubs['current'].publish(lone)
        if i % 50 == 0:
            graph.spin_for(max(0.0, start + 3 * i / 2000 - time.monotonic()))

    def settled() -> bool:  # two counter lines in a row with nothing new
        c = counters(sysid.text())
        return len(c) >= 3 and c[-1]['halves_received'] == c[-2]['halves_received'] > 0
    graph.spin_until(settled, 60, 'the node to take the whole flood')
    rss_end = rss_kib(sysid.pid)
    seen = counters(sysid.text())
    assert max(c['open_windows'] for c in seen) <= max_windows
    assert max(c['pending_halves'] for c in seen) <= max_pending
    last = seen[-1]
    assert last['moves_accepted'] <= max_windows
    received = last['halves_received']
    assert received > 0.9 * 3 * flood  # (reliable, paced: normally all of them)
    assert last['moves_rejected'] >= received // 3 * 2 - max_windows - max_pending
    log = sysid.text()
    assert f'window evicted: more than {max_windows} open windows' in log
    assert f'unpaired: evicted, more than {max_pending} halves waiting' in log
    # memory: what the caps allow, not what the flood carried (61 MB)
    assert rss_end - rss_start < 30 * 1024, (rss_start, rss_end)

    # nothing else is lost: a good window afterwards is identified from all its moves
    good = move_messages(GalvoSimulator(seed=4).moves(angles=[0.9], moves_per_angle=20),
                         t0=200.0)
    for s, msg in good:
        pubs[s].publish(msg)
    graph.spin_until(lambda: len(results) >= 2, 30, 'the two good windows')
    assert sorted(m.target_angle for m in results) == [-0.9, 0.9]
    assert all(m.moves == 10 for m in results)
    for m in results:
        rel = m.natural_frequencies[0] / REFERENCE_MODEL.natural_frequencies[0] - 1
        assert abs(rel) < 0.003
    assert sysid.running
    assert 'Traceback' not in log
    print(f'sysid RSS {rss_start / 1024:.1f} -> {rss_end / 1024:.1f} MiB over a '
          f'{3 * flood}-message flood; counters {last}')
