"""Input-delay models and the paper's fictitious identification input.

Between the DSP's current command u[k] and the motor torque sit one sample of computation
delay and the current amplifier's first-order lag; the paper lumps both into an equivalent
delay of 1.6 sample periods and removes it from the data before the fit (its Sec. V-B, Fig. 9)
by filtering the input::

    u~[k] = P_delay[z] u[k],   P_delay[z] = Tustin{Pade_3(exp(-0.6 tau s))} z^-1

This module builds such filters as discrete transfer functions ``(b, a)`` in powers of z^-1
(the :func:`scipy.signal.lfilter` convention):

- :func:`pade_delay_filter`: any total delay D >= 0 as ``z^-m`` times the Tustin
  (bilinear) transform of the Pade approximation of the fractional rest (the paper's filter
  for D = 1.6 tau);
- :func:`lag_delay_filter`: the physical alternative, whole samples of computation delay times
  a discretised first-order lag 1/(T_lag s + 1), either by zero-order hold (``'zoh'``) or by the
  interval average (``'average'``, the mean of the lag's output over each sample period, which
  is what a zero-order-hold model of the mechanics should be driven by);
- :func:`fictitious_input`: the filter applied to records from rest;
- :func:`estimate_delay`: the equivalent delay estimated from data instead of the paper's
  "trial and error".
"""

from __future__ import annotations

from dataclasses import dataclass
from math import factorial
from typing import TYPE_CHECKING

import numpy as np
from scipy.optimize import minimize_scalar

from galvo_sysid.errors import ConfigurationError, IdentificationError, InvalidDataError
from galvo_sysid.filters import bilinear, lfilter
from galvo_sysid.ident.arx import fit_arx
from galvo_sysid.model import REFERENCE_MODEL, ModalModel

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import ArrayLike, NDArray

__all__ = [
    'DelayEstimate',
    'estimate_delay',
    'fictitious_input',
    'lag_delay_filter',
    'pade_coefficients',
    'pade_delay_filter',
    'paper_delay_filter',
]

Filter = tuple['NDArray[np.float64]', 'NDArray[np.float64]']


_MAX_DELAY_SAMPLES = 1_000_000
"""Longest delay a filter is built for [samples] (a longer one is a unit mistake)."""


def _check_period(sample_period: float) -> None:
    if not (np.isfinite(sample_period) and sample_period > 0):
        raise ConfigurationError(f'sample_period must be positive and finite, got {sample_period}')


def pade_coefficients(delay: float, order: int = 3) -> Filter:
    """Return the [order/order] Pade approximation of exp(-delay s).

    Args:
        delay: The delay [s], >= 0.
        order: Numerator and denominator degree, 1..10.

    Returns:
        ``(num, den)`` polynomial coefficients in descending powers of s, ``den[-1] == 1``.
    """
    if not (np.isfinite(delay) and delay >= 0):
        raise ConfigurationError(f'delay must be finite and >= 0, got {delay}')
    if not 1 <= order <= 10:
        raise ConfigurationError(f'pade order must be 1..10, got {order}')
    n = order
    # c_k = (2n - k)! n! / ((2n)! k! (n - k)!)
    # den = sum c_k (delay s)^k, num = sum c_k (-delay s)^k
    c = np.array([factorial(2 * n - k) * factorial(n) / (factorial(2 * n) * factorial(k)
                                                         * factorial(n - k)) for k in range(n + 1)])
    powers = delay ** np.arange(n + 1)
    den = (c * powers)[::-1]
    num = (c * powers * (-1.0) ** np.arange(n + 1))[::-1]
    return np.asarray(num, dtype=float), np.asarray(den, dtype=float)


def pade_delay_filter(delay: float, *, sample_period: float, order: int = 3) -> Filter:
    """Discrete filter for a total delay D = m T + d, 0 <= d < T: z^-m Tustin{Pade(exp(-d s))}.

    Args:
        delay: Total delay D [s], >= 0.
        sample_period: Sample period T [s].
        order: Pade order for the fractional part.

    Returns:
        ``(b, a)`` in powers of z^-1 (scipy.signal.lfilter convention), ``a[0] == 1``.
    """
    _check_period(sample_period)
    if not (np.isfinite(delay) and delay >= 0):
        raise ConfigurationError(f'delay must be finite and >= 0, got {delay}')
    if not 1 <= order <= 10:
        raise ConfigurationError(f'pade order must be 1..10, got {order}')
    whole_f, frac = divmod(delay, sample_period)
    if not whole_f <= _MAX_DELAY_SAMPLES:
        raise ConfigurationError(f'delay {delay:g} s is more than {_MAX_DELAY_SAMPLES} sample '
                                 f'periods of {sample_period:g} s')
    whole = round(whole_f)
    eps = 1e-9 * sample_period
    if frac >= sample_period - eps:
        whole, frac = whole + 1, 0.0
    if frac <= eps:
        b = np.zeros(whole + 1)
        b[-1] = 1.0
        return b, np.ones(1)
    num, den = pade_coefficients(frac, order)
    bz, az = bilinear(num, den, fs=1.0 / sample_period)
    bz = np.asarray(bz, dtype=float) / az[0]
    az = np.asarray(az, dtype=float) / az[0]
    return np.concatenate([np.zeros(whole), bz]), az


