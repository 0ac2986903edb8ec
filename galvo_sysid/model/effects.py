"""The one registry of physical effects: names, parameters, their checks and how each acts.

A plant model (:class:`~galvo_sysid.model.plant.PlantModel`) is the modal model plus a list
of :class:`Effect` s. Each effect type of :data:`EFFECTS` says its parameters (unit, range,
meaning) and how it acts on the running plant (:class:`~galvo_sysid.model.physics.Physics`).
The model file, the simulator, the ``galvo_driver``'s ``effects`` parameter, ``galvo-sysid
simulate --effect`` and the discrepancy workflow all go through this registry, so adding an
effect is one entry here (plus, for new physics, its action in the simulator and the
discrepancy plant).

=======================  =====================================================================
effect                   parameters
=======================  =====================================================================
``input_delay``          ``delay`` [s]: the total equivalent input delay (computation delay +
                         lag + dead time; the paper's scanner has 1.6 tau). It adds dead time,
                         so it is at least the input dynamics' equivalent delay.
``unmodeled_resonance``  ``natural_frequency`` [rad/s], ``damping_ratio``, ``residue``
                         [deg/(A s^2)]: an extra mode k / (s^2 + 2 zeta omega s + omega^2).
``coulomb_friction``     ``friction_current`` [A]: Coulomb friction on the rigid-body motion
                         as the current whose torque equals it.
``pivot_stiffness``      ``natural_frequency`` [rad/s]: a spring (centred at 0 deg) turning
                         the rigid body k0/s^2 into k0/(s^2 + w^2).
``gain_change``          ``gain_ratio``: the torque constant relative to the modal model (it
                         scales the current's torque, not the friction).
``current_saturation``   ``current_limit`` [A]: the amplifier's output current is clipped.
``viscous_friction``     ``current_per_velocity`` [A s/deg]: viscous friction on the rigid-body
                         motion, as a current proportional to its velocity (it damps the rigid
                         body: k0/(s^2 + k0 b s + w_p^2)).
``cogging_torque``       ``amplitude`` [A], ``period`` [deg], ``phase`` [rad]: a torque
                         periodic in the rotor's (rigid-body) angle p, amplitude sin(2 pi p /
                         period + phase), as an equivalent current (cogging, torque ripple that
                         does not depend on the current).
``encoder_cyclic_error`` ``amplitude`` [deg], ``period`` [deg], ``phase`` [rad]: the encoder
                         reads y + amplitude sin(2 pi y / period + phase): an error of the
                         reading, not of the torque (the controller acts on it, the shaft does
                         not feel it); 2 pi amplitude / period must stay below 0.5.
``amplifier_bandwidth``  ``bandwidth`` [Hz]: the current amplifier's first-order lag has this
                         -3 dB bandwidth (lag time constant 1 / (2 pi bandwidth); inf: no lag).
                         It acts before an ``input_delay``, whose total equivalent delay stays.
``proposed_terms``       the discrepancy fallback's dictionary terms (:mod:`.terms`): one
                         coefficient per term, e.g. ``current_x3`` [A/deg^3] (an extra current
                         c x^3 of the rotor's angle) or ``reading_x_absx`` [1/deg] (the encoder
                         reads y + c y|y|), and amplitude, period [deg] and phase [rad] of the
                         periodic ones (``current_sin_*``, ``current_i_sin_*``,
                         ``reading_sin_*``); every parameter defaults to 0 (absent). A
                         data-driven proposal, not a named effect: the discrepancy workflow
                         never tries it as a candidate (:data:`CANDIDATE_NAMES`).
=======================  =====================================================================
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model.terms import PERIODIC_TERMS, TERMS

if TYPE_CHECKING:
    from galvo_sysid.model.physics import Physics

__all__ = [
    'CANDIDATE_NAMES',
    'EFFECTS',
    'EFFECT_NAMES',
    'MAX_EFFECTS',
    'MAX_JSON_DEPTH',
    'Effect',
    'EffectType',
    'ParameterSpec',
    'effects_from_json',
    'effects_from_list',
    'parse_effect',
]

MAX_EFFECTS = 32
"""Most effects one model may carry."""

MAX_JSON_DEPTH = 8
"""Deepest nesting of brackets in effects given as JSON (the list form needs 3)."""


@dataclass(frozen=True)
class ParameterSpec:
    """One parameter of an effect: unit, meaning and allowed range.

    Attributes:
        name: Parameter name.
        unit: Unit, for help texts.
        description: What it is.
        low: Smallest value.
        high: Largest value (``inf`` allowed only with ``allow_inf``).
        low_open: The value must be strictly above ``low``.
        allow_inf: ``inf`` means "none" (e.g. no current limit).
        default: The value when the parameter is not given (None: it must be given).
    """

    name: str
    unit: str
    description: str
    low: float = -math.inf
    high: float = math.inf
    low_open: bool = False
    allow_inf: bool = False
    default: float | None = None

    def check(self, effect: str, value: Any) -> float:
        """Return ``value`` as a float if allowed, else raise ConfigurationError."""
        if isinstance(value, bool) or not isinstance(value, int | float | str):
            raise ConfigurationError(f'{effect}: {self.name} must be a number, got {value!r}')
        try:
            v = float(value)
        except (ValueError, OverflowError):  # not a number, an integer beyond float
            raise ConfigurationError(
                f'{effect}: {self.name} must be a number, got {value!r}') from None
        if math.isnan(v) or (math.isinf(v) and not (self.allow_inf and v > 0)):
            raise ConfigurationError(f'{effect}: {self.name} must be finite, got {value!r}')
        too_low = v <= self.low if self.low_open else v < self.low
        if too_low or (v > self.high and not (self.allow_inf and math.isinf(v))):
            low = f'> {self.low:g}' if self.low_open else f'>= {self.low:g}'
            raise ConfigurationError(
                f'{effect}: {self.name} must be {low} and <= {self.high:g} {self.unit}, '
                f'got {value!r}')
        return v


@dataclass(frozen=True)
class EffectType:
    """One kind of physical effect.

    Attributes:
        name: The effect's name in files, JSON and on the command line.
        description: One line for help texts.
        parameters: Its parameters, in order.
        act: How it acts: ``act(physics, parameters) -> physics``.
        linear: Whether the plant stays linear with it.
        repeatable: Whether a model may carry several of it.
        order: Effects act in this order (stable within equal orders; the amplifier's
            bandwidth before the input delay, whose total it keeps).
        candidate: Whether the discrepancy workflow tries it as a candidate (the fallback's
            ``proposed_terms`` is loaded and simulated, never named by the search).
    """

    name: str
    description: str
    parameters: tuple[ParameterSpec, ...]
    act: Callable[[Physics, Mapping[str, float]], Physics]
    linear: bool = True
    repeatable: bool = False
    order: int = 0
    candidate: bool = True

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """The parameter names, in order."""
        return tuple(p.name for p in self.parameters)


def _input_delay(ph: Physics, p: Mapping[str, float]) -> Physics:
    extra = p['delay'] - ph.computation_delay * ph.sample_period - ph.lag_time_constant
    if extra < -1e-9 * ph.sample_period:
        nominal = ph.pure_delay + ph.lag_time_constant - ph.dead_time
        raise ConfigurationError(f'input_delay: delay {p["delay"]!r} s is below the input '
                                 f"dynamics' equivalent delay {nominal!r} s")
    return replace(ph, dead_time=max(extra, 0.0))


def _resonance(ph: Physics, p: Mapping[str, float]) -> Physics:
    return replace(ph, residues=(*ph.residues, p['residue']),
                   natural_frequencies=(*ph.natural_frequencies, p['natural_frequency']),
                   damping_ratios=(*ph.damping_ratios, p['damping_ratio']))


_FREQUENCY = ParameterSpec('natural_frequency', 'rad/s', 'natural frequency', 0.0, 1e8,
                           low_open=True)


def _periodic(unit: str, what: str, largest: float) -> tuple[ParameterSpec, ...]:
    """Amplitude, period [deg] and phase [rad] of an effect periodic in the angle."""
    return (ParameterSpec('amplitude', unit, f'{what} amplitude', 0.0, largest),
            ParameterSpec('period', 'deg', 'period in the angle', 0.0, 360.0, low_open=True),
            ParameterSpec('phase', 'rad', 'phase at 0 deg', -math.pi, math.pi))


def _proposed_parameters() -> tuple[ParameterSpec, ...]:
    """One coefficient per dictionary term (default 0: absent), then amplitude, period and
    phase of each periodic family (:mod:`galvo_sysid.model.terms`)."""  # noqa: D205, D209
    out = [ParameterSpec(t.parameter, t.unit, f'coefficient of {t.expression} on the '
                         f'{t.side}', -1e12, 1e12, default=0.0) for t in TERMS]
    for f in PERIODIC_TERMS:
        largest = 1e3 if f.side == 'current' and not f.times_current else 10.0
        out += [ParameterSpec(f'{f.prefix}_amplitude', f.unit, f'amplitude of {f.expression} '
                              f'on the {f.side}', 0.0, largest, default=0.0),
                ParameterSpec(f'{f.prefix}_period', 'deg', 'its period P in the angle', 0.0,
                              360.0, low_open=True, default=1.0),
                ParameterSpec(f'{f.prefix}_phase', 'rad', 'its phase at 0 deg', -math.pi,
                              math.pi, default=0.0)]
    return tuple(out)


def _proposed(ph: Physics, p: Mapping[str, float]) -> Physics:
    amplitudes = {f'{f.prefix}_amplitude' for f in PERIODIC_TERMS}
    present = {f.prefix for f in PERIODIC_TERMS if p[f'{f.prefix}_amplitude']}
    kept = tuple((k, v) for k, v in p.items()
                 if (v and k not in amplitudes and not k.endswith(('_period', '_phase'))) or
                 k.rsplit('_', 1)[0] in present)
    return replace(ph, terms=kept)


def _bandwidth(ph: Physics, p: Mapping[str, float]) -> Physics:
    f = p['bandwidth']
    return replace(ph, lag_time_constant=0.0 if math.isinf(f) else 1.0 / (2 * math.pi * f))

EFFECTS: dict[str, EffectType] = {e.name: e for e in (
    EffectType('input_delay', 'the total equivalent input delay is longer than modelled',
               (ParameterSpec('delay', 's', 'total equivalent input delay (computation delay '
                              '+ lag + dead time)', 0.0, 0.01, low_open=True),),
               _input_delay),
    EffectType('unmodeled_resonance', 'a resonant mode the model lacks',
               (_FREQUENCY,
                ParameterSpec('damping_ratio', '', 'damping ratio', 0.0, 1.0, low_open=True),
                ParameterSpec('residue', 'deg/(A s^2)', 'residue', -1e15, 1e15)),
               _resonance, repeatable=True),
    EffectType('coulomb_friction', 'Coulomb friction on the rigid-body motion',
               (ParameterSpec('friction_current', 'A', 'friction torque as a current',
                              0.0, 1e3),),
               lambda ph, p: replace(ph, friction_current=p['friction_current']),
               linear=False),
    EffectType('pivot_stiffness', 'a spring turning the rigid body into k0/(s^2 + w^2)',
               (_FREQUENCY,),
               lambda ph, p: replace(ph, pivot_frequency=p['natural_frequency'])),
    EffectType('gain_change', 'the torque constant differs from the model',
               (ParameterSpec('gain_ratio', '', 'torque constant relative to the model',
                              0.0, 100.0, low_open=True),),
               lambda ph, p: replace(ph, gain_ratio=p['gain_ratio'])),
    EffectType('current_saturation', "the amplifier's output current is clipped",
               (ParameterSpec('current_limit', 'A', 'current limit', 0.0, 1e9, low_open=True,
                              allow_inf=True),),
               lambda ph, p: replace(ph, current_limit=p['current_limit']), linear=False),
    EffectType('viscous_friction', 'viscous friction on the rigid-body motion',
               (ParameterSpec('current_per_velocity', 'A s/deg',
                              'friction current per rigid-body velocity', 0.0, 1.0),),
               lambda ph, p: replace(ph, viscous_coefficient=p['current_per_velocity'])),
    EffectType('cogging_torque', "a torque periodic in the rotor's angle (cogging)",
               _periodic('A', 'torque (as a current)', 1e3),
               lambda ph, p: replace(ph, cogging_amplitude=p['amplitude'],
                                     cogging_period=p['period'], cogging_phase=p['phase']),
               linear=False),
    EffectType('encoder_cyclic_error', "a cyclic error of the encoder's reading",
               _periodic('deg', 'reading error', 10.0),
               lambda ph, p: replace(ph, encoder_error_amplitude=p['amplitude'],
                                     encoder_error_period=p['period'],
                                     encoder_error_phase=p['phase']),
               linear=False),
    EffectType('amplifier_bandwidth', "the current amplifier's bandwidth differs",
               (ParameterSpec('bandwidth', 'Hz', '-3 dB bandwidth of the amplifier lag', 0.0,
                              1e9, low_open=True, allow_inf=True),),
               _bandwidth, order=-1),
    EffectType('proposed_terms', "the discrepancy fallback's dictionary terms (a proposal, "
               'not a named effect)', _proposed_parameters(), _proposed, linear=False,
               candidate=False),
)}
"""The registry: every effect type by name."""

EFFECT_NAMES: tuple[str, ...] = tuple(EFFECTS)
"""The effect names (besides ``none``, which the discrepancy workflow reports for no effect)."""

CANDIDATE_NAMES: tuple[str, ...] = tuple(n for n, e in EFFECTS.items() if e.candidate)
"""The effects the discrepancy workflow tries as candidates (all but ``proposed_terms``)."""


@dataclass(frozen=True)
class Effect:
    """One physical effect with its parameters; build it with :meth:`create`.

    Attributes:
        name: One of :data:`EFFECT_NAMES`.
        parameters: ``(name, value)`` pairs in the order of the effect type's parameters.
    """

    name: str
    parameters: tuple[tuple[str, float], ...]

    @classmethod
    def create(cls, name: str, parameters: Mapping[str, Any]) -> Effect:
        """Check and build an effect.

        Raises:
            ConfigurationError: Unknown effect, wrong parameter names or bad values.
        """
        kind = EFFECTS.get(name) if isinstance(name, str) else None
        if kind is None:
            raise ConfigurationError(
                f'unknown effect {name!r}; expected one of {", ".join(EFFECT_NAMES)}')
        if not isinstance(parameters, Mapping):
            raise ConfigurationError(f'{name}: parameters must be a mapping, got '
                                     f'{type(parameters).__name__}')
        expected = kind.parameter_names
        required = {p.name for p in kind.parameters if p.default is None}
        if not required <= set(parameters) <= set(expected):
            raise ConfigurationError(
                f'effect {name!r} takes parameters {list(expected)}, got '
                f'{sorted(str(k) for k in parameters)}')
        values = tuple((p.name, p.check(name, parameters.get(p.name, p.default)))
                       for p in kind.parameters)
        return cls(name=name, parameters=values)

    @property
    def kind(self) -> EffectType:
        """The effect's type in the registry."""
        return EFFECTS[self.name]

    def params(self) -> dict[str, float]:
        """The parameters as a dict."""
        return dict(self.parameters)

    def act(self, physics: Physics) -> Physics:
        """The plant with this effect acting on it."""
        return self.kind.act(physics, self.params())

    def given(self) -> dict[str, float]:
        """The parameters that differ from their defaults (all of an effect without any)."""
        defaults = {p.name: p.default for p in self.kind.parameters}
        return {k: v for k, v in self.parameters if defaults[k] is None or v != defaults[k]}

    def to_dict(self) -> dict[str, Any]:
        """``{'effect': name, 'parameters': {...}}`` (parameters at their default left out)."""
        return {'effect': self.name, 'parameters': self.given()}

    def __str__(self) -> str:
        inner = ', '.join(f'{k}={v:.6g}' for k, v in self.given().items())
        return f'{self.name}({inner})'


