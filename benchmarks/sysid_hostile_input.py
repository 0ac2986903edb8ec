"""The sysid node under the two load floods of issue 12, over real DDS (a benchmark, not a test).

Each scenario starts a fresh ``sysid`` (windows of ``--window-size`` moves, default fit
processes) as a child process and feeds it, for ``--duration`` seconds, a steady stream of good
moves (``--good-rate`` moves/s of one angle, both signs, simulated) interleaved with a flood:

1. oversized: one pair (current and encoder half) of ``MoveSamples`` with ``--huge-samples``
   float64 samples each (default 5,000,000: 40 MB a half), ``--huge-rate`` pairs/s (default 1);
2. angles: ``--angle-rate`` distinct target angles/s (default 2,000), each a lone move (both
   halves, 512 samples) never seen again.

Every stamp is the publisher's clock (one data clock for the good stream and the flood). The
node's resident memory (VmRSS of its main process) is sampled every 0.5 s from a thread; its
counters are read from ``/diagnostics`` (its log's ``counters:`` lines if none came). Printed
per scenario: what was sent and at what rate, the node's configured bounds, resident memory
(start, max, end of the flood, after settling), what the node refused, evicted or never
received, and the good stream's windows: expected (full windows its moves make) against those
identified on ``galvo/modal_parameters``. Nothing is asserted: the figures are printed.

The test of the same input paths at small sizes is ``test/nodes/test_sysid_input.py``; the
helpers (child processes, counters, messages) are ``test/ros_graph.py``'s.

Usage: ``.venv/bin/python benchmarks/sysid_hostile_input.py [--duration 30]
[--scenario oversized angles] [--good-rate 20] [--window-size 20]``.
Stays on this machine (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, ROS_DOMAIN_ID 91 unless
set); the node and its fit processes are stopped on exit, Ctrl-C and SIGTERM.
"""

from __future__ import annotations

import os

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('ROS_DOMAIN_ID', '91')

import argparse
import math
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from galvo_sysid_msgs.msg import ModalParameters, MoveSamples
from rclpy.qos import QoSProfile, ReliabilityPolicy

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test'))

from ros_graph import MOVES_QOS, RESULTS_QOS, Graph, counters, move_message, rss_kib, wait_matched
from sysid_load import process_tree_rss

from galvo_sysid.interfaces.messages import fill, fill_header, move_samples_fields
from galvo_sysid.interfaces.topics import (
    DIAGNOSTICS_TOPIC,
    RESULT_TOPIC,
    SIGNAL_TOPICS,
    absolute_topic,
)
from galvo_sysid.model import REFERENCE_MODEL
from galvo_sysid.monitor.verdict import STATUS_OK
from galvo_sysid.sim.simulator import GalvoSimulator

if TYPE_CHECKING:
    from collections.abc import Callable

    from galvo_sysid.sim.config import Move

GOOD_ANGLE = 0.9
STAMP0 = 1000.0  # stamp [s] of the start of the flood
OMEGA_1 = REFERENCE_MODEL.natural_frequencies[0]
BOUNDS = ('max_samples', 'max_buffered_bytes', 'max_pending', 'max_windows', 'window_timeout',
          'window_size', 'fit_processes', 'qos_depth')
HUGE_QOS = QoSProfile(depth=2, reliability=ReliabilityPolicy.RELIABLE)
"""The oversized pairs' own publishers: two 40 MB messages of history each, not 1,000."""


