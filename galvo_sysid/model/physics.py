"""The plant as it physically runs: every mode, the input dynamics and the effects, flat.

:class:`Physics` is what a :class:`~galvo_sysid.model.plant.PlantModel` means once its effects
are applied (:meth:`PlantModel.physics`): the simulator and the discrepancy workflow both run
it. Signal chain (the DSP's command u is what gets recorded)::

    u --pure delay--> amplifier lag --> clip(+-current_limit) --> * gain_ratio
      --> - friction + cogging --> mechanics --> shaft angle y --> encoder reading

    mechanics(s) = k0 / (s^2 + c_v s + w_p^2)
                   + sum_i k_i / (s^2 + 2 zeta_i omega_i s + omega_i^2)

with the pure delay ``computation_delay`` samples plus ``dead_time``, w_p the pivot stiffness
(0 for a free rigid body), c_v = k0 ``viscous_coefficient`` the viscous friction (a current
proportional to the velocity of the rigid-body coordinate), the Coulomb friction an
equivalent current opposing that velocity and the cogging torque an equivalent current
periodic in the rigid-body angle p, ``cogging_amplitude`` sin(2 pi p / ``cogging_period`` +
``cogging_phase``) (:meth:`Physics.cogging`); no friction or cogging torque scales with
``gain_ratio``. The encoder reads y + ``encoder_error_amplitude`` sin(2 pi y /
``encoder_error_period`` + ``encoder_error_phase``) (:meth:`Physics.reading`): a cyclic error
of the reading, not a torque. The discrepancy fallback's proposed terms (``terms``) add a
current (with the cogging's) and an error of the reading.

Its parameters by name (:meth:`Physics.parameters`) are what plant changes act on
(:mod:`galvo_sysid.model.changes`): the modal names ``k0``, ``k1``.., ``omega_1``..,
``zeta_1``.. and those of :data:`PHYSICAL_PARAMETERS`.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model.dynamics import check_sample_period
from galvo_sysid.model.modal import MAX_DAMPING_RATIO, MAX_MAGNITUDE, parameter_names
from galvo_sysid.model.terms import term_current, term_reading, term_reading_slope

if TYPE_CHECKING:
    from numpy.typing import ArrayLike, NDArray

__all__ = ['PHYSICAL_PARAMETERS', 'Physics', 'check_parameter_name']

PHYSICAL_PARAMETERS = ('lag_time_constant', 'dead_time', 'friction_current', 'pivot_frequency',
                       'gain_ratio', 'current_limit', 'viscous_coefficient',
                       'cogging_amplitude', 'cogging_period', 'cogging_phase',
                       'encoder_error_amplitude', 'encoder_error_period',
                       'encoder_error_phase')
"""Parameters of :class:`Physics` besides the modal ones (names of plant changes)."""

_NAME = re.compile(r'k\d+|omega_[1-9]\d*|zeta_[1-9]\d*|' + '|'.join(PHYSICAL_PARAMETERS))


def check_parameter_name(name: str) -> str:
    """Return ``name`` if it can name a plant parameter, else raise ConfigurationError."""
    if not (isinstance(name, str) and _NAME.fullmatch(name)):
        raise ConfigurationError(
            f'unknown plant parameter {name!r}; expected k0, k<i>, omega_<i>, zeta_<i> or one '
            f'of {", ".join(PHYSICAL_PARAMETERS)}')
    return name


@dataclass(frozen=True)
class Physics:
    """The plant that runs (see the module docs); hashable, so loops can be cached by it.

    Attributes:
        sample_period: DSP sampling period [s].
        k0: Rigid-body gain [deg/(A s^2)].
        residues: Residues of every resonant mode (model modes, then unmodelled ones).
        natural_frequencies: Their natural frequencies [rad/s].
        damping_ratios: Their damping ratios.
        computation_delay: Whole samples of DSP computation delay.
        dead_time: Extra pure delay [s].
        lag_time_constant: Amplifier lag [s] (0: none).
        pivot_frequency: Pivot spring w_p [rad/s] (0: free rigid body).
        gain_ratio: Torque constant relative to the modal model.
        friction_current: Coulomb friction as an equivalent current [A] (0: none).
        current_limit: Amplifier current limit [A] (inf: none).
        viscous_coefficient: Viscous friction: equivalent current per rigid-body velocity
            [A s/deg] (0: none).
        cogging_amplitude: Cogging torque's amplitude as an equivalent current [A] (0: none).
        cogging_period: Its period in the rigid-body angle [deg].
        cogging_phase: Its phase at 0 deg [rad].
        encoder_error_amplitude: Cyclic error of the encoder's reading [deg] (0: none).
        encoder_error_period: Its period in the shaft angle [deg].
        encoder_error_phase: Its phase at 0 deg [rad].
        terms: The ``proposed_terms`` effect's parameters that act, ``(name, value)``
            (:mod:`galvo_sysid.model.terms`): an extra current of the rigid body's angle,
            velocity and acceleration and the DSP's current command, evaluated at each
            sample's start and held over the sample (:meth:`term_current`), and an error of
            the encoder's reading (:meth:`reading`). Empty: none.
    """

    sample_period: float
    k0: float
    residues: tuple[float, ...]
    natural_frequencies: tuple[float, ...]
    damping_ratios: tuple[float, ...]
    computation_delay: int = 1
    dead_time: float = 0.0
    lag_time_constant: float = 0.0
    pivot_frequency: float = 0.0
    gain_ratio: float = 1.0
    friction_current: float = 0.0
    current_limit: float = math.inf
    viscous_coefficient: float = 0.0
    cogging_amplitude: float = 0.0
    cogging_period: float = 1.0
    cogging_phase: float = 0.0
    encoder_error_amplitude: float = 0.0
    encoder_error_period: float = 1.0
    encoder_error_phase: float = 0.0
    terms: tuple[tuple[str, float], ...] = ()

    def __post_init__(self) -> None:
        check_sample_period(self.sample_period)
        n = len(self.residues)
        if len(self.natural_frequencies) != n or len(self.damping_ratios) != n:
            raise ConfigurationError('every mode needs a residue, a frequency and a damping')
        values = np.array([self.k0, *self.residues, *self.natural_frequencies,
                           *self.damping_ratios], dtype=float)
        if not np.all(np.isfinite(values)) or np.max(np.abs(values)) > MAX_MAGNITUDE:
            raise ConfigurationError(f'modal parameters must be finite and within '
                                     f'+-{MAX_MAGNITUDE:g}')
        if any(w <= 0 for w in self.natural_frequencies) or any(
                z <= 0 for z in self.damping_ratios):
            raise ConfigurationError('natural frequencies and damping ratios must be positive')
        for i, z in enumerate(self.damping_ratios, start=1):
            if z > MAX_DAMPING_RATIO:  # as a model file's damping_ratio
                raise ConfigurationError(
                    f'damping ratios must be at most {MAX_DAMPING_RATIO:g}, got zeta_{i} = '
                    f'{z:.4g} (an overdamped mode is two real poles, not a resonance; a model '
                    f'file refuses it too)')
        for name, low, strict in (('dead_time', 0.0, False), ('lag_time_constant', 0.0, False),
                                  ('pivot_frequency', 0.0, False), ('gain_ratio', 0.0, True),
                                  ('friction_current', 0.0, False),
                                  ('viscous_coefficient', 0.0, False),
                                  ('cogging_amplitude', 0.0, False),
                                  ('cogging_period', 0.0, True),
                                  ('encoder_error_amplitude', 0.0, False),
                                  ('encoder_error_period', 0.0, True)):
            value = getattr(self, name)
            if not (math.isfinite(value) and (value > low if strict else value >= low)):
                kind = 'positive' if strict else '>= 0'
                raise ConfigurationError(f'{name} must be finite and {kind}, got {value!r}')
        if math.isnan(self.current_limit) or self.current_limit <= 0:
            raise ConfigurationError(
                f'current_limit must be positive (inf for none), got {self.current_limit!r}')
        for name in ('cogging_phase', 'encoder_error_phase'):
            if not math.isfinite(getattr(self, name)):
                raise ConfigurationError(f'{name} must be finite')
        slope = 2 * math.pi * self.encoder_error_amplitude / self.encoder_error_period
        if slope >= 0.5:
            raise ConfigurationError(
                f'encoder error: 2 pi amplitude / period must stay below 0.5 (a reading that '
                f'keeps increasing with the angle), got {slope:.3g}')

    @property
    def n_modes(self) -> int:
        """Number of resonant modes (model and unmodelled)."""
        return len(self.residues)

    @property
    def pure_delay(self) -> float:
        """Computation delay plus dead time [s]."""
        return self.computation_delay * self.sample_period + self.dead_time

    @property
    def linear(self) -> bool:
        """True without Coulomb friction, saturation, cogging and encoder error (the closed
        loop is then linear)."""  # noqa: D205, D209
        return (self.friction_current == 0 and math.isinf(self.current_limit)
                and self.cogging_amplitude == 0 and self.encoder_error_amplitude == 0
                and not self.terms)

    @property
    def current_terms(self) -> bool:
        """Whether proposed terms add a current."""
        return any(k.startswith('current_') for k, _ in self.terms)

    @property
    def reading_error(self) -> bool:
        """Whether the encoder's reading differs from the shaft angle."""
        return bool(self.encoder_error_amplitude) or any(
            k.startswith('reading_') for k, _ in self.terms)

    def term_current(self, position: ArrayLike, velocity: ArrayLike, acceleration: ArrayLike,
                     current: ArrayLike) -> NDArray[np.float64]:
        """The proposed terms' extra current [A] at the rigid body's angle [deg], velocity
        [deg/s] and acceleration [deg/s^2] and the DSP's current command [A].

        The simulator and the discrepancy workflow evaluate it at each sample's start (the
        acceleration: the rigid body's velocity change over the previous sample / T) and hold
        it over the sample.
        """  # noqa: D205
        p = np.asarray(position, dtype=float)
        shape = np.broadcast(p, np.asarray(velocity), np.asarray(acceleration),
                             np.asarray(current)).shape
        out = term_current(dict(self.terms), p, np.asarray(velocity, dtype=float),
                           np.asarray(acceleration, dtype=float),
                           np.asarray(current, dtype=float))
        return np.asarray(np.broadcast_to(out, shape), dtype=np.float64)

    @property
    def rigid_damping(self) -> float:
        """The viscous friction's damping of the rigid body, k0 ``viscous_coefficient`` [1/s]."""
        return self.k0 * self.viscous_coefficient

    def cogging(self, position: ArrayLike, velocity: ArrayLike) -> NDArray[np.float64]:
        """Cogging torque [A] held over a sample that starts at ``position`` [deg] with
        ``velocity`` [deg/s]: its mean over the sample at that constant velocity,
        a sin(k (p + v T / 2) + phase) sinc(k v T / 2), k = 2 pi / period.

        The simulator and the discrepancy workflow both hold it over each sample.
        """  # noqa: D205
        p = np.asarray(position, dtype=float)
        v = np.asarray(velocity, dtype=float)
        if self.cogging_amplitude == 0:
            return np.zeros(np.broadcast(p, v).shape)
        k = 2 * math.pi / self.cogging_period
        half = 0.5 * k * v * self.sample_period
        return np.asarray(self.cogging_amplitude * np.sin(k * p + half + self.cogging_phase)
                          * np.sinc(half / math.pi), dtype=np.float64)

    def reading(self, angle: ArrayLike) -> NDArray[np.float64]:
        """The encoder's reading of the shaft angle [deg] (its cyclic error added)."""
        y = np.asarray(angle, dtype=float)
        out = np.array(y, dtype=np.float64)
        if self.encoder_error_amplitude:
            k = 2 * math.pi / self.encoder_error_period
            out = out + self.encoder_error_amplitude * np.sin(k * y + self.encoder_error_phase)
        if self.terms:
            out = out + term_reading(dict(self.terms), y)
        return np.asarray(out, dtype=np.float64)

    def true_angle(self, reading: ArrayLike) -> NDArray[np.float64]:
        """The shaft angle [deg] whose reading is ``reading`` (the inverse of
        :meth:`reading`, by Newton's method: the reading increases with the angle)."""  # noqa: D205, D209
        r = np.asarray(reading, dtype=float)
        y = np.array(r, dtype=np.float64)
        if not self.reading_error:
            return y
        a, ph = self.encoder_error_amplitude, self.encoder_error_phase
        k = 2 * math.pi / self.encoder_error_period
        terms = dict(self.terms)
        for _ in range(30):
            slope = 1 + a * k * np.cos(k * y + ph) + term_reading_slope(terms, y)
            step = (self.reading(y) - r) / slope
            y = y - step
            if float(np.max(np.abs(step), initial=0.0)) < 1e-13 * (1 + float(
                    np.max(np.abs(r), initial=0.0))):
                break
        return y

    def static_gain(self) -> float:
        """Steady angle per unit applied torque current [deg/A] (inf without a pivot)."""
        if self.pivot_frequency <= 0:
            return math.inf
        return self.k0 / self.pivot_frequency**2 + sum(
            k / w**2 for k, w in zip(self.residues, self.natural_frequencies, strict=True))

    def parameters(self) -> dict[str, float]:
        """Every changeable parameter by name (see the module docs)."""
        names = parameter_names(self.n_modes)
        values = [self.k0, *self.residues, *self.natural_frequencies, *self.damping_ratios]
        out = {n: float(v) for n, v in zip(names, values, strict=True)}
        out.update({name: float(getattr(self, name)) for name in PHYSICAL_PARAMETERS})
        return out

    def with_parameter(self, name: str, value: float) -> Physics:
        """Return a copy with one parameter (a name of :meth:`parameters`) set to ``value``.

        Raises:
            ConfigurationError: Unknown name or a value out of range.
        """
        if name not in self.parameters():
            check_parameter_name(name)
            raise ConfigurationError(f'the plant has no parameter {name!r} (it has '
                                     f'{self.n_modes} resonant modes)')
        v = float(value)
        if name in PHYSICAL_PARAMETERS or name == 'k0':
            kwargs: dict[str, Any] = {name: v}
            return replace(self, **kwargs)
        prefix, index = name.rsplit('_', 1) if '_' in name else ('k', name[1:])
        attr = {'k': 'residues', 'omega': 'natural_frequencies', 'zeta': 'damping_ratios'}[prefix]
        values = list(getattr(self, attr))
        values[int(index) - 1] = v
        new: dict[str, Any] = {attr: tuple(values)}
        return replace(self, **new)
