"""Efficiency of the refined fit against the Cramer-Rao bound over excitation conditions.

Issue 13, item 5: does one window of 100 moves, identified by the refined fit
(``identify_window``, the sysid node's default), reach the Cramer-Rao bound whatever the
moves, the controller, the noise and the scanner? A family of conditions, built by fixed rules
(:func:`conditions`; nothing is chosen per condition by looking at its results):

- ``default``: the paper's scanner at 1 psi with the simulator's defaults (S-curve moves,
  notches at every mode, 800 Hz crossover, 2 mA current noise, 1.3 encoder steps);
- one change at a time from there, each to an end of its range: moves of each shape and 20-80
  samples (``min_duration``; the peak current is left free, ``PEAK_LIMIT``, so the duration is
  what is asked), among them ``weak``, the minimum-jerk 80-sample moves of
  ``benchmarks/dither_gain.py`` (mode 3 excited several times less; the excitation ratio is
  printed as there), and ``weak`` with a 10 mA dither at mode 3; the controller at 1500 Hz
  with notches and at 600 Hz without (the fastest crossover without notches that keeps the
  6 dB / 30 deg margins; 1000 Hz and above are unstable); current noise 20 mA; encoder noise
  0.5 and 3 quantisation steps;
- the first scanners of the generated family (``random_scanner(0..)``) at the move size
  nearest 1 psi (0.3 deg), with their own controller and noise.

Per condition and noise seed 0..``--seeds``-1, one window (``simulate_window``) is identified
with the true model as the scanner's model (its bands and starting point, as the monitor uses
the commissioned one). **The bound** is the Cramer-Rao bound with the noise's true spectrum,
at the true parameters on the same window (``crlb_known_noise`` with the simulator's exact
residual noise, ``residual_noise_autocovariance``: issue 13's yardstick). Per parameter, in
relative units: the median |error| against 1.25 x 0.674 x the median bound (0.674 sigma is
the median |error| of an efficient unbiased estimator); the efficiency rms(error) /
rms(bound); the bias mean(error) / rms(bound); the largest |error| / bound (a fit in a wrong
minimum shows there); the calibration rms(error / reported std) over the windows that
resolved the mode; the median reported std over the bound (``std/b``: the fit reports a
sandwich covariance, its own covariance whatever its noise model: above 1 where its weighting
is not the noise's); and ``crlb/b``, the median of the bound the fit can know over the true
one: ``crlb_at``, the bound with the noise the moves' scatter shows, each move's own ringing
taken out (what ``identify --json`` reports as ``crlb_std``; it reads low at a lightly damped
mode, whose noise each move's ringing partly hides). A condition PASSes when for k0 and every
parameter of a mode resolved in every window: median |error| <= the limit, efficiency <= 1.3,
calibration within 0.8-1.25. Every figure of a mode's parameter is over the windows that
resolve the mode (in the others its parameters are a noise fit the result flags as such, not
an estimate). Modes not resolved in every window are reported (resolved count) and left out of
the verdict; their efficiency and calibration, where at least ``PARTIAL_WINDOWS`` windows
resolve them, are summarised in one line against the must-show's limits (a residue that only
just passes the resolution test is a biased sample: its error there is above the bound, and
its reported std says so); the column ``eff all`` gives the efficiency over every window,
those that flag the mode unresolved too (the same as ``eff`` for a mode resolved in every
window). The chance that an
estimator exactly at the bound fails these tests by sampling alone, with this many seeds, is
printed last (below 1e-4 per parameter at the default 400 seeds, 0.002 at 200, 0.022 at 100,
0.14 at 40, 0.57 at 8). At 100 seeds an estimator at the bound is expected to fail 2.3 of the
14 conditions by chance; so the default is 400, at which a FAIL is the estimator's (read it
with the bias and max |error| / bound columns).

Usage (from the repository root; about 7 minutes for the default 400 seeds, 2 processes)::

    python benchmarks/efficiency.py
    python benchmarks/efficiency.py --seeds 8 --scanners 0 1
    python benchmarks/efficiency.py --family-only --scanners 33 34 35  # scanners alone
"""

from __future__ import annotations

import os

os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')
os.environ.setdefault('OMP_NUM_THREADS', '1')

