"""Tests of the effect registry: names, parameters, checks and how each effect acts."""

from __future__ import annotations

import math

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
}


def test_every_effect_acts_as_registered() -> None:
    assert set(PARAMS) == set(EFFECT_NAMES) == set(EFFECTS)
    model = PAPER_MODEL
    for name, p in PARAMS.items():
        model = model.with_effect(name, p)
    ph = model.physics()
    assert ph.pure_delay + ph.lag_time_constant == pytest.approx(2.1 * TAU)
    assert ph.dead_time == pytest.approx(0.5 * TAU)
    assert ph.friction_current == 0.01
    assert ph.pivot_frequency == 300.0
    assert ph.gain_ratio == 0.9
    assert ph.current_limit == 0.7
    assert ph.natural_frequencies[-1] == 3e4
    assert ph.residues[-1] == 1e5
    assert not ph.linear
    items = [e.to_dict() for e in model.effects]
    assert {i['effect'] for i in items} == set(EFFECT_NAMES)
    assert effects_from_list(items) == model.effects
    assert effects_from_list([{'effect': 'none', 'parameters': {}}]) == ()


def test_linear_flags_of_the_registry() -> None:
    nonlinear = {n for n, e in EFFECTS.items() if not e.linear}
    assert nonlinear == {'coulomb_friction', 'current_saturation'}
    for name in nonlinear:
        assert not PAPER_MODEL.with_effect(name, PARAMS[name]).physics().linear


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
])
def test_bad_effects_raise(name: str, params: dict[str, object]) -> None:
    with pytest.raises(ConfigurationError):
        PAPER_MODEL.with_effect(name, params)


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
