"""Confusion table of the discrepancy workflow (issue 6): effects x magnitudes x seeds.

Each case runs the closed-loop simulator (galvo_sysid.sim.simulator) with one hidden physical
effect, at the angles 0.1, 1 and 10 psi (moves alternating +angle/-angle), and hands only
the recorded moves (current, encoder, target angle, move id, stamp) to
``find_discrepancy`` with the nominal model. The table shows how often the effect is named
(first effect found), the error of its parameters, and the gap before and after; the
no-effect cases give the false-alarm rate.

Targets (issue 6): every effect named in >= 95 % of its cases, false alarms on no-effect
data <= 5 %, gap after <= half the gap before.

Usage::

    python benchmarks/discrepancy_confusion.py                 # 3 seeds, ~3 min on 2 cores
    python benchmarks/discrepancy_confusion.py --seeds 10 --jobs 2
    python benchmarks/discrepancy_confusion.py --quick         # 1 seed, fewer moves
    python benchmarks/discrepancy_confusion.py --effects coulomb_friction --seeds 20
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import statistics
import sys
import time
from dataclasses import replace
from typing import Any

for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')

from galvo_sysid.discrepancy import MoveSet, find_discrepancy  # noqa: E402
from galvo_sysid.model import PSI, TAU  # noqa: E402

CASES: dict[str, list[tuple[str, dict[str, float]]]] = {
    'input_delay': [('+0.3 tau', {'delay': 1.9 * TAU}), ('+1 tau', {'delay': 2.6 * TAU})],
    'unmodeled_resonance': [
        ('k=3e4', {'natural_frequency': 3e4, 'damping_ratio': 0.02, 'residue': 3e4}),
        ('k=1e5', {'natural_frequency': 3e4, 'damping_ratio': 0.02, 'residue': 1e5})],
    'coulomb_friction': [('10 mA', {'friction_current': 0.01}),
                         ('30 mA', {'friction_current': 0.03})],
    'pivot_stiffness': [('200 rad/s', {'natural_frequency': 200.0}),
                        ('500 rad/s', {'natural_frequency': 500.0})],
    'gain_change': [('0.97', {'gain_ratio': 0.97}), ('0.90', {'gain_ratio': 0.90})],
    'current_saturation': [('0.95 A', {'current_limit': 0.95}),
                           ('0.80 A', {'current_limit': 0.80})],
}
"""Each effect at two magnitudes (the truth the simulator runs)."""

ANGLES = (0.1 * PSI, PSI, 10 * PSI)


def simulate(effect: str | None, params: dict[str, float], *, seed: int,
             moves_per_angle: int) -> MoveSet:
    """Moves of the simulated scanner with one effect (or none)."""
    from galvo_sysid.model import PAPER_MODEL
    from galvo_sysid.sim.config import SimulatorConfig
    from galvo_sysid.sim.simulator import GalvoSimulator

    cfg = SimulatorConfig()
    if effect is not None:
        cfg = replace(cfg, plant=PAPER_MODEL.with_effect(effect, params))
    sim = GalvoSimulator(config=cfg, seed=seed)
    return MoveSet.from_moves(sim.moves(angles=list(ANGLES), moves_per_angle=moves_per_angle))


_SHORT = {'delay': 'D', 'natural_frequency': 'w', 'damping_ratio': 'zeta', 'residue': 'k',
          'friction_current': 'F', 'gain_ratio': 'g', 'current_limit': 'I'}


def _errors(truth: dict[str, float], found: dict[str, float]) -> dict[str, float]:
    """Relative error of each parameter, by short name."""
    return {_SHORT[k]: (found[k] - v) / v for k, v in truth.items() if k in found}


def run_case(case: tuple[str | None, str, dict[str, float], int, int]) -> dict[str, Any]:
    """Simulate and analyse one case."""
    effect, label, params, seed, moves_per_angle = case
    moves = simulate(effect, params, seed=seed, moves_per_angle=moves_per_angle)
    start = time.perf_counter()
    result = find_discrepancy(moves)
    seconds = time.perf_counter() - start
    named = result.effect
    errors = _errors(params, result.parameters) if effect and named == effect else {}
    return {'effect': effect or 'none', 'label': label, 'seed': seed, 'named': named,
            'steps': [s.effect for s in result.steps], 'errors': errors,
            'gap_before': result.gap_before, 'gap_after': result.gap_after,
            'seconds': seconds}


def _pct(x: float) -> str:
    return f'{100 * x:.2g} %'


def report(rows: list[dict[str, Any]]) -> bool:
    """Print the tables; return True if every target is met."""
    print()
    print('Per effect and magnitude (medians over seeds; gap in noise-floor units, see '
          'docs/discrepancy.md; parameters: D delay, w natural frequency, zeta damping, '
          'k residue, F friction, g gain, I current limit)')
    head = (f'{"effect":<20} {"magnitude":<10} {"named":>7} {"parameter error, median |.|":<29}'
            f' {"gap before":>10} {"gap after":>9} {"halved":>7} {"s/case":>6}')
    print(head)
    print('-' * len(head))
    ok = True
    per_effect: dict[str, list[bool]] = {}
    keys = list(dict.fromkeys((r['effect'], r['label']) for r in rows))
    for effect, label in keys:
        sel = [r for r in rows if r['effect'] == effect and r['label'] == label]
        n = len(sel)
        if effect == 'none':
            hits = sum(r['named'] == 'none' for r in sel)
        else:
            hits = sum(r['named'] == effect for r in sel)
            per_effect.setdefault(effect, []).extend(r['named'] == effect for r in sel)
        names = sorted({k for r in sel for k in r['errors']})
        errs = ', '.join(
            f'{k} {_pct(statistics.median(abs(r["errors"][k]) for r in sel if k in r["errors"]))}'
            for k in names) or '-'
        halved = sum(r['gap_after'] <= 0.5 * r['gap_before'] for r in sel
                     if r['gap_before'] > 0)
        with_gap = sum(r['gap_before'] > 0 for r in sel)
        gb = statistics.median(r['gap_before'] for r in sel)
        ga = statistics.median(r['gap_after'] for r in sel)
        secs = statistics.mean(r['seconds'] for r in sel)
        halved_txt = f'{halved}/{with_gap}' if with_gap and effect != 'none' else '-'
        print(f'{effect:<20} {label:<10} {hits:>3}/{n:<3} {errs:<29} {gb:>10.3g} {ga:>9.3g} '
              f'{halved_txt:>7} {secs:>6.1f}')
        if effect != 'none' and halved < with_gap:
            ok = False
    # confusion matrix
    names = ['none', *CASES]
    print()
    print('Confusion (rows: hidden effect, columns: first effect named)')
    short = {'none': 'none', 'input_delay': 'delay', 'unmodeled_resonance': 'reson',
             'coulomb_friction': 'frict', 'pivot_stiffness': 'pivot', 'gain_change': 'gain',
             'current_saturation': 'satur'}
    print(f'{"":<20}' + ''.join(f'{short[c]:>7}' for c in names))
    for truth in names:
        sel = [r for r in rows if r['effect'] == truth]
        if not sel:
            continue
        print(f'{truth:<20}' + ''.join(f'{sum(r["named"] == c for r in sel):>7}'
                                       for c in names))
    print()
    print('Targets')
    for effect, hits in per_effect.items():
        rate = sum(hits) / len(hits)
        good = rate >= 0.95
        ok &= good
        print(f'  {effect:<20} named in {100 * rate:5.1f} % of {len(hits)} cases '
              f'(target >= 95 %) {"ok" if good else "MISSED"}')
    nones = [r for r in rows if r['effect'] == 'none']
    if nones:
        alarms = sum(r['named'] != 'none' for r in nones) / len(nones)
        good = alarms <= 0.05
        ok &= good
        print(f'  {"no effect":<20} false alarms {100 * alarms:5.1f} % of {len(nones)} cases '
              f'(target <= 5 %) {"ok" if good else "MISSED"}')
    extra = [r for r in rows if r['effect'] != 'none' and len(r['steps']) > 1]
    print(f'  cases with more than one effect added: {len(extra)}'
          + (' (' + '; '.join(f'{r["effect"]} {r["label"]} seed {r["seed"]}: {r["steps"]}'
                              for r in extra[:6]) + ')' if extra else ''))
    return ok


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seeds', type=int, default=3, help='seeds per effect and magnitude')
    parser.add_argument('--none-seeds', type=int, default=None,
                        help='seeds of no-effect data (default: 4 x --seeds)')
    parser.add_argument('--moves-per-angle', type=int, default=40,
                        help='moves per angle (half each sign)')
    parser.add_argument('--effects', nargs='+', choices=list(CASES), default=list(CASES))
    parser.add_argument('--jobs', type=int, default=min(2, os.cpu_count() or 1))
    parser.add_argument('--quick', action='store_true', help='1 seed, 20 moves per angle')
    args = parser.parse_args(argv)
    if args.quick:
        args.seeds, args.moves_per_angle = 1, 20
    none_seeds = 4 * args.seeds if args.none_seeds is None else args.none_seeds
    cases: list[tuple[str | None, str, dict[str, float], int, int]] = [
        (effect, label, params, 1000 + seed, args.moves_per_angle)
        for effect in args.effects for label, params in CASES[effect]
        for seed in range(args.seeds)]
    cases += [(None, '-', {}, 5000 + seed, args.moves_per_angle) for seed in range(none_seeds)]
    print(f'discrepancy confusion: {len(cases)} cases ({args.seeds} seed(s) per effect and '
          f'magnitude, {none_seeds} without effect), angles {", ".join(f"{a:g}" for a in ANGLES)}'
          f' deg, {args.moves_per_angle} moves per angle, {args.jobs} job(s)')
    start = time.perf_counter()
    if args.jobs > 1:
        with multiprocessing.get_context('fork').Pool(args.jobs) as pool:
            rows = pool.map(run_case, cases, chunksize=1)
    else:
        rows = [run_case(c) for c in cases]
    ok = report(rows)
    print(f'\n{len(cases)} cases in {time.perf_counter() - start:.0f} s wall '
          f'({sum(r["seconds"] for r in rows):.0f} s of analysis)')
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