def paper_delay_filter(*, sample_period: float, delay: float | None = None,
                       order: int = 3) -> Filter:
    """The paper's P_delay[z]: Tustin of the 3rd-order Pade of exp(-0.6 T s), times z^-1.

    Args:
        sample_period: Sample period T [s].
        delay: Total equivalent delay [s]; default 1.6 T (the paper's value).
        order: Pade order.

    Returns:
        ``(b, a)`` in powers of z^-1.
    """
    _check_period(sample_period)
    return pade_delay_filter(1.6 * sample_period if delay is None else delay,
                             sample_period=sample_period, order=order)


def lag_delay_filter(*, sample_period: float, lag_time_constant: float,
                     computation_delay: int = 1, discretization: str = 'zoh',
                     prewarp: float | None = None) -> Filter:
    """Computation delay z^-d times a discretised first-order lag L(s) = 1/(T_lag s + 1).

    Discretisations of the lag:

    - ``'zoh'``: zero-order hold, (1 - p) z^-1 / (1 - p z^-1), p = exp(-T/T_lag): the lag's
      output sampled at the sample instants. Fed as a held input to a zero-order-hold model of
      the mechanics it acts about half a sample late (its low-frequency delay is T/(1 - p),
      not T_lag).
    - ``'average'``: the mean of the lag's output over each sample period,
      u~[k] = c v[k] + (1 - c) u[k] with v the sampled lag output and c = (T_lag/T)(1 - p);
      its low-frequency delay is exactly T_lag.
    - ``'tustin'``: the bilinear transform, prewarped to match L exactly at ``prewarp``
      [rad/s] if given.

    What the fit of a mode at frequency w needs is F(e^{j w T}) = e^{-j w d T} L(j w) at that w
    (the mode's residue is scaled by the ratio); none of these is exact at every mode.

    Args:
        sample_period: Sample period T [s].
        lag_time_constant: T_lag [s], >= 0 (0: no lag).
        computation_delay: Whole samples of computation delay d, >= 0.
        discretization: ``'zoh'``, ``'average'`` or ``'tustin'``.
        prewarp: Prewarp frequency [rad/s] for ``'tustin'``, below pi/T.

    Returns:
        ``(b, a)`` in powers of z^-1.
    """
    _check_period(sample_period)
    if not (np.isfinite(lag_time_constant) and lag_time_constant >= 0):
        raise ConfigurationError(f'lag_time_constant must be finite and >= 0, '
                                 f'got {lag_time_constant}')
    if computation_delay < 0:
        raise ConfigurationError(f'computation_delay must be >= 0, got {computation_delay}')
    if discretization not in ('zoh', 'average', 'tustin'):
        raise ConfigurationError(f"discretization must be 'zoh', 'average' or 'tustin', "
                                 f'got {discretization!r}')
    if prewarp is not None and not 0 < prewarp < np.pi / sample_period:
        raise ConfigurationError(f'prewarp must be in (0, pi/T), got {prewarp}')
    shift = np.zeros(computation_delay)
    if lag_time_constant == 0:
        return np.concatenate([shift, [1.0]]), np.ones(1)
    p = float(np.exp(-sample_period / lag_time_constant))
    if discretization == 'zoh':
        b, a = np.array([0.0, 1.0 - p]), np.array([1.0, -p])
    elif discretization == 'average':
        c = lag_time_constant / sample_period * (1.0 - p)
        # c (1 - p) z^-1 / (1 - p z^-1) + (1 - c)
        b = np.array([1.0 - c, c * (1.0 - p) - (1.0 - c) * p])
        a = np.array([1.0, -p])
    else:
        fs = (1.0 / sample_period if prewarp is None
              else prewarp / (2.0 * np.tan(prewarp * sample_period / 2.0)))
        bz, az = bilinear([1.0], [lag_time_constant, 1.0], fs=fs)
        b = np.asarray(bz, dtype=float) / az[0]
        a = np.asarray(az, dtype=float) / az[0]
    return np.concatenate([shift, b]), a


def fictitious_input(u: ArrayLike, b: ArrayLike, a: ArrayLike) -> NDArray[np.float64]:
    """Apply the delay filter ``b / a`` along the last axis, from rest (paper Fig. 9).

    Args:
        u: Input record (N,) or records (M, N).
        b: Filter numerator in powers of z^-1.
        a: Filter denominator in powers of z^-1, ``a[0] != 0``.

    Returns:
        The fictitious input u~, same shape as ``u``.
    """
    u_arr = np.asarray(u, dtype=float)
    if u_arr.ndim == 0 or u_arr.shape[-1] == 0:
        raise InvalidDataError('u must hold at least one sample along its last axis')
    if not np.all(np.isfinite(u_arr)):
        raise InvalidDataError('u contains NaN or Inf')
    b_arr = np.atleast_1d(np.asarray(b, dtype=float))
    a_arr = np.atleast_1d(np.asarray(a, dtype=float))
    if b_arr.ndim != 1 or a_arr.ndim != 1 or a_arr[0] == 0:
        raise ConfigurationError('filter must be 1-D (b, a) with a[0] != 0')
    return np.asarray(lfilter(b_arr, a_arr, u_arr), dtype=float)


