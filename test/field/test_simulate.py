"""Bags from the simulator: same messages as the driver node, plant changes and effects."""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np
import pytest

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.field.bags import BagReader
from galvo_sysid.field.offline import identify_bag
from galvo_sysid.field.simulate import parse_drift, parse_step, simulate_bag
from galvo_sysid.model import Drift, StepChange
from galvo_sysid.monitor.moves import MoveHalf
from galvo_sysid.sim.simulator import GalvoSimulator


def test_parse_drift() -> None:
    assert parse_drift('omega_1=-2e-5/move') == Drift('omega_1', -2e-5, unit='move')
    assert parse_drift('k0 = -0.001/s @ 2') == Drift('k0', -0.001, unit='second', start=2.0)
    assert parse_drift('zeta_2=1e-3/second@0.5s') == Drift('zeta_2', 1e-3, start=0.5)
    for bad in ('omega_1=-2e-5', 'omega_1=fast/s', 'k0=1/s@3move', 'bogus=1/s'):
        with pytest.raises(ConfigurationError):
            parse_drift(bad)


def test_parse_step() -> None:
    assert parse_step('k0=0.9@400') == StepChange('k0', 0.9, at=400, unit='move',
                                                  relative=True)
    assert parse_step('omega_2=1.01@1.5s') == StepChange('omega_2', 1.01, at=1.5,
                                                         unit='second', relative=True)
    with pytest.raises(ConfigurationError):
        parse_step('k0=0.9')


def test_bag_holds_the_simulator_moves(tmp_path: Path) -> None:
    summary = simulate_bag(tmp_path / 'b', angles=[0.6], moves_per_angle=10, seed=4)
    assert summary.moves == 10
    assert summary.scanner_time == pytest.approx(10 * 606e-5)
    moves = list(GalvoSimulator(seed=4).moves(angles=[0.6], moves_per_angle=10))
    with BagReader(summary.path) as reader:
        raws = list(reader.raw_messages())
        halves = [h for h in reader.move_halves() if isinstance(h, MoveHalf)]
    assert [r.timestamp for r in raws[::2]] == [round(m.stamp * 1e9) for m in moves]
    assert len(halves) == 20
    for h in halves:
        m = moves[h.move_id]
        assert h.target_angle == m.target_angle
        assert h.stamp == pytest.approx(m.stamp, abs=1e-9)
        assert h.sample_period == m.sample_period
        np.testing.assert_array_equal(h.data, m.current if h.signal == 'current' else m.encoder)


def test_effect_and_step_reach_the_plant(tmp_path: Path) -> None:
    gain = simulate_bag(tmp_path / 'gain', angles=[0.3], moves_per_angle=200, seed=1,
                        effects=['gain_change:gain_ratio=0.9'])
    assert gain.changes == ('effect gain_change:gain_ratio=0.9',)
    found = identify_bag(gain.path)
    assert found.pooled is not None
    assert found.pooled.k0 == pytest.approx(0.9 * 3.564e6, rel=0.01)
    assert {w.drift.level_name for w in found.windows} == {'ERROR'}
    step = simulate_bag(tmp_path / 'step', angles=[0.3], moves_per_angle=400, seed=1,
                        steps=['omega_2=0.98@200'])
    windows = identify_bag(step.path).windows
    j = windows[0].drift.names.index('omega_2')
    deviation = [w.drift.relative_deviation[j] for w in windows]
    assert deviation[0] == pytest.approx(0.0, abs=0.003)
    assert deviation[-1] == pytest.approx(-0.02, abs=0.003)


@pytest.mark.parametrize('effect', [
    'viscous_friction:current_per_velocity=1e-5',
    'cogging_torque:amplitude=0.01,period=0.7,phase=0.3',
    'encoder_cyclic_error:amplitude=1e-3,period=0.5,phase=-1',
    'amplifier_bandwidth:bandwidth=12000',
    'proposed_terms:current_x3=-0.05,reading_x_absx=1e-3',
])
def test_every_new_effect_can_be_simulated(tmp_path: Path, effect: str) -> None:
    """`galvo-sysid simulate --effect NAME:...` for the effects of issue 14 (the registry's)."""
    from galvo_sysid.cli.main import main

    bag = tmp_path / 'b'
    assert main(['simulate', '--out', str(bag), '--angles', '1psi', '--moves-per-angle', '4',
                 '--effect', effect]) == 0
    nominal = simulate_bag(tmp_path / 'n', angles=[0.3], moves_per_angle=4)
    with BagReader(bag) as reader:
        enc = [h.data for h in reader.move_halves()
               if isinstance(h, MoveHalf) and h.signal == 'encoder']
    with BagReader(nominal.path) as reader:
        ref = [h.data for h in reader.move_halves()
               if isinstance(h, MoveHalf) and h.signal == 'encoder']
    assert len(enc) == 4
    assert max(np.abs(a - b).max() for a, b in zip(enc, ref, strict=True)) > 1e-4


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_bag_says_jazzy_and_the_qos_the_driver_offers(tmp_path: Path, storage: str) -> None:
    from rosbags.interfaces import QosDurability, QosHistory, QosReliability
    from rosbags.rosbag2 import Reader

    from galvo_sysid.monitor.parameters import defaults

    bag = simulate_bag(tmp_path / 'b', angles=[0.6], moves_per_angle=2, seed=1,
                       storage=storage).path
    driver = defaults('galvo_driver')
    assert driver['qos_depth'] == 1000
    with Reader(bag) as reader:
        assert reader.ros_distro == 'jazzy'
        assert len(reader.connections) == 2
        for c in reader.connections:
            (qos,) = c.ext.offered_qos_profiles
            assert qos.history == QosHistory.KEEP_LAST
            assert qos.depth == driver['qos_depth']
            assert qos.reliability == QosReliability.RELIABLE
            assert qos.durability == QosDurability.VOLATILE
    (file,) = [p for p in bag.iterdir() if p.suffix in {'.mcap', '.db3'}]
    if storage == 'mcap':  # the storage's own copy of the metadata
        assert b'ros_distro: jazzy' in file.read_bytes()
    else:
        import sqlite3

        with contextlib.closing(sqlite3.connect(file)) as db:
            assert db.execute('SELECT ros_distro FROM schema').fetchall() == [('jazzy',)]
            (text,), = db.execute('SELECT metadata FROM metadata').fetchall()
        assert 'ros_distro: jazzy' in text
        assert 'depth: 1000' in text
