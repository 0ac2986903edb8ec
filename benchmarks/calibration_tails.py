"""Confident wrong answers: how often a window's error lies beyond 3, 4 and 5 reported std.

The other accuracy benchmarks judge the rms of error / std; a window that says a parameter is
known to 1 % when it is 10 % off hides in an rms of hundreds. This one counts the tails over
the scanner family (:func:`galvo_sysid.sim.family.random_scanner`, ``--scanners`` seeds from
``--first``, default 0..39),
at the reference move (0.3 deg where it fits) and at fractions of it (weaker moves excite the
upper modes less: their cost has several noisy basins and a lightly damped fit's cost is flat
beyond a narrow peak, where the linearised std claims too much).

Per scanner, move size and noise seed (``--noise``), the first 100 moves of each direction are
identified with the scanner's true model (:func:`galvo_sysid.ident.identify.identify_window`).
Counted per window: k0 and every residue, and the frequency and damping of every mode the
window reports resolved (an unresolved mode's frequency and damping carry its band's std and
say nothing). For a calibrated Gaussian std the shares beyond 3, 4 and 5 std would be 0.27 %,
0.0063 % and 0.00006 %. Printed per move size: windows, parameters counted, the counts beyond
3, 4 and 5 std, rms(error / std) (each |z| clipped at 10), modes reported unresolved, and
every error beyond 4 std.

Run: ``.venv/bin/python benchmarks/calibration_tails.py [--scanners 40] [--first 0] [--noise 2]
[--fractions 1 0.5]`` (about 40 s per move size here, two processes).
"""

from __future__ import annotations

import argparse
import math
import multiprocessing
import os
import sys
import time
from pathlib import Path

for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from galvo_sysid import keep_freed_memory  # noqa: E402
from galvo_sysid.errors import GalvoSysidError  # noqa: E402
from galvo_sysid.ident.identify import identify_window  # noqa: E402
from galvo_sysid.sim.family import random_scanner  # noqa: E402
from galvo_sysid.sim.simulator import GalvoSimulator  # noqa: E402

Z_CLIP = 10.0
"""|error / std| above this counts as this in the rms (one wild window does not set it)."""


def windows(seed: int, noise: int, fraction: float) -> list[dict[str, object]]:
    """Both directions' windows of one scanner, move size and noise seed: z per parameter."""
    sc = random_scanner(seed)
    angle = fraction * sc.reference_angle
    sim = GalvoSimulator(config=sc.config, seed=20_000 + 10 * seed + noise)
    moves = list(sim.moves(angles=[angle], moves_per_angle=200))
    ref = sc.model.modal.parameters()
    out: list[dict[str, object]] = []
    for sign in (1.0, -1.0):
        ms = [m for m in moves if m.target_angle == sign * angle][:100]
        cur = np.array([m.current for m in ms])
        enc = np.array([m.encoder for m in ms])
        row: dict[str, object] = {'seed': seed, 'noise': noise, 'sign': sign}
        try:
            r = identify_window(cur, enc, sample_period=sc.model.sample_period, model=sc.model,
                                target_angle=sign * angle)
        except GalvoSysidError as exc:
            row['error'] = type(exc).__name__
            out.append(row)
            continue
        est, std = r.model.parameters(), r.std_by_name()
        z = {}
        for name in ref:
            mode = int(name.rsplit('_', 1)[1]) if '_' in name else 0
            if mode and not r.resolved[mode - 1]:
                continue  # an unresolved mode's frequency and damping say nothing
            z[name] = (est[name] - ref[name]) / std[name] if std[name] > 0 else math.inf
        row['z'] = z
        row['unresolved'] = sum(not x for x in r.resolved)
        out.append(row)
    return out


def _job(args: tuple[int, int, float]) -> list[dict[str, object]]:
    return windows(*args)


def summarise(fraction: float, rows: list[dict[str, object]]) -> None:
    """Print one move size's line and its errors beyond 4 std."""
    zs: list[float] = []
    wild = []
    failed = sum('error' in r for r in rows)
    unresolved = 0
    for r in rows:
        if 'z' not in r:
            continue
        unresolved += int(r['unresolved'])  # type: ignore[call-overload]
        for name, z in r['z'].items():  # type: ignore[attr-defined]
            zs.append(abs(z))
            if abs(z) > 4:
                wild.append(f'seed {r["seed"]} noise {r["noise"]} sign {r["sign"]:+.0f} '
                            f'{name} {z:+.1f}')
    a = np.array(zs)
    rms = math.sqrt(float(np.mean(np.minimum(a, Z_CLIP) ** 2))) if a.size else math.nan
    print(f'{fraction:>8g} {len(rows):>7} {failed:>6} {a.size:>7} {int(np.sum(a > 3)):>5} '
          f'{int(np.sum(a > 4)):>5} {int(np.sum(a > 5)):>5} {rms:>6.3f} {unresolved:>6}')
    for line in wild:
        print(f'{"":>10}beyond 4 std: {line}')


def main() -> int:
    keep_freed_memory()
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--scanners', type=int, default=40, help='scanners of the family')
    parser.add_argument('--first', type=int, default=0, help='seed of the first scanner')
    parser.add_argument('--noise', type=int, default=2, help='noise seeds per scanner and size')
    parser.add_argument('--fractions', nargs='+', type=float, default=[1.0, 0.5],
                        help='move sizes as fractions of the reference move')
    args = parser.parse_args()
    seeds = range(args.first, args.first + args.scanners)
    print(f'calibration tails: scanners {seeds[0]}..{seeds[-1]} of the family, {args.noise} noise '
          f'seeds, both directions, 100 moves per window; {time.strftime("%Y-%m-%d %H:%M")}, '
          f'load average {os.getloadavg()[0]:.2f} at the start')
    print('(expected for a calibrated Gaussian std: 0.27 % beyond 3, 0.0063 % beyond 4, '
          '0.00006 % beyond 5)')
    print()
    print(f'{"fraction":>8} {"windows":>7} {"failed":>6} {"params":>7} {">3sd":>5} {">4sd":>5} '
          f'{">5sd":>5} {"rms z":>6} {"unres":>6}')
    start = time.perf_counter()
    with multiprocessing.get_context('fork').Pool(2) as pool:
        for fraction in args.fractions:
            jobs = [(s, k, fraction) for s in seeds for k in range(args.noise)]
            rows = [r for part in pool.map(_job, jobs) for r in part]
            summarise(fraction, rows)
    print(f'\nfinished in {time.perf_counter() - start:.0f} s, load average '
          f'{os.getloadavg()[0]:.2f} at the end')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
