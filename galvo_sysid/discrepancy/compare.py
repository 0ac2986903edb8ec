"""The comparison: a plant model against the measured moves, residual, noise floor and gap.

The comparison does not depend on the controller: the model is driven by each move's
measured current, from rest at the move's start angle (:mod:`galvo_sysid.discrepancy.plant`), and
its angle is compared with the measured encoder. Back-to-back moves do not start quite at
rest: the ringing that the previous moves (up to two, known from move ids and stamps) leave
in the resonant modes is carried over into the record. Moves are grouped by signed target
angle. See docs/discrepancy.md for the derivation and an example.

Residual, noise floor and gap (the spectra and the gap's formula are in
:mod:`galvo_sysid.discrepancy.spectra`):

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
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from galvo_sysid.discrepancy.moves import _extended_inputs
from galvo_sysid.discrepancy.plant import (
    PlantSimulator,
    clip_correction,
    mode_free_responses,
    resonance_pulse_response,
)
from galvo_sysid.discrepancy.spectra import (
    _analysed,
    _band_excess,
    _fft_conv,
    _gap,
    _noise_gap,
    _orthonormal,
    _power,
    _second_difference_spectrum,
    _stack,
)
from galvo_sysid.errors import ConfigurationError, InvalidDataError
from galvo_sysid.model.paper import PAPER_MODEL
from galvo_sysid.model.physics import Physics

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from galvo_sysid.discrepancy.moves import MoveSet
    from galvo_sysid.model.plant import PlantModel

__all__ = ['Comparison', 'Diagnostics']

_K = TypeVar('_K')
_V = TypeVar('_V')


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
        drift_z: The mean acceleration residual over the record in units of its standard
            error (from the moves' scatter), (G,): a residual that builds up steadily over
            the record (a constant acceleration error: friction in one direction, a current
            offset) sits at 0 Hz, which J leaves out.
        detrended_residual: ``residual`` less its least-squares straight line (the unknown
            start offset and start velocity) [deg], (G, N).
        detrended_floor: Its noise floor, from the scatter of the moves' own detrended
            residuals [deg], (G, N).
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
    drift_z: NDArray[np.float64]
    detrended_residual: NDArray[np.float64]
    detrended_floor: NDArray[np.float64]

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
        self._carries: dict[tuple[Any, ...], NDArray[np.float64]] = {}
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
                ss += np.sum(_power(x), axis=0) / w**2
            var = ss / (dof * (1.0 - q.shape[1] / (2.0 * self.n_bins)))
        self.noise_variance = var                  # per-move variance sigma^2(f)
        self.n_real = 2 * self.n_bins * len(self.index)
        self.weights = [np.sqrt(m / var) for m in counts]   # 1 / std of the group means

    # ------------------------------------------------------------------ simulation

    def simulator(self, physics: Physics) -> PlantSimulator:
        """The (cached) open-loop simulator of a plant."""
        return _cached(self._sims, physics, lambda: PlantSimulator(
            physics, sample_period=self.moves.sample_period, length=self.moves.samples))

    def _pulse(self, physics: Physics) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Resonant modes' pulse responses over the extended records: command, applied."""
        key = (physics.residues, physics.natural_frequencies, physics.damping_ratios,
               physics.gain_ratio, physics.pure_delay, physics.lag_time_constant)
        length = self.ext.shape[1]
        t = self.moves.sample_period
        return _cached(self._pulses, key, lambda: (
            resonance_pulse_response(physics, sample_period=t, length=length),
            resonance_pulse_response(physics, sample_period=t, length=length, applied=True)))

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
        held = np.asarray(hold, dtype=float)
        key = (physics.residues, physics.natural_frequencies, physics.damping_ratios,
               physics.gain_ratio, physics.pure_delay, physics.lag_time_constant,
               physics.current_limit, ext.shape, current.shape, held.shape, held.tobytes())

        def make() -> NDArray[np.float64]:
            h_u, h_d = self._pulse(physics)
            out = (_fft_conv(ext - hold, h_u, length - n, length)
                   - _fft_conv(current - hold, h_u[:n], 0, n))
            if math.isfinite(physics.current_limit):
                d = clip_correction(ext, physics, sample_period=self.moves.sample_period)
                out += (_fft_conv(d, h_d, length - n, length)
                        - _fft_conv(d[:, length - n:], h_d[:n], 0, n))
            return out
        # cached: the candidates that leave the modes, the input dynamics and the limit alone
        # (friction, viscous friction, the encoder's error...) share it
        return _cached(self._carries, key, make)

    def simulate(self, model: PlantModel | Physics, *, per_move: bool = False) -> NDArray[
            np.float64]:
        """Simulated angle: per move (M, N), or per group mean (G, N).

        With ``per_move=False`` a linear model is simulated on the group means and a
        nonlinear one move by move and averaged.
        """
        phys = _physics(model)
        sim = self.simulator(phys)
        if not per_move and phys.linear:
            hold = sim.holding_current(self.mean_start)[:, None]
            return sim.simulate(self.mean_current, self.mean_start) + self.carry(
                phys, self.mean_ext, self.mean_current, hold=hold)
        hold = sim.holding_current(sim.true_start(self.start))[:, None]
        carry = self.carry(phys, self.ext, self.moves.current, hold=hold)
        if phys.reading_error:    # the encoder reads the carried ringing too
            y = sim.simulate(self.moves.current, self.start, extra=carry)
        else:
            y = sim.simulate(self.moves.current, self.start) + carry
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
        def make() -> list[NDArray[np.float64]]:
            free = self._ringing(physics)
            return [_orthonormal(_stack(free * w).T) for w in self.weights]
        return _cached(self._bases, (physics.natural_frequencies, physics.damping_ratios), make)

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
        phys = _physics(model)
        ring = phys if ringing is None else _physics(ringing)
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
        phys = _physics(model)
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
        worst = -math.inf
        for _, _, excess, n in _band_excess(_power(self.whitened(model, ringing=ringing)),
                                            bands=bands):
            worst = max(worst, excess / math.sqrt(n))
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
        drift_z = np.zeros(g_count)
        # a straight line per record (start offset and velocity) removed by least squares
        line = np.stack([np.ones(n), t - t.mean()], axis=1)
        flat = np.eye(n) - line @ np.linalg.pinv(line)
        detrended = resid_moves @ flat.T
        det_mean = np.empty((g_count, n))
        det_floor = np.empty((g_count, n))
        bases = self.basis(phys)
        for g, idx in enumerate(self.index):
            w = self.weights[g]
            r = _stack(spec[g] * w)
            r -= (bases[g].T @ r) @ bases[g].T
            z2[g] = _power(r)
            res_spec[g] = np.sqrt(z2[g]) / w * to_angle / math.sqrt(_analysed(n))
            noise_spec[g] = to_angle / w / math.sqrt(_analysed(n))
            per = resid_moves[idx]
            floor[g] = per.std(axis=0, ddof=1) / math.sqrt(len(idx))
            det_mean[g] = detrended[idx].mean(axis=0)
            det_floor[g] = detrended[idx].std(axis=0, ddof=1) / math.sqrt(len(idx))
            acc = np.diff(per, 2, axis=1)
            acc_floor[g] = acc.std(axis=0, ddof=1) / math.sqrt(len(idx))
            drift_sd = float(acc.mean(axis=1).std(ddof=1)) / math.sqrt(len(idx))
            if drift_sd > 0:
                drift_z[g] = float(np.mean(np.diff(residual[g], 2))) / drift_sd
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
            group_cost_noise=np.array([nb - q.shape[1] / 2.0 for q in bases]),
            drift_z=drift_z, detrended_residual=det_mean, detrended_floor=det_floor)


def _physics(model: PlantModel | Physics) -> Physics:
    """The plant with its effects acting (a :class:`Physics` as it is)."""
    return model if isinstance(model, Physics) else model.physics()


def _cached(cache: dict[_K, _V], key: _K, make: Callable[[], _V]) -> _V:
    """``cache[key]``, made first if missing (a cache of more than 64 is emptied first)."""
    found = cache.get(key)
    if found is None:
        if len(cache) > 64:
            cache.clear()
        found = make()
        cache[key] = found
    return found
