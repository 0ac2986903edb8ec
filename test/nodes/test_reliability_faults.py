"""Faults over real DDS, the nodes as child processes (issue 7, "Faults" and "Parameters").

- The driver stops (hangs with SIGSTOP, later exits): the watchdog's /diagnostics turn STALE
  ``stale_timeout`` after the last result, and OK again when data returns (SIGCONT, or a new
  driver).
- sysid is killed (SIGKILL) mid-window and restarted: its fit processes do not outlive it,
  it resumes, and the windows after the restart hold only moves sent after it (their last
  stamps are those of the restart's 10th moves; the plant before the crash had omega_1 3 %
  lower, which a mixed window would show).
- Messages lost (single halves dropped at random and a gap of whole moves), over a reliable
  and over a best-effort link (sysid ``qos_reliability:=best_effort``): every window still
  has ``window_size`` moves, exactly the windows the moves that arrived make (the same
  :class:`~galvo_sysid.monitor.pairing.MoveWindower` run offline on them); each half without partner
  is counted as set aside. (A best-effort writer can match before the reader knows it, so
  the first messages may be lost even on localhost: the test probes first.)
- A replay looping back in time (the same move_ids and stamps again): buffers reset once,
  the windows after the loop close at their own 10th move (a stale mix would close at the 5th).
- Invalid parameters (negative or too small window size, ARX orders out of range,
  tolerance <= 0, ...) are rejected by the nodes' parameter callbacks with a reason naming
  the parameter; the old values stay; a valid change is still accepted afterwards.
"""

from __future__ import annotations

import array
import math
import signal
import time
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from galvo_sysid_msgs.msg import DriftStatus, ModalParameters, MoveSamples
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from ros_graph import (
    MOVES_QOS,
    RESULTS_QOS,
    Graph,
    alive,
    counters,
    move_messages,
    subscriber_ids,
    wait_matched,
    wait_new_subscribers,
)

from galvo_sysid.interfaces.messages import fill_header, move_half_from_msg, stamp_to_seconds
from galvo_sysid.model import REFERENCE_MODEL, StepChange
from galvo_sysid.monitor.pairing import MoveWindower
from galvo_sysid.sim.simulator import GalvoSimulator

if TYPE_CHECKING:
    pass

OMEGA_1 = REFERENCE_MODEL.natural_frequencies[0]



class Results:
    """ModalParameters of one namespace, with their arrival times."""

    def __init__(self, graph: Graph, ns: str) -> None:
        self.items: list[tuple[float, ModalParameters]] = []
        graph.node.create_subscription(ModalParameters, f'{ns}/galvo/modal_parameters',
                                       self._on, RESULTS_QOS)

    def _on(self, msg: ModalParameters) -> None:
        self.items.append((time.monotonic(), msg))

    def __len__(self) -> int:
        return len(self.items)

    @property
    def msgs(self) -> list[ModalParameters]:
        return [m for _, m in self.items]


def _publishers(graph: Graph, ns: str) -> dict[str, Any]:
    return {s: graph.node.create_publisher(MoveSamples, f'{ns}/galvo/{s}', MOVES_QOS)
            for s in ('current', 'encoder')}


def _publish(pubs: dict[str, Any], msgs: list[tuple[str, MoveSamples]]) -> None:
    for s, m in msgs:
        pubs[s].publish(m)


def _sysid(graph: Graph, ns: str, name: str, *extra: str) -> Any:
    return graph.start('sysid', name, '-r', f'__ns:={ns}', '-p', 'stats_period:=0.5',
                       '-p', 'diagnostics_period:=0.0', *extra)


# -- the driver stops ----------------------------------------------------------------------

