"""The input dynamics and the exact zero-order-hold sampling every part of the project uses.

Between the DSP's current command and the motor torque sit ``computation_delay`` whole sample
periods of DSP computation delay, an optional extra dead time and the current amplifier's
first-order lag (:class:`InputDynamics`). The paper lumps them into an equivalent delay of
1.6 sample periods (one sample plus a 0.6-sample lag).

One place for the two operations that were written several times before:

- :func:`split_delay`: a pure delay as whole samples plus a fraction of a sample;
- :func:`zoh`: the exact zero-order hold of a continuous state space over a time step,
  computed by :func:`expm_balanced`.

:func:`modal_state_space` builds the continuous state space of a sum of modes behind the lag;
:func:`discretize` samples a modal model with its input dynamics exactly (fractional delays
split inside the sample) and :func:`simulate` runs it open loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.linalg import matrix_balance

from galvo_sysid.errors import ConfigurationError, InvalidDataError

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import ArrayLike, NDArray

    from galvo_sysid.model.modal import ModalModel

__all__ = [
    'MAX_COMPUTATION_DELAY',
    'DiscreteStateSpace',
    'InputDynamics',
    'check_sample_period',
    'discretize',
    'expm_balanced',
    'modal_state_space',
    'simulate',
    'split_delay',
    'zoh',
]

MAX_COMPUTATION_DELAY = 64
"""Most whole samples of computation delay a model may have (a bound on memory)."""

_SPLIT_EPS = 1e-9
"""A delay within this fraction of a sample of a whole number of samples is whole."""


def check_sample_period(sample_period: float, *, what: str = 'sample_period') -> float:
    """Return ``sample_period`` as a float if it is positive and finite, else raise.

    Raises:
        ConfigurationError: Not a positive finite number.
    """
    if isinstance(sample_period, bool) or not isinstance(sample_period, int | float) or not (
            math.isfinite(sample_period) and sample_period > 0):
        raise ConfigurationError(f'{what} must be positive and finite, got {sample_period!r}')
    return float(sample_period)


@dataclass(frozen=True)
class InputDynamics:
    """What sits between the DSP's current command and the motor torque.

    Attributes:
        computation_delay: DSP computation delay in whole sample periods.
        lag_time_constant: Time constant of the current amplifier's first-order lag [s];
            0 means no lag.
        dead_time: Extra pure delay [s] (0 for the nominal plant).
    """

    computation_delay: int = 1
    lag_time_constant: float = 6e-6
    dead_time: float = 0.0

    def __post_init__(self) -> None:
        if isinstance(self.computation_delay, bool) or not isinstance(self.computation_delay,
                                                                      int):
            raise ConfigurationError('computation_delay must be a whole number of samples')
        if not 0 <= self.computation_delay <= MAX_COMPUTATION_DELAY:
            raise ConfigurationError(
                f'computation_delay must be within 0..{MAX_COMPUTATION_DELAY} samples, got '
                f'{self.computation_delay}')
        if not (math.isfinite(self.lag_time_constant) and self.lag_time_constant >= 0):
            raise ConfigurationError('lag_time_constant must be finite and >= 0')
        if not (math.isfinite(self.dead_time) and self.dead_time >= 0):
            raise ConfigurationError('dead_time must be finite and >= 0')

    def pure_delay(self, sample_period: float) -> float:
        """Computation delay plus dead time [s]."""
        return self.computation_delay * sample_period + self.dead_time

    def equivalent_delay(self, sample_period: float) -> float:
        """Return the low-frequency equivalent input delay [s] (pure delay plus lag)."""
        return self.computation_delay * sample_period + self.lag_time_constant + self.dead_time

    def frequency_response(self, omega: ArrayLike, sample_period: float) -> NDArray[np.complex128]:
        """Return the input dynamics' continuous-time frequency response at ``omega``."""
        w = np.asarray(omega, dtype=float)
        delay = self.pure_delay(sample_period)
        return np.asarray(np.exp(-1j * w * delay) / (1 + 1j * w * self.lag_time_constant),
                          dtype=np.complex128)