import argparse
import datetime
import math
import multiprocessing
import statistics
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from dither_gain import excitation

from galvo_sysid import keep_freed_memory
from galvo_sysid.errors import GalvoSysidError
from galvo_sysid.ident.identify import identify_window
from galvo_sysid.ident.refine.bound import crlb_at, crlb_known_noise
from galvo_sysid.ident.result import IdentificationResult
from galvo_sysid.ident.warm import WarmStart
from galvo_sysid.model import (
    PAPER_MODEL,
    PSI,
    TAU,
    ModalModel,
    PlantModel,
    parameter_mode,
    relative_errors,
)
from galvo_sysid.sim.config import SimulatorConfig
from galvo_sysid.sim.controller import ControllerConfig
from galvo_sysid.sim.dither import dither_for_modes
from galvo_sysid.sim.family import random_scanner
from galvo_sysid.sim.noise import residual_noise_autocovariance
from galvo_sysid.sim.profiles import ProfileConfig, move_profile
from galvo_sysid.sim.simulator import GalvoSimulator, simulate_window

MOVES = (('scurve', 20), ('sine-squared', 40), ('minimum-jerk', 40))
"""Move shapes and lengths [samples] besides the default and the weak moves."""

WEAK = ('minimum-jerk', 80)
"""The weakly exciting moves (those of benchmarks/dither_gain.py)."""

PEAK_LIMIT = 20.0
"""Peak current [A] allowed to the shaped moves: above what any of them needs at 1 psi."""

DITHER = 0.01
"""Dither amplitude at mode 3 [A]."""

SCANNERS = (0, 1, 2)
"""Seeds of the generated scanners."""

MEDIAN_FACTOR = 1.25 * 0.674
MAX_EFFICIENCY = 1.3
CALIBRATION = (0.8, 1.25)
"""The must-show: median |err| <= 1.25 x 0.674 x bound, efficiency and calibration limits."""

PARTIAL_WINDOWS = 10
"""A mode resolved in only some windows: its calibration over those windows is summarised
(against ``CALIBRATION``) where at least this many resolve it."""


@dataclass(frozen=True)
class Condition:
    """One excitation condition: the simulator's settings and the move size."""

    name: str
    config: SimulatorConfig
    angle: float
    scanner: str = ''

    @property
    def truth(self) -> PlantModel:
        """The simulated plant, which the fit is scored against."""
        return self.config.plant


def shaped(shape: str, samples: int) -> ProfileConfig:
    """Moves of ``shape`` lasting ``samples`` sample periods of the paper's scanner."""
    return ProfileConfig(shape=shape, min_duration=samples * TAU, peak_current=PEAK_LIMIT)


def conditions(scanners: tuple[int, ...] = SCANNERS, *,
               family_only: bool = False) -> list[Condition]:
    """The family (see the module docs); with ``family_only`` the generated scanners alone."""
    out = []
    for seed in scanners:
        sc = random_scanner(seed)
        angle = min(sc.angles, key=lambda a: abs(a - PSI))
        out.append(Condition(f'scanner-{seed}', sc.config, angle, sc.describe()))
    return out if family_only else _paper_conditions() + out


def _paper_conditions() -> list[Condition]:
    """The paper's scanner under the excitation conditions of the module docs."""
    base = SimulatorConfig()
    weak = replace(base, profile=shaped(*WEAK))
    step = base.encoder_resolution
    out = [Condition('default', base, PSI)]
    out += [Condition(f'{s}-{n}', replace(base, profile=shaped(s, n)), PSI) for s, n in MOVES]
    out += [Condition('weak', weak, PSI),
            Condition('weak+dither', replace(weak, dither=dither_for_modes(
                DITHER, '3', model=PAPER_MODEL)), PSI),
            Condition('notch-1500Hz', replace(base, controller=ControllerConfig(
                crossover_frequency=1500.0)), PSI),
            Condition('no-notch-600Hz', replace(base, controller=ControllerConfig(
                crossover_frequency=600.0, notch_frequencies=())), PSI),
            Condition('current-20mA', replace(base, current_noise_std=0.02), PSI),
            Condition('encoder-0.5step', replace(base, measurement_noise_std=0.5 * step), PSI),
            Condition('encoder-3step', replace(base, measurement_noise_std=3.0 * step), PSI)]
    return out


