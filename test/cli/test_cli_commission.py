"""Commission once, then monitor: galvo-sysid commission on a bag, the file it writes used by
identify and the simulator (a digital twin), as a user would run them."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from conftest import VENV_BIN

from galvo_sysid.field.simulate import simulate_bag
from galvo_sysid.model import load_model
from galvo_sysid.sim.config import SimulatorConfig
from galvo_sysid.sim.family import random_scanner

SEED = 7   # 27.1 us, 277 samples, 3 modes at 1.07, 1.74 and 3.15 kHz, 2 samples of delay


def run(venv_bin: Path, *args: str | Path,
        timeout: float = 180) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(venv_bin / 'galvo-sysid'), *map(str, args)], capture_output=True,
                          text=True, timeout=timeout, check=False)


@pytest.fixture(scope='module')
def commissioned(tmp_path_factory: pytest.TempPathFactory) -> tuple[
        Path, Path, subprocess.CompletedProcess[str]]:
    """A healthy scanner's bag (5 sizes x 200 moves), commissioned by the command line."""
    scanner = random_scanner(SEED)
    tmp = tmp_path_factory.mktemp('commission')
    simulate_bag(tmp / 'healthy', angles=list(scanner.angles), moves_per_angle=200, seed=1,
                 config=scanner.config)
    proc = run(VENV_BIN, 'commission', tmp / 'healthy', '--out', tmp / 'scanner.yaml',
               '--plot', tmp / 'bode.png', '--json')
    return tmp, tmp / 'scanner.yaml', proc


def test_commission_writes_the_scanners_model(commissioned) -> None:
    tmp, path, proc = commissioned
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    truth = random_scanner(SEED).model
    model = load_model(path)
    assert out['modes'] == model.n_modes == truth.n_modes == 3
    assert all(out['resolved'])
    assert model.modal.natural_frequencies == pytest.approx(truth.modal.natural_frequencies,
                                                            rel=2e-4)
    assert model.dynamics.computation_delay == truth.dynamics.computation_delay
    assert (model.sample_period, model.record_length) == (truth.sample_period,
                                                          truth.record_length)
    assert model.dwell_length == truth.dwell_length           # read from the stamps
    assert set(model.std_by_name()) >= set(model.modal.parameters())
    assert model.bands is not None
    assert 'commissioned by galvo-sysid from healthy' in model.description
    assert (tmp / 'bode.png').read_bytes()[:4] == b'\x89PNG'
    assert [s['modes'] for s in out['steps']][:4] == [0, 1, 2, 3]


def test_then_monitor_with_it(commissioned, venv_bin: Path) -> None:
    tmp, path, _ = commissioned
    scanner = random_scanner(SEED)
    later = tmp / 'later'
    simulate_bag(later, angles=[scanner.reference_angle], moves_per_angle=400, seed=2,
                 config=scanner.config)
    proc = run(venv_bin, 'identify', later, '--model', path, '--json')
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out['model_mismatch'] is None
    assert len(out['windows']) == 4
    for w in out['windows']:
        assert w['drift']['level'] == 'OK', w['drift']['message']
    # a changed scanner: its first mode 2 % lower is flagged, as drift of omega_1
    changed = tmp / 'changed'
    truth = scanner.model
    simulate_bag(changed, angles=[scanner.reference_angle], moves_per_angle=400, seed=3,
                 config=SimulatorConfig(plant=truth, design=truth), steps=['omega_1=0.98@0'])
    proc = run(venv_bin, 'identify', changed, '--model', path, '--json')
    assert proc.returncode == 0, proc.stderr
    levels = {w['drift']['level'] for w in json.loads(proc.stdout)['windows']}
    assert levels == {'ERROR'}
    # and the paper's model is not this scanner's: said so, not drift
    proc = run(venv_bin, 'identify', later)
    assert proc.returncode == 1
    assert 'do not match' in proc.stdout + proc.stderr


def test_commission_says_what_is_wrong_in_one_line(venv_bin: Path, tmp_path: Path) -> None:
    proc = run(venv_bin, 'commission', tmp_path / 'missing', '--out', tmp_path / 'm.yaml')
    assert proc.returncode == 1
    assert proc.stderr.count('\n') == 1
    assert 'Traceback' not in proc.stderr
    simulate_bag(tmp_path / 'few', angles=[0.3], moves_per_angle=20, seed=1)
    proc = run(venv_bin, 'commission', tmp_path / 'few', '--out', tmp_path / 'm.yaml')
    assert proc.returncode == 1
    assert 'no window of 100 moves' in proc.stderr
    assert not (tmp_path / 'm.yaml').exists()


