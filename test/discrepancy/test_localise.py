"""Where the gap is: frequency band, phase of the move, move size."""

from __future__ import annotations

import math

from discrepancy_cases import CASES, analysed, hidden_effects


def test_where_the_gap_is():
    resonance = analysed(hidden_effects(CASES[3][:2]), seed=103)
    bands = resonance.where.main_bands
    assert bands[0].low < 3e4 / (2 * math.pi) < bands[0].high
    assert bands[0].share > 0.5
    gain = analysed(hidden_effects(CASES[9][:2]), seed=109)
    assert gain.where.size_trend.startswith('grows')
    assert gain.where.main_phase in ('acceleration', 'deceleration')
    pivot = analysed(hidden_effects(CASES[7][:2]), seed=107)
    # a spring's torque goes with the angle (its steady part at the target included)
    assert pivot.where.size_trend in ('only large moves', 'grows faster than the angle',
                                      'grows with the angle')
    assert pivot.where.gaps[-1] > 5 * pivot.where.gaps[0]
    assert pivot.where.bands[0].excess > 3                   # lowest band: a spring is slow
    for r in (resonance, gain, pivot):
        assert r.where_after.main_bands == ()


def test_friction_acts_on_every_move_size():
    """Coulomb friction is a current offset whatever the move: the summary said 'only small
    moves' while the move figure showed the same residual at every size (issue 15)."""
    friction = analysed(hidden_effects(CASES[5][:2]), seed=105)
    assert friction.where.size_trend in ('about constant', 'shrinks with the angle',
                                         'grows with the angle')
    assert friction.where.gaps[-1] > 0.3   # the largest moves too
