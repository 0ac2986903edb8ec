"""Plant models as YAML: the modal mechanics, the input dynamics and the physical effects.

A :class:`PlantModel` is what the discrepancy workflow compares the measurements with and
what it writes back after adding an effect: a :class:`~galvo_sysid.model.modal.ModalModel`
(paper Eq. 1), the :class:`~galvo_sysid.model.modal.InputDynamics` (DSP computation delay,
amplifier lag, dead time) and a list of :class:`Effect` s named as in issue 6:

=======================  =====================================================================
effect                   parameters
=======================  =====================================================================
``input_delay``          ``delay`` [s]: the total equivalent input delay (computation delay +
                         lag + dead time; the nominal plant has 1.6 tau). It adds dead time
                         to the input dynamics, so it is at least their equivalent delay.
``unmodeled_resonance``  ``natural_frequency`` [rad/s], ``damping_ratio``, ``residue``
                         [deg/(A s^2)]: an extra mode k / (s^2 + 2 zeta omega s + omega^2).
``coulomb_friction``     ``friction_current`` [A]: Coulomb friction on the rigid-body motion
                         as the current whose torque equals it.
``pivot_stiffness``      ``natural_frequency`` [rad/s]: a spring (centred at 0 deg) turning
                         the rigid body k0/s^2 into k0/(s^2 + w^2).
``gain_change``          ``gain_ratio``: the torque constant relative to the modal model (it
                         scales the current's torque, not the friction).
``current_saturation``   ``current_limit`` [A]: the amplifier's output current is clipped.
=======================  =====================================================================

The YAML file (:func:`save_model`, :func:`load_model`)::

    format: galvo_sysid/plant_model
    version: 1
    sample_period: 1.0e-05          # [s], the DSP period the delays refer to
    mechanics:
      k0: 3564000.0                  # [deg/(A s^2)]
      modes:                         # ascending frequency
      - {natural_frequency: 71080.0, damping_ratio: 0.006218, residue: 2069000.0}
      ...
    input_dynamics:
      computation_delay: 1           # whole sample periods
      lag_time_constant: 6.0e-06     # [s]
      dead_time: 0.0                 # [s]
    effects:
    - {effect: coulomb_friction, parameters: {friction_current: 0.02}}
    description: free text (optional)

The same file drives the simulator: :func:`to_plant_spec` converts a model into the
simulator's :class:`~galvo_sysid.model.effects.PlantSpec` (``SimulatorConfig(plant=...)``) and
:func:`from_plant_spec` converts back.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml  # type: ignore[import-untyped]  # PyYAML ships no stubs here

from galvo_sysid.errors import ConfigurationError, InvalidDataError
from galvo_sysid.model.modal import REFERENCE_MODEL, TAU, InputDynamics, ModalModel

if TYPE_CHECKING:
    import os

    from galvo_sysid.model.effects import PlantSpec

__all__ = [
    'EFFECT_NAMES',
    'EFFECT_PARAMETERS',
    'FORMAT',
    'NOMINAL_MODEL',
    'Effect',
    'PlantModel',
    'from_plant_spec',
    'load_model',
    'load_plant_spec',
    'model_from_dict',
    'model_to_dict',
    'save_model',
    'to_plant_spec',
]

FORMAT = 'galvo_sysid/plant_model'
"""Value of the ``format`` key of a plant model file."""

_VERSION = 1

EFFECT_PARAMETERS: dict[str, tuple[str, ...]] = {
    'input_delay': ('delay',),
    'unmodeled_resonance': ('natural_frequency', 'damping_ratio', 'residue'),
    'coulomb_friction': ('friction_current',),
    'pivot_stiffness': ('natural_frequency',),
    'gain_change': ('gain_ratio',),
    'current_saturation': ('current_limit',),
}
"""Each effect's parameter names (the JSON/YAML contract of issue 6)."""

EFFECT_NAMES: tuple[str, ...] = tuple(EFFECT_PARAMETERS)
"""The effect names, besides ``none``."""


def _check_value(effect: str, name: str, value: float) -> None:
    if not math.isfinite(value):
        raise ConfigurationError(f'{effect}: {name} must be finite, got {value!r}')
    positive = {'delay', 'natural_frequency', 'damping_ratio', 'gain_ratio', 'current_limit'}
    if name in positive and value <= 0:
        raise ConfigurationError(f'{effect}: {name} must be positive, got {value!r}')
    if name == 'friction_current' and value < 0:
        raise ConfigurationError(f'{effect}: friction_current must be >= 0, got {value!r}')


