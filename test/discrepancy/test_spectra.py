"""Where an effect acts, and whether it leaves noise there (issue 14)."""

from __future__ import annotations

import numpy as np
import pytest

from galvo_sysid.discrepancy.spectra import _where_it_acts


def test_right_and_wrong_corrections_where_they_act():
    rng = np.random.default_rng(0)
    groups, bins = 6, 253
    noise = rng.normal(scale=np.sqrt(0.5), size=(groups, 2 * bins))   # E z^2 = 1 per bin
    bump = np.zeros((groups, 2 * bins))
    bump[:, 20:40] = 8.0                                                 # the effect's shape
    # the right effect: what is left where it acts is the noise
    excess, left = _where_it_acts(noise + bump, noise)
    assert abs(excess) < 4
    assert abs(left) < 0.02
    # a wrong one closing 3/4 of the gap: a quarter of the shape is left there
    excess, left = _where_it_acts(noise + bump, noise + 0.5 * bump)
    assert excess > 50
    assert left == pytest.approx(0.25, abs=0.05)
    # noise only, a correction lost in it: nothing to say against it
    tiny = 0.01 * bump
    excess, _ = _where_it_acts(noise + tiny, noise)
    assert abs(excess) < 4
    assert _where_it_acts(noise, noise) == (0.0, 1.0)
