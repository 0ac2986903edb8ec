"""Discrepancy workflow: where a plant model and the measured moves disagree, and why.

The comparison does not depend on the controller: the model is driven by each move's
measured current, from rest at the move's start angle (:mod:`galvo_sysid.discrepancy.plant`), and
its angle is compared with the measured encoder. Back-to-back moves do not start quite at
rest: the ringing that the previous moves (up to two, known from move ids and stamps) leave
in the resonant modes is carried over into the record. Moves are grouped by signed target
angle. See docs/discrepancy.md for the derivation and an example.

Residual, noise floor and gap:

- Each move's residual e = y_measured - y_model is differenced twice (which removes the
  unknown start offset and start velocity of the rigid body exactly), its first two values
  (the kick of the unrecorded command in flight at the start) are left out, and it is
  Fourier transformed; bins 1 .. L/2-1 are used. The mean over a group's M moves is what the model
  must explain; the move-to-move scatter around it, pooled over the groups, gives the noise
  floor sigma^2(f) / M of that mean at every frequency.
- z^2(f) = |mean residual|^2 / (sigma^2(f) / M); its sum J over bins and groups is the
  noise-normalised cost (the negative log-likelihood of Gaussian noise, up to a constant).
  If the model explains the data, J is about J_noise = number of bins x groups.
- **gap** = sqrt(max(0, J / J_noise - 1)): the systematic part of the mean residual, RMS
  over all frequencies and groups, in units of the noise floor: 0 when the model explains
  the data within the noise, 1 when the unexplained residual is as large as the noise floor.
  Noise alone keeps it below :attr:`Comparison.noise_gap` (about 0.28 for six groups).

Naming an effect: each candidate of :data:`~galvo_sysid.model.effects.EFFECT_NAMES` is fitted
(its parameters minimise J) and scored by the drop of the Bayesian information criterion,
score = 2 (J_model - J_candidate) - p ln(n) (p fitted parameters, n real data points; the
unmodelled resonance pays 2 ln(bins) more for picking its frequency). The best candidate is
accepted when its score exceeds ``threshold`` and it closes at least a quarter of the gap; the
residual's whiteness (largest band excess of z^2) is reported next to it. The accepted effect
is added to the model, the effects added so far are refitted together, and the search repeats
while the gap stays above the noise, so several effects are found in turn. ``none`` is the
answer when no candidate is worth its parameters.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.optimize import minimize, minimize_scalar

from galvo_sysid.discrepancy.plant import (
    PlantSimulator,
    clip_correction,
    mode_free_responses,
    mode_pulse_responses,
    resonance_pulse_response,
)
from galvo_sysid.errors import ConfigurationError, InvalidDataError
from galvo_sysid.model.effects import EFFECT_NAMES, EFFECTS, Effect
from galvo_sysid.model.paper import PAPER_MODEL
from galvo_sysid.model.physics import Physics
from galvo_sysid.model.plant import PlantModel

if TYPE_CHECKING:
    import os

    from numpy.typing import ArrayLike, NDArray

__all__ = [
    'DEFAULT_THRESHOLD',
    'CandidateFit',
    'Comparison',
    'Diagnostics',
    'DiscrepancyResult',
    'Localisation',
    'MoveSet',
    'Step',
    'find_discrepancy',
    'read_moves',
]

DEFAULT_THRESHOLD = 10.0
"""Score (BIC drop) a candidate needs to be accepted."""


_PHASES = ('acceleration', 'deceleration', 'settling')

_BAND_SIGNIFICANCE = 5.0
"""Band excess (noise standard deviations) that counts as significant (noise alone passes
it in any of 16 bands with a probability below 0.01 %)."""

_MAX_RESONANCE = 0.95
"""Highest unmodelled resonance searched, as a fraction of the Nyquist frequency."""

_MIN_DAMPING = 1e-3
"""Smallest damping ratio an unmodelled resonance may be given (below it the fit is a
free sinusoid that chases noise rather than a mechanical mode)."""



# --------------------------------------------------------------------------- data


@dataclass(frozen=True)
class MoveSet:
    """Recorded moves: commanded current and encoder angle, one row per move.

    Attributes:
        current: Commanded current [A], (M, N).
        encoder: Encoder angle [deg], (M, N); each record starts at rest at its start angle.
        target_angle: Signed commanded rotation of each move [deg], (M,).
        move_id: Move ids, (M,).
        sample_period: Sampling period [s].
        stamp: Time of each record's first sample [s], (M,); NaN where unknown. With stamps
            and consecutive move ids the moves before a record are known, and the ringing
            they leave is part of the comparison (see :class:`Comparison`).
    """

    current: NDArray[np.float64]
    encoder: NDArray[np.float64]
    target_angle: NDArray[np.float64]
    move_id: NDArray[np.int64]
    sample_period: float
    stamp: NDArray[np.float64]

    @classmethod
    def create(cls, current: ArrayLike, encoder: ArrayLike, target_angle: ArrayLike, *,
               sample_period: float, move_id: ArrayLike | None = None,
               stamp: ArrayLike | None = None) -> MoveSet:
        """Check and build a move set.

        Raises:
            InvalidDataError: Wrong shapes, NaN/Inf, fewer than 4 samples, zero angles.
            ConfigurationError: Bad sample period.
        """
        cur = np.atleast_2d(np.asarray(current, dtype=float))
        enc = np.atleast_2d(np.asarray(encoder, dtype=float))
        if cur.ndim != 2 or cur.shape != enc.shape:
            raise InvalidDataError(
                f'current and encoder must both be (moves, samples), got {cur.shape} and '
                f'{enc.shape}')
        if cur.shape[1] < 16:
            raise InvalidDataError(f'records need at least 16 samples, got {cur.shape[1]}')
        if not (np.all(np.isfinite(cur)) and np.all(np.isfinite(enc))):
            raise InvalidDataError('current or encoder contains NaN or Inf')
        angles = np.broadcast_to(np.asarray(target_angle, dtype=float), (cur.shape[0],)).copy()
        if not np.all(np.isfinite(angles)) or np.any(angles == 0):
            raise InvalidDataError('target angles must be finite and non-zero')
        if not (math.isfinite(sample_period) and sample_period > 0):
            raise ConfigurationError(f'sample_period must be positive, got {sample_period!r}')
        ids = (np.arange(cur.shape[0]) if move_id is None
               else np.asarray(move_id, dtype=np.int64).reshape(-1))
        if ids.shape != (cur.shape[0],):
            raise InvalidDataError('move_id must have one id per move')
        stamps = (np.full(cur.shape[0], np.nan) if stamp is None
                  else np.asarray(stamp, dtype=float).reshape(-1))
        if stamps.shape != (cur.shape[0],):
            raise InvalidDataError('stamp must have one value per move')
        return cls(current=cur, encoder=enc, target_angle=angles, move_id=ids,
                   sample_period=float(sample_period), stamp=stamps)

    @classmethod
    def from_moves(cls, moves: Iterable[Any]) -> MoveSet:
        """Build from move objects (e.g. :class:`galvo_sysid.sim.simulator.Move`).

        Each needs ``current``, ``encoder``, ``target_angle``, ``sample_period`` and
        ``move_id``; ``stamp`` is used if present.

        Raises:
            InvalidDataError: No moves, records of different lengths or sample periods.
        """
        items = list(moves)
        if not items:
            raise InvalidDataError('no moves')
        periods = {float(m.sample_period) for m in items}
        if len(periods) != 1:
            raise InvalidDataError(f'moves have different sample periods: {sorted(periods)}')
        lengths = {len(m.current) for m in items} | {len(m.encoder) for m in items}
        if len(lengths) != 1:
            raise InvalidDataError(f'records have different lengths: {sorted(lengths)}')
        return cls.create([m.current for m in items], [m.encoder for m in items],
                          [m.target_angle for m in items], sample_period=periods.pop(),
                          move_id=[m.move_id for m in items],
                          stamp=[float(getattr(m, 'stamp', math.nan)) for m in items])

    @property
    def moves(self) -> int:
        """Number of moves."""
        return int(self.current.shape[0])

    @property
    def samples(self) -> int:
        """Samples per record."""
        return int(self.current.shape[1])

    def subset(self, rows: ArrayLike) -> MoveSet:
        """The moves of some rows."""
        idx = np.asarray(rows, dtype=np.intp)
        return MoveSet(current=self.current[idx], encoder=self.encoder[idx],
                       target_angle=self.target_angle[idx], move_id=self.move_id[idx],
                       sample_period=self.sample_period, stamp=self.stamp[idx])

    def groups(self, *, resolution: float = 1e-6) -> list[tuple[float, NDArray[np.intp]]]:
        """(signed angle, row indices) of each target angle, ascending angle."""
        keys = np.round(self.target_angle / resolution).astype(np.int64)
        out = []
        for key in np.unique(keys):
            idx = np.flatnonzero(keys == key)
            out.append((float(np.mean(self.target_angle[idx])), idx))
        return out


def read_moves(bag: str | os.PathLike[str], *, namespace: str | None = None,
               max_moves_per_angle: int | None = None,
               min_moves: int = 3) -> tuple[MoveSet, list[dict[str, Any]]]:
    """Read the moves of a bag (paired by move id like ``galvo-sysid identify``).

    Args:
        bag: rosbag2 bag (directory, .mcap or .db3).
        namespace: Scanner namespace when the bag holds several.
        max_moves_per_angle: Keep at most this many moves of each signed angle (the first).
        min_moves: Target angles with fewer usable moves are set aside (a noise floor needs
            at least 3).

    Returns:
        (moves, set-aside moves as JSON-ready dicts with a ``reason``).

    Raises:
        BagError: Missing, corrupt or unreadable bag.
        InvalidDataError: No usable move.
    """
    from galvo_sysid.field.bags import BagReader, SetAside
    from galvo_sysid.field.offline import rejection_to_dict
    from galvo_sysid.monitor.pairing import MoveWindower

    windower = MoveWindower(window_size=1000)
    rejected: list[dict[str, Any]] = []
    windows = []
    stamps: dict[int, float] = {}
    with BagReader(bag) as reader:
        for item in reader.move_halves(namespace=namespace):
            if isinstance(item, SetAside):
                rejected.append(item.to_dict())
            else:
                if item.signal == 'current':
                    stamps[int(item.move_id)] = float(item.stamp)
                windows.extend(windower.add(item))
            rejected.extend(rejection_to_dict(r) for r in windower.pop_rejections())
    windows.extend(windower.flush(min_moves=1))
    rejected.extend(rejection_to_dict(r) for r in windower.pop_rejections())
    if not windows:
        raise InvalidDataError(f'no usable move in {bag}')
    lengths = {w.current.shape[1] for w in windows}
    periods = {w.sample_period for w in windows}
    if len(lengths) != 1 or len(periods) != 1:
        raise InvalidDataError(f'{bag}: moves differ in record length {sorted(lengths)} or '
                               f'sample period {sorted(periods)}')
    counts: dict[float, int] = {}
    for w in windows:
        counts[w.target_angle] = counts.get(w.target_angle, 0) + len(w.move_ids)
    cur, enc, ang, ids = [], [], [], []
    taken: dict[float, int] = {}
    for w in sorted(windows, key=lambda w: w.first_stamp):
        if counts[w.target_angle] < min_moves:
            rejected.extend({'move_id': int(mid), 'target_angle': w.target_angle,
                             'stamp': stamps.get(int(mid)),
                             'reason': f'only {counts[w.target_angle]} move(s) of this target '
                                       f'angle (a noise floor needs {min_moves})'}
                            for mid in w.move_ids)
            continue
        for row, mid in enumerate(w.move_ids):
            n = taken.get(w.target_angle, 0)
            if max_moves_per_angle is not None and n >= max_moves_per_angle:
                continue
            taken[w.target_angle] = n + 1
            cur.append(w.current[row])
            enc.append(w.encoder[row])
            ang.append(w.target_angle)
            ids.append(mid)
    if not ids:
        raise InvalidDataError(f'{bag}: no target angle has {min_moves} usable moves')
    order = np.argsort(ids, kind='stable')
    id_arr = np.array(ids)[order]
    return MoveSet.create(np.array(cur)[order], np.array(enc)[order], np.array(ang)[order],
                          sample_period=periods.pop(), move_id=id_arr,
                          stamp=[stamps.get(int(i), math.nan) for i in id_arr]), rejected


# --------------------------------------------------------------------------- comparison


_SKIP = 2
"""Second differences left out at the start of each record: they hold the kick of the
unrecorded commands just before the record (the command in flight and the amplifier's
current), which the dwell's held current only approximates."""


