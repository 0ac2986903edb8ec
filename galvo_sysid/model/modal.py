"""The galvano scanner plant: modal mechanics (paper Eq. 1) and the input dynamics.

The mechanical part is a rigid-body mode plus resonant modes::

    P_mech(s) = k0 / s^2 + sum_i k_i / (s^2 + 2 zeta_i omega_i s + omega_i^2)

from the commanded current u [A] to the motor-shaft angle y [deg]. Between the DSP's
current command and the torque sit the input dynamics: ``computation_delay`` whole sample
periods of DSP computation delay and the current amplifier's first-order lag with time
constant ``lag_time_constant``. The paper lumps both into an equivalent delay of 1.6 sample
periods (one sample plus a 0.6-sample lag).

This module holds the model types, the paper's reference values (Table I) and accuracy
(Table II), frequency responses, and the exact zero-order-hold discretisation used to
simulate the plant.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.linalg import expm

from galvo_sysid.errors import ConfigurationError, InvalidDataError

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import ArrayLike, NDArray

__all__ = [
    'PAPER_ANGLES',
    'PAPER_TABLE_II',
    'PSI',
    'REFERENCE_MODEL',
    'TAU',
    'DiscreteStateSpace',
    'InputDynamics',
    'ModalModel',
    'discretize',
    'modal_state_space',
    'relative_errors',
    'simulate',
]

TAU = 10e-6
"""Sampling period of the paper's DSP [s]."""

PSI = 0.3
"""The paper's unit rotation angle psi [deg]."""

PAPER_ANGLES: tuple[float, ...] = tuple(
    round(f * PSI, 10) for f in (*[i / 10 for i in range(1, 10)], *range(1, 11))
)
"""The 19 rotation angles of the paper's experiments, 0.1 psi ... 10 psi [deg]."""


@dataclass(frozen=True)
class ModalModel:
    """Rigid-body mode plus resonant modes (paper Eq. 1), modes in ascending frequency.

    Attributes:
        k0: Rigid-body gain [deg/(A s^2)].
        residues: Residues k_i of the resonant modes [deg/(A s^2)].
        natural_frequencies: Natural frequencies omega_i [rad/s].
        damping_ratios: Damping ratios zeta_i.
    """

    k0: float
    residues: tuple[float, ...]
    natural_frequencies: tuple[float, ...]
    damping_ratios: tuple[float, ...]

    def __post_init__(self) -> None:
        n = len(self.residues)
        if len(self.natural_frequencies) != n or len(self.damping_ratios) != n:
            msg = 'residues, natural_frequencies and damping_ratios must have equal lengths'
            raise ConfigurationError(msg)
        values = np.array([self.k0, *self.residues, *self.natural_frequencies,
                           *self.damping_ratios], dtype=float)
        if not np.all(np.isfinite(values)):
            raise ConfigurationError('modal parameters must be finite')
        if any(w <= 0 for w in self.natural_frequencies):
            raise ConfigurationError('natural frequencies must be positive')
        if any(z <= 0 for z in self.damping_ratios):
            raise ConfigurationError('damping ratios must be positive')

    @property
    def n_modes(self) -> int:
        """Number of resonant modes."""
        return len(self.residues)

    def parameters(self) -> dict[str, float]:
        """Return the parameters by name: k0, k1.., omega_1.., zeta_1.."""
        out = {'k0': float(self.k0)}
        for prefix, values in (('k', self.residues), ('omega_', self.natural_frequencies),
                               ('zeta_', self.damping_ratios)):
            for i, v in enumerate(values, start=1):
                out[f'{prefix}{i}'] = float(v)
        return out

    def frequency_response(self, omega: ArrayLike) -> NDArray[np.complex128]:
        """Return P_mech(j omega) at the angular frequencies ``omega`` [rad/s]."""
        s = 1j * np.asarray(omega, dtype=float)
        with np.errstate(divide='ignore', invalid='ignore'):
            h = self.k0 / s**2
        for k, w, z in zip(self.residues, self.natural_frequencies, self.damping_ratios,
                           strict=True):
            h = h + k / (s**2 + 2 * z * w * s + w**2)
        return np.asarray(h, dtype=np.complex128)


REFERENCE_MODEL = ModalModel(
    k0=3.564e6,
    residues=(2.069e6, -5.485e6, -4.604e5),
    natural_frequencies=(7.108e4, 1.193e5, 1.674e5),
    damping_ratios=(6.218e-3, 7.723e-3, 4.579e-3),
)
"""The paper's Table I: the servo-analyzer curve fit, regarded as the true plant."""