def test_driver_stops_watchdog_goes_stale_and_recovers(graph: Graph) -> None:
    ns, scanner = '/fault_stale', 'fault_stale'
    stale_timeout = 1.5
    results = Results(graph, ns)
    diags: list[tuple[float, int]] = []
    verdicts: list[DriftStatus] = []

    def on_diag(msg: DiagnosticArray) -> None:
        for s in msg.status:
            if s.hardware_id == scanner and s.name.endswith('plant drift'):
                diags.append((time.monotonic(), int.from_bytes(s.level, 'little')))

    graph.node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 100)
    graph.node.create_subscription(DriftStatus, f'{ns}/galvo/drift', verdicts.append,
                                   RESULTS_QOS)
    remap = f'__ns:={ns}'
    _sysid(graph, ns, 'sysid', '-p', 'window_size:=20', '-p', 'fit_processes:=0')
    graph.start('watchdog', 'watchdog', '-r', remap, '-p', f'stale_timeout:={stale_timeout}',
                '-p', 'publish_rate:=10.0')
    driver_args = ('-r', remap, '-p', 'angles:=[0.9]', '-p', 'moves_per_angle:=40',
                   '-p', 'seed:=7')
    driver = graph.start('galvo_driver', 'driver1', *driver_args)

    def level() -> int:
        return diags[-1][1] if diags else -1

    try:
        graph.spin_until(lambda: level() == 0 and len(results) >= 2, 60, 'diagnostics OK')

        # 1. the driver hangs: STALE stale_timeout after the last result
        driver.popen.send_signal(signal.SIGSTOP)
        t_stale = graph.spin_until(lambda: level() == 3, 3 * stale_timeout + 5, 'STALE')
        last_result = results.items[-1][0]
        print(f'driver hung: STALE {t_stale - last_result:.2f} s after the last result '
              f'(stale_timeout {stale_timeout} s)')
        assert stale_timeout - 0.3 < t_stale - last_result < stale_timeout + 1.2
        graph.spin_until(lambda: verdicts[-1].level == DriftStatus.STALE, 5, 'DriftStatus STALE')
        n = len(results)

        # 2. it resumes: OK again with the next result
        driver.popen.send_signal(signal.SIGCONT)
        t_cont = time.monotonic()
        t_ok = graph.spin_until(lambda: len(results) > n and level() == 0, 20,
                                'OK after resuming')
        print(f'driver resumed: OK again after {t_ok - t_cont:.2f} s')
    finally:
        driver.popen.send_signal(signal.SIGCONT)

    # 3. the driver exits: STALE again; 4. a new driver: OK again
    assert driver.stop() == 0
    t_stop = time.monotonic()
    t_stale = graph.spin_until(lambda: level() == 3, 3 * stale_timeout + 5, 'STALE again')
    assert t_stale - t_stop < stale_timeout + 1.0
    n = len(results)
    t_new = time.monotonic()
    graph.start('galvo_driver', 'driver2', *driver_args)
    t_ok = graph.spin_until(lambda: len(results) > n and level() == 0, 30,
                            'OK with a new driver')
    print(f'driver exited: STALE after {t_stale - t_stop:.2f} s; a new driver process: OK '
          f'again after {t_ok - t_new:.2f} s (process start and discovery included)')
    for m in results.msgs:
        assert m.moves == 20
        assert abs(m.natural_frequencies[0] / OMEGA_1 - 1) < 0.003
    assert 'Traceback' not in graph.logs(100_000)


# -- sysid killed and restarted --------------------------------------------------------------

def _stamp(msg: Any) -> float:
    return stamp_to_seconds(msg.header.stamp)


