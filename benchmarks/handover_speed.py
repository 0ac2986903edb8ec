"""How long a window takes to reach a fit process: shared memory against the pool's pipe.

The sysid node's :class:`~galvo_sysid.monitor.scheduler.WindowScheduler` hands each window to
one of its fit processes. Since 2026-11-27 the records go through a block of shared memory
(:mod:`galvo_sysid.monitor.handover`); before, the whole window was pickled into the process
pool's pipe (what the scheduler still does where shared memory cannot be had). This script
times both: a scheduler with one spawned fit process (the node's were spawned until
2026-11-28 and come from a fork server since; the hand-over is the same) is given ``--windows``
windows of ``--moves`` x 512 samples one after the other, a few ms apart, and the fit
returns at once the time it started (:func:`time.perf_counter` is the machine's monotonic
clock, the same in every process). Reported per way: median, p90 and p99 of submit -> fit
start, first on a quiet machine, then beside ``--hogs`` processes that keep a CPU busy each
(FFTs with short sleeps, as the node's message threads and a publisher do under load).

Usage: ``.venv/bin/python benchmarks/handover_speed.py [--windows 300] [--moves 100]
[--hogs 2]``.
"""

from __future__ import annotations

import os

os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

import argparse
import datetime
import multiprocessing
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from galvo_sysid.monitor.handover import WindowBuffer
from galvo_sysid.monitor.moves import Window
from galvo_sysid.monitor.scheduler import WindowScheduler


def started(window: Window) -> float:
    """The fit: the time it started (picklable for a spawned child)."""
    return time.perf_counter()


def hog(seconds: float) -> None:
    """Keep a CPU busy with FFTs and short sleeps for ``seconds``."""
    a = np.random.default_rng(0).standard_normal((200, 512))
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        np.fft.rfft(a, axis=1)
        time.sleep(0.0003)


def timings(*, windows: int, moves: int, pipe: bool) -> list[float]:
    """Submit -> fit start [ms] of each window, through shared memory or (``pipe``) whole."""
    put = WindowBuffer.put
    if pipe:
        WindowBuffer.put = lambda self, window: None  # type: ignore[method-assign]
    try:
        rng = np.random.default_rng(1)
        out = []
        with WindowScheduler(started, processes=1, start_method='spawn',
                             warm_up=False) as scheduler:
            for i in range(windows):
                w = Window(index=i, target_angle=0.3, sample_period=1e-5,
                           current=rng.standard_normal((moves, 512)),
                           encoder=rng.standard_normal((moves, 512)),
                           move_ids=tuple(range(moves)), first_stamp=0.0, last_stamp=1.0)
                t0 = time.perf_counter()
                scheduler.submit(w)
                outcome = scheduler.take(block=True)[0]
                if i:  # the first also waits for the child to start
                    out.append(1e3 * (float(outcome.result) - t0))  # type: ignore[arg-type]
                time.sleep(0.005)
        return out
    finally:
        WindowBuffer.put = put  # type: ignore[method-assign]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--windows', type=int, default=300)
    parser.add_argument('--moves', type=int, default=100)
    parser.add_argument('--hogs', type=int, default=2)
    args = parser.parse_args()
    if args.windows < 2 or args.moves < 1 or args.hogs < 0:
        parser.error('need --windows >= 2, --moves >= 1, --hogs >= 0')
    load = ', '.join(f'{x:.2f}' for x in os.getloadavg())
    print(f'window hand-over to a fit process: {args.windows} windows of {args.moves} x 512 '
          f'samples ({2 * args.moves * 512 * 8 / 1e3:.0f} kB), one spawned fit process; '
          f'{datetime.datetime.now().isoformat(timespec="seconds")}, {os.cpu_count()} CPUs, '
          f'load average {load}\n')
    print('| beside | way | median [ms] | p90 [ms] | p99 [ms] |\n|---|---|---|---|---|')
    for hogs in (0, args.hogs) if args.hogs else (0,):
        ctx = multiprocessing.get_context('spawn')
        procs: list[Any] = [ctx.Process(target=hog, args=(3600.0,), daemon=True)
                            for _ in range(hogs)]
        for p in procs:
            p.start()
        try:
            for pipe in (True, False):
                t = timings(windows=args.windows, moves=args.moves, pipe=pipe)
                q = np.percentile(t, [50, 90, 99])
                print(f'| {hogs} busy processes | {"pipe (pickled)" if pipe else "shared memory"} '
                      f'| {q[0]:.2f} | {q[1]:.2f} | {q[2]:.2f} |', flush=True)
        finally:
            for p in procs:
                p.terminate()
                p.join()
    print(f'\nload average at the end {os.getloadavg()[0]:.2f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
