"""galvo_sysid on data of a simulator it shares no code with: the field path, end to end.

Each scanner of ``test/independent_scanner.py`` (its own plant discretisation, controller,
move profiles and noise; nothing imported from ``galvo_sysid``) is run for
``--moves-per-angle`` moves at each of ``--angles``, and its records go the way a user's own
data go:

1. written to a NumPy ``.npz`` file and put into a bag by ``galvo-sysid import``;
2. identified by ``galvo-sysid identify --model TRUTH --json``, TRUTH the scanner's true
   plant written as a model file (so every window is judged against the truth): per window
   and parameter of a mode it resolves, z = (estimate - truth) / reported std and the error
   over the Cramer-Rao bound the window reports; the pooled estimate's z likewise;
3. commissioned from scratch by ``galvo-sysid commission`` (no model: the first day): the
   number of modes found, the largest relative error of their frequencies, the delay, and
   the z of its parameters against the truth.

With ``--current measured`` the current record is the amplifier's measured output current
(disturbance included, 1 mA sensor noise) read when the encoder is, instead of the command:
the current that flows over a sample is the next sample's reading and the lag's smooth
response between them, which no delay of the model expresses. The first commissioning must
warn (counted: "warned"); the bag is then commissioned with ``--measured-current`` (the
amplifier lag searched: no data sheet) and identified with the model found and
``--measured-current LAG``, LAG the lag found; the truth of the held current is the
scanner's modes behind no delay and its lag.

Printed: one line per scanner and a summary; an estimator whose stds are right gives rms z
near 1 and about 0.3 % of |z| beyond 3. Nothing here was tuned to these scanners: their
seeds are drawn as they come.

Usage: ``.venv/bin/python benchmarks/independent_scanners.py [--seeds 0 1 ...] [--count 8]
[--angles 0.1 0.3 1] [--moves-per-angle 200]`` (about 20 s per scanner here).
"""

from __future__ import annotations

import os

os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

import argparse
import datetime
import json
import math
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test'))

from independent_scanner import Scanner, random_scanner, simulate

from galvo_sysid.model import InputDynamics, ModalModel, PlantModel
from galvo_sysid.model.files import save_model

CLI = str(Path(sys.executable).parent / 'galvo-sysid')


def truth_model(s: Scanner) -> PlantModel:
    """The scanner's true plant as a galvo_sysid model (for ``identify --model``)."""
    return PlantModel(
        modal=ModalModel(k0=s.k0, residues=s.residues, natural_frequencies=s.omegas,
                         damping_ratios=s.zetas),
        dynamics=InputDynamics(computation_delay=s.delay, lag_time_constant=s.lag),
        sample_period=s.sample_period, record_length=s.record, dwell_length=s.dwell,
        description=f'independent scanner, seed {s.seed} (test/independent_scanner.py)')


