"""The simulator's noise as the refined fit's residual sees it, exactly.

The refined fit explains each record's second-differenced encoder by the plant's response to
the *recorded* current (its nuisance aside). In the simulator's linear loop what is left is
open loop, whatever the controller does (its reaction to the noise is in the recorded
current, which the model takes as input):

- the current noise (first-order coloured), which enters the plant beside the amplifier's
  current, through the plant's disturbance path;
- the encoder's measurement noise (first-order coloured) and its quantisation (rounding to
  the encoder step, taken as white with variance step^2 / 12);

all second-differenced. :func:`residual_noise_autocovariance` gives that noise's
autocovariance per move from the simulator's configuration: with it, the Cramer-Rao bound
of a simulated window is the bound with the true noise spectrum
(:func:`~galvo_sysid.ident.refine.bound.crlb_known_noise`), the yardstick of
``benchmarks/efficiency.py``, against which the bound the fit estimates from the moves'
scatter is itself checked.
"""

from __future__ import annotations

import functools
import math
from typing import TYPE_CHECKING

import numpy as np

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.filters import lfilter
from galvo_sysid.model.sampling import sample_plant

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from galvo_sysid.model.physics import Physics
    from galvo_sysid.sim.config import SimulatorConfig

__all__ = ['ar_coefficient', 'residual_noise_autocovariance']

_DECAY = 1e-12
"""Energy of the plant's disturbance response left after its last sample, relative to the
whole (where the response is cut)."""

_MAX_RING = 1 << 21
"""Longest disturbance response computed [samples]."""


def ar_coefficient(corner: float, sample_period: float) -> float:
    """Pole of the first-order colouring of a noise with corner ``corner`` [Hz] (inf: 0)."""
    return 0.0 if math.isinf(corner) else math.exp(-2 * math.pi * corner * sample_period)


@functools.lru_cache(maxsize=16)
def _disturbance_response(physics: Physics) -> NDArray[np.float64]:
    """Second-differenced encoder response to a unit current-noise sample, until it dies out.

    Kept per plant (read-only): a benchmark asks for it once per simulated window.

    Raises:
        ConfigurationError: A nonlinear plant, or a response that does not die out (an
            undamped mode, e.g. an undamped pivot spring).
    """
    if not physics.linear:
        raise ConfigurationError('the exact residual noise needs a linear plant (no friction, '
                                 'saturation, cogging, encoder error or proposed terms)')
    sp = sample_plant(physics)
    c = sp.continuous.c
    drive = physics.gain_ratio * sp.g_d
    # The rigid body's double pole at 1 is cancelled by the second difference; the modes
    # decay as radius^k at the slowest.
    modal = [abs(z) for z in np.linalg.eigvals(sp.phi) if abs(z - 1.0) > 1e-6]
    slowest = max(modal, default=0.0)
    if slowest >= 1.0:
        raise ConfigurationError('the plant has an undamped mode: its noise is not stationary')
    ring = int(min(_MAX_RING, 64 + math.ceil(math.log(_DECAY) / (2 * math.log(slowest)))
                   if slowest > 0 else 64))
    h = np.empty(ring + 2)
    h[0] = 0.0
    x = drive.copy()
    for k in range(1, ring + 2):
        h[k] = float(c @ x)
        x = sp.phi @ x
    out = np.concatenate([[h[0]], [h[1] - 2.0 * h[0]], h[2:] - 2.0 * h[1:-1] + h[:-2]])
    out.flags.writeable = False
    return out


def residual_noise_autocovariance(config: SimulatorConfig, lags: int) -> NDArray[np.float64]:
    """Autocovariance of one move's residual noise (see the module docs), lags 0..lags-1.

    Args:
        config: The simulator's configuration (a linear plant; drifts and steps are not
            looked at: the plant at the start is used).
        lags: Lags wanted (e.g. the record's rows).

    Returns:
        r[0..lags-1] [deg^2], of the second difference of the encoder per sample.

    Raises:
        ConfigurationError: A nonlinear plant, an undamped mode, or fewer than one lag.
    """
    if isinstance(lags, bool) or not isinstance(lags, int) or lags < 1:
        raise ConfigurationError(f'lags must be a whole number >= 1, got {lags!r}')
    t = config.sample_period
    g = _disturbance_response(config.plant.physics())
    a_i = ar_coefficient(config.current_noise_corner, t)
    g = lfilter([math.sqrt(1.0 - a_i * a_i) * config.current_noise_std], [1.0, -a_i], g)
    size = 1 << math.ceil(math.log2(2 * max(g.size, lags)))
    r = np.fft.irfft(np.abs(np.fft.rfft(g, size)) ** 2, size)[:lags]
    a_v = ar_coefficient(config.measurement_noise_corner, t)
    r_v = config.measurement_noise_std ** 2 * a_v ** np.abs(np.arange(-2, lags + 2))
    d2 = np.array([1.0, -4.0, 6.0, -4.0, 1.0])
    r = r + np.array([d2 @ r_v[k: k + 5] for k in range(lags)])
    quantisation = np.array([6.0, -4.0, 1.0]) * config.encoder_resolution ** 2 / 12.0
    r[: min(3, lags)] += quantisation[: min(3, lags)]
    return np.asarray(r, dtype=np.float64)
