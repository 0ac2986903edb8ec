"""Where a window's estimate lies far off: does maximum likelihood itself land there too?

Where a window's estimate lies several Cramer-Rao bounds from the truth, two causes differ:
the search missed a lower-cost basin near the truth (the estimator's fault), or the
likelihood itself is lowest out there (the threshold effect of frequency estimation at low
signal: maximum likelihood is not efficient, and no unbiased estimator reaches the bound).
For each noise seed this script identifies ``benchmarks/efficiency.py``'s window of a
generated scanner (``identify_window``, the refined fit), then polishes the same cost (the
same prewhitened problem, the fit's noise model) from the true modes and lag, and prints the
mode's frequency, damping and cost both ways, and the cost at the truth itself.

The fit's problem is kept by wrapping the refined fit's last step (``fit._result``, which
receives it): this script reads it, the fit is unchanged.

With ``--residues k0 k1 ...`` it also takes those shared coefficients of both solutions
(relative errors over the window's exact bound, as ``efficiency.py`` scores them) and ends
with their median |error| / bound over the seeds, against the must-show's 1.25 x 0.674: where
maximum likelihood polished from the truth itself stays above it, no estimator that finds
the likelihood's optimum meets that median (a seed range such as ``--seeds 0-199``). A third
figure polishes the same problem, from the fit, whitened and weighed with the simulator's exact
noise instead of the noise model the fit estimated (``residual_noise_autocovariance``, the
bound's own noise): the likelihood with the noise known. Where that meets the median and the
fit's does not, what the fit loses is in its noise model.

Usage: ``.venv/bin/python benchmarks/ml_from_truth.py --scanner 32 --mode 5 --seeds 8 237``
"""

from __future__ import annotations

import argparse
import datetime
import math
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from galvo_sysid.ident.refine import fit as refine_fit_module
from galvo_sysid.ident.refine.checks import bounds
from galvo_sysid.ident.refine.options import DEFAULT_LAG_BOUNDS
from galvo_sysid.ident.refine.whitener import Whitener
from galvo_sysid.sim.noise import residual_noise_autocovariance

