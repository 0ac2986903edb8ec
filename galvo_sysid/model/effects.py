"""The simulated plant with its physical effects, and plant changes over time.

:class:`PlantSpec` is the truth the simulator runs: the modal model (paper Eq. 1), the input
dynamics (computation delay + amplifier lag) and :class:`PlantEffects`, the physical effects
the discrepancy workflow must be able to find (issue 6):

- ``input_delay``: extra dead time ``dead_time`` [s] (the effect's ``delay`` parameter is the
  total equivalent input delay, nominally 1.6 tau; see :meth:`PlantEffects.with_effect`),
- ``unmodeled_resonance``: extra modes k / (s^2 + 2 zeta omega s + omega^2),
- ``coulomb_friction``: a torque opposing the rotor's velocity, as an equivalent current
  ``friction_current`` [A] (at the nominal torque constant),
- ``pivot_stiffness``: the rigid body k0/s^2 becomes k0/(s^2 + w_p^2),
  ``pivot_frequency`` = w_p [rad/s],
- ``gain_change``: the torque constant relative to the model, ``gain_ratio``, multiplying
  every mode's gain (the friction current is not scaled: it is a torque),
- ``current_saturation``: the amplifier's output current clipped at ``current_limit`` [A].

Signal chain of the simulated plant (the DSP's command u is what gets recorded)::

    u --delay--> amplifier lag --> clip(., +-limit) --> + current noise --> * gain_ratio
      --> - friction --> P_mech (+ extra modes, pivot) --> shaft angle y

Friction opposes the velocity of the rigid-body coordinate (the mean rotation of rotor and
mirror). The fitted Table I modes have a negative sum of residues (the high-frequency
acceleration per current is negative), so feeding friction from the total encoder velocity
would make it a non-physical positive feedback at the resonances.

Plant changes (:class:`Drift`, :class:`StepChange`) act on any parameter by name (see
:meth:`PlantSpec.parameters`) and are evaluated at the start of each move by
:func:`plant_at`: the plant is piecewise constant, one value per move.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.linalg import matrix_balance

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model.modal import (
    REFERENCE_MODEL,
    TAU,
    InputDynamics,
    ModalModel,
    modal_state_space,
)

if TYPE_CHECKING:
    from numpy.typing import NDArray

__all__ = [
    'EFFECT_NAMES',
    'ContinuousPlant',
    'Drift',
    'PlantEffects',
    'PlantSpec',
    'Resonance',
    'SampledPlant',
    'StepChange',
    'continuous_plant',
    'expm_balanced',
    'plant_at',
    'sample_plant',
]

EFFECT_NAMES: tuple[str, ...] = ('input_delay', 'unmodeled_resonance', 'coulomb_friction',
                                 'pivot_stiffness', 'gain_change', 'current_saturation')
"""Effect names of the discrepancy workflow's JSON contract (besides ``none``)."""


def _finite(name: str, value: float, *, minimum: float | None = None,
            positive: bool = False) -> None:
    if not math.isfinite(value):
        raise ConfigurationError(f'{name} must be finite, got {value!r}')
    if positive and value <= 0:
        raise ConfigurationError(f'{name} must be positive, got {value!r}')
    if minimum is not None and value < minimum:
        raise ConfigurationError(f'{name} must be >= {minimum}, got {value!r}')


@dataclass(frozen=True)
class Resonance:
    """An unmodelled resonant mode k / (s^2 + 2 zeta omega s + omega^2).

    Attributes:
        natural_frequency: omega [rad/s].
        damping_ratio: zeta.
        residue: k [deg/(A s^2)].
    """

    natural_frequency: float
    damping_ratio: float
    residue: float

    def __post_init__(self) -> None:
        _finite('natural_frequency', self.natural_frequency, positive=True)
        _finite('damping_ratio', self.damping_ratio, positive=True)
        _finite('residue', self.residue)


