"""The moves of a bag: target angles with too few moves for a noise floor are set aside."""

from __future__ import annotations

import numpy as np
import pytest

from galvo_sysid.discrepancy import read_moves
from galvo_sysid.errors import InvalidDataError


def test_angles_with_too_few_moves_are_set_aside(tmp_path):
    from galvo_sysid.field.bags import CURRENT_TOPIC, ENCODER_TOPIC, BagWriter
    from galvo_sysid.field.simulate import write_moves
    from galvo_sysid.interfaces.topics import MOVE_SAMPLES
    from galvo_sysid.sim.simulator import GalvoSimulator

    sim = GalvoSimulator(seed=1)
    moves = [*sim.moves(angles=[0.3], moves_per_angle=8), sim.run_move(1.0),
             sim.run_move(-1.0)]
    path = tmp_path / 'few'
    with BagWriter(path) as bag:
        bag.add_topic(CURRENT_TOPIC, MOVE_SAMPLES)
        bag.add_topic(ENCODER_TOPIC, MOVE_SAMPLES)
        write_moves(bag, moves)
    found, rejected = read_moves(path)
    assert found.moves == 8
    assert sorted(found.move_id.tolist()) == list(range(8))
    assert [r['move_id'] for r in rejected] == [8, 9]
    assert 'noise floor needs 3' in rejected[0]['reason']
    with pytest.raises(InvalidDataError, match='no target angle has 9'):
        read_moves(path, min_moves=9)
    # a measured current: each move's held current, a sample shorter (the encoder too)
    from galvo_sysid.ident.measured import held_current

    held, _ = read_moves(path, measured_lag=6e-6)
    assert held.current.shape == (8, found.samples - 1)
    np.testing.assert_array_equal(
        held.current, held_current(found.current, sample_period=1e-5, lag=6e-6))
    np.testing.assert_array_equal(held.encoder, found.encoder[:, :-1])


def test_a_minority_record_length_is_set_aside(tmp_path):
    # issue 12, defect 8: a short first move made the whole bag unreadable ("moves differ in
    # record length [40, 512]")
    from dataclasses import replace

    from galvo_sysid.field.bags import CURRENT_TOPIC, ENCODER_TOPIC, BagWriter
    from galvo_sysid.field.simulate import write_moves
    from galvo_sysid.interfaces.topics import MOVE_SAMPLES
    from galvo_sysid.sim.simulator import GalvoSimulator

    moves = list(GalvoSimulator(seed=2).moves(angles=[0.3], moves_per_angle=10))
    moves[0] = replace(moves[0], current=moves[0].current[:40], encoder=moves[0].encoder[:40])
    path = tmp_path / 'short_first'
    with BagWriter(path) as bag:
        bag.add_topic(CURRENT_TOPIC, MOVE_SAMPLES)
        bag.add_topic(ENCODER_TOPIC, MOVE_SAMPLES)
        write_moves(bag, moves)
    found, rejected = read_moves(path)
    assert found.moves == 9
    assert found.samples == len(moves[1].current)
    assert [r['move_id'] for r in rejected] == [0]
    assert rejected[0]['reason'].startswith('record of 40 samples at 1e-05 s, most moves have')


def test_moves_that_do_not_travel_their_target_angle_are_set_aside_with_the_reason(tmp_path):
    """An encoder in radians (or a flipped sign, swapped topics): each move is set aside in
    words; with none left the error names why (it was `SVD did not converge` on all-zero
    moves, and the encoder-error bound's words on an absurd angle)."""
    from dataclasses import replace

    from galvo_sysid.field.bags import CURRENT_TOPIC, ENCODER_TOPIC, BagWriter
    from galvo_sysid.field.simulate import write_moves
    from galvo_sysid.interfaces.topics import MOVE_SAMPLES
    from galvo_sysid.sim.simulator import GalvoSimulator

    moves = list(GalvoSimulator(seed=2).moves(angles=[0.3], moves_per_angle=6))
    moves = [replace(m, encoder=np.radians(m.encoder)) if i % 2 else m
             for i, m in enumerate(moves)]
    path = tmp_path / 'radians'
    with BagWriter(path) as bag:
        bag.add_topic(CURRENT_TOPIC, MOVE_SAMPLES)
        bag.add_topic(ENCODER_TOPIC, MOVE_SAMPLES)
        write_moves(bag, moves)
    found, rejected = read_moves(path)  # +0.3 deg: moves 0, 2, 4; -0.3 deg (radians): 1, 3, 5
    assert found.move_id.tolist() == [0, 2, 4]
    assert [r['move_id'] for r in rejected] == [1, 3, 5]
    assert 'deg for a target angle of -0.3 deg' in rejected[0]['reason']
    with pytest.raises(InvalidDataError, match='no target angle has 4 usable moves '
                                               r'\(set aside, e\.g\.: the move travels'):
        read_moves(path, min_moves=4)
