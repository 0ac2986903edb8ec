"""An independent simulator of effects outside the effect registry (issue 14).

The discrepancy workflow must say `unexplained`, never a wrong name, when the scanner has an
effect its candidates do not include. These effects are implemented here only, in the test
and benchmark data generation, never in ``galvo_sysid``: the package's closed loop (plant,
controller, noise, quantised encoder) with a per-sample update of its own on top, so the
workflow cannot have been fitted to them.

Each effect is a torque (an equivalent current at the nominal torque constant, acting on the
rigid body, like friction) of the rigid body's angle p [deg], velocity v [deg/s] and the
amplifier's current i [A], or an error of the encoder's reading of the angle y [deg]. The
torques are integrated over ``SUBSTEPS`` sub-steps per sample, each evaluated at the
sub-step's start (a discretisation the package does not use). Used by test_heldout.py and
benchmarks/discrepancy_confusion.py (which puts this directory on sys.path).

==================  ===============================================  ========================
effect              law                                              parameters
==================  ===============================================  ========================
viscous             d = -b v                                         b [A s/deg]
cogging             d = a sin(2 pi p / P + phi)                      a [A], P [deg], phi
encoder_cyclic      reading y + a sin(2 pi y / P + phi)              a [deg], P [deg], phi
quadratic_drag      d = -c v |v|                                     c [A s^2/deg^2]
cubic_spring        d = -kappa p^3                                   kappa [A/deg^3]
commutation_ripple  d = r sin(2 pi p / P + phi) i (torque constant)  r, P [deg], phi
encoder_scale_bow   reading y + c y |y| (scale error grows with y)   c [1/deg]
backlash_spring     d = -kappa (p - q), q follows p within +-w / 2   kappa [A/deg], w [deg]
mode_shift          the model's mode ``mode`` is off by ``relative``  mode, relative
mode_drift          that mode drifts by ``relative`` over the moves   mode, relative
==================  ===============================================  ========================

``viscous``, ``cogging`` and ``encoder_cyclic`` are the three effects of the issue's report
(its independent simulator); they are library effects once the registry has them, and then
serve as a cross-check of the registry's own simulation. The others stay outside the library.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace

import numpy as np

from galvo_sysid.discrepancy import MoveSet
from galvo_sysid.model import PAPER_MODEL
from galvo_sysid.model.changes import Drift
from galvo_sysid.model.plant import PlantModel
from galvo_sysid.sim.config import SimulatorConfig
from galvo_sysid.sim.loop import ClosedLoop
from galvo_sysid.sim.simulator import GalvoSimulator

SUBSTEPS = 4
"""Sub-steps per sample over which a torque is held (evaluated at each sub-step's start)."""

TORQUES = ('viscous', 'cogging', 'quadratic_drag', 'cubic_spring', 'commutation_ripple',
           'backlash_spring')
READINGS = ('encoder_cyclic', 'encoder_scale_bow')
MODAL = ('mode_shift', 'mode_drift')
"""Model errors of the scanner's own modes (through the package's plant changes)."""

HELDOUT = ('quadratic_drag', 'cubic_spring', 'commutation_ripple', 'encoder_scale_bow',
           'backlash_spring', 'mode_shift', 'mode_drift')
"""Effects no candidate of the workflow includes."""


@dataclass(frozen=True)
class Hidden:
    """One effect of this module with its parameters (hashable, for caches)."""

    name: str
    params: tuple[tuple[str, float], ...]

    @classmethod
    def of(cls, name: str, **params: float) -> Hidden:
        if name not in (*TORQUES, *READINGS, *MODAL):
            raise ValueError(f'unknown held-out effect {name!r}')
        return cls(name, tuple(sorted(params.items())))

    @property
    def p(self) -> dict[str, float]:
        return dict(self.params)

    def __str__(self) -> str:
        return f'{self.name}(' + ', '.join(f'{k}={v:.4g}' for k, v in self.params) + ')'


def _torque(h: Hidden) -> Callable[[float, float, float, list[float]], float]:
    """d(p, v, i, memory) [A] of a torque effect (memory: state of a hysteretic law)."""
    p = h.p
    if h.name == 'viscous':
        b = p['b']
        return lambda pos, vel, cur, mem: -b * vel
    if h.name == 'cogging':
        a, k, ph = p['a'], 2 * math.pi / p['P'], p['phi']
        return lambda pos, vel, cur, mem: a * math.sin(k * pos + ph)
    if h.name == 'quadratic_drag':
        c = p['c']
        return lambda pos, vel, cur, mem: -c * vel * abs(vel)
    if h.name == 'cubic_spring':
        kappa = p['kappa']
        return lambda pos, vel, cur, mem: -kappa * pos**3
    if h.name == 'commutation_ripple':
        r, k, ph = p['r'], 2 * math.pi / p['P'], p['phi']
        return lambda pos, vel, cur, mem: r * math.sin(k * pos + ph) * cur
    if h.name == 'backlash_spring':
        kappa, half = p['kappa'], p['w'] / 2

        def backlash(pos: float, vel: float, cur: float, mem: list[float]) -> float:
            q = mem[0]
            if pos - q > half:
                q = pos - half
            elif q - pos > half:
                q = pos + half
            mem[0] = q
            return -kappa * (pos - q)
        return backlash
    raise ValueError(h.name)


def _reading(h: Hidden) -> Callable[[float], float]:
    p = h.p
    if h.name == 'encoder_cyclic':
        a, k, ph = p['a'], 2 * math.pi / p['P'], p['phi']
        return lambda y: y + a * math.sin(k * y + ph)
    if h.name == 'encoder_scale_bow':
        c = p['c']
        return lambda y: y + c * y * abs(y)
    raise ValueError(h.name)


class _HeldOutLoop(ClosedLoop):
    """The package's closed loop with the held-out effects in a per-sample update."""

    def __init__(self, spec: object, controller: object, cfg: SimulatorConfig,
                 effects: tuple[Hidden, ...]) -> None:
        super().__init__(spec, controller, cfg)
        sp = self.sp
        self.torques = [_torque(e) for e in effects if e.name in TORQUES]
        self.readings = [_reading(e) for e in effects if e.name in READINGS]
        h = cfg.sample_period / SUBSTEPS
        from galvo_sysid.model.dynamics import split_delay, zoh

        cp = sp.continuous
        drives = np.stack([cp.b_u, cp.b_d], axis=1)
        self.h_phi, g = zoh(cp.a, drives, h)
        self.h_u, self.h_d = g[:, 0], g[:, 1]
        _, frac = split_delay(spec.pure_delay, cfg.sample_period)
        if frac != 0:
            raise ValueError('the held-out loop needs a whole number of samples of delay')
        self.memory = [0.0]

    def exact_move(self, z, r, ff, n, v, record, quantum):
        nx, nz = self.nx, self.nz
        cp = self.sp.continuous
        pi, vi, ci = cp.position_index, cp.velocity_index, cp.current_index
        w = self.sp.whole
        gain = self.gain
        length = r.shape[0]
        u_rec = np.empty(record)
        y_rec = np.empty(record)
        big = np.vstack([self.az, self.cy, self.cu])
        zk = z.copy()
        mem = self.memory
        for k in range(length):
            out = big @ zk
            y = float(out[nz])
            for read in self.readings:
                y = read(y)
            meas = y + v[k]
            if quantum > 0:
                meas = math.floor(meas / quantum + 0.5) * quantum
            uk = float(out[nz + 1]) + self.dc * (r[k] - meas) + ff[k]
            if k < record:
                u_rec[k] = uk
                y_rec[k] = meas
            z_next = out[:nz] + self.be * (r[k] - meas) + self.bff * ff[k]
            # the plant over the sample, sub-step by sub-step (the register and the
            # controller as the package's loop has them)
            u_cmd = uk if w == 0 else float(zk[nx + w - 1])
            x = zk[:nx].copy()
            for _ in range(SUBSTEPS):
                d = gain * n[k]
                if self.torques:
                    cur = gain * float(x[ci]) if ci is not None else gain * u_cmd
                    for f in self.torques:
                        d += f(float(x[pi]), float(x[vi]), cur, mem)
                x = self.h_phi @ x + self.h_u * u_cmd + self.h_d * d
            z_next[:nx] = x
            zk = z_next
        z[:] = zk
        return u_rec, y_rec


class HeldOutSimulator(GalvoSimulator):
    """:class:`GalvoSimulator` whose closed loop carries effects of this module."""

    def __init__(self, effects: tuple[Hidden, ...], *, config: SimulatorConfig,
                 seed: int) -> None:
        self._effects = effects
        super().__init__(config=replace(config, method='exact'), seed=seed)

    def _loop(self, spec):
        loop = self._loops.get(spec)
        if loop is None:
            loop = _HeldOutLoop(spec, self.controller, self.config, self._effects)
            self._loops[spec] = loop
        return loop


def _config(effects: tuple[Hidden, ...], moves_per_angle: int,
            angles: tuple[float, ...]) -> tuple[SimulatorConfig, tuple[Hidden, ...]]:
    """The package simulator's config (modal errors as plant changes) and the rest."""
    plant: PlantModel = PAPER_MODEL
    drifts = []
    rest = []
    for e in effects:
        if e.name == 'mode_shift':
            m = plant.modal
            i = int(e.p['mode']) - 1
            w = list(m.natural_frequencies)
            w[i] *= 1 + e.p['relative']
            plant = plant.with_modal(replace(m, natural_frequencies=tuple(w)))
        elif e.name == 'mode_drift':
            total = len(angles) * moves_per_angle
            drifts.append(Drift(parameter=f'omega_{int(e.p["mode"])}',
                                rate=e.p['relative'] / total, unit='move'))
        else:
            rest.append(e)
    cfg = SimulatorConfig(plant=plant, design=PAPER_MODEL, drifts=tuple(drifts))
    return cfg, tuple(rest)


@functools.cache
def heldout_moves(effects: tuple[Hidden, ...], seed: int, *, angles: tuple[float, ...],
                  moves_per_angle: int, library: tuple[tuple[str, tuple[tuple[str, float],
                                                                          ...]], ...] = (),
                  independent: bool = False) -> MoveSet:
    """Moves of the scanner with held-out effects (and registry effects ``library``).

    Args:
        effects: Effects of this module.
        seed: Noise seed.
        angles: Target angles [deg] (moves alternate +angle and -angle).
        moves_per_angle: Moves per angle.
        library: Registry effects acting too: ((name, ((parameter, value), ...)), ...).
        independent: Run this module's loop even without a torque or reading effect.
    """
    cfg, rest = _config(effects, moves_per_angle, angles)
    plant = cfg.plant
    for name, params in library:
        plant = plant.with_effect(name, dict(params))
    cfg = replace(cfg, plant=plant)
    sim: GalvoSimulator
    if rest or independent:
        sim = HeldOutSimulator(rest, config=cfg, seed=seed)
    else:
        sim = GalvoSimulator(config=cfg, seed=seed)
    return MoveSet.from_moves(sim.moves(angles=list(angles), moves_per_angle=moves_per_angle))


def draw(name: str, rng: np.random.Generator) -> Hidden:
    """A held-out effect with parameters drawn at random from a wide range (not tuned).

    Magnitudes are log-uniform over a decade or more, periods and phases uniform, so the
    benchmark's cases are not the ones the workflow was developed on.
    """
    def log_uniform(lo: float, hi: float) -> float:
        return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))

    phase = float(rng.uniform(0, 2 * math.pi))
    sign = float(rng.choice([-1.0, 1.0]))
    params: Mapping[str, float]
    if name == 'viscous':
        params = {'b': log_uniform(2e-6, 2e-5)}
    elif name == 'cogging':
        params = {'a': log_uniform(2e-3, 2e-2), 'P': log_uniform(0.2, 2.0), 'phi': phase}
    elif name == 'encoder_cyclic':
        params = {'a': log_uniform(2e-4, 3e-3), 'P': log_uniform(0.2, 2.0), 'phi': phase}
    elif name == 'quadratic_drag':
        params = {'c': log_uniform(1e-9, 1e-8)}
    elif name == 'cubic_spring':
        params = {'kappa': log_uniform(1e-3, 1e-2)}
    elif name == 'commutation_ripple':
        params = {'r': log_uniform(0.01, 0.05), 'P': log_uniform(0.2, 2.0), 'phi': phase}
    elif name == 'encoder_scale_bow':
        params = {'c': sign * log_uniform(2e-4, 2e-3)}
    elif name == 'backlash_spring':
        params = {'kappa': log_uniform(0.05, 0.5), 'w': log_uniform(0.005, 0.05)}
    elif name == 'mode_shift':
        params = {'mode': 1.0, 'relative': sign * log_uniform(2e-3, 1e-2)}
    elif name == 'mode_drift':
        params = {'mode': 1.0, 'relative': sign * log_uniform(5e-3, 2e-2)}
    else:
        raise ValueError(name)
    return Hidden.of(name, **params)
