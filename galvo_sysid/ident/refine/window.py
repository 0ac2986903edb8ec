"""One window's averaged moves as a regression problem, and its moves' scatter.

:class:`WindowProblem` holds a window of M records (current and encoder of one target
angle): their average, on which the model is fitted, and the moves' deviations from it, from
which the noise is estimated. Its columns (:meth:`WindowProblem.columns`) are the filtered
responses of the rigid body and of each unit mode to the averaged current (the linear
parameters k0, k_i multiply them), each mode's two free-response columns (the ringing the
previous move left), an offset and the amplifier lag's free response: the window's nuisance.

The current before a record is not recorded; with the computation delay it still acts on the
first rows. It is taken as the level the records end at (the settled current of the previous
move, which a positioning move leaves before the next one starts), which removes the bias
that assuming the record's first sample would leave (the feed-forward starts at sample 0).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from scipy import fft as sp_fft
from scipy.linalg import qr, solve_triangular

from galvo_sysid.errors import InvalidDataError
from galvo_sysid.ident.refine.regressors import (
    FIRST_ROW,
    Regressors,
    filtered_input,
    free_responses,
    powers,
    rigid_taps,
    second_difference,
)
from galvo_sysid.ident.refine.whitener import Whitener, lower_times

if TYPE_CHECKING:
    from collections.abc import Sequence
    from typing import TypeAlias

    from numpy.typing import ArrayLike, NDArray

    Floats: TypeAlias = Sequence[float] | NDArray[np.float64]
    Candidates: TypeAlias = tuple[NDArray[np.complex128], NDArray[np.complex128]]

__all__ = ['MIN_SAMPLES', 'WindowProblem', 'validate', 'window_records']

MIN_SAMPLES = 64
"""Fewest samples per record the refined fit accepts."""

_MAX_DECAY = 700.0  # exp(-700) is about 1e-304: a lag's decay per sample beyond it is 0


def validate(current: ArrayLike, encoder: ArrayLike) -> tuple[NDArray[np.float64],
                                                               NDArray[np.float64]]:
    """Records as float arrays (M, N), checked; one record (N,) becomes (1, N).

    Raises:
        InvalidDataError: Not numeric, different shapes, too short, NaN or Inf.
    """
    try:
        cur = np.asarray(current, dtype=float)
        enc = np.asarray(encoder, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InvalidDataError(f'records are not numeric arrays: {exc}') from exc
    if cur.ndim == 1:
        cur, enc = cur[None, :], enc[None, :] if enc.ndim == 1 else enc
    if cur.ndim != 2 or enc.shape != cur.shape:
        raise InvalidDataError(f'current and encoder must both be (M, N) or (N,), got shapes '
                               f'{np.shape(current)} and {np.shape(encoder)}')
    if cur.shape[1] < MIN_SAMPLES:
        raise InvalidDataError(f'records have {cur.shape[1]} samples; the refined fit needs at '
                               f'least {MIN_SAMPLES}')
    if not (np.all(np.isfinite(cur)) and np.all(np.isfinite(enc))):
        raise InvalidDataError('current or encoder contains NaN or Inf')
    return cur, enc


def window_records(windows: Sequence[tuple[ArrayLike, ArrayLike]], min_moves: int) -> list[
        tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """Each window's records checked, the encoder relative to each record's start.

    Raises:
        InvalidDataError: A bad window (its index is named when there are several).
    """
    out = []
    for j, (current, encoder) in enumerate(windows):
        where = f'window {j}: ' if len(windows) > 1 else ''
        try:
            cur, enc = validate(current, encoder)
        except InvalidDataError as exc:
            raise InvalidDataError(f'{where}{exc}') from exc
        if cur.shape[0] < min_moves:
            raise InvalidDataError(f'{where}a joint fit needs at least {min_moves} moves per '
                                   f'window')
        if not np.any(cur.mean(axis=0) - cur[:, 0].mean()):
            raise InvalidDataError(f'{where}no excitation: the averaged current is constant')
        out.append((cur, enc - enc[:, :1]))
    return out


_LAST_MOVES: list[tuple[tuple[float, int, float], NDArray[np.float64], Regressors]] = []


def _moves_input(cur: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The moves' currents less their mean, and each one's level before its record (the
    settled end of the previous move, less the mean's): the input of their deviations."""  # noqa: D205, D209
    return cur - cur.mean(axis=0), cur[:, -1:] - cur[:, -1].mean()


