"""``galvo-sysid plan``: what the data of a deployment will allow, before recording any.

An engineer deploying the monitor asks: how precisely will each parameter be known from a
window of N moves of this mix? How many moves until a given change (e.g. omega_3 -1 %) is
detectable at the watchdog's n_sigma? What is the smallest dither that reaches a requested
accuracy, and what position error does it cost?

:func:`plan` answers from the scanner's model file: it simulates a probe window of moves per
target angle (the closed-loop simulator with the model as the plant, its controller designed
from the model, the given profile, noise and dither), evaluates the Cramer-Rao bound the
refined fit reports at the model's own parameters
(:func:`~galvo_sysid.ident.refine.bound.crlb_at`), and scales it to the number of moves (the
bound falls as 1 / sqrt(moves)). The answers are as good as the simulator's noise levels are
for the real machine: give the measured ones (``current_noise``, ``encoder_noise``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.ident.refine.bound import crlb_at
from galvo_sysid.ident.refine.options import DEFAULT_RESOLVE_Z as RESOLVE_Z
from galvo_sysid.model.modal import parameter_mode
from galvo_sysid.model.paper import PSI
from galvo_sysid.sim.config import SimulatorConfig
from galvo_sysid.sim.dither import MAX_DITHER, DitherConfig
from galvo_sysid.sim.profiles import ProfileConfig
from galvo_sysid.sim.simulator import simulate_window

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from galvo_sysid.model.plant import PlantModel

__all__ = ['DITHER_STEPS', 'Plan', 'plan']

PROBE_MOVES = 60
"""Moves per angle simulated to evaluate the bound (then scaled to the planned number)."""

DITHER_STEPS = (0.0, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2)
"""Dither amplitudes [A] tried when searching the smallest one that reaches a target."""


@dataclass(frozen=True)
class Plan:
    """What a deployment's data allow (see the module docs).

    Attributes:
        model: The plant model's parameters (the truth of the plan).
        angles: Target angles of the move mix [deg].
        moves: Moves per window.
        dither: The dither planned.
        window_std: Per angle, the Cramer-Rao std of every parameter from one window.
        pooled_std: The same for one window of every angle together.
        unresolved: Modes (1-based) whose residue's std from one window (at the best angle)
            exceeds a fifth of it: single windows will not place them (their frequency and
            damping bounds are local and say nothing; the refined fit reports such a mode
            unresolved).
        position_error: Rms position error the dither adds [deg] (noise-free simulation).
        encoder_resolution: The encoder's count [deg] (to say the error in counts).
        moves_to_detect: Per parameter of ``change``: moves per window for the change to
            exceed ``n_sigma`` std at the best angle and, for a mode's parameter, for the
            window to resolve the mode (its residue beyond 5 std; the watchdog does not
            judge an unresolved mode) (None: more than 10^7).
        n_sigma: The significance of ``moves_to_detect``.
        dither_for_target: Per parameter of ``target``: the smallest dither amplitude [A]
            (of :data:`DITHER_STEPS`) at the planned frequencies whose pooled std reaches
            the target, with its position error [deg] (None: none does).
    """

    model: dict[str, float]
    angles: tuple[float, ...]
    moves: int
    dither: DitherConfig
    window_std: dict[float, dict[str, float]]
    pooled_std: dict[str, float]
    unresolved: tuple[int, ...]
    position_error: float
    encoder_resolution: float
    moves_to_detect: dict[str, int | None] = field(default_factory=dict)
    n_sigma: float = 3.0
    dither_for_target: dict[str, tuple[float, float] | None] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        from galvo_sysid.jsonsafe import json_safe

        return dict(json_safe({
            'model': self.model, 'angles': list(self.angles), 'moves': self.moves,
            'dither': {'amplitude': self.dither.amplitude,
                       'frequencies': None if self.dither.frequencies is None
                       else list(self.dither.frequencies)},
            'window_std': {str(a): s for a, s in self.window_std.items()},
            'pooled_std': self.pooled_std, 'unresolved': list(self.unresolved),
            'position_error': self.position_error,
            'position_error_counts': self.position_error / self.encoder_resolution
            if self.encoder_resolution > 0 else None,
            'moves_to_detect': self.moves_to_detect, 'n_sigma': self.n_sigma,
            'dither_for_target': {k: None if v is None else {'amplitude': v[0],
                                                              'position_error': v[1]}
                                  for k, v in self.dither_for_target.items()}}))


def _config(model: PlantModel, *, profile: ProfileConfig, dither: DitherConfig,
            current_noise: float | None, encoder_noise: float | None) -> SimulatorConfig:
    base = SimulatorConfig(plant=model, profile=profile, dither=dither)
    return replace(base,
                   current_noise_std=base.current_noise_std if current_noise is None
                   else current_noise,
                   measurement_noise_std=base.measurement_noise_std if encoder_noise is None
                   else encoder_noise)


def _bounds(model: PlantModel, config: SimulatorConfig, angles: Sequence[float], moves: int,
            seed: int) -> tuple[dict[float, dict[str, float]], dict[str, float]]:
    """Per-angle and pooled Cramer-Rao std for windows of ``moves`` moves."""
    per_angle: dict[float, dict[str, float]] = {}
    info: dict[str, float] = {}
    scale = math.sqrt(PROBE_MOVES / moves)
    for j, angle in enumerate(angles):
        cur, enc = simulate_window(angle, moves=PROBE_MOVES, seed=seed + j, config=config)
        std = crlb_at([(cur, enc)], sample_period=model.sample_period, model=model.modal,
                      dynamics=model.dynamics)
        per_angle[angle] = {k: v * scale for k, v in std.items()}
        for k, v in per_angle[angle].items():
            info[k] = info.get(k, 0.0) + (1.0 / v**2 if v > 0 else math.inf)
    pooled = {k: (1.0 / math.sqrt(v) if v > 0 else math.inf) for k, v in info.items()}
    return per_angle, pooled


def _position_error(config: SimulatorConfig, angle: float) -> float:
    """Rms of what the dither adds to the angle (noise-free simulation, last of 3 moves)."""
    if not config.dither.active:
        return 0.0
    quiet = replace(config, encoder_resolution=0.0, measurement_noise_std=0.0,
                    current_noise_std=0.0)
    _, with_dither = simulate_window(angle, moves=3, seed=0, config=quiet)
    _, without = simulate_window(angle, moves=3, seed=0,
                                 config=replace(quiet, dither=DitherConfig()))
    return float(np.sqrt(np.mean((with_dither[-1] - without[-1]) ** 2)))


def plan(model: PlantModel, *, angles: Sequence[float] | None = None, moves: int = 100,
         dither: DitherConfig | None = None, profile: ProfileConfig | None = None,
         current_noise: float | None = None, encoder_noise: float | None = None,
         change: Mapping[str, float] | None = None, n_sigma: float = 3.0,
         target: Mapping[str, float] | None = None, seed: int = 0) -> Plan:
    """Plan a deployment (see the module docs).

    Args:
        model: The scanner's plant model (the truth the plan assumes).
        angles: Target angles of the move mix [deg] (default 0.3 deg, the paper's 1 psi).
        moves: Moves per window.
        dither: Planned dither (default none).
        profile: Move profile (default the simulator's).
        current_noise: Rms current noise [A] (default the simulator's).
        encoder_noise: Rms encoder noise before quantisation [deg] (default the simulator's).
        change: Relative parameter changes to detect, e.g. ``{'omega_3': -0.01}``.
        n_sigma: Significance at which a change counts as detected.
        target: Relative std wanted per parameter, e.g. ``{'zeta_3': 0.1}``; the dither
            frequencies are the planned ones (default the model's resonances).
        seed: Noise seed of the probe windows.

    Returns:
        The plan.

    Raises:
        ConfigurationError: Bad options or unknown parameter names.
        GalvoSysidError: The scanner cannot make the moves.
    """
    if isinstance(moves, bool) or not isinstance(moves, int) or not 3 <= moves <= 10**6:
        raise ConfigurationError(f'moves must be a whole number in 3..1000000, got {moves!r}')
    if not (math.isfinite(n_sigma) and n_sigma > 0):
        raise ConfigurationError(f'n_sigma must be positive, got {n_sigma!r}')
    names = model.modal.parameters()
    for label, given in (('change', change or {}), ('target', target or {})):
        for name, value in given.items():
            if name not in names:
                raise ConfigurationError(f'{label}: unknown parameter {name!r} (the model has '
                                         f'{", ".join(names)})')
            if not (math.isfinite(value) and value != 0 and (label == 'change' or value > 0)):
                raise ConfigurationError(f'{label}: bad value {value!r} for {name}')
    planned = dither or DitherConfig()
    angle_list = tuple(float(a) for a in (angles or (PSI,)))
    if not angle_list or not all(math.isfinite(a) and a != 0 for a in angle_list):
        raise ConfigurationError('angles must be finite and non-zero')
    config = _config(model, profile=profile or ProfileConfig(), dither=planned,
                     current_noise=current_noise, encoder_noise=encoder_noise)
    per_angle, pooled = _bounds(model, config, angle_list, moves, seed)
    detect: dict[str, int | None] = {}
    for name, rel in (change or {}).items():
        delta = abs(rel * names[name])
        best = min(s[name] for s in per_angle.values())
        need = math.ceil(moves * (n_sigma * best / delta) ** 2)
        mode = parameter_mode(name)
        if mode:  # the watchdog judges a mode's parameters only where the window resolves it
            k = f'k{mode}'
            k_best = min(s[k] for s in per_angle.values())
            need = max(need, math.ceil(moves * (RESOLVE_Z * k_best / abs(names[k])) ** 2))
        detect[name] = need if need <= 10**7 else None
    for_target: dict[str, tuple[float, float] | None] = {}
    if target:
        for_target = _dither_search(model, config, angle_list, moves, seed, target, names)
    unresolved = tuple(i for i in range(1, model.n_modes + 1)
                       if not min(s[f'k{i}'] for s in per_angle.values()) * RESOLVE_Z
                       <= abs(names[f'k{i}']))
    return Plan(model=dict(names), angles=angle_list, moves=moves, dither=planned,
                window_std=per_angle, pooled_std=pooled, unresolved=unresolved,
                position_error=max(_position_error(config, a) for a in angle_list),
                encoder_resolution=config.encoder_resolution, moves_to_detect=detect,
                n_sigma=n_sigma, dither_for_target=for_target)


def _dither_search(model: PlantModel, config: SimulatorConfig, angles: tuple[float, ...],
                   moves: int, seed: int, target: Mapping[str, float],
                   names: dict[str, float]) -> dict[str, tuple[float, float] | None]:
    """The smallest dither of :data:`DITHER_STEPS` meeting each target, and its cost."""
    out: dict[str, tuple[float, float] | None] = dict.fromkeys(target)
    for amplitude in DITHER_STEPS:
        if amplitude > MAX_DITHER or all(v is not None for v in out.values()):
            break
        trial = replace(config, dither=replace(config.dither, amplitude=amplitude))
        _, pooled = _bounds(model, trial, angles, moves, seed)
        cost: float | None = None
        for name, rel in target.items():
            if out[name] is None and pooled[name] <= rel * abs(names[name]):
                if cost is None:
                    cost = max(_position_error(trial, a) for a in angles)
                out[name] = (amplitude, cost)
    return out
