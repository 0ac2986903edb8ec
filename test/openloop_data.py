"""Open-loop test data for the identification tests (plant.simulate, known truth).

A move is a smooth bang-bang current pulse (accelerate, then decelerate, edges rounded by a
raised cosine) sized so that the rigid body turns ``target_angle`` degrees, followed by rest.
Noise: a coloured (first-order low-pass) current disturbance that enters the plant but not the
record (the record is the commanded current), coloured encoder noise, and encoder quantisation.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from galvo_sysid.model import REFERENCE_MODEL, TAU, InputDynamics, ModalModel, simulate

N_SAMPLES = 512
QUANTUM = 4e-5  # encoder resolution [deg]


def move_current(target_angle: float, *, n: int = N_SAMPLES, start: int = 8,
                 duration: int = 100, edge: int = 2, k0: float = REFERENCE_MODEL.k0,
                 sample_period: float = TAU) -> NDArray[np.float64]:
    """One smooth bang-bang current record that turns the rigid body by ``target_angle``."""
    k = np.arange(n, dtype=float)
    half = duration / 2

    def ramp(x: NDArray[np.float64]) -> NDArray[np.float64]:
        t = np.clip(x / edge, 0.0, 1.0)
        return 0.5 - 0.5 * np.cos(np.pi * t)

    shape = (ramp(k - start) - 2 * ramp(k - start - half) + ramp(k - start - duration))
    # rigid body: angle after the pulse = k0 * T^2 * sum_j (n_end - j) u_j ... scale numerically
    y = np.cumsum(np.cumsum(shape)) * k0 * sample_period**2
    return np.asarray(shape * target_angle / y[-1], dtype=float)


def coloured(rng: np.random.Generator, shape: tuple[int, int], std: float,
             pole: float) -> NDArray[np.float64]:
    """First-order low-pass noise with stationary standard deviation ``std``."""
    from scipy.signal import lfilter

    e = rng.standard_normal(shape) * std * np.sqrt(1 - pole**2)
    return np.asarray(lfilter([1.0], [1.0, -pole], e, axis=-1), dtype=float)


def open_loop_window(target_angle: float, *, moves: int = 100, seed: int = 0,
                     model: ModalModel = REFERENCE_MODEL,
                     dynamics: InputDynamics | None = None,
                     current_noise: float = 2e-4, encoder_noise: float = 2e-5,
                     quantum: float = QUANTUM, start_angle: float = 1.0,
                     ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``moves`` records (current, encoder), each (moves, 512), of the same rotation."""
    rng = np.random.default_rng(seed)
    dyn = InputDynamics() if dynamics is None else dynamics
    u = np.tile(move_current(target_angle), (moves, 1))
    drive = u
    if current_noise > 0:
        drive = u + coloured(rng, u.shape, current_noise, 0.9)
    y = simulate(model, dyn, drive, sample_period=TAU) + start_angle
    if encoder_noise > 0:
        y = y + coloured(rng, y.shape, encoder_noise, 0.7)
    if quantum > 0:
        y = np.round(y / quantum) * quantum
    return u, y
