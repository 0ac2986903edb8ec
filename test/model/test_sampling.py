"""Tests of the running plant (Physics), its exact sampling, and plant changes over time."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.linalg import expm

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model import (
    PAPER_MODEL,
    REFERENCE_MODEL,
    TAU,
    Drift,
    InputDynamics,
    ModalModel,
    Physics,
    StepChange,
    plant_at,
    simulate,
)
from galvo_sysid.model.dynamics import expm_balanced
from galvo_sysid.model.sampling import continuous_plant, sample_plant

NOMINAL = PAPER_MODEL.physics()


def _run(ph: Physics, u: np.ndarray, *, substeps: int = 1) -> np.ndarray:
    """Drive the sampled plant with commands u (no disturbance current)."""
    sp = sample_plant(ph, substeps=substeps)
    x = np.zeros(sp.phi.shape[0])
    hist = np.zeros(sp.whole + 2)
    y = np.empty(u.shape[0])
    for k in range(u.shape[0]):
        y[k] = sp.continuous.c @ x
        hist = np.concatenate([[u[k]], hist[:-1]])
        x = sp.phi @ x + sp.g_old * hist[sp.whole + 1] + sp.g_new * hist[sp.whole]
    return y


@pytest.mark.parametrize('dead_time', [0.0, 0.37 * TAU, TAU, 1.5 * TAU])
@pytest.mark.parametrize('lag', [0.6 * TAU, 0.0])
@pytest.mark.parametrize('substeps', [1, 5])
def test_sampling_matches_plant_discretisation(dead_time: float, lag: float,
                                                substeps: int) -> None:
    u = np.random.default_rng(1).normal(size=200)
    ph = replace(NOMINAL, lag_time_constant=lag, dead_time=dead_time)
    ref = simulate(REFERENCE_MODEL, InputDynamics(lag_time_constant=lag, dead_time=dead_time),
                   u, sample_period=TAU)
    y = _run(ph, u, substeps=substeps)
    np.testing.assert_allclose(y, ref, atol=1e-12 * np.abs(ref).max())


def test_dead_time_of_the_input_dynamics_equals_an_input_delay_effect() -> None:
    u = np.random.default_rng(2).normal(size=200)
    dynamics = InputDynamics(computation_delay=1, lag_time_constant=0.0, dead_time=0.6 * TAU)
    ref = simulate(REFERENCE_MODEL, dynamics, u, sample_period=TAU)
    y = _run(replace(PAPER_MODEL, dynamics=dynamics).physics(), u)
    np.testing.assert_allclose(y, ref, atol=1e-12 * np.abs(ref).max())
    as_effect = replace(PAPER_MODEL, dynamics=InputDynamics(lag_time_constant=0.0)).with_effect(
        'input_delay', {'delay': 1.6 * TAU})
    np.testing.assert_allclose(_run(as_effect.physics(), u), y, atol=1e-12 * np.abs(ref).max())


def test_disturbance_drive_split_over_substeps_sums_to_the_sample() -> None:
    sp = sample_plant(NOMINAL, substeps=7)
    np.testing.assert_allclose(sp.gamma_d.sum(axis=1), sp.g_d, rtol=1e-12, atol=1e-20)
    assert sp.gamma_d.shape == (sp.phi.shape[0], 7)


def test_expm_balanced_matches_scipy() -> None:
    ph = PAPER_MODEL.with_effect('pivot_stiffness', {'natural_frequency': 600.0}).with_effect(
        'unmodeled_resonance', {'natural_frequency': 2 * math.pi * 4000, 'damping_ratio': 0.02,
                                'residue': 3e5}).physics()
    cp = continuous_plant(ph)
    for t in (TAU, TAU / 8, 0.37 * TAU):
        ref = expm(cp.a * t)
        np.testing.assert_allclose(expm_balanced(cp.a * t), ref,
                                   atol=1e-13 * np.abs(ref).max())


def _mech_response(ph: Physics, omega: np.ndarray) -> np.ndarray:
    """Response from the disturbance current d to the angle (the mechanics)."""
    cp = continuous_plant(ph)
    n = cp.a.shape[0]
    return np.array([cp.c @ np.linalg.solve(1j * w * np.eye(n) - cp.a, cp.b_d) for w in omega])


def test_effects_change_the_mechanics_as_specified() -> None:
    omega = np.array([2 * math.pi * f for f in (50.0, 700.0, 9000.0, 23000.0)])
    s = 1j * omega
    nominal = REFERENCE_MODEL.frequency_response(omega)
    np.testing.assert_allclose(_mech_response(NOMINAL, omega), nominal, rtol=1e-9)
    wp = 2 * math.pi * 100
    pivot = _mech_response(
        PAPER_MODEL.with_effect('pivot_stiffness', {'natural_frequency': wp}).physics(), omega)
    k0 = REFERENCE_MODEL.k0
    np.testing.assert_allclose(pivot, nominal - k0 / s**2 + k0 / (s**2 + wp**2), rtol=1e-9)
    wr, zr, kr = 2 * math.pi * 4000, 0.02, 2e5
    extra = _mech_response(PAPER_MODEL.with_effect('unmodeled_resonance', {
        'natural_frequency': wr, 'damping_ratio': zr, 'residue': kr}).physics(), omega)
    np.testing.assert_allclose(extra, nominal + kr / (s**2 + 2 * zr * wr * s + wr**2),
                               rtol=1e-9)


def test_gain_ratio_scales_the_command_response_only() -> None:
    u = np.random.default_rng(2).normal(size=100)
    y1 = _run(NOMINAL, u)
    gained = PAPER_MODEL.with_effect('gain_change', {'gain_ratio': 1.25}).physics()
    np.testing.assert_allclose(_run(gained, u), 1.25 * y1, rtol=1e-12, atol=1e-18)
    np.testing.assert_array_equal(continuous_plant(NOMINAL).b_d, continuous_plant(gained).b_d)


def test_linearity_flag() -> None:
    assert NOMINAL.linear
    assert replace(NOMINAL, dead_time=TAU, gain_ratio=2.0, pivot_frequency=10.0).linear
    assert not replace(NOMINAL, friction_current=0.01).linear
    assert not replace(NOMINAL, current_limit=2.0).linear


def test_bad_physics_values_raise() -> None:
    for kwargs in ({'dead_time': -1e-6}, {'friction_current': math.nan},
                   {'current_limit': math.nan}, {'gain_ratio': math.inf},
                   {'pivot_frequency': -1.0}, {'k0': 1e300}):
        with pytest.raises(ConfigurationError):
            replace(NOMINAL, **kwargs)  # type: ignore[arg-type]


def test_parameters_by_name() -> None:
    p = NOMINAL.parameters()
    assert p['omega_2'] == REFERENCE_MODEL.natural_frequencies[1]
    assert p['k0'] == REFERENCE_MODEL.k0
    assert p['gain_ratio'] == 1.0
    assert math.isinf(p['current_limit'])
    changed = NOMINAL.with_parameter('zeta_3', 0.01).with_parameter('k2', -5e6)
    assert changed.damping_ratios[2] == 0.01
    assert changed.residues[1] == -5e6
    assert changed.with_parameter('friction_current', 0.02).friction_current == 0.02
    assert changed.with_parameter('lag_time_constant', 0.0).lag_time_constant == 0
    with pytest.raises(ConfigurationError, match='3 resonant modes'):
        NOMINAL.with_parameter('omega_4', 1.0)
    with pytest.raises(ConfigurationError):
        NOMINAL.with_parameter('omega_1', -1.0)


def test_drift_is_linear_in_time_and_moves() -> None:
    w1 = REFERENCE_MODEL.natural_frequencies[0]
    per_second = Drift('omega_1', -0.01, unit='second', start=1.0)
    assert plant_at(NOMINAL, time=0.5, move=0, drifts=[per_second]) == NOMINAL
    at = plant_at(NOMINAL, time=3.0, move=0, drifts=[per_second])
    assert at.natural_frequencies[0] == pytest.approx(w1 * (1 - 0.02))
    per_move = Drift('k0', 2.0, unit='move', relative=False)
    assert plant_at(NOMINAL, time=0.0, move=10, drifts=[per_move]).k0 == \
        pytest.approx(REFERENCE_MODEL.k0 + 20.0)


def test_steps_apply_from_their_time_on() -> None:
    steps = [StepChange('friction_current', 0.01, at=5), StepChange('gain_ratio', 1.1, at=2.0,
                                                                     unit='second',
                                                                     relative=True)]
    assert plant_at(NOMINAL, time=1.0, move=4, steps=steps) == NOMINAL
    s = plant_at(NOMINAL, time=1.0, move=5, steps=steps)
    assert s.friction_current == 0.01
    assert s.gain_ratio == 1.0
    s = plant_at(NOMINAL, time=2.0, move=5, steps=steps)
    assert s.gain_ratio == pytest.approx(1.1)


def test_bad_changes_raise() -> None:
    with pytest.raises(ConfigurationError):
        Drift('omega_1', 0.1, unit='hour')
    with pytest.raises(ConfigurationError):
        Drift('speed', 0.1)
    with pytest.raises(ConfigurationError):
        StepChange('k0', math.nan, at=1)
    with pytest.raises(ConfigurationError):
        StepChange('k0', 1.0, at=-1)
    with pytest.raises(ConfigurationError):  # a name the plant does not have
        plant_at(NOMINAL, time=0, move=0, steps=[StepChange('omega_9', 1.0, at=0)])


def test_model_without_modes_is_a_rigid_body() -> None:
    rigid = ModalModel(k0=1e6, residues=(), natural_frequencies=(), damping_ratios=())
    u = np.zeros(50)
    u[0] = 1.0
    y = _run(replace(PAPER_MODEL, modal=rigid).physics(), u)
    ref = simulate(rigid, InputDynamics(), u, sample_period=TAU)
    np.testing.assert_allclose(y, ref, rtol=1e-12, atol=1e-18)