@dataclass(frozen=True)
class PlantEffects:
    """Physical effects added to the modal plant; the defaults change nothing.

    Attributes:
        dead_time: Extra pure input delay [s].
        resonances: Unmodelled resonant modes.
        friction_current: Coulomb friction as an equivalent current [A].
        pivot_frequency: Pivot (spring) natural frequency w_p of the rigid body [rad/s].
        gain_ratio: Torque constant relative to the model.
        current_limit: Amplifier output current limit [A] (inf: none).
    """

    dead_time: float = 0.0
    resonances: tuple[Resonance, ...] = ()
    friction_current: float = 0.0
    pivot_frequency: float = 0.0
    gain_ratio: float = 1.0
    current_limit: float = math.inf

    def __post_init__(self) -> None:
        _finite('dead_time', self.dead_time, minimum=0.0)
        _finite('friction_current', self.friction_current, minimum=0.0)
        _finite('pivot_frequency', self.pivot_frequency, minimum=0.0)
        _finite('gain_ratio', self.gain_ratio, positive=True)
        if math.isnan(self.current_limit) or self.current_limit <= 0:
            raise ConfigurationError(
                f'current_limit must be positive (inf for none), got {self.current_limit!r}')
        if not all(isinstance(r, Resonance) for r in self.resonances):
            raise ConfigurationError('resonances must be Resonance instances')

    @property
    def is_linear(self) -> bool:
        """True without friction and saturation (the closed loop is then linear)."""
        return self.friction_current == 0 and math.isinf(self.current_limit)

    def with_effect(self, name: str, parameters: Mapping[str, float], *,
                    dynamics: InputDynamics | None = None,
                    sample_period: float = TAU) -> PlantEffects:
        """Return a copy with one effect set, by its issue-6 name and parameters.

        Args:
            name: One of :data:`EFFECT_NAMES`.
            parameters: The effect's parameters, e.g. ``{'friction_current': 0.01}``.
            dynamics: Input dynamics the total ``delay`` of ``input_delay`` refers to.
            sample_period: Sampling period [s] (for that total delay).

        Returns:
            The new effects (an unmodelled resonance is added to those present).
        """
        expected = {
            'input_delay': {'delay'},
            'unmodeled_resonance': {'natural_frequency', 'damping_ratio', 'residue'},
            'coulomb_friction': {'friction_current'},
            'pivot_stiffness': {'natural_frequency'},
            'gain_change': {'gain_ratio'},
            'current_saturation': {'current_limit'},
        }
        if name not in expected:
            raise ConfigurationError(f'unknown effect {name!r}; expected one of {EFFECT_NAMES}')
        if set(parameters) != expected[name]:
            raise ConfigurationError(
                f'effect {name!r} takes parameters {sorted(expected[name])}, '
                f'got {sorted(parameters)}')
        p = {k: float(v) for k, v in parameters.items()}
        if name == 'input_delay':
            nominal = (dynamics or InputDynamics()).equivalent_delay(sample_period)
            extra = p['delay'] - nominal
            if extra < -1e-12 * sample_period:
                raise ConfigurationError(
                    f'delay {p["delay"]!r} s is below the nominal equivalent delay {nominal!r} s')
            return replace(self, dead_time=max(extra, 0.0))
        if name == 'unmodeled_resonance':
            return replace(self, resonances=(*self.resonances, Resonance(**p)))
        if name == 'coulomb_friction':
            return replace(self, friction_current=p['friction_current'])
        if name == 'pivot_stiffness':
            return replace(self, pivot_frequency=p['natural_frequency'])
        if name == 'gain_change':
            return replace(self, gain_ratio=p['gain_ratio'])
        return replace(self, current_limit=p['current_limit'])

    def to_list(self, *, dynamics: InputDynamics | None = None,
                sample_period: float = TAU) -> list[dict[str, Any]]:
        """Return the active effects as ``[{'effect': name, 'parameters': {...}}, ...]``."""
        out: list[dict[str, Any]] = []
        if self.dead_time > 0:
            nominal = (dynamics or InputDynamics()).equivalent_delay(sample_period)
            out.append({'effect': 'input_delay',
                        'parameters': {'delay': nominal + self.dead_time}})
        out.extend({'effect': 'unmodeled_resonance',
                    'parameters': {'natural_frequency': r.natural_frequency,
                                   'damping_ratio': r.damping_ratio, 'residue': r.residue}}
                   for r in self.resonances)
        if self.friction_current > 0:
            out.append({'effect': 'coulomb_friction',
                        'parameters': {'friction_current': self.friction_current}})
        if self.pivot_frequency > 0:
            out.append({'effect': 'pivot_stiffness',
                        'parameters': {'natural_frequency': self.pivot_frequency}})
        if self.gain_ratio != 1:
            out.append({'effect': 'gain_change', 'parameters': {'gain_ratio': self.gain_ratio}})
        if math.isfinite(self.current_limit):
            out.append({'effect': 'current_saturation',
                        'parameters': {'current_limit': self.current_limit}})
        return out

    @classmethod
    def from_list(cls, items: Sequence[Mapping[str, Any]], *,
                  dynamics: InputDynamics | None = None,
                  sample_period: float = TAU) -> PlantEffects:
        """Build effects from ``[{'effect': name, 'parameters': {...}}, ...]``."""
        effects = cls()
        for item in items:
            try:
                name, params = item['effect'], item['parameters']
            except (KeyError, TypeError) as err:
                raise ConfigurationError(
                    "each effect needs 'effect' and 'parameters' entries") from err
            if name == 'none':
                continue
            effects = effects.with_effect(name, params, dynamics=dynamics,
                                          sample_period=sample_period)
        return effects


