"""The Cramer-Rao bound each window reports: against an independent computation and Monte Carlo.

The independent bound: the Fisher matrix of the window's filtered average from Jacobians by
finite differences of the exact discretised plant (:func:`galvo_sysid.model.dynamics.simulate`,
not the fit's regressors), the nuisance (each mode's free response, the lag's, an offset)
written out analytically, and the noise covariance known exactly (white encoder noise plus
white current noise through the plant's impulse response), partialled out by the Schur
complement.
"""

from __future__ import annotations

import numpy as np
import pytest

from galvo_sysid.ident.refine import refine_fit
from galvo_sysid.model import REFERENCE_MODEL, TAU, InputDynamics, ModalModel, simulate
from galvo_sysid.model.modal import default_bands

N = 512
LAG = 0.6 * TAU


def _current(moves: int) -> np.ndarray:
    k = np.arange(N, dtype=float)
    pulse = np.where((k >= 8) & (k < 58), 1.0, np.where((k >= 58) & (k < 108), -1.0, 0.0))
    return np.tile(0.5 * pulse, (moves, 1))


PRE = 4000  # samples of current noise before each record: the noise is stationary in it


def _window(seed: int, moves: int, enc_std: float, cur_std: float) -> tuple[np.ndarray,
                                                                          np.ndarray]:
    rng = np.random.default_rng(seed)
    u = _current(moves)
    drive = np.hstack([np.zeros((moves, PRE)), u]) + cur_std * rng.standard_normal(
        (moves, PRE + N))
    y = simulate(REFERENCE_MODEL, InputDynamics(lag_time_constant=LAG), drive,
                 sample_period=TAU)[:, PRE:]
    return u, y + enc_std * rng.standard_normal(y.shape)


def _params(model: ModalModel, lag: float) -> np.ndarray:
    return np.array([*model.parameters().values(), lag])


def _model(theta: np.ndarray, n: int) -> tuple[ModalModel, float]:
    return ModalModel(k0=theta[0], residues=tuple(theta[1:1 + n]),
                      natural_frequencies=tuple(theta[1 + n:1 + 2 * n]),
                      damping_ratios=tuple(theta[1 + 2 * n:1 + 3 * n])), float(theta[-1])


def _filtered(y: np.ndarray) -> np.ndarray:
    return (y[2:] - 2 * y[1:-1] + y[:-2])


def independent_crlb(model: ModalModel, lag: float, u: np.ndarray, moves: int,
                     enc_std: float, cur_std: float) -> np.ndarray:
    """Cramer-Rao std of [k0, k_i, omega_i, zeta_i, lag] (see the module docs)."""
    n = model.n_modes
    theta = _params(model, lag)

    def out(th: np.ndarray) -> np.ndarray:
        m, tl = _model(th, n)
        return _filtered(simulate(m, InputDynamics(lag_time_constant=tl), u,
                                  sample_period=TAU))

    base = out(theta)
    cols = []
    for j in range(theta.size):
        h = 1e-6 * abs(theta[j])
        up, down = theta.copy(), theta.copy()
        up[j] += h
        down[j] -= h
        cols.append((out(up) - out(down)) / (2 * h))
    jac = np.array(cols).T
    k = np.arange(2, N, dtype=float) * TAU
    nuis = [np.ones_like(k), np.exp(-k / lag)]
    for w, z in zip(model.natural_frequencies, model.damping_ratios, strict=True):
        wd = w * np.sqrt(1 - z * z)
        nuis += [np.exp(-z * w * k) * np.cos(wd * k), np.exp(-z * w * k) * np.sin(wd * k)]
    full = np.hstack([jac, np.array(nuis).T])
    # noise of the average over the moves, filtered by (1 - q^-1)^2 (rows 2..N-1): white
    # encoder noise, and stationary white current noise through the plant (its filtered
    # impulse response h, long enough for the modes to ring out)
    length = PRE + N
    h = _filtered(np.concatenate([[0.0, 0.0], simulate(
        model, InputDynamics(lag_time_constant=lag), np.eye(length)[0], sample_period=TAU)]))
    r_cur = np.array([h[: h.size - t] @ h[t:] for t in range(N - 2)])
    r_enc = np.zeros(N - 2)
    r_enc[:3] = (6.0, -4.0, 1.0)
    r = cur_std**2 * r_cur + enc_std**2 * r_enc
    cov = r[np.abs(np.arange(N - 2)[:, None] - np.arange(N - 2)[None, :])] / moves
    chol = np.linalg.cholesky(cov)
    white = np.linalg.solve(chol, full)
    scale = np.linalg.norm(white, axis=0)
    info = (white / scale).T @ (white / scale)
    inv = np.linalg.inv(info) / np.outer(scale, scale)
    assert np.allclose(base, out(theta))
    return np.sqrt(np.diag(inv)[: theta.size])


