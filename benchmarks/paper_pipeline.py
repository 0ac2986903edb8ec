"""Benchmark of the paper's pipeline: methods A and B, solvers, delay handling, timing.

For several noise seeds and the paper's rotation angles, one window of 100 moves each from the
closed-loop simulator (:func:`galvo_sysid.sim.simulator.simulate_window`) is identified by
:func:`galvo_sysid.ident.paper.paper_pipeline` in several variants:

- ``A``, ``B``: methods A (average) and B (concatenation), normal equations, delay 1.6 T;
- ``A-qr``, ``B-qr``: the same solved by QR;
- ``A-nodelay``: method A without the fictitious input (delay 0);
- ``A-est``: method A with the delay estimated from the data.

It prints the median and 90th-percentile |relative error| [%] per parameter (at 1 psi and
over all angles) next to the paper's Table II, cond(R) per angle, the estimated delays, the
whole-model (matrix logarithm) conversion failures, and the time per window.

Run from the repository root::

    python benchmarks/paper_pipeline.py               # 3 seeds, all 19 angles
    python benchmarks/paper_pipeline.py --quick       # 2 seeds, 5 angles

BLAS threads are limited to one (set before numpy loads), as for the other benchmarks.
"""

from __future__ import annotations

import os

os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')
os.environ.setdefault('OMP_NUM_THREADS', '1')

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from galvo_sysid.errors import GalvoSysidError
from galvo_sysid.ident.decompose import arx_to_continuous, continuous_modal_decomposition
from galvo_sysid.ident.paper import paper_pipeline
from galvo_sysid.model import PAPER_ANGLES, PAPER_TABLE_II, PSI, REFERENCE_MODEL, TAU
from galvo_sysid.sim.simulator import simulate_window

VARIANTS: dict[str, dict[str, Any]] = {
    'A': {'method': 'A'},
    'B': {'method': 'B'},
    'A-qr': {'method': 'A', 'solver': 'qr'},
    'B-qr': {'method': 'B', 'solver': 'qr'},
    'A-nodelay': {'method': 'A', 'delay': 0.0},
    'A-est': {'method': 'A', 'delay': None},
}
NAMES = list(REFERENCE_MODEL.parameters())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seeds', type=int, nargs='+', default=[0, 1, 2])
    parser.add_argument('--quick', action='store_true', help='2 seeds, 5 angles')
    args = parser.parse_args()
    seeds = args.seeds[:2] if args.quick else args.seeds
    angles = [0.1 * PSI, 0.5 * PSI, PSI, 3 * PSI, 10 * PSI] if args.quick else list(PAPER_ANGLES)

    errors: dict[tuple[str, float], list[list[float]]] = {}
    conds: dict[tuple[str, float], list[float]] = {}
    delays: list[float] = []
    times: dict[str, list[float]] = {}
    logm_fail = {'A': 0, 'B': 0}
    failures: dict[str, int] = {}
    n_windows = 0
    for seed in seeds:
        for angle in angles:
            cur, enc = simulate_window(angle, moves=100, seed=seed)
            n_windows += 1
            for label, kwargs in VARIANTS.items():
                t0 = time.perf_counter()
                try:
                    res = paper_pipeline(cur, enc, sample_period=TAU, **kwargs)
                except GalvoSysidError as exc:
                    failures[label] = failures.get(label, 0) + 1
                    print(f'  {label} {angle:.3g} deg seed {seed}: {exc}')
                    continue
                times.setdefault(label, []).append(time.perf_counter() - t0)
                errors.setdefault((label, angle), []).append(
                    [100 * v for v in res.relative_errors().values()])
                conds.setdefault((label, angle), []).append(res.cond)
                if label == 'A-est':
                    delays.append(res.delay / TAU)
                if label in logm_fail:
                    try:
                        continuous_modal_decomposition(arx_to_continuous(res.arx))
                    except GalvoSysidError:
                        logm_fail[label] += 1

    def stats(label: str, which: list[float]) -> tuple[np.ndarray, np.ndarray]:
        rows = np.abs(np.array([e for a in which for e in errors.get((label, a), [])]))
        return np.median(rows, axis=0), np.percentile(rows, 90, axis=0)

    for title, which in ((f'1 psi ({len(seeds)} windows)', [PSI]),
                         (f'all {len(angles)} angles ({len(seeds) * len(angles)} windows)',
                          angles)):
        print(f'\nmedian | 90th percentile |relative error| [%], {title}')
        print('param    ' + ''.join(f'{label:>19}' for label in VARIANTS)
              + f'{"paper A":>9}{"paper B":>9}')
        cols = [stats(label, which) for label in VARIANTS]
        for i, name in enumerate(NAMES):
            cells = ''.join(f'{med[i]:9.3g} |{p90[i]:8.3g}' for med, p90 in cols)
            print(f'{name:9}{cells}{abs(PAPER_TABLE_II["A"][name]):9.4g}'
                  f'{abs(PAPER_TABLE_II["B"][name]):9.4g}')

    print('\ncond(R) of the normal equations (median over seeds)')
    print('angle [psi]' + ''.join(f'{label:>10}' for label in ('A', 'B', 'A-qr', 'B-qr')))
    for angle in angles:
        print(f'{angle / PSI:11.1f}' + ''.join(
            f'{np.median(conds[(label, angle)]):10.2e}' for label in ('A', 'B', 'A-qr', 'B-qr')))

    d = np.array(delays)
    print(f'\nestimated delay [T]: median {np.median(d):.3f}, range {d.min():.3f} .. {d.max():.3f}'
          f' (truth: 1 sample + 0.6 T lag, equivalent 1.6 T)')
    print(f'whole-model logm conversion failed (complex, negative-real poles): '
          f'A {logm_fail["A"]}/{n_windows}, B {logm_fail["B"]}/{n_windows} windows; '
          f'block conversion failures: {failures or "none"}')
    print('\ntime per window [ms] (one BLAS thread): median | 90th percentile')
    for label, t in times.items():
        print(f'  {label:10} {1e3 * np.median(t):7.1f} | {1e3 * np.percentile(t, 90):7.1f}')


if __name__ == '__main__':
    main()