_EFFECT_PARAMETERS = ('dead_time', 'friction_current', 'pivot_frequency', 'gain_ratio',
                      'current_limit')


@dataclass(frozen=True)
class PlantSpec:
    """Everything that defines the simulated plant (the simulator's truth).

    Attributes:
        model: Mechanical modal model.
        dynamics: Computation delay and amplifier lag.
        effects: Physical effects.
    """

    model: ModalModel = REFERENCE_MODEL
    dynamics: InputDynamics = field(default_factory=InputDynamics)
    effects: PlantEffects = field(default_factory=PlantEffects)

    def parameters(self) -> dict[str, float]:
        """Return every changeable parameter by name.

        The modal names of :meth:`ModalModel.parameters` (k0, k1.., omega_1.., zeta_1..),
        ``lag_time_constant`` and the effect fields ``dead_time``, ``friction_current``,
        ``pivot_frequency``, ``gain_ratio``, ``current_limit``.
        """
        out = self.model.parameters()
        out['lag_time_constant'] = float(self.dynamics.lag_time_constant)
        for name in _EFFECT_PARAMETERS:
            out[name] = float(getattr(self.effects, name))
        return out

    def replace_parameter(self, name: str, value: float) -> PlantSpec:
        """Return a copy with one parameter (a name of :meth:`parameters`) set to ``value``."""
        if name not in self.parameters():
            raise ConfigurationError(
                f'unknown plant parameter {name!r}; expected one of {sorted(self.parameters())}')
        v = float(value)
        if name in _EFFECT_PARAMETERS:
            kwargs: dict[str, Any] = {name: v}
            return replace(self, effects=replace(self.effects, **kwargs))
        if name == 'lag_time_constant':
            return replace(self, dynamics=replace(self.dynamics, lag_time_constant=v))
        m = self.model
        if name == 'k0':
            return replace(self, model=replace(m, k0=v))
        prefix, index = name.rsplit('_', 1) if '_' in name else ('k', name[1:])
        i = int(index) - 1
        attr = {'k': 'residues', 'omega': 'natural_frequencies', 'zeta': 'damping_ratios'}[prefix]
        values = list(getattr(m, attr))
        values[i] = v
        new: dict[str, Any] = {attr: tuple(values)}
        return replace(self, model=replace(m, **new))


_UNITS = ('second', 'move')
_PARAMETER_NAME = re.compile(r'k\d+|omega_\d+|zeta_\d+|lag_time_constant|'
                             + '|'.join(_EFFECT_PARAMETERS))


def _check_parameter_name(name: str) -> None:
    if not (isinstance(name, str) and _PARAMETER_NAME.fullmatch(name)):
        raise ConfigurationError(f'unknown plant parameter {name!r}')


@dataclass(frozen=True)
class Drift:
    """A parameter drifting linearly from ``start`` on.

    With ``relative`` the value is p * (1 + rate * (t - start)) (e.g. rate = -0.01 per second
    is omega_1 falling 1 % per second), otherwise p + rate * (t - start). t counts seconds of
    simulated time or moves, by ``unit``.

    Attributes:
        parameter: Name from :meth:`PlantSpec.parameters`.
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
        if self.unit not in _UNITS:
            raise ConfigurationError(f'unit must be one of {_UNITS}, got {self.unit!r}')
        _check_parameter_name(self.parameter)


@dataclass(frozen=True)
class StepChange:
    """A parameter jumping at ``at`` (seconds or move index, by ``unit``).

    Attributes:
        parameter: Name from :meth:`PlantSpec.parameters`.
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
        if self.unit not in _UNITS:
            raise ConfigurationError(f'unit must be one of {_UNITS}, got {self.unit!r}')
        _check_parameter_name(self.parameter)