def describe(cond: Condition) -> str:
    """Moves, controller (with its margins), noise and dither of a condition, on one line."""
    cfg = cond.config
    m = cond.truth
    sim = GalvoSimulator(config=cfg)
    margins = sim.margins()
    prof = move_profile(cond.angle, length=cfg.record, record_length=cfg.record, k0=m.modal.k0,
                        dynamics=m.dynamics, sample_period=m.sample_period, config=cfg.profile)
    notches = 'no notches' if cfg.controller and cfg.controller.notch_frequencies == () \
        else 'notches'
    text = (f'{cfg.profile.shape} {prof.duration} samples {np.max(np.abs(prof.feedforward)):.2g}'
            f' A; {notches} {margins.gain_crossover_frequency:.0f} Hz (GM '
            f'{margins.gain_margin_db:.1f} dB, PM {margins.phase_margin:.0f} deg); '
            f'{1e3 * cfg.current_noise_std:.2g} mA, '
            f'{cfg.measurement_noise_std / cfg.encoder_resolution:.2g} steps')
    if cfg.dither.active:
        text += f'; dither {1e3 * cfg.dither.amplitude:.3g} mA'
    return text + (f'; {cond.scanner}' if cond.scanner else '')


@dataclass(frozen=True)
class Window:
    """One window's fit against the truth (relative errors and bounds)."""

    errors: dict[str, float]
    bounds: dict[str, float]
    z: dict[str, float]
    reported: dict[str, float]
    resolved: tuple[bool, ...]
    seconds: float
    excitation: float
    estimated: dict[str, float] = field(default_factory=dict)
    warm: bool = False


def run_window(cond: Condition, seed: int, *,
               warm_start: WarmStart | None = None) -> tuple[Window, IdentificationResult]:
    """Simulate, identify and bound one window (started from ``warm_start`` if given)."""
    truth = cond.truth
    t = truth.sample_period
    cur, enc = simulate_window(cond.angle, moves=100, seed=seed, config=cond.config)
    t0 = time.perf_counter()
    res = identify_window(cur, enc, sample_period=t, model=truth, target_angle=cond.angle,
                          warm_start=warm_start)
    seconds = time.perf_counter() - t0
    exact = crlb_known_noise([(cur, enc)], sample_period=t, model=truth.modal,
                             dynamics=truth.dynamics,
                             autocovariance=residual_noise_autocovariance(cond.config,
                                                                          enc.shape[1]))
    estimated = crlb_at([(cur, enc)], sample_period=t, model=truth.modal,
                        dynamics=truth.dynamics)
    window = scored(res, exact, truth.modal, seconds=seconds,
                    excitation=excitation(cur) if truth is PAPER_MODEL else math.nan,
                    estimated=estimated)
    return replace(window, warm=res.warm_started), res


def _attempt(cond: Condition, seeds: tuple[int, ...], warm: bool) -> list[Window | str]:
    """run_window of each seed, or the one-line error it raised; with ``warm``, each window
    started from the previous one's result (as the sysid node does, the first afresh)."""  # noqa: D205, D209
    out: list[Window | str] = []
    start: WarmStart | None = None
    for seed in seeds:
        try:
            window, res = run_window(cond, seed, warm_start=start)
        except GalvoSysidError as exc:
            out.append(f'{type(exc).__name__}: {exc}')
            start = None
            continue
        out.append(window)
        start = WarmStart.from_result(res) if warm else None
    return out


def scored(result: IdentificationResult, bound: dict[str, float], truth: ModalModel, *,
           seconds: float, excitation: float = math.nan,
           estimated: dict[str, float] | None = None) -> Window:
    """A fit against the truth: relative errors and bounds, z-scores, reported std (and the
    estimated bound over the yardstick ``bound``, if given)."""  # noqa: D205, D209
    ref = truth.parameters()
    est = result.model.parameters()
    std = result.std_by_name()
    return Window(errors=relative_errors(result.model, truth),
                  bounds={n: bound[n] / abs(ref[n]) for n in ref},
                  z={n: (est[n] - ref[n]) / std[n] if std[n] > 0 else math.nan for n in ref},
                  reported={n: std[n] / abs(ref[n]) for n in ref},
                  resolved=result.resolved, seconds=seconds, excitation=excitation,
                  estimated={n: estimated[n] / bound[n] for n in ref} if estimated else {})


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if x.size else math.nan


