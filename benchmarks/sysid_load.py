"""Sustained load on the sysid node over real DDS (a benchmark, not a test; issue 7 "Load").

Starts ``sysid`` (its default parameters: windows of 100 moves, two fit processes) as a child
process and publishes simulated moves to it at ``--rate`` moves/s (a move is two
``MoveSamples`` of 512 samples: current and encoder) for ``--duration`` seconds, from a
publisher thread of this process. The moves are simulated once (``--cycles`` schedules over a
few angles, forward and back, each with noise of its own) and replayed with fresh move_ids and
advancing stamps: with the default 10 schedules, the windows of an angle repeat their data only
every 10th window, so a fit started from the previous window of its angle (the node's
``warm_start``, on unless ``--no-warm-start``) does not start at its own answer. Reported:

- moves published and the rate achieved;
- how many of the windows identified were fitted from the previous window of their angle;
- moves lost: published, minus those in identified windows, minus those still waiting in
  windows that cannot be complete yet at the end; with the causes: halves that never reached
  the node (its own counter), moves it set aside, windows dropped because fits fell behind,
  windows whose fit failed;
- with ``--fit-budget-ms``, how many fits were cut short at the node's ``fit_budget_ms``;
  and in any case, how many modes the results report unresolved (what a budget costs);
- latency per window, from the publication of its last move to the arrival of its result
  here (median, p99, max), results matched to windows by their stamps; and the same without
  each angle's first window of each sign (with the warm start, the only ones not started from
  the previous window of their angle: the very first of each sign from the model file, the
  others from the latest result of their sign; what a long run converges to), and those first
  windows' latencies;
- the node's own figures over its last 200 windows (its last counters line, as on
  ``/diagnostics``): from a window's completion to its fit's end, the CPU time of the fit
  itself in its process, and per window the difference (``wait_ms``): the hand-over to the
  fit process and back and the time the fit waited for a CPU beside the other fit and the
  message handling;
- where the CPU went from the first move to the last result: the node's own process (its
  executor and message handling), its fit processes (and the CPU per window), and this
  process (the publisher thread and the result listener), each as a share of one CPU; the
  machine has ``os.cpu_count()`` of them;
- the node's resident memory (main process plus fit processes) after start-up and at the end,
  and along the run.

Usage: ``.venv/bin/python benchmarks/sysid_load.py [--rate 1000] [--duration 60]
[--window-size 100] [--fit-processes 2] [--method refined] [--angles 0.3 0.9 2.1]
[--qos best_effort] [--cycles 10] [--no-warm-start] [--fit-budget-ms 0]``.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import rclpy
from galvo_sysid_msgs.msg import ModalParameters, MoveSamples
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from galvo_sysid.interfaces.messages import fill, fill_header, move_samples_fields, stamp_to_seconds
from galvo_sysid.interfaces.topics import RESULT_TOPIC, SIGNAL_TOPICS, absolute_topic
from galvo_sysid.sim.simulator import GalvoSimulator

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test'))
from ros_graph import descendants  # the test helpers: the processes below a node

MOVE_TIME = 606e-5  # simulated seconds per move (512 recorded + 94 dwell samples at 10 us)
NS = '/load'


def process_tree_rss(pid: int) -> tuple[int, int]:
    """Resident memory [KiB] of ``pid`` and the processes below it, and their number."""
    kids = descendants(pid)
    total = 0
    for p in [pid, *kids]:
        try:
            for line in Path(f'/proc/{p}/status').read_text().splitlines():
                if line.startswith('VmRSS:'):
                    total += int(line.split()[1])
        except OSError:
            pass
    return total, len(kids)


def process_tree_cpu(pid: int) -> tuple[float, float]:
    """CPU seconds (user + system) used so far by ``pid``, and by the processes below it."""
    tick = os.sysconf('SC_CLK_TCK')

    def cpu(p: int) -> float:
        try:
            fields = Path(f'/proc/{p}/stat').read_text().rsplit(')', 1)[1].split()
            return (int(fields[11]) + int(fields[12])) / tick
        except (OSError, IndexError, ValueError):  # gone meanwhile
            return 0.0

    return cpu(pid), sum(cpu(p) for p in descendants(pid))


_COUNTERS = re.compile(r'counters: (.*)$', re.MULTILINE)


def last_counters(text: str) -> dict[str, int]:
    found = _COUNTERS.findall(text)
    if not found:
        return {}
    return {k: int(v) for k, v in (kv.split('=') for kv in found[-1].split(', '))}


def pct(values: list[float], q: float) -> float:
    if not values:
        return math.nan
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, math.ceil(q * len(ordered)) - 1)]


def run(args: argparse.Namespace, workdir: Path) -> dict[str, Any]:
    sim = GalvoSimulator(seed=17)
    cycle = [(m.target_angle, m.current, m.encoder) for _ in range(args.cycles)
             for m in sim.moves(angles=args.angles, moves_per_angle=2 * args.window_size)]
    log_path = workdir / 'sysid.log'
    log = log_path.open('w')
    proc = subprocess.Popen(
        [str(Path(sys.executable).parent / 'sysid'), '--ros-args', '-r', f'__ns:={NS}',
         '-p', f'window_size:={args.window_size}', '-p', f'fit_processes:={args.fit_processes}',
         '-p', 'stats_period:=1.0', '-p', 'diagnostics_period:=0.0',
         '-p', f'qos_reliability:={args.qos}', '-p', f'method:={args.method}',
         '-p', f'warm_start:={str(args.warm_start).lower()}',
         '-p', f'fit_budget_ms:={float(args.fit_budget_ms)}'],
        stdout=log, stderr=subprocess.STDOUT)
    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node('sysid_load', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        return _measure(args, node, executor, proc, cycle, log_path)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)
        log.close()


def _measure(args: argparse.Namespace, node: Any, executor: SingleThreadedExecutor,
             proc: subprocess.Popen[bytes], cycle: list[tuple[float, Any, Any]],
             log_path: Path) -> dict[str, Any]:
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE
                     if args.qos == 'reliable' else ReliabilityPolicy.BEST_EFFORT)
    pubs = [node.create_publisher(MoveSamples, absolute_topic(t, namespace=NS), qos)
            for t in SIGNAL_TOPICS.values()]
    arrivals: dict[int, float] = {}  # stamp [ns] of a window's last move -> arrival time
    moves_in: dict[int, int] = {}
    unresolved: dict[int, int] = {}  # modes reported unresolved per window

    def on_result(msg: ModalParameters) -> None:
        key = round(stamp_to_seconds(msg.header.stamp) * 1e6)
        arrivals[key] = time.monotonic()
        moves_in[key] = int(msg.moves)
        unresolved[key] = sum(not r for r in msg.resolved)

    node.create_subscription(ModalParameters, absolute_topic(RESULT_TOPIC, namespace=NS), on_result,
                             QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                                        durability=DurabilityPolicy.TRANSIENT_LOCAL))
    msgs = [[fill(MoveSamples(), move_samples_fields(move_id=0, target_angle=angle,
                                                     sample_period=1e-5, data=data))
             for data in (cur, enc)] for angle, cur, enc in cycle]
    end = time.monotonic() + 60
    while min(p.get_subscription_count() for p in pubs) == 0:
        if time.monotonic() > end or proc.poll() is not None:
            raise SystemExit(f'sysid did not subscribe; see {log_path}')
        executor.spin_once(timeout_sec=0.05)
    warm = time.monotonic() + args.warmup  # fit processes start and run their warm-up fit
    while time.monotonic() < warm:
        executor.spin_once(timeout_sec=0.05)
    rss_start, children = process_tree_rss(proc.pid)
    rss_trace: list[tuple[float, int]] = [(0.0, rss_start)]
    completes: dict[int, float] = {}  # stamp key of a window's last move -> publish time
    state = {'published': 0, 'elapsed': 0.0, 'late': 0.0}
    stamp0 = 1000.0

    def publish() -> None:
        n = int(args.rate * args.duration)
        counts: dict[float, int] = {}
        t0 = time.monotonic()
        for i in range(n):
            delay = t0 + i / args.rate - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                state['late'] = max(state['late'], -delay)
            angle = cycle[i % len(cycle)][0]
            stamp = stamp0 + i * MOVE_TIME
            for pub, msg in zip(pubs, msgs[i % len(msgs)], strict=True):
                msg.move_id = i
                fill_header(msg, stamp=stamp)
                pub.publish(msg)
            counts[angle] = counts.get(angle, 0) + 1
            if counts[angle] % args.window_size == 0:
                completes[round(stamp * 1e6)] = time.monotonic()
            state['published'] = i + 1
        state['elapsed'] = time.monotonic() - t0
        state['leftover'] = sum(c % args.window_size for c in counts.values())

    thread = threading.Thread(target=publish, name='publisher')
    cpu_start = (*process_tree_cpu(proc.pid), time.process_time())
    start = time.monotonic()
    thread.start()
    next_rss = start + args.duration / 4
    while thread.is_alive():
        executor.spin_once(timeout_sec=0.01)
        if time.monotonic() >= next_rss:
            rss_trace.append((time.monotonic() - start, process_tree_rss(proc.pid)[0]))
            next_rss += args.duration / 4
    thread.join()
    settle = time.monotonic() + args.settle
    while time.monotonic() < settle and not set(completes) <= set(arrivals):
        executor.spin_once(timeout_sec=0.05)
    cpu_end = (*process_tree_cpu(proc.pid), time.process_time())
    cpu_wall = time.monotonic() - start
    rss_end, _ = process_tree_rss(proc.pid)
    rss_trace.append((time.monotonic() - start, rss_end))
    end = time.monotonic() + 3  # one more counters line after the last input
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.05)
    text = log_path.read_text(errors='replace')
    c = last_counters(text)
    latencies = [arrivals[k] - t for k, t in completes.items() if k in arrivals]
    # every angle's first window (both signs) starts from the model or another angle, the others
    # from the previous window of their angle: the latency once each angle has had its first
    # window
    firsts = set(sorted(completes, key=completes.__getitem__)[:2 * len(args.angles)])
    later = [arrivals[k] - t for k, t in completes.items() if k in arrivals and k not in firsts]
    published = int(state['published'])
    identified = sum(moves_in.values())
    leftover = int(state['leftover'])
    return {
        'published': published, 'achieved': published / state['elapsed'],
        'late': state['late'], 'windows_expected': len(completes),
        'windows_received': len(arrivals),
        'windows_full': sum(1 for m in moves_in.values() if m == args.window_size),
        'moves_lost': published - identified - leftover,
        'halves_not_received': 2 * published - c.get('halves_received', 0),
        'set_aside': c.get('moves_rejected', -1), 'dropped': c.get('windows_dropped', -1),
        'failed': c.get('windows_failed', -1), 'leftover': leftover,
        'warm': c.get('windows_warm_started', -1), 'identified': c.get('windows_identified', -1),
        'cut': c.get('windows_cut_short', -1), 'unresolved': sum(unresolved.values()),
        'unresolved_windows': sum(1 for v in unresolved.values() if v),
        'median': 1e3 * statistics.median(latencies) if latencies else math.nan,
        'p99': 1e3 * pct(latencies, 0.99), 'max': 1e3 * max(latencies, default=math.nan),
        'later': [1e3 * statistics.median(later) if later else math.nan,
                  1e3 * pct(later, 0.99), 1e3 * max(later, default=math.nan)],
        'node': c,
        'firsts': sorted(round(1e3 * (arrivals[k] - completes[k])) for k in firsts
                         if k in arrivals),
        'rss_start': rss_start / 1024, 'rss_end': rss_end / 1024, 'rss_trace': rss_trace,
        'children': children, 'cpu_wall': cpu_wall,
        'cpu': [b - a for a, b in zip(cpu_start, cpu_end, strict=True)],
    }


def _cpu_row(r: dict[str, Any]) -> str:
    """Where the CPU went while the moves came: the node, its fit processes, the publisher."""
    node, fits, here = r['cpu']
    wall = r['cpu_wall']
    per_window = f', {1e3 * fits / r["windows_received"]:.0f} ms per window' \
        if r['windows_received'] else ''
    return (f'{wall:.1f} s on {os.cpu_count()} CPUs: node {node:.1f} ({node / wall:.2f} CPU), '
            f'fit processes {fits:.1f} ({fits / wall:.2f} CPU{per_window}), this process '
            f'(publisher, result listener) {here:.1f} ({here / wall:.2f} CPU); in all '
            f'{(node + fits + here) / wall:.2f} CPU')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--rate', type=float, default=1000.0, help='moves/s (default 1000)')
    parser.add_argument('--duration', type=float, default=60.0, help='seconds (default 60)')
    parser.add_argument('--window-size', type=int, default=100)
    parser.add_argument('--fit-processes', type=int, default=2)
    parser.add_argument('--method', choices=['refined', 'paper-A', 'paper-B'], default='refined',
                        help="the sysid node's identification method")
    parser.add_argument('--angles', type=float, nargs='+', default=[0.3, 0.9, 2.1])
    parser.add_argument('--qos', choices=['reliable', 'best_effort'], default='reliable',
                        help="the move topics' reliability (publisher and sysid)")
    parser.add_argument('--cycles', type=int, default=10,
                        help='distinct schedules simulated (each window of an angle has moves '
                             'of its own noise until they repeat; default 10)')
    parser.add_argument('--no-warm-start', dest='warm_start', action='store_false',
                        help="the sysid node's warm_start parameter false (every fit afresh)")
    parser.add_argument('--fit-budget-ms', type=float, default=0.0,
                        help="the sysid node's fit_budget_ms (default 0: no budget)")
    parser.add_argument('--warmup', type=float, default=6.0, help='seconds before publishing')
    parser.add_argument('--settle', type=float, default=15.0,
                        help='seconds to wait for the last results')
    args = parser.parse_args()
    if args.cycles < 1:
        parser.error('--cycles must be at least 1')
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    os.environ.setdefault('ROS_DOMAIN_ID', str(150 + os.getpid() % 50))
    workdir = Path(tempfile.mkdtemp(prefix='galvo_load_'))
    os.environ.setdefault('ROS_LOG_DIR', str(workdir / 'ros'))
    print(f'sysid load: {args.rate:g} moves/s for {args.duration:g} s, windows of '
          f'{args.window_size} moves over {len(args.angles)} angles (both signs), '
          f'{args.fit_processes} fit processes, method {args.method}, warm start '
          f'{"on" if args.warm_start else "off"}, fit budget '
          f'{f"{args.fit_budget_ms:g} ms" if args.fit_budget_ms else "none"}, {args.qos} QoS; '
          f'{args.cycles} distinct '
          f'schedules of moves; '
          f'{os.cpu_count()} CPUs, '
          f'load average before {os.getloadavg()[0]:.2f}; log in {workdir}', flush=True)
    r = run(args, workdir)
    rows = [
        ('moves published (rate achieved)',
         f'{r["published"]} ({r["achieved"]:.0f} moves/s; publisher at most '
         f'{1e3 * r["late"]:.0f} ms behind)'),
        ('moves lost', f'{r["moves_lost"]} ({100 * r["moves_lost"] / r["published"]:.2f} %)'),
        ('  halves not received by the node', str(r['halves_not_received'])),
        ('  moves set aside by the node', str(r['set_aside'])),
        ('  windows dropped (fits behind) / failed', f'{r["dropped"]} / {r["failed"]}'),
        ('moves waiting in incomplete windows at the end', str(r['leftover'])),
        ('windows expected / results (full)',
         f'{r["windows_expected"]} / {r["windows_received"]} ({r["windows_full"]})'),
        ('  of the windows identified, fits started from an earlier result (of the angle, or '
         'of the sign) or from the model file',
         f'{r["warm"]} of {r["identified"]}'),
        ('  of those, fits cut short at fit_budget_ms (weak modes not profiled)',
         f'{r["cut"]} (budget: {f"{args.fit_budget_ms:g} ms" if args.fit_budget_ms else "none"})'),
        ('modes reported unresolved (in windows)',
         f'{r["unresolved"]} (in {r["unresolved_windows"]} of {r["windows_received"]})'),
        ('latency per window median / p99 / max [ms]',
         f'{r["median"]:.0f} / {r["p99"]:.0f} / {r["max"]:.0f}'),
        ("  without each angle's first window (both signs): median / p99 / max [ms]",
         ' / '.join(f'{v:.0f}' for v in r['later'])
         + f' (the first windows: {", ".join(str(v) for v in r["firsts"])} ms)'),
        ("  the node's own, its last 200 windows: completion -> fit end; the fit's CPU "
         'time in its process; the rest (per window): median / p99 / max [ms]',
         '; '.join(' / '.join(str(r['node'].get(f'{key}_{q}', -1))
                              for q in ('median', 'p99', 'max'))
                   for key in ('latency_ms', 'fit_cpu_ms', 'wait_ms'))),
        ('CPU from the first move to the last result [s]', _cpu_row(r)),
        ('resident memory start -> end [MiB]',
         f'{r["rss_start"]:.0f} -> {r["rss_end"]:.0f} (node + {r["children"]} processes '
         'below it: fork server, fits, resource tracker; RSS summed, shared pages counted '
         'in each)'),
        ('resident memory along the run [MiB]',
         ', '.join(f'{t:.0f} s: {kib / 1024:.0f}' for t, kib in r['rss_trace'])),
    ]
    print('| figure | value |')
    print('|---|---|')
    for name, value in rows:
        print(f'| {name} | {value} |')
    print(f'load average after: {os.getloadavg()[0]:.2f}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
