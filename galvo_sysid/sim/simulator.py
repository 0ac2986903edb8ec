"""Closed-loop simulator of a galvano scanner doing positioning moves (plain numerics).

The loop, sampled at tau = 10 us like the paper's DSP::

    r, u_ff (profiles) --> e = r - encoder --> C(z) (controller) --> u = u_ff + u_fb  [recorded]
    u --> computation delay --> amplifier lag --> [clip] --> + current noise --> mechanics
    mechanics (Table I modes, [effects]) --> angle y --> + measurement noise --> quantiser
    --> encoder  [recorded]

Plant (:class:`galvo_sysid.model.plant.PlantModel`, by default the paper's): the Table I modal
model, one sample of DSP
computation delay, the current amplifier's first-order lag (0.6 tau), and optional physical
effects (dead time, unmodelled resonances, Coulomb friction, pivot stiffness, gain change,
current saturation). The linear part is sampled exactly (zero-order hold, fractional delays
split exactly), so the open-loop response of the plant to the recorded current
(:func:`galvo_sysid.model.modal.simulate`) reproduces the recorded encoder up to the noise.

Controller (:mod:`galvo_sysid.sim.controller`, :mod:`galvo_sysid.sim.profiles`): 2-DOF, a
jerk-limited reference with acceleration feed-forward u_ff = a_ref / k0 plus a PID-type lead
with notches at the three nominal resonances (800 Hz crossover, about 15 dB gain margin and
46 deg phase margin on the nominal plant).

Noise (defaults, all configurable in :class:`SimulatorConfig`):

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
  about 1e-3 deg short at the record's end while the integrator winds up.)

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
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.signal import lfilter

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model.changes import Drift, StepChange, plant_at
from galvo_sysid.model.dynamics import DiscreteStateSpace
from galvo_sysid.model.paper import PAPER_ANGLES, PAPER_MODEL
from galvo_sysid.model.physics import Physics
from galvo_sysid.model.plant import PlantModel
from galvo_sysid.model.sampling import ContinuousPlant, sample_plant
from galvo_sysid.sim.controller import (
    Controller,
    ControllerConfig,
    LoopMargins,
    design_controller,
    loop_margins,
)
from galvo_sysid.sim.profiles import MoveProfile, ProfileConfig, move_profile

if TYPE_CHECKING:
    from numpy.typing import NDArray

__all__ = [
    'DEFAULT_ENCODER_RESOLUTION',
    'GalvoSimulator',
    'Move',
    'SimulatorConfig',
    'simulate_window',
]

DEFAULT_ENCODER_RESOLUTION = 40.0 / 2**20
"""20 bits over +-20 deg [deg]."""

_METHODS = ('auto', 'fast', 'exact')


@dataclass(frozen=True)
class SimulatorConfig:
    """Everything the simulator needs; defaults give the paper's nominal scanner.

    Attributes:
        plant: The simulated (true) plant, with effects; its sample period is the DSP's.
        design: Nominal model the controller, notches and feed-forward are designed on
            (None: the plant without its effects).
        controller: Feedback controller design parameters (None: designed from the model,
            see :func:`galvo_sysid.sim.controller.auto_controller_config`).
        profile: Move profile parameters.
        record_length: Recorded samples per move (None: the plant model's).
        dwell_length: Unrecorded samples after each record (None: the plant model's).
        encoder_resolution: Quantisation step of the encoder [deg]; 0 for none.
        encoder_range: Largest angle the scanner may be commanded to [deg].
        measurement_noise_std: RMS of the encoder noise before quantisation [deg].
        measurement_noise_corner: Corner of its first-order colouring [Hz] (inf: white).
        current_noise_std: RMS of the noise added to the motor current [A].
        current_noise_corner: Corner of its first-order colouring [Hz] (inf: white).
        drifts: Plant drifts.
        steps: Plant step changes.
        method: ``'auto'``, ``'fast'`` (linear plants only) or ``'exact'``.
        substeps: Sub-steps per sample over which saturation is evaluated.
    """

    plant: PlantModel = PAPER_MODEL
    design: PlantModel | None = None
    controller: ControllerConfig | None = None
    profile: ProfileConfig = field(default_factory=ProfileConfig)
    record_length: int | None = None
    dwell_length: int | None = None
    encoder_resolution: float = DEFAULT_ENCODER_RESOLUTION
    encoder_range: float = 20.0
    measurement_noise_std: float = 5e-5
    measurement_noise_corner: float = 20e3
    current_noise_std: float = 2e-3
    current_noise_corner: float = 10e3
    drifts: tuple[Drift, ...] = ()
    steps: tuple[StepChange, ...] = ()
    method: str = 'auto'
    substeps: int = 8

    def __post_init__(self) -> None:
        def check(name: str, *, positive: bool = False, allow_inf: bool = False) -> None:
            value = getattr(self, name)
            ok = (isinstance(value, int | float) and not math.isnan(value)
                  and (allow_inf or math.isfinite(value)) and (value > 0 if positive
                                                               else value >= 0))
            if not ok:
                kind = 'positive' if positive else 'non-negative'
                raise ConfigurationError(f'{name} must be {kind} and finite, got {value!r}')

        if not isinstance(self.plant, PlantModel):
            raise ConfigurationError('plant must be a PlantModel')
        if self.design is not None:
            if not isinstance(self.design, PlantModel):
                raise ConfigurationError('design must be a PlantModel')
            if abs(self.design.sample_period - self.plant.sample_period) > \
                    1e-9 * self.plant.sample_period:
                raise ConfigurationError('the design model and the plant have different '
                                         'sample periods')
        if self.record_length is None:
            object.__setattr__(self, 'record_length', self.plant.record_length)
        if self.dwell_length is None:
            object.__setattr__(self, 'dwell_length', self.plant.dwell_length)
        check('encoder_resolution')
        check('encoder_range', positive=True)
        check('measurement_noise_std')
        check('current_noise_std')
        check('measurement_noise_corner', positive=True, allow_inf=True)
        check('current_noise_corner', positive=True, allow_inf=True)
        for name in ('record_length', 'dwell_length', 'substeps'):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 0:
                raise ConfigurationError(f'{name} must be a non-negative integer, got {value!r}')
        if self.record < 16:
            raise ConfigurationError('record_length must be at least 16 samples')
        if self.substeps < 1:
            raise ConfigurationError('substeps must be >= 1')
        if self.method not in _METHODS:
            raise ConfigurationError(f'method must be one of {_METHODS}, got {self.method!r}')
        if not all(isinstance(d, Drift) for d in self.drifts):
            raise ConfigurationError('drifts must be Drift instances')
        if not all(isinstance(s, StepChange) for s in self.steps):
            raise ConfigurationError('steps must be StepChange instances')

    @property
    def sample_period(self) -> float:
        """DSP sampling period [s] (the plant model's)."""
        return self.plant.sample_period

    @property
    def design_model(self) -> PlantModel:
        """The model the controller is designed on."""
        return self.design if self.design is not None else self.plant.nominal()

    @property
    def record(self) -> int:
        """Recorded samples per move."""
        assert self.record_length is not None
        return self.record_length

    @property
    def dwell(self) -> int:
        """Unrecorded samples after each record."""
        assert self.dwell_length is not None
        return self.dwell_length

    @property
    def move_length(self) -> int:
        """Samples per move, recorded plus dwell."""
        return self.record + self.dwell

    @property
    def moves_per_second(self) -> float:
        """Back-to-back move rate in simulated time."""
        return 1.0 / (self.move_length * self.sample_period)


@dataclass(frozen=True)
class Move:
    """One recorded positioning move.

    Attributes:
        move_id: Running number of the move.
        target_angle: Signed commanded rotation [deg].
        start_angle: Commanded angle at the start of the move [deg].
        stamp: Simulated time of the move's first sample [s].
        sample_period: Sampling period [s].
        current: Commanded current [A] as the DSP computes it, shape (N,).
        encoder: Encoder angle [deg] (quantised, noisy), shape (N,).
    """

    move_id: int
    target_angle: float
    start_angle: float
    stamp: float
    sample_period: float
    current: NDArray[np.float64]
    encoder: NDArray[np.float64]


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


class _Loop:
    """The closed loop for one plant: matrices of both paths (built on first use)."""

    def __init__(self, spec: Physics, controller: Controller, cfg: SimulatorConfig) -> None:
        self.spec = spec
        sp = sample_plant(spec, substeps=cfg.substeps)
        self.sp = sp
        cp = sp.continuous
        ac, bc, cc, dc = controller.state_space()
        nx, nc = cp.a.shape[0], ac.shape[0]
        w = sp.whole
        nh = w + 1                                # register u[k-1] .. u[k-w-1]
        nz = nx + nh + nc
        self.nx, self.nh, self.nc, self.nz = nx, nh, nc, nz
        gain = spec.gain_ratio
        # z' = az z + be e + bff uff + bn n + gd dnl ; u = cu z + dc e + uff
        cu = np.zeros(nz)
        cu[nx + nh:] = cc
        az = np.zeros((nz, nz))
        be = np.zeros(nz)
        bff = np.zeros(nz)
        az[:nx, :nx] = sp.phi
        az[:nx, nx + w] += sp.g_old                 # u_old = u[k-w-1] = register[w]
        if w == 0:                                  # u_new = u[k]
            az[:nx] += np.outer(sp.g_new, cu)
            be[:nx] += sp.g_new * dc
            bff[:nx] += sp.g_new
        else:                                       # u_new = register[w-1]
            az[:nx, nx + w - 1] += sp.g_new
        az[nx] = cu                                 # register[0] <- u[k]
        be[nx] = dc
        bff[nx] = 1.0
        for i in range(1, nh):
            az[nx + i, nx + i - 1] = 1.0
        az[nx + nh:, nx + nh:] = ac
        be[nx + nh:] = bc
        bn = np.zeros(nz)
        bn[:nx] = gain * sp.g_d
        gd = np.zeros((nz, sp.substeps))
        gd[:nx] = sp.gamma_d
        cy = np.zeros(nz)
        cy[:nx] = cp.c
        self.az, self.be, self.bff, self.bn, self.gd, self.cy, self.cu = az, be, bff, bn, gd, cy, cu
        self.dc = float(dc)
        # Fast path: m = y + v + q -> e = r - cy z - v - q ; inputs w = [r, uff, n, v, q].
        self.a_cl = az - np.outer(be, cy)
        self.b_cl = np.stack([be, bff, bn, -be, -be], axis=1)
        self.cu_cl = cu - dc * cy
        self.du_cl = np.array([dc, 1.0, 0.0, -dc, -dc])
        poles = np.linalg.eigvals(self.a_cl)
        self.spectral_radius = float(np.max(np.abs(poles)))
        if self.spectral_radius >= 1:
            raise ConfigurationError(
                f'the closed loop is unstable on this plant (spectral radius '
                f'{self.spectral_radius:.6f}); plant parameters: {spec.parameters()}')
        self._fast: dict[tuple[int, int], _FastBlock] = {}
        # Saturation. The amplifier current i(t) inside a sample follows from the lag alone
        # (d does not act on it): i(t) = coef(t) @ [i0, u_old, u_new]; rows for the start,
        # middle and end of each sub-step. Over a sub-step where |i| stays beyond the limit the
        # motor sees the constant limit current: the lag's own contribution to the mechanics
        # (sat_r @ [i_start, u_old, u_new], carried to the sample's end) is replaced by it,
        # exactly. A sub-step where i crosses the limit holds the clipped part at its midpoint.
        substeps = sp.substeps
        h = cfg.sample_period / substeps
        lag = spec.lag_time_constant

        def coef(t: float, *, closed: bool) -> tuple[float, float, float]:
            if lag > 0:
                if t <= sp.split:
                    e1 = math.exp(-t / lag)
                    return (e1, 1 - e1, 0.0)
                e1, e2 = math.exp(-sp.split / lag), math.exp(-(t - sp.split) / lag)
                return (e1 * e2, (1 - e1) * e2, 1 - e2)
            old = t <= sp.split if closed else t < sp.split
            return (0.0, 1.0, 0.0) if old else (0.0, 0.0, 1.0)

        self.sat_coef = np.array([[coef(j * h, closed=False) for j in range(substeps)],
                                  [coef((j + 0.5) * h, closed=False) for j in range(substeps)],
                                  [coef((j + 1) * h, closed=True) for j in range(substeps)]])
        self.sat_split = np.array([j * h < sp.split < (j + 1) * h for j in range(substeps)])
        self.sat_new = [j * h >= sp.split for j in range(substeps)]  # u_new drives sub-step j
        self.sat_h = h
        self.lag = lag
        mech = np.ones(nx)
        if cp.current_index is not None:
            mech[cp.current_index] = 0.0
        lag_col = (sp.sub_phi[:, cp.current_index] if cp.current_index is not None
                   else np.zeros(nx))
        sat_r = np.zeros((substeps, nz, 3))
        carry = np.eye(nx)                          # sub_phi^(substeps - 1 - j), j descending
        for j in range(substeps - 1, -1, -1):
            drives = np.stack([lag_col, sp.sub_g_old[j], sp.sub_g_new[j]], axis=1)
            sat_r[j, :nx] = carry @ (mech[:, None] * drives)
            carry = carry @ sp.sub_phi
        self.sat_r = sat_r
        # Whole sample beyond the limit (i0, u_old, u_new all beyond it on one side): the sum
        # of the sub-step corrections, as one matrix on [i0, u_old, u_new].
        pick = np.zeros((substeps, 3, 3))
        pick[:, 0, :] = self.sat_coef[0]
        pick[:, 1, 1] = 1.0
        pick[:, 2, 2] = 1.0
        self.sat_r_full = np.einsum('jnk,jkl->nl', sat_r, pick)
        self.gd_sum_limit = gd.sum(axis=1) * gain * spec.current_limit \
            if math.isfinite(spec.current_limit) else np.zeros(nz)
        self.limit = spec.current_limit
        self.gain = gain
        # Friction: the rigid-body velocity's row of the update and its gain from d.
        self.friction = spec.friction_current
        self.v_index = cp.velocity_index
        self.v_gain = float(sp.g_d[cp.velocity_index])
        self.gd_sum = gd.sum(axis=1)
        self.i_index = cp.current_index

    def fast(self, record: int, total: int) -> _FastBlock:
        key = (record, total)
        if key not in self._fast:
            self._fast[key] = _FastBlock(self, record, total)
        return self._fast[key]


class _FastBlock:
    """Markov parameters and transition powers of the linear closed loop over one move."""

    def __init__(self, loop: _Loop, record: int, total: int) -> None:
        a, b = loop.a_cl, loop.b_cl
        nz, ni = b.shape
        # A^k B (k < total) and [cy; cu] A^k (k < record) by doubling: one batched product
        # per power of two.
        akb = np.empty((total, nz, ni))
        akb[0] = b
        rows = np.empty((record, 2, nz))
        rows[0] = np.stack([loop.cy, loop.cu_cl])
        power = a
        filled = 1
        while filled < total:
            count = min(filled, total - filled)
            akb[filled:filled + count] = power @ akb[:count]
            if filled < record:
                rc = min(filled, record - filled)
                rows[filled:filled + rc] = rows[:rc] @ power
            filled += count
            power = power @ power
        # End state: sum_k A^(L-1-k) B w[k]  ->  (nz, ni * total) against w.reshape(ni * total)
        self.g = akb[::-1].transpose(1, 2, 0).reshape(nz, ni * total)
        self.o_y = rows[:, 0]                                  # (record, nz): cy A^k
        self.o_u = rows[:, 1]
        self.a_total = np.linalg.matrix_power(a, total)
        h_y = np.zeros((record, ni))
        h_u = np.zeros((record, ni))
        h_y[1:] = np.einsum('n,kni->ki', loop.cy, akb[:record - 1])
        h_u[1:] = np.einsum('n,kni->ki', loop.cu_cl, akb[:record - 1])
        h_u[0] = loop.du_cl
        self.nfft = 1 << (2 * record - 1).bit_length()
        self.hf_y = np.fft.rfft(h_y, self.nfft, axis=0)       # (nfft/2+1, ni)
        self.hf_u = np.fft.rfft(h_u, self.nfft, axis=0)
        self.record, self.total, self.ni = record, total, ni

    def run(self, z0: NDArray[np.float64], w: NDArray[np.float64]) -> tuple[
            NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Simulate M back-to-back moves from state z0 with inputs w (M, ni, total).

        Returns:
            (y (M, record), u (M, record), start states (M + 1, nz)).
        """
        m = w.shape[0]
        forced = w.reshape(m, -1) @ self.g.T                  # (M, nz)
        starts = np.empty((m + 1, z0.shape[0]))
        starts[0] = z0
        for i in range(m):
            starts[i + 1] = self.a_total @ starts[i] + forced[i]
        wf = np.fft.rfft(w[:, :, :self.record], self.nfft, axis=-1)   # (M, ni, F)
        y = np.fft.irfft(np.einsum('mif,fi->mf', wf, self.hf_y), self.nfft, axis=-1)
        u = np.fft.irfft(np.einsum('mif,fi->mf', wf, self.hf_u), self.nfft, axis=-1)
        y = y[:, :self.record] + starts[:m] @ self.o_y.T
        u = u[:, :self.record] + starts[:m] @ self.o_u.T
        return y, u, starts


def _clipped_mean(i_start: float, u_a: float, limit: float, lag: float, h: float) -> float:
    """Mean over [0, h] of i - clip(i) for i(t) = u_a + (i_start - u_a) exp(-t / lag)."""
    amp = i_start - u_a
    total = 0.0
    for sign in (1.0, -1.0):                      # the part beyond +limit, then beyond -limit
        level = sign * limit
        # i(t) - level is monotone; the part of [0, h] where sign * (i - level) > 0:
        e_h = math.exp(-h / lag)
        beyond_start = sign * (i_start - level) > 0
        beyond_end = sign * (u_a + amp * e_h - level) > 0
        if not (beyond_start or beyond_end):
            continue
        if beyond_start and beyond_end:
            a, b = 0.0, h
        else:
            t_cross = lag * math.log(amp / (level - u_a))
            a, b = (0.0, t_cross) if beyond_start else (t_cross, h)
        # integral of i - level over [a, b]
        total += (u_a - level) * (b - a) + amp * lag * (math.exp(-a / lag) - math.exp(-b / lag))
    return total / h


def _ar_coefficient(corner: float, sample_period: float) -> float:
    return 0.0 if math.isinf(corner) else math.exp(-2 * math.pi * corner * sample_period)


def _map_state(x: NDArray[np.float64], old: ContinuousPlant,
               new: ContinuousPlant) -> NDArray[np.float64]:
    """Carry the plant state over a change of its layout (new modes start at rest)."""
    if old.a.shape == new.a.shape and old.current_index == new.current_index:
        return x.copy()
    out = np.zeros(new.a.shape[0])
    if old.current_index is not None and new.current_index is not None:
        out[new.current_index] = x[old.current_index]
    o_off, n_off = old.position_index, new.position_index
    pairs = min((x.shape[0] - o_off) // 2, (out.shape[0] - n_off) // 2)
    out[n_off:n_off + 2 * pairs] = x[o_off:o_off + 2 * pairs]
    return out


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
        self._loops: OrderedDict[Physics, _Loop] = OrderedDict()
        self._profiles: dict[float, MoveProfile] = {}
        self._rng = np.random.default_rng(seed)
        self._a_i = _ar_coefficient(cfg.current_noise_corner, cfg.sample_period)
        self._a_v = _ar_coefficient(cfg.measurement_noise_corner, cfg.sample_period)
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

    def _loop(self, spec: Physics) -> _Loop:
        loop = self._loops.get(spec)
        if loop is None:
            loop = _Loop(spec, self.controller, self.config)
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
                raise ConfigurationError("method 'fast' cannot simulate friction or saturation")
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
                    white[:, 0].ravel(), zi=[ai * s.current_noise])[0].reshape(count, length)
        v = lfilter([math.sqrt(1 - av * av) * cfg.measurement_noise_std], [1.0, -av],
                    white[:, 1].ravel(), zi=[av * s.measurement_noise])[0].reshape(count, length)
        return n, v, uni * cfg.encoder_resolution, rng_states

    def _pack(self, loop: _Loop) -> NDArray[np.float64]:
        """The closed-loop state z = [x, register, xc] of ``loop`` from the carried state."""
        s = self._state
        x = _map_state(s.x, s.cp, loop.sp.continuous)
        hist = np.zeros(loop.nh)
        k = min(loop.nh, s.history.shape[0])
        hist[:k] = s.history[:k]
        return np.concatenate([x, hist, s.xc])

    def _unpack(self, loop: _Loop, z: NDArray[np.float64], *, n_last: float, v_last: float,
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

    def _run_fast(self, loop: _Loop, targets: list[float]) -> list[tuple[Move, _State]]:
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

    def _run_exact(self, loop: _Loop, targets: list[float]) -> list[tuple[Move, _State]]:
        rec = self.config.record
        out = []
        for a in targets:
            n, v, _, rng_states = self._noise(1)
            r, ff, starts = self._inputs([a], self._state.position)
            z = self._pack(loop)
            u, y = self._exact_move(loop, z, r[0], ff[0], n[0], v[0], rec)
            move = self._move(a, starts[0], u, y)
            self._state = self._unpack(loop, z, n_last=float(n[0, -1]), v_last=float(v[0, -1]),
                                       rng_state=rng_states[0], angle=a)
            out.append((move, self._state))
        return out

    def _exact_move(self, loop: _Loop, z: NDArray[np.float64], r: NDArray[np.float64],
                    ff: NDArray[np.float64], n: NDArray[np.float64], v: NDArray[np.float64],
                    record: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Sample-by-sample simulation of one move; updates ``z`` in place."""
        q = self.config.encoder_resolution
        length = r.shape[0]
        nz = loop.nz
        pre = (np.outer(loop.be, r) + np.outer(loop.bff, ff) + np.outer(loop.bn, n)).T.copy()
        # One product gives the free next state and both outputs: [az; cy; cu] @ z.
        big = np.vstack([loop.az, loop.cy, loop.cu])
        be_neg = -loop.be
        dc = loop.dc
        u_rec = np.empty(record)
        y_rec = np.empty(record)
        w = loop.sp.whole
        idx_old, idx_new = loop.nx + w, loop.nx + w - 1
        limit, friction = loop.limit, loop.friction
        saturation = math.isfinite(limit)
        zk = z.copy()
        floor = math.floor
        for k in range(length):
            out = big @ zk
            meas = float(out[nz]) + v[k]
            if q > 0:
                meas = floor(meas / q + 0.5) * q
            uk = float(out[nz + 1]) + dc * (r[k] - meas) + ff[k]
            if k < record:
                u_rec[k] = uk
                y_rec[k] = meas
            z_next = out[:nz]
            z_next += pre[k]
            z_next += be_neg * meas
            if saturation:
                u_old = float(zk[idx_old])
                u_new = uk if w == 0 else float(zk[idx_new])
                i0 = float(zk[loop.i_index]) if loop.i_index is not None else u_old
                if max(abs(i0), abs(u_old), abs(u_new)) > limit:
                    z_next += self._saturation(loop, i0, u_old, u_new)
            if friction > 0:
                self._friction(loop, zk, z_next)
            zk = z_next
        z[:] = zk
        return u_rec, y_rec

    @staticmethod
    def _saturation(loop: _Loop, i0: float, u_old: float,
                    u_new: float) -> NDArray[np.float64]:
        """Correction of the next state for the amplifier's current limit over one sample."""
        limit, gain = loop.limit, loop.gain
        x = np.array([i0, u_old, u_new])
        if not loop.sat_split.any():
            if min(i0, u_old, u_new) > limit:
                return np.asarray(loop.gd_sum_limit - loop.sat_r_full @ x, dtype=np.float64)
            if max(i0, u_old, u_new) < -limit:
                return np.asarray(-loop.gd_sum_limit - loop.sat_r_full @ x, dtype=np.float64)
        start, mid, end = loop.sat_coef @ x                   # (substeps,) each
        above = (start > limit) & (mid > limit) & (end > limit) & ~loop.sat_split
        below = (start < -limit) & (mid < -limit) & (end < -limit) & ~loop.sat_split
        d = gain * (np.clip(mid, -limit, limit) - mid)        # crossing sub-steps: midpoint
        full = above | below
        d[above] = gain * limit
        d[below] = -gain * limit
        if loop.lag > 0:  # crossing sub-steps: the exact mean of the clipped part instead
            crossing = np.flatnonzero(~full & ~loop.sat_split & (
                (np.abs(start) > limit) | (np.abs(end) > limit)))
            for j in crossing:
                u_a = u_new if loop.sat_new[j] else u_old
                d[j] = -gain * _clipped_mean(float(start[j]), u_a, limit, loop.lag, loop.sat_h)
        corr: NDArray[np.float64] = loop.gd @ d
        if full.any():
            drives = np.stack([start[full], np.full(int(full.sum()), u_old),
                               np.full(int(full.sum()), u_new)], axis=1)
            corr -= np.einsum('jnk,jk->n', loop.sat_r[full], drives)
        return corr

    @staticmethod
    def _friction(loop: _Loop, z: NDArray[np.float64], z_next: NDArray[np.float64]) -> None:
        """Add Coulomb friction (stick-slip, held over the sample) to ``z_next``.

        The rigid-body velocity at the sample's end is v_end = v_free + v_gain * d for a
        friction current -d held over the sample. Stuck (v = 0 exactly) while the friction
        needed to stay stuck is at most F; slipping with friction -F sign(v); a stop inside
        the sample ends stuck, a reversal splits the sample at the linearly interpolated zero.
        """
        f = loop.friction
        v0 = float(z[loop.v_index])
        v_free = float(z_next[loop.v_index])
        gain = loop.v_gain
        hold = -v_free / gain                      # friction current keeping v_end = 0
        stop = False
        if v0 == 0.0:
            if abs(hold) <= f:
                d, stop = hold, True
            else:
                d = -f if v_free > 0 else f
        else:
            sign = 1.0 if v0 > 0 else -1.0
            d = -f * sign
            v_end = v_free + gain * d
            if v_end * sign <= 0:
                if abs(hold) <= f:
                    d, stop = hold, True
                else:                              # reverses: friction flips at the zero
                    theta = v0 / (v0 - v_end)
                    d = -f * sign * (2 * theta - 1)
        z_next += loop.gd_sum * d
        if stop:
            z_next[loop.v_index] = 0.0


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