def test_sysid_killed_mid_window_restarts_without_mixing(graph: Graph) -> None:
    ns = '/fault_restart'
    results = Results(graph, ns)
    pubs = _publishers(graph, ns)
    args = ('-p', 'window_size:=10', '-p', 'pair_timeout:=0.5')  # default: 2 fit processes
    sysid = _sysid(graph, ns, 'sysid1', *args)

    # before the crash the plant's omega_1 is 3 % low; after it, nominal
    before = GalvoSimulator(seed=21)
    before.add_step(StepChange(parameter='omega_1', value=0.97, at=0, relative=True))
    phase1 = move_messages(before.moves(angles=[0.9], moves_per_angle=36), t0=500.0)
    sent1, lost = phase1[:60], phase1[60:]  # 15 moves per sign sent, then 3 more while down
    after = GalvoSimulator(seed=22)
    t0 = _stamp(phase1[-1][1]) + 0.01
    phase2 = move_messages(after.moves(angles=[0.9], moves_per_angle=30), t0=t0)
    for i, (_, msg) in enumerate(phase2):
        msg.move_id = 1000 + i // 2  # the driver's numbering goes on

    wait_matched(graph, pubs.values())
    _publish(pubs, sent1)
    graph.spin_until(lambda: len(results) >= 2, 30, 'the first two windows')
    graph.spin_until(lambda: sysid.note_children() != [] and counters(sysid.text()) != []
                     and counters(sysid.text())[-1]['moves_accepted'] == 30, 10,
                     'the 10 moves of the open windows buffered')
    assert counters(sysid.text())[-1]['open_windows'] == 2
    for m in results.msgs:
        assert m.natural_frequencies[0] / OMEGA_1 == pytest.approx(0.97, abs=0.003)

    sysid.kill()  # mid-window: 5 moves of each sign buffered
    fit_children = sorted(sysid.known_children)
    assert fit_children
    graph.spin_until(lambda: not any(alive(p) for p in fit_children), 15,
                     'the fit processes to end with their parent')
    _publish(pubs, lost)  # nobody listens
    topics = [f'{ns}/galvo/current', f'{ns}/galvo/encoder']
    dead = {t: subscriber_ids(graph, t) for t in topics}  # still listed until their lease ends
    sysid2 = _sysid(graph, ns, 'sysid2', *args)
    wait_new_subscribers(graph, topics, dead)
    n = len(results)
    _publish(pubs, phase2)
    graph.spin_until(lambda: len(results) >= n + 2, 30, 'two windows after the restart')
    graph.spin_for(1.0)  # nothing more may come
    new = results.msgs[n:]
    assert len(new) == 2
    # the windows close at the 10th move of each sign sent after the restart
    tenth = {}
    for sign in (1, -1):
        halves = [m for s, m in phase2 if s == 'current' and math.copysign(1, m.target_angle)
                  == sign]
        tenth[sign] = _stamp(halves[9])
    for m in new:
        assert m.moves == 10
        assert sorted({int(x.window_index) for x in new}) == [0, 1]  # a fresh process
        assert _stamp(m) == pytest.approx(tenth[int(math.copysign(1, m.target_angle))],
                                          abs=1e-6)
        assert abs(m.natural_frequencies[0] / OMEGA_1 - 1) < 0.003  # no crashed-plant moves
    assert sysid2.running
    assert 'Traceback' not in sysid2.text()


# -- messages lost ---------------------------------------------------------------------------

