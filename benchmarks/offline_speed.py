"""Offline identification speed: ``galvo-sysid identify`` on a bag vs the scanner's real time.

The target (issue 5): a bag of the paper's 19 angles x 200 moves (3,800 moves, about 23 s of
scanner time, 38 windows of 100 moves) identified at least 10x faster than real time, with the
process start included (and the pooled estimate: one joint fit of all windows, see
:mod:`galvo_sysid.field.offline`). Each run is a fresh ``galvo-sysid identify BAG --json`` process,
timed
by wall clock, best and median of ``--repeat`` runs (on a shared machine the best run shows
what the code costs, the median what a busy machine gives). Also printed: how the time grows
with the number of windows (bags of 1, 2, 5, 10 and 19 angles) and the process start alone
(a bag too short for any window).

Last, one paired run on the 19-angle bag (the runs interleaved, so a busy machine slows all
alike): the refined method, ``--method paper-A``, and decoding the bag alone (a fresh process
that reads and pairs every message exactly as ``identify`` does, no fit). Their ratios
(refined / paper-A, paper-A / decoding) say how the code compares with itself, which machines
of this kind reproduce better than absolute times (issue 17).

Usage: ``.venv/bin/python benchmarks/offline_speed.py [--repeat 3] [--jobs N]``
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from galvo_sysid.field.simulate import simulate_bag
from galvo_sysid.model import PAPER_ANGLES

CLI = str(Path(sys.executable).parent / 'galvo-sysid')

DECODE = """
import sys
from galvo_sysid.field.bags.reader import BagReader
from galvo_sysid.model import PAPER_MODEL
from galvo_sysid.monitor.pairing import MoveWindower
with BagReader(sys.argv[1]) as bag:
    pairer = MoveWindower(window_size=100, sample_period=PAPER_MODEL.sample_period)
    windows = sum(len(done) for _, done, _ in bag.feed(pairer))