def plant_at(base: PlantSpec, *, time: float, move: int, drifts: Sequence[Drift] = (),
             steps: Sequence[StepChange] = ()) -> PlantSpec:
    """Return the plant a move starting at ``time`` [s] (move index ``move``) runs on.

    Steps that are due apply first, in the order of their time, then drifts multiply (or add
    to) the result.
    """
    spec = base
    due = [s for s in steps if (time if s.unit == 'second' else move) >= s.at]
    for s in sorted(due, key=lambda s: s.at):
        old = spec.parameters().get(s.parameter, math.nan)
        spec = spec.replace_parameter(s.parameter, old * s.value if s.relative else s.value)
    for d in drifts:
        t = (time if d.unit == 'second' else move) - d.start
        if t <= 0:
            continue
        old = spec.parameters().get(d.parameter, math.nan)
        spec = spec.replace_parameter(
            d.parameter, old * (1 + d.rate * t) if d.relative else old + d.rate * t)
    return spec


@dataclass(frozen=True)
class ContinuousPlant:
    """Continuous-time state space of the plant from the delayed command to the angle.

    x' = a x + b_u u_applied + b_d d, y = c x, where d is a current entering the mechanics
    directly (noise, friction, saturation correction) at the nominal torque constant.

    Attributes:
        a: State matrix.
        b_u: Drive of the delayed command (through the lag if there is one).
        b_d: Drive of the disturbance current d.
        c: Encoder angle output.
        current_index: Index of the amplifier current state (None without a lag).
        position_index: Index of the rigid-body position.
        velocity_index: Index of the rigid-body velocity.
    """

    a: NDArray[np.float64]
    b_u: NDArray[np.float64]
    b_d: NDArray[np.float64]
    c: NDArray[np.float64]
    current_index: int | None
    position_index: int
    velocity_index: int


def continuous_plant(spec: PlantSpec) -> ContinuousPlant:
    """Build the continuous state space of ``spec`` (lag state first, then mode pairs)."""
    m, e = spec.model, spec.effects
    lag = spec.dynamics.lag_time_constant
    gains = [m.k0, *m.residues, *(r.residue for r in e.resonances)]
    freqs = [e.pivot_frequency, *m.natural_frequencies,
             *(r.natural_frequency for r in e.resonances)]
    damps = [0.0, *m.damping_ratios, *(r.damping_ratio for r in e.resonances)]
    off = 1 if lag > 0 else 0
    a, b_u, b_d, c = modal_state_space(gains=gains, frequencies=freqs, dampings=damps,
                                       lag_time_constant=lag, input_gain=e.gain_ratio)
    return ContinuousPlant(a=a, b_u=b_u, b_d=b_d, c=c, current_index=0 if lag > 0 else None,
                           position_index=off, velocity_index=off + 1)


@dataclass(frozen=True)
class SampledPlant:
    """The plant sampled at the DSP's period, exactly, with sub-steps for nonlinear effects.

    Over sample k the applied (delayed) command is u[k - whole - 1] for the first
    ``split`` seconds and u[k - whole] after it (``split`` = 0 without a fractional delay).
    With d held per sub-step j (of ``substeps``)::

        x[k+1] = phi x[k] + g_old u_old + g_new u_new + gamma_d @ d_substeps

    and for d held over the whole sample ``gamma_d.sum(axis=1) == g_d``.

    Attributes:
        continuous: The continuous plant.
        sample_period: Sampling period [s].
        whole: Whole samples of pure delay.
        split: Fractional delay [s] (0 if the delay is a whole number of samples).
        substeps: Sub-steps per sample.
        phi: Full-sample transition.
        g_old: Full-sample drive of u[k - whole - 1].
        g_new: Full-sample drive of u[k - whole].
        g_d: Full-sample drive of d held over the sample.
        gamma_d: (n, substeps) drive of d held per sub-step.
        sub_phi: Sub-step transition.
        sub_g_old: (substeps, n) sub-step drives of u_old.
        sub_g_new: (substeps, n) sub-step drives of u_new.
    """

    continuous: ContinuousPlant
    sample_period: float
    whole: int
    split: float
    substeps: int
    phi: NDArray[np.float64]
    g_old: NDArray[np.float64]
    g_new: NDArray[np.float64]
    g_d: NDArray[np.float64]
    gamma_d: NDArray[np.float64]
    sub_phi: NDArray[np.float64]
    sub_g_old: NDArray[np.float64]
    sub_g_new: NDArray[np.float64]


