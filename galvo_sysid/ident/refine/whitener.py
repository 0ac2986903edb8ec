"""The noise model of the refined fit: a causal whitening map made from the moves' scatter.

:class:`Whitener` is the exact prediction-error map of a stationary noise (an exact head of
rows, then an FIR filter); :func:`noise_whitener` makes one from a window's per-move noise
in two passes (see there). Besides whitening any columns (:meth:`Whitener.apply`), a whitener
gives the whitened tail of a decaying exponential in closed form
(:meth:`Whitener.exponential_tail`): the free-response columns of many candidate modes are
whitened without a transform each. :func:`stationary_noise_model` estimates the noise the
Cramer-Rao bound needs: the stationary noise of deviations that also carry each move's own
nuisance (its initial conditions), by expectation-maximisation over that nuisance; its two
passes reduce to one whitener of the first pass's lags for the fit
(:meth:`WhitenerChain.single`). A whitener's head rows are a lower-triangular product
(:func:`lower_times`, BLAS ``trmm`` for many columns).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy import fft as sp_fft
from scipy.linalg import toeplitz
from scipy.linalg.blas import dtrmm
from scipy.linalg.lapack import dpotrf, dtrtri

if TYPE_CHECKING:
    from numpy.typing import NDArray

__all__ = ['BOUND_ITERATIONS', 'BOUND_ORDER_DIVISOR', 'NoiseModel', 'Whitener', 'WhitenerChain',
           'noise_whitener', 'stationary_noise_model']


def _taper(n: int) -> NDArray[np.float64]:
    """Hann taper scaled to unit mean square: autocovariances without the leakage of a bare
    record (its sidelobes fill a spectral valley tens of dB deep, e.g. the filtered encoder
    noise's low frequencies, where the rigid body's information lies)."""  # noqa: D205, D209
    w = np.hanning(n + 2)[1:-1]
    return np.asarray(w / np.sqrt(np.mean(w * w)), dtype=np.float64)


class Whitener:
    """A causal whitening map over a record: an exact head of rows, then an FIR filter.

    Made from a stationary noise's autocovariance (:meth:`from_autocovariance`), row k is
    the prediction error of sample k from all the samples before it (order k), divided by
    its standard deviation: the rows of L^-1 for the Cholesky factor L of the Toeplitz
    covariance. From row ``order`` on the rows are all the order-``order`` prediction-error
    filter, applied as an FIR (by FFT); the first rows are exact too, so a record's start
    is whitened as well as its middle. Two whiteners compose (:meth:`then`) into one.

    Args:
        head: (h, h) lower-triangular rows of the first h samples.
        taps: FIR filter of the rows from h on (length <= h + 1).
    """

    def __init__(self, head: NDArray[np.float64], taps: NDArray[np.float64]) -> None:
        self.head = np.asarray(head, dtype=float)
        self.filter = np.asarray(taps, dtype=float)
        self._spectra: dict[int, NDArray[np.complex128]] = {}

    @classmethod
    def from_autocovariance(cls, autocovariance: NDArray[np.float64]) -> Whitener:
        """The exact whitener of a stationary noise with autocovariance r[0..order]."""
        r = np.asarray(autocovariance, dtype=float)
        order = r.size - 1
        head = np.zeros((order, order))
        a = np.array([1.0])
        err = float(r[0])
        for k in range(order + 1):
            if k:  # Levinson-Durbin: the order-k predictor from the order-(k - 1) one
                acc = float(r[k] + a[1:] @ r[k - 1: 0: -1]) if k > 1 else float(r[1])
                refl = -acc / err
                a = np.concatenate([a, [0.0]])
                a = a + refl * a[::-1]
                err *= max(1.0 - refl * refl, 1e-12)
            if k < order:
                head[k, : k + 1] = a[::-1] / math.sqrt(err)
        return cls(head, a / math.sqrt(err))

    def then(self, outer: Whitener) -> Whitener:
        """The map ``outer`` after this one, as one whitener."""
        size = self.head.shape[0] + outer.head.shape[0]
        head = lower_times(outer.matrix(size), self.matrix(size))
        return Whitener(np.tril(head), np.convolve(outer.filter, self.filter))

    def matrix(self, rows: int) -> NDArray[np.float64]:
        """The map on a record of ``rows`` samples as a (rows, rows) lower-triangular matrix:
        the head's rows, then the FIR filter's (as :meth:`apply` maps it)."""  # noqa: D205, D209
        column = np.zeros(rows)
        column[: self.filter.size] = self.filter[:rows]
        out = toeplitz(column, np.zeros(rows))
        p = min(self.order, rows)
        out[:p, :p] = self.head[:p, :p]
        return np.asarray(out, dtype=np.float64)

    @property
    def order(self) -> int:
        """Rows of the exact head (the FIR filter applies from this row on)."""
        return int(self.head.shape[0])

    def exponential_tail(self, e: NDArray[np.complex128], start: int,
                         rows: int) -> NDArray[np.complex128]:
        """Whitened rows ``order .. rows-1`` of the records ``lambda_i^(start + k)``, k >= 0.

        ``e[i, k] = lambda_i^k`` (k = 0 .. at least ``start + rows - 1``). The FIR filter
        a maps a power of lambda to itself times ``sum_j a_j lambda^-j``, so the rows past
        the head are ``lambda^(start + k - L) sum_j a_j lambda^(L - j)`` (L = the filter's
        order; every power non-negative): what :meth:`apply` gives those rows, without a
        transform. Needs ``L <= order < rows``.
        """
        p = self.order
        lags = self.filter.size - 1
        poly = e[:, lags::-1] @ self.filter
        return np.asarray(poly[:, None] * e[:, start + p - lags: start + rows - lags],
                          dtype=np.complex128)

    def apply(self, arr: NDArray[np.float64], axis: int = 0) -> NDArray[np.float64]:
        """Whiten ``arr`` along ``axis`` (its rows are the record's samples from the first)."""
        moved = np.moveaxis(np.asarray(arr, dtype=float), axis, 0)
        n = moved.shape[0]
        size = _fft_size(n + self.filter.size - 1)
        spectrum = self._spectra.get(size)
        if spectrum is None:
            spectrum = self._spectra[size] = sp_fft.rfft(self.filter, size)
        shape = (-1,) + (1,) * (moved.ndim - 1)
        out = sp_fft.irfft(sp_fft.rfft(moved, size, axis=0) * spectrum.reshape(shape), size,
                           axis=0)[:n]
        p = min(self.head.shape[0], n)
        rest = moved.shape[1:]
        out[:p] = lower_times(self.head[:p, :p], moved[:p].reshape(p, -1)).reshape((p, *rest))
        return np.moveaxis(out, 0, axis)

    def transposed(self, arr: NDArray[np.float64]) -> NDArray[np.float64]:
        """``W^T arr`` for the map W :meth:`apply` is along the rows of ``arr`` (rows, k).

        Whitened records' products with columns, ``(W y)^T c = y^T (W^T c)``, without
        whitening the records: the columns are mapped instead (a few columns for many
        records). The FIR part's transpose is a correlation with the filter (by FFT), the
        head's its transpose.
        """
        v = np.asarray(arr, dtype=float)
        n = v.shape[0]
        p = min(self.order, n)
        size = _fft_size(n + self.filter.size - 1)
        spectrum = self._spectra.get(size)
        if spectrum is None:
            spectrum = self._spectra[size] = sp_fft.rfft(self.filter, size)
        tail = v.copy()
        tail[:p] = 0.0  # the head's rows are not the filter's
        shape = (-1,) + (1,) * (v.ndim - 1)
        out = sp_fft.irfft(np.conj(spectrum).reshape(shape) * sp_fft.rfft(tail, size, axis=0),
                           size, axis=0)[:n]
        out[:p] += self.head[:p, :p].T @ v[:p]
        return np.asarray(out, dtype=np.float64)


_TRMM_COLUMNS = 48  # from this many columns on a triangular product beats a full one


def lower_times(lower: NDArray[np.float64], arr: NDArray[np.float64]) -> NDArray[np.float64]:
    """``lower @ arr`` for a lower-triangular (p, p) ``lower`` and (p, k) ``arr``.

    Many columns: BLAS ``trmm`` on the transposes (``arr^T lower^T``: C-ordered arrays are
    then Fortran-ordered, so nothing is copied on the way in), which skips the zeros above the
    diagonal; few: a plain product (``trmm``'s set-up costs more than it saves).
    """
    if arr.shape[1] < _TRMM_COLUMNS or lower.shape[0] < _TRMM_COLUMNS:
        return np.asarray(lower @ arr, dtype=np.float64)
    lower = np.ascontiguousarray(lower, dtype=np.float64)
    arr = np.ascontiguousarray(arr, dtype=np.float64)
    return np.asarray(dtrmm(1.0, lower.T, arr.T, side=1, lower=0).T, dtype=np.float64)


def _fft_size(n: int) -> int:
    """The smallest 2^a 3^b 5^c >= n (a fast real FFT length, scipy's ``next_fast_len``)."""
    return int(sp_fft.next_fast_len(n, real=True))


def _autocovariance(dev: NDArray[np.float64], order: int) -> NDArray[np.float64]:
    """Sum over the moves (rows) of each lag's products, lags 0..order (one FFT pass)."""
    n = dev.shape[1]
    size = _fft_size(n + order)  # no wrap-around for the lags wanted
    f = sp_fft.rfft(dev, size, axis=1)
    power = np.sum(f.real * f.real + f.imag * f.imag, axis=0)
    return np.asarray(sp_fft.irfft(power, size)[: order + 1], dtype=np.float64)


def _normalised(r: NDArray[np.float64]) -> NDArray[np.float64]:
    r = r / r[0]
    r[1:] *= 1.0 - 1e-9 * np.arange(1, r.size) / (r.size - 1)  # stays positive definite
    return r


def noise_whitener(dev: NDArray[np.float64], order: int, scale: float) -> Whitener | None:
    """The :class:`Whitener` of the per-move noise ``dev`` (M, rows), or None without noise.

    Two passes (prewhitening, as in spectral estimation): the first whitener comes from the
    autocovariance of the Hann-tapered records (the taper keeps the dynamic range: see
    :func:`_taper`), which flattens the spectrum but blurs its sharp peaks (the resonances
    the current noise rings); the second from the bare autocovariance of what the first
    leaves, nearly white, so neither leakage nor the taper's blur matters. Both up to lag
    ``order``, averaged over the moves; the map is the second after the first.
    """
    n = dev.shape[1]
    order = max(1, min(order, n // 2))
    r = _autocovariance(dev * _taper(n), order)
    if not r[0] > scale * scale * 1e-20 * dev.size:
        return None
    first = Whitener.from_autocovariance(_normalised(r))
    rest = first.apply(dev, axis=1)
    r2 = _autocovariance(rest, order)
    if not r2[0] > 0:
        return first
    return first.then(Whitener.from_autocovariance(_normalised(r2)))


BOUND_ITERATIONS = 3
"""Expectation-maximisation steps of :func:`stationary_noise_model` (see there)."""

BOUND_ORDER_DIVISOR = 3
"""The bound's noise model has at least rows // this many lags (see
:func:`~galvo_sysid.ident.refine.joint.covariance`)."""

_CHOLESKY_ORDER = 200  # up to this many lags a LAPACK Cholesky beats the Python recursion



class WhitenerChain:
    """Whiteners applied one after the other (what :meth:`Whitener.then` composes, without
    composing their heads: cheaper where only :meth:`apply` is wanted)."""  # noqa: D205, D209

    def __init__(self, *stages: Whitener) -> None:
        self.stages = stages

    def apply(self, arr: NDArray[np.float64], axis: int = 0) -> NDArray[np.float64]:
        """Whiten ``arr`` along ``axis`` by every stage in turn."""
        out = np.asarray(arr, dtype=float)
        for stage in self.stages:
            out = stage.apply(out, axis=axis)
        return out

    def single(self, lags: int) -> tuple[Whitener, float]:
        """One whitener of ``lags`` lags for the noise the stages whiten, and its variance.

        The noise the stages map to white noise has the spectrum ``1 / |A(f)|^2``, A the
        stages' filters in series; its autocovariance up to ``lags`` gives the exact
        prediction-error map of that order (:func:`_levinson`). Returns the map and the factor
        by which its output's variance exceeds the stages' (the autocovariance's lag 0): the
        same noise model to that many lags, with a head of ``lags`` rows instead of the sum
        of the stages' (the fit whitens every column with the head).
        """
        r = self.autocovariance(lags)
        return _levinson(_normalised(r)), float(r[0])

    def autocovariance(self, lags: int) -> NDArray[np.float64]:
        """Lags 0..``lags`` of the autocovariance of the noise the stages map to unit white
        noise (what :meth:`single` makes its whitener from)."""  # noqa: D205, D209
        taps = sum(stage.filter.size for stage in self.stages)
        grid = _fft_size(max(8192, 16 * taps))
        gain = np.ones(grid // 2 + 1)
        for stage in self.stages:
            gain *= np.abs(sp_fft.rfft(stage.filter, grid)) ** 2
        return np.asarray(sp_fft.irfft(1.0 / gain, grid)[: lags + 1], dtype=np.float64)


@dataclass(frozen=True)
class NoiseModel:
    """A window's stationary noise model as its fit weighed it.

    A later fit of the same moves (a joint fit started from the windows' fits) reuses it
    instead of estimating it again.

    Attributes:
        autocovariance: Lags 0..L of the noise of unit whitened variance
            (:meth:`WhitenerChain.autocovariance`): the fit's whitener of L lags is made from
            it (:meth:`whitener`).
        variance: The whitened variance per row of a move's deviation
            (:func:`stationary_noise_model`).
        moves: The window's moves.
        rows: The window's rows (samples from the first filtered row on).
    """

    autocovariance: tuple[float, ...]
    variance: float
    moves: int
    rows: int

    def whitener(self) -> Whitener:
        """The window's whitener (:meth:`WhitenerChain.single`'s)."""
        return _levinson(_normalised(np.array(self.autocovariance, dtype=float)))

    def weight(self) -> float:
        """The window's weight: one over its average's whitened noise std."""
        factor = float(self.autocovariance[0])
        return 1.0 / max(math.sqrt(self.variance * factor / (self.moves - 1)), 1e-300)

    def level_ratio(self, whitener: Whitener, dev: NDArray[np.float64],
                    nuisance: NDArray[np.float64]) -> float:
        """How these deviations' noise compares with this model's (1: the same).

        The whitened variance per row of ``dev`` (M, rows), each move's nuisance (the
        columns ``nuisance``, (rows, p)) taken out by generalised least squares, over
        :attr:`variance`. For moves of this model's noise it is 1 to about 1 % (two windows
        of 100 moves); noise of another level scales it, noise of another spectrum raises
        it (a whitener of the wrong spectrum leaves more prediction error). Used to reuse a
        model of the previous window of the same moves (:meth:`JointProblem.prewhiten`).

        Args:
            whitener: :meth:`whitener` (made once by the caller).
            dev: The moves' deviations from their mean (unwhitened rows).
            nuisance: Each move's nuisance columns (unwhitened rows).
        """
        w_dev = whitener.apply(np.ascontiguousarray(dev), axis=1)
        w_nuis = whitener.apply(nuisance, axis=0)
        scale = np.linalg.norm(w_nuis, axis=0)
        scale[scale == 0] = 1.0
        q, _ = np.linalg.qr(w_nuis / scale)
        rest = w_dev - (w_dev @ q) @ q.T
        dof = int(dev.shape[0]) * max(int(dev.shape[1]) - int(q.shape[1]), 1)
        return float(np.sum(rest * rest)) / (dof * max(float(self.variance), 1e-300))


def _levinson(autocovariance: NDArray[np.float64]) -> Whitener:
    """:meth:`Whitener.from_autocovariance`, faster for the bound's repeated noise models (the
    same map to rounding): up to ``_CHOLESKY_ORDER`` lags by a LAPACK Cholesky factor of the
    Toeplitz matrix (its inverse's rows are the prediction-error rows), beyond by the
    recursion in place (no array built per order; the factor's cubic cost grows faster)."""  # noqa: D205, D209
    r = np.asarray(autocovariance, dtype=float)
    order = r.size - 1
    if order <= _CHOLESKY_ORDER:
        chol, info = dpotrf(toeplitz(r), lower=1, clean=1, overwrite_a=1)
        if info == 0:
            rows, info = dtrtri(chol, lower=1, overwrite_c=1)
        if info != 0:
            raise np.linalg.LinAlgError('the autocovariance is not positive definite')
        return Whitener(np.tril(rows[:order, :order]), rows[order, ::-1].copy())
    head = np.zeros((order, order))
    a = np.zeros(order + 1)
    a[0] = 1.0
    err = float(r[0])
    head[0, 0] = 1.0 / math.sqrt(err)
    for k in range(1, order + 1):
        refl = -float(r[k] + a[1:k] @ r[k - 1: 0: -1]) / err
        a[1: k + 1] += refl * a[k - 1:: -1]
        err *= max(1.0 - refl * refl, 1e-12)
        if k < order:
            head[k, : k + 1] = a[k:: -1] / math.sqrt(err)
    return Whitener(head, a / math.sqrt(err))


def _first_pass(records: NDArray[np.float64], order: int) -> Whitener | None:
    """:func:`noise_whitener`'s first pass: from the Hann-tapered records' lag sums."""
    r = _autocovariance(records * _taper(records.shape[1]), order)
    return _levinson(_normalised(r)) if r[0] > 0 else None


def stationary_noise_model(dev: NDArray[np.float64], nuisance: NDArray[np.float64],
                           order: int, iterations: int = BOUND_ITERATIONS, *,
                           first_order: int | None = None) -> tuple[WhitenerChain,
                                                                    float] | None:
    """The stationary noise under per-move nuisance: (whitener, whitened variance) or None.

    ``dev`` (M, rows) are the moves' deviations from their mean, each the stationary noise
    plus the move's own nuisance, a combination of the columns ``nuisance`` (rows, p): the
    ringing, lag state and offset the previous move and the controller's unrecorded reaction
    to it left, which differ from move to move. That nuisance is no noise of the window's
    average (its columns absorb it), yet it is large and not stationary: a mode ringing
    through the record puts far more power at the mode's frequency into the deviations than
    the noise has there (on ``random_scanner(1)`` twenty times the noise in the valley the
    first mode's antiresonance cuts: :func:`noise_whitener` of the deviations whole makes the
    Cramer-Rao bound of omega_1 ten times too large). Removing each move's least-squares
    projection onto the columns removes the noise's own component in them too (the bound
    0.6x too small at a lightly damped mode).

    So the noise model is estimated by expectation-maximisation over that missing component
    (Gaussian noise, nuisance free per move), in :func:`noise_whitener`'s two passes: the
    first pass (Hann-tapered, ``first_order`` lags, ``order`` if None or more) from the
    projected deviations, once; then, starting from the first pass as the model,
    ``iterations`` + 1 times each move's nuisance is the generalised least-squares fit of its
    deviation with the current model, the deviation less it the noise's expected value, and
    the second pass (bare, ``order`` lags) is re-estimated from those records and the
    conditional covariance of the part they miss (``sigma^2 (W_q^T W_q)^-1``, W_q the
    whitened columns), its lag sums in closed form from the transforms of the first pass's
    output (no transform per record and step).

    The fine resolution belongs to the second pass, and the steps start from the first:
    where a nuisance column holds the whole of a band (the per-move offset holds the lowest
    frequencies), the scatter does not tell the noise there and the steps keep what they
    start with. A fine first pass of the projected deviations has a false peak or hole
    there; a coarse one is smooth across it. On ``random_scanner(30)`` (1,240 rows, 413
    lags) the fine first pass and the least-squares start gave k0 an rms error 1.5 times
    its bound (the weighting of the lowest frequencies 30 times too low), now 1.08. On
    ``benchmarks/efficiency.py``'s other conditions the worst efficiency of each moved by at
    most 0.03 either way (2026-11-27).

    Each step adds about 1 ms to 3 ms of a window of 100 moves of 339 rows. At a
    lightly damped mode's frequency the noise is barely identifiable from the scatter (every
    move's ringing absorbs it there) and the steps converge slowly: on ``random_scanner(1)``
    the bound of omega_1 and zeta_1 comes out 0.75-0.8 of the one with the noise's exact
    covariance, the other parameters' within 0.93-1.05 (``test/ident/test_bound.py``).

    Returns:
        The whitener and the variance per whitened row of a deviation (its noise's variance
        times (M - 1) / M), or None when the deviations do not scatter.
    """
    m, n = dev.shape
    lags = max(1, min(order, n // 2))
    coarse = lags if first_order is None else max(1, min(first_order, lags))
    scale = np.linalg.norm(nuisance, axis=0)
    scale[scale == 0] = 1.0
    q, _ = np.linalg.qr(nuisance / scale)
    p = q.shape[1]
    first = _first_pass(dev - (dev @ q) @ q.T, coarse)
    if first is None:
        return None
    # the second pass's lag sums of first.apply(dev - q beta) + pseudo-records, from the
    # transforms of first.apply(dev) and first.apply(q) (first is linear): no transform of
    # the records per step
    y = first.apply(np.ascontiguousarray(dev.T))
    y_q = first.apply(q)
    size = _fft_size(n + lags)
    f_y = sp_fft.rfft(y, size, axis=0)
    f_q = sp_fft.rfft(y_q, size, axis=0)
    power_y = np.sum(f_y.real**2 + f_y.imag**2, axis=1)
    rows = min(lags, n)
    # the first E-step with the first pass as the model: the nuisance (p, M) and M times its
    # conditional covariance (where the whitened columns are singular, each move's
    # least-squares nuisance and none)
    q_0, r_0 = np.linalg.qr(y_q)
    res_0 = y - q_0 @ (q_0.T @ y)
    var_0 = float(np.sum(res_0 * res_0) / (m * max(n - p, 1)))
    try:
        beta = np.linalg.solve(r_0, q_0.T @ y)
        spread_0 = np.linalg.inv(r_0)
        extra = m * var_0 * (spread_0 @ spread_0.T)
    except np.linalg.LinAlgError:
        beta, extra = q.T @ dev.T, np.zeros((p, p))

    def whiten(second: Whitener, x: NDArray[np.float64], f_x: NDArray[np.complex128],
               f_filter: NDArray[np.complex128]) -> NDArray[np.float64]:
        # second.apply(x) from x's transform (the filter has order + 1 taps: same size)
        out = np.asarray(sp_fft.irfft(f_x * f_filter[:, None], size, axis=0)[:n],
                         dtype=np.float64)
        out[:rows] = lower_times(second.head[:rows, :rows], x[:rows])
        return out

    result: tuple[WhitenerChain, float] | None = None
    for _ in range(iterations + 1):
        cross = f_y @ beta.T               # (K, p)
        power = (power_y - 2.0 * np.sum((f_q * cross.conj()).real, axis=1)
                 + np.einsum('kj,jl,kl->k', f_q, beta @ beta.T + extra, f_q.conj()).real)
        r2 = sp_fft.irfft(power, size)[: lags + 1]
        if not r2[0] > 0:
            return result
        second = _levinson(_normalised(r2))
        f_filter = sp_fft.rfft(second.filter, size)
        w_y = whiten(second, y, f_y, f_filter)
        q_w, r_w = np.linalg.qr(whiten(second, y_q, f_q, f_filter))
        resid = w_y - q_w @ (q_w.T @ w_y)
        var = float(np.sum(resid * resid) / (m * max(n - p, 1)))
        if not var > 0:
            return None
        result = (WhitenerChain(first, second), var)
        try:
            beta = np.linalg.solve(r_w, q_w.T @ w_y)
            spread = np.linalg.inv(r_w)
        except np.linalg.LinAlgError:
            return result
        extra = m * var * (spread @ spread.T)
    return result