def effects_from_list(items: Any, *, where: str = 'effects') -> tuple[Effect, ...]:
    """Effects from ``[{'effect': NAME, 'parameters': {...}}, ...]`` (``none`` entries skipped).

    Raises:
        ConfigurationError: Not such a list, too long, or a bad entry (the message names it).
    """
    if not isinstance(items, Sequence) or isinstance(items, str | bytes):
        raise ConfigurationError(f'{where} must be a list of {{effect: NAME, parameters: '
                                 f'{{...}}}}')
    if len(items) > MAX_EFFECTS:
        raise ConfigurationError(f'{where}: at most {MAX_EFFECTS} effects, got {len(items)}')
    out = []
    for i, item in enumerate(items, start=1):
        if not isinstance(item, Mapping) or set(item) != {'effect', 'parameters'}:
            raise ConfigurationError(
                f'{where}[{i}] must be {{effect: NAME, parameters: {{...}}}}')
        if item['effect'] == 'none':
            continue
        try:
            out.append(Effect.create(item['effect'], item['parameters']))
        except ConfigurationError as err:
            raise ConfigurationError(f'{where}[{i}]: {err}') from None
    return tuple(out)


def parse_effect(text: str) -> Effect:
    """``NAME:KEY=VALUE[,KEY=VALUE...]`` (the command line's form) -> :class:`Effect`.

    Raises:
        ConfigurationError: Bad syntax or a bad effect.
    """
    name, _, rest = text.partition(':')
    params: dict[str, float] = {}
    for item in filter(None, (p.strip() for p in rest.split(','))):
        key, sep, value = item.partition('=')
        try:
            if not sep:
                raise ValueError(item)
            number = float(value)
        except ValueError:
            msg = f'bad effect {text!r}: expected NAME:KEY=VALUE[,KEY=VALUE...]'
            raise ConfigurationError(msg) from None
        if key.strip() in params:
            raise ConfigurationError(f'bad effect {text!r}: {key.strip()} given twice')
        params[key.strip()] = number
    if not name.strip():
        raise ConfigurationError(f'bad effect {text!r}: no effect name')
    return Effect.create(name.strip(), params)


