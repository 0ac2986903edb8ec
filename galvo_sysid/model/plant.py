"""The one model of a scanner: what it is supposed to be, used everywhere.

A :class:`PlantModel` holds the modal mechanics (paper Eq. 1), the input dynamics, the
physical effects (:mod:`galvo_sysid.model.effects`), the sample period, how its moves are
recorded (record and dwell lengths), and what identification needs to know about it: a
frequency band per mode and, for a commissioned model, each parameter's standard deviation.
It is read from and written to one YAML file (:mod:`galvo_sysid.model.files`) and drives:

- the simulator and the ``galvo_driver`` (through :meth:`PlantModel.physics`, the plant
  with its effects acting), whose controller is designed from it;
- identification (``identify_window(..., model=...)``, the sysid node's ``model``
  parameter): number of modes, bands, starting point, input dynamics, sample period;
- the watchdog's reference and the discrepancy workflow's model.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model.dynamics import InputDynamics, check_sample_period
from galvo_sysid.model.effects import MAX_EFFECTS, Effect
from galvo_sysid.model.modal import Band, ModalModel, default_bands, parameter_names
from galvo_sysid.model.physics import Physics

__all__ = ['MAX_MODES', 'MAX_RECORD_LENGTH', 'PlantModel']

MAX_MODES = 16
"""Most resonant modes a model may have."""

MAX_RECORD_LENGTH = 1_000_000
"""Longest record (and dwell) a model may declare [samples]."""


@dataclass(frozen=True)
class PlantModel:
    """A scanner's model (see the module docs).

    Attributes:
        modal: The modal mechanics (rigid body + resonant modes).
        dynamics: Computation delay, amplifier lag and dead time.
        sample_period: DSP sampling period [s].
        effects: Physical effects in the order they were added.
        description: Free text, kept in the file.
        bands: Frequency band of each mode [rad/s], or None for :func:`default_bands`.
        uncertainty: ``(parameter name, standard deviation)`` pairs (a commissioned model's),
            names of :meth:`parameters` and ``lag_time_constant``.
        record_length: Samples recorded per move (the simulator's default).
        dwell_length: Samples between one record's end and the next move (ditto).
    """

    modal: ModalModel
    dynamics: InputDynamics
    sample_period: float
    effects: tuple[Effect, ...] = ()
    description: str = ''
    bands: tuple[Band, ...] | None = None
    uncertainty: tuple[tuple[str, float], ...] = ()
    record_length: int = 512
    dwell_length: int = 94

    def __post_init__(self) -> None:
        if not isinstance(self.modal, ModalModel):
            raise ConfigurationError('modal must be a ModalModel')
        if not isinstance(self.dynamics, InputDynamics):
            raise ConfigurationError('dynamics must be an InputDynamics')
        t = check_sample_period(self.sample_period)
        if not 1e-8 <= t <= 1.0:
            raise ConfigurationError(f'sample_period must be within 1e-8 .. 1 s, got {t!r}')
        if self.modal.n_modes > MAX_MODES:
            raise ConfigurationError(f'at most {MAX_MODES} resonant modes, got '
                                     f'{self.modal.n_modes}')
        for name in ('record_length', 'dwell_length'):
            value = getattr(self, name)
            low = 16 if name == 'record_length' else 0
            if isinstance(value, bool) or not isinstance(value, int) or not (
                    low <= value <= MAX_RECORD_LENGTH):
                raise ConfigurationError(f'{name} must be a whole number within '
                                         f'{low}..{MAX_RECORD_LENGTH}, got {value!r}')
        if len(self.effects) > MAX_EFFECTS:
            raise ConfigurationError(f'at most {MAX_EFFECTS} effects')
        seen: set[str] = set()
        for e in self.effects:
            if not isinstance(e, Effect):
                raise ConfigurationError('effects must be Effect instances')
            if e.name in seen and not e.kind.repeatable:
                raise ConfigurationError(f'effect {e.name!r} given twice')
            seen.add(e.name)
        if self.bands is not None:
            self._check_bands(self.bands)
        order = [*self.modal.parameters(), 'lag_time_constant']
        for name, std in self.uncertainty:
            if name not in order:
                raise ConfigurationError(f'uncertainty of unknown parameter {name!r}')
            if not std >= 0:  # NaN and negative refused; inf (unknown) allowed
                raise ConfigurationError(f'standard deviation of {name} must be >= 0')
        # one canonical order, so that equal models compare equal
        canonical = tuple(sorted(((str(n), float(s)) for n, s in self.uncertainty),
                                 key=lambda item: order.index(item[0])))
        object.__setattr__(self, 'uncertainty', canonical)
        self.physics()  # the effects must act on this plant (e.g. input_delay's minimum)

    def _check_bands(self, bands: Sequence[Band]) -> None:
        if len(bands) != self.modal.n_modes:
            raise ConfigurationError(f'{len(bands)} bands for {self.modal.n_modes} modes')
        nyquist = math.pi / self.sample_period
        for i, ((lo, hi), w) in enumerate(zip(bands, self.modal.natural_frequencies,
                                              strict=True), start=1):
            if not 0 < lo < w < hi <= nyquist:
                raise ConfigurationError(
                    f'band of mode {i} ({lo:.6g}..{hi:.6g} rad/s) must hold its frequency '
                    f'{w:.6g} rad/s and stay below Nyquist ({nyquist:.6g} rad/s)')

    # ------------------------------------------------------------------ views

    @property
    def n_modes(self) -> int:
        """Number of resonant modes of the modal model."""
        return self.modal.n_modes

    @property
    def nyquist(self) -> float:
        """Nyquist frequency [rad/s]."""
        return math.pi / self.sample_period

    @property
    def base_delay(self) -> float:
        """Equivalent input delay of the input dynamics alone [s]."""
        return self.dynamics.equivalent_delay(self.sample_period)

    @property
    def equivalent_delay(self) -> float:
        """Total equivalent input delay [s], an ``input_delay`` effect included."""
        e = self.effect('input_delay')
        return e.params()['delay'] if e is not None else self.base_delay

    @property
    def move_length(self) -> int:
        """Samples per move, recorded plus dwell."""
        return self.record_length + self.dwell_length

    def parameters(self) -> dict[str, float]:
        """The modal parameters by name: k0, k1.., omega_1.., zeta_1.."""
        return self.modal.parameters()

    def parameter_names(self) -> tuple[str, ...]:
        """Names of :meth:`parameters`, in order."""
        return parameter_names(self.n_modes)

    def std_by_name(self) -> dict[str, float]:
        """The standard deviations the model carries (empty for a model without them)."""
        return dict(self.uncertainty)

    def mode_bands(self) -> tuple[Band, ...]:
        """Each mode's frequency band: the model's, or :func:`default_bands` around its modes
        (none for a rigid body alone)."""  # noqa: D205, D209
        if self.bands is not None:
            return self.bands
        if not self.modal.natural_frequencies:
            return ()
        return default_bands(self.modal, sample_period=self.sample_period)

    def physics(self) -> Physics:
        """The plant with every effect acting (what the simulator runs)."""
        m, d = self.modal, self.dynamics
        ph = Physics(sample_period=self.sample_period, k0=m.k0, residues=m.residues,
                     natural_frequencies=m.natural_frequencies,
                     damping_ratios=m.damping_ratios,
                     computation_delay=d.computation_delay, dead_time=d.dead_time,
                     lag_time_constant=d.lag_time_constant)
        for e in sorted(self.effects, key=lambda e: e.kind.order):
            ph = e.act(ph)
        return ph

    def effect(self, name: str) -> Effect | None:
        """The (last) effect of that name, or None."""
        found = [e for e in self.effects if e.name == name]
        return found[-1] if found else None

    # ------------------------------------------------------------------ copies

    def with_effect(self, name: str, parameters: Mapping[str, Any]) -> PlantModel:
        """Return a copy with an effect set (a repeatable one is added to the others).

        Raises:
            ConfigurationError: Unknown effect or bad parameters.
        """
        new = Effect.create(name, parameters)
        if new.kind.repeatable:
            effects = (*self.effects, new)
        else:
            effects = tuple(new if e.name == name else e for e in self.effects)
            if new not in effects:
                effects = (*effects, new)
        return replace(self, effects=effects)

    def with_effects(self, effects: Sequence[Effect]) -> PlantModel:
        """Return a copy with these effects added, in order (see :meth:`with_effect`)."""
        out = self
        for e in effects:
            out = out.with_effect(e.name, e.params())
        return out

    def nominal(self) -> PlantModel:
        """The same scanner without effects (what a controller is designed for)."""
        return replace(self, effects=())

    def with_modal(self, modal: ModalModel, *,
                   uncertainty: Mapping[str, float] | None = None) -> PlantModel:
        """Return a copy with other modal parameters (same number of modes keeps the bands)."""
        bands = self.bands if modal.n_modes == self.n_modes else None
        return replace(self, modal=modal, bands=bands,
                       uncertainty=tuple((uncertainty or {}).items()))

    def __str__(self) -> str:
        d = self.dynamics
        text = (f'{self.n_modes} resonant mode(s), sample period '
                f'{self.sample_period * 1e6:.4g} us, computation delay {d.computation_delay} '
                f'sample(s), lag {d.lag_time_constant * 1e6:.3g} us')
        if d.dead_time:
            text += f', dead time {d.dead_time * 1e6:.3g} us'
        if self.effects:
            text += '; ' + ', '.join(str(e) for e in self.effects)
        return text