def _analysed(n: int) -> int:
    """Second differences analysed of records of n samples: an even number, L."""
    return (n - 2 - _SKIP) // 2 * 2


def _second_difference_spectrum(x: NDArray[np.float64]) -> NDArray[np.complex128]:
    """Spectrum (bins 1 .. L/2 - 1) of the second difference of records (..., N).

    The first :data:`_SKIP` second differences are left out, one more if that leaves an odd
    number (L = :func:`_analysed` (N)).
    """
    n = x.shape[-1]
    d2 = np.diff(x, 2, axis=-1)[..., n - 2 - _analysed(n):]
    spec = np.fft.rfft(d2, axis=-1)
    return np.asarray(spec[..., 1:-1], dtype=np.complex128)


def _stack(z: NDArray[np.complex128]) -> NDArray[np.float64]:
    """Complex (..., F) -> real (..., 2F): real parts, then imaginary parts."""
    return np.concatenate([z.real, z.imag], axis=-1)


@dataclass(frozen=True)
class Diagnostics:
    """Arrays describing how one model compares with the moves (for reports and plots).

    Attributes:
        angles: Signed target angle of each group [deg], (G,).
        counts: Moves per group, (G,).
        frequencies: Frequencies of the spectral bins [Hz], (F,).
        residual_spectrum: |mean residual| per group as an angle spectrum [deg], (G, F),
            the modes' random ringing projected out.
        noise_spectrum: Its noise floor [deg], (G, F).
        z2: Noise-normalised squared residual per group and bin, (G, F).
        time: Sample times [s], (N,).
        measured: Mean measured angle relative to the start [deg], (G, N).
        simulated: Mean simulated angle relative to the start [deg], (G, N).
        residual: Mean residual (measured - simulated) [deg], (G, N).
        residual_floor: Its noise floor (standard error) [deg], (G, N).
        acceleration_residual: Second difference of ``residual`` [deg], (G, N - 2): where in
            the move the model's acceleration is wrong.
        acceleration_floor: Its noise floor [deg], (G, N - 2).
        current: Mean commanded current [A], (G, N).
        cost: J.
        cost_noise: J_noise, the expectation of J from the noise alone.
        group_cost: J per group, (G,).
        group_cost_noise: J_noise per group, (G,).
    """

    angles: NDArray[np.float64]
    counts: NDArray[np.int64]
    frequencies: NDArray[np.float64]
    residual_spectrum: NDArray[np.float64]
    noise_spectrum: NDArray[np.float64]
    z2: NDArray[np.float64]
    time: NDArray[np.float64]
    measured: NDArray[np.float64]
    simulated: NDArray[np.float64]
    residual: NDArray[np.float64]
    residual_floor: NDArray[np.float64]
    acceleration_residual: NDArray[np.float64]
    acceleration_floor: NDArray[np.float64]
    current: NDArray[np.float64]
    cost: float
    cost_noise: float
    group_cost: NDArray[np.float64]
    group_cost_noise: NDArray[np.float64]

    @property
    def gap(self) -> float:
        """sqrt(max(0, J / J_noise - 1)) (see the module docs)."""
        return _gap(self.cost, self.cost_noise)

    @property
    def noise_gap(self) -> float:
        """The largest gap noise alone gives (see :attr:`Comparison.noise_gap`)."""
        return _noise_gap(self.cost_noise)

    @property
    def group_gaps(self) -> NDArray[np.float64]:
        """The gap of each group."""
        return np.array([_gap(c, n) for c, n in zip(self.group_cost, self.group_cost_noise,
                                                     strict=True)])