@dataclass(frozen=True)
class Stats:
    """One parameter over the windows of a condition (relative units)."""

    name: str
    resolved: int
    windows: int
    median_error: float
    limit: float
    efficiency: float
    bias: float
    worst: float
    calibration: float
    reported: float
    estimated: float = math.nan
    efficiency_all: float = math.nan
    """rms(error) / rms(bound) over every window, those that flag the mode unresolved too."""

    @property
    def counted(self) -> bool:
        """Whether the verdict counts it (k0, or its mode resolved in every window)."""
        return self.resolved == self.windows

    @property
    def partial(self) -> bool:
        """Whether its mode is resolved in only some windows, at least ``PARTIAL_WINDOWS``."""
        return PARTIAL_WINDOWS <= self.resolved < self.windows

    def failures(self) -> list[str]:
        """The must-show's tests it fails (none if not counted)."""
        if not self.counted:
            return []
        out = []
        if not self.median_error <= self.limit:
            out.append('median')
        if not self.efficiency <= MAX_EFFICIENCY:
            out.append('efficiency')
        if not CALIBRATION[0] <= self.calibration <= CALIBRATION[1]:
            out.append('calibration')
        return out


def parameter_stats(name: str, windows: list[Window]) -> Stats:
    """Median |error|, limit, efficiency, bias, worst |error|/bound and calibration, over the
    windows that resolve the parameter's mode (all of them for k0; in a window that does not
    resolve it, a mode's parameters are a noise fit the result flags, not an estimate)."""  # noqa: D205, D209
    mode = parameter_mode(name)
    ok = np.array([mode == 0 or w.resolved[mode - 1] for w in windows], dtype=bool)
    err_all = np.array([w.errors[name] for w in windows])
    bound_all = np.array([w.bounds[name] for w in windows])
    err, bound = err_all[ok], bound_all[ok]
    z = np.array([w.z[name] for w in windows])[ok]
    z = z[np.isfinite(z)]
    reported = np.array([w.reported[name] for w in windows])[ok] / bound
    est = np.array([w.estimated.get(name, math.nan) for w in windows])
    some = bool(err.size)
    return Stats(name=name, resolved=int(ok.sum()), windows=len(windows),
                 estimated=float(np.median(est)) if np.all(np.isfinite(est)) else math.nan,
                 median_error=float(np.median(np.abs(err))) if some else math.nan,
                 limit=MEDIAN_FACTOR * float(np.median(bound)) if some else math.nan,
                 efficiency=_rms(err) / _rms(bound) if some else math.nan,
                 bias=float(np.mean(err)) / _rms(bound) if some else math.nan,
                 worst=float(np.max(np.abs(err) / bound)) if some else math.nan,
                 calibration=_rms(z),
                 reported=float(np.median(reported)) if reported.size else math.nan,
                 efficiency_all=_rms(err_all) / _rms(bound_all) if err_all.size else math.nan)


def partial_summary(partial: list[tuple[str, Stats]]) -> str:
    """The line on the modes resolved in only some windows: their efficiency and calibration
    over the windows that resolve them, against the must-show's limits, and which miss."""  # noqa: D205, D209
    eff = [s.efficiency for _, s in partial]
    cal = [s.calibration for _, s in partial]
    off = [f'{c} {s.name} ({s.resolved}/{s.windows}) ' + ', '.join(
               [f'eff {_cell(s.efficiency)}'] * (not s.efficiency <= MAX_EFFICIENCY)
               + [f'calib {_cell(s.calibration)}']
               * (not CALIBRATION[0] <= s.calibration <= CALIBRATION[1]))
           for c, s in partial
           if not (s.efficiency <= MAX_EFFICIENCY
                   and CALIBRATION[0] <= s.calibration <= CALIBRATION[1])]
    return (f'modes resolved in only some windows (at least {PARTIAL_WINDOWS}), over the windows '
            f'that resolve them: efficiency {_cell(min(eff))}-{_cell(max(eff))}, calibration '
            f'{_cell(min(cal))}-{_cell(max(cal))} for {len(partial)} parameters of '
            f'{len({c for c, _ in partial})} conditions; '
            + (f'outside eff <= {MAX_EFFICIENCY} or calibration {CALIBRATION[0]}-'
               f'{CALIBRATION[1]}: {"; ".join(off)}' if off else 'all within the must-show'))