sys.path.insert(0, str(Path(__file__).resolve().parent))
import efficiency  # the benchmark's conditions and windows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--scanner', type=int, required=True, help='seed of the scanner')
    parser.add_argument('--mode', type=int, required=True, help='mode number (1 = lowest)')
    parser.add_argument('--seeds', type=_seeds, nargs='+', required=True,
                        help='noise seeds (a range as FIRST-LAST)')
    parser.add_argument('--residues', nargs='*', default=[], metavar='NAME',
                        help='shared coefficients (k0, k1, ...) to score both ways')
    args = parser.parse_args(argv)
    args.seeds = [seed for chunk in args.seeds for seed in chunk]
    cond = efficiency.conditions((args.scanner,), family_only=True)[0]
    truth = cond.truth
    i = args.mode - 1
    if not 0 <= i < truth.modal.n_modes:
        parser.error(f'scanner {args.scanner} has modes 1..{truth.modal.n_modes}')
    kept: dict[str, Any] = {}
    last_step = refine_fit_module._result

    def keep(joint: Any, x: Any, band_list: Any, profiles: Any, **kw: Any) -> Any:
        kept.update(joint=joint, x=np.array(x), bands=band_list)
        return last_step(joint, x, band_list, profiles, **kw)

    refine_fit_module._result = keep  # type: ignore[assignment]
    load = ', '.join(f'{v:.2f}' for v in os.getloadavg())
    print(f'{cond.name}, mode {args.mode}: the fit against maximum likelihood polished from '
          f'the truth; {datetime.datetime.now().isoformat(timespec="seconds")}, load {load}')
    hz = 1.0 / (2.0 * math.pi)
    w_true = truth.modal.natural_frequencies[i]
    print(f'truth: {w_true * hz:.1f} Hz, zeta {truth.modal.damping_ratios[i]:.4g}')
    print(f'{"seed":>5} {"fit Hz":>9} {"zeta":>8} {"err/bound":>9} {"cost":>9} '
          f'{"truth cost":>10} {"from truth Hz":>13} {"zeta":>8} {"err/bound":>9} {"cost":>9}')
    names = ['k0', *(f'k{j}' for j in range(1, truth.modal.n_modes + 1))]
    unknown = [r for r in args.residues if r not in names]
    if unknown:
        parser.error(f'--residues: {unknown} not among {names}')
    true_k = dict(zip(names, (truth.modal.k0, *truth.modal.residues), strict=True))
    scores: dict[str, tuple[list[float], ...]] = {r: ([], [], []) for r in args.residues}
    for seed in args.seeds:
        window, _ = efficiency.run_window(cond, seed)
        joint, x, band_list = kept['joint'], kept['x'], kept['bands']
        omega, zeta, _ = joint.unpack(x)
        x_true = joint.pack(np.array(truth.modal.natural_frequencies),
                            np.array(truth.modal.damping_ratios),
                            truth.dynamics.lag_time_constant)
        lower, upper = bounds(band_list, joint.estimate_lag, DEFAULT_LAG_BOUNDS)
        inside = np.clip(x_true, lower + 1e-9 * (upper - lower), upper - 1e-9 * (upper - lower))
        sol = least_squares(joint.residual, inside, jac=joint.jacobian, bounds=(lower, upper),
                            x_scale='jac', method='trf', ftol=1e-10, xtol=1e-10, max_nfev=200)
        omega_t, zeta_t, _ = joint.unpack(sol.x)
        bound = window.bounds[f'omega_{args.mode}']  # relative
        print(f'{seed:>5} {omega[i] * hz:>9.1f} {zeta[i]:>8.4g} '
              f'{(omega[i] / w_true - 1) / bound:>+9.2f} {joint.cost(x):>9.2f} '
              f'{joint.cost(x_true):>10.2f} {omega_t[i] * hz:>13.1f} {zeta_t[i]:>8.4g} '
              f'{(omega_t[i] / w_true - 1) / bound:>+9.2f} {joint.cost(sol.x):>9.2f}')
        if not scores:
            continue
        at_fit = dict(zip(names, joint.coefficients(x)[0], strict=False))
        at_ml = dict(zip(names, joint.coefficients(sol.x)[0], strict=False))
        # the same problem whitened and weighed with the exact noise of the window's average
        prob = joint.problems[0]
        noise = residual_noise_autocovariance(cond.config, prob.k.size) / prob.moves
        prob.set_whitening(Whitener.from_autocovariance(noise / noise[0]))
        joint.set_weights([1.0 / math.sqrt(noise[0])])
        known = least_squares(joint.residual, x, jac=joint.jacobian, bounds=(lower, upper),
                              x_scale='jac', method='trf', ftol=1e-10, xtol=1e-10, max_nfev=200)
        at_known = dict(zip(names, joint.coefficients(known.x)[0], strict=False))
        for r in args.residues:
            for got, out in zip((at_fit, at_ml, at_known), scores[r], strict=True):
                out.append(abs(float(got[r]) / true_k[r] - 1.0) / window.bounds[r])
    if scores:
        print(f'median |error| / bound over {len(args.seeds)} seeds (must-show: <= '
              f'{efficiency.MEDIAN_FACTOR:.3f}):')
        for r, (fit_z, ml_z, known_z) in scores.items():
            print(f'  {r}: the fit {np.median(fit_z):.3f} (rms {_rms(fit_z):.3f}), maximum '
                  f'likelihood from the truth {np.median(ml_z):.3f} ({_rms(ml_z):.3f}), with '
                  f'the noise known {np.median(known_z):.3f} ({_rms(known_z):.3f})')
    return 0


def _rms(values: list[float]) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def _seeds(text: str) -> list[int]:
    """A seed (``7``) or a range of them (``0-199``)."""
    first, _, last = text.partition('-')
    try:
        lo, hi = int(first), int(last or first)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not a seed or FIRST-LAST: {text!r}') from None
    if hi < lo:
        raise argparse.ArgumentTypeError(f'an empty range: {text!r}')
    return list(range(lo, hi + 1))


if __name__ == '__main__':
    sys.exit(main())
