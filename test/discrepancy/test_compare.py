"""The comparison: the ringing of the previous moves is carried over into each record."""

from __future__ import annotations

import numpy as np
from discrepancy_cases import measured

from galvo_sysid.discrepancy import Comparison
from galvo_sysid.model import PAPER_MODEL


def test_carried_over_ringing_explains_back_to_back_moves():
    """Later moves do not start at rest: the previous moves' ringing is carried over."""
    moves = measured((), seed=0, moves_per_angle=6, noise=False)
    comp = Comparison(moves, history=2)
    rest = Comparison(moves, history=0)
    assert comp.with_history[1:].all()
    assert not comp.with_history[0]
    err = np.abs(moves.encoder - comp.simulate(PAPER_MODEL, per_move=True))
    err_rest = np.abs(moves.encoder - rest.simulate(PAPER_MODEL, per_move=True))
    d2 = np.abs(np.diff(moves.encoder - comp.simulate(PAPER_MODEL, per_move=True), 2))
    d2_rest = np.abs(np.diff(moves.encoder - rest.simulate(PAPER_MODEL, per_move=True), 2))
    assert err[0].max() < 1e-10
    assert err_rest[0].max() < 1e-10
    assert d2_rest[1:].max() > 1e-6                   # ringing not in a from-rest model
    assert d2[1:].max() < 0.05 * d2_rest[1:].max()    # two moves of history remove most
