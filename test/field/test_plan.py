"""galvo-sysid plan: Cramer-Rao bounds of a deployment, moves to detect a change, dither."""

from __future__ import annotations

import math

import pytest

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.field.plan import DITHER_STEPS, plan
from galvo_sysid.model import PAPER_MODEL
from galvo_sysid.sim.dither import DitherConfig, dither_for_modes

OMEGA_3 = PAPER_MODEL.modal.natural_frequencies[2]


def test_a_dither_at_the_weak_mode_buys_its_frequency_for_a_fraction_of_a_count() -> None:
    plain = plan(PAPER_MODEL, moves=100, change={'omega_3': -0.01, 'omega_1': -0.002})
    dithered = plan(PAPER_MODEL, moves=100, dither=dither_for_modes(0.01, '3', model=PAPER_MODEL),
                    change={'omega_3': -0.01})
    assert plain.position_error == 0.0
    # the paper's moves hardly excite mode 3: a single window does not resolve it
    assert plain.unresolved == (3,)
    gain = plain.pooled_std['omega_3'] / dithered.pooled_std['omega_3']
    assert gain > 3.0
    assert dithered.pooled_std['zeta_3'] < plain.pooled_std['zeta_3']
    assert 0 < dithered.position_error < dithered.encoder_resolution  # under one count rms
    # moves to detect: the change at n_sigma and, for mode 3, the residue resolved
    need = plain.moves_to_detect['omega_3']
    assert need is not None
    again = plan(PAPER_MODEL, moves=need, change={'omega_3': -0.01})
    std = again.window_std[again.angles[0]]
    ref = PAPER_MODEL.modal.parameters()
    assert 3 * std['omega_3'] <= 0.01 * OMEGA_3 * 1.0001
    assert 5 * std['k3'] <= abs(ref['k3']) * 1.0001
    assert plain.moves_to_detect['omega_1'] == 1  # 0.2 % of omega_1 is seen in any window


def test_the_smallest_dither_for_a_target_is_the_first_that_reaches_it() -> None:
    target = 0.15
    found = plan(PAPER_MODEL, moves=100, dither=DitherConfig(frequencies=(OMEGA_3,)),
                 target={'zeta_3': target}).dither_for_target['zeta_3']
    assert found is not None
    amplitude, cost = found
    zeta_3 = PAPER_MODEL.modal.damping_ratios[2]
    at = plan(PAPER_MODEL, moves=100, dither=DitherConfig(amplitude=amplitude,
                                                          frequencies=(OMEGA_3,)))
    assert at.pooled_std['zeta_3'] <= target * zeta_3
    assert cost == pytest.approx(at.position_error, rel=1e-9)
    before = DITHER_STEPS[DITHER_STEPS.index(amplitude) - 1]
    below = plan(PAPER_MODEL, moves=100, dither=DitherConfig(amplitude=before,
                                                             frequencies=(OMEGA_3,)))
    assert below.pooled_std['zeta_3'] > target * zeta_3


@pytest.mark.parametrize(('options', 'says'), [
    ({'change': {'omega_9': -0.01}}, "unknown parameter 'omega_9'"),
    ({'target': {'zeta_3': -0.1}}, 'bad value'),
    ({'moves': 2}, 'moves must be'),
    ({'angles': [math.nan]}, 'angles must be finite'),
])
def test_bad_plans_are_refused(options: dict[str, object], says: str) -> None:
    with pytest.raises(ConfigurationError, match=says):
        plan(PAPER_MODEL, **options)  # type: ignore[arg-type]


def test_dither_modes_of_the_driver_and_simulate() -> None:
    from galvo_sysid.monitor.parameters import defaults
    from galvo_sysid.nodes.driver_node import simulator_config

    values = dict(defaults('galvo_driver'))
    assert not simulator_config(values).dither.active
    values.update({'dither.amplitude': 0.01, 'dither.modes': '3'})
    config = simulator_config(values)
    assert config.dither.amplitude == 0.01
    assert config.dither.frequencies == (OMEGA_3,)
    for bad in ('4', '0', '1,1', 'x'):
        with pytest.raises(ConfigurationError, match='dither modes'):
            simulator_config(dict(values, **{'dither.modes': bad}))