class Scenario:
    """One fresh sysid node, its subscriptions and publishers here, and what was measured."""

    def __init__(self, graph: Graph, args: argparse.Namespace, name: str) -> None:
        self.graph = graph
        self.args = args
        self.name = name
        self.ns = f'/hostile_{name}'
        node = graph.node
        self.results: list[ModalParameters] = []
        self.diags: list[dict[str, str]] = []
        self._subs = [
            node.create_subscription(ModalParameters,
                                     absolute_topic(RESULT_TOPIC, namespace=self.ns),
                                     self.results.append, RESULTS_QOS),
            node.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, self._on_diagnostics,
                                     QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)),
        ]
        self.pubs = {s: node.create_publisher(MoveSamples, absolute_topic(t, namespace=self.ns),
                                              MOVES_QOS) for s, t in SIGNAL_TOPICS.items()}
        self.proc = graph.start('sysid', f'sysid_{name}', '-r', f'__ns:={self.ns}',
                                '-p', f'window_size:={args.window_size}',
                                '-p', 'stats_period:=1.0', '-p', 'diagnostics_period:=0.5',
                                '-p', f'hardware_id:=hostile_{name}')
        self.rss: list[tuple[float, int]] = []
        self.start = 0.0

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.hardware_id == f'hostile_{self.name}':
                self.diags.append({kv.key: kv.value for kv in status.values})

    def counters(self) -> dict[str, int]:
        """The node's latest counters: from /diagnostics, else from its log."""
        if self.diags:
            return {k: int(v) for k, v in self.diags[-1].items() if v.lstrip('-').isdigit()}
        logged = counters(self.proc.text())
        return logged[-1] if logged else {}

    def peak(self, key: str) -> int:
        """The largest value of a counter in the diagnostics seen."""
        return max((int(d[key]) for d in self.diags if d.get(key, '').isdigit()), default=-1)

    def publisher(self, topic_signal: str, qos: QoSProfile) -> Any:
        """Another publisher here on the node's topic of ``topic_signal``."""
        return self.graph.node.create_publisher(
            MoveSamples, absolute_topic(SIGNAL_TOPICS[topic_signal], namespace=self.ns), qos)

    def ready(self, flood: dict[str, Any]) -> dict[str, Any]:
        """Wait for the node's subscriptions (to the good stream's and the ``flood``'s
        publishers) and its warm-up; its bounds (parameters)."""  # noqa: D205, D209
        wait_matched(self.graph, [*self.pubs.values(), *flood.values()], timeout=60)
        bounds = self.graph.get_parameters(f'{self.ns}/sysid', list(BOUNDS))
        self.graph.spin_for(self.args.warmup)  # fit processes start, run their warm-up fit
        return bounds

    def stamp(self) -> float:
        """The publishers' data clock [s]."""
        return STAMP0 + time.monotonic() - self.start

    def sample_rss(self, stop: threading.Event) -> None:
        """Sample the node's VmRSS every 0.5 s until ``stop``."""
        while not stop.wait(0.5):
            self.rss.append((time.monotonic() - self.start, rss_kib(self.proc.pid)))

    def settle(self, expected: int) -> float:
        """Spin until the node has taken all it will, its fits are done and the results are
        here (or ``--settle`` seconds); the seconds it took."""  # noqa: D205, D209
        t0 = time.monotonic()
        end = t0 + self.args.settle
        last, since = -1, time.monotonic()
        while time.monotonic() < end:
            self.graph.spin_for(0.25)
            c = self.counters()
            received = c.get('halves_received', -1)
            if received != last:
                last, since = received, time.monotonic()
                continue
            done = (c.get('windows_waiting', 1) == 0 and c.get('pending_halves', 1) == 0
                    and c.get('windows_completed', -1) == sum(
                        c.get(k, 0) for k in ('windows_identified', 'windows_failed',
                                              'windows_mismatched', 'windows_dropped'))
                    and len(self.results) >= c.get('windows_identified', 0))
            quiet = time.monotonic() - since  # seconds without a new half
            if done and quiet > 3 and (len(self.results) >= expected or quiet > 8):
                break
        self.graph.spin_for(1.2)  # one more diagnostics message after the last input
        return time.monotonic() - t0

    def close(self) -> None:
        """Stop the node (and its fit processes); drop the subscriptions and publishers."""
        self.proc.stop()
        for sub in self._subs:
            self.graph.node.destroy_subscription(sub)
        for pub in self.pubs.values():
            self.graph.node.destroy_publisher(pub)


def paced(rate: float, duration: float, start: float, stop: threading.Event,
          step: Callable[[int], None]) -> tuple[int, float]:
    """Call ``step(i)`` at ``rate`` per second from ``start`` for ``duration`` seconds (behind
    schedule: at once, no pause); how many calls and the seconds they took."""  # noqa: D205, D209
    i = 0
    end = start + duration
    while not stop.is_set():
        now = time.monotonic()
        if now >= end:
            break
        due = start + i / rate
        if due > now:
            time.sleep(min(due - now, end - now))
            continue
        step(i)
        i += 1
    return i, time.monotonic() - start


def good_stream(sc: Scenario, moves: list[Move], stop: threading.Event,
                sent: dict[float, int]) -> None:
    msgs = [{s: move_message(m, s, stamp=0.0) for s in SIGNAL_TOPICS} for m in moves]

    def step(i: int) -> None:
        pair = msgs[i % len(msgs)]
        stamp = sc.stamp()
        for s, msg in pair.items():
            msg.move_id = i
            fill_header(msg, stamp=stamp)
            sc.pubs[s].publish(msg)
        angle = moves[i % len(moves)].target_angle
        sent[angle] = sent.get(angle, 0) + 1

    paced(sc.args.good_rate, sc.args.duration, sc.start, stop, step)