@pytest.mark.parametrize(('enc_std', 'cur_std'), [(2e-5, 5e-3), (5e-6, 2e-2)])
def test_the_reported_bound_matches_an_independent_computation(enc_std: float,
                                                               cur_std: float) -> None:
    moves = 200
    u, y = _window(1, moves, enc_std, cur_std)
    fit = refine_fit(u, y, sample_period=TAU, initial=REFERENCE_MODEL,
                     dynamics=InputDynamics(lag_time_constant=LAG),
                     bands=default_bands(REFERENCE_MODEL, sample_period=TAU))
    assert fit.crlb_covariance is not None
    ours = np.sqrt(np.diag(fit.crlb_covariance))
    theirs = independent_crlb(fit.model, fit.lag_time_constant, u[0], moves, enc_std, cur_std)
    ratio = ours / theirs
    # a mode's omega and zeta may come out up to 20 % low: at a lightly damped mode's
    # frequency the moves' own ringing (free per move) hides part of the noise from the scatter
    # (stationary_noise_model); k0.., k_i and the lag within 10 %
    modal = np.array([name.startswith(('omega_', 'zeta_')) for name in fit.parameter_names])
    ok = np.where(modal, (ratio > 0.8) & (ratio < 1.1), np.abs(ratio - 1) < 0.1)
    assert np.all(ok), str(list(zip(fit.parameter_names, ratio.round(3), strict=True)))


def test_errors_scatter_as_the_bound_says() -> None:
    # Monte Carlo over 24 windows: error / bound of the seven well-determined parameters
    # (168 values: their rms is known to about +-6 %) must have an rms near 1
    names = ('k0', 'k1', 'k2', 'omega_1', 'omega_2', 'zeta_1', 'zeta_2')
    truth = REFERENCE_MODEL.parameters()
    z = []
    for seed in range(24):
        u, y = _window(100 + seed, 100, 2e-5, 5e-3)
        fit = refine_fit(u, y, sample_period=TAU, initial=REFERENCE_MODEL,
                         dynamics=InputDynamics(lag_time_constant=LAG),
                         bands=default_bands(REFERENCE_MODEL, sample_period=TAU))
        est, bound = fit.model.parameters(), fit.crlb_by_name()
        z.extend((est[n] - truth[n]) / bound[n] for n in names)
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.85 < rms < 1.18, rms


def test_without_the_bound_the_fit_is_the_same_and_says_no_bound() -> None:
    """``bound=False`` (the sysid node's setting) changes nothing but the bound's absence."""
    from galvo_sysid.errors import ConfigurationError
    from galvo_sysid.ident.identify import identify_window
    from galvo_sysid.model import PSI
    from galvo_sysid.sim.simulator import simulate_window

    cur, enc = simulate_window(PSI, moves=30, seed=4)
    full = identify_window(cur, enc, sample_period=TAU)
    bare = identify_window(cur, enc, sample_period=TAU, bound=False)
    assert full.crlb_std
    assert set(full.crlb_std) == set(full.model.parameters())
    assert bare.crlb_std == {}
    assert bare.model == full.model
    assert bare.std_by_name() == full.std_by_name()
    assert bare.resolved == full.resolved
    with pytest.raises(ConfigurationError, match='bound'):
        identify_window(cur, enc, sample_period=TAU, bound='no')
