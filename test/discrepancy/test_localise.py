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
    assert pivot.where.size_trend in ('only large moves', 'grows faster than the angle')
    assert pivot.where.bands[0].excess > 3                   # lowest band: a spring is slow
    for r in (resonance, gain, pivot):
        assert r.where_after.main_bands == ()