@dataclass(frozen=True)
class Effect:
    """One physical effect: its issue-6 name and parameters.

    Build it with :meth:`create`, which checks the names and values.

    Attributes:
        name: One of :data:`EFFECT_NAMES`.
        parameters: ``(name, value)`` pairs in the order of :data:`EFFECT_PARAMETERS`.
    """

    name: str
    parameters: tuple[tuple[str, float], ...]

    @classmethod
    def create(cls, name: str, parameters: Mapping[str, Any]) -> Effect:
        """Check and build an effect.

        Raises:
            ConfigurationError: Unknown effect, wrong parameter names or bad values.
        """
        if name not in EFFECT_PARAMETERS:
            raise ConfigurationError(
                f'unknown effect {name!r}; expected one of {", ".join(EFFECT_NAMES)}')
        if not isinstance(parameters, Mapping):
            raise ConfigurationError(f'{name}: parameters must be a mapping')
        expected = EFFECT_PARAMETERS[name]
        if set(parameters) != set(expected):
            raise ConfigurationError(
                f'effect {name!r} takes parameters {list(expected)}, got {sorted(parameters)}')
        values: list[tuple[str, float]] = []
        for key in expected:
            try:
                value = float(parameters[key])
            except (TypeError, ValueError):
                raise ConfigurationError(
                    f'{name}: {key} must be a number, got {parameters[key]!r}') from None
            _check_value(name, key, value)
            values.append((key, value))
        return cls(name=name, parameters=tuple(values))

    def params(self) -> dict[str, float]:
        """The parameters as a dict."""
        return dict(self.parameters)

    def to_dict(self) -> dict[str, Any]:
        """``{'effect': name, 'parameters': {...}}``."""
        return {'effect': self.name, 'parameters': self.params()}

    def __str__(self) -> str:
        inner = ', '.join(f'{k}={v:.6g}' for k, v in self.parameters)
        return f'{self.name}({inner})'


@dataclass(frozen=True)
class PlantModel:
    """A plant model: modal mechanics, input dynamics and physical effects.

    At most one effect of each name except ``unmodeled_resonance`` (any number).

    Attributes:
        modal: The modal mechanics (rigid body + resonant modes).
        dynamics: Computation delay, amplifier lag and dead time.
        effects: Physical effects in the order they were added.
        sample_period: DSP sampling period [s] (``input_delay`` refers to it).
        description: Free text, kept in the YAML file.
    """

    modal: ModalModel = REFERENCE_MODEL
    dynamics: InputDynamics = field(default_factory=InputDynamics)
    effects: tuple[Effect, ...] = ()
    sample_period: float = TAU
    description: str = ''

    def __post_init__(self) -> None:
        if not isinstance(self.modal, ModalModel):
            raise ConfigurationError('modal must be a ModalModel')
        if not isinstance(self.dynamics, InputDynamics):
            raise ConfigurationError('dynamics must be an InputDynamics')
        if not (math.isfinite(self.sample_period) and self.sample_period > 0):
            raise ConfigurationError('sample_period must be positive and finite')
        seen: set[str] = set()
        for e in self.effects:
            if not isinstance(e, Effect):
                raise ConfigurationError('effects must be Effect instances')
            if e.name in seen and e.name != 'unmodeled_resonance':
                raise ConfigurationError(f'effect {e.name!r} given twice')
            seen.add(e.name)
            if e.name == 'input_delay':
                base = self.base_delay
                if e.params()['delay'] < base - 1e-9 * self.sample_period:
                    raise ConfigurationError(
                        f'input_delay: delay {e.params()["delay"]!r} s is below the input '
                        f"dynamics' equivalent delay {base!r} s")

    @property
    def base_delay(self) -> float:
        """Equivalent input delay of the input dynamics alone [s]."""
        return self.dynamics.equivalent_delay(self.sample_period)

    @property
    def equivalent_delay(self) -> float:
        """Total equivalent input delay [s], the ``input_delay`` effect included."""
        e = self.effect('input_delay')
        return e.params()['delay'] if e is not None else self.base_delay

    def effect(self, name: str) -> Effect | None:
        """The (last) effect of that name, or None."""
        found = [e for e in self.effects if e.name == name]
        return found[-1] if found else None

    def with_effect(self, name: str, parameters: Mapping[str, Any]) -> PlantModel:
        """Return a copy with an effect set (an unmodelled resonance is added to the others).

        Raises:
            ConfigurationError: Unknown effect or bad parameters.
        """
        new = Effect.create(name, parameters)
        if name == 'unmodeled_resonance':
            effects = (*self.effects, new)
        else:
            effects = tuple(new if e.name == name else e for e in self.effects)
            if new not in effects:
                effects = (*effects, new)
        return replace(self, effects=effects)

    def without_effects(self) -> PlantModel:
        """The same mechanics and input dynamics without any effect."""
        return replace(self, effects=())

    def __str__(self) -> str:
        d = self.dynamics
        text = (f'{self.modal.n_modes} resonant modes, computation delay '
                f'{d.computation_delay} sample(s), lag {d.lag_time_constant * 1e6:.3g} us')
        if d.dead_time:
            text += f', dead time {d.dead_time * 1e6:.3g} us'
        if self.effects:
            text += '; ' + ', '.join(str(e) for e in self.effects)
        return text


