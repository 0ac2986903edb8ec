"""Scanner family benchmark: commissioning and monitoring on scanners nobody tuned by hand.

For each seed of a fixed list, :func:`galvo_sysid.sim.family.random_scanner` draws a
scanner (sample period 5-50 us, records 256-2,048 samples, 1-5 modes between 1 and 30 kHz
below 0.6 x Nyquist, 1-2 samples of DSP delay, lag 0-1 sample, damping 0.002-0.03, residues
of either sign, controller designed from the model, noise as the default simulator's; see
that module). Then, as a user would:

1. **commission**: 200 moves (100 of each sign) at each move size that fits, the model
   learnt from them with no prior (:func:`galvo_sysid.ident.commission.commission`): modes
   found against the truth, the frequency error of the found modes, the input dynamics; the
   pooled fit's errors against the truth and their size in reported standard deviations;
2. **monitor**: independent windows of 100 moves at 0.3 deg (1 psi; the largest size that
   fits where it does not), each identified with the commissioned model as the sysid node
   would (:func:`galvo_sysid.ident.identify.identify_window`): the share of parameters within
   3 of their reported standard deviations, the windows with an error beyond 5 (a confident
   wrong answer; counted only when the window did not say the data do not match the
   model), mismatches, failures, unresolved modes, time per window.

Run: ``.venv/bin/python benchmarks/scanner_family.py [--seeds 0 1 ...] [--windows 5]``.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time
from pathlib import Path

for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from galvo_sysid import keep_freed_memory  # noqa: E402
from galvo_sysid.errors import GalvoSysidError, ModelMismatchError  # noqa: E402
from galvo_sysid.ident.commission import commission  # noqa: E402
from galvo_sysid.ident.identify import identify_window  # noqa: E402
from galvo_sysid.sim.family import random_scanner  # noqa: E402
from galvo_sysid.sim.simulator import GalvoSimulator  # noqa: E402

SEEDS = tuple(range(20))
"""The fixed list of scanners (seeds of random_scanner)."""


def _windows(sim: GalvoSimulator, angles: tuple[float, ...], moves_per_sign: int) -> list[
        tuple[np.ndarray, np.ndarray]]:
    moves = list(sim.moves(angles=list(angles), moves_per_angle=2 * moves_per_sign))
    out = []
    for a in angles:
        for sign in (1.0, -1.0):
            ms = [m for m in moves if m.target_angle == sign * a]
            out.append((np.array([m.current for m in ms]), np.array([m.encoder for m in ms])))
    return out


def run(seed: int, windows: int) -> dict[str, object]:
    """Commission and monitor one scanner; return its row."""
    sc = random_scanner(seed)
    truth = sc.model
    t0 = time.perf_counter()
    found = commission(_windows(GalvoSimulator(config=sc.config, seed=seed), sc.angles, 100),
                       sample_period=truth.sample_period)
    t_comm = time.perf_counter() - t0
    model = found.model
    row: dict[str, object] = {'seed': seed, 'scanner': sc.describe(), 'true_modes': truth.n_modes,
                              'found_modes': model.n_modes, 'commission_s': t_comm}
    t = truth.sample_period
    row['delay'] = (f'{truth.dynamics.computation_delay}+'
                    f'{truth.dynamics.lag_time_constant / t:.2f} / '
                    f'{model.dynamics.computation_delay}+'
                    f'{model.dynamics.lag_time_constant / t:.2f}')
    match = model.n_modes == truth.n_modes
    if match:
        tw = np.array(truth.modal.natural_frequencies)
        fw = np.array(model.modal.natural_frequencies)
        row['freq_err'] = float(np.max(np.abs(fw / tw - 1)) * 100)
        ref = truth.modal.parameters()
        est = model.modal.parameters()
        std = model.std_by_name()
        rel = [abs(est[n] / ref[n] - 1) * 100 for n in ref]
        z = [abs(est[n] - ref[n]) / std[n] for n in ref if std.get(n, 0) > 0]
        row['pooled_med'] = statistics.median(rel)
        row['pooled_zmax'] = max(z) if z else math.nan
    # monitoring: independent windows at the reference angle, identified with the model
    a = sc.reference_angle
    sim = GalvoSimulator(config=sc.config, seed=10_000 + seed)
    moves = list(sim.moves(angles=[a], moves_per_angle=200 * windows))
    cur = np.array([m.current for m in moves if m.target_angle > 0])
    enc = np.array([m.encoder for m in moves if m.target_angle > 0])
    ok = mismatch = failed = unresolved = within = params = confident_wrong = 0
    times = []
    ref = truth.modal.parameters()
    for w in range(windows):
        c, e = cur[100 * w:100 * (w + 1)], enc[100 * w:100 * (w + 1)]
        t1 = time.perf_counter()
        try:
            r = identify_window(c, e, sample_period=truth.sample_period, model=model,
                                target_angle=a)
        except ModelMismatchError:
            mismatch += 1
            continue
        except GalvoSysidError:
            failed += 1
            continue
        finally:
            times.append(time.perf_counter() - t1)
        ok += 1
        unresolved += sum(not x for x in r.resolved)
        if not match:
            continue
        est = r.model.parameters()
        std = r.std_by_name()
        zs = [abs(est[n] - ref[n]) / std[n] if std[n] > 0 else math.inf for n in ref]
        params += len(zs)
        within += sum(z <= 3 for z in zs)
        confident_wrong += int(any(z > 5 for z in zs))
    row.update(windows_ok=ok, mismatch=mismatch, failed=failed, unresolved=unresolved,
               within=within, params=params, confident_wrong=confident_wrong,
               ms=1e3 * statistics.median(times))
    return row


def main() -> int:
    keep_freed_memory()  # as the entry points do: the fits reuse freed memory
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seeds', nargs='+', type=int, default=list(SEEDS))
    parser.add_argument('--windows', type=int, default=5,
                        help='independent monitoring windows per scanner')
    args = parser.parse_args()
    load = os.getloadavg()[0]
    print(f'scanner family: {len(args.seeds)} scanners (seeds {args.seeds[0]}..'
          f'{args.seeds[-1]}), {args.windows} monitoring windows each; '
          f'{time.strftime("%Y-%m-%d")}, load average {load:.2f} at the start')
    print()
    head = (f'{"seed":>4} {"modes":>9} {"f err%":>7} {"delay true/found":>17} '
            f'{"pooled %":>9} {"max z":>6} {"win ok/mis/fail":>15} {"<=3sd":>6} {">5sd":>5} '
            f'{"unres":>5} {"ms/win":>7} {"comm s":>7}  scanner')
    print(head)
    rows = []
    start = time.perf_counter()
    for seed in args.seeds:
        row = run(seed, args.windows)
        rows.append(row)
        modes = f'{row["found_modes"]}/{row["true_modes"]}'
        ferr = f'{row["freq_err"]:.3g}' if 'freq_err' in row else '-'
        pooled = f'{row["pooled_med"]:.3g}' if 'pooled_med' in row else '-'
        zmax = f'{row["pooled_zmax"]:.2g}' if 'pooled_zmax' in row else '-'
        share = (f'{100 * row["within"] / row["params"]:.0f}%' if row['params'] else '-')
        wins = f'{row["windows_ok"]}/{row["mismatch"]}/{row["failed"]}'
        print(f'{seed:>4} {modes:>9} {ferr:>7} {row["delay"]:>17} {pooled:>9} {zmax:>6} '
              f'{wins:>15} {share:>6} '
              f'{row["confident_wrong"]:>5} {row["unresolved"]:>5} {row["ms"]:7.0f} '
              f'{row["commission_s"]:7.1f}  {row["scanner"]}', flush=True)
    correct = sum(r['found_modes'] == r['true_modes'] for r in rows)
    params = sum(int(r['params']) for r in rows)
    within = sum(int(r['within']) for r in rows)
    wrong = sum(int(r['confident_wrong']) for r in rows)
    total = sum(int(r['windows_ok']) + int(r['mismatch']) + int(r['failed']) for r in rows)
    print()
    print(f'modes found correctly: {correct} of {len(rows)} scanners (target >= 19 of 20)')
    print(f'monitoring windows: {total}, identified {sum(int(r["windows_ok"]) for r in rows)}, '
          f'mismatch {sum(int(r["mismatch"]) for r in rows)}, failed '
          f'{sum(int(r["failed"]) for r in rows)}')
    if params:
        print(f'parameters within 3 reported std: {within} of {params} '
              f'({100 * within / params:.1f} %; target >= 95 %)')
    print(f'windows with an error beyond 5 std and no mismatch said: {wrong} (target 0)')
    print(f'median time per window {statistics.median(float(r["ms"]) for r in rows):.0f} ms; '
          f'total {time.perf_counter() - start:.0f} s; load average {os.getloadavg()[0]:.2f} '
          f'at the end')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
