"""Plant model YAML: round trips, the simulator's view of the same model, clear errors."""

from __future__ import annotations

import math

import pytest

from galvo_sysid.errors import ConfigurationError, InvalidDataError
from galvo_sysid.model.io import (
    EFFECT_NAMES,
    NOMINAL_MODEL,
    Effect,
    PlantModel,
    from_plant_spec,
    load_model,
    load_plant_spec,
    model_from_dict,
    model_from_yaml,
    model_to_dict,
    save_model,
    to_plant_spec,
)
from galvo_sysid.model.modal import REFERENCE_MODEL, TAU, InputDynamics

RESONANCE = {'natural_frequency': 3e4, 'damping_ratio': 0.02, 'residue': 1e5}


def augmented() -> PlantModel:
    return (NOMINAL_MODEL
            .with_effect('input_delay', {'delay': 2.1e-5})
            .with_effect('unmodeled_resonance', RESONANCE)
            .with_effect('unmodeled_resonance', {'natural_frequency': 9e4,
                                                 'damping_ratio': 0.01, 'residue': -2e5})
            .with_effect('coulomb_friction', {'friction_current': 0.02})
            .with_effect('pivot_stiffness', {'natural_frequency': 300.0})
            .with_effect('gain_change', {'gain_ratio': 0.95})
            .with_effect('current_saturation', {'current_limit': 0.8}))


def test_nominal_model_is_table_one_with_the_paper_input_dynamics():
    assert NOMINAL_MODEL.modal == REFERENCE_MODEL
    assert NOMINAL_MODEL.dynamics == InputDynamics(computation_delay=1,
                                                   lag_time_constant=0.6 * TAU)
    assert NOMINAL_MODEL.equivalent_delay == pytest.approx(1.6 * TAU)
    assert NOMINAL_MODEL.effects == ()


def test_yaml_round_trip_keeps_every_number(tmp_path):
    model = augmented()
    path = save_model(model, tmp_path / 'm.yaml')
    back = load_model(path)
    assert back == model
    assert [e.name for e in back.effects] == [e.name for e in model.effects]
    text = path.read_text()
    assert text.startswith('# galvo_sysid plant model')
    assert 'coulomb_friction' in text


def test_with_effect_replaces_all_but_resonances():
    m = NOMINAL_MODEL.with_effect('gain_change', {'gain_ratio': 0.9})
    m = m.with_effect('gain_change', {'gain_ratio': 1.1})
    assert [e.params() for e in m.effects] == [{'gain_ratio': 1.1}]
    m = m.with_effect('unmodeled_resonance', RESONANCE).with_effect('unmodeled_resonance',
                                                                    RESONANCE)
    assert [e.name for e in m.effects].count('unmodeled_resonance') == 2
    assert m.equivalent_delay == pytest.approx(1.6 * TAU)
    assert m.with_effect('input_delay', {'delay': 3e-5}).equivalent_delay == 3e-5


def test_simulator_plant_of_a_model_and_back():
    spec = to_plant_spec(augmented())
    eff = spec.effects
    assert spec.model == REFERENCE_MODEL
    assert eff.dead_time == pytest.approx(2.1e-5 - 1.6 * TAU)
    assert [r.natural_frequency for r in eff.resonances] == [3e4, 9e4]
    assert eff.friction_current == 0.02
    assert eff.pivot_frequency == 300.0
    assert eff.gain_ratio == 0.95
    assert eff.current_limit == 0.8
    back = from_plant_spec(spec)
    found = sorted((e.name, sorted(e.params().items())) for e in back.effects)
    expected = sorted((e.name, sorted(e.params().items())) for e in augmented().effects)
    assert [n for n, _ in found] == [n for n, _ in expected]
    for (_, a), (_, b) in zip(found, expected, strict=True):
        assert [k for k, _ in a] == [k for k, _ in b]
        assert [v for _, v in a] == pytest.approx([v for _, v in b], rel=1e-12)
    assert to_plant_spec(NOMINAL_MODEL).effects.is_linear