def _gap(cost: float, noise: float) -> float:
    return math.sqrt(max(0.0, cost / noise - 1.0)) if noise > 0 else math.nan


def _noise_gap(noise: float) -> float:
    return math.sqrt(3.0 / math.sqrt(noise))


def _fft_conv(x: NDArray[np.float64], h: NDArray[np.float64], lo: int,
              hi: int) -> NDArray[np.float64]:
    """Samples lo:hi of the causal convolutions of records x (..., L) with h (..., L)."""
    nfft = 1 << (x.shape[-1] + h.shape[-1] - 1).bit_length()
    out = np.fft.irfft(np.fft.rfft(x, nfft, axis=-1) * np.fft.rfft(h, nfft, axis=-1), nfft,
                       axis=-1)
    return np.asarray(out[..., lo:hi], dtype=np.float64)


class Comparison:
    """A plant model against the measured moves: residuals, noise floor, cost, gap.

    Each record is simulated from rest at its start angle, except that the ringing the
    previous moves left in the resonant modes is carried over: when the move ids and stamps
    show that up to ``history`` moves ran just before a record, their measured currents (the
    unrecorded dwell between records holding the last current) drive the model's resonant
    modes into the record.

    The noise floor is estimated once, from the move-to-move scatter of the residuals of
    ``reference`` (the model the analysis starts from), and kept for every model compared,
    so that costs and gaps of different models are comparable.

    Args:
        moves: The measured moves (at least 3 per group).
        reference: The model whose residual scatter sets the noise floor.
        history: Previous moves whose ringing is carried over (0: every record from rest).
    """

    def __init__(self, moves: MoveSet, reference: PlantModel = PAPER_MODEL, *,
                 history: int = 2) -> None:
        groups = moves.groups()
        counts = np.array([len(idx) for _, idx in groups], dtype=np.int64)
        if np.any(counts < 3):
            small = [f'{a:+g} deg ({len(i)})' for a, i in groups if len(i) < 3]
            raise InvalidDataError(
                f'each target angle needs at least 3 moves for a noise floor; too few: '
                f'{", ".join(small)}')
        if abs(moves.sample_period - reference.sample_period) > 1e-9 * moves.sample_period:
            raise ConfigurationError(
                f'the moves are sampled at {moves.sample_period!r} s but the model at '
                f'{reference.sample_period!r} s')
        if history < 0:
            raise ConfigurationError(f'history must be >= 0, got {history}')
        self.moves = moves
        self.angles = np.array([a for a, _ in groups])
        self.index = [idx for _, idx in groups]
        self.counts = counts
        self.start = moves.encoder[:, 0].copy()
        self.mean_current = np.stack([moves.current[i].mean(axis=0) for i in self.index])
        self.mean_encoder = np.stack([moves.encoder[i].mean(axis=0) for i in self.index])
        self.mean_start = np.array([self.start[i].mean() for i in self.index])
        self.ext, self.with_history = _extended_inputs(moves, history)
        self.mean_ext = np.stack([self.ext[i].mean(axis=0) for i in self.index])
        self._sims: dict[Physics, PlantSimulator] = {}
        self._pulses: dict[tuple[Any, ...], tuple[NDArray[np.float64], NDArray[np.float64]]] = {}
        n = moves.samples
        length = _analysed(n)                     # second differences analysed
        self.n_bins = length // 2 - 1
        self.frequencies = np.arange(1, self.n_bins + 1) / (length * moves.sample_period)
        self._bases: dict[tuple[Any, ...], list[NDArray[np.float64]]] = {}
        # Noise floor: pooled scatter of the per-move spectra around their group means, with
        # each move's own random ringing of the reference's modes projected out (the same
        # projection as for the means, see ``basis``).
        ref = reference.physics()
        spec = _second_difference_spectrum(moves.encoder - self.simulate(ref, per_move=True))
        free = self._ringing(ref)
        dev = [spec[idx] - spec[idx].mean(axis=0) for idx in self.index]
        dof = sum(len(idx) - 1 for idx in self.index)
        var = sum(np.sum(np.abs(d)**2, axis=0) for d in dev) / dof
        for _ in range(2):
            w = 1.0 / np.sqrt(var)
            q = _orthonormal(_stack(free * w).T)
            ss = np.zeros(self.n_bins)
            for d in dev:
                x = _stack(d * w)
                x -= (x @ q) @ q.T
                ss += np.sum(x[:, :self.n_bins]**2 + x[:, self.n_bins:]**2, axis=0) / w**2
            var = ss / (dof * (1.0 - q.shape[1] / (2.0 * self.n_bins)))
        self.noise_variance = var                  # per-move variance sigma^2(f)
        self.n_real = 2 * self.n_bins * len(self.index)
        self.weights = [np.sqrt(m / var) for m in counts]   # 1 / std of the group means

    # ------------------------------------------------------------------ simulation

    def simulator(self, physics: Physics) -> PlantSimulator:
        """The (cached) open-loop simulator of a plant."""
        sim = self._sims.get(physics)
        if sim is None:
            if len(self._sims) > 64:
                self._sims.clear()
            sim = PlantSimulator(physics, sample_period=self.moves.sample_period,
                                 length=self.moves.samples)
            self._sims[physics] = sim
        return sim

    def _pulse(self, physics: Physics) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Resonant modes' pulse responses over the extended records: command, applied."""
        key = (physics.residues, physics.natural_frequencies, physics.damping_ratios,
               physics.gain_ratio, physics.pure_delay, physics.lag_time_constant)
        found = self._pulses.get(key)
        if found is None:
            if len(self._pulses) > 64:
                self._pulses.clear()
            length = self.ext.shape[1]
            t = self.moves.sample_period
            found = (resonance_pulse_response(physics, sample_period=t, length=length),
                     resonance_pulse_response(physics, sample_period=t, length=length,
                                              applied=True))
            self._pulses[key] = found
        return found

    def carry(self, physics: Physics, ext: NDArray[np.float64], current: NDArray[np.float64],
              *, hold: NDArray[np.float64] | float = 0.0) -> NDArray[np.float64]:
        """Ringing (R, N) that the moves before the records leave in the resonant modes.

        Args:
            physics: The plant.
            ext: Extended records (R, L): previous moves, dwells, then the record.
            current: The records themselves (R, N).
            hold: Current holding each record's start angle (a pivot spring's equilibrium,
                which the record's own simulation already accounts for), (R, 1).
        """
        n = self.moves.samples
        length = ext.shape[1]
        if length == n or not physics.residues:
            return np.zeros_like(current)
        h_u, h_d = self._pulse(physics)
        out = (_fft_conv(ext - hold, h_u, length - n, length)
               - _fft_conv(current - hold, h_u[:n], 0, n))
        if math.isfinite(physics.current_limit):
            d = clip_correction(ext, physics, sample_period=self.moves.sample_period)
            out += (_fft_conv(d, h_d, length - n, length)
                    - _fft_conv(d[:, length - n:], h_d[:n], 0, n))
        return out

    def simulate(self, model: PlantModel | Physics, *, per_move: bool = False) -> NDArray[
            np.float64]:
        """Simulated angle: per move (M, N), or per group mean (G, N).

        With ``per_move=False`` a linear model is simulated on the group means and a
        nonlinear one move by move and averaged.
        """
        phys = model if isinstance(model, Physics) else model.physics()
        sim = self.simulator(phys)
        if not per_move and phys.linear:
            hold = sim.holding_current(self.mean_start)[:, None]
            return sim.simulate(self.mean_current, self.mean_start) + self.carry(
                phys, self.mean_ext, self.mean_current, hold=hold)
        hold = sim.holding_current(self.start)[:, None]
        y = sim.simulate(self.moves.current, self.start) + self.carry(
            phys, self.ext, self.moves.current, hold=hold)
        if per_move:
            return y
        return np.stack([y[i].mean(axis=0) for i in self.index])

    # ------------------------------------------------------------------ measures

    def _ringing(self, physics: Physics) -> NDArray[np.complex128]:
        """(2 n_modes, F) spectra of the resonant modes' free ringing (decaying cos, sin)."""
        if not physics.natural_frequencies:
            return np.zeros((0, self.n_bins), dtype=np.complex128)
        free = mode_free_responses(physics.natural_frequencies, physics.damping_ratios,
                                   sample_period=self.moves.sample_period,
                                   length=self.moves.samples)
        return _second_difference_spectrum(free.reshape(-1, self.moves.samples))

    def basis(self, physics: Physics) -> list[NDArray[np.float64]]:
        """Orthonormal whitened ringing columns (2F, r) of each group (see :meth:`whitened`)."""
        key = (physics.natural_frequencies, physics.damping_ratios)
        bases = self._bases.get(key)
        if bases is None:
            if len(self._bases) > 64:
                self._bases.clear()
            free = self._ringing(physics)
            bases = [_orthonormal(_stack(free * w).T) for w in self.weights]
            self._bases[key] = bases
        return bases

    def whitened(self, model: PlantModel | Physics, *,
                 ringing: PlantModel | Physics | None = None) -> NDArray[np.float64]:
        """(G, 2F) noise-normalised mean residual spectra (real parts, then imaginary).

        The carried-over ringing is predicted from the previous moves' measured currents;
        the rest, driven by noise the records do not hold (the current noise, the encoder
        noise fed back), is a random free ringing of each resonant mode. Its two shapes
        (decaying cosine and sine) per mode and group are projected out, for the modes of
        ``ringing`` (default: the model itself; candidates of one round all use the round's
        base model, so that their costs compare).
        """
        phys = model if isinstance(model, Physics) else model.physics()
        ring = phys if ringing is None else (
            ringing if isinstance(ringing, Physics) else ringing.physics())
        spec = _second_difference_spectrum(self.mean_encoder - self.simulate(phys))
        out = np.stack([_stack(spec[g] * self.weights[g]) for g in range(len(self.index))])
        for g, q in enumerate(self.basis(ring)):
            out[g] -= (q.T @ out[g]) @ q.T
        return out

    def cost(self, model: PlantModel | Physics, *,
             ringing: PlantModel | Physics | None = None) -> float:
        """J of a model (see the module docs and :meth:`whitened`)."""
        r = self.whitened(model, ringing=ringing)
        return float(np.sum(r * r))

    def noise_cost(self, model: PlantModel | Physics | None = None) -> float:
        """J_noise: the expectation of J if a model explained the data.

        One per complex bin and group, less half the projected ringing shapes of ``model``'s
        modes (default: none projected).
        """
        n = float(self.n_bins * len(self.index))
        if model is None:
            return n
        phys = model if isinstance(model, Physics) else model.physics()
        return n - sum(int(q.shape[1]) for q in self.basis(phys)) / 2.0

    @property
    def noise_gap(self) -> float:
        """The largest gap the noise alone gives (three standard deviations).

        J of a model that explains the data is a sum of n = n_bins x groups independent
        terms of mean and standard deviation 1, so J / J_noise - 1 stays below 3 / sqrt(n)
        (on simulated data without any effect its spread over seeds is 0.029 for the
        expected 0.026).
        """
        return _noise_gap(self.noise_cost())

    def gap(self, model: PlantModel | Physics) -> float:
        """The gap of a model, in units of the noise floor (see the module docs)."""
        return _gap(self.cost(model), self.noise_cost(model))

    def whiteness(self, model: PlantModel | Physics, *, bands: int = 16,
                  ringing: PlantModel | Physics | None = None) -> float:
        """Largest excess of z^2 in any of ``bands`` log-spaced bands, in noise std units.

        About 0 +- 1 when the residual is white (noise only); > 5 means a band still holds
        a systematic residual.
        """
        r = self.whitened(model, ringing=ringing)
        nb = self.n_bins
        z2 = (r[:, :nb]**2 + r[:, nb:]**2).sum(axis=0)
        g = len(self.index)
        edges = np.unique(np.geomspace(1, nb + 1, bands + 1).astype(int))
        worst = -math.inf
        for lo, hi in itertools.pairwise(int(e) for e in edges):
            n = (hi - lo) * g
            worst = max(worst, (float(z2[lo - 1:hi - 1].sum()) - n) / math.sqrt(n))
        return worst

    def diagnostics(self, model: PlantModel) -> Diagnostics:
        """Everything the report shows about one model."""
        phys = model.physics()
        mean_sim = self.simulate(phys)
        resid_moves = self.moves.encoder - self.simulate(phys, per_move=True)
        spec = _second_difference_spectrum(self.mean_encoder - mean_sim)
        nb = self.n_bins
        n = self.moves.samples
        t = np.asarray(np.arange(n) * self.moves.sample_period, dtype=np.float64)
        omega = 2 * np.pi * self.frequencies * self.moves.sample_period
        to_angle = 1.0 / np.abs(1 - np.exp(-1j * omega))**2      # undo the 2nd difference
        g_count = len(self.index)
        z2 = np.empty((g_count, nb))
        res_spec = np.empty((g_count, nb))
        noise_spec = np.empty((g_count, nb))
        residual = self.mean_encoder - mean_sim
        floor = np.empty((g_count, n))
        acc_floor = np.empty((g_count, n - 2))
        bases = self.basis(phys)
        for g, idx in enumerate(self.index):
            w = self.weights[g]
            r = _stack(spec[g] * w)
            r -= (bases[g].T @ r) @ bases[g].T
            z2[g] = r[:nb]**2 + r[nb:]**2
            res_spec[g] = np.sqrt(z2[g]) / w * to_angle / math.sqrt(_analysed(n))
            noise_spec[g] = to_angle / w / math.sqrt(_analysed(n))
            per = resid_moves[idx]
            floor[g] = per.std(axis=0, ddof=1) / math.sqrt(len(idx))
            acc_floor[g] = np.diff(per, 2, axis=1).std(axis=0, ddof=1) / math.sqrt(len(idx))
        start = self.mean_start[:, None]
        gcost = z2.sum(axis=1)
        return Diagnostics(
            angles=self.angles.copy(), counts=self.counts.copy(),
            frequencies=self.frequencies.copy(), residual_spectrum=res_spec,
            noise_spectrum=noise_spec, z2=z2, time=t,
            measured=self.mean_encoder - start, simulated=mean_sim - start,
            residual=residual, residual_floor=floor,
            acceleration_residual=np.diff(residual, 2, axis=1), acceleration_floor=acc_floor,
            current=self.mean_current.copy(), cost=float(gcost.sum()),
            cost_noise=self.noise_cost(phys), group_cost=gcost,
            group_cost_noise=np.array([nb - q.shape[1] / 2.0 for q in bases]))


