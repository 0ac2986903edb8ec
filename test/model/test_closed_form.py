"""The plant's sampled response against a closed form that shares no code with the model.

The simulator (``model/sampling.py``), the model's own discretisation (``model/dynamics.py``)
and the discrepancy workflow's open-loop plant (``discrepancy/plant.py``) all build the
continuous plant with :func:`galvo_sysid.model.dynamics.modal_state_space` and sample it with
the same zero-order hold, so their agreement says nothing about that builder. Here the
reference is the step response of paper Eq. 1 behind the amplifier lag, written out by partial
fractions (no state space, no matrix exponential, no python-control):

- rigid body k0/s^2 behind 1/(tau s + 1): k0 (t^2/2 - tau t + tau^2 (1 - exp(-t/tau)));
- mode g/(s^2 + 2 zeta w s + w^2) behind the lag: sum over the poles p_j of G(s)/s (0, the
  mode's pair, -1/tau) of r_j exp(p_j t), r_j = K / prod_{m != j} (p_j - p_m);

and a command held over one sample and delayed by D (computation delay and dead time) gives
y(kT) = step(kT - D) - step(kT - D - T), which is exact for any fractional D.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest

from galvo_sysid.discrepancy import PlantSimulator
from galvo_sysid.model import PAPER_MODEL, InputDynamics, PlantModel, simulate
from galvo_sysid.model.sampling import sample_plant
from galvo_sysid.sim.config import SimulatorConfig
from galvo_sysid.sim.family import random_scanner
from galvo_sysid.sim.simulator import GalvoSimulator

SAMPLES = 400
TOLERANCE = 1e-9
"""Largest difference from the closed form, relative to the largest |y|: the sampling is exact,
so only rounding is left (measured 2e-13); 1 % more damping in any one mode of the paper's
scanner moves its response by more than 100 times this (the last test)."""


def _step(t: np.ndarray, plant: PlantModel) -> np.ndarray:
    """Step response of the lag and the mechanics (no delay) at times t (0 for t < 0)."""
    m = plant.modal
    tau = plant.dynamics.lag_time_constant
    tt = np.maximum(t, 0.0)
    if tau > 0:
        y = m.k0 * (tt**2 / 2 - tau * tt + tau**2 * -np.expm1(-tt / tau))
    else:
        y = m.k0 * tt**2 / 2
    for g, w, z in zip(m.residues, m.natural_frequencies, m.damping_ratios, strict=True):
        root = w * np.sqrt(complex(z * z - 1.0))
        poles = [0.0, -z * w + root, -z * w - root]
        gain = complex(g)
        if tau > 0:
            poles.append(-1.0 / tau)
            gain = g / tau
        for j, p in enumerate(poles):
            r = gain / np.prod([p - q for i, q in enumerate(poles) if i != j])
            y = y + np.real(r * np.exp(p * tt))
    return np.where(t > 0, y, 0.0)


def _pulse_response(plant: PlantModel, n: int) -> np.ndarray:
    """Angle y[k] at kT after a unit command held over [0, T), the input dynamics' delay
    included."""
    t = plant.sample_period
    d = plant.dynamics.pure_delay(t)
    times = np.arange(n) * t
    return _step(times - d, plant) - _step(times - d - t, plant)


def _closed_form(plant: PlantModel, u: np.ndarray) -> np.ndarray:
    return np.convolve(_pulse_response(plant, u.size), u)[: u.size]


PLANTS = ('paper', 'paper + 0.37 T dead time', 'family seed 7', 'family seed 14')
"""The paper's scanner, with a fractional dead time, and two seeded family scanners (seed 7:
T 27.1 us, 3 modes, 2 samples of delay, lag 0.50 T; seed 14: T 41 us, 5 modes up to 7.24 kHz,
1 sample, lag 0.31 T)."""


@functools.cache
def _plant(name: str) -> PlantModel:
    if name.startswith('family seed '):
        return random_scanner(int(name.removeprefix('family seed '))).model
    if name == 'paper':
        return PAPER_MODEL
    t = PAPER_MODEL.sample_period
    return dataclasses.replace(PAPER_MODEL, dynamics=InputDynamics(
        computation_delay=1, lag_time_constant=0.6 * t, dead_time=0.37 * t))


def _sampled(plant: PlantModel, u: np.ndarray) -> np.ndarray:
    """The simulator's sampled plant stepped by hand (command only, from rest)."""
    sp = sample_plant(plant.physics())
    x = np.zeros(sp.phi.shape[0])
    hist = np.zeros(sp.whole + 2)
    y = np.empty(u.size)
    for k in range(u.size):
        y[k] = sp.continuous.c @ x
        hist = np.concatenate([[u[k]], hist[:-1]])
        x = sp.phi @ x + sp.g_old * hist[sp.whole + 1] + sp.g_new * hist[sp.whole]
    return y


@pytest.mark.parametrize('name', PLANTS)
def test_open_loop_responses_equal_the_closed_form(name: str) -> None:
    """A random command through the model's discretisation, the simulator's sampled plant
    and the discrepancy workflow's plant: each equals the closed form to rounding."""
    plant = _plant(name)
    u = np.random.default_rng(16).normal(size=SAMPLES)
    ref = _closed_form(plant, u)
    scale = float(np.max(np.abs(ref)))
    t = plant.sample_period
    outputs = {
        'model.simulate': simulate(plant.modal, plant.dynamics, u, sample_period=t),
        'sample_plant': _sampled(plant, u),
        'discrepancy PlantSimulator': PlantSimulator(plant.physics(), sample_period=t,
                                                     length=SAMPLES).simulate(u, 0.0),
    }
    for what, y in outputs.items():
        assert np.max(np.abs(y - ref)) < TOLERANCE * scale, (name, what)


@pytest.mark.parametrize('name', PLANTS[::2])
def test_closed_loop_simulator_encoder_is_the_closed_form_of_its_current(name: str) -> None:
    """The closed-loop simulator, noise off: its first move starts at exact rest, so its
    encoder is the closed-form plant driven by the current it recorded."""
    plant = _plant(name)
    config = SimulatorConfig(plant=plant, current_noise_std=0.0, measurement_noise_std=0.0,
                             encoder_resolution=0.0)
    move = GalvoSimulator(config=config, seed=0).run_move(0.3)
    ref = move.start_angle + _closed_form(plant, move.current)
    assert np.max(np.abs(move.encoder - ref)) < TOLERANCE * float(np.max(np.abs(ref))), name


def test_the_closed_form_sees_a_one_percent_change_of_any_damping_ratio() -> None:
    """The reference is sensitive where the shared builder could go wrong: 1 % more damping
    in one mode moves the paper plant's response by far more than TOLERANCE."""
    u = np.random.default_rng(16).normal(size=SAMPLES)
    ref = _closed_form(PAPER_MODEL, u)
    m = PAPER_MODEL.modal
    for i in range(m.n_modes):
        zeta = list(m.damping_ratios)
        zeta[i] *= 1.01
        other = dataclasses.replace(PAPER_MODEL, modal=dataclasses.replace(
            m, damping_ratios=tuple(zeta)))
        change = np.max(np.abs(_closed_form(other, u) - ref)) / np.max(np.abs(ref))
        assert change > 100 * TOLERANCE, (i, change)
