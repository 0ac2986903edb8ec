"""Plant changes over time: a parameter drifting or stepping, evaluated move by move.

:class:`Drift` and :class:`StepChange` act on any parameter of the running plant by name
(:meth:`galvo_sysid.model.physics.Physics.parameters`: ``k0``, ``k1``.., ``omega_1``..,
``zeta_1``.. and :data:`~galvo_sysid.model.physics.PHYSICAL_PARAMETERS`: ``lag_time_constant``,
``dead_time``, ``friction_current``, ``pivot_frequency``, ``gain_ratio``, ``current_limit``,
``viscous_coefficient``, the cogging's and the encoder error's amplitude, period and phase)
and are evaluated at the start of each move by :func:`plant_at`: the plant is piecewise
constant, one value per move.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model.physics import Physics, check_parameter_name

__all__ = ['UNITS', 'Drift', 'StepChange', 'plant_at']

UNITS = ('second', 'move')
"""Units of the time of a change: seconds of scanner time, or moves."""


def _finite(name: str, value: float, *, minimum: float | None = None) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ConfigurationError(f'{name} must be finite, got {value!r}')
    if minimum is not None and value < minimum:
        raise ConfigurationError(f'{name} must be >= {minimum}, got {value!r}')


@dataclass(frozen=True)
class Drift:
    """A parameter drifting linearly from ``start`` on.

    With ``relative`` the value is p * (1 + rate * (t - start)) (e.g. rate = -0.01 per second
    is omega_1 falling 1 % per second), otherwise p + rate * (t - start). t counts seconds of
    simulated time or moves, by ``unit``.

    Attributes:
        parameter: Name from :meth:`Physics.parameters`.
        rate: Change per unit (relative or absolute).
        unit: ``'second'`` or ``'move'``.
        start: When the drift starts (seconds or move index).
        relative: Relative (default) or absolute rate.
    """

    parameter: str
    rate: float
    unit: str = 'second'
    start: float = 0.0
    relative: bool = True

    def __post_init__(self) -> None:
        _finite('rate', self.rate)
        _finite('start', self.start, minimum=0.0)
        if self.unit not in UNITS:
            raise ConfigurationError(f'unit must be one of {UNITS}, got {self.unit!r}')
        check_parameter_name(self.parameter)


@dataclass(frozen=True)
class StepChange:
    """A parameter jumping at ``at`` (seconds or move index, by ``unit``).

    Attributes:
        parameter: Name from :meth:`Physics.parameters`.
        value: The new value, or the factor applied to the old one if ``relative``.
        at: When (seconds or move index); the move starting at or after it has the new value.
        unit: ``'second'`` or ``'move'``.
        relative: Whether ``value`` is a factor.
    """

    parameter: str
    value: float
    at: float
    unit: str = 'move'
    relative: bool = False

    def __post_init__(self) -> None:
        _finite('value', self.value)
        _finite('at', self.at, minimum=0.0)
        if self.unit not in UNITS:
            raise ConfigurationError(f'unit must be one of {UNITS}, got {self.unit!r}')
        check_parameter_name(self.parameter)



def plant_at(base: Physics, *, time: float, move: int, drifts: Sequence[Drift] = (),
             steps: Sequence[StepChange] = ()) -> Physics:
    """Return the plant a move starting at ``time`` [s] (move index ``move``) runs on.

    Steps that are due apply first, in the order of their time, then drifts multiply (or add
    to) the result.
    """
    spec = base
    due = [s for s in steps if (time if s.unit == 'second' else move) >= s.at]
    for s in sorted(due, key=lambda s: s.at):
        old = spec.parameters().get(s.parameter, math.nan)
        spec = spec.with_parameter(s.parameter, old * s.value if s.relative else s.value)
    for d in drifts:
        t = (time if d.unit == 'second' else move) - d.start
        if t <= 0:
            continue
        old = spec.parameters().get(d.parameter, math.nan)
        spec = spec.with_parameter(
            d.parameter, old * (1 + d.rate * t) if d.relative else old + d.rate * t)
    return spec