print(windows)
"""
"""Decoding alone: every message read, decoded and paired into windows, nothing fitted."""


def paired(bag: Path, *, repeat: int, jobs: int | None) -> dict[str, list[float]]:
    """Wall times of refined, paper-A and decoding-only processes, interleaved per repeat."""
    extra = ['--jobs', str(jobs)] if jobs is not None else []
    commands = {
        'refined': [CLI, 'identify', str(bag), '--json', *extra],
        'paper-A': [CLI, 'identify', str(bag), '--json', '--method', 'paper-A', *extra],
        'decoding only': [sys.executable, '-c', DECODE, str(bag)],
    }
    times: dict[str, list[float]] = {name: [] for name in commands}
    for _ in range(repeat):
        for name, args in commands.items():
            start = time.perf_counter()
            proc = subprocess.run(args, capture_output=True, text=True, check=False)
            times[name].append(time.perf_counter() - start)
            if proc.returncode != 0:
                raise SystemExit(f'{name} failed: {proc.stderr.strip()}')
    return times


def timed_identify(bag: Path, *, repeat: int,
                   jobs: int | None) -> tuple[float, float, dict]:
    """Best and median wall time of a fresh identify process, and its JSON output."""
    args = [CLI, 'identify', str(bag), '--json']
    if jobs is not None:
        args += ['--jobs', str(jobs)]
    times = []
    out: dict = {}
    for _ in range(repeat):
        start = time.perf_counter()
        proc = subprocess.run(args, capture_output=True, text=True, check=False)
        times.append(time.perf_counter() - start)
        out = json.loads(proc.stdout) if proc.stdout else {}
    return min(times), statistics.median(times), out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--repeat', type=int, default=5, help='runs per bag')
    parser.add_argument('--jobs', type=int, default=None,
                        help='galvo-sysid identify --jobs (default: its own, one per CPU)')
    args = parser.parse_args()
    cpus = len(os.sched_getaffinity(0))
    load = ', '.join(f'{x:.1f}' for x in os.getloadavg())
    print(f'machine: {cpus} CPU(s) available (load average {load} at start: other work '
          f'slows these numbers), Python {sys.version.split()[0]}; identify --jobs '
          f'{args.jobs or "default (one per CPU)"}; best and median of {args.repeat} runs\n')
    with tempfile.TemporaryDirectory() as tmp:
        short = Path(tmp) / 'short'
        simulate_bag(short, angles=[0.3], moves_per_angle=20)
        start_time, start_median, _ = timed_identify(short, repeat=args.repeat, jobs=args.jobs)
        print(f'process start + imports + reading a 20-move bag (no window): '
              f'{start_time:.2f} s best, {start_median:.2f} s median\n')
        header = (f'{"angles":>6} {"windows":>7} {"moves":>6} {"scanner [s]":>11} '
                  f'{"best [s]":>9} {"x real":>7} {"median [s]":>10} {"x real":>7} '
                  f'{"ms/window":>9}')
        print(header)
        print('-' * len(header))
        rows = []
        for n_angles in (1, 2, 5, 10, 19):
            bag = Path(tmp) / f'a{n_angles}'
            angles = PAPER_ANGLES[::-1][:n_angles] if n_angles < 19 else PAPER_ANGLES
            summary = simulate_bag(bag, angles=list(angles), moves_per_angle=200, seed=n_angles)
            wall, median, out = timed_identify(bag, repeat=args.repeat, jobs=args.jobs)
            windows = len(out.get('windows', []))
            failed = len({r['reason'] for r in out.get('rejected', [])})
            per_window = (wall - start_time) / windows if windows else float('nan')
            rows.append((n_angles, windows, wall, median))
            note = f'  ({failed} window(s) not identified)' if failed else ''
            real = summary.scanner_time
            print(f'{n_angles:>6} {windows:>7} {summary.moves:>6} {real:>11.2f} '
                  f'{wall:>9.2f} {real / wall:>7.1f} {median:>10.2f} {real / median:>7.1f} '
                  f'{1e3 * per_window:>9.0f}{note}')
        (_, w0, t0, _), (_, w1, t1, _) = rows[0], rows[-1]
        slope = (t1 - t0) / (w1 - w0)
        print(f'\nbest runs: time grows linearly with the windows, about {1e3 * slope:.0f} ms '
              f'per window (wall, fits in parallel) on top of {t0 - slope * w0:.2f} s')
        pooled = out.get('pooled') or {}
        print(f'pooled estimate of the last bag: {pooled.get("pooling")} over '
              f'{pooled.get("pooled_windows")} windows'
              + (f' ({pooled["pooling_note"]})' if pooled.get('pooling_note') else ''))
        _, _, full, full_median = rows[-1]
        print(f'19 angles x 200 moves: {full:.2f} s best, {full_median:.2f} s median for '
              f'23.0 s of scanner time = {23.03 / full:.1f}x / {23.03 / full_median:.1f}x '
              f'real time (target: >= 20x)')
        times = paired(Path(tmp) / 'a19', repeat=args.repeat, jobs=args.jobs)
        load = ', '.join(f'{x:.1f}' for x in os.getloadavg())
        print(f'\npaired run on the 19-angle bag ({args.repeat} interleaved repeats; load '
              f'average {load} at the end):\n')
        print(f'{"process":<14} {"best [s]":>9} {"median [s]":>10} {"x real (best)":>13}')
        best = {name: min(t) for name, t in times.items()}
        for name, t in times.items():
            print(f'{name:<14} {min(t):>9.2f} {statistics.median(t):>10.2f} '
                  f'{23.03 / min(t):>13.1f}')
        print(f'\nrefined / paper-A = {best["refined"] / best["paper-A"]:.2f} (target <= 1.3); '
              f'paper-A / decoding only = {best["paper-A"] / best["decoding only"]:.2f} '
              f'(target <= 2)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
