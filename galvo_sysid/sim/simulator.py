"""Closed-loop simulator of a galvano scanner doing positioning moves (plain numerics).

The loop, sampled at tau = 10 us like the paper's DSP::

    r, u_ff (profiles) --> e = r - encoder --> C(z) (controller) --> u = u_ff + u_fb  [recorded]
    u --> computation delay --> amplifier lag --> [clip] --> + current noise --> mechanics
    mechanics (Table I modes, [effects]) --> angle y --> + measurement noise --> quantiser
    --> encoder  [recorded]

Plant (:class:`galvo_sysid.model.plant.PlantModel`, by default the paper's): the Table I modal
model, one sample of DSP
computation delay, the current amplifier's first-order lag (0.6 tau), and optional physical
effects of the registry (:mod:`galvo_sysid.model.effects`: dead time, unmodelled resonances,
Coulomb and viscous friction, pivot stiffness, gain change, current saturation, cogging
torque, encoder cyclic error, amplifier bandwidth). The linear part is sampled exactly
(zero-order hold, fractional delays split exactly), so the open-loop response of the plant
to the recorded current (:func:`galvo_sysid.model.modal.simulate`) reproduces the recorded
encoder up to the noise.

Controller (:mod:`galvo_sysid.sim.controller`, :mod:`galvo_sysid.sim.profiles`): 2-DOF, a
jerk-limited reference with acceleration feed-forward u_ff = a_ref / k0 plus a PID-type lead
with notches at the three nominal resonances (800 Hz crossover, about 15 dB gain margin and
46 deg phase margin on the nominal plant).

Noise (defaults, all configurable in :class:`~galvo_sysid.sim.config.SimulatorConfig`):

- Encoder: 20 bits over the +-20 deg mechanical range (resolution 40/2^20 = 3.8e-5 deg,
  0.67 urad), the class of digital position detectors of current galvo servos.
- Measurement noise: 5e-5 deg RMS (0.9 urad, the usual galvo position-noise spec of about
  1 urad RMS), first-order coloured with a 20 kHz corner (detector electronics bandwidth).
- Current noise: 2 mA RMS added to the actual motor current (amplifier noise and torque
  ripple; 0.2 % of the 1 A peak moving current), first-order coloured with a 10 kHz corner
  (the current loop's bandwidth).

Through the loop these give a settled encoder scatter of about 1.7e-4 deg RMS from move to
move (3 urad; mostly the current noise, the rest measurement noise and quantisation) and a
recorded current scatter of about 1.2 mA RMS: single moves look ragged in an enlarged view
while the average of 100 moves is ten times cleaner (the paper's Fig. 6). The moves
themselves excite the resonances: the 11 kHz mode (damping 0.6 %) rings with ~5e-4 deg
after each move and still ~1e-4 deg at the record's end, so the next move starts with a
little ringing carried over.

Moves: each move is ``record_length`` (512) recorded samples from its start, at rest at the
start angle, plus ``dwell_length`` (94) unrecorded samples, so back-to-back moves make
1 / (606 tau) = 165 moves/s. Simulated time runs continuously from move to move (the state,
including ringing and noise filters, carries over).

Two paths compute the same loop:

- ``fast`` (linear plants): the closed loop is linear, so a batch of moves is computed with
  matrix products and FFT convolutions over the closed loop's Markov parameters (thousands of
  moves per second). In the loop the encoder's quantisation is represented by its equivalent
  additive uniform noise (Widrow's model, valid here since the measurement noise dithers the
  quantiser); the recorded encoder is quantised exactly.
- ``exact``: sample by sample with the quantiser in the loop and the nonlinear effects.
  Saturation acts on the actual amplifier current, which the lag makes exactly known inside
  the sample. Over each of ``substeps`` sub-steps in which it stays beyond the limit the
  motor is driven by the constant limit current, exactly; in the sub-step where it crosses
  the limit the exact mean of the clipped part is held (the linear part stays exact).
  Coulomb friction is a stick-slip (Karnopp-type) model on the rigid-body velocity, held
  per sample: stuck (velocity exactly zero) while the friction needed to hold the rotor is
  at most F, else sliding with -F sign(v); a stop inside a sample ends stuck and a reversal
  splits the sample at the interpolated zero crossing. (0.01 A of friction leaves moves
  about 1e-3 deg short at the record's end while the integrator winds up.) The cogging
  torque is evaluated from the rigid body's angle and velocity at each sample's start (its
  mean over the sample at that velocity, :meth:`~galvo_sysid.model.physics.Physics.cogging`)
  and held over the sample; the encoder's cyclic error is added to the angle it reads.

``method='auto'`` (default) uses ``fast`` for linear plants and ``exact`` otherwise. Both
paths draw the same random numbers, so without quantisation they agree to rounding error.

Plant changes: :class:`galvo_sysid.model.changes.Drift` and
:class:`galvo_sysid.model.changes.StepChange` (in the config or added on command) and
:meth:`GalvoSimulator.set_plant`; the plant is evaluated at the start of each move and held
during it.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.filters import lfilter
from galvo_sysid.model.changes import Drift, StepChange, plant_at
from galvo_sysid.model.dynamics import DiscreteStateSpace
from galvo_sysid.model.paper import PAPER_ANGLES
from galvo_sysid.model.physics import Physics
from galvo_sysid.model.plant import PlantModel
from galvo_sysid.model.sampling import ContinuousPlant, sample_plant
from galvo_sysid.sim.config import Move, SimulatorConfig
from galvo_sysid.sim.controller import LoopMargins, design_controller, loop_margins
from galvo_sysid.sim.dither import dither_signal
from galvo_sysid.sim.loop import ClosedLoop, map_state
from galvo_sysid.sim.noise import ar_coefficient
from galvo_sysid.sim.profiles import MoveProfile, move_profile

if TYPE_CHECKING:
    from numpy.typing import NDArray

__all__ = ['GalvoSimulator', 'simulate_window']

@dataclass
class _State:
    """Everything that carries from one move to the next."""

    x: NDArray[np.float64]          # continuous plant state
    cp: ContinuousPlant             # its layout
    history: NDArray[np.float64]    # past commands u[k-1], u[k-2], ... (newest first)
    xc: NDArray[np.float64]         # controller state
    current_noise: float            # last value of the coloured current noise
    measurement_noise: float        # last value of the coloured measurement noise
    rng_state: dict[str, Any]
    position: float                 # commanded angle [deg]
    move_index: int
    time: float


class GalvoSimulator:
    """A galvano scanner under closed-loop positioning control, move by move.

    Args:
        config: Simulator configuration (default: the nominal scanner).
        seed: Seed of the noise; equal seeds give equal moves.
    """

    def __init__(self, *, config: SimulatorConfig | None = None, seed: int = 0) -> None:
        self.config = config or SimulatorConfig()
        cfg = self.config
        design = cfg.design_model
        self.controller = design_controller(design, config=cfg.controller)
        self._base = cfg.plant.physics()
        self._drifts: list[Drift] = list(cfg.drifts)
        self._steps: list[StepChange] = list(cfg.steps)
        self._revision = 0
        self._loops: OrderedDict[Physics, ClosedLoop] = OrderedDict()
        self._profiles: dict[float, MoveProfile] = {}
        self._rng = np.random.default_rng(seed)
        self._a_i = ar_coefficient(cfg.current_noise_corner, cfg.sample_period)
        self._a_v = ar_coefficient(cfg.measurement_noise_corner, cfg.sample_period)
        loop = self._loop(plant_at(self._base, time=0.0, move=0, drifts=self._drifts,
                                   steps=self._steps))
        ac = self.controller.state_space()[0]
        self._state = _State(
            x=np.zeros(loop.nx), cp=loop.sp.continuous, history=np.zeros(0),
            xc=np.zeros(ac.shape[0]),
            current_noise=float(self._rng.standard_normal()) * cfg.current_noise_std,
            measurement_noise=float(self._rng.standard_normal()) * cfg.measurement_noise_std,
            rng_state={}, position=0.0, move_index=0, time=0.0)

    # ------------------------------------------------------------------ plant and changes

    @property
    def plant(self) -> Physics:
        """The plant the next move will run on (effects, drifts and steps applied)."""
        return plant_at(self._base, time=self._state.time, move=self._state.move_index,
                        drifts=self._drifts, steps=self._steps)

    @property
    def position(self) -> float:
        """Commanded angle the scanner stands at [deg]."""
        return self._state.position

    @property
    def time(self) -> float:
        """Simulated time of the next move's first sample [s]."""
        return self._state.time

    @property
    def move_count(self) -> int:
        """Moves simulated so far (the next move's id)."""
        return self._state.move_index

    def set_plant(self, plant: PlantModel | Physics) -> None:
        """Replace the base plant (drifts and steps still apply on top of it).

        The controller stays the one designed at the start (a real scanner's controller does
        not follow its plant either); the sample period must stay the same.
        """
        physics = plant.physics() if isinstance(plant, PlantModel) else plant
        if not isinstance(physics, Physics):
            raise ConfigurationError('plant must be a PlantModel or a Physics')
        if physics.sample_period != self._base.sample_period:
            raise ConfigurationError('the new plant has another sample period')
        self._loop(plant_at(physics, time=self.time, move=self.move_count, drifts=self._drifts,
                            steps=self._steps))
        self._base = physics
        self._revision += 1

    def add_drift(self, drift: Drift) -> None:
        """Start a drift (its ``start`` is absolute: seconds or move index)."""
        if not isinstance(drift, Drift):
            raise ConfigurationError('drift must be a Drift')
        self._drifts.append(drift)
        self._revision += 1

    def add_step(self, step: StepChange) -> None:
        """Schedule a step change."""
        if not isinstance(step, StepChange):
            raise ConfigurationError('step must be a StepChange')
        self._steps.append(step)
        self._revision += 1

    def clear_changes(self) -> None:
        """Drop all drifts and step changes (the base plant stays)."""
        self._drifts.clear()
        self._steps.clear()
        self._revision += 1

    def margins(self, plant: PlantModel | Physics | None = None) -> LoopMargins:
        """Loop margins of the controller on a plant's linear part (default: current)."""
        spec = self.plant if plant is None else (
            plant.physics() if isinstance(plant, PlantModel) else plant)
        sp = sample_plant(spec)
        n = sp.phi.shape[0]
        nh = sp.whole + 1
        a = np.zeros((n + nh, n + nh))
        a[:n, :n] = sp.phi
        a[:n, n + sp.whole] = sp.g_old
        b = np.zeros(n + nh)
        if sp.whole == 0:
            b[:n] = sp.g_new
        else:
            a[:n, n + sp.whole - 1] = sp.g_new
        b[n] = 1.0
        for i in range(1, nh):
            a[n + i, n + i - 1] = 1.0
        c = np.concatenate([sp.continuous.c, np.zeros(nh)])
        return loop_margins(self.controller, DiscreteStateSpace(a=a, b=b, c=c))

    def _loop(self, spec: Physics) -> ClosedLoop:
        loop = self._loops.get(spec)
        if loop is None:
            loop = ClosedLoop(spec, self.controller, self.config)
            self._loops[spec] = loop
            if len(self._loops) > 16:
                self._loops.popitem(last=False)
        else:
            self._loops.move_to_end(spec)
        return loop

    def _profile(self, angle: float) -> MoveProfile:
        prof = self._profiles.get(angle)
        if prof is None:
            cfg = self.config
            design = cfg.design_model
            prof = move_profile(angle, length=cfg.move_length, record_length=cfg.record,
                                k0=design.modal.k0, dynamics=design.dynamics,
                                sample_period=cfg.sample_period, config=cfg.profile)
            if cfg.dither.active:
                prof = replace(prof, feedforward=prof.feedforward + dither_signal(
                    cfg.dither, model=design, record=cfg.record, length=cfg.move_length))
            self._profiles[angle] = prof
        return prof

    def check_angles(self, angles: Sequence[float]) -> None:
        """Check that moves of these angles (both signs) can be made on this scanner.

        Raises:
            ConfigurationError: An angle is not finite, outside the encoder's range, or its
                move does not fit in the record.
        """
        for a in angles:
            if not (math.isfinite(a) and 0 < abs(a) <= self.config.encoder_range):
                raise ConfigurationError(
                    f'angle {a!r} deg: moves must be non-zero and within the '
                    f'+-{self.config.encoder_range:g} deg range')
            self._profile(float(a))
            self._profile(-float(a))

    # ------------------------------------------------------------------ moves

    def run_move(self, target_angle: float) -> Move:
        """Simulate one move of ``target_angle`` degrees from where the scanner stands."""
        return self._run([float(target_angle)])[0][0]

    def moves(self, *, angles: Sequence[float] = PAPER_ANGLES,
              moves_per_angle: int = 200, batch: int = 64) -> Iterator[Move]:
        """Yield a schedule of moves.

        For each angle a in ``angles`` (in order), ``moves_per_angle`` moves alternate
        +a (forward) and -a (return), so each signed angle gets ``moves_per_angle / 2``
        moves: the paper's 100 pairs per angle is ``moves_per_angle=200``.

        Moves are computed ``batch`` at a time; a plant change made while iterating
        (``set_plant``, ``add_drift``, ...) takes effect from the next yielded move.
        """
        if not isinstance(moves_per_angle, int) or moves_per_angle < 2 or moves_per_angle % 2:
            raise ConfigurationError(
                f'moves_per_angle must be a positive even integer, got {moves_per_angle!r}')
        if batch < 1:
            raise ConfigurationError('batch must be >= 1')
        targets = [float(a) if i % 2 == 0 else -float(a)
                   for a in angles for i in range(moves_per_angle)]
        if not targets:
            raise ConfigurationError('angles must not be empty')
        self._check_targets(targets)
        i = 0
        while i < len(targets):
            revision = self._revision
            linear = self.plant.linear and self.config.method != 'exact'
            size = batch if linear else min(batch, 4)  # exact moves gain nothing from batches
            results = self._run(targets[i:i + size])
            committed: _State | None = None
            for move, state in results:
                if committed is not None and (self._revision != revision
                                              or self._state is not committed):
                    break  # changed meanwhile: recompute the rest from the committed state
                self._state = committed = state
                self._rng.bit_generator.state = state.rng_state
                i += 1
                yield move

    def _check_targets(self, targets: Sequence[float]) -> None:
        pos = self._state.position
        for a in targets:
            if not math.isfinite(a):
                raise ConfigurationError(f'angles must be finite, got {a!r}')
            pos += a
            if abs(pos) > self.config.encoder_range + 1e-9:
                raise ConfigurationError(
                    f'a move of {a!r} deg would leave the +-{self.config.encoder_range} deg '
                    f'range')

    def _run(self, targets: list[float]) -> list[tuple[Move, _State]]:
        """Simulate ``targets`` back to back, commit the final state, return (move, state)."""
        cfg = self.config
        out: list[tuple[Move, _State]] = []
        self._check_targets(targets)
        i = 0
        while i < len(targets):
            spec = plant_at(self._base, time=self._state.time, move=self._state.move_index,
                            drifts=self._drifts, steps=self._steps)
            loop = self._loop(spec)
            exact = cfg.method == 'exact' or not spec.linear
            if exact and cfg.method == 'fast':
                raise ConfigurationError("method 'fast' cannot simulate friction, saturation, "
                                         "cogging, an encoder error or proposed terms")
            # Moves that share this plant (no drift or step in between) run as one batch.
            j = i + 1
            if not exact:
                t, mi = self._state.time, self._state.move_index
                dt = cfg.move_length * cfg.sample_period
                while j < len(targets) and plant_at(
                        self._base, time=t + (j - i) * dt, move=mi + (j - i),
                        drifts=self._drifts, steps=self._steps) == spec:
                    j += 1
            batch = targets[i:j]
            if exact:
                out.extend(self._run_exact(loop, batch))
            else:
                out.extend(self._run_fast(loop, batch))
            i = j
        return out

    def _noise(self, count: int) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                          NDArray[np.float64], list[dict[str, Any]]]:
        """Draw the noise of ``count`` moves: (current (M, L), measurement (M, L), q)."""
        cfg = self.config
        length = cfg.move_length
        white = np.empty((count, 2, length))
        uni = np.empty((count, length))
        rng_states = []
        for m in range(count):
            white[m] = self._rng.standard_normal((2, length))
            uni[m] = self._rng.random(length) - 0.5
            rng_states.append(dict(self._rng.bit_generator.state))
        s = self._state
        ai, av = self._a_i, self._a_v
        n = lfilter([math.sqrt(1 - ai * ai) * cfg.current_noise_std], [1.0, -ai],
                    white[:, 0].ravel(), zi=[ai * s.current_noise]).reshape(count, length)
        v = lfilter([math.sqrt(1 - av * av) * cfg.measurement_noise_std], [1.0, -av],
                    white[:, 1].ravel(), zi=[av * s.measurement_noise]).reshape(count, length)
        return n, v, uni * cfg.encoder_resolution, rng_states

    def _pack(self, loop: ClosedLoop) -> NDArray[np.float64]:
        """The closed-loop state z = [x, register, xc] of ``loop`` from the carried state."""
        s = self._state
        x = map_state(s.x, s.cp, loop.sp.continuous)
        hist = np.zeros(loop.nh)
        k = min(loop.nh, s.history.shape[0])
        hist[:k] = s.history[:k]
        return np.concatenate([x, hist, s.xc])

    def _unpack(self, loop: ClosedLoop, z: NDArray[np.float64], *, n_last: float, v_last: float,
                rng_state: dict[str, Any], angle: float) -> _State:
        s = self._state
        hist = np.zeros(max(loop.nh, s.history.shape[0]))
        hist[:loop.nh] = z[loop.nx:loop.nx + loop.nh]
        return _State(x=z[:loop.nx].copy(), cp=loop.sp.continuous, history=hist,
                      xc=z[loop.nx + loop.nh:].copy(), current_noise=n_last,
                      measurement_noise=v_last, rng_state=rng_state,
                      position=s.position + angle, move_index=s.move_index + 1,
                      time=s.time + self.config.move_length * self.config.sample_period)

    def _inputs(self, targets: list[float], start: float) -> tuple[
            NDArray[np.float64], NDArray[np.float64], list[float]]:
        """Absolute references and feed-forwards (M, L) of back-to-back moves."""
        m = len(targets)
        r = np.empty((m, self.config.move_length))
        ff = np.empty_like(r)
        starts = []
        pos = start
        for i, a in enumerate(targets):
            prof = self._profile(a)
            r[i] = pos + prof.reference
            ff[i] = prof.feedforward
            starts.append(pos)
            pos += a
        return r, ff, starts

    def _move(self, target: float, start: float, u: NDArray[np.float64],
              enc: NDArray[np.float64]) -> Move:
        cfg = self.config
        s = self._state
        return Move(move_id=s.move_index, target_angle=target, start_angle=start,
                    stamp=s.time, sample_period=cfg.sample_period, current=u, encoder=enc)

    def _quantise(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        q = self.config.encoder_resolution
        return np.floor(x / q + 0.5) * q if q > 0 else x

    def _run_fast(self, loop: ClosedLoop, targets: list[float]) -> list[tuple[Move, _State]]:
        cfg = self.config
        rec, total = cfg.record, cfg.move_length
        block = loop.fast(rec, total)
        n, v, q, rng_states = self._noise(len(targets))
        r, ff, starts = self._inputs(targets, self._state.position)
        w = np.stack([r, ff, n, v, q], axis=1)
        y, u, zs = block.run(self._pack(loop), w)
        enc = self._quantise(y + v[:, :rec])
        out = []
        for i, a in enumerate(targets):
            move = self._move(a, starts[i], u[i].copy(), enc[i].copy())
            self._state = self._unpack(loop, zs[i + 1], n_last=float(n[i, -1]),
                                       v_last=float(v[i, -1]), rng_state=rng_states[i],
                                       angle=a)
            out.append((move, self._state))
        return out

    def _run_exact(self, loop: ClosedLoop, targets: list[float]) -> list[tuple[Move, _State]]:
        rec = self.config.record
        out = []
        for a in targets:
            n, v, _, rng_states = self._noise(1)
            r, ff, starts = self._inputs([a], self._state.position)
            z = self._pack(loop)
            u, y = loop.exact_move(z, r[0], ff[0], n[0], v[0], rec, self.config.encoder_resolution)
            move = self._move(a, starts[0], u, y)
            self._state = self._unpack(loop, z, n_last=float(n[0, -1]), v_last=float(v[0, -1]),
                                       rng_state=rng_states[0], angle=a)
            out.append((move, self._state))
        return out


def simulate_window(target_angle: float, *, moves: int = 100, seed: int = 0,
                    config: SimulatorConfig | None = None) -> tuple[NDArray[np.float64],
                                                                   NDArray[np.float64]]:
    """Simulate ``moves`` moves of one signed angle (with the return moves in between).

    The scanner starts at rest at 0 deg and moves +target, -target, +target, ...; only the
    moves of ``target_angle`` are returned, as the sysid node would average them.

    Args:
        target_angle: Signed rotation [deg].
        moves: Number of moves of ``target_angle`` to return.
        seed: Noise seed.
        config: Simulator configuration.

    Returns:
        (current (M, N) [A], encoder (M, N) [deg]).
    """
    if not isinstance(moves, int) or moves < 1:
        raise ConfigurationError(f'moves must be a positive integer, got {moves!r}')
    if not math.isfinite(target_angle):
        raise ConfigurationError(f'target_angle must be finite, got {target_angle!r}')
    sim = GalvoSimulator(config=config, seed=seed)
    cur, enc = [], []
    for move in sim.moves(angles=[target_angle], moves_per_angle=2 * moves, batch=200):
        if move.move_id % 2 == 0:
            cur.append(move.current)
            enc.append(move.encoder)
    return np.array(cur), np.array(enc)
