"""The simulator's exact residual noise against the scatter of simulated moves."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.ident.refine.window import WindowProblem, window_records
from galvo_sysid.model import PAPER_MODEL, PSI
from galvo_sysid.model.dynamics import split_delay
from galvo_sysid.sim.config import SimulatorConfig
from galvo_sysid.sim.family import random_scanner
from galvo_sysid.sim.noise import residual_noise_autocovariance
from galvo_sysid.sim.simulator import simulate_window


def _noise_records(cfg: SimulatorConfig, angle: float, seed: int) -> np.ndarray:
    """The moves' residual noise at the true model: deviations less each move's nuisance."""
    plant = cfg.plant
    t, model, dyn = plant.sample_period, plant.modal, plant.dynamics
    cur, enc = simulate_window(angle, moves=100, seed=seed, config=cfg)
    delay, frac = split_delay(dyn.pure_delay(t), t)
    ((c, e),) = window_records([(cur, enc)], 3)
    prob = WindowProblem(c, e, sample_period=t, delay=delay, fraction=frac,
                         n_modes=model.n_modes)
    omega, zeta = np.array(model.natural_frequencies), np.array(model.damping_ratios)
    coef = np.concatenate([[model.k0], model.residues, np.zeros(prob.n_linear - 1 - model.n_modes)])
    return prob.noise(omega, zeta, dyn.lag_time_constant, coef)


@pytest.mark.parametrize(('which', 'tol'), [('paper', 0.05), ('scanner-1', 0.05),
                                           ('current-20mA', 0.1)])
def test_autocovariance_matches_the_moves_scatter(which: str, tol: float) -> None:
    # The encoder noise dominates the first two; the current noise through the plant the
    # third (its resonant part is long-correlated, and each move's nuisance removal takes
    # some of it: a looser tolerance).
    if which == 'paper':
        cfg, angle = SimulatorConfig(), PSI
    elif which == 'current-20mA':
        cfg, angle = replace(SimulatorConfig(), current_noise_std=0.02), PSI
    else:
        sc = random_scanner(1)
        cfg, angle = sc.config, min(sc.angles, key=lambda a: abs(a - PSI))
    noise = np.vstack([_noise_records(cfg, angle, seed) for seed in (0, 1)])
    m, rows = noise.shape
    # the lag sums of the records, away from their ends (the nuisance removal thins those)
    inner = noise[:, 20: rows - 20]
    lags = 6
    seen = np.array([np.sum(inner[:, : inner.shape[1] - k] * inner[:, k:]) /
                     (m * (inner.shape[1] - k)) for k in range(lags)])
    exact = residual_noise_autocovariance(cfg, lags)
    # the deviations are of the window mean: each move's noise times (M - 1) / M
    exact = exact * (1.0 - 1.0 / 100)
    assert abs(seen[0] / exact[0] - 1.0) < tol, (seen, exact)
    assert np.all(np.abs(seen - exact) < tol * exact[0]), (seen / exact[0], exact / exact[0])


def test_exact_noise_refuses_a_nonlinear_plant() -> None:
    plant = PAPER_MODEL.with_effect('coulomb_friction', {'friction_current': 0.01})
    with pytest.raises(ConfigurationError, match='linear'):
        residual_noise_autocovariance(SimulatorConfig(plant=plant), 10)


@pytest.mark.parametrize('lags', [0, -3, 2.5, True])
def test_bad_lags_are_refused(lags: object) -> None:
    with pytest.raises(ConfigurationError, match='lags'):
        residual_noise_autocovariance(SimulatorConfig(), lags)  # type: ignore[arg-type]
