"""``galvo-sysid discrepancy`` on a bag, end to end, and its module entry point."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from discrepancy_cases import ANGLES, MOVES_PER_ANGLE

from galvo_sysid.discrepancy import read_moves


def test_cli_on_a_bag(tmp_path, capsys):
    from galvo_sysid.cli.main import main
    from galvo_sysid.field.simulate import simulate_bag

    bag = tmp_path / 'gain'
    simulate_bag(bag, angles=list(ANGLES), moves_per_angle=MOVES_PER_ANGLE, seed=5,
                 effects=['gain_change:gain_ratio=0.95'])
    moves, rejected = read_moves(bag)
    assert moves.moves == 3 * MOVES_PER_ANGLE
    assert rejected == []
    assert np.isfinite(moves.stamp).all()
    augmented = tmp_path / 'aug.yaml'
    assert main(['discrepancy', str(bag), '--json', '--save-model', str(augmented),
                 '--max-effects', '1']) == 0
    data = json.loads(capsys.readouterr().out)
    assert data['verdict'] == 'named'
    assert data['summary'].startswith('named: gain_change (gain_ratio=0.95')
    assert data['effect'] == 'gain_change'
    assert data['parameters']['gain_ratio'] == pytest.approx(0.95, rel=0.002)
    assert data['gap_after'] <= 0.5 * data['gap_before']
    # the augmented model explains the same bag: nothing left to find
    assert main(['discrepancy', str(bag), '--model', str(augmented), '--effects',
                 'gain_change', 'coulomb_friction']) == 0
    text = capsys.readouterr().out
    assert 'verdict: consistent: the model explains the moves within the noise' in text
    # the augmented model exists: not replaced without --force, never into the bag
    stored = augmented.read_bytes()
    assert main(['discrepancy', str(bag), '--save-model', str(augmented)]) == 1
    assert 'exists already; give --force' in capsys.readouterr().err
    assert augmented.read_bytes() == stored
    assert main(['discrepancy', str(bag), '--report', str(bag), '--force']) == 1
    assert 'into the bag it reads' in capsys.readouterr().err
    assert main(['discrepancy', str(tmp_path / 'missing')]) == 1
    assert 'error' in capsys.readouterr().err
    bad = tmp_path / 'bad.yaml'
    bad.write_text('mechanics: {}\n')
    assert main(['discrepancy', str(bag), '--model', str(bad)]) == 1
    assert "'k0' is missing" in capsys.readouterr().err


def test_module_entry_point_help():
    out = subprocess.run([sys.executable, '-m', 'galvo_sysid.cli.discrepancy', '--help'],
                         capture_output=True, text=True, check=True)
    assert 'unmodeled_resonance' in out.stdout
    assert '--report DIR' in out.stdout


def test_a_measured_currents_lag_reaches_the_moves(tmp_path, capsys):
    """``--measured-current LAG`` makes each move's current held before anything else: a lag
    that cannot be one is refused in one line, before any fit."""
    from galvo_sysid.cli.main import main
    from galvo_sysid.field.simulate import simulate_bag

    bag = tmp_path / 'plain'
    simulate_bag(bag, angles=[0.3], moves_per_angle=6, seed=5)
    assert main(['discrepancy', str(bag), '--measured-current=-1e-6']) == 1
    err = capsys.readouterr().err
    assert err.count('\n') == 1
    assert 'must be a time >= 0' in err
