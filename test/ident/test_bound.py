"""The Cramer-Rao bound against J^T Sigma^-1 J with the noise's true covariance.

A generated scanner (``random_scanner(1)``: short records, a first mode whose antiresonance
cuts a deep, narrow valley into the noise spectrum, moves that start with the previous move's
ringing) simulated in closed loop: the noise of the model's residual is open loop, the
encoder's (coloured measurement noise, quantisation) plus the current noise through the
plant, all second-differenced, so its autocovariance is known exactly
(:func:`~galvo_sysid.sim.noise.residual_noise_autocovariance`, checked here against the
scatter of simulated moves). The bound :func:`crlb_at` reports from the moves' scatter must
match the bound with that covariance, the nuisance partialled out alike. (The bound of the fit's own
noise model, estimated from the moves' deviations whole, was ten times too large for omega_1
and zeta_1 here: the moves' ringing filled the valley.)
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import cholesky, solve_triangular, toeplitz

from galvo_sysid.errors import InvalidDataError
from galvo_sysid.ident.refine.bound import crlb_at, crlb_known_noise
from galvo_sysid.ident.refine.joint import JointProblem, _jacobian, _partialled
from galvo_sysid.ident.refine.options import DEFAULT_WHITEN_ORDER
from galvo_sysid.ident.refine.whitener import stationary_noise_model
from galvo_sysid.ident.refine.window import WindowProblem
from galvo_sysid.model import PAPER_MODEL, PSI, TAU
from galvo_sysid.model.dynamics import split_delay
from galvo_sysid.sim.config import SimulatorConfig
from galvo_sysid.sim.family import random_scanner
from galvo_sysid.sim.noise import residual_noise_autocovariance
from galvo_sysid.sim.simulator import simulate_window


def test_bound_matches_the_true_noise_covariance() -> None:
    sc = random_scanner(1)
    cfg = sc.config
    plant = cfg.plant
    angle = min(sc.angles, key=lambda a: abs(a - PSI))
    cur, enc = simulate_window(angle, moves=100, seed=3, config=cfg)
    ours = crlb_at([(cur, enc)], sample_period=plant.sample_period, model=plant.modal,
                   dynamics=plant.dynamics)
    theirs = crlb_known_noise([(cur, enc)], sample_period=plant.sample_period, model=plant.modal,
                              dynamics=plant.dynamics,
                              autocovariance=residual_noise_autocovariance(cfg, enc.shape[1]))
    ratio = np.array(list(ours.values())) / np.array(list(theirs.values()))
    assert np.all((ratio > 0.7) & (ratio < 1.3)), dict(zip(ours, ratio.round(3), strict=True))


def test_known_noise_bound_refuses_bad_input() -> None:
    cur, enc = simulate_window(PSI, moves=5, seed=0)
    r = residual_noise_autocovariance(SimulatorConfig(), 10)
    with pytest.raises(InvalidDataError, match='lags'):
        crlb_known_noise([(cur, enc)], sample_period=TAU, model=PAPER_MODEL.modal,
                         dynamics=PAPER_MODEL.dynamics, autocovariance=r)
    bad = residual_noise_autocovariance(SimulatorConfig(), enc.shape[1])
    bad[1:] = 2 * bad[0]
    with pytest.raises(InvalidDataError, match='positive definite'):
        crlb_known_noise([(cur, enc)], sample_period=TAU, model=PAPER_MODEL.modal,
                         dynamics=PAPER_MODEL.dynamics, autocovariance=bad)


def _k0_efficiency_of_the_weighting(first_order: int | None) -> float:
    """rms error of k0 over its bound for the generalised least squares of ``random_scanner(30)``'s
    window at the truth, weighted by the fit's noise model (``first_order`` None: as the fit
    makes it, through ``JointProblem.prewhiten``; else that model with a first pass of
    ``first_order`` lags), the error's covariance with the noise's true one (a sandwich)."""
    sc = random_scanner(30)  # 1,240 rows: the noise model has 413 lags
    cfg = sc.config
    plant = cfg.plant
    t = plant.sample_period
    angle = min(sc.angles, key=lambda a: abs(a - PSI))
    cur, enc = simulate_window(angle, moves=100, seed=0, config=cfg)
    delay, frac = split_delay(plant.dynamics.pure_delay(t), t)
    prob = WindowProblem(cur, enc, sample_period=t, delay=delay, fraction=frac,
                         n_modes=plant.modal.n_modes)
    joint = JointProblem([prob], np.ones(1), fixed_lag=None)
    x = joint.pack(np.array(plant.modal.natural_frequencies),
                   np.array(plant.modal.damping_ratios), plant.dynamics.lag_time_constant)
    omega, zeta, lag = joint.unpack(x)
    coef = joint.coefficients(x)[0]
    rows = prob.k.size
    if first_order is None:
        joint.prewhiten(x, DEFAULT_WHITEN_ORDER)
        assert prob.whiten is not None
        whiten = prob.whiten.matrix(rows)
    else:
        dev = prob.deviations(omega, zeta, lag, coef)
        nuis = prob.columns(omega, zeta, lag, whitened=False)[:, 1 + plant.modal.n_modes:]
        found = stationary_noise_model(dev, nuis, rows // 3, first_order=first_order)
        assert found is not None
        whiten = found[0].apply(np.eye(rows))
    phys = np.concatenate([omega, zeta, [t]])
    jac, nuis = _jacobian(prob, omega, zeta, lag, coef, phys, True, False)
    sigma = toeplitz(residual_noise_autocovariance(cfg, enc.shape[1])[:rows]) / prob.moves
    chol = cholesky(sigma, lower=True)
    best = _partialled(solve_triangular(chol, jac, lower=True),
                       solve_triangular(chol, nuis, lower=True))
    bound = np.linalg.inv(best.T @ best)[0, 0]
    weighted = _partialled(whiten @ jac, whiten @ nuis)
    gain = np.linalg.solve(weighted.T @ weighted, weighted.T @ whiten)
    return float(np.sqrt((gain @ sigma @ gain.T)[0, 0] / bound))


def test_a_long_records_noise_model_weighs_the_lowest_frequencies_as_the_noise_does() -> None:
    """On a long record the noise model's many lags resolve the lowest frequencies, where the
    per-move offset holds the whole band and the scatter does not tell the noise: there the
    expectation-maximisation keeps what it starts from. Started from a coarse first pass,
    k0's rms error is near its bound; from a first pass as fine as the model (as before), it
    weighed the lowest frequencies about 30 times too low and k0's error was 1.5 times the
    bound (``benchmarks/efficiency.py``'s scanner-30: efficiency 1.55, now 1.11)."""
    ours = _k0_efficiency_of_the_weighting(None)
    fine = _k0_efficiency_of_the_weighting(1240 // 3)
    assert ours < 1.15, ours
    assert fine > 1.15, fine
