"""``galvo-sysid identify``'s warm chains: the same accuracy for less time, on scanners of a family.

``identify_bag`` starts each refined fit from the result of the window two before it (two
chains; :data:`galvo_sysid.field.offline.WARM_CHAINS`), another angle of the same plant where
the moves alternate between the signs (issue 17: no repeated work per window). This benchmark
checks that it costs no accuracy: per scanner (the paper's with noise seeds ``--paper``, and
:func:`galvo_sysid.sim.family.random_scanner` seeds ``--scanners``) one bag is simulated (every
angle of the scanner, 200 moves each: one window of 100 moves per signed angle) and identified
twice with the scanner's true model, with and without the warm start (``warm_start=False``:
every window afresh), one after the other in this process (``jobs=1``: the fits' own CPU).

Counted per window, as ``calibration_tails.py`` counts: k0 and every residue, and the
frequency and damping of every mode the window reports resolved, as z = error / reported std
against the truth. Printed for both: windows, of them fitted from a start, parameters counted,
rms z (each |z| clipped at 10), the counts beyond 3, 4 and 5 std, modes reported unresolved,
failed windows, and the CPU time of ``identify_bag`` (reading, the window fits, the joint fit).
For a calibrated std the shares beyond 3, 4 and 5 are 0.27 %, 0.0063 % and 0.00006 %.

Run: ``.venv/bin/python benchmarks/offline_warm.py [--scanners 0 1 ... 11] [--paper 1 2 3]``
(about 2 minutes with the defaults here).
"""

from __future__ import annotations

import argparse
import datetime
import math
import os
import sys
import tempfile
import time
from pathlib import Path

for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from galvo_sysid import keep_freed_memory  # noqa: E402
from galvo_sysid.field.offline import identify_bag  # noqa: E402
from galvo_sysid.field.results import BagIdentification  # noqa: E402
from galvo_sysid.field.simulate import simulate_bag  # noqa: E402
from galvo_sysid.model import PAPER_ANGLES, PAPER_MODEL, PlantModel  # noqa: E402
from galvo_sysid.sim.family import random_scanner  # noqa: E402

Z_CLIP = 10.0
"""|z| above this counts as this in the rms (one wild window does not set it)."""


def _scanners(paper: list[int], family: list[int]) -> list[tuple[str, PlantModel, dict]]:
    """(name, true model, simulate_bag arguments) of every scanner to run."""
    out: list[tuple[str, PlantModel, dict]] = [
        (f'paper seed {s}', PAPER_MODEL, {'angles': list(PAPER_ANGLES), 'seed': s})
        for s in paper]
    for s in family:
        sc = random_scanner(s)
        out.append((f'scanner-{s}', sc.model, {'angles': list(sc.angles), 'seed': 500 + s,
                                              'config': sc.config}))
    return out


def _count(found: BagIdentification, truth: PlantModel, tally: dict[str, list[float]]) -> None:
    """Add the z of each counted parameter of the bag's windows to ``tally``."""
    ref = truth.modal.parameters()
    for w in found.windows:
        r = w.result
        tally['windows'].append(1.0)
        tally['warm'].append(float(r.warm_started))
        tally['unresolved'].append(float(sum(not x for x in r.resolved)))
        est, std = r.model.parameters(), r.std_by_name()
        for name, value in ref.items():
            mode = int(name.rsplit('_', 1)[1]) if name.startswith(('omega_', 'zeta_')) else 0
            if mode and not r.resolved[mode - 1]:
                continue  # an unresolved mode's frequency and damping say nothing
            tally['z'].append((est[name] - value) / std[name] if std[name] > 0 else math.inf)


def main() -> int:
    keep_freed_memory()  # as the entry points do
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--scanners', type=int, nargs='*', default=list(range(12)),
                        help='random_scanner seeds (default 0..11)')
    parser.add_argument('--paper', type=int, nargs='*', default=[1, 2, 3],
                        help="noise seeds of the paper's scanner (default 1 2 3)")
    args = parser.parse_args()
    load = ', '.join(f'{x:.2f}' for x in os.getloadavg())
    runs = _scanners(args.paper, args.scanners)
    print(f'identify_bag with and without its warm chains: {len(runs)} scanners, one bag each '
          f'(every angle x 200 moves), the true model, jobs=1; '
          f'{datetime.datetime.now().isoformat(timespec="seconds")}, load average {load}\n')
    tallies = {warm: {k: [] for k in ('windows', 'warm', 'z', 'unresolved', 'cpu', 'failed')}
               for warm in (False, True)}
    with tempfile.TemporaryDirectory() as tmp:
        for i, (name, truth, sim) in enumerate(runs):
            bag = Path(tmp) / f'bag{i}'
            simulate_bag(bag, moves_per_angle=200, **sim)
            for warm in (False, True):
                t = tallies[warm]
                c0 = time.process_time()
                found = identify_bag(bag, model=truth, warm_start=warm, jobs=1)
                t['cpu'].append(time.process_time() - c0)
                t['failed'].append(float(len(found.mismatched)))
                _count(found, truth, t)
            print(f'  {name}: {len(found.windows)} windows, {tallies[True]["cpu"][-1]:.2f} s '
                  f'warm against {tallies[False]["cpu"][-1]:.2f} s afresh', flush=True)
    print(f'\n{"":10} {"windows":>8} {"warm":>5} {"params":>7} {"rms z":>6} {">3":>4} '
          f'{">4":>4} {">5":>4} {"unres":>6} {"failed":>6} {"CPU s":>7} {"per window":>10}')
    for warm in (False, True):
        t = tallies[warm]
        z = np.clip(np.abs(np.array(t['z'])), 0.0, Z_CLIP)
        n = int(sum(t['windows']))
        print(f'{"warm" if warm else "afresh":10} {n:>8} {int(sum(t["warm"])):>5} {z.size:>7} '
              f'{math.sqrt(float(np.mean(z ** 2))):>6.3f} {int(np.sum(z > 3)):>4} '
              f'{int(np.sum(z > 4)):>4} {int(np.sum(z > 5)):>4} {int(sum(t["unresolved"])):>6} '
              f'{int(sum(t["failed"])):>6} {sum(t["cpu"]):>7.1f} '
              f'{1e3 * sum(t["cpu"]) / max(n, 1):>8.0f} ms')
    print(f'\nload average at the end {os.getloadavg()[0]:.2f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