def test_commission_never_writes_over_its_bag_nor_silently_over_a_model(
        venv_bin: Path, tmp_path: Path) -> None:
    """The model file is checked before the work: never into the bag read (its storage file
    or metadata.yaml, which a user mistyping --out once destroyed), an existing file only
    with --force (the reference model a watchdog uses is not replaced by accident)."""
    simulate_bag(tmp_path / 'few', angles=[0.3], moves_per_angle=20, seed=1)
    storage = next((tmp_path / 'few').glob('*.mcap'))
    before = {p.name: p.read_bytes() for p in (tmp_path / 'few').iterdir()}
    for out in (storage, tmp_path / 'few' / 'metadata.yaml', tmp_path / 'few' / 'm.yaml'):
        proc = run(venv_bin, 'commission', tmp_path / 'few', '--out', out, '--force')
        assert proc.returncode == 1, proc.stderr
        assert proc.stderr.count('\n') == 1
        assert 'would be written into the bag it reads' in proc.stderr
    assert {p.name: p.read_bytes() for p in (tmp_path / 'few').iterdir()} == before
    (tmp_path / 'm.yaml').write_text('kept')
    proc = run(venv_bin, 'commission', tmp_path / 'few', '--out', tmp_path / 'm.yaml')
    assert proc.returncode == 1
    assert 'exists already; give --force to replace it' in proc.stderr
    assert (tmp_path / 'm.yaml').read_text() == 'kept'
    (tmp_path / 'plot.png').mkdir()
    proc = run(venv_bin, 'commission', tmp_path / 'few', '--out', tmp_path / 'n.yaml',
               '--plot', tmp_path / 'plot.png')
    assert proc.returncode == 1
    assert 'the plot file is a directory' in proc.stderr
    assert not (tmp_path / 'n.yaml').exists()


def test_a_measured_current_is_commissioned_and_identified_with_the_lag_found(
        venv_bin: Path, tmp_path: Path) -> None:
    """A bag whose current is the coil current measured with the encoder (scanner 1 of the
    independent simulator: amplifier lag 0.78 T): plain commissioning warns, says the current
    leads the encoder and names the option; ``--measured-current`` finds the lag, writes it
    into the model's description, and ``identify --measured-current LAG`` places the mode
    within its std."""
    from independent_scanner import random_scanner as independent_scanner
    from independent_scanner import simulate

    s = independent_scanner(1)
    t = s.sample_period
    data = simulate(s, angles=[1.0], moves_per_angle=200, seed=2, current='measured')
    np.savez(tmp_path / 'moves.npz', **data)
    assert run(venv_bin, 'import', tmp_path / 'moves.npz', '--out',
               tmp_path / 'bag').returncode == 0
    plain = run(venv_bin, 'commission', tmp_path / 'bag', '--out', tmp_path / 'plain.yaml')
    assert plain.returncode == 0, plain.stderr
    assert 'WARNING' in plain.stdout
    # the fit as recorded ends at no delay and no lag: the rigid body's lead test names it
    assert 'the current record leads the encoder by one sample' in plain.stdout
    assert 'commission again with --measured-current' in plain.stdout
    proc = run(venv_bin, 'commission', tmp_path / 'bag', '--out', tmp_path / 'held.yaml',
               '--measured-current', '--json')
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    lag = out['measured_current_lag']
    assert lag == pytest.approx(s.lag, abs=0.04 * t)
    assert out['lag_search'][-1]['fitted'] == pytest.approx(lag, abs=0.002 * t)
    assert out['warnings'] == []
    model = load_model(tmp_path / 'held.yaml')
    assert (model.n_modes, model.dynamics.computation_delay) == (1, 0)
    assert model.record_length == data['current'].shape[1] - 1
    assert f'--measured-current {lag:.6g}' in model.description
    ident = run(venv_bin, 'identify', tmp_path / 'bag', '--model', tmp_path / 'held.yaml',
                '--measured-current', repr(lag), '--json')
    assert ident.returncode == 0, ident.stderr
    report = json.loads(ident.stdout)
    assert report['measured_current_lag'] == lag
    windows = report['windows']
    assert len(windows) == 2
    for w in windows:
        assert w['drift']['level'] == 'OK', w['drift']['message']
        z = (w['natural_frequencies'][0] - s.omegas[0]) / w['natural_frequencies_std'][0]
        assert abs(z) < 4.5
    bad = run(venv_bin, 'identify', tmp_path / 'bag', '--model', tmp_path / 'held.yaml',
              '--measured-current=-1e-6')
    assert bad.returncode == 1
    assert bad.stderr.count('\n') == 1
    assert 'must be a time >= 0' in bad.stderr
