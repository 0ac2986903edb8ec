"""The Cramer-Rao bound against J^T Sigma^-1 J with the noise's true covariance.

A generated scanner (``random_scanner(1)``: short records, a first mode whose antiresonance
cuts a deep, narrow valley into the noise spectrum, moves that start with the previous move's
ringing) simulated in closed loop: the noise of the model's residual is open loop, the
encoder's (coloured measurement noise, quantisation) plus the current noise through the
plant, all second-differenced, so its autocovariance is computed exactly here from the plant's
impulse response. The bound :func:`crlb_at` reports from the moves' scatter must match the
bound with that covariance, the nuisance partialled out alike. (The bound of the fit's own
noise model, estimated from the moves' deviations whole, was ten times too large for omega_1
and zeta_1 here: the moves' ringing filled the valley.)
"""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import lfilter

from galvo_sysid.ident.refine.bound import crlb_at
from galvo_sysid.ident.refine.joint import JointProblem, _jacobian
from galvo_sysid.ident.refine.window import WindowProblem, window_records
from galvo_sysid.model import PSI, InputDynamics
from galvo_sysid.model.dynamics import discretize, split_delay
from galvo_sysid.sim.config import SimulatorConfig
from galvo_sysid.sim.family import random_scanner
from galvo_sysid.sim.simulator import simulate_window

RING = 20000  # samples of the plant's impulse response (its modes ring out well before)


def noise_autocovariance(cfg: SimulatorConfig, lags: int) -> np.ndarray:
    """Autocovariance of the second-differenced residual noise of one move, lags 0..lags-1."""
    plant = cfg.plant
    t = plant.sample_period
    ss = discretize(plant.modal, InputDynamics(computation_delay=0, lag_time_constant=0.0), t)
    powers = [ss.b]
    for _ in range(RING - 2):
        powers.append(ss.a @ powers[-1])
    h = np.concatenate([[0.0], np.array(powers) @ ss.c])
    hd = np.concatenate([h[:1], [h[1] - 2 * h[0]], h[2:] - 2 * h[1:-1] + h[:-2]])
    ai = math.exp(-2 * math.pi * cfg.current_noise_corner * t)
    av = math.exp(-2 * math.pi * cfg.measurement_noise_corner * t)
    g = lfilter([math.sqrt(1 - ai * ai) * cfg.current_noise_std], [1.0, -ai], hd)
    spectrum = np.abs(np.fft.rfft(g, 2 * RING)) ** 2
    r = np.fft.irfft(spectrum, 2 * RING)[:lags]
    rv = cfg.measurement_noise_std ** 2 * av ** np.abs(np.arange(-2, lags + 2))
    d2 = np.array([1.0, -4.0, 6.0, -4.0, 1.0])
    r += np.array([d2 @ rv[k: k + 5] for k in range(lags)])
    r[:3] += np.array([6.0, -4.0, 1.0]) * cfg.encoder_resolution ** 2 / 12
    return r


def true_bound(cur: np.ndarray, enc: np.ndarray, cfg: SimulatorConfig) -> np.ndarray:
    """Cramer-Rao std of [k0, k_i, omega_i, zeta_i, lag] with the true noise covariance."""
    plant = cfg.plant
    t, model, dyn = plant.sample_period, plant.modal, plant.dynamics
    delay, frac = split_delay(dyn.pure_delay(t), t)
    ((c, e),) = window_records([(cur, enc)], 3)
    prob = WindowProblem(c, e, sample_period=t, delay=delay, fraction=frac,
                         n_modes=model.n_modes)
    joint = JointProblem([prob], np.ones(1), fixed_lag=None)
    omega = np.array(model.natural_frequencies)
    zeta = np.array(model.damping_ratios)
    x = joint.pack(omega, zeta, dyn.lag_time_constant)
    coef = joint.coefficients(x)[0]
    phys = np.concatenate([omega, zeta, [t]])
    jac, nuis = _jacobian(prob, omega, zeta, dyn.lag_time_constant, coef, phys, True, False)
    rows = jac.shape[0]
    r = noise_autocovariance(cfg, rows)
    sigma = r[np.abs(np.arange(rows)[:, None] - np.arange(rows)[None, :])] / prob.moves
    chol = np.linalg.cholesky(sigma)
    jw = np.linalg.solve(chol, jac)
    nw = np.linalg.solve(chol, nuis)
    q, _ = np.linalg.qr(nw / np.linalg.norm(nw, axis=0))
    jt = jw - q @ (q.T @ jw)
    info = jt.T @ jt
    d = np.sqrt(np.diag(info))
    return np.sqrt(np.diag(np.linalg.inv(info / np.outer(d, d)) / np.outer(d, d)))


def test_bound_matches_the_true_noise_covariance() -> None:
    sc = random_scanner(1)
    cfg = sc.config
    plant = cfg.plant
    angle = min(sc.angles, key=lambda a: abs(a - PSI))
    cur, enc = simulate_window(angle, moves=100, seed=3, config=cfg)
    ours = crlb_at([(cur, enc)], sample_period=plant.sample_period, model=plant.modal,
                   dynamics=plant.dynamics)
    theirs = true_bound(cur, enc, cfg)
    ratio = np.array(list(ours.values())) / theirs
    assert np.all((ratio > 0.7) & (ratio < 1.3)), dict(zip(ours, ratio.round(3), strict=True))