PAPER_TABLE_II: dict[str, dict[str, float]] = {
    'A': {'k0': -3.638, 'k1': 6.301, 'k2': -23.13, 'k3': 61.93, 'omega_1': 0.5523,
          'omega_2': 1.053, 'omega_3': 1.690, 'zeta_1': -9.581, 'zeta_2': -8.513,
          'zeta_3': 655.4},
    'B': {'k0': -3.583, 'k1': 0.8503, 'k2': -25.15, 'k3': -612.4, 'omega_1': 0.9544,
          'omega_2': 1.082, 'omega_3': 2.531, 'zeta_1': 136.2, 'zeta_2': 5.023,
          'zeta_3': 1216.0},
}
"""The paper's Table II: relative errors [%] of its identified model, methods A and B."""


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
    lag_time_constant: float = 0.6 * TAU
    dead_time: float = 0.0

    def __post_init__(self) -> None:
        if self.computation_delay < 0:
            raise ConfigurationError('computation_delay must be >= 0 samples')
        if not (np.isfinite(self.lag_time_constant) and self.lag_time_constant >= 0):
            raise ConfigurationError('lag_time_constant must be finite and >= 0')
        if not (np.isfinite(self.dead_time) and self.dead_time >= 0):
            raise ConfigurationError('dead_time must be finite and >= 0')

    def equivalent_delay(self, sample_period: float) -> float:
        """Return the low-frequency equivalent input delay [s]."""
        return self.computation_delay * sample_period + self.lag_time_constant + self.dead_time

    def frequency_response(self, omega: ArrayLike, sample_period: float) -> NDArray[np.complex128]:
        """Return the input dynamics' continuous-time frequency response at ``omega``."""
        w = np.asarray(omega, dtype=float)
        delay = self.computation_delay * sample_period + self.dead_time
        return np.asarray(np.exp(-1j * w * delay) / (1 + 1j * w * self.lag_time_constant),
                          dtype=np.complex128)


@dataclass(frozen=True)
class DiscreteStateSpace:
    """x[k+1] = a x[k] + b u[k], y[k] = c x[k]; the plant from command to encoder angle."""

    a: NDArray[np.float64]
    b: NDArray[np.float64]
    c: NDArray[np.float64]


def modal_state_space(*, gains: Sequence[float], frequencies: Sequence[float],
                      dampings: Sequence[float], lag_time_constant: float,
                      input_gain: float = 1.0) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                                         NDArray[np.float64], NDArray[np.float64]]:
    """Continuous state space of ``input_gain * lag(s) * sum_i g_i/(s^2 + 2 z_i w_i s + w_i^2)``.

    The states are the lag's output current first (if ``lag_time_constant`` > 0), then
    (position, velocity) per mode; the output is the sum of the mode positions.

    Args:
        gains: Mode gains g_i (the rigid body is a mode with frequency 0, damping 0).
        frequencies: Natural frequencies w_i [rad/s].
        dampings: Damping ratios z_i.
        lag_time_constant: First-order lag in front of the mechanics [s] (0: none).
        input_gain: Factor between the command and the mechanics (e.g. a torque-constant ratio).

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
        a[v, v] = -2 * z * w
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

    The computation delay adds ``computation_delay`` shift states; a dead time that is not a
    multiple of the sample period is handled exactly by splitting the hold interval.

    Args:
        model: Mechanical modal model.
        dynamics: Input delay and amplifier lag.
        sample_period: Sampling period [s].

    Returns:
        The discrete state space from command u[k] to angle y[k].
    """
    if not (np.isfinite(sample_period) and sample_period > 0):
        raise ConfigurationError('sample_period must be positive and finite')
    a_c, b_c, _, c_c = modal_state_space(
        gains=[model.k0, *model.residues], frequencies=[0.0, *model.natural_frequencies],
        dampings=[0.0, *model.damping_ratios], lag_time_constant=dynamics.lag_time_constant)
    n = a_c.shape[0]

    def zoh(t: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(Phi, Gamma) of a zero-order hold held for time t."""
        m = np.zeros((n + 1, n + 1))
        m[:n, :n] = a_c * t
        m[:n, n] = b_c * t
        e = expm(m)
        return e[:n, :n], e[:n, n]

    # Total pure delay D = (whole + frac) T: over [kT, (k+1)T) the plant sees u[k-whole-1]
    # for frac*T, then u[k-whole] for the rest of the period.
    whole_f, frac = divmod(dynamics.computation_delay * sample_period + dynamics.dead_time,
                           sample_period)
    whole = round(whole_f)
    eps = 1e-9 * sample_period
    frac_t = frac if eps < frac < sample_period - eps else 0.0
    if frac >= sample_period - eps:  # rounding left a whole period in frac
        whole += 1
    phi, _ = zoh(sample_period)
    phi_rest, gamma_rest = zoh(sample_period - frac_t)
    drives = {whole: gamma_rest}
    if frac_t > 0:
        drives[whole + 1] = phi_rest @ zoh(frac_t)[1]
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


def relative_errors(identified: ModalModel,
                    reference: ModalModel = REFERENCE_MODEL) -> dict[str, float]:
    """Return (identified - reference) / reference for every parameter, by name."""
    ref = reference.parameters()
    ident = identified.parameters()
    if ref.keys() != ident.keys():
        raise ConfigurationError('models have different numbers of modes')
    return {name: (ident[name] - ref[name]) / ref[name] for name in ref}
