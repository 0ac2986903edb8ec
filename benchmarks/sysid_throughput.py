"""Throughput and latency of the sysid node over real DDS (a benchmark, not a test).

Starts ``sysid`` as a child process and publishes simulated moves to it at a fixed rate
(moves/s; a move is two ``MoveSamples`` messages of 512 samples, current and encoder) for
``--duration`` seconds per rate. The moves are simulated once (GalvoSimulator, ``--cycles``
schedules of three angles forward and back, each with noise of its own) and replayed with
fresh move_ids and stamps: with the default 10 schedules the windows of an angle repeat their
data only every 10th window, so the node's warm start (each fit from the previous window of
its angle) does not start at its own answer, as it did with one schedule replayed (the run
of 2026-11-27 06:10: medians 61-71 ms). Reported per rate:

- moves published and the rate achieved,
- windows expected (every ``window_size`` moves of one signed angle) and results received
  (each must say it used ``window_size`` moves: a lost move would leave a window short),
- windows whose fit failed (the identification said why, e.g. no physical third mode),
- moves the node set aside (from its log) and windows it dropped because fits fell behind,
- latency from the publication of a window's last move to the arrival of its result
  (median, p99, max),
- the node's resident memory (with its fit child) after start-up and at the end.

Usage: ``.venv/bin/python benchmarks/sysid_throughput.py [--rates 165 500 1000]
[--duration 10] [--fit-processes 1] [--window-size 100] [--cycles 10]``.
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import rclpy
from galvo_sysid_msgs.msg import ModalParameters, MoveSamples
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from galvo_sysid.interfaces.messages import fill, fill_header, move_samples_fields
from galvo_sysid.interfaces.topics import RESULT_TOPIC, SIGNAL_TOPICS, absolute_topic
from galvo_sysid.sim.simulator import GalvoSimulator

ANGLES = (0.3, 0.9, 2.1)
MOVE_TIME = 606e-5  # simulated seconds per move (512 + 94 samples at 10 us)


def rss_kib(pid: int) -> int:
    """Resident memory of a process and its direct children (the fit processes) [KiB]."""
    pids = [pid]
    for stat in Path('/proc').glob('[0-9]*/stat'):
        try:
            fields = stat.read_text().rsplit(')', 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:  # field 4 of /proc/<pid>/stat: the parent's pid
            pids.append(int(stat.parent.name))
    total = 0
    for p in pids:
        try:
            for line in Path(f'/proc/{p}/status').read_text().splitlines():
                if line.startswith('VmRSS:'):
                    total += int(line.split()[1])
        except OSError:
            pass
    return total


def simulate_moves(cycles: int) -> list[tuple[float, object, object]]:
    """(target_angle, current, encoder) of ``cycles`` schedule cycles, one simulator run."""
    sim = GalvoSimulator(seed=11)
    return [(m.target_angle, m.current, m.encoder) for _ in range(cycles)
            for m in sim.moves(angles=ANGLES, moves_per_angle=200)]


def run_rate(rate: float, duration: float, moves: list[tuple[float, object, object]], *,
             window_size: int, fit_processes: int, workdir: Path) -> dict[str, float]:
    env = dict(os.environ)
    exe = Path(sys.executable).parent / 'sysid'
    log_path = workdir / f'sysid_{rate:g}.log'
    log = log_path.open('w')
    proc = subprocess.Popen(
        [str(exe), '--ros-args', '-r', '__ns:=/bench', '-p', f'window_size:={window_size}',
         '-p', f'fit_processes:={fit_processes}', '-p', 'stats_period:=0.0',
         '-p', 'queue_size:=64'], stdout=log, stderr=subprocess.STDOUT, env=env)
    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node('bench', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    qos_in = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    pubs = [node.create_publisher(MoveSamples, absolute_topic(t, namespace='bench'), qos_in)
            for t in SIGNAL_TOPICS.values()]
    arrivals: dict[int, tuple[float, int]] = {}

    def on_result(msg: ModalParameters) -> None:
        arrivals[int(msg.window_index)] = (time.monotonic(), int(msg.moves))

    node.create_subscription(ModalParameters, absolute_topic(RESULT_TOPIC, namespace='bench'),
                             on_result,
                             QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                                        durability=DurabilityPolicy.TRANSIENT_LOCAL))
    # messages built once; only move_id and stamp change per publication
    msgs = []
    for angle, cur, enc in moves:
        pair = []
        for data in (cur, enc):
            pair.append(fill(MoveSamples(), move_samples_fields(
                move_id=0, target_angle=angle, sample_period=1e-5, data=data)))
        msgs.append(pair)
    end = time.monotonic() + 30
    while min(p.get_subscription_count() for p in pubs) == 0 and time.monotonic() < end:
        executor.spin_once(timeout_sec=0.05)
    time.sleep(6.0)  # let the node's fit children start and run their warm-up fit
    rss_start = rss_kib(proc.pid)
    completes: list[float] = []  # publication time of each window's last move, in order
    counts: dict[float, int] = {}
    published = [0]

    def publish() -> None:
        n = int(rate * duration)
        t0 = time.monotonic()
        stamp0 = 1000.0
        for i in range(n):
            due = t0 + i / rate
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            angle = moves[i % len(moves)][0]
            pair = msgs[i % len(msgs)]
            for pub, msg in zip(pubs, pair, strict=True):
                msg.move_id = i
                fill_header(msg, stamp=stamp0 + i * MOVE_TIME)
                pub.publish(msg)
            counts[angle] = counts.get(angle, 0) + 1
            if counts[angle] % window_size == 0:
                completes.append(time.monotonic())
            published[0] += 1
        published.append(time.monotonic() - t0)

    thread = threading.Thread(target=publish)
    thread.start()
    while thread.is_alive():
        executor.spin_once(timeout_sec=0.01)
    thread.join()
    settle = time.monotonic() + 10
    while len(arrivals) < len(completes) and time.monotonic() < settle:
        executor.spin_once(timeout_sec=0.05)
    rss_end = rss_kib(proc.pid)
    executor.shutdown()
    node.destroy_node()
    rclpy.shutdown(context=context)
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=15)
    except subprocess.TimeoutExpired:
        proc.kill()
    log.close()
    text = log_path.read_text()
    set_aside = 0
    for line in text.splitlines():
        if 'set aside' in line and 'moves set aside' in line:
            set_aside += int(line.split('moves set aside')[0].split()[-1])
        elif 'move set aside' in line:
            set_aside += 1
    dropped = text.count('dropped: identification queue full')
    failed = text.count('not identified')
    latencies = sorted(arrivals[k][0] - completes[k] for k in arrivals if k < len(completes))
    full = sum(1 for _, m in arrivals.values() if m == window_size)

    def pct(q: float) -> float:
        if not latencies:
            return math.nan
        return 1e3 * latencies[min(len(latencies) - 1, int(q * len(latencies)))]

    return {
        'rate': rate, 'achieved': published[0] / published[1], 'published': published[0],
        'expected': len(completes), 'received': len(arrivals), 'full': full,
        'set_aside': set_aside, 'dropped': dropped, 'failed': failed,
        'median': 1e3 * statistics.median(latencies) if latencies else math.nan,
        'p99': pct(0.99), 'max': 1e3 * latencies[-1] if latencies else math.nan,
        'rss_start': rss_start / 1024, 'rss_end': rss_end / 1024,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--rates', type=float, nargs='+', default=[165, 500, 1000, 1500])
    parser.add_argument('--duration', type=float, default=10.0)
    parser.add_argument('--fit-processes', type=int, default=2)
    parser.add_argument('--window-size', type=int, default=100)
    parser.add_argument('--cycles', type=int, default=10,
                        help='distinct schedules simulated (each window of an angle has moves '
                             'of its own noise until they repeat; default 10)')
    args = parser.parse_args()
    if args.cycles < 1:
        parser.error('--cycles must be at least 1')
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    os.environ.setdefault('ROS_DOMAIN_ID', str(150 + os.getpid() % 50))
    workdir = Path(tempfile.mkdtemp(prefix='galvo_bench_'))
    os.environ.setdefault('ROS_LOG_DIR', str(workdir / 'ros'))
    moves = simulate_moves(args.cycles)
    print(f'sysid throughput: window_size {args.window_size}, fit_processes '
          f'{args.fit_processes}, {args.duration:g} s per rate, {args.cycles} distinct '
          f'schedules of moves, {os.cpu_count()} CPUs; load average before '
          f'{os.getloadavg()[0]:.2f}; '
          f'logs in {workdir}')
    header = ('| moves/s asked | achieved | moves published | windows expected | results '
              '(full) | fits failed | moves set aside | windows dropped | latency median [ms] '
              '| p99 [ms] | max [ms] | RSS start -> end [MiB] |')
    print(header)
    print('|' + '|'.join(['---'] * (header.count('|') - 1)) + '|')
    for rate in args.rates:
        r = run_rate(rate, args.duration, moves, window_size=args.window_size,
                     fit_processes=args.fit_processes, workdir=workdir)
        print(f'| {r["rate"]:g} | {r["achieved"]:.0f} | {r["published"]} | {r["expected"]} | '
              f'{r["received"]} ({r["full"]}) | {r["failed"]} | {r["set_aside"]} | '
              f'{r["dropped"]} | '
              f'{r["median"]:.0f} | {r["p99"]:.0f} | {r["max"]:.0f} | '
              f'{r["rss_start"]:.0f} -> {r["rss_end"]:.0f} |', flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