@pytest.mark.parametrize('reliability', ['reliable', 'best_effort'])
def test_lost_messages_windows_complete_from_what_arrived(graph: Graph,
                                                          reliability: str) -> None:
    ns = f'/fault_loss_{reliability}'
    window_size = 8
    results = Results(graph, ns)
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE
                     if reliability == 'reliable' else ReliabilityPolicy.BEST_EFFORT)
    pubs = {s: graph.node.create_publisher(MoveSamples, f'{ns}/galvo/{s}', qos)
            for s in ('current', 'encoder')}
    sysid = _sysid(graph, ns, 'sysid', '-p', f'window_size:={window_size}',
                   '-p', 'fit_processes:=0', '-p', 'pair_timeout:=0.5',
                   '-p', f'qos_reliability:={reliability}')
    msgs = move_messages(GalvoSimulator(seed=31).moves(angles=[0.9], moves_per_angle=70),
                         t0=700.0)
    rng = np.random.default_rng(5)
    sent = []
    for i, (s, m) in enumerate(msgs):
        move = i // 2
        if 20 <= move < 30:
            continue  # a gap: ten whole moves never arrive
        if rng.random() < 0.08:
            continue  # a single half lost
        sent.append((s, m))
    # what the moves that arrived make, offline
    offline = MoveWindower(window_size=window_size, pair_timeout=0.5)
    expected = []
    for s, m in sent:
        expected += offline.add(move_half_from_msg(m, signal=s))
    offline.expire(math.inf)
    unpaired = len(offline.pop_rejections())
    assert unpaired >= 2  # the random drops did orphan some halves
    assert len(expected) >= 4

    wait_matched(graph, pubs.values())
    # A best-effort writer may match before the reader knows it: the first messages can be
    # lost even on localhost. Probe until the node has received something (zero-angle halves,
    # each set aside once and counted), then send the stream.
    probe = move_message_zero_angle()
    probes = 0

    def probed() -> bool:
        nonlocal probes
        c = counters(sysid.text())
        if c and c[-1]['halves_received'] > 0:
            return True
        probe.move_id = 9_000_000 + probes
        pubs['current'].publish(probe)
        probes += 1
        graph.spin_for(0.05)
        return False
    graph.spin_until(probed, 20, 'the node to receive a probe')
    graph.spin_for(0.6)  # the probes in flight arrive and are counted
    before = counters(sysid.text())[-1]['halves_received']
    for s, m in sent:
        pubs[s].publish(m)
        graph.spin_for(0.0005)  # about 1,000 messages/s: a best-effort link keeps up

    def all_said() -> bool:  # every half received is used, set aside or (none) waiting
        c = counters(sysid.text())
        return len(c) >= 2 and c[-1]['pending_halves'] == 0 and \
            c[-1]['halves_received'] > before and c[-1] == c[-2]
    graph.spin_until(all_said, 30, 'every orphaned half set aside')
    last = counters(sysid.text())[-1]
    received = last['halves_received'] - before
    if received == len(sent):
        graph.spin_until(lambda: len(results) >= len(expected), 30, 'the complete windows')
    graph.spin_for(0.5)  # and no more
    got = sorted((round(m.target_angle, 6), round(_stamp(m), 6), m.moves) for m in results.msgs)
    want = sorted((round(w.target_angle, 6), round(w.last_stamp, 6), w.moves) for w in expected)
    assert all(m.moves == window_size for m in results.msgs)
    assert 'unpaired' in sysid.text(), sysid.text()[-3000:]
    if received == len(sent):  # the link itself lost nothing (the rule here)
        assert got == want
        assert last['moves_rejected'] == unpaired + before  # the probes are set aside too
    else:  # a best-effort link lost some more: windows complete from what arrived
        assert reliability == 'best_effort', last
        lost = len(sent) - received
        assert len(want) - lost <= len(got) <= len(want)


def move_message_zero_angle() -> MoveSamples:
    """A current half of zero target angle: the node sets it aside and counts it."""
    msg = MoveSamples()
    msg.target_angle = 0.0
    msg.sample_period = 1e-5
    msg.data = array.array('d', [0.0] * 64)
    fill_header(msg, stamp=1.0)
    return msg


# -- a replay looping back --------------------------------------------------------------------

