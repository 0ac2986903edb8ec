"""Where a window's refined fit spends its time: the stages of ``identify_window``, per window.

Simulates single windows of 100 moves and identifies each with ``identify_window`` (the
sysid node's default, the refined fit), one at a time in one process (the time a window takes
on this machine when its fit is the only job; ``benchmarks/efficiency.py`` runs two fits at
once and prints their wall time too, which the other fit's use of the memory bus lengthens by
about a tenth):

- by default, windows of the paper's scanner (the paper's 19 angles, noise seeds
  0..``--windows``-1 in turn);
- with ``--family``, issue 13's benchmark family: each condition of
  ``benchmarks/efficiency.py`` (moves, controllers, noise, scanners of the generated family)
  with noise seeds 0..``--windows``-1, identified with the condition's true model as the
  scanner's model, as there. The median over all of them is issue 13's "time per window".

Each stage is timed by wrapping the functions that run it:

- ``screen``: the moves' screening (:func:`galvo_sysid.ident.identify._screen`);
- ``start (ARX)``: the paper pipeline whose model starts the fit;
- ``starts (scan)``: the frequency scans that choose the starts;
- ``polish``: every ``least_squares`` run (stage 1 from each start, stage 2, a profile's
  re-polish);
- ``prewhiten``: the noise model from the moves' scatter;
- ``profiles``: the weakly excited modes' scans over their bands;
- ``result``: covariance, Cramer-Rao bound, checks and the strong modes' local profiles.

With ``--warm``, each window's fit starts from the previous window of its condition (or
angle), as the sysid node's do (:mod:`galvo_sysid.ident.warm`). Each sequence starts from a
window of another noise seed (``START_SEED`` on), fitted afresh first and untimed, so no fit
starts from the result of its own data (which would converge at once).

It prints, per stage, the mean wall time per window, its share, and the calls per window; the
median time per window; the machine's load. For a finer view, the same windows can be
profiled line by line (``pip install line_profiler``; not a dependency of the project)::

    python -m cProfile -o /tmp/fit.prof benchmarks/fit_stages.py --windows 10
    python -c "import pstats; pstats.Stats('/tmp/fit.prof').sort_stats('tottime').print_stats(30)"

Usage: ``.venv/bin/python benchmarks/fit_stages.py [--windows 20] [--family] [--warm]``
(``--family`` with ``--windows 3``: 42 windows, about 10 s).
"""

from __future__ import annotations

import os

os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')
os.environ.setdefault('OMP_NUM_THREADS', '1')

import argparse
import collections
import datetime
import functools
import statistics
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import galvo_sysid.ident.identify as identify_module
import galvo_sysid.ident.refine.fit as fit_module
from galvo_sysid import keep_freed_memory
from galvo_sysid.ident.refine.joint import JointProblem
from galvo_sysid.ident.warm import WarmStart
from galvo_sysid.model import PAPER_ANGLES, TAU
from galvo_sysid.sim.simulator import simulate_window

START_SEED = 10_000
"""First noise seed of the untimed windows that start the ``--warm`` sequences."""

STAGES: tuple[tuple[Any, str, str], ...] = (
    (identify_module, '_screen', 'screen'),
    (identify_module, 'paper_pipeline', 'start (ARX)'),
    (fit_module, '_starts', 'starts (scan)'),
    (fit_module, 'least_squares', 'polish'),
    (JointProblem, 'prewhiten', 'prewhiten'),
    (fit_module, 'profile_modes', 'profiles'),
    (fit_module, '_result', 'result'),
)
"""(owner, attribute, stage): the functions timed. ``profile_modes`` is also called inside
``_result``'s checks only through ``check_linearised``, which is timed as part of ``result``."""

SECONDS: collections.Counter[str] = collections.Counter()
CALLS: collections.Counter[str] = collections.Counter()


def _timed(function: Any, stage: str) -> Any:
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        start = time.perf_counter()
        try:
            return function(*args, **kwargs)
        finally:
            SECONDS[stage] += time.perf_counter() - start
            CALLS[stage] += 1
    return wrapper


