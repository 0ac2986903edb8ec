"""A coil current measured when the encoder is read, made into the held current that drives it.

The model takes the current the DSP commands, held over each sample period behind the
computation delay and the amplifier's first-order lag. A coil current *measured* at the
instant the encoder is read is the lag's output instead: over sample k it flows as
``v_k + (i_k - v_k) exp(-s / lag)``, so the held input behind it is

    v_k = (i_{k+1} - a i_k) / (1 - a),   a = exp(-T / lag)

(:func:`held_current`; no lag: the next reading). Fed with ``v`` the model holds exactly,
behind no computation delay and the same lag. The lag must be known: from the amplifier's
data sheet (``1 / (2 pi f_c)``, f_c its current-loop bandwidth), or found from the data
(:func:`search_lag`): the fit of the held current estimates a lag of its own, which equals
the lag the held current was made with only at the true one (made with a smaller lag, the
held current still carries part of the lag, and the fit finds a lag between the two).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from galvo_sysid.errors import ConfigurationError, InvalidDataError

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from numpy.typing import ArrayLike, NDArray

__all__ = ['LAG_TOLERANCE', 'MAX_LAG_SAMPLES', 'LagSearch', 'check_lag', 'held_current',
           'held_windows', 'search_lag']

MAX_LAG_SAMPLES = 20.0
"""Largest amplifier lag of a measured current [sample periods]: beyond it the held
current's reconstruction multiplies the current sensor's noise by over 20."""

LAG_TOLERANCE = 1e-3
"""The lag search ends when the fitted and the assumed lag agree this well [sample periods]."""

_MAX_STEPS = 12


def check_lag(lag: float, sample_period: float | None = None) -> float:
    """``lag`` [s] as a float, if it is a usable amplifier lag of a measured current.

    Raises:
        ConfigurationError: Negative, not finite, not a number, or above
            :data:`MAX_LAG_SAMPLES` sample periods (when ``sample_period`` is given).
    """
    if isinstance(lag, bool) or not isinstance(lag, (int, float)) or not math.isfinite(lag) \
            or lag < 0:
        msg = f'the amplifier lag of a measured current must be a time >= 0 [s], got {lag!r}'
        raise ConfigurationError(msg)
    if sample_period is not None and lag > MAX_LAG_SAMPLES * sample_period:
        msg = (f'an amplifier lag of {lag:.3g} s is {lag / sample_period:.3g} sample periods: '
               f'above {MAX_LAG_SAMPLES:g}, turning the measured current into the held one '
               f'would multiply its noise by over {1 / -math.expm1(-1 / MAX_LAG_SAMPLES):.0f}')
        raise ConfigurationError(msg)
    return float(lag)


def held_current(current: ArrayLike, *, sample_period: float,
                 lag: float) -> NDArray[np.float64]:
    """The held current behind a measured one, along the last axis (one sample shorter).

    Args:
        current: Coil current read at the encoder's instants [A], (..., N).
        sample_period: Sampling period [s].
        lag: The amplifier's lag time constant [s] (0: none).

    Raises:
        ConfigurationError: A bad lag (:func:`check_lag`).
        InvalidDataError: Fewer than 2 samples.
    """
    lag = check_lag(lag, sample_period)
    i = np.asarray(current, dtype=float)
    if i.ndim < 1 or i.shape[-1] < 2:
        raise InvalidDataError(f'a measured current needs 2 samples or more, got shape '
                               f'{i.shape}')
    a = math.exp(-sample_period / lag) if lag > 0 else 0.0
    return np.asarray((i[..., 1:] - a * i[..., :-1]) / (1.0 - a), dtype=np.float64)


def held_windows(windows: Sequence[tuple[ArrayLike, ArrayLike]], *, sample_period: float,
                 lag: float) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """``(held current, encoder)`` of each ``(measured current, encoder)`` window: the held
    current (:func:`held_current`) against the encoder's samples but the last."""  # noqa: D205, D209
    return [(held_current(cur, sample_period=sample_period, lag=lag),
             np.asarray(enc, dtype=float)[..., :-1]) for cur, enc in windows]


@dataclass(frozen=True)
class LagSearch:
    """How :func:`search_lag` found the amplifier lag.

    Attributes:
        lag: The lag the held current is made with [s].
        steps: ``(assumed lag, lag the fit found)`` of each step [s].
        converged: The two agree within :data:`LAG_TOLERANCE` at ``lag`` (else ``lag`` is
            the last step's, at a bound or after the most steps).
    """

    lag: float
    steps: tuple[tuple[float, float], ...]
    converged: bool


def search_lag(fitted_lag: Callable[[float], float], *, sample_period: float,
               upper: float, first: tuple[float, float] | None = None) -> LagSearch:
    """The lag at which the held current's fit finds the lag it was made with.

    Secant steps on ``g(lag) = fitted_lag(lag) - lag`` from 0 (the held current is then the
    next reading), kept within ``[0, upper]``; where the secant's slope is not one ``g`` can
    have (between -2 and -0.05), a fixed-point step (the lag the fit found) instead.

    Args:
        fitted_lag: The lag [s] a fit of the held current made with the given lag [s] finds.
        sample_period: Sampling period [s] (the tolerance's unit).
        upper: Largest lag looked at [s].
        first: ``(0, fitted_lag(0))`` if already known.

    Returns:
        The lag and the steps to it.
    """
    t = sample_period
    x0, f0 = first if first is not None else (0.0, fitted_lag(0.0))
    steps = [(x0, f0)]
    g0 = f0 - x0
    x1 = min(max(f0, 0.0), upper)
    for _ in range(_MAX_STEPS):
        f1 = fitted_lag(x1)
        steps.append((x1, f1))
        g1 = f1 - x1
        if abs(g1) <= LAG_TOLERANCE * t:
            return LagSearch(lag=x1, steps=tuple(steps), converged=True)
        # g falls with the lag, by less than one per lag (the fit's lag lies between the
        # assumed one and the truth); a slope outside that is noise: a fixed-point step
        slope = (g1 - g0) / (x1 - x0) if x1 != x0 else 0.0
        x2 = x1 - g1 / slope if -2.0 < slope < -0.05 else x1 + g1
        x2 = min(max(x2, 0.0), upper)
        if x2 == x1:  # held at a bound
            break
        x0, g0, x1 = x1, g1, x2
    return LagSearch(lag=x1, steps=tuple(steps), converged=False)