def run_flood(sc: Scenario, moves: list[Move], flood: Callable[[threading.Event], dict[str, Any]]
              ) -> dict[str, Any]:
    """The good stream and ``flood`` on two threads for ``--duration`` s, memory sampled."""
    stop = threading.Event()
    good: dict[float, int] = {}
    out: dict[str, Any] = {}
    sc.start = time.monotonic()
    sc.rss.append((0.0, rss_kib(sc.proc.pid)))
    threads = [threading.Thread(target=good_stream, args=(sc, moves, stop, good), daemon=True),
               threading.Thread(target=lambda: out.update(flood(stop)), daemon=True),
               threading.Thread(target=sc.sample_rss, args=(stop,), daemon=True)]
    for t in threads:
        t.start()
    try:
        while any(t.is_alive() for t in threads[:2]):
            sc.graph.spin_for(0.05)
        out['rss_flood_end'] = rss_kib(sc.proc.pid)
        ws = sc.args.window_size
        out['good'] = good
        out['expected'] = sum(n // ws for n in good.values())
        out['settle'] = sc.settle(out['expected'])
        out['rss_end'] = rss_kib(sc.proc.pid)
        out['tree_end'], out['children'] = process_tree_rss(sc.proc.pid)
    finally:
        stop.set()
        for t in threads:
            t.join(timeout=30)
    return out


def oversized(sc: Scenario, pubs: dict[str, Any], stop: threading.Event) -> dict[str, Any]:
    n = sc.args.huge_samples
    msgs = {s: fill(MoveSamples(), move_samples_fields(move_id=0, target_angle=GOOD_ANGLE,
                                                       sample_period=1e-5,
                                                       data=np.full(n, 0.1)))
            for s in SIGNAL_TOPICS}
    times: list[float] = []

    def step(i: int) -> None:
        stamp = sc.stamp()
        for s, msg in msgs.items():
            msg.move_id = 10**9 + i
            fill_header(msg, stamp=stamp)
            t = time.monotonic()
            pubs[s].publish(msg)
            times.append(time.monotonic() - t)

    pairs, elapsed = paced(sc.args.huge_rate, sc.args.duration, sc.start, stop, step)
    return {'pairs': pairs, 'elapsed': elapsed, 'publish_times': times}


def angle_flood(sc: Scenario, pubs: dict[str, Any], moves: list[Move], stop: threading.Event
                ) -> dict[str, Any]:
    msgs = {s: move_message(moves[0], s, stamp=0.0) for s in SIGNAL_TOPICS}
    batch = sc.args.angle_batch
    state = {'moves': 0}

    def step(_: int) -> None:
        stamp = sc.stamp()
        for _ in range(batch):
            k = state['moves']
            state['moves'] = k + 1
            for s, msg in msgs.items():
                msg.move_id = 10**8 + k
                msg.target_angle = 1.0 + 1e-5 * k  # distinct (resolution 1e-6 deg)
                fill_header(msg, stamp=stamp)
                pubs[s].publish(msg)

    _, elapsed = paced(sc.args.angle_rate / batch, sc.args.duration, sc.start, stop, step)
    return {'moves': state['moves'], 'elapsed': elapsed}


def mib(kib: float) -> str:
    return f'{kib / 1024:.1f}'


def report_common(sc: Scenario, r: dict[str, Any], bounds: dict[str, Any]
                  ) -> list[tuple[str, str]]:
    ws = sc.args.window_size
    good = r['good']
    ok = [m for m in sc.results if m.status == STATUS_OK]
    plausible = [m for m in ok if abs(m.natural_frequencies[0] / OMEGA_1 - 1) < 0.003]
    per_sign = ', '.join(
        f'{a:+g} deg: {sum(1 for m in ok if m.target_angle == a)} of {good.get(a, 0) // ws} '
        f'({good.get(a, 0)} moves)' for a in sorted(good))
    in_windows = sum(int(m.moves) for m in ok)
    rss = [k for _, k in sc.rss]
    budget = int(bounds['max_buffered_bytes'])
    return [
        ('good moves sent (rate achieved)',
         f'{sum(good.values())} ({sum(good.values()) / sc.args.duration:.1f} moves/s of '
         f'{sc.args.good_rate:g}; +/-{GOOD_ANGLE:g} deg, {moves_len(sc)} samples)'),
        ('good windows expected / identified (plausible omega_1)',
         f'{r["expected"]} / {len(ok)} ({len(plausible)}); per sign {per_sign}'),
        ('moves in the identified windows', f'{sorted({int(m.moves) for m in ok})} each, '
         f'{in_windows} in all; good moves in no window: {sum(good.values()) - in_windows} '
         f'(incomplete at the end: {sum(n % ws for n in good.values())})'),
        ('node RSS start / max / end of flood / settled [MiB]',
         f'{mib(rss[0])} / {mib(max(rss))} / {mib(r["rss_flood_end"])} / {mib(r["rss_end"])} '
         f'(samples every 0.5 s: {len(rss)}; node + {r["children"]} processes below it at '
         f'the end: {mib(r["tree_end"])})'),
        ('node RSS along the run [MiB]',
         ', '.join(f'{t:.0f} s: {mib(k)}' for t, k in sc.rss[::max(1, len(sc.rss) // 10)])),
        ('configured bounds',
         f'max_buffered_bytes {budget} ({budget / 2**20:.0f} MiB: {budget * 3 // 4 / 2**20:.0f} '
         f'open windows, {budget // 4 / 2**20:.0f} waiting halves); max_samples '
         f'{bounds["max_samples"]} (a half of at most {8 * bounds["max_samples"] / 2**10:.0f} '
         f'KiB of samples, a pair {16 * bounds["max_samples"] / 2**20:.0f} MiB); '
         f'max_windows {bounds["max_windows"]}, max_pending {bounds["max_pending"]}, '
         f'qos_depth {bounds["qos_depth"]}, fit_processes {bounds["fit_processes"]}'),
        ('resets (stamps jumped back) / stale halves / moves in "unpaired" log lines',
         f'{sc.counters().get("resets", -1)} / {sc.counters().get("halves_stale", -1)} / '
         f'{unpaired(sc.proc.text())} (a move can be counted for each half)'),
        ('most one topic came late behind the other (topic_lag_ms_max)',
         f'{sc.counters().get("topic_lag_ms_max", -1)} ms (each topic judged by its own clock)'),
        ('peak buffered_bytes / open_windows (diagnostics)',
         f'{sc.peak("buffered_bytes")} / {sc.peak("open_windows")}'),
        ('settling after the flood', f'{r["settle"]:.1f} s'),
    ]


def unpaired(log: str) -> int:
    """Moves the node's log says were set aside as unpaired (the lines it held back and only
    counted included)."""  # noqa: D205, D209
    pattern = r'(\d+) moves? set aside \([^)]*\): unpaired after|(\d+) x unpaired after'
    return sum(int(m.group(1) or m.group(2)) for m in re.finditer(pattern, log))


def moves_len(sc: Scenario) -> int:
    return int(sc.args.record_length)


def print_table(title: str, rows: list[tuple[str, str]], c: dict[str, int], source: str) -> None:
    print(f'\n{title}')
    print('| figure | value |')
    print('|---|---|')
    for name, value in rows:
        print(f'| {name} | {value} |')
    print(f'final counters ({source}): ' + ', '.join(f'{k}={v}' for k, v in c.items()))
    sys.stdout.flush()


def scenario_oversized(graph: Graph, args: argparse.Namespace, moves: list[Move]) -> None:
    sc = Scenario(graph, args, 'oversized')
    try:
        pubs = {s: sc.publisher(s, HUGE_QOS) for s in SIGNAL_TOPICS}
        bounds = sc.ready(pubs)
        r = run_flood(sc, moves, lambda stop: oversized(sc, pubs, stop))
        c = sc.counters()
        times = r['publish_times']
        halves = 2 * r['pairs']
        text = sc.proc.text()
        said = text.count('refused before decoding')
        rows = [
            ('oversized pairs sent (rate achieved)',
             f'{r["pairs"]} pairs = {halves} halves of {args.huge_samples:,} float64 '
             f'({8 * args.huge_samples / 1e6:.0f} MB each) in {r["elapsed"]:.1f} s: '
             f'{r["pairs"] / r["elapsed"]:.2f} pairs/s of {args.huge_rate:g}'),
            ('publish() per oversized half median / max [s]',
             f'{statistics.median(times):.3f} / {max(times):.3f}' if times else '-'),
            ('oversized halves refused by the node (halves_refused)',
             f'{c.get("halves_refused", -1)} of {halves} sent '
             f'(refusal lines in its log: {said}, said once then summed)'),
            ('halves received by the node / sent in all',
             f'{c.get("halves_received", -1)} / {halves + 2 * sum(r["good"].values())}'),
            *report_common(sc, r, bounds),
        ]
        for p in pubs.values():
            graph.node.destroy_publisher(p)
        print_table('1. oversized flood (one pair of 5M-double halves a second + good stream)',
                    rows, c, '/diagnostics' if sc.diags else 'log')
    finally:
        sc.close()


def scenario_angles(graph: Graph, args: argparse.Namespace, moves: list[Move]) -> None:
    sc = Scenario(graph, args, 'angles')
    try:
        pubs = {s: sc.publisher(s, MOVES_QOS) for s in SIGNAL_TOPICS}
        bounds = sc.ready(pubs)
        r = run_flood(sc, moves, lambda stop: angle_flood(sc, pubs, moves, stop))
        c = sc.counters()
        halves = 2 * r['moves'] + 2 * sum(r['good'].values())
        rows = [
            ('flood moves sent (distinct angles, rate achieved)',
             f'{r["moves"]} lone moves ({2 * r["moves"]} halves) in {r["elapsed"]:.1f} s: '
             f'{r["moves"] / r["elapsed"]:.0f} angles/s of {args.angle_rate:g}'),
            ('halves received by the node / sent in all',
             f'{c.get("halves_received", -1)} / {halves} (not received: '
             f'{halves - c.get("halves_received", 0)})'),
            ('windows evicted / expired; halves evicted',
             f'{c.get("windows_evicted", -1)} / {c.get("windows_expired", -1)}; '
             f'{c.get("halves_evicted", -1)}'),
            ('moves set aside (moves_rejected)', str(c.get('moves_rejected', -1))),
            *report_common(sc, r, bounds),
        ]
        for p in pubs.values():
            graph.node.destroy_publisher(p)
        print_table(f'2. angle flood ({args.angle_rate:g} distinct target angles/s + good '
                    'stream)', rows, c, '/diagnostics' if sc.diags else 'log')
    finally:
        sc.close()


def machine(when: str) -> None:
    date = subprocess.run(['date'], capture_output=True, text=True, check=False).stdout.strip()
    load = Path('/proc/loadavg').read_text().strip()
    print(f'{when}: {date}; /proc/loadavg {load}', flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--duration', type=float, default=30.0, help='seconds of flood (30)')
    parser.add_argument('--scenario', nargs='+', choices=['oversized', 'angles'],
                        default=['oversized', 'angles'])
    parser.add_argument('--window-size', type=int, default=20)
    parser.add_argument('--good-rate', type=float, default=20.0, help='good moves/s (20)')
    parser.add_argument('--huge-samples', type=int, default=5_000_000)
    parser.add_argument('--huge-rate', type=float, default=1.0, help='oversized pairs/s (1)')
    parser.add_argument('--angle-rate', type=float, default=2000.0,
                        help='distinct angles/s (2000)')
    parser.add_argument('--angle-batch', type=int, default=20,
                        help='flood moves published back to back (20)')
    parser.add_argument('--warmup', type=float, default=5.0, help='seconds before the flood')
    parser.add_argument('--settle', type=float, default=40.0,
                        help='seconds at most to wait for the last results')
    args = parser.parse_args()
    workdir = Path(tempfile.mkdtemp(prefix='galvo_hostile_'))
    os.environ.setdefault('ROS_LOG_DIR', str(workdir / 'ros'))
    count = 2 * math.ceil(args.good_rate * args.duration / 2 + 1)
    sim_moves = list(GalvoSimulator(seed=12).moves(angles=[GOOD_ANGLE], moves_per_angle=count))
    args.record_length = len(sim_moves[0].current)

    def terminate(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, terminate)
    machine('start')
    print(f'sysid under hostile input: {args.duration:g} s of flood per scenario, windows of '
          f'{args.window_size} moves; ROS_DOMAIN_ID {os.environ["ROS_DOMAIN_ID"]}, '
          f'{os.cpu_count()} CPUs; logs in {workdir}', flush=True)
    graph = Graph(Path(sys.executable).parent, workdir, name='sysid_hostile_input')
    try:
        if 'oversized' in args.scenario:
            scenario_oversized(graph, args, sim_moves)
        if 'angles' in args.scenario:
            scenario_angles(graph, args, sim_moves)
    except KeyboardInterrupt:
        print('interrupted: stopping the node', file=sys.stderr)
        return 130
    finally:
        graph.close()
        machine('end')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