def main() -> int:
    keep_freed_memory()  # as the entry points do: the fits reuse freed memory
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--windows', type=int, default=20,
                        help='windows to fit (with --family: noise seeds per condition)')
    parser.add_argument('--family', action='store_true',
                        help="issue 13's benchmark family (efficiency.py's conditions)")
    parser.add_argument('--warm', action='store_true',
                        help='start each fit from the previous window of its condition or angle '
                             "(the sysid node's warm start)")
    args = parser.parse_args()
    if args.windows < 1:
        parser.error('--windows must be at least 1')
    load = ', '.join(f'{x:.2f}' for x in os.getloadavg())
    windows = _family(args.windows) if args.family else _paper(args.windows)
    firsts = ([] if not args.warm else _family(1, first_seed=START_SEED) if args.family
              else _paper(len(PAPER_ANGLES), first_seed=START_SEED))
    what = (f'{args.windows} noise seeds of each condition of efficiency.py' if args.family
            else 'paper scanner')
    if args.warm:
        what += ', each fit started from the previous window of its condition or angle'
    print(f'fit stages of identify_window (refined), {len(windows)} windows of 100 moves, '
          f'{what}; {datetime.datetime.now().isoformat(timespec="seconds")}, load average '
          f'{load}\n')
    windows[0]()  # imports, caches
    starts: dict[Any, WarmStart | None] = {}
    if args.warm:  # each sequence starts from a window of another seed, fitted afresh, untimed
        for fit in firsts:
            starts[fit.keywords['group']] = WarmStart.from_result(fit())
    for owner, name, stage in STAGES:
        setattr(owner, name, _timed(getattr(owner, name), stage))
    totals = []
    for fit in windows:
        group = fit.keywords['group']
        start = time.perf_counter()
        result = fit(warm_start=starts.get(group))
        totals.append(time.perf_counter() - start)
        if args.warm:
            starts[group] = WarmStart.from_result(result)
    n = len(windows)
    total = sum(totals)
    print(f'{"stage":<15} {"ms/window":>9} {"share":>6} {"calls/window":>12}')
    for _, _, stage in STAGES:
        print(f'{stage:<15} {1e3 * SECONDS[stage] / n:>9.1f} {SECONDS[stage] / total:>6.0%} '
              f'{CALLS[stage] / n:>12.1f}')
    rest = total - sum(SECONDS.values())
    print(f'{"the rest":<15} {1e3 * rest / n:>9.1f} {rest / total:>6.0%}')
    print(f'\nper window: mean {1e3 * total / n:.1f} ms, median '
          f'{1e3 * statistics.median(totals):.1f} ms (target of issue 13: < 60 ms); load '
          f'average at the end {os.getloadavg()[0]:.2f}')
    return 0


def _fit(current: Any, encoder: Any, *, group: Any, **kwargs: Any) -> Any:
    """identify_window, ``group`` naming the window's sequence (its condition or angle)."""
    return identify_module.identify_window(current, encoder, **kwargs)


def _paper(count: int, *, first_seed: int = 0) -> list[Any]:
    """Fits of paper-scanner windows (19 angles in turn, seeds first_seed + 0..count-1)."""
    out = []
    for i in range(count):
        angle = PAPER_ANGLES[i % len(PAPER_ANGLES)]
        cur, enc = simulate_window(angle, moves=100, seed=first_seed + i)
        out.append(functools.partial(_fit, cur, enc, group=angle, sample_period=TAU))
    return out


def _family(seeds: int, *, first_seed: int = 0) -> list[Any]:
    """Fits of efficiency.py's conditions, seeds first_seed + 0..seeds-1 each, as efficiency.py
    fits them."""  # noqa: D205, D209
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import efficiency as eff  # a script beside this one, not a package
    out = []
    for cond in eff.conditions():
        truth = cond.truth
        for seed in range(first_seed, first_seed + seeds):
            cur, enc = simulate_window(cond.angle, moves=100, seed=seed, config=cond.config)
            out.append(functools.partial(_fit, cur, enc, group=cond.name,
                                         sample_period=truth.sample_period, model=truth,
                                         target_angle=cond.angle))
    return out


if __name__ == '__main__':
    sys.exit(main())