def _json_depth(text: str) -> int:
    """The deepest nesting of ``[`` / ``{`` in ``text`` outside JSON strings (no parsing)."""
    depth = deepest = 0
    in_string = escaped = False
    for c in text:
        if in_string:
            if escaped:
                escaped = False
            elif c == '\\':
                escaped = True
            elif c == '"':
                in_string = False
        elif c == '"':
            in_string = True
        elif c in '[{':
            depth += 1
            deepest = max(deepest, depth)
        elif c in ']}':
            depth -= 1
    return deepest


def _json_constant(name: str) -> Any:
    raise ConfigurationError(f'{name} is not a JSON number')


def _json_int(text: str) -> int:
    if len(text.lstrip('-')) > 20:
        raise ConfigurationError(f'integer {text[:20]}... is too long')
    return int(text)


def effects_from_json(text: str, *, where: str = 'effects',
                      max_chars: int = 65_536) -> tuple[Effect, ...]:
    """Effects from their JSON list (the ``galvo_driver``'s ``effects`` parameter): the size
    and the nesting are bounded before parsing, numbers must be JSON numbers (no strings,
    NaN or Infinity), then :func:`effects_from_list` checks each entry with the registry.

    Args:
        text: ``[{"effect": NAME, "parameters": {...}}, ...]`` ("" is no effect).
        where: How an error names the value.
        max_chars: Longest text accepted.

    Raises:
        ConfigurationError: Too long, nested too deeply, not valid JSON, or a bad effect
            (one line naming the entry).
    """  # noqa: D205
    if not isinstance(text, str):
        raise ConfigurationError(f'{where} must be JSON text, got {type(text).__name__}')
    if len(text) > max_chars:
        raise ConfigurationError(f'{where}: longer than {max_chars} characters')
    if _json_depth(text) > MAX_JSON_DEPTH:
        raise ConfigurationError(f'{where}: JSON nested deeper than {MAX_JSON_DEPTH}')
    try:
        items = json.loads(text or '[]', parse_constant=_json_constant, parse_int=_json_int)
    except ConfigurationError as err:
        raise ConfigurationError(f'{where}: {err}') from None
    except (ValueError, RecursionError) as err:  # JSONDecodeError is a ValueError
        raise ConfigurationError(f'{where} is not valid JSON: {err}') from None
    if isinstance(items, list):
        for i, item in enumerate(items, start=1):
            params = item.get('parameters') if isinstance(item, dict) else None
            for key, value in (params.items() if isinstance(params, dict) else ()):
                if isinstance(value, str):
                    text_value = value if len(value) <= 40 else f'{value[:37]}...'
                    raise ConfigurationError(f'{where}[{i}]: {item.get("effect")!s:.40}: '
                                             f'{key!s:.40} must be a number, got '
                                             f'{text_value!r}')
    return effects_from_list(items, where=where)