def _moves_regressors(cur: NDArray[np.float64], *, sample_period: float, delay: int,
                      fraction: float) -> Regressors:
    """The moves' deviations from their mean current as :class:`Regressors`.

    The last one is kept (read-only; a copy of its records is compared, about 20 us): the
    screening of a window (:func:`~galvo_sysid.ident.screen.screen_moves`) and its fit ask
    for the same one, about 1 ms of transforms for 100 moves.
    """
    key = (float(sample_period), int(delay), float(fraction))
    last = _LAST_MOVES[0] if _LAST_MOVES else None
    if last is not None and last[0] == key and last[1].shape == cur.shape \
            and np.array_equal(last[1], cur):
        return last[2]
    dev, pre = _moves_input(cur)
    regs = Regressors(dev, sample_period=sample_period, delay=delay, fraction=fraction, pre=pre)
    _LAST_MOVES[:] = [(key, np.array(cur, dtype=float), regs)]
    return regs


class WindowProblem:
    """A window's averaged moves, its columns and its moves' scatter (see the module docs).

    Args:
        current: Current records (M, N), validated.
        encoder: Encoder records (M, N), start angle removed.
        sample_period: Sampling period [s].
        delay: Whole samples of pure delay.
        fraction: Fractional part of the pure delay [samples].
        n_modes: Resonant modes.
    """

    def __init__(self, current: NDArray[np.float64], encoder: NDArray[np.float64], *,
                 sample_period: float, delay: int, fraction: float, n_modes: int) -> None:
        self.cur, self.enc = current, encoder
        self.moves = current.shape[0]
        self.t = sample_period
        self.n_modes = n_modes
        pre = float(current[:, -1].mean())
        self.regs = Regressors(current.mean(axis=0), sample_period=sample_period, delay=delay,
                               fraction=fraction, pre=pre)
        self.first = FIRST_ROW
        self.n = current.shape[1]
        self.k = np.arange(self.n, dtype=float)[self.first:]
        self.yf_raw = second_difference(encoder.mean(axis=0))[self.first:]
        self.n_linear = 1 + n_modes + 2 * n_modes + 2
        self._moves_regs: Regressors | None = None
        self._moves_enc: NDArray[np.float64] | None = None
        self._deviations: tuple[bytes, NDArray[np.float64]] | None = None  # the last one
        self.set_whitening(None)

    # -- whitening -------------------------------------------------------------------------
    def set_whitening(self, a: Whitener | None) -> None:
        """Use a prewhitening map (a :class:`Whitener`) on data and columns, or none."""
        self.whiten = a
        self.yf = self.apply_whitening(self.yf_raw)
        self._columns_cache: dict[bool, tuple[bytes, NDArray[np.float64]]] = {}
        self._derivatives: tuple[bytes, NDArray[np.float64]] | None = None  # the last one

    def whitening_transposed(self, arr: NDArray[np.float64]) -> NDArray[np.float64]:
        """The whitening map's transpose on columns ``arr`` (rows, k): ``(W y) . c`` is
        ``y . W^T c`` (:meth:`Whitener.transposed`; ``arr`` without a whitener)."""  # noqa: D205, D209
        if self.whiten is None:
            return arr
        return self.whiten.transposed(arr)

    def apply_whitening(self, arr: NDArray[np.float64], axis: int = 0) -> NDArray[np.float64]:
        """Whiten ``arr`` along the row ``axis`` (an invertible lower-triangular map, so no row
        is lost)."""  # noqa: D205, D209
        if self.whiten is None:
            return arr
        return self.whiten.apply(arr, axis=axis)

    # -- columns ---------------------------------------------------------------------------
    def columns(self, omega: Floats, zeta: Floats, lag: float, *,
                whitened: bool = True) -> NDArray[np.float64]:
        """Regressor matrix (rows, n_linear).

        Columns: rigid body, modes, two free-response columns per mode, offset, and the
        amplifier lag's free response. The last matrix of each kind (whitened or not) is
        kept and given again for the same parameters (read-only: the fit, its scans and its
        profiles ask for the same point several times).
        """
        key = np.concatenate([np.asarray(omega, dtype=float), np.asarray(zeta, dtype=float),
                              [lag]]).tobytes()
        cached = self._columns_cache.get(whitened)
        if cached is not None and cached[0] == key:
            return cached[1]
        phi = self._columns(omega, zeta, lag)
        if whitened:
            phi = self.apply_whitening(phi)
        phi.flags.writeable = False
        self._columns_cache[whitened] = (key, phi)
        return phi

    def _columns(self, omega: Floats, zeta: Floats, lag: float) -> NDArray[np.float64]:
        """:meth:`columns` unwhitened, computed."""
        n = self.n_modes
        _, e = powers(omega, zeta, self.n, self.t)
        phi = np.empty((self.k.size, self.n_linear))
        phi[:, : 1 + n] = self.regs.all(omega, zeta, lag, e)[:, self.first:].T
        phi[:, 1 + n: 1 + 3 * n] = free_responses(omega, zeta, self.n, self.t, e,
                                                  first=self.first).T
        phi[:, -2] = 1.0
        phi[:, -1] = self.lag_free(lag)
        return phi

    def lag_free(self, lag: float) -> NDArray[np.float64]:
        """Free response of the lag state from the first row on (a unit impulse without lag)."""
        if lag <= 0:
            out = np.zeros(self.k.size)
            out[0] = 1.0
            return out
        rate = min(self.t / lag, _MAX_DECAY)
        return np.asarray(np.exp(-(self.k - self.first) * rate), dtype=np.float64)

    def model_derivatives(self, omega: NDArray[np.float64], zeta: NDArray[np.float64],
                          lag: float, coef: NDArray[np.float64], *, lag_free: bool,
                          whitened: bool = True) -> NDArray[np.float64]:
        """The model's derivatives: d (columns @ coef) / d x_j, shape (rows, 2 n (+1)).

        For every nonlinear parameter (ln omega_i, ln zeta_i, then T_l / T if ``lag_free``), by
        forward differences, whitened or not. The last result is kept and given again for the
        same arguments (read-only: the covariance asks for the fit's last Jacobian's).

        Each difference is combined with the coefficients before it is convolved and whitened
        (both linear): one response and one whitened column per parameter, not one per
        column it touches.
        """
        key = b''.join(np.asarray(v, dtype=float).tobytes()
                       for v in (omega, zeta, [lag, float(lag_free), float(whitened)], coef))
        if self._derivatives is not None and self._derivatives[0] == key:
            return self._derivatives[1]
        n = self.n_modes
        h = 1e-6
        regs, first = self.regs, self.first
        # one batch: the 2 n single-mode perturbations (omega_i e^h, then zeta_i e^h) and the
        # n modes at the point, which each difference is taken from
        w_p = np.concatenate([omega * math.exp(h), omega, omega])
        z_p = np.concatenate([zeta, zeta * math.exp(h), zeta])
        _, e = powers(w_p, z_p, self.n, self.t)
        h_lag = regs.lag_impulse(lag)
        imp = regs.mode_impulses(w_p, z_p, lag, e, h_lag)
        gains = np.tile(coef[1: 1 + n], 2)
        diff = gains[:, None] * (imp[: 2 * n] - np.tile(imp[2 * n:], (2, 1)))
        free = free_responses(w_p, z_p, self.n, self.t, e, first=first)
        cos = np.tile(coef[1 + n: 1 + 3 * n: 2], 2)[:, None]
        sin = np.tile(coef[2 + n: 1 + 3 * n: 2], 2)[:, None]
        free_diff = (cos * (free[0: 4 * n: 2] - np.tile(free[4 * n:: 2], (2, 1)))
                     + sin * (free[1: 4 * n: 2] - np.tile(free[4 * n + 1:: 2], (2, 1))))
        if lag_free:  # the rigid body, the modes and the lag state at lag + step
            step = h * self.t
            k0 = coef[0]
            h_lag2 = regs.lag_impulse(lag + step)
            base = imp[2 * n:]
            moved = regs.mode_impulses(omega, zeta, lag + step, e[2 * n:], h_lag2)
            lag_imp = (k0 * ((lag + step) * h_lag2 - lag * h_lag)
                       + coef[1: 1 + n] @ (moved - base))
            diff = np.vstack([diff, lag_imp[None, :]])
        out = regs.convolve(diff)[:, first:].T
        out[:, : 2 * n] += free_diff.T
        if lag_free:
            out[:, -1] += (coef[-1] * (self.lag_free(lag + step) - self.lag_free(lag))
                           - k0 * step * regs.rigid_single[first:])
        if whitened:
            out = self.apply_whitening(out)
        out = np.asarray(out / h, dtype=np.float64)
        out.flags.writeable = False
        self._derivatives = (key, out)
        return out

    # -- scans -----------------------------------------------------------------------------
    def candidate_transforms(self, lag: float, w_c: NDArray[np.float64],
                             z_c: NDArray[np.float64]) -> Candidates:
        """Candidate modes' powers and impulse responses' transforms, for :meth:`scan`.

        They depend on the record length, the sample period and the input dynamics only: the
        windows of a joint fit with records of one length share them.
        """
        _, e = powers(w_c, z_c, self.n, self.t)
        h = self.regs.mode_impulses(w_c, z_c, lag, e)
        return e, self.regs.transform(h)

    def _candidates(self, lag: float, w_c: NDArray[np.float64], z_c: NDArray[np.float64],
                    shared: Candidates | None = None) -> NDArray[np.float64]:
        """Whitened (forced, free cos, free sin) columns of candidate modes: (rows, 3, m).

        With a whitener, the rows past its head come from one transform per candidate (the
        filter folded into the convolution) and, for the free responses, in closed form
        (:meth:`Whitener.exponential_tail`); the head rows from the head. The same numbers as
        whitening the columns (to rounding), at a third of the transforms. ``shared``: the
        candidates' :meth:`candidate_transforms`, if already made.
        """
        e, hh = self.candidate_transforms(lag, w_c, z_c) if shared is None else shared
        first, rows = self.first, self.k.size
        m = hh.shape[0]
        wh = self.whiten
        if wh is None or not wh.filter.size - 1 <= wh.order < rows:
            out = np.empty((rows, 3, m))
            out[:, 0] = self.regs.convolve_transformed(hh)[:, first:].T
            out[:, 1] = e[:, first:].real.T
            out[:, 2] = e[:, first:].imag.T
            return self.apply_whitening(out)
        p = wh.order
        forced, filtered = self.regs.convolve_filtered(hh, wh.filter)
        tail = wh.exponential_tail(e, first, rows)
        out = np.empty((rows, 3, m))
        head = np.empty((p, 3, m))  # the head's rows as one product
        head[:, 0] = forced[:, first: first + p].T
        head[:, 1] = e[:, first: first + p].real.T
        head[:, 2] = e[:, first: first + p].imag.T
        out[:p] = lower_times(wh.head, head.reshape(p, -1)).reshape(p, 3, m)
        out[p:, 0] = filtered[:, first + p:].T
        out[p:, 1] = tail.real.T
        out[p:, 2] = tail.imag.T
        return out

    @staticmethod
    def _gains(others: NDArray[np.float64], y: NDArray[np.float64],
               cand: NDArray[np.float64], keep: int = 0) -> tuple[
                   NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """(cost reduction, forced coefficient, others' coefficients) of each candidate's 3
        columns after ``others``.

        ``cand`` is (rows, 3, m), as :meth:`_candidates` gives it. The third array holds the
        coefficients of the first ``keep`` columns of ``others`` with each candidate's columns
        in the regression, (keep, m) (none by default).
        """  # noqa: D205
        scale = np.linalg.norm(others, axis=0)
        scale[scale == 0] = 1.0
        q, r = qr(others / scale, mode='economic', check_finite=False)
        qty = q.T @ y
        r_o = y - q @ qty
        rows, _, m = cand.shape
        flat = cand.reshape(rows, 3 * m)  # the candidates' columns: two products, not m
        qtf = q.T @ flat
        flat_o = flat - q @ qtf
        c_o = flat_o.reshape(rows, 3, m)
        gram = np.empty((m, 3, 3))
        for i in range(3):
            for j in range(i, 3):
                gram[:, i, j] = gram[:, j, i] = np.einsum('ka,ka->a', c_o[:, i], c_o[:, j])
        rhs = (r_o @ flat_o).reshape(3, m).T
        try:
            sol = np.linalg.solve(gram, rhs[..., None])[..., 0]
        except np.linalg.LinAlgError:
            return np.full(m, -1.0), np.zeros(m), np.zeros((keep, m))
        gain = np.sum(rhs * sol, axis=1)
        gain[~np.isfinite(gain)] = -1.0
        kept = np.zeros((keep, m))
        if keep:  # others' coefficients: R c = Q^T (y - candidate columns x sol)
            proj = qty[:, None] - np.einsum('pcm,mc->pm', qtf.reshape(-1, 3, m), sol)
            kept = (solve_triangular(r, proj, check_finite=False) / scale[:, None])[:keep]
        return (np.asarray(gain, dtype=np.float64), np.asarray(sol[:, 0], dtype=np.float64),
                np.asarray(kept, dtype=np.float64))

    def scan(self, i: int, omega: NDArray[np.float64], zeta: NDArray[np.float64],
             lag: float, w_c: NDArray[np.float64], z_c: NDArray[np.float64], *,
             shared: Candidates | None = None) -> tuple[NDArray[np.float64],
                                                       NDArray[np.float64]]:
        """(cost reduction, residue) of mode i at each candidate (w_c, z_c), others fixed.

        ``shared``: the candidates' :meth:`candidate_transforms` (same lag), if already made.
        """
        gain, k = self.scan_residues(i, omega, zeta, lag, w_c, z_c, shared=shared,
                                     others=False)
        return gain, k[1 + i]

    def scan_residues(self, i: int, omega: NDArray[np.float64], zeta: NDArray[np.float64],
                      lag: float, w_c: NDArray[np.float64], z_c: NDArray[np.float64], *,
                      shared: Candidates | None = None, others: bool = True) -> tuple[
                          NDArray[np.float64], NDArray[np.float64]]:
        """:meth:`scan` with every shared coefficient [k0, k_1 .. k_n] at each candidate.

        Returns ``(cost reduction, residues (1 + n, m))``: mode i's row is the
        candidate's own residue; the others' rows (``others``, else zeros) are the other
        modes' residues and k0 solved anew with the candidate in place of mode i.
        """
        n = self.n_modes
        phi = self.columns(omega, zeta, lag)
        mine = np.array([1 + i, 1 + n + 2 * i, 2 + n + 2 * i])
        gain, k, kept = self._gains(np.delete(phi, mine, axis=1), self.yf,
                                    self._candidates(lag, w_c, z_c, shared),
                                    keep=n if others else 0)
        out = np.zeros((1 + n, k.size))
        if others:
            out[np.arange(1 + n) != 1 + i] = kept
        out[1 + i] = k
        return gain, out

    def scan_new(self, omega: NDArray[np.float64], zeta: NDArray[np.float64], lag: float,
                 w_c: NDArray[np.float64], z_c: NDArray[np.float64]) -> NDArray[np.float64]:
        """Cost reduction of one more mode at each candidate (w_c, z_c), the modes fixed."""
        phi = self.columns(omega, zeta, lag)
        gain = self._gains(phi, self.yf, self._candidates(lag, w_c, z_c))[0]
        return np.maximum(gain, 0.0)

    # -- the moves' scatter ----------------------------------------------------------------
    def deviations(self, omega: NDArray[np.float64], zeta: NDArray[np.float64], lag: float,
                   coef: NDArray[np.float64]) -> NDArray[np.float64]:
        """Each move's filtered residual minus the window mean (unwhitened rows), (M, rows).

        By linearity this is the residual of the moves' deviations from the window mean, whose
        forced response is one convolution with the model's combined impulse response; the
        deviations' transforms are computed once per window. The last result is kept and
        given again for the same arguments (read-only: the noise model, the covariance and the
        adequacy check ask for the same one).
        """
        n = self.n_modes
        key = b''.join(np.asarray(v, dtype=float).tobytes() for v in (omega, zeta, [lag], coef))
        if self._deviations is not None and self._deviations[0] == key:
            return self._deviations[1]
        if self._moves_regs is None:
            self._moves_regs = _moves_regressors(self.cur, sample_period=self.t,
                                                 delay=self.regs.delay,
                                                 fraction=self.regs.fraction)
            self._moves_enc = second_difference(self.enc - self.enc.mean(axis=0))
        regs, enc_f = self._moves_regs, self._moves_enc
        assert enc_f is not None
        h_lag = regs.lag_impulse(lag)
        h = coef[1: 1 + n] @ regs.mode_impulses(omega, zeta, lag, h_lag=h_lag) \
            + coef[0] * lag * h_lag
        forced = regs.convolve(h[None, :])[0] \
            + coef[0] * (regs.rigid_double - lag * regs.rigid_single)
        dev = np.asarray((enc_f - forced)[:, self.first:], dtype=np.float64)
        dev.flags.writeable = False
        self._deviations = (key, dev)
        return dev

    def deviations_times(self, omega: NDArray[np.float64], zeta: NDArray[np.float64],
                         lag: float, coef: NDArray[np.float64],
                         columns: NDArray[np.float64]) -> NDArray[np.float64]:
        """``deviations(...) @ columns`` (columns (rows, k)): (M, k), the deviations unmade.

        From the kept deviations if they are these; else without making them (an FFT of each
        move's current and a convolution per move): a move's forced response is a
        convolution of its filtered current with the model's impulse response h, so its
        product with a column c is the current's product with the correlation of c with h,
        one per column (and the rigid body's FIR likewise). The joint fit's covariance, the
        only user of a window's deviations there, saves most of their cost. The same numbers
        to rounding.
        """
        key = b''.join(np.asarray(v, dtype=float).tobytes() for v in (omega, zeta, [lag], coef))
        if self._deviations is not None and self._deviations[0] == key:
            return np.asarray(self._deviations[1] @ columns, dtype=np.float64)
        n, first, size = self.n_modes, self.first, self.n
        if self._moves_enc is None:
            self._moves_enc = second_difference(self.enc - self.enc.mean(axis=0))
        padded = np.zeros((size, columns.shape[1]))
        padded[first:] = columns
        regs = self.regs  # the impulse responses depend on the sample period and delay only
        h_lag = regs.lag_impulse(lag)
        h = coef[1: 1 + n] @ regs.mode_impulses(omega, zeta, lag, h_lag=h_lag) \
            + coef[0] * lag * h_lag
        nfft = regs.nfft
        corr = sp_fft.irfft(np.conj(sp_fft.rfft(h, nfft))[:, None]
                            * sp_fft.rfft(padded, nfft, axis=0), nfft, axis=0)[:size]
        double, single = rigid_taps(sample_period=self.t, delay=regs.delay,
                                    fraction=regs.fraction)
        taps = coef[0] * (double - lag * single)
        fir_corr = np.zeros_like(padded)  # sum_i taps_i c[j + i]
        for i, tap in enumerate(taps):
            if tap != 0 and i < size:
                fir_corr[: size - i] += tap * padded[i:]
        # the moves' inputs as the moves' Regressors take them (see _moves_regressors)
        u0, u_f = filtered_input(*_moves_input(self.cur))
        return np.asarray(self._moves_enc[:, first:] @ columns - u_f @ corr - u0 @ fir_corr,
                          dtype=np.float64)

    def noise(self, omega: NDArray[np.float64], zeta: NDArray[np.float64], lag: float,
              coef: NDArray[np.float64]) -> NDArray[np.float64]:
        """The moves' noise: :meth:`deviations` without what each move's own nuisance explains.

        A move's deviation also holds its own initial conditions (the ringing and the lag
        state the previous move left, an offset), which the averaged window's nuisance
        columns absorb: they are no noise of the estimate. Each move's projection onto those
        columns is removed (unwhitened rows, (M, rows)); the noise model, the weights and the
        Cramer-Rao bound come from what is left.
        """
        dev = self.deviations(omega, zeta, lag, coef)
        nuisance = self.columns(omega, zeta, lag, whitened=False)[:, 1 + self.n_modes:]
        scale = np.linalg.norm(nuisance, axis=0)
        scale[scale == 0] = 1.0
        q, _ = qr(nuisance / scale, mode='economic', check_finite=False)
        return np.asarray(dev - (dev @ q) @ q.T, dtype=np.float64)

    def raw_noise_rms(self) -> float:
        """Rms of the averaged filtered noise from the moves' scatter alone (no model), whitened
        by the current filter: the rows' noise the fit weighs the window with."""  # noqa: D205, D209
        dev = second_difference(self.enc - self.enc.mean(axis=0))[:, self.first:]
        dev = self.apply_whitening(dev, axis=1)
        return float(np.sqrt(np.mean(dev**2) / max(self.moves - 1, 1)))
