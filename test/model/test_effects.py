"""Tests of the effect registry: names, parameters, checks and how each effect acts."""

from __future__ import annotations

import math

import numpy as np
import pytest

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model import EFFECT_NAMES, EFFECTS, PAPER_MODEL, TAU, Effect, parse_effect
from galvo_sysid.model.effects import effects_from_list

PARAMS = {
    'input_delay': {'delay': 2.1 * TAU},
    'unmodeled_resonance': {'natural_frequency': 3e4, 'damping_ratio': 0.01, 'residue': 1e5},
    'coulomb_friction': {'friction_current': 0.01},
    'pivot_stiffness': {'natural_frequency': 300.0},
    'gain_change': {'gain_ratio': 0.9},
    'current_saturation': {'current_limit': 0.7},
    'viscous_friction': {'current_per_velocity': 1e-5},
    'cogging_torque': {'amplitude': 0.01, 'period': 0.7, 'phase': 0.3},
    'encoder_cyclic_error': {'amplitude': 1e-3, 'period': 0.5, 'phase': -1.0},
    'amplifier_bandwidth': {'bandwidth': 15e3},
    'proposed_terms': {'current_x3': -3e-3, 'reading_sin_amplitude': 1e-4,
                       'reading_sin_period': 0.3},
}


def test_every_effect_acts_as_registered() -> None:
    assert set(PARAMS) == set(EFFECT_NAMES) == set(EFFECTS)
    model = PAPER_MODEL
    for name, p in PARAMS.items():
        model = model.with_effect(name, p)
    ph = model.physics()
    assert ph.pure_delay + ph.lag_time_constant == pytest.approx(2.1 * TAU)
    lag = 1 / (2 * math.pi * 15e3)               # the amplifier's, before the input delay
    assert ph.lag_time_constant == pytest.approx(lag)
    assert ph.dead_time == pytest.approx(1.1 * TAU - lag)
    assert ph.viscous_coefficient == 1e-5
    assert ph.rigid_damping == pytest.approx(1e-5 * PAPER_MODEL.modal.k0)
    assert (ph.cogging_amplitude, ph.cogging_period, ph.cogging_phase) == (0.01, 0.7, 0.3)
    assert (ph.encoder_error_amplitude, ph.encoder_error_period,
            ph.encoder_error_phase) == (1e-3, 0.5, -1.0)
    assert ph.friction_current == 0.01
    assert ph.pivot_frequency == 300.0
    assert ph.gain_ratio == 0.9
    assert ph.current_limit == 0.7
    assert ph.natural_frequencies[-1] == 3e4
    assert ph.residues[-1] == 1e5
    assert ph.terms == (('current_x3', -3e-3), ('reading_sin_amplitude', 1e-4),
                        ('reading_sin_period', 0.3), ('reading_sin_phase', 0.0))
    assert not ph.linear
    items = [e.to_dict() for e in model.effects]
    assert {i['effect'] for i in items} == set(EFFECT_NAMES)
    assert effects_from_list(items) == model.effects
    assert effects_from_list([{'effect': 'none', 'parameters': {}}]) == ()


def test_linear_flags_of_the_registry() -> None:
    nonlinear = {n for n, e in EFFECTS.items() if not e.linear}
    assert nonlinear == {'coulomb_friction', 'current_saturation', 'cogging_torque',
                         'encoder_cyclic_error', 'proposed_terms'}
    for name, params in PARAMS.items():
        assert PAPER_MODEL.with_effect(name, params).physics().linear == (
            name not in nonlinear)


def test_repeatable_effects_add_up_others_replace() -> None:
    res = PARAMS['unmodeled_resonance']
    twice = PAPER_MODEL.with_effect('unmodeled_resonance', res).with_effect(
        'unmodeled_resonance', {**res, 'natural_frequency': 4e4})
    assert twice.physics().n_modes == 5
    friction = PAPER_MODEL.with_effect('coulomb_friction', {'friction_current': 0.01})
    again = friction.with_effect('coulomb_friction', {'friction_current': 0.02})
    assert len(again.effects) == 1
    assert again.physics().friction_current == 0.02


