"""Tests of the move profiles (reference and feed-forward)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model import PAPER_ANGLES, REFERENCE_MODEL, TAU, InputDynamics, ModalModel
from galvo_sysid.model import simulate as simulate_plant
from galvo_sysid.sim.profiles import ProfileConfig, move_profile

K0 = REFERENCE_MODEL.k0


def _profile(angle: float, **kwargs: object):
    kwargs.setdefault('dynamics', InputDynamics())
    kwargs.setdefault('sample_period', TAU)
    return move_profile(angle, length=606, record_length=512, k0=K0, **kwargs)  # type: ignore[arg-type]


@pytest.mark.parametrize('angle', [0.03, 0.3, 1.7, 3.0, -0.9])
def test_profile_reaches_the_target_at_rest(angle: float) -> None:
    p = _profile(angle)
    ff = p.feedforward
    assert np.all(ff[p.duration:] == 0)
    assert ff.sum() == pytest.approx(0.0, abs=1e-12)           # velocity back to zero
    assert p.reference[-1] == pytest.approx(angle, abs=1e-12 * abs(angle))
    assert p.reference[0] == 0.0
    assert np.all(np.abs(ff) <= ProfileConfig().peak_current * (1 + 1e-9))
    # Moves forward: the reference never overshoots nor goes backwards.
    r = p.reference * np.sign(angle)
    assert np.all(np.diff(r) >= -1e-13 * abs(angle))
    assert r.max() <= abs(angle) * (1 + 1e-12)


def test_reference_is_the_rigid_response_to_the_feedforward() -> None:
    p = _profile(0.3)
    rigid = ModalModel(k0=K0, residues=(), natural_frequencies=(), damping_ratios=())
    y = simulate_plant(rigid, InputDynamics(), p.feedforward, sample_period=TAU)
    np.testing.assert_allclose(p.reference, y, atol=1e-13)


def test_durations_grow_with_the_angle_and_fit_the_record() -> None:
    durations = [_profile(a).duration for a in PAPER_ANGLES]
    assert durations == sorted(durations)
    assert durations[0] * TAU >= ProfileConfig().times(TAU)[0]
    assert durations[-1] <= 0.6 * 512
    assert _profile(3.0).duration * TAU == pytest.approx(1.9e-3, rel=0.05)
    # Constant peak acceleration: duration ~ sqrt(angle) for large moves.
    assert _profile(3.0).duration / _profile(0.75).duration == pytest.approx(2.0, rel=0.1)


def test_sign_symmetry_and_zero_move() -> None:
    a, b = _profile(0.6), _profile(-0.6)
    np.testing.assert_allclose(a.feedforward, -b.feedforward)
    z = _profile(0.0)
    assert np.all(z.feedforward == 0)
    assert np.all(z.reference == 0)


def test_jerk_limit_shapes_the_acceleration() -> None:
    p = _profile(3.0, config=ProfileConfig(jerk_time=50e-6))
    ramp = np.abs(np.diff(p.feedforward[:20]))
    # The ramp takes ~5 samples to reach the peak.
    assert np.argmax(p.feedforward) >= 4
    assert ramp.max() < 0.3 * p.feedforward.max()


def test_too_large_moves_and_bad_configuration_raise() -> None:
    with pytest.raises(ConfigurationError):
        _profile(30.0)
    with pytest.raises(ConfigurationError):
        _profile(math.nan)
    with pytest.raises(ConfigurationError):
        ProfileConfig(peak_current=0.0)
    with pytest.raises(ConfigurationError):
        ProfileConfig(jerk_time=-1.0)
    with pytest.raises(ConfigurationError):
        ProfileConfig(max_fraction=1.5)
    with pytest.raises(ConfigurationError):
        move_profile(0.3, length=606, record_length=512, k0=-1.0, dynamics=InputDynamics(),
                     sample_period=TAU)
