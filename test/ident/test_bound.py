"""The Cramer-Rao bound against J^T Sigma^-1 J with the noise's true covariance.

A generated scanner (``random_scanner(1)``: short records, a first mode whose antiresonance
cuts a deep, narrow valley into the noise spectrum, moves that start with the previous move's
ringing) simulated in closed loop: the noise of the model's residual is open loop, the
encoder's (coloured measurement noise, quantisation) plus the current noise through the
plant, all second-differenced, so its autocovariance is known exactly
(:func:`~galvo_sysid.sim.noise.residual_noise_autocovariance`, checked here against the
scatter of simulated moves). The bound :func:`crlb_at` reports from the moves' scatter must
match the bound with that covariance, the nuisance partialled out alike. (The bound of the fit's own
noise model, estimated from the moves' deviations whole, was ten times too large for omega_1
and zeta_1 here: the moves' ringing filled the valley.)
"""

from __future__ import annotations

import numpy as np
import pytest

from galvo_sysid.errors import InvalidDataError
from galvo_sysid.ident.refine.bound import crlb_at, crlb_known_noise
from galvo_sysid.model import PAPER_MODEL, PSI, TAU
from galvo_sysid.sim.config import SimulatorConfig
from galvo_sysid.sim.family import random_scanner
from galvo_sysid.sim.noise import residual_noise_autocovariance
from galvo_sysid.sim.simulator import simulate_window


def test_bound_matches_the_true_noise_covariance() -> None:
    sc = random_scanner(1)
    cfg = sc.config
    plant = cfg.plant
    angle = min(sc.angles, key=lambda a: abs(a - PSI))
    cur, enc = simulate_window(angle, moves=100, seed=3, config=cfg)
    ours = crlb_at([(cur, enc)], sample_period=plant.sample_period, model=plant.modal,
                   dynamics=plant.dynamics)
    theirs = crlb_known_noise([(cur, enc)], sample_period=plant.sample_period, model=plant.modal,
                              dynamics=plant.dynamics,
                              autocovariance=residual_noise_autocovariance(cfg, enc.shape[1]))
    ratio = np.array(list(ours.values())) / np.array(list(theirs.values()))
    assert np.all((ratio > 0.7) & (ratio < 1.3)), dict(zip(ours, ratio.round(3), strict=True))


def test_known_noise_bound_refuses_bad_input() -> None:
    cur, enc = simulate_window(PSI, moves=5, seed=0)
    r = residual_noise_autocovariance(SimulatorConfig(), 10)
    with pytest.raises(InvalidDataError, match='lags'):
        crlb_known_noise([(cur, enc)], sample_period=TAU, model=PAPER_MODEL.modal,
                         dynamics=PAPER_MODEL.dynamics, autocovariance=r)
    bad = residual_noise_autocovariance(SimulatorConfig(), enc.shape[1])
    bad[1:] = 2 * bad[0]
    with pytest.raises(InvalidDataError, match='positive definite'):
        crlb_known_noise([(cur, enc)], sample_period=TAU, model=PAPER_MODEL.modal,
                         dynamics=PAPER_MODEL.dynamics, autocovariance=bad)