NOMINAL_MODEL = PlantModel(description='nominal: Table I modes, one sample of DSP delay, '
                                       'amplifier lag 0.6 tau')
"""The project's nominal plant: Table I, one sample of computation delay, 0.6 tau lag."""


# --------------------------------------------------------------------------- dict / YAML


def model_to_dict(model: PlantModel) -> dict[str, Any]:
    """The model as plain data (the YAML layout of the module docs)."""
    m, d = model.modal, model.dynamics
    out: dict[str, Any] = {
        'format': FORMAT,
        'version': _VERSION,
        'sample_period': float(model.sample_period),
        'mechanics': {
            'k0': float(m.k0),
            'modes': [{'natural_frequency': float(w), 'damping_ratio': float(z),
                       'residue': float(k)}
                      for k, w, z in zip(m.residues, m.natural_frequencies, m.damping_ratios,
                                         strict=True)],
        },
        'input_dynamics': {'computation_delay': int(d.computation_delay),
                           'lag_time_constant': float(d.lag_time_constant),
                           'dead_time': float(d.dead_time)},
        'effects': [e.to_dict() for e in model.effects],
    }
    if model.description:
        out['description'] = model.description
    return out


def _section(data: Mapping[str, Any], key: str, where: str) -> Mapping[str, Any]:
    value = data.get(key)
    if not isinstance(value, Mapping):
        raise ConfigurationError(f'{where}: {key!r} must be a mapping')
    return value


def _number(data: Mapping[str, Any], key: str, where: str, default: float | None = None) -> float:
    if key not in data:
        if default is None:
            raise ConfigurationError(f'{where}: {key!r} is missing')
        return default
    value = data[key]
    if isinstance(value, str):  # YAML 1.1 reads 3.0e6 (no sign in the exponent) as text
        try:
            return float(value)
        except ValueError:
            pass
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigurationError(f'{where}: {key!r} must be a number, got {value!r}')
    return float(value)


def model_from_dict(data: Mapping[str, Any], *, source: str = 'model') -> PlantModel:
    """Build a model from plain data (the YAML layout of the module docs).

    Raises:
        ConfigurationError: Wrong layout, missing keys or bad values (the message names
            ``source`` and the key).
    """
    if not isinstance(data, Mapping):
        raise ConfigurationError(f'{source}: expected a mapping at the top level')
    fmt = data.get('format', FORMAT)
    if fmt != FORMAT:
        raise ConfigurationError(f'{source}: format {fmt!r} is not {FORMAT!r}')
    version = data.get('version', _VERSION)
    if version != _VERSION:
        raise ConfigurationError(f'{source}: unsupported version {version!r} '
                                 f'(this galvo_sysid reads version {_VERSION})')
    known = {'format', 'version', 'sample_period', 'mechanics', 'input_dynamics', 'effects',
             'description'}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ConfigurationError(f'{source}: unknown key(s) {unknown}')
    sample_period = _number(data, 'sample_period', source, TAU)
    mech = _section(data, 'mechanics', source)
    modes = mech.get('modes', [])
    if not isinstance(modes, list):
        raise ConfigurationError(f'{source}: mechanics.modes must be a list')
    residues, freqs, damps = [], [], []
    for i, mode in enumerate(modes, start=1):
        where = f'{source}: mechanics.modes[{i}]'
        if not isinstance(mode, Mapping):
            raise ConfigurationError(f'{where} must be a mapping')
        freqs.append(_number(mode, 'natural_frequency', where))
        damps.append(_number(mode, 'damping_ratio', where))
        residues.append(_number(mode, 'residue', where))
    dyn = data.get('input_dynamics', {})
    if not isinstance(dyn, Mapping):
        raise ConfigurationError(f'{source}: input_dynamics must be a mapping')
    where = f'{source}: input_dynamics'
    delay_samples = _number(dyn, 'computation_delay', where, 1.0)
    if delay_samples != int(delay_samples):
        raise ConfigurationError(f'{where}: computation_delay must be a whole number of samples')
    k0 = _number(mech, 'k0', f'{source}: mechanics')
    lag = _number(dyn, 'lag_time_constant', where, 0.6 * sample_period)
    dead = _number(dyn, 'dead_time', where, 0.0)
    try:
        modal = ModalModel(k0=k0, residues=tuple(residues), natural_frequencies=tuple(freqs),
                           damping_ratios=tuple(damps))
        dynamics = InputDynamics(computation_delay=int(delay_samples), lag_time_constant=lag,
                                 dead_time=dead)
    except ConfigurationError as err:
        raise ConfigurationError(f'{source}: {err}') from None
    items = data.get('effects') or []
    if not isinstance(items, list):
        raise ConfigurationError(f'{source}: effects must be a list')
    effects = []
    for i, item in enumerate(items, start=1):
        if not isinstance(item, Mapping) or set(item) != {'effect', 'parameters'}:
            raise ConfigurationError(
                f'{source}: effects[{i}] must be {{effect: NAME, parameters: {{...}}}}')
        if item['effect'] == 'none':
            continue
        try:
            effects.append(Effect.create(str(item['effect']), item['parameters']))
        except ConfigurationError as err:
            raise ConfigurationError(f'{source}: effects[{i}]: {err}') from None
    description = data.get('description', '')
    try:
        return PlantModel(modal=modal, dynamics=dynamics, effects=tuple(effects),
                          sample_period=sample_period, description=str(description or ''))
    except ConfigurationError as err:
        raise ConfigurationError(f'{source}: {err}') from None


