"""What a killed or starved recording keeps (a benchmark, not a test; issue 12, defect 5).

Killed: ``galvo-sysid record`` runs as a child process and this script publishes simulated
moves to it over real DDS at the driver's real-time rate (a move is two ``MoveSamples``
messages of 512 samples, current and encoder); after a random 3-6 s the recorder is killed
with SIGKILL (no clean-up runs), ``galvo-sysid bag recover`` finishes the bag, and the bag is
read back. Reported per storage and trial: messages sent before the kill, kept, the share
kept, the seconds lost (the kill's wall time minus the receive time of the last message
kept) and the time ``bag recover`` took.

Full disk (``--full-disk``, needs root to mount a tmpfs): the same recorder on a small
tmpfs until the disk is full; reported: messages received, kept, lost, the exit code, the
error line and whether ``galvo-sysid info`` reads the bag as it is.

Usage: ``.venv/bin/python benchmarks/killed_recording.py [--trials 3] [--rate 165]
[--flush-interval 1.0] [--full-disk]``.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import rclpy
from galvo_sysid_msgs.msg import MoveSamples
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy

from galvo_sysid.field.bags import BagReader
from galvo_sysid.interfaces.messages import fill, fill_header, move_samples_fields
from galvo_sysid.sim.simulator import GalvoSimulator

BIN = Path(sys.executable).parent
QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)


class Feed:
    """Publishes simulated moves (both halves) with fresh move ids at a fixed rate."""

    def __init__(self, rate: float) -> None:
        self.rate = rate
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node('killed_recording_feed', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.pubs = {s: self.node.create_publisher(MoveSamples, f'/galvo/{s}', QOS)
                     for s in ('current', 'encoder')}
        self.moves = list(GalvoSimulator(seed=5).moves(angles=[0.3], moves_per_angle=200))
        self.next_id = 0

    def subscribers(self) -> set[bytes]:
        """Endpoint ids of the subscriptions to the moves (a killed recorder's stay a while)."""
        return {bytes(i.endpoint_gid) for s in ('current', 'encoder')
                for i in self.node.get_subscriptions_info_by_topic(f'/galvo/{s}')}

    def wait_new_subscriber(self, old: set[bytes], timeout: float = 60.0) -> None:
        """Wait until both topics have a subscription that is not in ``old``."""
        end = time.monotonic() + timeout
        while not all({bytes(i.endpoint_gid) for i in
                       self.node.get_subscriptions_info_by_topic(f'/galvo/{s}')} - old
                      for s in ('current', 'encoder')):
            if time.monotonic() > end:
                raise SystemExit('the recorder did not subscribe')
            self.executor.spin_once(timeout_sec=0.05)

    def publish_for(self, seconds: float, *, until: object = None) -> int:
        """Publish moves at the rate for ``seconds`` (or until ``until()``); return messages."""
        start = time.monotonic()
        sent = 0
        k = 0
        while time.monotonic() - start < seconds:
            if until is not None and until():  # type: ignore[operator]
                break
            due = start + k / self.rate
            if due > time.monotonic():
                time.sleep(due - time.monotonic())
            move = self.moves[self.next_id % len(self.moves)]
            for s in ('current', 'encoder'):
                msg = fill(MoveSamples(), move_samples_fields(
                    move_id=self.next_id, target_angle=move.target_angle,
                    sample_period=move.sample_period,
                    data=move.current if s == 'current' else move.encoder))
                fill_header(msg, stamp=1000.0 + self.next_id * 606e-5)
                self.pubs[s].publish(msg)
                sent += 1
            self.next_id += 1
            k += 1
        return sent

    def close(self) -> None:
        """Shut the feed's rclpy down."""
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


def recorder(bag: Path, storage: str, flush_interval: float, log: Path) -> subprocess.Popen[bytes]:
    with log.open('w') as out:
        return subprocess.Popen([str(BIN / 'galvo-sysid'), 'record', '--out', str(bag),
                                 '--storage', storage, '--flush-interval', str(flush_interval),
                                 '/galvo/current', '/galvo/encoder'],
                                stdout=out, stderr=subprocess.STDOUT)


def kept(bag: Path) -> tuple[int, int]:
    """Messages in the bag and the receive time of the last [ns]."""
    with BagReader(bag) as reader:
        info = reader.info
    return info.message_count, info.end


def killed(feed: Feed, storage: str, flush_interval: float, rng: np.random.Generator,
           work: Path, trial: int) -> dict[str, float]:
    bag = work / f'{storage}_{trial}'
    old = feed.subscribers()
    proc = recorder(bag, storage, flush_interval, work / f'{bag.name}.log')
    try:
        feed.wait_new_subscriber(old)
        sent = feed.publish_for(float(rng.uniform(3.0, 6.0)))
        t_kill = time.time()
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    t0 = time.monotonic()
    done = subprocess.run([str(BIN / 'galvo-sysid'), 'bag', 'recover', str(bag)],
                          capture_output=True, text=True, check=False)
    recover_s = time.monotonic() - t0
    if done.returncode != 0:
        raise SystemExit(f'recover failed: {done.stderr}')
    count, last = kept(bag)
    return {'sent': sent, 'kept': count,
            'lost_s': t_kill - last * 1e-9 if count else float('nan'),
            'recover_s': recover_s}


def full_disk(feed: Feed, storage: str, flush_interval: float, work: Path,
              size: str) -> dict[str, object]:
    disk = work / f'disk_{storage}'
    disk.mkdir()
    subprocess.run(['mount', '-t', 'tmpfs', '-o', f'size={size}', 'tmpfs', str(disk)],
                   check=True)
    try:
        bag = disk / 'bag'
        log = work / f'full_{storage}.log'
        old = feed.subscribers()
        proc = recorder(bag, storage, flush_interval, log)
        try:
            feed.wait_new_subscriber(old)
            feed.publish_for(120.0, until=lambda: proc.poll() is not None)
            proc.wait(30)
        finally:
            if proc.poll() is None:
                proc.send_signal(signal.SIGKILL)
                proc.wait(10)
        text = log.read_text()
        error = next((line for line in text.splitlines() if 'error' in line), '')
        received = int(re.search(r'record: (\d+) messages', text).group(1))  # type: ignore[union-attr]
        lost = re.search(r'([\d,]+) messages not yet written are lost', error)
        info = subprocess.run([str(BIN / 'galvo-sysid'), 'info', str(bag)],
                              capture_output=True, text=True, check=False)
        count = int(re.search(r'messages: (\d+)', info.stdout).group(1)) if info.returncode == 0 \
            else 0  # type: ignore[union-attr]
        return {'received': received, 'kept': count,
                'lost': int(lost.group(1).replace(',', '')) if lost else 0,
                'exit': proc.returncode, 'readable': info.returncode == 0, 'error': error}
    finally:
        subprocess.run(['umount', '-l', str(disk)], check=False)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--trials', type=int, default=3)
    parser.add_argument('--rate', type=float, default=165.0, help='moves per second')
    parser.add_argument('--flush-interval', type=float, default=1.0)
    parser.add_argument('--full-disk', action='store_true')
    parser.add_argument('--disk-size', default='4m')
    args = parser.parse_args()
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 100))
    work = Path(tempfile.mkdtemp(prefix='killed_recording_'))
    os.environ.setdefault('ROS_LOG_DIR', str(work / 'log'))
    load = os.getloadavg()[0]
    print(f'# killed recording: {args.rate:g} moves/s ({2 * args.rate:g} messages/s, 512 '
          f'samples), flush interval {args.flush_interval:g} s, SIGKILL after 3-6 s; '
          f'load {load:.2f} on {os.cpu_count()} cores')
    print(f'{"storage":8} {"trial":>5} {"sent":>6} {"kept":>6} {"kept %":>7} {"lost s":>7} '
          f'{"recover s":>9}')
    feed = Feed(args.rate)
    rng = np.random.default_rng(2026)
    try:
        for storage in ('mcap', 'sqlite3'):
            for trial in range(args.trials):
                r = killed(feed, storage, args.flush_interval, rng, work, trial)
                print(f'{storage:8} {trial:>5} {r["sent"]:>6.0f} {r["kept"]:>6.0f} '
                      f'{100 * r["kept"] / r["sent"]:>6.1f}% {r["lost_s"]:>7.2f} '
                      f'{r["recover_s"]:>9.2f}', flush=True)
        if args.full_disk:
            print(f'\n# full disk: a {args.disk_size} tmpfs, same feed until the recorder stops')
            print(f'{"storage":8} {"received":>8} {"kept":>6} {"lost":>6} {"exit":>4} '
                  f'{"readable":>8}  error line')
            for storage in ('mcap', 'sqlite3'):
                r2 = full_disk(feed, storage, args.flush_interval, work, args.disk_size)
                error = str(r2['error']).split(': error: ')[-1]
                print(f'{storage:8} {r2["received"]:>8} {r2["kept"]:>6} {r2["lost"]:>6} '
                      f'{r2["exit"]:>4} {"yes" if r2["readable"] else "NO":>8}  {error}',
                      flush=True)
    finally:
        feed.close()


if __name__ == '__main__':
    main()
