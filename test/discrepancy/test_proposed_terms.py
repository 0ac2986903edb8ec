"""The fallback's proposal as the registry's ``proposed_terms`` effect (issue 14, item 4).

The simulator and the workflow's plant simulate it alike; it is loaded and saved like any
effect; the workflow never tries it as a candidate. The round trip through the workflow
(proposal -> model file -> the gap within the noise) is in test_fallback.py.
"""

from __future__ import annotations

import numpy as np
import pytest
from discrepancy_cases import hidden_effects, measured

from galvo_sysid.discrepancy import PlantSimulator, find_discrepancy
from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model import PAPER_MODEL, TAU
from galvo_sysid.model.effects import CANDIDATE_NAMES, EFFECT_NAMES, Effect
from galvo_sysid.model.files import model_from_yaml, model_to_yaml

# every term at once: each acts at these sizes (the move of 10 psi reaches about 2.9 deg)
TERMS = {'current_x3': -0.05, 'current_v_absv': -1e-9, 'current_a': 1e-9,
         'current_i_absi': 0.02, 'current_sin_amplitude': 0.01, 'current_sin_period': 0.7,
         'current_i_sin_amplitude': 0.02, 'current_i_sin_period': 0.5,
         'reading_x_absx': 1e-3, 'reading_sin_amplitude': 3e-4, 'reading_sin_period': 0.45}


def test_the_plant_reproduces_the_simulator_from_rest():
    """Noise-free, the first move from rest at 0 deg: the workflow's plant with the terms
    matches the simulator's encoder to rounding, while the terms move it by 0.1 deg."""
    moves = measured(hidden_effects(('proposed_terms', TERMS)), seed=0, moves_per_angle=2,
                     noise=False)
    model = PAPER_MODEL.with_effect('proposed_terms', TERMS)
    y = PlantSimulator(model.physics(), sample_period=TAU,
                       length=moves.samples).simulate(moves.current[0], moves.encoder[0, 0])
    assert np.max(np.abs(y - moves.encoder[0])) < 1e-13
    nominal = PlantSimulator(PAPER_MODEL.physics(), sample_period=TAU,
                             length=moves.samples).simulate(moves.current[0], 0.0)
    assert np.max(np.abs(nominal - moves.encoder[0])) > 0.05


def test_the_model_file_round_trip():
    """Saved and loaded equal; only the terms given are written (the others default to 0)."""
    model = PAPER_MODEL.with_effect('proposed_terms', TERMS)
    text = model_to_yaml(model)
    assert model_from_yaml(text) == model
    written = model.effect('proposed_terms')
    assert written is not None
    assert written.to_dict()['parameters'] == TERMS
    phys = model.physics()
    assert not phys.linear
    assert phys.current_terms
    assert phys.reading_error
    assert model_from_yaml(model_to_yaml(PAPER_MODEL.with_effect(
        'proposed_terms', {'reading_x2': 1e-4}))).physics().reading(2.0) == pytest.approx(
        2.0 + 4e-4)
    with pytest.raises(ConfigurationError, match='takes parameters'):
        Effect.create('proposed_terms', {'current_x5': 1.0})


def test_never_a_candidate():
    """The registry holds it, the workflow's candidates do not (and refuse it)."""
    assert 'proposed_terms' in EFFECT_NAMES
    assert 'proposed_terms' not in CANDIDATE_NAMES
    assert set(CANDIDATE_NAMES) == set(EFFECT_NAMES) - {'proposed_terms'}
    assert len(CANDIDATE_NAMES) == 10
    moves = measured(hidden_effects(), seed=0, moves_per_angle=2, noise=False)
    with pytest.raises(ConfigurationError, match='proposed_terms'):
        find_discrepancy(moves, effects=['proposed_terms'])


def test_the_commands_load_a_proposal_model(tmp_path, capsys):
    """`simulate --model` and `discrepancy --model` take a model file with the terms (as
    ``proposal.yaml`` is): moves simulated with it are consistent with it (10 moves per angle
    suffice: the same moves simulated without the terms are 'unexplained' against it, checked
    by hand 2026-11-28)."""
    import json

    from galvo_sysid.cli.main import main
    from galvo_sysid.model.files import save_model

    path = save_model(PAPER_MODEL.with_effect('proposed_terms', {'current_x3': -3e-3}),
                      tmp_path / 'proposal.yaml')
    bag = tmp_path / 'bag'
    assert main(['simulate', '--out', str(bag), '--model', str(path), '--angles', '0.1psi',
                 '1psi', '10psi', '--moves-per-angle', '10', '--seed', '1']) == 0
    capsys.readouterr()
    assert main(['discrepancy', str(bag), '--model', str(path), '--json']) == 0
    out = json.loads(capsys.readouterr().out)
    assert out['verdict'] == 'consistent'
