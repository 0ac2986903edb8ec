"""Tests of the simulated plant with effects, its sampling, and plant changes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model.effects import (
    EFFECT_NAMES,
    Drift,
    PlantEffects,
    PlantSpec,
    Resonance,
    StepChange,
    continuous_plant,
    expm_balanced,
    plant_at,
    sample_plant,
)
from galvo_sysid.model.modal import REFERENCE_MODEL, TAU, InputDynamics, ModalModel, simulate


def _run(spec: PlantSpec, u: np.ndarray, *, substeps: int = 1) -> np.ndarray:
    """Drive the sampled plant with commands u (no disturbance current)."""
    sp = sample_plant(spec, substeps=substeps)
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
    spec = PlantSpec(dynamics=InputDynamics(lag_time_constant=lag),
                     effects=PlantEffects(dead_time=dead_time))
    ref = simulate(REFERENCE_MODEL, InputDynamics(lag_time_constant=lag, dead_time=dead_time),
                   u, sample_period=TAU)
    y = _run(spec, u, substeps=substeps)
    np.testing.assert_allclose(y, ref, atol=1e-12 * np.abs(ref).max())


def test_dead_time_of_the_input_dynamics_is_honoured() -> None:
    # The same total delay given in InputDynamics instead of as an effect: same plant.
    u = np.random.default_rng(2).normal(size=200)
    dynamics = InputDynamics(computation_delay=1, lag_time_constant=0.0, dead_time=0.6 * TAU)
    ref = simulate(REFERENCE_MODEL, dynamics, u, sample_period=TAU)
    y = _run(PlantSpec(dynamics=dynamics), u)
    np.testing.assert_allclose(y, ref, atol=1e-12 * np.abs(ref).max())
    as_effect = _run(PlantSpec(dynamics=InputDynamics(lag_time_constant=0.0),
                               effects=PlantEffects(dead_time=0.6 * TAU)), u)
    np.testing.assert_allclose(y, as_effect, atol=1e-12 * np.abs(ref).max())


def test_disturbance_drive_split_over_substeps_sums_to_the_sample() -> None:
    sp = sample_plant(PlantSpec(), substeps=7)
    np.testing.assert_allclose(sp.gamma_d.sum(axis=1), sp.g_d, rtol=1e-12, atol=1e-20)
    assert sp.gamma_d.shape == (sp.phi.shape[0], 7)


def test_expm_balanced_matches_scipy() -> None:
    spec = PlantSpec(effects=PlantEffects(pivot_frequency=600.0, resonances=(
        Resonance(2 * math.pi * 4000, 0.02, 3e5),)))
    cp = continuous_plant(spec)
    for t in (TAU, TAU / 8, 0.37 * TAU):
        ref = expm(cp.a * t)
        np.testing.assert_allclose(expm_balanced(cp.a * t), ref,
                                   atol=1e-13 * np.abs(ref).max())


def _mech_response(spec: PlantSpec, omega: np.ndarray) -> np.ndarray:
    """Response from the disturbance current d to the angle (the mechanics)."""
    cp = continuous_plant(spec)
    n = cp.a.shape[0]
    return np.array([cp.c @ np.linalg.solve(1j * w * np.eye(n) - cp.a, cp.b_d) for w in omega])


def test_effects_change_the_mechanics_as_specified() -> None:
    omega = np.array([2 * math.pi * f for f in (50.0, 700.0, 9000.0, 23000.0)])
    s = 1j * omega
    nominal = REFERENCE_MODEL.frequency_response(omega)
    np.testing.assert_allclose(_mech_response(PlantSpec(), omega), nominal, rtol=1e-9)
    wp = 2 * math.pi * 100
    pivot = _mech_response(PlantSpec(effects=PlantEffects(pivot_frequency=wp)), omega)
    k0 = REFERENCE_MODEL.k0
    np.testing.assert_allclose(pivot, nominal - k0 / s**2 + k0 / (s**2 + wp**2), rtol=1e-9)
    res = Resonance(natural_frequency=2 * math.pi * 4000, damping_ratio=0.02, residue=2e5)
    extra = _mech_response(PlantSpec(effects=PlantEffects(resonances=(res,))), omega)
    wr = res.natural_frequency
    np.testing.assert_allclose(
        extra, nominal + res.residue / (s**2 + 2 * res.damping_ratio * wr * s + wr**2),
        rtol=1e-9)


def test_gain_ratio_scales_the_command_response_only() -> None:
    u = np.random.default_rng(2).normal(size=100)
    y1 = _run(PlantSpec(), u)
    y2 = _run(PlantSpec(effects=PlantEffects(gain_ratio=1.25)), u)
    np.testing.assert_allclose(y2, 1.25 * y1, rtol=1e-12, atol=1e-18)
    a = continuous_plant(PlantSpec()).b_d
    b = continuous_plant(PlantSpec(effects=PlantEffects(gain_ratio=1.25))).b_d
    np.testing.assert_array_equal(a, b)  # friction/noise current enters unscaled


def test_linearity_flag() -> None:
    assert PlantEffects().is_linear
    assert PlantEffects(dead_time=TAU, gain_ratio=2.0, pivot_frequency=10.0).is_linear
    assert not PlantEffects(friction_current=0.01).is_linear
    assert not PlantEffects(current_limit=2.0).is_linear


def test_effect_names_round_trip() -> None:
    effects = PlantEffects()
    params = {
        'input_delay': {'delay': 2.1 * TAU},
        'unmodeled_resonance': {'natural_frequency': 3e4, 'damping_ratio': 0.01,
                                'residue': 1e5},
        'coulomb_friction': {'friction_current': 0.01},
        'pivot_stiffness': {'natural_frequency': 300.0},
        'gain_change': {'gain_ratio': 0.9},
        'current_saturation': {'current_limit': 0.7},
    }
    assert set(params) == set(EFFECT_NAMES)
    for name, p in params.items():
        effects = effects.with_effect(name, p)
    assert effects.dead_time == pytest.approx(0.5 * TAU)
    assert effects.friction_current == 0.01
    assert effects.pivot_frequency == 300.0
    assert effects.gain_ratio == 0.9
    assert effects.current_limit == 0.7
    assert effects.resonances == (Resonance(3e4, 0.01, 1e5),)
    items = effects.to_list()
    assert {i['effect'] for i in items} == set(EFFECT_NAMES)
    assert {i['effect']: i['parameters'] for i in items}['input_delay']['delay'] == \
        pytest.approx(2.1 * TAU)
    assert PlantEffects.from_list(items) == effects
    assert PlantEffects().to_list() == []
    assert PlantEffects.from_list([{'effect': 'none', 'parameters': {}}]) == PlantEffects()


@pytest.mark.parametrize(('name', 'params'), [
    ('magic', {'x': 1.0}),
    ('coulomb_friction', {'friction': 0.1}),
    ('coulomb_friction', {'friction_current': -0.1}),
    ('gain_change', {'gain_ratio': 0.0}),
    ('current_saturation', {'current_limit': -1.0}),
    ('input_delay', {'delay': 0.5 * TAU}),
    ('unmodeled_resonance', {'natural_frequency': 1e4, 'damping_ratio': 0.0, 'residue': 1.0}),
])
def test_bad_effects_raise(name: str, params: dict[str, float]) -> None:
    with pytest.raises(ConfigurationError):
        PlantEffects().with_effect(name, params)


def test_bad_effect_values_raise() -> None:
    for kwargs in ({'dead_time': -1e-6}, {'friction_current': math.nan},
                   {'current_limit': math.nan}, {'gain_ratio': math.inf},
                   {'pivot_frequency': -1.0}):
        with pytest.raises(ConfigurationError):
            PlantEffects(**kwargs)  # type: ignore[arg-type]
    with pytest.raises(ConfigurationError):
        PlantEffects.from_list([{'parameters': {}}])


def test_parameters_by_name() -> None:
    spec = PlantSpec()
    p = spec.parameters()
    assert p['omega_2'] == REFERENCE_MODEL.natural_frequencies[1]
    assert p['k0'] == REFERENCE_MODEL.k0
    assert p['gain_ratio'] == 1.0
    assert math.isinf(p['current_limit'])
    changed = spec.replace_parameter('zeta_3', 0.01).replace_parameter('k2', -5e6)
    assert changed.model.damping_ratios[2] == 0.01
    assert changed.model.residues[1] == -5e6
    assert changed.replace_parameter('friction_current', 0.02).effects.friction_current == 0.02
    assert changed.replace_parameter('lag_time_constant', 0.0).dynamics.lag_time_constant == 0
    with pytest.raises(ConfigurationError):
        spec.replace_parameter('omega_4', 1.0)
    with pytest.raises(ConfigurationError):
        spec.replace_parameter('omega_1', -1.0)


def test_drift_is_linear_in_time_and_moves() -> None:
    base = PlantSpec()
    w1 = REFERENCE_MODEL.natural_frequencies[0]
    per_second = Drift('omega_1', -0.01, unit='second', start=1.0)
    assert plant_at(base, time=0.5, move=0, drifts=[per_second]) == base
    at = plant_at(base, time=3.0, move=0, drifts=[per_second])
    assert at.model.natural_frequencies[0] == pytest.approx(w1 * (1 - 0.02))
    per_move = Drift('k0', 2.0, unit='move', relative=False)
    assert plant_at(base, time=0.0, move=10, drifts=[per_move]).model.k0 == \
        pytest.approx(REFERENCE_MODEL.k0 + 20.0)


def test_steps_apply_from_their_time_on() -> None:
    base = PlantSpec()
    steps = [StepChange('friction_current', 0.01, at=5), StepChange('gain_ratio', 1.1, at=2.0,
                                                                     unit='second',
                                                                     relative=True)]
    assert plant_at(base, time=1.0, move=4, steps=steps) == base
    s = plant_at(base, time=1.0, move=5, steps=steps)
    assert s.effects.friction_current == 0.01
    assert s.effects.gain_ratio == 1.0
    s = plant_at(base, time=2.0, move=5, steps=steps)
    assert s.effects.gain_ratio == pytest.approx(1.1)


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
        plant_at(PlantSpec(), time=0, move=0, steps=[StepChange('omega_9', 1.0, at=0)])


def test_model_without_modes_is_a_rigid_body() -> None:
    rigid = ModalModel(k0=1e6, residues=(), natural_frequencies=(), damping_ratios=())
    u = np.zeros(50)
    u[0] = 1.0
    y = _run(PlantSpec(model=rigid), u)
    ref = simulate(rigid, InputDynamics(), u, sample_period=TAU)
    np.testing.assert_allclose(y, ref, rtol=1e-12, atol=1e-18)
