"""Tests of galvo_sysid.ident.decompose: ZOH modal decomposition, whole-model conversion, Bode
data."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.linalg
from scipy.signal import ss2tf

from galvo_sysid.errors import ConfigurationError, IdentificationError
from galvo_sysid.ident.arx import ArxModel
from galvo_sysid.ident.decompose import (
    arx_to_continuous,
    arx_to_modal,
    bode_data,
    continuous_modal_decomposition,
    modal_decomposition,
    simulate_zoh,
    zoh_mode_numerator,
)
from galvo_sysid.model import (
    REFERENCE_MODEL,
    TAU,
    InputDynamics,
    ModalModel,
    discretize,
    simulate,
)
from galvo_sysid.model.modal import default_bands

T = TAU
NO_DELAY = InputDynamics(computation_delay=0, lag_time_constant=0.0)


def _as_arx(num, den):
    """ArxModel of H(z) = num/den (descending powers of z, strictly proper, equal length)."""
    num = np.asarray(num, dtype=float) / den[0]
    den = np.asarray(den, dtype=float) / den[0]
    assert abs(num[0]) < 1e-12 * np.max(np.abs(num))
    return ArxModel(a=tuple(den[1:]), b=tuple(num[1:]), sample_period=T, cond=1.0,
                    residual_variance=0.0, n_samples=0)


def _zoh_tf(model):
    ss = discretize(model, NO_DELAY, T)
    num, den = ss2tf(ss.a, ss.b[:, None], ss.c[None, :], np.zeros((1, 1)))
    return num[0], den


def _assert_model_close(model, truth, rtol):
    got = model.parameters()
    for name, value in truth.parameters().items():
        assert got[name] == pytest.approx(value, rel=rtol), name


@pytest.mark.parametrize(('omega', 'zeta'), [(7.108e4, 6.218e-3), (1.674e5, 0.05), (2e5, 0.9)])
def test_zoh_mode_numerator_matches_matrix_exponential(omega, zeta):
    a_c = np.array([[0.0, 1.0], [-omega**2, -2 * zeta * omega]])
    m = np.zeros((3, 3))
    m[:2, :2] = a_c * T
    m[1, 2] = T
    e = scipy.linalg.expm(m)
    phi, gamma = e[:2, :2], e[:2, 2]
    beta1, beta0 = zoh_mode_numerator(omega, zeta, T)
    assert beta1 == pytest.approx(gamma[0], rel=1e-10)
    assert beta0 == pytest.approx((phi @ gamma - np.trace(phi) * gamma)[0], rel=1e-10)
    with pytest.raises(ConfigurationError):
        zoh_mode_numerator(omega, 1.2, T)


def test_simulate_zoh_matches_the_plant_simulation():
    rng = np.random.default_rng(4)
    u = rng.standard_normal((2, 300))
    y_ref = simulate(REFERENCE_MODEL, NO_DELAY, u, sample_period=T)
    y = simulate_zoh(REFERENCE_MODEL, u, sample_period=T)
    np.testing.assert_allclose(y, y_ref, rtol=1e-9, atol=1e-12 * np.max(np.abs(y_ref)))


def test_exact_zoh_model_decomposes_to_table_i():
    dec = modal_decomposition(_as_arx(*_zoh_tf(REFERENCE_MODEL)))
    _assert_model_close(dec.model, REFERENCE_MODEL, 1e-7)
    assert all(abs(p - 1) < 1e-3 for p in dec.rigid_poles)
    assert len(dec.mode_poles) == 3
    assert dec.spurious_poles == ()


def test_drifted_model_and_custom_bands():
    drifted = ModalModel(k0=3.3e6, residues=(2.3e6, -5.0e6, -6e5),
                         natural_frequencies=(6.6e4, 1.25e5, 1.6e5),
                         damping_ratios=(9e-3, 5e-3, 2e-2))
    model = arx_to_modal(_as_arx(*_zoh_tf(drifted)))
    _assert_model_close(model, drifted, 1e-7)
    # two modes only, bands given explicitly
    two = ModalModel(k0=1e6, residues=(1e6, 2e5), natural_frequencies=(4e4, 2.5e5),
                     damping_ratios=(0.01, 0.2))
    model = arx_to_modal(_as_arx(*_zoh_tf(two)), bands=[(2e4, 8e4), (1.5e5, 3e5)])
    _assert_model_close(model, two, 1e-7)


def test_spurious_poles_are_rejected():
    """Small extra partial-fraction terms (noise-model poles) do not fool the pick.

    Added: a lightly damped pair in band 1 and a better damped one in band 2, each with a
    small residue, and a negative real pole. Partial fractions are exact, so the modes come
    back unchanged.
    """
    num, den = _zoh_tf(REFERENCE_MODEL)
    for w, z, k in ((7.5e4, 0.002, 2e4), (1.3e5, 0.05, 3e5)):
        num, den = _with_extra_mode(num, den, w, z, k)
    # negative real pole, residue 1e-6 (cf. the rigid body's k0 T^2 ~ 4e-4)
    num = np.polyadd(np.convolve(num, [1.0, 0.8]), 1e-6 * den)
    den = np.convolve(den, [1.0, 0.8])
    arx = _as_arx(num, den)
    dec = modal_decomposition(arx)
    _assert_model_close(dec.model, REFERENCE_MODEL, 1e-6)
    assert len(dec.spurious_poles) == 5
    # the whole-model matrix logarithm cannot represent the negative real pole
    cont = arx_to_continuous(arx)
    assert not cont.is_real
    with pytest.raises(IdentificationError, match='complex'):
        continuous_modal_decomposition(cont)


def _with_extra_mode(num, den, omega, zeta, k):
    """num/den plus the ZOH of k/(s^2 + 2 zeta omega s + omega^2) (a spurious pole pair)."""
    mode = ModalModel(k0=0.0, residues=(k,), natural_frequencies=(omega,),
                      damping_ratios=(zeta,))
    ss = discretize(mode, NO_DELAY, T)
    keep = np.r_[2:4]
    n2, d2 = ss2tf(ss.a[np.ix_(keep, keep)], ss.b[keep, None], ss.c[None, keep],
                   np.zeros((1, 1)))
    return np.polyadd(np.convolve(num, d2), np.convolve(n2[0], den)), np.convolve(den, d2)


def test_selection_prefers_the_resonance_peak():
    """A heavily damped noise pair with a larger residue next to a weak, lightly damped mode 3.

    The default ('peak') keeps the true mode; ranking by |k|/omega ('residue') does not.
    """
    num, den = _with_extra_mode(*_zoh_tf(REFERENCE_MODEL), 1.9e5, 0.06, -6e5)
    arx = _as_arx(num, den)
    model = modal_decomposition(arx).model
    assert model.natural_frequencies[2] == pytest.approx(1.674e5, rel=1e-6)
    assert model.residues[2] == pytest.approx(-4.604e5, rel=1e-4)
    assert modal_decomposition(arx, selection='h2').model.natural_frequencies[2] == \
        pytest.approx(1.674e5, rel=1e-6)
    wrong = modal_decomposition(arx, selection='residue').model
    assert wrong.natural_frequencies[2] == pytest.approx(1.9e5, rel=1e-6)
    with pytest.raises(ConfigurationError):
        modal_decomposition(arx, selection='largest')


def test_whole_model_conversion_of_a_clean_model():
    arx = _as_arx(*_zoh_tf(REFERENCE_MODEL))
    cont = arx_to_continuous(arx)
    assert cont.is_real
    _assert_model_close(continuous_modal_decomposition(cont), REFERENCE_MODEL, 1e-4)
    omega = np.geomspace(1e3, 2.5e5, 40)
    np.testing.assert_allclose(cont.frequency_response(omega),
                               REFERENCE_MODEL.frequency_response(omega), rtol=1e-4)


def test_missing_mode_or_rigid_body_raises():
    arx = _as_arx(*_zoh_tf(REFERENCE_MODEL))
    with pytest.raises(IdentificationError, match='no lightly damped mode'):
        modal_decomposition(arx, bands=[(6e4, 8e4), (2.0e5, 2.5e5)])
    with pytest.raises(IdentificationError, match='no lightly damped mode'):
        modal_decomposition(arx, max_damping=1e-3)
    # no rigid body: a model of three modes only (plus a well-damped pair far from z = 1)
    modes = ModalModel(k0=0.0, residues=REFERENCE_MODEL.residues,
                       natural_frequencies=REFERENCE_MODEL.natural_frequencies,
                       damping_ratios=REFERENCE_MODEL.damping_ratios)
    ss = discretize(modes, NO_DELAY, T)
    keep = np.r_[2:8]  # drop the (uncontrollable) rigid-body states
    num, den = ss2tf(ss.a[np.ix_(keep, keep)], ss.b[keep, None], ss.c[None, keep],
                     np.zeros((1, 1)))
    num = np.convolve(num[0], [1.0, -0.2])
    den = np.polymul(den, np.poly([0.3 + 0.3j, 0.3 - 0.3j]).real)
    den = np.polymul(den, [1.0, -0.2 + 1e-3])
    with pytest.raises(IdentificationError, match='rigid-body'):
        modal_decomposition(_as_arx(np.r_[0.0, num], den))


def test_order_too_low_raises():
    arx = ArxModel(a=(-1.5, 0.7), b=(1.0, 0.5), sample_period=T, cond=1.0,
                   residual_variance=0.0, n_samples=0)
    with pytest.raises(IdentificationError, match='cannot hold'):
        modal_decomposition(arx)


def test_default_bands_partition_around_the_modes():
    bands = default_bands(REFERENCE_MODEL)
    w = REFERENCE_MODEL.natural_frequencies
    assert len(bands) == 3
    for (lo, hi), wi in zip(bands, w, strict=True):
        assert lo < wi < hi
    for (_, hi), (lo, _) in itertools.pairwise(bands):
        assert hi == pytest.approx(lo)
    # outer bands mirror the inner edges (symmetric in log frequency)
    assert w[0] / bands[0][0] == pytest.approx(bands[0][1] / w[0])
    assert bands[2][1] / w[2] == pytest.approx(w[2] / bands[2][0])
    assert default_bands(REFERENCE_MODEL, outer_ratio=1.3)[2][1] == pytest.approx(1.3 * w[2])
    assert default_bands(REFERENCE_MODEL, sample_period=1.6e-5)[-1][1] <= 0.98 * np.pi / 1.6e-5
    with pytest.raises(ConfigurationError):
        default_bands(REFERENCE_MODEL, outer_ratio=0.9)
    with pytest.raises(ConfigurationError):
        modal_decomposition(_as_arx(*_zoh_tf(REFERENCE_MODEL)), bands=[(5e4, 4e4)])


def test_bode_data():
    omega = np.array([1e4, 7.108e4, 2e5])
    mag, phase = bode_data(REFERENCE_MODEL, omega)
    h = REFERENCE_MODEL.frequency_response(omega)
    np.testing.assert_allclose(mag, 20 * np.log10(np.abs(h)))
    assert phase[0] == pytest.approx(-180.0, abs=1.0)
    dyn = InputDynamics()
    mag2, phase2 = bode_data(REFERENCE_MODEL, omega, input_dynamics=dyn, sample_period=T)
    np.testing.assert_allclose(mag2 - mag, 20 * np.log10(np.abs(dyn.frequency_response(omega, T))))
    # delay + lag: extra phase lag of w T + atan(w 0.6 T) at the first frequency
    extra = np.degrees(omega[0] * T + np.arctan(omega[0] * 0.6 * T))
    assert phase2[0] - phase[0] == pytest.approx(-extra, abs=1e-6)
    arx = _as_arx(*_zoh_tf(REFERENCE_MODEL))
    mag3, _ = bode_data(arx, omega[:1])
    assert mag3[0] == pytest.approx(mag[0], abs=0.01)  # ZOH ~ continuous at low frequency
    with pytest.raises(ConfigurationError):
        bode_data(arx, omega, input_dynamics=dyn, sample_period=T)
    with pytest.raises(ConfigurationError):
        bode_data(REFERENCE_MODEL, omega, input_dynamics=dyn)
