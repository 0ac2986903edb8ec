"""The plant-model file: round trips, the packaged paper model, strict reading, clear errors."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from galvo_sysid.errors import ConfigurationError, InvalidDataError
from galvo_sysid.model import (
    EFFECT_NAMES,
    PAPER_MODEL,
    REFERENCE_MODEL,
    TAU,
    Effect,
    InputDynamics,
    PlantModel,
    load_model,
    model_from_yaml,
    model_to_yaml,
    save_model,
)
from galvo_sysid.model.effects import CANDIDATE_NAMES
from galvo_sysid.model.files import model_from_dict, model_to_dict, packaged_model_path

RESONANCE = {'natural_frequency': 3e4, 'damping_ratio': 0.02, 'residue': 1e5}


def augmented() -> PlantModel:
    return (PAPER_MODEL
            .with_effect('input_delay', {'delay': 2.1e-5})
            .with_effect('unmodeled_resonance', RESONANCE)
            .with_effect('unmodeled_resonance', {'natural_frequency': 9e4,
                                                 'damping_ratio': 0.01, 'residue': -2e5})
            .with_effect('coulomb_friction', {'friction_current': 0.02})
            .with_effect('pivot_stiffness', {'natural_frequency': 300.0})
            .with_effect('gain_change', {'gain_ratio': 0.95})
            .with_effect('current_saturation', {'current_limit': 0.8}))


def test_packaged_model_is_table_one_with_the_paper_input_dynamics():
    assert packaged_model_path().is_file()
    assert load_model(None) == load_model('') == PAPER_MODEL
    assert PAPER_MODEL.modal.k0 == 3.564e6
    assert PAPER_MODEL.modal.natural_frequencies == (7.108e4, 1.193e5, 1.674e5)
    assert PAPER_MODEL.modal.residues == (2.069e6, -5.485e6, -4.604e5)
    assert PAPER_MODEL.modal.damping_ratios == (6.218e-3, 7.723e-3, 4.579e-3)
    assert PAPER_MODEL.dynamics == InputDynamics(computation_delay=1,
                                                 lag_time_constant=0.6 * TAU)
    assert PAPER_MODEL.equivalent_delay == pytest.approx(1.6 * TAU)
    assert PAPER_MODEL.effects == ()
    assert (PAPER_MODEL.record_length, PAPER_MODEL.dwell_length) == (512, 94)


def test_yaml_round_trip_keeps_every_number(tmp_path):
    model = replace(augmented(), bands=((5e4, 9e4), (9e4, 1.4e5), (1.4e5, 2e5)),
                    uncertainty=(('k0', 12.0), ('omega_2', 3.5), ('zeta_1', 1e-5),
                                 ('lag_time_constant', 1e-8)),
                    record_length=1024, dwell_length=10, description='a test')
    path = save_model(model, tmp_path / 'm.yaml')
    back = load_model(path)
    assert back == model
    assert [e.name for e in back.effects] == [e.name for e in model.effects]
    text = path.read_text()
    assert text.startswith('# galvo_sysid plant model')
    assert 'coulomb_friction' in text
    assert not list(tmp_path.glob('.*.tmp'))  # written atomically


def test_with_effect_replaces_all_but_resonances():
    m = PAPER_MODEL.with_effect('gain_change', {'gain_ratio': 0.9})
    m = m.with_effect('gain_change', {'gain_ratio': 1.1})
    assert [e.params() for e in m.effects] == [{'gain_ratio': 1.1}]
    m = m.with_effect('unmodeled_resonance', RESONANCE).with_effect('unmodeled_resonance',
                                                                    RESONANCE)
    assert [e.name for e in m.effects].count('unmodeled_resonance') == 2
    assert m.equivalent_delay == pytest.approx(1.6 * TAU)
    assert m.with_effect('input_delay', {'delay': 3e-5}).equivalent_delay == 3e-5


def test_the_file_feeds_the_simulator(tmp_path):
    from galvo_sysid.sim.config import SimulatorConfig
    from galvo_sysid.sim.simulator import GalvoSimulator

    path = save_model(replace(PAPER_MODEL.with_effect('gain_change', {'gain_ratio': 0.9}),
                              record_length=300), tmp_path / 'g.yaml')
    sim = GalvoSimulator(config=SimulatorConfig(plant=load_model(path)))
    assert sim.plant.gain_ratio == 0.9
    move = sim.run_move(0.3)
    assert move.encoder.shape == (300,)


def test_version_one_files_are_read():
    model = model_from_yaml('mechanics: {k0: 3.0e6, modes: []}\n')
    assert model.modal.k0 == 3e6
    assert model.modal.n_modes == 0
    assert model.dynamics == InputDynamics()
    assert model.sample_period == TAU
    with pytest.raises(ConfigurationError, match='unknown key'):
        model_from_yaml('version: 1\nmechanics: {k0: 3.0e6, modes: []}\nscanner: {}\n')


@pytest.mark.parametrize(('mutate', 'message'), [
    (lambda d: d.update(format='other'), 'format'),
    (lambda d: d.update(version=7), 'version'),
    (lambda d: d.update(colour='red'), 'unknown key'),
    (lambda d: d.pop('mechanics'), 'mechanics'),
    (lambda d: d.pop('sample_period'), 'sample_period'),
    (lambda d: d['mechanics'].pop('k0'), 'k0'),
    (lambda d: d['mechanics']['modes'][0].update(damping_ratio=-1.0), 'damping'),
    (lambda d: d['mechanics']['modes'][0].update(residue=1e200), 'residue'),
    (lambda d: d['mechanics']['modes'][0].update(residue='123'), 'number'),
    (lambda d: d['mechanics'].update(k0='big'), 'number'),
    (lambda d: d['mechanics'].update(k0=True), 'number'),
    (lambda d: d['mechanics'].update(modes='123'), 'list'),
    (lambda d: d['mechanics']['modes'][0].update(band=[1.0]), 'band'),
    (lambda d: d['mechanics']['modes'][0].update(band=[1.0, 2.0]), 'band'),
    (lambda d: d['input_dynamics'].update(computation_delay=1.5), 'whole number'),
    (lambda d: d['input_dynamics'].update(computation_delay=100_000_000), 'within'),
    (lambda d: d['input_dynamics'].update(lag_time_constnt=1e-6), 'unknown key'),
    (lambda d: d['scanner'].update(record_length=10.7), 'whole number'),
    (lambda d: d.update(sample_period=-1.0), 'sample_period'),
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
    data = model_to_dict(PAPER_MODEL)
    mutate(data)
    with pytest.raises(ConfigurationError, match=message) as info:
        model_from_dict(data, source='m.yaml')
    assert str(info.value).startswith('m.yaml')
    assert '\n' not in str(info.value)


@pytest.mark.parametrize(('data', 'holds'), [('root:x:0:0:root', 'a str'),
                                               ([1, 2], 'a list'), (None, 'nothing')])
def test_a_file_that_is_no_model_says_so(data, holds):
    """Another text file given as the model (e.g. /etc/passwd parses as a YAML string)."""
    with pytest.raises(ConfigurationError, match=f'not a plant model file .*it holds {holds}'):
        model_from_dict(data, source='m.yaml')


def test_a_typo_or_a_text_in_a_model_file_is_refused(tmp_path):
    """Defect 14 (repro 10): a misspelt key inside ``input_dynamics`` (lag_typo.yaml) was
    ignored, the model loaded without the lag it asked for; a residue written as text was
    read as a number."""
    head = ('format: galvo_sysid/plant_model\nversion: 1\nmechanics: {k0: 3.564e6, modes: '
            '[{natural_frequency: 71080.0, damping_ratio: 0.006218, residue: %s}]}\n')
    typo = tmp_path / 'lag_typo.yaml'
    typo.write_text(head % '2069000.0' +
                    'input_dynamics: {computation_delay: 1, lag_time_constnt: 3.0e-5}\n')
    with pytest.raises(ConfigurationError, match=r"unknown key\(s\) \['lag_time_constnt'\]") \
            as info:
        load_model(typo)
    assert str(info.value).startswith(f'{typo}: input_dynamics: ')
    text = tmp_path / 'text.yaml'
    text.write_text(head % "'123'")
    with pytest.raises(ConfigurationError,
                       match=r"modes\[1\]: residue must be a number, got '123'"):
        load_model(text)
    good = tmp_path / 'good.yaml'  # the same file spelt right loads, with its lag
    good.write_text(head % '2069000.0' +
                    'input_dynamics: {computation_delay: 1, lag_time_constant: 3.0e-5}\n')
    assert load_model(good).dynamics.lag_time_constant == 3.0e-5


def test_file_errors(tmp_path):
    with pytest.raises(InvalidDataError, match='cannot read'):
        load_model(tmp_path / 'missing.yaml')
    with pytest.raises(InvalidDataError, match='not a regular file'):
        load_model(tmp_path)
    bad = tmp_path / 'bad.yaml'
    bad.write_text('mechanics: [unclosed\n')
    with pytest.raises(ConfigurationError, match='not valid YAML'):
        load_model(bad)
    top = tmp_path / 'list.yaml'
    top.write_text('- 1\n- 2\n')
    with pytest.raises(ConfigurationError, match='mapping'):
        load_model(top)
    binary = tmp_path / 'bin.yaml'
    binary.write_bytes(b'\xff\xfe\x00\x01')
    with pytest.raises(InvalidDataError, match='not a text file'):
        load_model(binary)


def test_alias_bombs_and_huge_files_are_refused(tmp_path):
    bomb = 'a: &a ["x","x","x","x","x","x","x","x","x"]\n' + ''.join(
        f'{c}: &{c} [*{p},*{p},*{p},*{p},*{p},*{p},*{p},*{p},*{p}]\n'
        for p, c in zip('abcdefg', 'bcdefgh', strict=True))
    path = tmp_path / 'bomb.yaml'
    path.write_text(bomb)
    with pytest.raises(ConfigurationError, match='aliases are not allowed'):
        load_model(path)
    huge = tmp_path / 'huge.yaml'
    huge.write_text('# ' + 'x' * 2_000_000 + '\n')
    with pytest.raises(ConfigurationError, match='larger than'):
        load_model(huge)


def test_numbers_are_read_like_ros_does():
    text = model_to_yaml(PAPER_MODEL).replace('k0: 3564000.0', 'k0: 3.564e6')
    assert 'k0: 3.564e6' in text
    assert model_from_yaml(text).modal.k0 == 3.564e6


def test_effect_contract():
    assert EFFECT_NAMES == ('input_delay', 'unmodeled_resonance', 'coulomb_friction',
                            'pivot_stiffness', 'gain_change', 'current_saturation',
                            'viscous_friction', 'cogging_torque', 'encoder_cyclic_error',
                            'amplifier_bandwidth', 'proposed_terms')
    assert EFFECT_NAMES[:-1] == CANDIDATE_NAMES
    e = Effect.create('unmodeled_resonance', {'residue': -1.0, 'natural_frequency': 2.0,
                                              'damping_ratio': 0.1})
    assert [k for k, _ in e.parameters] == ['natural_frequency', 'damping_ratio', 'residue']
    assert e.to_dict() == {'effect': 'unmodeled_resonance',
                           'parameters': {'natural_frequency': 2.0, 'damping_ratio': 0.1,
                                          'residue': -1.0}}
    with pytest.raises(ConfigurationError, match='finite'):
        Effect.create('gain_change', {'gain_ratio': math.nan})
    with pytest.raises(ConfigurationError, match='> 0'):
        Effect.create('current_saturation', {'current_limit': 0.0})


def test_models_that_cannot_be_are_refused():
    with pytest.raises(ConfigurationError, match='band of mode 1'):
        replace(PAPER_MODEL, bands=((1e5, 2e5), (1e5, 2e5), (1.5e5, 1.8e5)))
    with pytest.raises(ConfigurationError, match='3 modes'):
        replace(PAPER_MODEL, bands=((5e4, 9e4),))
    with pytest.raises(ConfigurationError, match='unknown parameter'):
        replace(PAPER_MODEL, uncertainty=(('omega_7', 1.0),))
    assert REFERENCE_MODEL is PAPER_MODEL.modal