def false_fail_rate(seeds: int, draws: int = 20000) -> float:
    """Chance that an efficient, unbiased, calibrated estimator fails a parameter's tests.

    Errors drawn as the bound times standard normal deviates (the bound taken equal in every
    window and the reported std equal to it), ``seeds`` windows per draw.
    """
    z = np.random.default_rng(0).standard_normal((draws, seeds))
    rms = np.sqrt(np.mean(z**2, axis=1))
    fail = ((np.median(np.abs(z), axis=1) > MEDIAN_FACTOR) | (rms > MAX_EFFICIENCY)
            | (rms < CALIBRATION[0]) | (rms > CALIBRATION[1]))
    return float(np.mean(fail))


def _load() -> str:
    return ', '.join(f'{x:.2f}' for x in os.getloadavg())


def _cell(x: float, fmt: str = '.3g') -> str:
    return format(x, fmt) if math.isfinite(x) else '-'


def main(argv: list[str] | None = None) -> int:
    keep_freed_memory()  # as the entry points do: the fits reuse freed memory
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seeds', type=int, default=400,
                        help='noise seeds 0..N-1 per condition')
    parser.add_argument('--jobs', type=int, default=2,
                        help='processes (each window is timed in its own; 1 on a busy machine)')
    parser.add_argument('--scanners', type=int, nargs='*', default=list(SCANNERS),
                        help='seeds of the generated scanners')
    parser.add_argument('--family-only', action='store_true',
                        help="only the generated scanners (--scanners), not the paper's "
                             'excitation conditions')
    parser.add_argument('--warm', type=int, default=0, metavar='N',
                        help="start each window from the previous seed's result, as the sysid "
                             "node does, in chains of N seeds (each chain's first afresh); "
                             '0: every window afresh')
    args = parser.parse_args(argv)
    if args.warm < 0:
        parser.error('--warm must be 0 or more')
    start = time.perf_counter()
    family = conditions(tuple(args.scanners), family_only=args.family_only)
    how = (f", each started from the previous seed's result in chains of {args.warm} (the "
           f"sysid node's warm start)" if args.warm else '')
    print(f'efficiency against the Cramer-Rao bound: {len(family)} conditions, one window of '
          f'100 moves each, refined fit, noise seeds 0..{args.seeds - 1}{how}')
    print(f'started {datetime.datetime.now().isoformat(timespec="seconds")}, load average '
          f'{_load()}')
    print()
    for cond in family:
        print(f'{cond.name:<16} {cond.angle:g} deg: {describe(cond)}')
    times: list[float] = []
    summary: list[tuple[str, float, str, float, str, str, float, str]] = []
    partial: list[tuple[str, Stats]] = []
    reference = math.nan
    chance = false_fail_rate(args.seeds)
    block = args.warm or 4
    chains = [(cond, tuple(range(first, min(first + block, args.seeds))), args.warm > 0)
              for cond in family for first in range(0, args.seeds, block)]
    if args.jobs > 1:
        with multiprocessing.get_context('fork').Pool(args.jobs) as pool:
            results = pool.starmap(_attempt, chains, chunksize=1)
    else:
        results = [_attempt(*chain) for chain in chains]
    tasks = [(cond, seed) for cond, seeds, _ in chains for seed in seeds]
    outcomes = [out for chain in results for out in chain]
    kept_warm = sum(isinstance(out, Window) and out.warm for out in outcomes)
    for cond in family:
        wins: list[Window] = []
        failed = 0
        for (c, seed), out in zip(tasks, outcomes, strict=True):
            if c is not cond:
                continue
            if isinstance(out, Window):
                wins.append(out)
            else:
                failed += 1
                print(f'  {cond.name} seed {seed}: {out}')
        if not wins:
            summary.append((cond.name, math.nan, '-', math.nan, '-', '-', math.nan, 'FAIL'))
            continue
        times += [w.seconds for w in wins]
        exc3 = statistics.median(w.excitation for w in wins)
        reference = exc3 if cond.name == 'default' else reference
        ratio = f', mode 3 excited {_cell(exc3 / reference)}x the default' \
            if math.isfinite(exc3) else ''
        print(f'\n== {cond.name}: {len(wins)} windows, {failed} failed{ratio}')
        print(f'{"param":<8} {"resolved":>8} {"med|err|%":>10} {"limit %":>9} {"eff":>6} '
              f'{"bias":>6} {"max|e|/b":>8} {"calib":>6} {"std/b":>6} {"crlb/b":>6} '
              f'{"eff all":>7}  verdict')
        stats = [parameter_stats(n, wins) for n in cond.truth.modal.parameters()]
        for s in stats:
            verdict = ('fails ' + ', '.join(s.failures()) if s.failures() else 'ok') \
                if s.counted else 'not counted'
            print(f'{s.name:<8} {s.resolved:>4}/{s.windows:<3} {_cell(100 * s.median_error):>10} '
                  f'{_cell(100 * s.limit):>9} {_cell(s.efficiency):>6} {_cell(s.bias, "+.2f"):>6}'
                  f' {_cell(s.worst):>8} {_cell(s.calibration):>6} {_cell(s.reported):>6} '
                  f'{_cell(s.estimated):>6} {_cell(s.efficiency_all):>7}  '
                  f'{verdict}')
        partial += [(cond.name, s) for s in stats if s.partial]
        counted = [s for s in stats if s.counted]
        bad = [f'{s.name} ({", ".join(s.failures())})' for s in counted if s.failures()]
        passed = not bad and not failed
        print(f'{cond.name}: {"PASS" if passed else "FAIL"} ({len(counted)} of {len(stats)} '
              f'parameters counted' + (f'; failing: {"; ".join(bad)}' if bad else '')
              + (f'; {failed} windows failed' if failed else '') + ')')
        worst = max(counted, key=lambda s: s.efficiency)
        calib = max(counted, key=lambda s: abs(math.log(s.calibration))
                    if s.calibration > 0 else math.inf)
        modes = cond.truth.n_modes
        full = sum(s.counted for s in stats if s.name.startswith('omega_'))
        summary.append((cond.name, worst.efficiency, worst.name, calib.calibration, calib.name,
                        f'{full}/{modes}', (1 - chance) ** len(counted),
                        'PASS' if passed else 'FAIL'))
    print('\nsummary (counted parameters: k0 and those of modes resolved in every window)')
    print(f'{"condition":<16} {"worst eff":>9} {"param":<8} {"worst calib":>11} {"param":<8} '
          f'{"modes resolved":>14} {"P(pass) at bound":>16}  verdict')
    for name, eff, pe, cal, pc, res, p_pass, verdict in summary:
        print(f'{name:<16} {_cell(eff):>9} {pe:<8} {_cell(cal):>11} {pc:<8} {res:>14} '
              f'{_cell(p_pass, ".2f"):>16}  {verdict}')
    print(f'\npassed {sum(row[-1] == "PASS" for row in summary)} of {len(summary)} conditions. '
          f"An estimator exactly at the bound fails a parameter's tests with probability "
          f'{chance:.3f} at {args.seeds} seeds by sampling alone; P(pass) at bound: the chance it '
          f"passes all the condition's counted parameters (taken as independent); "
          f'expected passes {sum(row[-2] for row in summary if math.isfinite(row[-2])):.1f}')
    if partial:
        print(partial_summary(partial))
    print(f'median time per window (identify_window, wall) {1e3 * statistics.median(times):.0f}'
          f' ms over {len(times)} windows')
    if args.warm:
        print(f'warm-started fits kept: {kept_warm} of {len(outcomes)} windows (the others '
              f'fitted afresh: the first of each chain of {args.warm}, and any whose warm fit '
              f'was not plausible)')
    print(f'finished in {time.perf_counter() - start:.0f} s, '
          f'{datetime.datetime.now().isoformat(timespec="seconds")}, load average {_load()}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
