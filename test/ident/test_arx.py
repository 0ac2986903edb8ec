"""Tests of galvo_sysid.ident.arx: least squares by normal equations and QR, model evaluation."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import freqz, lfilter

from galvo_sysid.errors import ConfigurationError, IdentificationError, InvalidDataError
from galvo_sysid.ident.arx import ArxModel, fit_arx, min_data_length, regressors

T = 1e-5
A_TRUE = np.array([1.0, -1.5, 0.7])       # poles 0.75 +- 0.37j
B_TRUE = np.array([0.0, 1.0, 0.5])


def _data(n=2000, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    u = rng.standard_normal(n)
    w = noise * rng.standard_normal(n)
    # A y = B u + w  =>  y = (B u + w) / A
    y = lfilter(B_TRUE, A_TRUE, u) + lfilter([1.0], A_TRUE, w)
    return u, y


@pytest.mark.parametrize('solver', ['normal', 'qr'])
def test_exact_recovery_noise_free(solver):
    u, y = _data()
    m = fit_arx(u, y, sample_period=T, na=2, nb=2, solver=solver)
    np.testing.assert_allclose(m.a, A_TRUE[1:], atol=1e-10)
    np.testing.assert_allclose(m.b, B_TRUE[1:], atol=1e-10)
    assert m.residual_variance < 1e-20
    assert m.solver == solver
    assert m.n_samples == 2000


def test_white_equation_error_is_consistent():
    u, y = _data(n=20000, noise=0.3, seed=1)
    m = fit_arx(u, y, sample_period=T, na=2, nb=2)
    np.testing.assert_allclose(m.a, A_TRUE[1:], atol=0.01)
    np.testing.assert_allclose(m.b, B_TRUE[1:], atol=0.01)
    assert m.residual_variance == pytest.approx(0.09, rel=0.05)


def test_overparameterised_solvers_agree_on_response():
    u, y = _data(n=3000, noise=0.05, seed=2)
    mn = fit_arx(u, y, sample_period=T, na=6, nb=6, solver='normal')
    mq = fit_arx(u, y, sample_period=T, na=6, nb=6, solver='qr')
    assert mn.cond == pytest.approx(mq.cond, rel=1e-3)
    omega = np.linspace(1e3, 3e5, 20)
    np.testing.assert_allclose(mn.frequency_response(omega), mq.frequency_response(omega),
                               rtol=1e-6)


def test_normal_equations_match_paper_definition():
    """R = 1/N sum phi phi^T, f = 1/N sum y phi; theta = R^-1 f; cond(R) reported."""
    u, y = _data(n=500, noise=0.1, seed=3)
    phi, target = regressors(u, y, 3, 2)
    assert phi.shape == (497, 5)
    # row for k = 3: [-y2, -y1, -y0, u2, u1]
    np.testing.assert_allclose(phi[0], [-y[2], -y[1], -y[0], u[2], u[1]])
    r = phi.T @ phi / phi.shape[0]
    f = phi.T @ target / phi.shape[0]
    theta = np.linalg.solve(r, f)
    m = fit_arx(u, y, sample_period=T, na=3, nb=2)
    np.testing.assert_allclose([*m.a, *m.b], theta, rtol=1e-9)
    assert m.cond == pytest.approx(np.linalg.cond(r), rel=1e-9)


def test_model_evaluation():
    m = ArxModel(a=tuple(A_TRUE[1:]), b=tuple(B_TRUE[1:]), sample_period=T, cond=1.0,
                 residual_variance=0.0, n_samples=0)
    assert (m.na, m.nb) == (2, 2)
    omega = np.linspace(0.0, np.pi / T, 33)[:-1]
    np.testing.assert_allclose(m.frequency_response(omega),
                               freqz(B_TRUE, A_TRUE, worN=omega * T)[1], rtol=1e-12)
    u, y = _data(n=50)
    np.testing.assert_allclose(m.simulate(u), y, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(m.simulate(np.vstack([u, u])), np.vstack([y, y]), atol=1e-12)
    # one-step-ahead prediction of noise-free data is exact
    np.testing.assert_allclose(m.predict(u, y), y, atol=1e-12)
    num, den = m.transfer_function()
    np.testing.assert_allclose(den, A_TRUE)
    np.testing.assert_allclose(num, B_TRUE)
    np.testing.assert_allclose(np.sort(np.abs(m.poles())), [np.sqrt(0.7)] * 2)


def test_unequal_orders_transfer_function():
    m = ArxModel(a=(-0.5,), b=(1.0, 0.25, 0.1), sample_period=T, cond=1.0,
                 residual_variance=0.0, n_samples=0)
    num, den = m.transfer_function()
    np.testing.assert_allclose(den, [1, -0.5, 0, 0])
    np.testing.assert_allclose(num, [0, 1.0, 0.25, 0.1])
    assert sorted(np.abs(m.poles()))[:2] == [0.0, 0.0]


@pytest.mark.parametrize(('na', 'nb'), [(0, 2), (2, 0), (61, 2), (2, 61), (2.5, 2)])
def test_bad_orders(na, nb):
    u, y = _data(n=300)
    with pytest.raises(ConfigurationError, match=r'must be an integer in 1\.\.60'):
        fit_arx(u, y, sample_period=T, na=na, nb=nb)


def test_bad_data():
    u, y = _data(n=300)
    with pytest.raises(InvalidDataError, match='needs at least'):
        fit_arx(u[: min_data_length(15, 15) - 1], y[: min_data_length(15, 15) - 1],
                sample_period=T)
    fit_arx(u[: min_data_length(2, 2)], y[: min_data_length(2, 2)], sample_period=T, na=2,
            nb=2)
    with pytest.raises(InvalidDataError, match='equal length'):
        fit_arx(u, y[:-1], sample_period=T, na=2, nb=2)
    bad = y.copy()
    bad[10] = np.nan
    with pytest.raises(InvalidDataError, match='NaN'):
        fit_arx(u, bad, sample_period=T, na=2, nb=2)
    with pytest.raises(ConfigurationError):
        fit_arx(u, y, sample_period=T, na=2, nb=2, solver='svd')
    with pytest.raises(ConfigurationError):
        fit_arx(u, y, sample_period=-T, na=2, nb=2)


@pytest.mark.parametrize('solver', ['normal', 'qr'])
def test_no_excitation_is_an_identification_error(solver):
    z = np.zeros(300)
    with pytest.raises(IdentificationError):
        fit_arx(z, z, sample_period=T, na=2, nb=2, solver=solver)