@pytest.mark.parametrize(('name', 'params'), [
    ('magic', {'x': 1.0}),
    ('coulomb_friction', {'friction': 0.1}),
    ('coulomb_friction', {'friction_current': -0.1}),
    ('coulomb_friction', {'friction_current': '0.1x'}),
    ('coulomb_friction', {'friction_current': [1]}),
    ('gain_change', {'gain_ratio': 0.0}),
    ('gain_change', {'gain_ratio': math.inf}),
    ('current_saturation', {'current_limit': -1.0}),
    ('input_delay', {'delay': 0.5 * TAU}),
    ('input_delay', {'delay': 1e8}),
    ('unmodeled_resonance', {'natural_frequency': 1e4, 'damping_ratio': 0.0, 'residue': 1.0}),
    ('unmodeled_resonance', {'natural_frequency': 1e4, 'damping_ratio': 0.1, 'residue': 1e200}),
    ('viscous_friction', {'current_per_velocity': -1e-5}),
    ('cogging_torque', {'amplitude': 0.01, 'period': 0.0, 'phase': 0.0}),
    ('cogging_torque', {'amplitude': -0.01, 'period': 1.0, 'phase': 0.0}),
    ('cogging_torque', {'amplitude': 0.01, 'period': 1.0, 'phase': 4.0}),
    ('cogging_torque', {'amplitude': 0.01, 'period': 1.0}),
    ('encoder_cyclic_error', {'amplitude': 0.1, 'period': 1.0, 'phase': 0.0}),  # not monotone
    ('amplifier_bandwidth', {'bandwidth': 0.0}),
    ('amplifier_bandwidth', {'bandwidth': 1e3}),    # its lag exceeds the input_delay below
])
def test_bad_effects_raise(name: str, params: dict[str, object]) -> None:
    base = (PAPER_MODEL.with_effect('input_delay', {'delay': 3 * TAU})
            if name == 'amplifier_bandwidth' else PAPER_MODEL)
    with pytest.raises(ConfigurationError):
        base.with_effect(name, params)


def test_amplifier_bandwidth_acts_before_the_input_delay_in_any_order() -> None:
    a = PAPER_MODEL.with_effect('amplifier_bandwidth', {'bandwidth': 10e3}).with_effect(
        'input_delay', {'delay': 3 * TAU})
    b = PAPER_MODEL.with_effect('input_delay', {'delay': 3 * TAU}).with_effect(
        'amplifier_bandwidth', {'bandwidth': 10e3})
    assert a.physics() == b.physics()
    assert a.physics().pure_delay + a.physics().lag_time_constant == pytest.approx(3 * TAU)
    none = PAPER_MODEL.with_effect('amplifier_bandwidth', {'bandwidth': math.inf})
    assert none.physics().lag_time_constant == 0.0


def test_encoder_reading_and_its_inverse() -> None:
    ph = PAPER_MODEL.with_effect('encoder_cyclic_error', PARAMS['encoder_cyclic_error']).physics()
    y = np.linspace(-3.0, 3.0, 1001)
    reading = ph.reading(y)
    assert np.max(np.abs(reading - y)) == pytest.approx(1e-3, rel=1e-3)
    np.testing.assert_allclose(ph.true_angle(reading), y, atol=1e-13)
    np.testing.assert_array_equal(PAPER_MODEL.physics().reading(y), y)


def test_cogging_is_the_mean_torque_over_the_sample() -> None:
    """Held over a sample from (p, v): the exact mean of a sin(2 pi p / P + phase) along
    p + v t, so fast moves over short periods are not aliased."""
    ph = PAPER_MODEL.with_effect('cogging_torque', PARAMS['cogging_torque']).physics()
    t = (np.arange(4000) + 0.5) / 4000 * TAU
    for p0, v in ((0.1, 0.0), (0.2, 3000.0), (-1.0, -20000.0)):
        path = 0.01 * np.sin(2 * math.pi * (p0 + v * t) / 0.7 + 0.3)
        assert float(ph.cogging(p0, v)) == pytest.approx(path.mean(), abs=1e-9)


def test_bad_effect_lists_raise() -> None:
    for items in ([{'parameters': {}}], [{'effect': 'coulomb_friction', 'parameters': 5}],
                  '[]', {'effect': 'gain_change'}, [{'effect': 'gain_change',
                                                      'parameters': {'gain_ratio': 1.0},
                                                      'extra': 1}]):
        with pytest.raises(ConfigurationError):
            effects_from_list(items)
    with pytest.raises(ConfigurationError, match='at most'):
        effects_from_list([{'effect': 'gain_change', 'parameters': {'gain_ratio': 1.0}}] * 100)


def test_unlimited_current_is_inf() -> None:
    e = Effect.create('current_saturation', {'current_limit': math.inf})
    assert math.isinf(PAPER_MODEL.with_effects([e]).physics().current_limit)


def test_parse_effect_from_the_command_line() -> None:
    assert parse_effect('coulomb_friction:friction_current=0.05') == Effect.create(
        'coulomb_friction', {'friction_current': 0.05})
    e = parse_effect('unmodeled_resonance:natural_frequency=3e4, damping_ratio=0.01,'
                     'residue=1e5')
    assert e.params() == {'natural_frequency': 3e4, 'damping_ratio': 0.01, 'residue': 1e5}
    for bad in ('coulomb_friction:friction_current', ':x=1', 'coulomb_friction:x=abc',
                'input_delay:delay=1'):
        with pytest.raises(ConfigurationError):
            parse_effect(bad)
    # a key given twice was taken at its last value without a word
    with pytest.raises(ConfigurationError, match='friction_current given twice'):
        parse_effect('coulomb_friction:friction_current=0.01,friction_current=0.02')