def _orthonormal(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """Orthonormal basis of the column space of a (rank-revealing)."""
    if a.shape[1] == 0:
        return np.zeros((a.shape[0], 0))
    u, sv, _ = np.linalg.svd(a, full_matrices=False)
    keep = sv > 1e-10 * sv[0]
    return np.asarray(u[:, keep], dtype=np.float64)


def _extended_inputs(moves: MoveSet, history: int) -> tuple[NDArray[np.float64],
                                                             NDArray[np.bool_]]:
    """Each record preceded by up to ``history`` previous moves (M, L), right-aligned.

    A previous move counts if its move id is one less and the stamps put it at most four
    record lengths before; the dwell between records holds the last current. Where no
    previous move is known the record stands alone (zeros before it).
    """
    n = moves.samples
    t = moves.sample_period
    pos = {int(mid): i for i, mid in enumerate(moves.move_id)}
    chains: list[list[tuple[int, int]]] = []       # per row: [(row, dwell after it), ...]
    for i, mid in enumerate(moves.move_id):
        chain: list[tuple[int, int]] = []
        cur = i
        for _ in range(history):
            prev = pos.get(int(moves.move_id[cur]) - 1)
            if prev is None:
                break
            gap = (moves.stamp[cur] - moves.stamp[prev]) / t - n
            if not (math.isfinite(gap) and -0.5 <= gap <= 4 * n):
                break
            chain.append((prev, max(round(gap), 0)))
            cur = prev
        chains.append(chain)
        del mid
    lengths = [n + sum(n + d for _, d in c) for c in chains]
    width = max(lengths)
    ext = np.zeros((moves.moves, width))
    for i, chain in enumerate(chains):
        end = width
        ext[i, end - n:end] = moves.current[i]
        end -= n
        for prev, dwell in chain:
            ext[i, end - dwell:end] = moves.current[prev, -1]
            end -= dwell
            ext[i, end - n:end] = moves.current[prev]
            end -= n
    return ext, np.array([bool(c) for c in chains])


def _replace_effect(model: PlantModel, index: int, params: dict[str, float]) -> PlantModel:
    """The model with its effect ``index`` given new parameters."""
    effects = list(model.effects)
    effects[index] = Effect.create(effects[index].name, params)
    return replace(model, effects=tuple(effects))


# --------------------------------------------------------------------------- candidates


@dataclass(frozen=True)
class CandidateFit:
    """One candidate effect fitted to the data.

    Attributes:
        effect: Effect name (``none``: the model as it is).
        parameters: Fitted parameters (see :data:`~galvo_sysid.model.effects.EFFECTS`).
        n_parameters: Parameters fitted.
        cost: J of the augmented model.
        score: BIC drop against the model without the candidate (0 for ``none``).
        gap: Gap of the augmented model.
        whiteness: Largest band excess of the augmented model's residual (noise standard
            deviations; noise alone stays below about 4).
        model: The augmented model.
    """

    effect: str
    parameters: dict[str, float]
    n_parameters: int
    cost: float
    score: float
    gap: float
    whiteness: float
    model: PlantModel = field(repr=False, compare=False)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: effect, score, parameters, cost, gap, whiteness."""
        return {'effect': self.effect, 'score': _finite_or_none(self.score),
                'parameters': dict(self.parameters), 'cost': _finite_or_none(self.cost),
                'gap': _finite_or_none(self.gap), 'whiteness': _finite_or_none(self.whiteness)}


def _finite_or_none(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _scalar_search(objective: Callable[[float], float], grid: NDArray[np.float64]) -> tuple[
        float, float]:
    """Minimise a 1-D objective: coarse grid, then bounded refinement around the best."""
    values = np.array([objective(float(x)) for x in grid])
    best = int(np.argmin(values))
    lo = float(grid[max(best - 1, 0)])
    hi = float(grid[min(best + 1, len(grid) - 1)])
    x_best, f_best = float(grid[best]), float(values[best])
    if hi > lo:
        res = minimize_scalar(objective, bounds=(lo, hi), method='bounded',
                              options={'xatol': 1e-4 * (hi - lo)})
        if float(res.fun) < f_best:
            x_best, f_best = float(res.x), float(res.fun)
    return x_best, f_best


class _Fitter:
    """Fits the candidate effects to the moves, on top of a base model."""

    def __init__(self, comparison: Comparison, base: PlantModel) -> None:
        self.comp = comparison
        self.base = base
        self.base_phys = base.physics()
        self.base_cost = comparison.cost(base)
        self.max_current = float(np.max(np.abs(comparison.moves.current)))

    def _cost_of(self, name: str, index: int | None = None) -> Callable[[dict[str, float]],
                                                                         float]:
        """Cost of the base model with effect ``name`` set (or effect ``index`` replaced)."""
        def cost(params: dict[str, float]) -> float:
            try:
                if index is None:
                    model = self.base.with_effect(name, params)
                else:
                    model = _replace_effect(self.base, index, params)
            except ConfigurationError:
                return math.inf
            return self.comp.cost(model, ringing=self.base_phys)
        return cost

    def _scalar_spec(self, name: str) -> tuple[str, NDArray[np.float64],
                                               Callable[[float], float],
                                               Callable[[float], float]]:
        """(parameter, search grid, grid value -> parameter, parameter -> grid value)."""
        t = self.base.sample_period

        def same(x: float) -> float:
            return x
        if name == 'input_delay':
            return 'delay', self.base.base_delay + np.linspace(0.0, 4.0, 17) * t, same, same
        if name == 'gain_change':
            return 'gain_ratio', np.linspace(0.5, 1.5, 21), same, same
        if name == 'coulomb_friction':
            return 'friction_current', np.linspace(0.0, 0.2, 11) * self.max_current, same, same
        if name == 'current_saturation':
            return ('current_limit', np.linspace(0.25, 1.0, 16) * self.max_current, same,
                    same)
        if name == 'pivot_stiffness':
            # the spring's effect grows with w^2: search in w^2, up to 3000 rad/s
            def root(x: float) -> float:
                return math.sqrt(max(x, 1.0))

            def square(v: float) -> float:
                return v * v
            return 'natural_frequency', np.linspace(0.0, 1.0, 16)**2 * 3000.0**2, root, square
        raise ConfigurationError(f'unknown effect {name!r}')

    def fit(self, name: str) -> tuple[dict[str, float], int]:
        """Fitted parameters of one candidate and their number."""
        if name == 'unmodeled_resonance':
            return self._fit_resonance(), 3
        key, grid, value, _ = self._scalar_spec(name)
        cost = self._cost_of(name)
        x, _ = _scalar_search(lambda x: cost({key: value(x)}), grid)
        return {key: value(x)}, 1

    def refine(self, index: int) -> PlantModel:
        """The base model with effect ``index`` refitted locally, the others held."""
        effect = self.base.effects[index]
        params = effect.params()
        cost = self._cost_of(effect.name, index)
        if effect.name == 'unmodeled_resonance':
            w0, z0, k0 = (params['natural_frequency'], params['damping_ratio'],
                          params['residue'])
            scale = abs(k0) if k0 else 1.0

            def objective(x: NDArray[np.float64]) -> float:
                zeta = z0 * math.exp(float(x[1]))
                if not _MIN_DAMPING <= zeta <= 0.95:
                    return math.inf
                return cost({'natural_frequency': w0 * math.exp(float(x[0])),
                             'damping_ratio': zeta, 'residue': scale * float(x[2])})
            x0 = np.array([0.0, 0.0, k0 / scale])
            simplex = x0 + np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.1, 0.0],
                                     [0.0, 0.0, 0.05]])
            res = minimize(objective, x0, method='Nelder-Mead',
                           options={'xatol': 1e-4, 'fatol': 1e-2, 'maxiter': 80,
                                    'initial_simplex': simplex})
            if float(res.fun) >= objective(x0):
                return self.base
            x = res.x
            new = {'natural_frequency': w0 * math.exp(float(x[0])),
                   'damping_ratio': z0 * math.exp(float(x[1])), 'residue': scale * float(x[2])}
            return _replace_effect(self.base, index, new)
        key, grid, value, inverse = self._scalar_spec(effect.name)
        start = inverse(params[key])
        width = float(grid[1] - grid[0])
        lo, hi = max(start - width, float(grid[0])), start + width
        res = minimize_scalar(lambda x: cost({key: value(x)}), bounds=(lo, hi),
                              method='bounded', options={'xatol': 1e-4 * (hi - lo)})
        if float(res.fun) >= cost({key: params[key]}):
            return self.base
        return _replace_effect(self.base, index, {key: value(float(res.x))})

    def _fit_resonance(self) -> dict[str, float]:
        """Scan (omega, zeta) with the residue solved linearly, then refine all three.

        For each grid point the extra mode's response to the groups' mean extended records
        (its ringing from the previous moves included) is fitted to the base model's
        whitened residual by weighted least squares; the best point starts a Nelder-Mead
        refinement of the full model's cost.
        """
        comp = self.comp
        base_phys = self.base.physics()
        resid = comp.whitened(base_phys)                  # (G, 2F)
        n = comp.moves.samples
        t = comp.moves.sample_period
        nyquist = math.pi / t
        lowest = 2 * math.pi / (n * t)
        w_max = _MAX_RESONANCE * nyquist
        grid_w, grid_z = np.meshgrid(np.geomspace(2 * lowest, w_max, 64),
                                     np.array([0.003, 0.01, 0.03, 0.1, 0.3]))
        omegas, zetas = grid_w.ravel(), grid_z.ravel()
        length = comp.mean_ext.shape[1]
        pulse = mode_pulse_responses(omegas, zetas, gain=base_phys.gain_ratio,
                                     lag=base_phys.lag_time_constant, delay=base_phys.pure_delay,
                                     sample_period=t, length=length)
        resp = _fft_conv(comp.mean_ext[None, :, :], pulse[:, None, :], length - n, length)
        resp_s = _second_difference_spectrum(resp)                       # (P, G, F)
        num = np.zeros(omegas.shape[0])
        den = np.zeros(omegas.shape[0])
        bases = comp.basis(base_phys)
        for g in range(len(comp.index)):
            m = _stack(resp_s[:, g] * comp.weights[g])                   # (P, 2F)
            m -= (m @ bases[g]) @ bases[g].T
            num += m @ resid[g]
            den += np.sum(m * m, axis=1)
        with np.errstate(divide='ignore', invalid='ignore'):
            k = np.where(den > 0, num / den, 0.0)
        drop = k * num
        best = int(np.argmax(drop))
        w0, z0, k0 = float(omegas[best]), float(zetas[best]), float(k[best])
        scale = abs(k0) if k0 != 0 else 1.0
        cost = self._cost_of('unmodeled_resonance')

        def objective(x: NDArray[np.float64]) -> float:
            omega, zeta = math.exp(x[0]), math.exp(x[1])
            if not (lowest <= omega <= w_max and _MIN_DAMPING <= zeta <= 0.95):
                return math.inf
            return cost({'natural_frequency': omega, 'damping_ratio': zeta,
                         'residue': float(x[2]) * scale})

        x0 = np.array([math.log(w0), math.log(z0), math.copysign(1.0, k0)])
        simplex = x0 + np.array([[0.0, 0.0, 0.0], [0.03, 0.0, 0.0], [0.0, 0.3, 0.0],
                                 [0.0, 0.0, 0.2]])
        res = minimize(objective, x0, method='Nelder-Mead',
                       options={'xatol': 1e-4, 'fatol': 1e-2, 'maxiter': 120,
                                'initial_simplex': simplex})
        x = res.x if float(res.fun) <= objective(x0) else x0
        return {'natural_frequency': math.exp(float(x[0])),
                'damping_ratio': math.exp(float(x[1])),
                'residue': float(x[2]) * scale}

    def candidate(self, name: str) -> CandidateFit:
        """Fit and score one candidate."""
        params, p = self.fit(name)
        model = self.base.with_effect(name, params)
        cost = self.comp.cost(model, ringing=self.base_phys)
        score = 2.0 * (self.base_cost - cost) - p * math.log(self.comp.n_real)
        if name == 'unmodeled_resonance':
            # look-elsewhere: the frequency is picked among about n_bins resolvable ones
            score -= 2.0 * math.log(self.comp.n_bins)
        return CandidateFit(effect=name, parameters=params, n_parameters=p, cost=cost,
                            score=score, gap=self.comp.gap(model),
                            whiteness=self.comp.whiteness(model), model=model)

    def none(self) -> CandidateFit:
        """The base model as it is."""
        return CandidateFit(effect='none', parameters={}, n_parameters=0, cost=self.base_cost,
                            score=0.0, gap=self.comp.gap(self.base),
                            whiteness=self.comp.whiteness(self.base), model=self.base)


# --------------------------------------------------------------------------- where


@dataclass(frozen=True)
class Band:
    """The residual's excess over the noise in one frequency band.

    Attributes:
        low: Lower edge [Hz].
        high: Upper edge [Hz].
        excess: (sum z^2 - count) / sqrt(count): noise standard deviations (about 0 +- 1
            for noise alone).
        share: Fraction of the total positive excess.
    """

    low: float
    high: float
    excess: float
    share: float

    def to_dict(self) -> dict[str, float]:
        """JSON-ready."""
        return {'low_hz': self.low, 'high_hz': self.high, 'excess': self.excess,
                'share': self.share}


@dataclass(frozen=True)
class Localisation:
    """Where a model and the moves disagree: frequency, phase of the move, move size.

    Attributes:
        bands: Every band, ascending frequency.
        phases: How the excess of the acceleration residual over its noise floor (per
            sample) divides among ``acceleration``, ``deceleration`` and ``settling`` (after
            the current has died down); shares of 1.
        main_phase: The phase with the largest share (``none`` if nothing is significant).
        angles: Target angle magnitudes [deg], ascending.
        gaps: Gap at each angle magnitude (both signs together).
        size_trend: How the gap depends on the angle: ``grows with the angle``, ``grows
            faster than the angle``, ``about constant``, ``shrinks with the angle``, ``only
            large moves``, ``only small moves``, ``none`` or ``single angle``.
        size_exponent: Slope of log(gap) over log(angle) (nan if undefined).
    """

    bands: tuple[Band, ...]
    phases: dict[str, float]
    main_phase: str
    angles: tuple[float, ...]
    gaps: tuple[float, ...]
    size_trend: str
    size_exponent: float

    @property
    def main_bands(self) -> tuple[Band, ...]:
        """Significant bands (excess > 5), largest first, at most three."""
        sig = sorted((b for b in self.bands if b.excess > _BAND_SIGNIFICANCE),
                     key=lambda b: -b.excess)
        return tuple(sig[:3])

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {
            'main_bands': [b.to_dict() for b in self.main_bands],
            'bands': [b.to_dict() for b in self.bands],
            'phases': dict(self.phases),
            'main_phase': self.main_phase,
            'sizes': [{'angle': a, 'gap': g} for a, g in zip(self.angles, self.gaps,
                                                             strict=True)],
            'size_trend': self.size_trend,
            'size_exponent': _finite_or_none(self.size_exponent),
        }

    def summary(self) -> list[str]:
        """Short human-readable lines."""
        lines = []
        bands = self.main_bands
        if bands:
            lines.append('frequency: ' + ', '.join(
                f'{_hz(b.low)}-{_hz(b.high)} ({100 * b.share:.0f} %)' for b in bands))
        else:
            lines.append('frequency: no band above the noise')
        if self.main_phase != 'none':
            lines.append('time: mostly ' + self.main_phase + ' (' + ', '.join(
                f'{k} {100 * v:.0f} %' for k, v in self.phases.items()) + ')')
        else:
            lines.append('time: no phase above the noise')
        sizes = ', '.join(f'{a:g} deg: {g:.2f}' for a, g in zip(self.angles, self.gaps,
                                                                   strict=True))
        lines.append(f'move size: {self.size_trend} (gap by angle: {sizes})')
        return lines


def _hz(f: float) -> str:
    return f'{f / 1e3:.3g} kHz' if f >= 1e3 else f'{f:.3g} Hz'


def _phase_bounds(current: NDArray[np.float64]) -> tuple[int, int]:
    """(start of braking, start of settling) sample indices of a mean move current.

    Acceleration runs from the first large current to its first reversal, braking from there
    to the last large current (above 5 % of the peak); settling is the rest.
    """
    mag = np.abs(current)
    peak = float(mag.max())
    n = current.shape[0]
    if peak == 0:
        return 0, 0
    big = np.flatnonzero(mag > 0.3 * peak)
    start = int(big[0])
    sign = np.sign(current[start])
    after = np.flatnonzero(current[start:] * sign < 0)
    brake = start + int(after[0]) if after.size else n
    tail = np.flatnonzero(mag > 0.05 * peak)
    settle = int(tail[-1]) + 1 if tail.size else n
    return min(brake, settle), settle


def localise(diag: Diagnostics, *, bands: int = 16) -> Localisation:
    """Where the residual of :class:`Diagnostics` exceeds the noise."""
    nb = diag.frequencies.shape[0]
    z2 = diag.z2.sum(axis=0)
    g = diag.z2.shape[0]
    edges = np.unique(np.geomspace(1, nb + 1, bands + 1).astype(int))
    raw = []
    df = float(diag.frequencies[0])
    for lo, hi in itertools.pairwise(int(e) for e in edges):
        n = (hi - lo) * g
        raw.append((lo * df - df / 2, (hi - 1) * df + df / 2,
                    (float(z2[lo - 1:hi - 1].sum()) - n) / math.sqrt(n),
                    float(z2[lo - 1:hi - 1].sum()) - n))
    total = sum(max(r[3], 0.0) for r in raw)
    band_list = tuple(Band(low=lo, high=hi, excess=ex,
                           share=(max(e, 0.0) / total if total > 0 else 0.0))
                      for lo, hi, ex, e in raw)
    # time: excess of the acceleration residual's (residual / floor)^2 over 1 in each phase
    sums = dict.fromkeys(_PHASES, 0.0)
    counts = dict.fromkeys(_PHASES, 0)
    for k in range(g):
        brake, settle = _phase_bounds(diag.current[k])
        fl = diag.acceleration_floor[k]
        with np.errstate(divide='ignore', invalid='ignore'):
            zt = np.where(fl > 0, diag.acceleration_residual[k] / fl, 0.0)
        ex = zt**2 - 1.0
        idx = np.arange(1, zt.shape[0] + 1)   # the second difference at k is centred on k
        for name, mask in (('acceleration', idx < brake),
                           ('deceleration', (idx >= brake) & (idx < settle)),
                           ('settling', idx >= settle)):
            sums[name] += float(ex[mask].sum())
            counts[name] += int(mask.sum())
    # significant if the time-domain excess is well above its rough noise spread
    n_total = sum(counts.values())
    total = sum(sums.values())
    significant = diag.gap > diag.noise_gap and total > 5 * math.sqrt(2 * max(n_total, 1))
    density = {k: max(v, 0.0) / counts[k] if counts[k] else 0.0 for k, v in sums.items()}
    tot = sum(density.values())
    phases = {k: (v / tot if tot > 0 else 0.0) for k, v in density.items()}
    main_phase = max(phases, key=lambda k: phases[k]) if significant else 'none'
    # move size: pool both signs of each magnitude
    mags = np.round(np.abs(diag.angles), 9)
    angles = tuple(float(a) for a in np.unique(mags))
    gaps, floors = [], []
    for a in angles:
        sel = np.flatnonzero(mags == a)
        noise = float(diag.group_cost_noise[sel].sum())
        gaps.append(_gap(float(diag.group_cost[sel].sum()), noise))
        floors.append(_noise_gap(noise))
    trend, slope = _size_trend(angles, gaps, floors)
    return Localisation(bands=band_list, phases=phases, main_phase=main_phase, angles=angles,
                        gaps=tuple(gaps), size_trend=trend, size_exponent=slope)


def _size_trend(angles: Sequence[float], gaps: Sequence[float],
                floors: Sequence[float]) -> tuple[str, float]:
    """Classify how the gap depends on the move size (``floors``: noise gap per angle)."""
    sig = [g > f for g, f in zip(gaps, floors, strict=True)]
    if not any(sig):
        return 'none', math.nan
    if len(angles) < 2:
        return 'single angle', math.nan
    if not sig[0] and sig[-1] and gaps[-1] > 3 * floors[-1]:
        return 'only large moves', math.nan
    if sig[0] and not sig[-1] and gaps[0] > 3 * floors[0]:
        return 'only small moves', math.nan
    x = np.log([a for a, s in zip(angles, sig, strict=True) if s])
    y = np.log([g for g, s in zip(gaps, sig, strict=True) if s])
    if x.shape[0] < 2:
        return 'only at ' + ', '.join(f'{a:g} deg' for a, s in zip(angles, sig, strict=True)
                                      if s), math.nan
    slope = float(np.polyfit(x, y, 1)[0])
    if slope > 1.2:
        return 'grows faster than the angle', slope
    if slope > 0.3:
        return 'grows with the angle', slope
    if slope >= -0.3:
        return 'about constant', slope
    return 'shrinks with the angle', slope


# --------------------------------------------------------------------------- workflow


@dataclass(frozen=True)
class Step:
    """One effect added by the workflow.

    Attributes:
        effect: Effect name.
        parameters: Its parameters.
        score: Its BIC drop.
        gap_before: Gap of the model before the step.
        gap_after: Gap after.
        whiteness_after: Largest band excess after (noise std units).
        candidates: Every candidate of this round, best first (``none`` included).
        model: The model after the step.
    """

    effect: str
    parameters: dict[str, float]
    score: float
    gap_before: float
    gap_after: float
    whiteness_after: float
    candidates: tuple[CandidateFit, ...]
    model: PlantModel = field(repr=False, compare=False)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {'effect': self.effect, 'parameters': dict(self.parameters),
                'score': _finite_or_none(self.score),
                'gap_before': _finite_or_none(self.gap_before),
                'gap_after': _finite_or_none(self.gap_after),
                'whiteness_after': _finite_or_none(self.whiteness_after),
                'candidates': [c.to_dict() for c in self.candidates]}


@dataclass(frozen=True)
class DiscrepancyResult:
    """What :func:`find_discrepancy` found.

    Attributes:
        effect: The first (most significant) effect added, or ``none``.
        parameters: Its parameters in the final model (empty for ``none``).
        gap_before: Gap of the given model.
        gap_after: Gap of the final model (every step added).
        candidates: The first round's candidates, best first (``none`` included).
        rounds: Every round's candidates (the last one found nothing, or stopped at
            ``max_effects``).
        steps: Every effect added, in order (each with its parameters as found in its
            round; ``parameters`` above and ``final_model`` hold the values refitted
            together with the later effects).
        initial_model: The model given.
        final_model: The model with every step added.
        where: Where the given model disagrees with the moves.
        where_after: Where the final model still does.
        threshold: Score a candidate needed.
        noise_gap: Largest gap the noise alone gives (about 0.1 % chance to exceed it).
        moves: Moves compared.
        before: Diagnostics of the given model (for reports).
        after: Diagnostics of the final model.
    """

    effect: str
    parameters: dict[str, float]
    gap_before: float
    gap_after: float
    candidates: tuple[CandidateFit, ...]
    rounds: tuple[tuple[CandidateFit, ...], ...]
    steps: tuple[Step, ...]
    initial_model: PlantModel
    final_model: PlantModel
    where: Localisation
    where_after: Localisation
    threshold: float
    noise_gap: float
    moves: int
    before: Diagnostics = field(repr=False, compare=False)
    after: Diagnostics = field(repr=False, compare=False)

    def to_dict(self) -> dict[str, Any]:
        """The ``--json`` object.

        Keys: effect, parameters, gap_before, gap_after, candidates, steps, then where,
        where_after, moves, angles, threshold, noise_gap and model (the final model).
        """
        from galvo_sysid.model.files import model_to_dict

        return {
            'effect': self.effect,
            'parameters': dict(self.parameters),
            'gap_before': _finite_or_none(self.gap_before),
            'gap_after': _finite_or_none(self.gap_after),
            'candidates': [c.to_dict() for c in self.candidates],
            'steps': [s.to_dict() for s in self.steps],
            'where': self.where.to_dict(),
            'where_after': self.where_after.to_dict(),
            'moves': self.moves,
            'angles': [float(a) for a in self.before.angles],
            'threshold': self.threshold,
            'noise_gap': self.noise_gap,
            'model': model_to_dict(self.final_model),
        }


def find_discrepancy(moves: MoveSet, model: PlantModel = PAPER_MODEL, *,
                     threshold: float = DEFAULT_THRESHOLD, max_effects: int = 3,
                     min_gap: float | None = None, min_improvement: float = 0.25,
                     effects: Sequence[str] = EFFECT_NAMES,
                     progress: Callable[[str], None] | None = None) -> DiscrepancyResult:
    """Compare a model with measured moves, name the missing effects and add them.

    Args:
        moves: The measured moves (at least 3 of each target angle).
        model: The model to start from (default: the nominal plant).
        threshold: Score (BIC drop) a candidate needs to be accepted.
        max_effects: Most effects added.
        min_gap: After an effect is added, the search goes on only while the gap is at
            least this; default :attr:`Comparison.noise_gap` (below it the model explains the
            moves within the noise).
        min_improvement: A candidate is accepted only if it also closes at least this
            fraction of the gap (statistically significant but practically irrelevant
            additions are left out).
        effects: Candidate effects to try.
        progress: Called with a short text before each candidate fit.

    Returns:
        The result; ``effect`` is ``none`` when the model explains the moves.

    Raises:
        InvalidDataError: Too few moves.
        ConfigurationError: Unknown effect name or bad settings.
    """
    unknown = [e for e in effects if e not in EFFECTS]
    if unknown:
        raise ConfigurationError(f'unknown effect(s) {unknown}; expected {EFFECT_NAMES}')
    if not (math.isfinite(threshold) and max_effects >= 0 and 0 <= min_improvement < 1):
        raise ConfigurationError(
            'threshold must be finite, max_effects >= 0 and 0 <= min_improvement < 1')
    comp = Comparison(moves, model)
    if min_gap is None:
        min_gap = comp.noise_gap
    current = model
    steps: list[Step] = []
    where_added: list[int] = []                # index of each step's effect in the model
    first: tuple[CandidateFit, ...] | None = None
    rounds: list[tuple[CandidateFit, ...]] = []
    for round_index in range(max_effects + 1):
        if round_index and (round_index >= max_effects or comp.gap(current) < min_gap):
            break   # enough effects, or the model explains the moves within the noise
        fitter = _Fitter(comp, current)
        fits = [fitter.none()]
        for name in effects:
            if progress is not None:
                progress(f'step {round_index + 1}: fitting {name}')
            fits.append(fitter.candidate(name))
        ranked = tuple(sorted(fits, key=lambda c: -c.score))
        rounds.append(ranked)
        if first is None:
            first = ranked
        best = ranked[0]
        relevant = best.gap <= (1.0 - min_improvement) * fits[0].gap
        if best.effect == 'none' or best.score <= threshold or not relevant or max_effects == 0:
            break
        current = best.model
        index = (len(current.effects) - 1 if best.effect == 'unmodeled_resonance' else
                 [e.name for e in current.effects].index(best.effect))
        if index not in where_added:
            where_added.append(index)
        if len(where_added) > 1:   # several effects now: refit them together, twice
            for _ in range(2):
                for i in where_added:
                    if progress is not None:
                        progress(f'step {round_index + 1}: refitting {current.effects[i].name}')
                    current = _Fitter(comp, current).refine(i)
        steps.append(Step(effect=best.effect, parameters=current.effects[index].params(),
                          score=best.score, gap_before=fits[0].gap, gap_after=comp.gap(current),
                          whiteness_after=comp.whiteness(current), candidates=ranked,
                          model=current))
    if steps:
        names = ', '.join(str(current.effects[i]) for i in where_added)
        current = replace(current, description=f'{model.description or "model"} + found '
                                               f'by galvo-sysid discrepancy: {names}')
    assert first is not None
    before = comp.diagnostics(model)
    after = comp.diagnostics(current) if steps else before
    head = steps[0] if steps else None
    return DiscrepancyResult(
        effect=head.effect if head else 'none',
        parameters=current.effects[where_added[0]].params() if head else {},
        gap_before=comp.gap(model), gap_after=comp.gap(current), candidates=first,
        rounds=tuple(rounds), steps=tuple(steps), initial_model=model, final_model=current,
        where=localise(before), where_after=localise(after), threshold=threshold,
        noise_gap=comp.noise_gap, moves=moves.moves, before=before, after=after)