def _run(args: list[str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run([CLI, *args], capture_output=True, text=True, check=False)


def _truth_vector(s: Scanner) -> dict[str, float]:
    out = {'k0': s.k0}
    for i, (k, w, z) in enumerate(zip(s.residues, s.omegas, s.zetas, strict=True), start=1):
        out[f'k{i}'], out[f'omega_{i}'], out[f'zeta_{i}'] = k, w, z
    return out


def _estimates(res: dict[str, Any]) -> tuple[dict[str, tuple[float, float]], list[bool]]:
    """{name: (estimate, std)} of an identify --json result, and its modes' resolved flags."""
    out = {'k0': (res['k0'], res['k0_std'])}
    for i, (k, w, z, sk, sw, sz) in enumerate(zip(
            res['residues'], res['natural_frequencies'], res['damping_ratios'],
            res['residues_std'], res['natural_frequencies_std'], res['damping_ratios_std'],
            strict=True), start=1):
        out[f'k{i}'], out[f'omega_{i}'], out[f'zeta_{i}'] = (k, sk), (w, sw), (z, sz)
    return out, list(res.get('resolved') or [True] * len(res['residues']))


def _scores(res: dict[str, Any], truth: dict[str, float]) -> tuple[list[float], list[float],
                                                                     int, int]:
    """(z of each parameter of k0 and the resolved modes, error / bound of the same,
    modes resolved, modes)."""  # noqa: D205, D209
    est, resolved = _estimates(res)
    if len(resolved) != sum(1 for name in truth if name.startswith('omega_')):
        return [], [], 0, 0  # a model of other modes than the truth's: no z
    bound = res.get('crlb_std') or {}
    z, e = [], []
    for name, (value, std) in est.items():
        mode = 0 if name == 'k0' else int(name.rsplit('_', 1)[-1] if '_' in name else name[1:])
        if mode and not resolved[mode - 1]:
            continue
        err = value - truth[name]
        z.append(err / std if std > 0 else math.inf)
        b = bound.get(name)
        if b:
            e.append(err / b)
    return z, e, sum(resolved), len(resolved)


def one_scanner(seed: int, *, angles: list[float], moves: int, work: Path,
                current: str = 'command', sensor_noise: float = 1e-3) -> dict[str, Any]:
    """Simulate, import, identify and commission one scanner; its figures."""
    s = random_scanner(seed)
    data = simulate(s, angles=angles, moves_per_angle=moves, seed=0, current=current,
                    sensor_noise=sensor_noise)
    npz, bag = work / f'moves_{seed}.npz', work / f'bag_{seed}'
    np.savez(npz, **data)
    imported = _run(['import', str(npz), '--out', str(bag)])
    if imported.returncode:
        return {'seed': seed, 'scanner': s, 'error': 'import: ' + imported.stderr.strip()}
    commissioned = work / f'model_{seed}.yaml'
    com = _run(['commission', str(bag), '--out', str(commissioned), '--json'])
    warned: list[str] = []
    held: list[str] = []  # identify's options for the held current
    if current == 'measured':  # as the warning says: commission the measured current
        warned = [] if com.returncode else json.loads(com.stdout).get('warnings', [])
        com = _run(['commission', str(bag), '--out', str(commissioned), '--json',
                    '--measured-current', '--force'])
        if com.returncode == 0:
            held = ['--measured-current', repr(json.loads(com.stdout)['measured_current_lag'])]
    found: dict[str, Any] = {'error': com.stderr.strip()} if com.returncode else \
        json.loads(com.stdout)
    # the truth's input dynamics are those of the command; the held current made from a
    # measured one has no delay, and the lag only where the data sheet's LAG is right
    if current == 'command':
        model_file = save_model(truth_model(s), work / f'truth_{seed}.yaml')
    elif com.returncode == 0:
        model_file = commissioned
    else:
        return {'seed': seed, 'scanner': s, 'error': 'commission: ' + com.stderr.strip()}
    ident = _run(['identify', str(bag), '--model', str(model_file), '--json', *held])
    if ident.returncode:
        return {'seed': seed, 'scanner': s, 'error': 'identify: ' + ident.stderr.strip()}
    report = json.loads(ident.stdout)
    truth = _truth_vector(s)
    z_all, e_all, resolved, modes = [], [], 0, 0
    for w in report['windows']:
        z, e, r, m = _scores(w, truth)
        z_all += z
        e_all += e
        resolved += r
        modes += m
    pooled = report.get('pooled')
    z_pool = _scores(pooled, truth)[0] if pooled else []
    return {'seed': seed, 'scanner': s, 'windows': len(report['windows']),
            'mismatched': len(report.get('mismatched_windows') or []), 'z': z_all, 'e': e_all,
            'resolved': resolved, 'modes': modes, 'z_pool': z_pool,
            'commission': found, 'model_mismatch': report.get('model_mismatch'),
            'warned': warned,
            'lag': found.get('measured_current_lag') or math.nan}


def _commission_line(s: Scanner, found: dict[str, Any]) -> tuple[str, list[float]]:
    """One line on the commissioned model against the truth, and the z of its parameters
    (when it found as many modes as there are)."""  # noqa: D205, D209
    if 'error' in found:
        return 'commission failed: ' + found['error'][:80], []
    model = found['model']
    modes = model['mechanics']['modes']
    omegas = [m['natural_frequency'] for m in modes]
    delay = model['input_dynamics']['computation_delay']
    text = f'{len(omegas)}/{len(s.omegas)} modes, delay {delay}/{s.delay}'
    if len(omegas) != len(s.omegas) or delay != s.delay:
        return text, []
    worst = max(abs(w - t) / t for w, t in zip(omegas, s.omegas, strict=True))
    z = [(model['mechanics']['k0'] - s.k0) / model['mechanics']['k0_std']]
    for m, k, w, d in zip(modes, s.residues, s.omegas, s.zetas, strict=True):
        for key, true in (('residue', k), ('natural_frequency', w), ('damping_ratio', d)):
            z.append((m[key] - true) / m['std'][key])
    rms = float(np.sqrt(np.mean(np.square(z))))
    return text + f' (freq within {100 * worst:.2f} %, rms z {rms:.2f})', z


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seeds', type=int, nargs='+', default=None)
    parser.add_argument('--count', type=int, default=8, help='scanners 0..count-1')
    parser.add_argument('--angles', type=float, nargs='+', default=[0.1, 0.3, 1.0])
    parser.add_argument('--moves-per-angle', type=int, default=200)
    parser.add_argument('--current', choices=['command', 'measured'], default='command',
                        help="what the current record holds: the controller's command "
                             "(default) or the amplifier's measured current (then identify "
                             'uses the commissioned model)')
    parser.add_argument('--sensor-noise', type=float, default=1e-3, metavar='A',
                        help="with --current measured: std of the current sensor's white noise "
                             '[A] (default 1 mA)')
    args = parser.parse_args()
    seeds = args.seeds if args.seeds is not None else list(range(args.count))
    load = ', '.join(f'{x:.2f}' for x in os.getloadavg())
    print(f'independent scanners {seeds}: {args.moves_per_angle} moves at each of '
          f'{args.angles} deg, current record: {args.current}'
          + (f' (sensor noise {1e3 * args.sensor_noise:g} mA)'
             if args.current == 'measured' and args.sensor_noise != 1e-3 else '') + '; '
          f'{datetime.datetime.now().isoformat(timespec="seconds")}, load average {load}\n')
    z_all: list[float] = []
    e_all: list[float] = []
    z_pool: list[float] = []
    z_com: list[float] = []
    right = 0
    warned = 0
    silent_wrong = 0  # held current: a parameter beyond 5 std and no warning
    print(f'{"seed":>4} {"win":>3} {"modes res.":>10} {"rms z":>6} {"max|z|":>7} {">3":>3} '
          f'{"rms e/b":>7} {"pooled rms z / max":>18}  commission; scanner')
    for seed in seeds:
        with tempfile.TemporaryDirectory(prefix='galvo_indep_') as tmp:
            r = one_scanner(seed, angles=args.angles, moves=args.moves_per_angle,
                            work=Path(tmp), current=args.current,
                            sensor_noise=args.sensor_noise)
        s = r['scanner']
        if 'error' in r:
            print(f'{seed:>4} ERROR {r["error"][:160]}; {s.describe()}')
            continue
        z, e, zp = np.array(r['z']), np.array(r['e']), np.array(r['z_pool'])
        z_all += r['z']
        e_all += r['e']
        z_pool += r['z_pool']
        rms = float(np.sqrt(np.mean(z**2))) if z.size else math.nan
        worst = float(np.max(np.abs(z))) if z.size else math.nan
        eff = float(np.sqrt(np.mean(e**2))) if e.size else math.nan
        measured = args.current == 'measured'  # the held current has no delay
        com_text, z_c = _commission_line(replace(s, delay=0) if measured else s,
                                         r['commission'])
        if measured:
            warned += bool(r['warned'])
            held_warned = bool(r['commission'].get('warnings'))
            com_text = (f'warned {"yes" if r["warned"] else "NO"}; held: warned '
                        f'{"yes" if held_warned else "no"}, lag {r["lag"] / s.sample_period:.2f}'
                        f'/{s.lag / s.sample_period:.2f} T, ' + com_text)
            if z_c and not held_warned and max(abs(v) for v in z_c) > 5:
                silent_wrong += 1
        z_com += z_c
        right += bool(z_c)
        pool = (f'{float(np.sqrt(np.mean(zp**2))):.2f} / {float(np.max(np.abs(zp))):.1f}'
                if zp.size else '-')
        print(f'{seed:>4} {r["windows"]:>3} {r["resolved"]:>4}/{r["modes"]:<5} {rms:>6.2f} '
              f'{worst:>7.1f} {int(np.sum(np.abs(z) > 3)):>3} {eff:>7.2f} {pool:>18}  '
              f'{com_text}; {s.describe()}'
              + (f'; MISMATCH: {r["model_mismatch"]}' if r['model_mismatch'] else ''))
    z, e, zp = np.array(z_all), np.array(e_all), np.array(z_pool)
    if z.size:
        print(f'\nwindows: {z.size} parameter estimates of resolved modes, rms z '
              f'{float(np.sqrt(np.mean(z**2))):.3f}, beyond 3 / 4 / 5 std: '
              f'{int(np.sum(np.abs(z) > 3))} / {int(np.sum(np.abs(z) > 4))} / '
              f'{int(np.sum(np.abs(z) > 5))} (a Gaussian: {0.0027 * z.size:.1f} / '
              f'{6.3e-5 * z.size:.2f} / {5.7e-7 * z.size:.3f}); rms error / bound '
              f'{float(np.sqrt(np.mean(e**2))):.3f}')
    if zp.size:
        print(f'pooled: {zp.size} estimates, rms z {float(np.sqrt(np.mean(zp**2))):.3f}, '
              f'max |z| {float(np.max(np.abs(zp))):.1f}')
    if args.current == 'measured':
        print(f'commission of the measured current as recorded: warned for {warned} of '
              f'{len(seeds)} scanners; commissioned as measured currents (the lag searched), '
              f'a parameter beyond 5 std without a warning for {silent_wrong}')
    what = 'modes and delay' + ('' if args.current == 'command' else ' (0) of the held current')
    print(f'commission: {what} right for {right} of {len(seeds)} scanners'
          + (f'; their parameters rms z {float(np.sqrt(np.mean(np.square(z_com)))):.3f}, '
             f'max |z| {float(np.max(np.abs(z_com))):.1f}' if z_com else ''))
    print(f'load average at the end {os.getloadavg()[0]:.2f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