@dataclass(frozen=True)
class DelayEstimate:
    """Result of :func:`estimate_delay`.

    Attributes:
        delay: Estimated equivalent input delay [s].
        cost: Mean of sin^2 of the residual phase over the evaluation frequencies.
        n_frequencies: Number of frequencies the cost was evaluated at.
    """

    delay: float
    cost: float
    n_frequencies: int


def estimate_delay(u: ArrayLike, y: ArrayLike, *, sample_period: float, na: int = 15,
                   nb: int = 15, bands: Sequence[tuple[float, float]] | None = None,
                   search: tuple[float, float] | None = None, n_points: int = 200,
                   reference: ModalModel = REFERENCE_MODEL,
                   max_cost: float = 0.05) -> DelayEstimate:
    """Estimate the equivalent input delay from one pre-processed input/output pair.

    The paper's reasoning (Sec. V-A), made a criterion: fit an ARX model to the raw input
    (no delay removed); away from the resonances the mechanical phase is a multiple of 180 deg,
    so the delay D is the one that makes the phase of ``H(e^{j w T}) e^{j w (D + T/2)}`` closest
    to a multiple of 180 deg, i.e. minimises the mean of ``sin^2`` of that phase over
    frequencies in ``bands``. The extra T/2 is the zero-order hold's own half-sample delay
    (exact for the rigid-body mode, whose ZOH response has phase -180 deg - w T / 2).

    Args:
        u: Input (e.g. the method-A average of the current records), shape (N,).
        y: Output (start angle removed), shape (N,).
        sample_period: Sample period T [s].
        na: ARX denominator order.
        nb: ARX numerator order.
        bands: Angular-frequency bands [rad/s] to evaluate the phase in; default below the
            reference model's first resonance, 0.05 .. 0.5 omega_1 (where the moves excite the
            plant well and nothing resonates; bands between the modes are spoilt by the
            anti-resonances and, for an amplifier lag, by its non-delay-like phase).
        search: Delay search interval [s]; default 0 .. 4 T.
        n_points: Frequencies per band.
        reference: Model whose first natural frequency sets the default band.
        max_cost: Largest acceptable cost (0.05: an RMS residual phase of about 13 deg);
            above it no delay explains the phase and the estimate is refused.

    Returns:
        The estimate with its cost.

    Raises:
        IdentificationError: The best cost exceeds ``max_cost`` (the data do not look like
            mechanics behind a delay in ``bands``), or the ARX response is degenerate.
    """
    _check_period(sample_period)
    lo, hi = (0.0, 4.0 * sample_period) if search is None else search
    if not (0 <= lo < hi and np.isfinite(hi)):
        raise ConfigurationError(f'search interval must satisfy 0 <= lo < hi, got {search}')
    if bands is None:
        if not reference.natural_frequencies:
            raise ConfigurationError('reference model has no resonant mode; give bands')
        w1 = reference.natural_frequencies[0]
        band_list: tuple[tuple[float, float], ...] = ((0.05 * w1, 0.5 * w1),)
    else:
        band_list = tuple(bands)
    nyquist = np.pi / sample_period
    omegas = []
    for w_lo, w_hi in band_list:
        if not (0 < w_lo < w_hi <= nyquist):
            raise ConfigurationError(f'band ({w_lo}, {w_hi}) must lie in (0, pi/T]')
        omegas.append(np.geomspace(w_lo, w_hi, n_points))
    omega = np.concatenate(omegas)
    model = fit_arx(u, y, na=na, nb=nb, sample_period=sample_period)
    h = model.frequency_response(omega)
    if not np.all(np.isfinite(h)) or np.any(h == 0):
        raise IdentificationError('ARX frequency response is degenerate; cannot estimate delay')
    phase = np.angle(h)

    def cost(d: float) -> float:
        return float(np.mean(np.sin(phase + omega * (d + 0.5 * sample_period)) ** 2))

    grid = np.linspace(lo, hi, 161)
    costs = np.array([cost(d) for d in grid])
    i = int(np.argmin(costs))
    a_, b_ = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    res = minimize_scalar(cost, bounds=(a_, b_), method='bounded',
                          options={'xatol': 1e-4 * sample_period})
    d_best = float(res.x) if res.fun <= costs[i] else float(grid[i])
    best = cost(d_best)
    if not best <= max_cost:
        raise IdentificationError(f'no delay in {lo:.3g} .. {hi:.3g} s makes the phase a multiple '
                                  f'of 180 deg (cost {best:.3g} > {max_cost:.3g})')
    return DelayEstimate(delay=d_best, cost=best, n_frequencies=omega.size)