def expm_balanced(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """Matrix exponential by balancing, scaling and squaring of a degree-16 Taylor series.

    As accurate as :func:`scipy.linalg.expm` on the plant's badly scaled matrices (entries
    from 1 to 1e10; the balancing takes care of that) and, using only matrix products, far
    faster on small matrices when OpenBLAS threads contend (a few ms for scipy's Pade solve
    on a busy 2-core machine against ~0.1 ms here), which matters when a drifting plant is
    re-sampled every move.
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


def sample_plant(spec: PlantSpec, *, sample_period: float = TAU,
                 substeps: int = 1) -> SampledPlant:
    """Sample the plant exactly (zero-order hold, fractional delay split exactly).

    Args:
        spec: The plant.
        sample_period: Sampling period [s].
        substeps: Sub-steps per sample over which a disturbance current may be held.

    Returns:
        The sampled plant.
    """
    if not (math.isfinite(sample_period) and sample_period > 0):
        raise ConfigurationError('sample_period must be positive and finite')
    if substeps < 1:
        raise ConfigurationError('substeps must be >= 1')
    cp = continuous_plant(spec)
    n = cp.a.shape[0]
    aug = np.zeros((n + 2, n + 2))
    aug[:n, :n] = cp.a
    aug[:n, n] = cp.b_u
    aug[:n, n + 1] = cp.b_d

    def zoh(t: float) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        if t <= 0:
            return np.eye(n), np.zeros(n), np.zeros(n)
        ex = expm_balanced(aug * t)
        return ex[:n, :n], ex[:n, n], ex[:n, n + 1]

    # Pure input delay: the computation delay, any dead time of the input dynamics and the
    # input_delay effect's extra dead time.
    delay = (spec.dynamics.computation_delay * sample_period + spec.dynamics.dead_time
             + spec.effects.dead_time)
    whole_f, frac = divmod(delay, sample_period)
    whole = round(whole_f)
    eps = 1e-9 * sample_period
    if frac >= sample_period - eps:
        whole, frac = whole + 1, 0.0
    elif frac <= eps:
        frac = 0.0
    h = sample_period / substeps
    sub_phi, sub_g_u, sub_g_d = zoh(h)
    sub_g_old = np.zeros((substeps, n))
    sub_g_new = np.zeros((substeps, n))
    for j in range(substeps):  # u_old before the split, u_new after it
        t0, t1 = j * h, (j + 1) * h
        if frac <= t0:
            sub_g_new[j] = sub_g_u
        elif frac >= t1:
            sub_g_old[j] = sub_g_u
        else:
            phi_rest, g_rest, _ = zoh(t1 - frac)
            sub_g_old[j] = phi_rest @ zoh(frac - t0)[1]
            sub_g_new[j] = g_rest
    powers = [np.eye(n)]
    for _ in range(substeps - 1):
        powers.append(sub_phi @ powers[-1])
    phi = sub_phi @ powers[-1]
    rev = powers[::-1]  # rev[j] = sub_phi^(substeps - 1 - j)
    g_old = sum((rev[j] @ sub_g_old[j] for j in range(substeps)), np.zeros(n))
    g_new = sum((rev[j] @ sub_g_new[j] for j in range(substeps)), np.zeros(n))
    gamma_d = np.stack([rev[j] @ sub_g_d for j in range(substeps)], axis=1)
    return SampledPlant(continuous=cp, sample_period=sample_period, whole=whole, split=frac,
                        substeps=substeps, phi=phi, g_old=g_old, g_new=g_new,
                        g_d=gamma_d.sum(axis=1), gamma_d=gamma_d, sub_phi=sub_phi,
                        sub_g_old=sub_g_old, sub_g_new=sub_g_new)