def test_load_plant_spec_feeds_the_simulator(tmp_path):
    from galvo_sysid.sim.simulator import GalvoSimulator, SimulatorConfig

    path = save_model(NOMINAL_MODEL.with_effect('gain_change', {'gain_ratio': 0.9}),
                      tmp_path / 'g.yaml')
    sim = GalvoSimulator(config=SimulatorConfig(plant=load_plant_spec(path)))
    assert sim.plant.effects.gain_ratio == 0.9
    move = sim.run_move(0.3)
    assert move.encoder.shape == (512,)


def test_defaults_of_a_short_file():
    model = model_from_yaml('mechanics: {k0: 3.0e6, modes: []}\n')
    assert model.modal.k0 == 3e6
    assert model.modal.n_modes == 0
    assert model.dynamics == InputDynamics()
    assert model.sample_period == TAU


@pytest.mark.parametrize(('mutate', 'message'), [
    (lambda d: d.update(format='other'), 'format'),
    (lambda d: d.update(version=7), 'version'),
    (lambda d: d.update(colour='red'), 'unknown key'),
    (lambda d: d.pop('mechanics'), 'mechanics'),
    (lambda d: d['mechanics'].pop('k0'), 'k0'),
    (lambda d: d['mechanics']['modes'][0].update(damping_ratio=-1.0), 'damping'),
    (lambda d: d['mechanics'].update(k0='big'), 'number'),
    (lambda d: d['input_dynamics'].update(computation_delay=1.5), 'whole number'),
    (lambda d: d['effects'].append({'effect': 'magic', 'parameters': {}}), 'unknown effect'),
    (lambda d: d['effects'].append({'effect': 'gain_change', 'parameters': {'gain': 1}}),
     'gain_ratio'),
    (lambda d: d['effects'].append({'effect': 'coulomb_friction',
                                    'parameters': {'friction_current': -0.1}}), '>= 0'),
    (lambda d: d['effects'].append({'effect': 'input_delay', 'parameters': {'delay': 1e-6}}),
     'below'),
    (lambda d: d['effects'].extend([{'effect': 'gain_change', 'parameters': {'gain_ratio': 1}},
                                    {'effect': 'gain_change', 'parameters': {'gain_ratio': 2}}]),
     'twice'),
    (lambda d: d['effects'].append('gain_change'), r'effects\[1\]'),
])
def test_bad_models_are_refused_with_a_clear_message(mutate, message):
    data = model_to_dict(NOMINAL_MODEL)
    mutate(data)
    with pytest.raises(ConfigurationError, match=message):
        model_from_dict(data, source='m.yaml')


def test_file_errors(tmp_path):
    with pytest.raises(InvalidDataError, match='cannot read'):
        load_model(tmp_path / 'missing.yaml')
    bad = tmp_path / 'bad.yaml'
    bad.write_text('mechanics: [unclosed\n')
    with pytest.raises(ConfigurationError, match='not valid YAML'):
        load_model(bad)
    top = tmp_path / 'list.yaml'
    top.write_text('- 1\n- 2\n')
    with pytest.raises(ConfigurationError, match='mapping'):
        load_model(top)


def test_effect_contract():
    assert EFFECT_NAMES == ('input_delay', 'unmodeled_resonance', 'coulomb_friction',
                            'pivot_stiffness', 'gain_change', 'current_saturation')
    e = Effect.create('unmodeled_resonance', {'residue': -1.0, 'natural_frequency': 2.0,
                                              'damping_ratio': 0.1})
    assert [k for k, _ in e.parameters] == ['natural_frequency', 'damping_ratio', 'residue']
    assert e.to_dict() == {'effect': 'unmodeled_resonance',
                           'parameters': {'natural_frequency': 2.0, 'damping_ratio': 0.1,
                                          'residue': -1.0}}
    with pytest.raises(ConfigurationError, match='finite'):
        Effect.create('gain_change', {'gain_ratio': math.nan})
    with pytest.raises(ConfigurationError, match='positive'):
        Effect.create('current_saturation', {'current_limit': 0.0})
