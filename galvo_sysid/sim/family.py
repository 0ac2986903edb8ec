"""Families of galvo scanners generated from seeds: test material nobody tuned by hand.

:func:`random_scanner` draws a scanner from documented ranges (those of real galvo servos):

- sample period 5-50 us (log-uniform, three significant digits);
- 1-5 resonant modes between 1 kHz and the smaller of 30 kHz and 0.6 x Nyquist, at least
  15 % apart, damping ratios 0.002-0.03 (log-uniform), residues of either sign with
  magnitudes 0.05-1.5 x k0 (log-uniform);
- k0 5e5-2e7 deg/(A s^2) (log-uniform);
- 1-2 samples of DSP computation delay, an amplifier lag of 0-1 sample period;
- records of 256-2,048 samples (log-uniform), a dwell of 5-20 % of the record;
- current noise 1-4 mA, encoder noise 3e-5-1e-4 deg (the range of the default simulator);
- the positioning controller designed from the model
  (:func:`galvo_sysid.sim.controller.design_controller`); a draw without a stable design is
  drawn again (counted in :attr:`Scanner.redraws`);
- move sizes: of 0.03, 0.1, 0.3, 1 and 3 deg those whose moves fit in the record, with the
  peak feed-forward current raised (at most 10 A) so that a 0.3 deg move takes at most a
  quarter of the record.

The same seed always gives the same scanner.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model.dynamics import InputDynamics
from galvo_sysid.model.modal import ModalModel
from galvo_sysid.model.plant import PlantModel
from galvo_sysid.sim.config import SimulatorConfig
from galvo_sysid.sim.profiles import ProfileConfig
from galvo_sysid.sim.simulator import GalvoSimulator

__all__ = ['CANDIDATE_ANGLES', 'Scanner', 'random_scanner']

CANDIDATE_ANGLES = (0.03, 0.1, 0.3, 1.0, 3.0)
"""Move sizes a generated scanner is given where they fit [deg]."""

_MAX_DRAWS = 50


@dataclass(frozen=True)
class Scanner:
    """A generated scanner.

    Attributes:
        seed: Its seed.
        model: The true plant (no effects).
        config: Simulator settings (noise, profile, record) with ``model`` as the plant.
        angles: Move sizes that fit [deg].
        redraws: Draws refused (no stable controller design) before this one.
    """

    seed: int
    model: PlantModel
    config: SimulatorConfig
    angles: tuple[float, ...]
    redraws: int = 0

    @property
    def reference_angle(self) -> float:
        """The move of the single-window checks: 0.3 deg (1 psi) if it fits, else the largest."""
        return 0.3 if 0.3 in self.angles else max(self.angles)

    def describe(self) -> str:
        """One line: sample period, record, modes [kHz], delay."""
        m = self.model
        modes = ', '.join(f'{w / (2 * math.pi) / 1e3:.2f}' for w in m.modal.natural_frequencies)
        return (f'T {m.sample_period * 1e6:.3g} us, N {m.record_length}, {m.n_modes} mode(s) '
                f'[{modes}] kHz, delay {m.dynamics.computation_delay} + lag '
                f'{m.dynamics.lag_time_constant / m.sample_period:.2f} T')


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def _round3(x: float) -> float:
    return float(f'{x:.3g}')


def _draw(rng: np.random.Generator, seed: int) -> tuple[PlantModel, SimulatorConfig,
                                                        tuple[float, ...]]:
    t = _round3(_log_uniform(rng, 5e-6, 50e-6))
    f_max = min(30e3, 0.6 / (2 * t))
    n = int(rng.integers(1, 6))
    while True:
        freqs = np.sort([_log_uniform(rng, 1e3, f_max) for _ in range(n)])
        if n == 1 or np.min(freqs[1:] / freqs[:-1]) >= 1.15:
            break
    k0 = _log_uniform(rng, 5e5, 2e7)
    residues = [float(rng.choice([-1.0, 1.0])) * _log_uniform(rng, 0.05, 1.5) * k0
                for _ in range(n)]
    damping = [_log_uniform(rng, 0.002, 0.03) for _ in range(n)]
    modal = ModalModel(k0=k0, residues=tuple(residues),
                       natural_frequencies=tuple(2 * math.pi * float(f) for f in freqs),
                       damping_ratios=tuple(damping))
    dynamics = InputDynamics(computation_delay=int(rng.integers(1, 3)),
                             lag_time_constant=float(rng.uniform(0.0, 1.0)) * t)
    record = round(_log_uniform(rng, 256, 2048))
    dwell = round(record * float(rng.uniform(0.05, 0.2)))
    model = PlantModel(modal=modal, dynamics=dynamics, sample_period=t,
                       record_length=record, dwell_length=dwell,
                       description=f'generated scanner, seed {seed} (galvo_sysid.sim.family)')
    quarter = 0.25 * record * t            # a 0.3 deg bang-bang move in a quarter record
    peak = min(10.0, max(1.0, 0.3 / (k0 * (quarter / 2) ** 2)))
    config = SimulatorConfig(
        plant=model, profile=ProfileConfig(peak_current=peak),
        current_noise_std=float(rng.uniform(1e-3, 4e-3)),
        measurement_noise_std=_log_uniform(rng, 3e-5, 1e-4))
    sim = GalvoSimulator(config=config, seed=seed)   # designs the controller
    angles = []
    for a in CANDIDATE_ANGLES:
        try:
            sim.check_angles([a])
        except ConfigurationError:
            continue
        angles.append(a)
    if not angles:
        raise ConfigurationError('no move size fits the record')
    return model, config, tuple(angles)


def random_scanner(seed: int) -> Scanner:
    """Draw the scanner of ``seed`` (see the module docs).

    Raises:
        ConfigurationError: No usable scanner in 50 draws (does not happen for the ranges
            above; a bound on the loop).
    """
    rng = np.random.default_rng([seed, 20261124])
    for redraws in range(_MAX_DRAWS):
        try:
            model, config, angles = _draw(rng, seed)
        except ConfigurationError:
            continue
        return Scanner(seed=seed, model=model, config=config, angles=angles, redraws=redraws)
    raise ConfigurationError(f'no usable scanner for seed {seed} in {_MAX_DRAWS} draws')
