"""A residue that passed the resolution test: its selection bias, and the covariance that
counts it (``refine/checks.py``)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from galvo_sysid.ident.refine.checks import selection_bias, widen_selected


def test_the_bias_is_largest_at_the_threshold_and_vanishes_above_it() -> None:
    b = [selection_bias(z, 5.0) for z in (5.0, 5.5, 6.0, 7.0, 8.0, 10.0)]
    assert b[0] == pytest.approx(2.98, abs=0.02)
    assert all(x > y for x, y in itertools.pairwise(b))
    assert b[-1] < 1e-2
    assert selection_bias(-5.5, 5.0) == pytest.approx(b[1])  # the sign does not matter
    assert selection_bias(4.9, 5.0) == 0.0  # not selected
    assert selection_bias(5.5, 0.0) == 0.0  # no test, no bias
    assert selection_bias(float('nan'), 5.0) == 0.0


@pytest.mark.parametrize('mu', [3.0, 4.0, 5.0, 8.0, -4.0])
def test_the_widened_std_is_calibrated_over_the_residues_that_pass(mu: float) -> None:
    """Residues drawn about a true mu (in std), kept only where |z| >= 5: the plain std is
    overconfident for a mode below the threshold (rms error/std 1.6 at mu = 4, 2.4 at 3);
    the widened one, sqrt(1 + b^2), is calibrated within 0.8-1.1 at every mu."""
    rng = np.random.default_rng(7)
    z = rng.normal(mu, 1.0, 6000)
    z = z[np.abs(z) >= 5.0][:1500]
    b = np.array([selection_bias(v, 5.0) for v in z])
    plain = float(np.sqrt(np.mean((z - mu) ** 2)))
    widened = float(np.sqrt(np.mean((z - mu) ** 2 / (1.0 + b * b))))
    if abs(mu) <= 4.0:
        assert plain > 1.5
    assert 0.8 <= widened <= 1.1, (plain, widened)


def test_a_selected_residue_s_std_is_widened_and_its_correlations_kept() -> None:
    """The residue's row and column scaled by sqrt(1 + b^2): its variance times 1 + b^2, its
    correlations as they were, the other parameters untouched; an unresolved residue and one
    far above the threshold unchanged."""
    n = 2
    rng = np.random.default_rng(3)
    a = rng.standard_normal((7, 7))
    cov = a @ a.T
    k = [5.2 * float(np.sqrt(cov[1, 1])), 5.1 * float(np.sqrt(cov[2, 2]))]
    out = cov.copy()
    widen_selected(out, k, [True, False], threshold=5.0, n=n)
    f = np.sqrt(1.0 + selection_bias(5.2, 5.0) ** 2)
    assert f > 2.0
    scale = np.ones(7)
    scale[1] = f
    np.testing.assert_allclose(out, cov * np.outer(scale, scale), rtol=1e-12)
    far = cov.copy()
    widen_selected(far, [12.0 * float(np.sqrt(cov[1, 1])), k[1]], [True, False], threshold=5.0,
                   n=n)
    np.testing.assert_allclose(far, cov, rtol=1e-6)  # far above: nothing to add
