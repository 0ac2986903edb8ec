"""Tests of the positioning controller design and its loop margins."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model import (
    PAPER_MODEL,
    REFERENCE_MODEL,
    TAU,
    InputDynamics,
    ModalModel,
    discretize,
)
from galvo_sysid.sim.controller import (
    Controller,
    ControllerConfig,
    auto_controller_config,
    closed_loop_poles,
    design_controller,
    loop_frequency_response,
    loop_margins,
)


@pytest.fixture(scope='module')
def controller() -> Controller:
    return design_controller(PAPER_MODEL)


def _plant(model=REFERENCE_MODEL, dynamics=None):
    return discretize(model, dynamics or InputDynamics(), TAU)


def test_nominal_margins_are_positive_and_reasonable(controller: Controller) -> None:
    m = loop_margins(controller, _plant())
    assert m.closed_loop_stable
    assert m.gain_crossover_frequency == pytest.approx(800.0, rel=1e-3)
    assert 10.0 < m.gain_margin_db < 25.0
    assert 40.0 < m.phase_margin < 60.0
    assert 0.5 < m.stability_margin <= 1.0


def test_margins_agree_with_a_direct_reading_of_the_loop(controller: Controller) -> None:
    m = loop_margins(controller, _plant())
    plant = _plant()
    # Phase margin: phase at |L| = 1, found by bisection on the loop gain.
    lo, hi = 2 * math.pi * 200, 2 * math.pi * 3000
    for _ in range(60):
        mid = (lo + hi) / 2
        if abs(loop_frequency_response(controller, plant, [mid])[0]) > 1:
            lo = mid
        else:
            hi = mid
    phase = np.degrees(np.angle(loop_frequency_response(controller, plant, [lo])[0]))
    assert 180 + phase == pytest.approx(m.phase_margin, abs=0.05)
    # Gain margin: |L| where the phase crosses -180 deg.
    w = 2 * math.pi * m.phase_crossover_frequency
    loop = loop_frequency_response(controller, plant, [w])[0]
    assert abs(np.angle(loop, deg=True)) == pytest.approx(180, abs=0.5)
    assert -20 * np.log10(abs(loop)) == pytest.approx(m.gain_margin_db, abs=0.05)


def test_state_space_realises_the_sections(controller: Controller) -> None:
    a, b, c, d = controller.state_space()
    omega = np.array([2 * math.pi * f for f in (10.0, 800.0, 11_300.0, 19_000.0, 40_000.0)])
    z = np.exp(1j * omega * TAU)
    ss = np.array([c @ np.linalg.solve(zz * np.eye(a.shape[0]) - a, b) + d for zz in z])
    np.testing.assert_allclose(ss, controller.frequency_response(omega), rtol=1e-10)


def test_notches_sit_at_the_resonances(controller: Controller) -> None:
    w = np.array(REFERENCE_MODEL.natural_frequencies)
    at = np.abs(controller.frequency_response(w))
    beside = np.abs(controller.frequency_response(w * 1.5))
    cfg = ControllerConfig()
    assert np.all(at < beside * 3 * cfg.notch_depth / cfg.notch_width)


def test_robust_to_plant_variations(controller: Controller) -> None:
    model = REFERENCE_MODEL
    variants = [
        dataclasses.replace(model, k0=model.k0 * g, residues=tuple(k * g for k in model.residues))
        for g in (0.7, 1.3)
    ] + [
        dataclasses.replace(model, natural_frequencies=tuple(w * f for w in
                                                             model.natural_frequencies))
        for f in (0.9, 1.1)
    ]
    for variant in variants:
        m = loop_margins(controller, _plant(variant))
        assert m.closed_loop_stable
        assert m.gain_margin_db > 6
        assert m.phase_margin > 30
    m = loop_margins(controller, _plant(dynamics=InputDynamics(dead_time=TAU)))
    assert m.closed_loop_stable
    assert m.phase_margin > 30


def test_too_much_gain_is_flagged_unstable(controller: Controller) -> None:
    hot = dataclasses.replace(controller, gain=controller.gain * 10)
    m = loop_margins(hot, _plant())
    assert not m.closed_loop_stable
    assert m.gain_margin_db < 0 or m.phase_margin < 0
    assert np.max(np.abs(closed_loop_poles(hot, _plant()))) > 1


def test_crossover_follows_the_configuration() -> None:
    c = design_controller(PAPER_MODEL, config=ControllerConfig(crossover_frequency=500.0))
    assert loop_margins(c, _plant()).gain_crossover_frequency == pytest.approx(500.0, rel=1e-3)


@pytest.mark.parametrize('kwargs', [
    {'crossover_frequency': -1.0},
    {'crossover_frequency': math.nan},
    {'lead_ratio': 0.5},
    {'integral_ratio': -0.1},
    {'notch_depth': 0.5, 'notch_width': 0.3},
    {'notch_frequencies': (0.0,)},
    {'lowpass_frequency': -5.0},
])
def test_bad_configuration_raises(kwargs: dict[str, float]) -> None:
    with pytest.raises(ConfigurationError):
        ControllerConfig(**kwargs)  # type: ignore[arg-type]


def test_design_above_nyquist_raises() -> None:
    with pytest.raises(ConfigurationError):
        design_controller(PAPER_MODEL, config=ControllerConfig(crossover_frequency=20_000.0))
    with pytest.raises(ConfigurationError):
        design_controller(PAPER_MODEL, config=ControllerConfig(notch_frequencies=(4e5,)))


def test_automatic_design_of_the_paper_scanner_is_the_800_hz_design() -> None:
    assert auto_controller_config(PAPER_MODEL) == ControllerConfig(crossover_frequency=800.0)
    auto = design_controller(PAPER_MODEL)
    explicit = design_controller(PAPER_MODEL, config=ControllerConfig())
    assert auto == explicit


def test_automatic_design_follows_the_model() -> None:
    slow = dataclasses.replace(
        PAPER_MODEL, sample_period=50e-6,
        dynamics=InputDynamics(computation_delay=1, lag_time_constant=30e-6),
        modal=dataclasses.replace(REFERENCE_MODEL, natural_frequencies=(
            2 * math.pi * 4500, 2 * math.pi * 5200, 2 * math.pi * 5900)))
    cfg = auto_controller_config(slow)
    # the 1.6-sample delay at 50 us limits it: 0.15 rad / (2 pi 80 us) = 298 Hz -> 290 Hz
    assert cfg.crossover_frequency == pytest.approx(290.0)
    c = design_controller(slow)
    m = loop_margins(c, discretize(slow.modal, slow.dynamics, slow.sample_period))
    assert m.closed_loop_stable
    assert m.gain_margin_db >= 6.0
    assert m.phase_margin >= 30.0


def test_automatic_crossover_takes_the_lowest_of_its_three_limits() -> None:
    """Each branch of min(f1 / 14, where the delay costs 0.15 rad, Nyquist / 8) in turn."""
    # a low first mode: 1,400 Hz / 14 = 100 Hz, far below the delay's 1.5 kHz and 6.25 kHz
    low_mode = dataclasses.replace(PAPER_MODEL, modal=dataclasses.replace(
        REFERENCE_MODEL, natural_frequencies=(2 * math.pi * 1400, 2 * math.pi * 5200,
                                               2 * math.pi * 5900)))
    assert auto_controller_config(low_mode).crossover_frequency == pytest.approx(100.0)
    # a mode's f1 / 14 is always below Nyquist / 8: that limit binds only a rigid body
    # (a model with no mode found) without delay: 12.5 kHz / 8 = 1,562.5 Hz, two digits
    # rounded down
    rigid = dataclasses.replace(
        PAPER_MODEL, sample_period=40e-6,
        dynamics=InputDynamics(computation_delay=0, lag_time_constant=0.0),
        modal=ModalModel(k0=REFERENCE_MODEL.k0, residues=(), natural_frequencies=(),
                         damping_ratios=()))
    assert auto_controller_config(rigid).crossover_frequency == pytest.approx(1500.0)


def test_a_model_without_a_stable_design_is_refused() -> None:
    # A first mode 10,000 times the rigid body's gain with 0.1 % damping: no notch tames it.
    hopeless = dataclasses.replace(PAPER_MODEL, modal=dataclasses.replace(
        REFERENCE_MODEL, residues=(3.6e10, -5.485e6, -4.604e5),
        damping_ratios=(0.001, 7.723e-3, 4.579e-3)))
    with pytest.raises(ConfigurationError, match='no stable positioning controller'):
        design_controller(hopeless)


def test_the_automatic_design_is_kept_per_model() -> None:
    """The same model gets the same (immutable) controller without a second design; another
    model its own, and an explicit config is designed as asked."""
    from galvo_sysid.sim.family import random_scanner

    assert design_controller(PAPER_MODEL) is design_controller(PAPER_MODEL)
    other = random_scanner(1).model
    assert design_controller(other) == design_controller(other)
    assert design_controller(other) != design_controller(PAPER_MODEL)
    cfg = ControllerConfig(crossover_frequency=400.0)
    assert design_controller(PAPER_MODEL, config=cfg) != design_controller(PAPER_MODEL)