def split_delay(delay: float, sample_period: float) -> tuple[int, float]:
    """Split a pure delay into whole samples and a fraction of a sample in [0, 1).

    A fraction within 1e-9 of a sample of 0 or 1 rounds to a whole number of samples.

    Args:
        delay: Pure delay [s] (>= 0).
        sample_period: Sampling period [s].

    Returns:
        ``(whole, fraction)``: the delay is ``(whole + fraction) * sample_period``.
    """
    whole_f, frac = divmod(delay / sample_period, 1.0)
    whole = round(whole_f)
    if frac > 1.0 - _SPLIT_EPS:
        return whole + 1, 0.0
    if frac < _SPLIT_EPS:
        return whole, 0.0
    return whole, float(frac)


def expm_balanced(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """Matrix exponential by balancing, scaling and squaring of a degree-16 Taylor series.

    As accurate as :func:`scipy.linalg.expm` on the plant's badly scaled matrices (entries
    from 1 to 1e10; the balancing takes care of that; a test compares the two) and, using
    only matrix products, far faster on small matrices when OpenBLAS threads contend (a few
    ms for scipy's Pade solve on a busy 2-core machine against ~0.1 ms here), which matters
    when a drifting plant is re-sampled every move.
    """
    b, (scale, _) = matrix_balance(a, permute=False, separate=True)
    norm = float(np.abs(b).sum(axis=0).max())
    squarings = max(0, math.ceil(math.log2(norm / 0.2))) if norm > 0 else 0
    b = b / 2.0**squarings
    n = a.shape[0]
    out = np.eye(n)
    term = np.eye(n)
    for k in range(1, 17):
        term = term @ b / k
        out = out + term
    for _ in range(squarings):
        out = out @ out
    return np.asarray(scale[:, None] * out / scale[None, :], dtype=np.float64)


def zoh(a: NDArray[np.float64], b: NDArray[np.float64],
        t: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Exact zero-order hold of x' = a x + b u over a step of ``t`` seconds.

    Args:
        a: State matrix (n, n).
        b: Input matrix (n, m) or one input (n,).
        t: Step [s]; 0 or less gives the identity and zero drive.

    Returns:
        ``(phi, gamma)`` = ``(e^{a t}, int_0^t e^{a s} ds b)``, gamma shaped like ``b``.
    """
    n = a.shape[0]
    b2 = b.reshape(n, -1)
    if t <= 0:
        return np.eye(n), np.zeros_like(b)
    m = b2.shape[1]
    aug = np.zeros((n + m, n + m))
    aug[:n, :n] = a * t
    aug[:n, n:] = b2 * t
    e = expm_balanced(aug)
    return e[:n, :n], e[:n, n:].reshape(b.shape)


@dataclass(frozen=True)
class DiscreteStateSpace:
    """x[k+1] = a x[k] + b u[k], y[k] = c x[k]; the plant from command to encoder angle."""

    a: NDArray[np.float64]
    b: NDArray[np.float64]
    c: NDArray[np.float64]

    def frequency_response(self, omega: ArrayLike, sample_period: float) -> NDArray[
            np.complex128]:
        """Return c (zI - a)^-1 b at z = exp(j omega T) (batched linear solves)."""
        w = np.asarray(omega, dtype=float)
        n = self.a.shape[0]
        z = np.exp(1j * w * sample_period)
        m = z[:, None, None] * np.eye(n)[None] - self.a[None]
        rhs = np.broadcast_to(self.b.astype(complex), (len(z), n))[..., None]
        x = np.linalg.solve(m, rhs)[..., 0]
        return np.asarray(x @ self.c, dtype=np.complex128)


def modal_state_space(*, gains: Sequence[float], frequencies: Sequence[float],
                      dampings: Sequence[float], lag_time_constant: float,
                      input_gain: float = 1.0, rigid_damping: float = 0.0) -> tuple[
                          NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                          NDArray[np.float64]]:
    """Continuous state space of ``input_gain * lag(s) * sum_i g_i/(s^2 + 2 z_i w_i s + w_i^2)``.

    The states are the lag's output current first (if ``lag_time_constant`` > 0), then
    (position, velocity) per mode; the output is the sum of the mode positions.

    Args:
        gains: Mode gains g_i (the rigid body is a mode with frequency 0, damping 0).
        frequencies: Natural frequencies w_i [rad/s].
        dampings: Damping ratios z_i.
        lag_time_constant: First-order lag in front of the mechanics [s] (0: none).
        input_gain: Factor between the command and the mechanics (e.g. a torque-constant ratio).
        rigid_damping: Viscous damping of the first mode (the rigid body) [1/s]: its
            denominator becomes s^2 + rigid_damping s + w_0^2.

    Returns:
        ``(a, b, drive, c)``: system matrix, command input, the mechanics' input per unit of
        torque current (for disturbance currents added after the lag), output row.
    """
    off = 1 if lag_time_constant > 0 else 0
    n = off + 2 * len(gains)
    a = np.zeros((n, n))
    drive = np.zeros(n)
    c = np.zeros(n)
    for i, (k, w, z) in enumerate(zip(gains, frequencies, dampings, strict=True)):
        p, v = off + 2 * i, off + 2 * i + 1
        a[p, v] = 1.0
        a[v, p] = -w * w
        a[v, v] = -2 * z * w - (rigid_damping if i == 0 else 0.0)
        drive[v] = k
        c[p] = 1.0
    b = np.zeros(n)
    if off:
        a[0, 0] = -1.0 / lag_time_constant
        b[0] = 1.0 / lag_time_constant
        a[1:, 0] = input_gain * drive[1:]
    else:
        b = input_gain * drive
    return a, b, drive, c


def discretize(model: ModalModel, dynamics: InputDynamics,
               sample_period: float) -> DiscreteStateSpace:
    """Exact zero-order-hold discretisation of the plant including its input dynamics.

    The computation delay adds shift states; a dead time that is not a multiple of the
    sample period is handled exactly by splitting the hold interval.

    Args:
        model: Mechanical modal model.
        dynamics: Input delay and amplifier lag.
        sample_period: Sampling period [s].

    Returns:
        The discrete state space from command u[k] to angle y[k].
    """
    t = check_sample_period(sample_period)
    a_c, b_c, _, c_c = modal_state_space(
        gains=[model.k0, *model.residues], frequencies=[0.0, *model.natural_frequencies],
        dampings=[0.0, *model.damping_ratios], lag_time_constant=dynamics.lag_time_constant)
    n = a_c.shape[0]
    # Total pure delay D = (whole + frac) T: over [kT, (k+1)T) the plant sees u[k-whole-1]
    # for frac*T, then u[k-whole] for the rest of the period.
    whole, frac = split_delay(dynamics.pure_delay(t), t)
    phi, _ = zoh(a_c, b_c, t)
    phi_rest, gamma_rest = zoh(a_c, b_c, (1.0 - frac) * t)
    drives = {whole: gamma_rest}
    if frac > 0:
        drives[whole + 1] = phi_rest @ zoh(a_c, b_c, frac * t)[1]
    length = max(drives)  # shift register u[k-1] .. u[k-length]
    nd = n + length
    a = np.zeros((nd, nd))
    b = np.zeros(nd)
    a[:n, :n] = phi
    for lag_samples, g in drives.items():
        if lag_samples == 0:
            b[:n] = g
        else:
            a[:n, n + lag_samples - 1] = g
    if length:
        b[n] = 1.0
        for j in range(1, length):
            a[n + j, n + j - 1] = 1.0
    c = np.zeros(nd)
    c[:n] = c_c
    return DiscreteStateSpace(a=a, b=b, c=c)


def simulate(model: ModalModel, dynamics: InputDynamics, u: ArrayLike, *, sample_period: float,
             y0: float = 0.0) -> NDArray[np.float64]:
    """Simulate the plant open loop from rest at angle ``y0``.

    Args:
        model: Mechanical modal model.
        dynamics: Input delay and amplifier lag.
        u: Commanded current [A], shape (N,) or (M, N) for M records.
        sample_period: Sampling period [s].
        y0: Start angle [deg].

    Returns:
        The angle y [deg], same shape as ``u``.
    """
    u_arr = np.asarray(u, dtype=float)
    if u_arr.ndim not in (1, 2):
        raise InvalidDataError('u must be one record (N,) or records (M, N)')
    if not np.all(np.isfinite(u_arr)):
        raise InvalidDataError('u contains NaN or Inf')
    ss = discretize(model, dynamics, sample_period)
    records = np.atleast_2d(u_arr)
    x = np.zeros((ss.a.shape[0], records.shape[0]))
    y = np.empty_like(records)
    for k in range(records.shape[1]):
        y[:, k] = ss.c @ x
        x = ss.a @ x + np.outer(ss.b, records[:, k])
    y += y0
    return y.reshape(u_arr.shape)
