"""The dictionary of the discrepancy fallback: term laws shared by its fit and the simulation.

The fallback (:mod:`galvo_sysid.discrepancy.fallback`) fits an unexplained gap with a few of
these terms; the registry's ``proposed_terms`` effect (:mod:`galvo_sysid.model.effects`)
carries their coefficients into a model, and :class:`~galvo_sysid.model.physics.Physics`
simulates them, both with the laws of this one table.

A term is a function of the angle x [deg], velocity v [deg/s], acceleration a [deg/s^2] and
current i [A]. ``current`` terms act as an extra current on the mechanics (like the cogging
torque: it does not scale with ``gain_ratio``); ``reading`` terms are added to the encoder's
reading of the shaft angle x. Periodic terms are amplitude sin(2 pi x / P + phase) (current
side also times i). Each term has one parameter of the effect (its coefficient, zero: absent);
a periodic term three (``*_amplitude``, ``*_period`` [deg], ``*_phase`` [rad]).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ['PERIODIC_TERMS', 'TERMS', 'PeriodicTerm', 'Term', 'current_law', 'term_current',
           'term_reading', 'term_reading_slope']

_Law = Callable[..., Any]


@dataclass(frozen=True)
class Term:
    """One term of the dictionary.

    Attributes:
        parameter: Its coefficient's parameter name in the ``proposed_terms`` effect.
        side: ``current`` or ``reading``.
        expression: As the fallback reports it (``x^3``).
        law: ``law(x, v, a, i)``.
        unit: The coefficient's unit.
        slope: d law / dx of a reading term (for inverting the reading), else None.
    """

    parameter: str
    side: str
    expression: str
    law: _Law
    unit: str
    slope: _Law | None = None


@dataclass(frozen=True)
class PeriodicTerm:
    """A periodic family: amplitude sin(2 pi x / P + phase), current side times i if
    ``times_current``; parameters ``{prefix}_amplitude``, ``_period``, ``_phase``."""  # noqa: D205, D209

    prefix: str
    side: str
    expression: str
    unit: str
    times_current: bool = False


TERMS: tuple[Term, ...] = (
    Term('current_x', 'current', 'x', lambda x, v, a, i: x, 'A/deg'),
    Term('current_x_absx', 'current', 'x|x|', lambda x, v, a, i: x * np.abs(x), 'A/deg^2'),
    Term('current_x3', 'current', 'x^3', lambda x, v, a, i: x**3, 'A/deg^3'),
    Term('current_v', 'current', 'v', lambda x, v, a, i: v, 'A s/deg'),
    Term('current_v_absv', 'current', 'v|v|', lambda x, v, a, i: v * np.abs(v), 'A s^2/deg^2'),
    Term('current_sign_v', 'current', 'sign(v)', lambda x, v, a, i: np.sign(v), 'A'),
    Term('current_a', 'current', 'a', lambda x, v, a, i: a, 'A s^2/deg'),
    Term('current_i_absi', 'current', 'i|i|', lambda x, v, a, i: i * np.abs(i), '1/A'),
    Term('current_i3', 'current', 'i^3', lambda x, v, a, i: i**3, '1/A^2'),
    Term('reading_x', 'reading', 'x', lambda x, v, a, i: x, '1', lambda x: np.ones_like(x)),
    Term('reading_x2', 'reading', 'x^2', lambda x, v, a, i: x**2, '1/deg', lambda x: 2 * x),
    Term('reading_x_absx', 'reading', 'x|x|', lambda x, v, a, i: x * np.abs(x), '1/deg',
         lambda x: 2 * np.abs(x)),
    Term('reading_x3', 'reading', 'x^3', lambda x, v, a, i: x**3, '1/deg^2',
         lambda x: 3 * x**2),
)
"""The non-periodic terms, current side first."""

PERIODIC_TERMS: tuple[PeriodicTerm, ...] = (
    PeriodicTerm('current_sin', 'current', 'sin(2 pi x / P)', 'A'),
    PeriodicTerm('current_i_sin', 'current', 'i sin(2 pi x / P)', '1', times_current=True),
    PeriodicTerm('reading_sin', 'reading', 'sin(2 pi x / P)', 'deg'),
)
"""The periodic families (a sine and a cosine each in the fallback's fit)."""


def _wave(p: Mapping[str, float], prefix: str) -> tuple[float, float, float] | None:
    """(amplitude, 2 pi / period, phase) of a periodic family, or None if its amplitude is 0."""
    amp = p.get(f'{prefix}_amplitude', 0.0)
    if not amp:
        return None
    return amp, 2 * math.pi / p[f'{prefix}_period'], p.get(f'{prefix}_phase', 0.0)


def _periodic(p: Mapping[str, float], prefix: str,
              x: Any) -> tuple[float, float, Any] | None:
    """(amplitude, 2 pi / period, the sine's argument at x), or None if the amplitude is 0."""
    wave = _wave(p, prefix)
    return None if wave is None else (wave[0], wave[1], wave[1] * x + wave[2])


def term_current(p: Mapping[str, float], x: Any, v: Any, a: Any, i: Any) -> Any:
    """The extra current [A] of the terms ``p`` (parameter name: value; absent: zero)."""
    return current_law(p)(x, v, a, i)


def current_law(p: Mapping[str, float]) -> _Law:
    """:func:`term_current` of the terms ``p`` as ``law(x, v, a, i)``, the terms looked up
    once: for the simulations' loops over samples, which call it at every sample."""  # noqa: D205, D209
    laws = tuple((c, t.law) for t in TERMS
                 if t.side == 'current' and (c := p.get(t.parameter, 0.0)))
    waves = tuple((wave, f.times_current) for f in PERIODIC_TERMS if f.side == 'current'
                  and (wave := _wave(p, f.prefix)) is not None)

    def law(x: Any, v: Any, a: Any, i: Any) -> Any:
        out: Any = 0.0
        for c, term in laws:
            out = out + c * term(x, v, a, i)
        for (amp, k, phase), times_current in waves:
            out = out + amp * np.sin(k * x + phase) * (i if times_current else 1.0)
        return out

    return law


def term_reading(p: Mapping[str, float], x: Any) -> Any:
    """The reading's error [deg] of the terms ``p`` at the shaft angle x."""
    out: Any = np.zeros_like(x)
    for t in TERMS:
        c = p.get(t.parameter, 0.0)
        if c and t.side == 'reading':
            out = out + c * t.law(x, 0.0, 0.0, 0.0)
    per = _periodic(p, 'reading_sin', x)
    if per is not None:
        out = out + per[0] * np.sin(per[2])
    return out


def term_reading_slope(p: Mapping[str, float], x: Any) -> Any:
    """The slope of :func:`term_reading` in x."""
    out: Any = np.zeros_like(x)
    for t in TERMS:
        c = p.get(t.parameter, 0.0)
        if c and t.side == 'reading' and t.slope is not None:
            out = out + c * t.slope(x)
    per = _periodic(p, 'reading_sin', x)
    if per is not None:
        out = out + per[0] * per[1] * np.cos(per[2])
    return out
