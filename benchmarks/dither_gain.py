"""What a small dither at a weakly excited mode buys (issue 13, item 4's must-show).

Two move conditions of the paper's scanner at 1 psi, single windows of 100 moves, identified
by the refined fit (``identify_window``, the sysid node's default):

- ``default``: the simulator's default moves (S-curve, 20 samples at least);
- ``weak``: slower minimum-jerk moves (``--weak-samples``, default 80 samples), which put
  several times less current into mode 3 than the default moves (printed: the mean move's
  current spectrum at omega_3 relative to the default's).

Each condition runs without and with a dither at mode 3 (``dither_for_modes(A, '3')``: one
tapered tone of amplitude A added to every move's current command, as the driver's
``dither.amplitude``/``dither.modes`` do). Per amplitude it prints how many windows resolved
mode 3, the median |relative error| of omega_3 and zeta_3 over the windows (an unresolved
mode's numbers included: they are what the fit reported), their ratio to the undithered
run, and the position error the dither adds: the rms difference of the encoder records with
and without it (same noise seed), in encoder counts (20 bits over +-20 deg). The noise seeds
are 0..``--seeds``-1; nothing is tuned per seed.

Usage (from the repository root)::

    python benchmarks/dither_gain.py                       # 10 seeds, 0 / 5 / 10 mA
    python benchmarks/dither_gain.py --seeds 20 --amplitudes 0 0.002 0.01
"""

from __future__ import annotations

import os

os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')
os.environ.setdefault('OMP_NUM_THREADS', '1')

import argparse
import datetime
import statistics
import time
from dataclasses import dataclass

import numpy as np

from galvo_sysid import keep_freed_memory
from galvo_sysid.ident.identify import identify_window
from galvo_sysid.model import PAPER_MODEL, PSI, TAU, relative_errors
from galvo_sysid.sim.config import DEFAULT_ENCODER_RESOLUTION, SimulatorConfig
from galvo_sysid.sim.dither import dither_for_modes
from galvo_sysid.sim.profiles import ProfileConfig
from galvo_sysid.sim.simulator import simulate_window

OMEGA_3 = float(PAPER_MODEL.modal.natural_frequencies[2])


def excitation(current: np.ndarray) -> float:
    """|DFT| of the mean move's current at the bin nearest omega_3."""
    mean = current.mean(axis=0)
    w = 2 * np.pi * np.fft.rfftfreq(mean.size, TAU)
    return float(np.abs(np.fft.rfft(mean))[int(np.argmin(np.abs(w - OMEGA_3)))])


@dataclass(frozen=True)
class Run:
    """One condition and dither amplitude over the seeds."""

    w3: float                   # median |relative error| of omega_3
    z3: float                   # median |relative error| of zeta_3
    resolved: int               # windows that resolved mode 3
    encoders: list[np.ndarray]  # the encoder records, per seed
    excitation: float           # median excitation of mode 3


def run(profile: ProfileConfig, amplitude: float, seeds: int) -> Run:
    """Identify one window per seed; errors, resolution and the encoder records."""
    cfg = SimulatorConfig(profile=profile,
                          dither=dither_for_modes(amplitude, '3', model=PAPER_MODEL))
    w3: list[float] = []
    z3: list[float] = []
    exc: list[float] = []
    encoders: list[np.ndarray] = []
    resolved = 0
    for seed in range(seeds):
        cur, enc = simulate_window(PSI, moves=100, seed=seed, config=cfg)
        result = identify_window(cur, enc, sample_period=TAU)
        err = relative_errors(result.model)
        w3.append(abs(err['omega_3']))
        z3.append(abs(err['zeta_3']))
        resolved += bool(result.resolved[2])
        encoders.append(enc)
        exc.append(excitation(cur))
    return Run(w3=statistics.median(w3), z3=statistics.median(z3), resolved=resolved,
               encoders=encoders, excitation=statistics.median(exc))


def _load() -> str:
    return ', '.join(f'{x:.2f}' for x in os.getloadavg())


def main(argv: list[str] | None = None) -> int:
    keep_freed_memory()  # as the entry points do: the fits reuse freed memory
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seeds', type=int, default=10)
    parser.add_argument('--amplitudes', type=float, nargs='+', default=[0.0, 0.005, 0.01],
                        help='dither amplitudes [A]; the first is the reference (use 0)')
    parser.add_argument('--weak-samples', type=int, default=80,
                        help="duration of the weak condition's minimum-jerk moves [samples]")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    print(f'dither gain at mode 3: paper scanner, 1 psi, windows of 100 moves, refined fit, '
          f'{args.seeds} seeds')
    print(f'started {datetime.datetime.now().isoformat(timespec="seconds")}, load average '
          f'{_load()}')
    conditions = {'default': ProfileConfig(),
                  'weak': ProfileConfig(shape='minimum-jerk',
                                        min_duration=args.weak_samples * TAU)}
    count = DEFAULT_ENCODER_RESOLUTION
    reference_exc = None
    print(f'{"moves":<8} {"dither":>7} {"exc. mode 3":>11} {"resolved":>9} '
          f'{"omega_3 |err|":>13} {"zeta_3 |err|":>12} {"gain w3":>8} {"gain z3":>8} '
          f'{"added position rms":>19}')
    for name, profile in conditions.items():
        base = None
        for amp in args.amplitudes:
            r = run(profile, amp, args.seeds)
            reference_exc = reference_exc or r.excitation
            base = base or r
            added = float(np.sqrt(np.mean([np.mean((a - b) ** 2) for a, b in zip(
                r.encoders, base.encoders, strict=True)])))
            print(f'{name:<8} {1e3 * amp:>4.1f} mA {r.excitation / reference_exc:>10.3g}x '
                  f'{r.resolved:>5}/{args.seeds:<3} {100 * r.w3:>11.3g} % {100 * r.z3:>10.3g} % '
                  f'{base.w3 / r.w3:>7.3g}x {base.z3 / r.z3:>7.3g}x '
                  f'{added / count:>8.3g} counts')
    print("exc. mode 3: the mean move's current at omega_3, relative to the default moves "
          "without dither; gain: the undithered run's median |error| over this one's; "
          'added position: rms(encoder with - without the dither), same noise seeds')
    print(f'finished in {time.perf_counter() - start:.0f} s, '
          f'{datetime.datetime.now().isoformat(timespec="seconds")}, load average '
          f'{_load()}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