def test_replay_looping_back_resets_without_stale_mix(graph: Graph) -> None:
    ns = '/fault_loop'
    results = Results(graph, ns)
    pubs = _publishers(graph, ns)
    sysid = _sysid(graph, ns, 'sysid', '-p', 'window_size:=10', '-p', 'fit_processes:=0',
                   '-p', 'time_jump:=0.1')
    one_pass = move_messages(GalvoSimulator(seed=41).moves(angles=[0.9], moves_per_angle=30),
                             t0=900.0)  # 15 moves per sign: one window each + 5 left over
    tenth = {}
    for sign in (1, -1):
        cur = [m for s, m in one_pass if s == 'current' and math.copysign(1, m.target_angle)
               == sign]
        tenth[sign] = _stamp(cur[9])
    wait_matched(graph, pubs.values())
    _publish(pubs, one_pass)
    graph.spin_until(lambda: len(results) >= 2, 30, 'the first pass windows')
    _publish(pubs, one_pass)  # the bag loops: same ids and stamps again
    graph.spin_until(lambda: len(results) >= 4, 30, 'the second pass windows')
    graph.spin_for(1.0)
    assert len(results) == 4
    for m in results.msgs:
        assert m.moves == 10
        assert _stamp(m) == pytest.approx(tenth[int(math.copysign(1, m.target_angle))],
                                          abs=1e-6)
    graph.spin_until(lambda: bool(counters(sysid.text())) and
                     counters(sysid.text())[-1]['halves_received'] == 120, 10, 'counters')
    c = counters(sysid.text())[-1]
    assert c['resets'] == 1
    assert c['moves_rejected'] == 10  # the leftovers of the first pass, discarded
    log = sysid.text()
    assert log.count('stamps jumped back') == 1
    assert 'discarded: time jumped back' in log


# -- invalid parameters ---------------------------------------------------------------------

SYSID_BAD = [('window_size', -5), ('window_size', 1), ('na', 0), ('na', 61), ('nb', 100),
             ('pair_timeout', 0.0), ('pair_timeout', -1.0), ('max_pending', 0),
             ('time_jump', math.nan), ('method', 'magic')]
WATCHDOG_BAD = [('tolerances.omega_1', 0.0), ('tolerances.k0', -0.01),
                ('stale_timeout', 0.0), ('n_sigma', -1.0), ('tolerances.omega', -1.0),
                ('tolerances.zeta_2', 'loose'), ('model', '/tmp/other_scanner.yaml')]
DRIVER_BAD = [('rate_factor', -1.0), ('moves_per_angle', 3), ('angles', [0.3, 45.0]),
              ('step.factor', 0.0), ('effects', '{not json')]


def test_invalid_parameters_rejected_with_reason_old_values_kept(graph: Graph) -> None:
    ns = '/fault_params'
    remap = f'__ns:={ns}'
    procs = [_sysid(graph, ns, 'sysid', '-p', 'fit_processes:=0'),
             graph.start('watchdog', 'watchdog', '-r', remap),
             graph.start('galvo_driver', 'driver', '-r', remap, '-p', 'wait_for_subscribers:=5')]
    for node, bad in ((f'{ns}/sysid', SYSID_BAD), (f'{ns}/watchdog', WATCHDOG_BAD),
                      (f'{ns}/galvo_driver', DRIVER_BAD)):
        names = sorted({n for n, _ in bad})
        old = graph.get_parameters(node, names)
        out = graph.set_parameters(node, [Parameter(n, value=v) for n, v in bad])
        for (name, value), res in zip(bad, out, strict=True):
            print(f'{node} {name} := {value!r}: {res.reason}')
            assert not res.successful, (node, name, value)
            assert res.reason, (node, name, value)
            short = name.split('.')[-1]
            assert any(x in res.reason for x in (name, short, short.replace('_', ' '))), \
                (name, res.reason)
        assert graph.get_parameters(node, names) == old
    # valid changes are still taken
    ok = graph.set_parameters(f'{ns}/sysid', [Parameter('window_size', value=20),
                                              Parameter('na', value=12)])
    assert all(r.successful for r in ok)
    assert graph.get_parameters(f'{ns}/sysid', ['window_size', 'na']) == {'window_size': 20,
                                                                         'na': 12}
    ok = graph.set_parameters(f'{ns}/watchdog', [Parameter('tolerances.omega_1', value=0.02)])
    assert ok[0].successful
    assert all(p.running for p in procs)
    assert 'Traceback' not in graph.logs(100_000)