_HEADER = """\
# galvo_sysid plant model (see galvo_sysid/model/io.py and docs/discrepancy.md).
# Units: angles deg, currents A, times s, frequencies rad/s, residues and k0 deg/(A s^2).
"""


def model_to_yaml(model: PlantModel) -> str:
    """The model as YAML text (with a short header comment)."""
    body = str(yaml.safe_dump(model_to_dict(model), sort_keys=False, default_flow_style=None))
    return _HEADER + body


def model_from_yaml(text: str, *, source: str = 'model') -> PlantModel:
    """Parse YAML text into a model.

    Raises:
        ConfigurationError: Not YAML, or not a valid plant model.
    """
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise ConfigurationError(f'{source}: not valid YAML: {" ".join(str(err).split())}') \
            from None
    return model_from_dict(data, source=source)


def save_model(model: PlantModel, path: str | os.PathLike[str]) -> Path:
    """Write the model as YAML; return the path written."""
    out = Path(path)
    out.write_text(model_to_yaml(model), encoding='utf-8')
    return out


def load_model(path: str | os.PathLike[str]) -> PlantModel:
    """Read a model from a YAML file.

    Raises:
        InvalidDataError: The file cannot be read.
        ConfigurationError: It is not a valid plant model.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding='utf-8')
    except OSError as err:
        raise InvalidDataError(f'cannot read plant model {p}: {err.strerror or err}') from None
    except UnicodeDecodeError:
        raise InvalidDataError(f'cannot read plant model {p}: not a text file') from None
    return model_from_yaml(text, source=str(p))


# --------------------------------------------------------------------------- simulator


def to_plant_spec(model: PlantModel) -> PlantSpec:
    """The simulator's :class:`~galvo_sysid.model.effects.PlantSpec` of the same plant.

    Use it as ``SimulatorConfig(plant=to_plant_spec(load_model(path)))``.

    Raises:
        ConfigurationError: The simulator's sample period differs from the model's or an
            effect is out of its range.
    """
    from galvo_sysid.model.effects import PlantEffects, PlantSpec

    effects = PlantEffects.from_list([e.to_dict() for e in model.effects],
                                     dynamics=model.dynamics,
                                     sample_period=model.sample_period)
    return PlantSpec(model=model.modal, dynamics=model.dynamics, effects=effects)


def from_plant_spec(spec: PlantSpec, *, sample_period: float = TAU,
                    description: str = '') -> PlantModel:
    """The :class:`PlantModel` of a simulator plant (inverse of :func:`to_plant_spec`)."""
    items = spec.effects.to_list(dynamics=spec.dynamics, sample_period=sample_period)
    model = PlantModel(modal=spec.model, dynamics=spec.dynamics, sample_period=sample_period,
                       description=description)
    for item in items:
        model = model.with_effect(item['effect'], item['parameters'])
    return model


def load_plant_spec(path: str | os.PathLike[str]) -> PlantSpec:
    """Read a model file straight into the simulator's plant (see :func:`to_plant_spec`)."""
    return to_plant_spec(load_model(path))

