"""Structured output-error fit of the physical modal model (past the paper).

The paper fits a 15th-order ARX model to the averaged window and decomposes it; its third
mode is poor (Table II: zeta_3 +655 %) and the amplifier lag is treated as a pure delay,
which biases the residues (k_2 about -20 %). This module fits the physical model itself::

    y[k] = P_mech(s) L(s) z^-d u[k]  (exact zero-order hold)  + free response + offset

with the input dynamics of :class:`galvo_sysid.model.modal.InputDynamics`: ``d`` whole samples of
DSP computation delay, an optional fractional dead time, and the current amplifier's
first-order lag ``L(s) = 1 / (1 + s T_l)``, whose time constant is estimated (the physical
form of the paper's "1.6 tau found by trial and error"). Every mode is discretised exactly
(partial fractions: closed-form impulse responses, convolved with the input by FFT in one
batch). The rigid-body gain k0, the residues k_i, the modes' initial conditions (the residual
vibration of the previous move), an offset and the lag state's initial value enter linearly
and are solved by linear least squares inside the loop (variable projection); only omega_i,
zeta_i and T_l are optimised nonlinearly (:func:`scipy.optimize.least_squares`,
Golub-Pereyra Jacobian). Data and model are both filtered by (1 - q^-1)^2, which removes the
start angle, a slow drift and the rigid-body initial velocity.

Starting points. The output-error cost has local minima in the frequency of a weakly excited,
lightly damped mode (ripples about 2 pi / (N T) apart); with a large damping ratio the same
cost is one broad bowl around the true frequency. So each mode's frequency is first scanned
over its band at a large damping ratio (``damping_start``), the others held at the starting
model's (the paper pipeline's) values; the fit then starts every mode at that large damping
ratio and lets the optimiser reduce it (a continuation that avoids the ripples). The starting
model itself and ``extra_starts`` are tried too; the lowest cost wins.

Two stages. Stage 1 is ordinary least squares on the filtered data; stage 2 prewhitens data
and model with an AR model of the per-move noise (generalised least squares), which mostly
sharpens k0 (3x).

Uncertainty (:attr:`RefinedFit.covariance`): the sandwich covariance ``A^-1 B A^-1`` with
``A = J^T J`` from the Jacobian J of the (whitened) filtered residual with respect to all
parameters and ``B = J^T S J``, S the covariance of the averaged residual estimated from the
per-move residuals (their scatter over the moves divided by M). It holds for coloured noise
and closed-loop input noise; without per-move records (M <= 2) it falls back to the
white-noise formula ``sigma^2 A^-1``. A mode whose residue is below ``resolve_z`` of its std
is reported as not resolved, with an uninformative std for its frequency and damping
(a weak mode's best fit is then a noise peak: the linearised std would be far too small).

Checks. A resolved mode ending at its band edge, or a residual between the band edges far
above the noise (``adequacy_limit``), raises :class:`~galvo_sysid.errors.IdentificationError`:
the data hold dynamics the model does not place in its bands.

:func:`refine_joint` fits several windows of one plant at once (shared modal parameters,
per-window nuisance terms): the pooled estimate, which resolves a mode no single window does.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import fft as sp_fft
from scipy.linalg import LinAlgError, cholesky, qr, solve_toeplitz, solve_triangular
from scipy.optimize import least_squares

from galvo_sysid.errors import (
    ConfigurationError,
    IdentificationError,
    InvalidDataError,
    ModelMismatchError,
)
from galvo_sysid.ident.decompose import default_bands
from galvo_sysid.model import TAU, ModalModel

if TYPE_CHECKING:
    from collections.abc import Sequence
    from typing import TypeAlias

    from numpy.typing import ArrayLike, NDArray

    Floats: TypeAlias = Sequence[float] | NDArray[np.float64]

__all__ = [
    'DEFAULT_ADEQUACY_LIMIT',
    'DEFAULT_DAMPING_START',
    'DEFAULT_LAG_BOUNDS',
    'DEFAULT_RESOLVE_Z',
    'DEFAULT_SCAN_POINTS',
    'DEFAULT_WHITEN_ORDER',
    'RefinedFit',
    'added_mode_gains',
    'filtered_fit_percent',
    'modal_regressors',
    'model_fit_percent',
    'refine_fit',
    'refine_joint',
    'second_difference',
    'window_noise_filters',
]

DEFAULT_DAMPING_START = 0.03
"""Damping ratio every mode starts from (the continuation start; see the module docs)."""

DEFAULT_LAG_BOUNDS = (0.0, 3.0)
"""Bounds of the estimated amplifier lag, in sample periods."""

DEFAULT_SCAN_POINTS = 24
"""Frequencies per band scanned for the first starting point."""

DEFAULT_WHITEN_ORDER = 16
"""Order of the AR model of the per-move noise used to prewhiten the second stage."""

DEFAULT_ADEQUACY_LIMIT = 20.0
"""Residual-to-noise energy ratio (per interval between band edges) above which the model is
rejected; about 1 for an adequate model."""

DEFAULT_RESOLVE_Z = 5.0
"""Significance |k_i| / std(k_i) below which a mode counts as not resolved."""

_STAGE1_TOL = 1e-5
_MAX_DAMPING = 0.3
_MIN_DAMPING = 1e-5
_FIRST_ROW = 2  # (1 - q^-1)^2 needs two past samples
_MAX_DECAY = 700.0  # exp(-700) is about 1e-304: a lag's decay per sample beyond it is 0


def first_row(delay: int, fraction: float) -> int:
    """First filtered row a fit uses: the record's own input has reached the plant (whole
    samples of delay, one more for a fractional part) and the second difference sees two
    samples after that, so whatever came before the record (its inputs, the state) is spanned
    by the nuisance columns (free responses, offset, lag state)."""  # noqa: D205, D209
    return max(_FIRST_ROW, delay + (1 if fraction > 0 else 0) + _FIRST_ROW)


def second_difference(x: ArrayLike) -> NDArray[np.float64]:
    """Return (1 - q^-1)^2 x along the last axis, x held at its first value before the record."""
    arr = np.asarray(x, dtype=float)
    d = np.diff(arr, n=1, axis=-1, prepend=arr[..., :1])
    return np.asarray(np.diff(d, n=1, axis=-1, prepend=0.0 * d[..., :1]), dtype=np.float64)


def _fir(b: Sequence[float] | NDArray[np.float64], x: NDArray[np.float64],
         axis: int = -1) -> NDArray[np.float64]:
    """FIR filter sum_j b_j x[k - j] along ``axis`` from rest (short filters; faster than
    :func:`scipy.signal.lfilter`, which filters FIR rows one by one)."""  # noqa: D205, D209
    xs = np.asarray(x, dtype=float)
    first = xs.ndim > 1 and axis % xs.ndim == 0
    if not first and axis % xs.ndim != xs.ndim - 1:
        return np.moveaxis(_fir(b, np.moveaxis(xs, axis, -1)), -1, axis)
    n = xs.shape[0] if first else xs.shape[-1]
    out = np.zeros_like(xs)
    for j, bj in enumerate(b):
        if bj != 0 and j < n:
            if first:
                out[j:] += bj * xs[: n - j]
            else:
                out[..., j:] += bj * xs[..., : n - j]
    return out


def _pulse_numerator(p: complex, fraction: float, t: float) -> tuple[complex, complex]:
    """(g1, g2): ZOH of 1/(s - p) with a dead time of ``fraction`` samples is
    ``(g1 z^-1 + g2 z^-2) / (1 - e^{pT} z^-1)``."""  # noqa: D205, D209
    lam = np.exp(p * t)
    if p == 0:
        g1 = complex((1.0 - fraction) * t)
        h2 = complex(t)
    else:
        e1 = np.exp(p * (1.0 - fraction) * t)
        g1 = complex((e1 - 1.0) / p)
        h2 = complex(e1 * (lam - 1.0) / p)
    return g1, h2 - lam * g1


def _split_delay(computation_delay: int, dead_time: float, sample_period: float) -> tuple[int,
                                                                                          float]:
    whole_f, frac = divmod(dead_time / sample_period, 1.0)
    whole = computation_delay + round(whole_f)
    if frac > 1.0 - 1e-9:
        whole, frac = whole + 1, 0.0
    elif frac < 1e-9:
        frac = 0.0
    return whole, float(frac)


def _powers(omega: Floats, zeta: Floats, n: int,
            sample_period: float) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    """Continuous poles p_j of the modes and E[j, k] = exp(p_j T k), k = 0 .. n-1."""
    w = np.asarray(omega, dtype=float)
    z = np.asarray(zeta, dtype=float)
    p = -z * w + 1j * w * np.sqrt(np.maximum(1.0 - z * z, 1e-12))
    # cumulative product of the discrete pole: far cheaper than n complex exponentials and
    # accurate to ~n eps
    e = np.empty((p.size, n), dtype=np.complex128)
    e[:, 0] = 1.0
    e[:, 1:] = np.exp(p * sample_period)[:, None]
    np.cumprod(e, axis=1, out=e)
    return p, e


class _Regressors:
    """Filtered exact-ZOH responses of the unit modes to a fixed input (records (..., N)).

    Every block is a sum of first-order pole terms whose impulse responses are closed-form
    powers of the discrete poles; they are convolved with the filtered input by FFT, all
    blocks in one batch.
    """

    def __init__(self, u: NDArray[np.float64], *, sample_period: float, delay: int,
                 fraction: float) -> None:
        if delay < 0:
            raise ConfigurationError('the input delay must be >= 0')
        self.t = sample_period
        self.delay = delay
        self.fraction = fraction
        self.first = first_row(delay, fraction)
        self.n = u.shape[-1]
        self.nfft = 1 << (2 * self.n - 1).bit_length()
        u0 = u - u[..., :1]
        self.uf = second_difference(u)
        self.uf_hat = sp_fft.rfft(self.uf, self.nfft, axis=-1)
        self._lag_cache: tuple[float, NDArray[np.float64]] | None = None
        # Fixed FIR parts of the rigid body (double and single integrator, see rigid()).
        f = fraction
        t = sample_period
        pad = [0.0] * delay
        self.rigid_double = _fir([*pad, 0.0, t * t * (1 - f) ** 2 / 2,
                                  t * t * (0.5 + f - f * f), t * t * f * f / 2], u0)
        self.rigid_single = _fir([*pad, 0.0, t * (1 - f), t * (2 * f - 1), -t * f], u0)

    def convolve(self, h: NDArray[np.float64]) -> NDArray[np.float64]:
        """Responses to the filtered input of the impulse responses h (m, N): (m,) + u.shape."""
        hh = sp_fft.rfft(h, self.nfft, axis=-1)
        prod = hh * self.uf_hat if self.uf_hat.ndim == 1 else hh[:, None, :] * self.uf_hat[None]
        return np.asarray(sp_fft.irfft(prod, self.nfft, axis=-1)[..., : self.n],
                          dtype=np.float64)

    def _pulse(self, p: NDArray[np.complex128]) -> tuple[NDArray[np.complex128],
                                                          NDArray[np.complex128]]:
        """Vectorised :func:`_pulse_numerator` for nonzero poles p."""
        t, f = self.t, self.fraction
        lam = np.exp(p * t)
        e1 = np.exp(p * (1.0 - f) * t)
        g1 = (e1 - 1.0) / p
        return g1, e1 * (lam - 1.0) / p - lam * g1

    def _shifted(self, a1: NDArray[np.complex128], a2: NDArray[np.complex128],
                 e: NDArray[np.complex128]) -> NDArray[np.float64]:
        """Real impulse responses 2 Re(a1 E[k-1-d] + a2 E[k-2-d]) (zero before)."""
        d, n = self.delay, self.n
        h = np.zeros(e.shape)
        if d + 1 < n:
            h[:, d + 1:] = 2.0 * (a1[:, None] * e[:, : n - d - 1]).real
        if d + 2 < n:
            h[:, d + 2:] += 2.0 * (a2[:, None] * e[:, : n - d - 2]).real
        return h

    def lag_impulse(self, lag: float) -> NDArray[np.float64]:
        """Impulse response of the lag pole term 1/(s + 1/T_l) (zeros without lag).

        The last one is cached (each evaluation asks for the same lag several times); the
        caller must not modify the returned array.
        """
        if self._lag_cache is not None and self._lag_cache[0] == lag:
            return self._lag_cache[1]
        h = np.zeros(self.n)
        if lag > 0:
            g1, g2 = _pulse_numerator(-1.0 / lag, self.fraction, self.t)
            rate = min(self.t / lag, _MAX_DECAY)  # a vanishing lag: no overflow, 0 * inf
            powers = np.exp(np.arange(self.n - self.delay - 1, dtype=float) * -rate)
            d = self.delay
            if d + 1 < self.n:
                h[d + 1:] = g1.real * powers
            if d + 2 < self.n:
                h[d + 2:] += g2.real * powers[:-1]
        h.flags.writeable = False
        self._lag_cache = (lag, h)
        return h

    def mode_impulses(self, omega: Floats, zeta: Floats, lag: float,
                      e: NDArray[np.complex128] | None = None,
                      h_lag: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
        """Impulse responses (m, N) of 1/((1 + s T_l)(s^2 + 2 zeta omega s + omega^2))."""
        w = np.asarray(omega, dtype=float)
        z = np.asarray(zeta, dtype=float)
        p, e_all = _powers(w, z, self.n, self.t) if e is None else (
            -z * w + 1j * w * np.sqrt(np.maximum(1.0 - z * z, 1e-12)), e)
        wd = p.imag
        c = 1.0 / ((1.0 + p * lag) * 2j * wd)  # residue at p
        g1, g2 = self._pulse(p)
        h = self._shifted(c * g1, c * g2, e_all)
        if lag > 0:
            c_a = lag / (1.0 - 2 * z * w * lag + (w * lag) ** 2)  # residue at -1/T_l
            hl = self.lag_impulse(lag) if h_lag is None else h_lag
            h += c_a[:, None] * hl[None, :]
        return h

    def rigid(self, lag: float, x_lag: NDArray[np.float64]) -> NDArray[np.float64]:
        """1/(s^2 (1 + s T_l)) = 1/s^2 - T_l/s + T_l/(s + 1/T_l), filtered."""
        return np.asarray(self.rigid_double - lag * self.rigid_single + lag * x_lag,
                          dtype=np.float64)

    def all(self, omega: Floats, zeta: Floats, lag: float,
            e: NDArray[np.complex128] | None = None) -> NDArray[np.float64]:
        """Rigid body and every mode: shape (1 + n_modes,) + u.shape."""
        h_lag = self.lag_impulse(lag)
        h = np.concatenate([h_lag[None, :], self.mode_impulses(omega, zeta, lag, e, h_lag)])
        x = self.convolve(h)
        x[0] = self.rigid(lag, x[0])
        return x


def modal_regressors(u: ArrayLike, natural_frequencies: Sequence[float],
                     damping_ratios: Sequence[float], *, sample_period: float,
                     lag_time_constant: float = 0.6 * TAU, computation_delay: int = 1,
                     dead_time: float = 0.0) -> NDArray[np.float64]:
    """Return the (1 - q^-1)^2-filtered response of each unit-gain mode to the input ``u``.

    Exact zero-order-hold responses of ``1/s^2`` (rigid body) and
    ``1/(s^2 + 2 zeta_i omega_i s + omega_i^2)`` (resonant modes), each behind the input
    dynamics (computation delay, dead time, amplifier lag), from rest with ``u`` held at its
    first value before the record. A modal model's filtered output is
    ``k0 * out[0] + sum_i k_i * out[i]``.

    Args:
        u: Input records, shape (N,) or (M, N).
        natural_frequencies: omega_i [rad/s].
        damping_ratios: zeta_i.
        sample_period: Sampling period T [s].
        lag_time_constant: Amplifier lag T_l [s] (0: none).
        computation_delay: Whole samples of computation delay (>= 0).
        dead_time: Extra pure delay [s].

    Returns:
        Array of shape (1 + n_modes,) + u.shape: rigid body first, then the modes.
    """
    u_arr = np.asarray(u, dtype=float)
    if u_arr.ndim not in (1, 2) or u_arr.shape[-1] < 1:
        raise InvalidDataError('u must be one record (N,) or records (M, N)')
    if len(natural_frequencies) != len(damping_ratios):
        raise ConfigurationError('natural_frequencies and damping_ratios differ in length')
    if lag_time_constant < 0 or dead_time < 0:
        raise ConfigurationError('lag_time_constant and dead_time must be >= 0')
    delay, frac = _split_delay(computation_delay, dead_time, sample_period)
    regs = _Regressors(u_arr, sample_period=sample_period, delay=delay, fraction=frac)
    return regs.all(natural_frequencies, damping_ratios, lag_time_constant)


def _free_responses(omega: Floats, zeta: Floats, n: int, sample_period: float,
                    e: NDArray[np.complex128] | None = None, *,
                    first: int = _FIRST_ROW) -> NDArray[np.float64]:
    """Free-response columns of every mode: Re and Im of exp(p_i T k) over rows k >= first.

    Shape (2 n_modes, n - first); ``e`` is :func:`_powers`' E if already computed.
    """
    if e is None:
        _, e = _powers(omega, zeta, n, sample_period)
    out = np.empty((2 * e.shape[0], n - first))
    out[0::2] = e[:, first:].real
    out[1::2] = e[:, first:].imag
    return out


@dataclass(frozen=True, eq=False)
class RefinedFit:
    """Outcome of :func:`refine_fit` and :func:`refine_joint`.

    Attributes:
        model: The identified mechanical modal model.
        lag_time_constant: Amplifier lag T_l [s] (estimated, or the fixed value).
        lag_estimated: Whether T_l was estimated.
        computation_delay: Whole samples of computation delay assumed.
        dead_time: Extra pure delay assumed [s].
        sample_period: Sampling period [s].
        parameter_names: Names of the covariance's rows: ModalModel.parameters() keys, then
            ``'lag'`` when estimated.
        covariance: Covariance of those parameters (physical units).
        covariance_method: ``'sandwich'`` (from the per-move residuals) or ``'white'``.
        initial_conditions: Amplitudes of each mode's two free-response columns (empty for a
            joint fit).
        offset: Constant of the filtered output (a current offset through the rigid body;
            nan for a joint fit).
        fit_percent: 100 (1 - ||r|| / ||yf - mean(yf)||) of the (1 - q^-1)^2-filtered
            averaged output yf and residual r.
        cost: Sum of squared filtered (unwhitened) residuals.
        n_evaluations: Residual evaluations spent by the optimiser (all starts).
        starts: Number of starting points tried.
        unresolved_modes: Modes (1-based) whose residue is below ``resolve_z`` std: the data
            do not determine them; their omega and zeta std are raised to at least those of a
            uniform distribution over the band and over (0, 0.3).
        residual_to_noise: ``((lo, hi), ratio)`` per interval between band edges: energy of
            the averaged residual over the noise's (about 1 for an adequate model; empty
            without per-move records or noise).
        chi2: Joint fits: the sum of squared residuals, prewhitened and weighted by each
            window's averaged noise (about ``rows`` for an adequate model; nan if not known).
        rows: Joint fits: residual rows over all windows.
    """

    model: ModalModel
    lag_time_constant: float
    lag_estimated: bool
    computation_delay: int
    dead_time: float
    sample_period: float
    parameter_names: tuple[str, ...]
    covariance: NDArray[np.float64] = field(repr=False)
    covariance_method: str
    initial_conditions: tuple[float, ...]
    offset: float
    fit_percent: float
    cost: float
    n_evaluations: int
    starts: int
    unresolved_modes: tuple[int, ...] = ()
    residual_to_noise: tuple[tuple[tuple[float, float], float], ...] = ()
    chi2: float = math.nan
    rows: int = 0

    @property
    def resolved(self) -> tuple[bool, ...]:
        """Per mode, whether the data resolve it (see :attr:`unresolved_modes`)."""
        return tuple(i not in self.unresolved_modes
                     for i in range(1, self.model.n_modes + 1))

    @property
    def input_delay(self) -> float:
        """Low-frequency equivalent input delay [s]: computation delay + dead time + lag."""
        return self.computation_delay * self.sample_period + self.dead_time \
            + self.lag_time_constant

    def std_by_name(self) -> dict[str, float]:
        """Standard deviation of every parameter, by name (incl. ``'lag'`` if estimated)."""
        sd = np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))
        return {n: float(s) for n, s in zip(self.parameter_names, sd, strict=True)}


def filtered_fit_percent(yf: NDArray[np.float64], residual: NDArray[np.float64]) -> float:
    """100 (1 - ||residual|| / ||yf - mean(yf)||)."""
    den = float(np.linalg.norm(yf - yf.mean()))
    return 100.0 * (1.0 - float(np.linalg.norm(residual)) / den) if den > 0 else float('nan')


def model_fit_percent(model: ModalModel, current: ArrayLike, encoder: ArrayLike, *,
                      sample_period: float, lag_time_constant: float = 0.0,
                      computation_delay: int = 1, dead_time: float = 0.0) -> float:
    """Fit [%] of a fixed model on the (1 - q^-1)^2-filtered averaged output.

    The model (with the given input dynamics) is driven by the averaged current; the modes'
    initial conditions and an offset are fitted by least squares, as in :func:`refine_fit`.

    Args:
        model: The modal model.
        current: Current records (M, N) or one record (N,).
        encoder: Encoder records, same shape.
        sample_period: Sampling period [s].
        lag_time_constant: Amplifier lag [s].
        computation_delay: Whole samples of computation delay.
        dead_time: Extra pure delay [s].

    Returns:
        ``100 (1 - ||yf - yf_model|| / ||yf - mean(yf)||)``.
    """
    cur, enc = _validate(current, encoder)
    u_avg, y_avg = cur.mean(axis=0), enc.mean(axis=0)
    regs = modal_regressors(u_avg, model.natural_frequencies, model.damping_ratios,
                            sample_period=sample_period, lag_time_constant=lag_time_constant,
                            computation_delay=computation_delay, dead_time=dead_time)
    first = first_row(*_split_delay(computation_delay, dead_time, sample_period))
    forced = np.tensordot(np.array([model.k0, *model.residues]), regs, axes=1)[first:]
    yf = second_difference(y_avg)[first:]
    cols = [_free_responses(model.natural_frequencies, model.damping_ratios, u_avg.size,
                            sample_period, first=first).T, np.ones((yf.size, 1))]
    if lag_time_constant > 0:
        k = np.arange(yf.size, dtype=float)
        cols.append(np.exp(-k * sample_period / lag_time_constant)[:, None])
    nuisance = np.hstack(cols)
    target = yf - forced
    coef = np.linalg.lstsq(nuisance, target, rcond=None)[0]
    return filtered_fit_percent(yf, target - nuisance @ coef)


class _Problem:
    """Variable projection on one averaged window (filtered rows from :func:`first_row` on)."""

    def __init__(self, u: NDArray[np.float64], y: NDArray[np.float64], *, sample_period: float,
                 delay: int, fraction: float, n_modes: int, fixed_lag: float | None) -> None:
        self.t = sample_period
        self.n_modes = n_modes
        self.fixed_lag = fixed_lag
        self.regs = _Regressors(u, sample_period=sample_period, delay=delay, fraction=fraction)
        self.first = self.regs.first
        self.n = u.shape[-1]
        self.k = np.arange(self.n, dtype=float)[self.first:]
        self.yf_raw = second_difference(y)[self.first:]
        self.n_linear = 1 + n_modes + 2 * n_modes + 2
        self.n_eval = 0
        # (current, encoder, regressors of the moves' deviations, their filtered encoder):
        # see _per_move_deviations
        self.move_data: tuple[NDArray[np.float64], NDArray[np.float64], _Regressors,
                              NDArray[np.float64]] | None = None
        self.set_whitening(None)

    def set_whitening(self, a: NDArray[np.float64] | None) -> None:
        """Use the FIR prewhitening filter ``a`` (a[0] = 1) on data and columns, or none."""
        self.whiten = a
        self.yf = self.apply_whitening(self.yf_raw)
        self.y_scale = float(np.linalg.norm(self.yf)) or 1.0
        self._cache_key: bytes | None = None
        self._cache: tuple[NDArray[np.float64], ...] = ()

    def apply_whitening(self, arr: NDArray[np.float64], axis: int = 0) -> NDArray[np.float64]:
        """Filter ``arr`` along the row ``axis`` (from rest: an invertible lower-triangular map,
        so no row is lost)."""  # noqa: D205, D209
        if self.whiten is None:
            return arr
        return _fir(self.whiten, arr, axis=axis)

    # -- parameters ----------------------------------------------------------------------
    @property
    def n_nonlinear(self) -> int:
        return 2 * self.n_modes + (0 if self.fixed_lag is not None else 1)

    def unpack(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64],
                                                      NDArray[np.float64], float]:
        """(omega, zeta, lag) from x = [ln omega_i, ln zeta_i, (T_l / T)]."""
        n = self.n_modes
        lag = self.fixed_lag if self.fixed_lag is not None else float(x[2 * n]) * self.t
        return np.exp(x[:n]), np.exp(x[n: 2 * n]), lag

    def pack(self, omega: Floats, zeta: Floats, lag: float) -> NDArray[
            np.float64]:
        parts = [np.log(omega), np.log(zeta)]
        if self.fixed_lag is None:
            parts.append(np.array([lag / self.t]))
        return np.concatenate(parts)

    # -- regressors ------------------------------------------------------------------------
    def columns(self, omega: Floats, zeta: Floats, lag: float, *,
                whitened: bool = True) -> NDArray[np.float64]:
        """Regressor matrix (rows, n_linear).

        Columns: rigid body, modes, two free-response columns per mode, offset, and the
        amplifier lag's free response (which, with the others, absorbs any difference between
        the current before the record and its first sample).
        """
        n = self.n_modes
        _, e = _powers(omega, zeta, self.n, self.t)
        phi = np.empty((self.k.size, self.n_linear))
        phi[:, : 1 + n] = self.regs.all(omega, zeta, lag, e)[:, self.first:].T
        phi[:, 1 + n: 1 + 3 * n] = _free_responses(omega, zeta, self.n, self.t, e,
                                                   first=self.first).T
        phi[:, -2] = 1.0
        phi[:, -1] = self.lag_free(lag)
        return self.apply_whitening(phi) if whitened else phi

    def lag_free(self, lag: float) -> NDArray[np.float64]:
        """Free response of the lag state, lambda_a^(k - 2) (a unit impulse at k = 2 if 0)."""
        if lag <= 0:
            out = np.zeros(self.k.size)
            out[0] = 1.0
            return out
        rate = min(self.t / lag, _MAX_DECAY)
        return np.asarray(np.exp(-(self.k - self.first) * rate), dtype=np.float64)

    # -- linear solve ----------------------------------------------------------------------
    def factor(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
        """(phi, q, r, scale, coef, residual) at x, cached for the Jacobian."""
        key = x.tobytes()
        if key == self._cache_key:
            return self._cache
        self.n_eval += 1
        omega, zeta, lag = self.unpack(x)
        phi = self.columns(omega, zeta, lag)
        scale = np.linalg.norm(phi, axis=0)
        scale[scale == 0] = 1.0
        q, r = qr(phi / scale, mode='economic', check_finite=False)
        coef = solve_triangular(r, q.T @ self.yf, check_finite=False) / scale
        resid = self.yf - phi @ coef
        self._cache_key = key
        self._cache = (phi, q, r, scale, coef, resid)
        return self._cache

    def residual(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        return self.factor(x)[5] / self.y_scale

    def cost(self, x: NDArray[np.float64]) -> float:
        r = self.factor(x)[5]
        return float(r @ r)

    # -- derivatives -----------------------------------------------------------------------
    def column_derivatives(self, x: NDArray[np.float64], phi: NDArray[np.float64]) -> list[
            tuple[NDArray[np.intp], NDArray[np.float64]]]:
        """For every nonlinear parameter: (affected column indices, d columns / d x_j)."""
        n = self.n_modes
        omega, zeta, lag = self.unpack(x)
        h = 1e-6
        # all 2 n single-mode perturbations in one batch: omega_i e^h, then zeta_i e^h
        w_p = np.concatenate([omega * math.exp(h), omega])
        z_p = np.concatenate([zeta, zeta * math.exp(h)])
        _, e = _powers(w_p, z_p, self.n, self.t)
        forced = self.regs.convolve(self.regs.mode_impulses(w_p, z_p, lag, e))[:, self.first:]
        free = _free_responses(w_p, z_p, self.n, self.t, e, first=self.first)
        # every perturbed column in one matrix, whitened in one call
        blocks = [forced.T, free.T]
        if self.fixed_lag is None:
            step = h * self.t
            blocks += [self.regs.all(omega, zeta, lag + step)[:, self.first:].T,
                       self.lag_free(lag + step)[:, None]]
        new = self.apply_whitening(np.hstack(blocks))
        out: list[tuple[NDArray[np.intp], NDArray[np.float64]]] = []
        for j in range(2 * n):
            i = j % n
            idx = np.array([1 + i, 1 + n + 2 * i, 2 + n + 2 * i])
            cols = new[:, [j, 2 * n + 2 * j, 2 * n + 2 * j + 1]]
            out.append((idx, (cols - phi[:, idx]) / h))
        if self.fixed_lag is None:
            idx = np.array([*range(1 + n), self.n_linear - 1])
            out.append((idx, (new[:, 6 * n:] - phi[:, idx]) / h))
        return out

    def jacobian(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Golub-Pereyra Jacobian of the projected residual."""
        phi, q, r, scale, coef, resid = self.factor(x)
        derivs = self.column_derivatives(x, phi)
        v = np.empty((resid.size, len(derivs)))
        w = np.zeros((self.n_linear, len(derivs)))
        for j, (idx, dphi) in enumerate(derivs):
            v[:, j] = dphi @ coef[idx]
            w[idx, j] = dphi.T @ resid
        term1 = v - q @ (q.T @ v)
        term2 = q @ solve_triangular(r, w / scale[:, None], trans='T', check_finite=False)
        return np.asarray(-(term1 + term2) / self.y_scale, dtype=np.float64)

    def scan_gains(self, i: int, omega: NDArray[np.float64], zeta: NDArray[np.float64],
                   lag: float, w_c: NDArray[np.float64],
                   z_c: NDArray[np.float64]) -> NDArray[np.float64]:
        """Cost reduction of mode i at each candidate (w_c, z_c), the other modes fixed."""
        return self.scan(i, omega, zeta, lag, w_c, z_c)[0]

    def scan(self, i: int, omega: NDArray[np.float64], zeta: NDArray[np.float64],
             lag: float, w_c: NDArray[np.float64],
             z_c: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(cost reduction, residue) of mode i at each candidate (w_c, z_c), others fixed.

        The other columns are projected out once; the candidates' columns are computed in one
        batch, each then costs a 3-column least-squares solve.
        """
        n = self.n_modes
        phi = self.columns(omega, zeta, lag)
        mine = np.array([1 + i, 1 + n + 2 * i, 2 + n + 2 * i])
        others = np.delete(phi, mine, axis=1)
        scale = np.linalg.norm(others, axis=0)
        scale[scale == 0] = 1.0
        q, _ = qr(others / scale, mode='economic', check_finite=False)
        r_o = self.yf - q @ (q.T @ self.yf)
        _, e = _powers(w_c, z_c, self.n, self.t)
        forced = self.regs.convolve(self.regs.mode_impulses(w_c, z_c, lag, e))[:, self.first:]
        free = _free_responses(w_c, z_c, self.n, self.t, e, first=self.first)
        cand = self.apply_whitening(np.stack([forced, free[0::2], free[1::2]], axis=-1),
                                    axis=1)  # (m, rows, 3)
        c_o = cand - q @ (q.T @ cand)
        gram = np.swapaxes(c_o, 1, 2) @ c_o
        rhs = np.swapaxes(c_o, 1, 2) @ r_o
        try:
            sol = np.linalg.solve(gram, rhs[..., None])[..., 0]
        except np.linalg.LinAlgError:
            return np.full(w_c.size, -1.0), np.zeros(w_c.size)
        gain = np.sum(rhs * sol, axis=1)
        gain[~np.isfinite(gain)] = -1.0
        return np.asarray(gain, dtype=np.float64), np.asarray(sol[:, 0], dtype=np.float64)

    def scan_new(self, omega: NDArray[np.float64], zeta: NDArray[np.float64], lag: float,
                 w_c: NDArray[np.float64], z_c: NDArray[np.float64]) -> NDArray[np.float64]:
        """Cost reduction of one more mode at each candidate (w_c, z_c), the modes fixed."""
        phi = self.columns(omega, zeta, lag)
        scale = np.linalg.norm(phi, axis=0)
        scale[scale == 0] = 1.0
        q, _ = qr(phi / scale, mode='economic', check_finite=False)
        r_o = self.yf - q @ (q.T @ self.yf)
        _, e = _powers(w_c, z_c, self.n, self.t)
        forced = self.regs.convolve(self.regs.mode_impulses(w_c, z_c, lag, e))[:, self.first:]
        free = _free_responses(w_c, z_c, self.n, self.t, e, first=self.first)
        cand = self.apply_whitening(np.stack([forced, free[0::2], free[1::2]], axis=-1),
                                    axis=1)
        c_o = cand - q @ (q.T @ cand)
        gram = np.swapaxes(c_o, 1, 2) @ c_o
        rhs = np.swapaxes(c_o, 1, 2) @ r_o
        try:
            sol = np.linalg.solve(gram, rhs[..., None])[..., 0]
        except np.linalg.LinAlgError:
            return np.zeros(w_c.size)
        gain = np.sum(rhs * sol, axis=1)
        gain[~np.isfinite(gain)] = 0.0
        return np.asarray(gain, dtype=np.float64)

    def scan_mode(self, i: int, omega: NDArray[np.float64], zeta: NDArray[np.float64],
                  lag: float, grid: NDArray[np.float64], zeta_scan: float) -> float:
        """Best frequency for mode i: ``omega[i]`` (at ``zeta[i]``) or a ``grid`` point (at
        ``zeta_scan``), the other modes fixed; the current value wins unless a grid point fits
        better."""  # noqa: D205, D209
        w_c, z_c = _scan_candidates(omega[i], zeta[i], grid, zeta_scan)
        return float(w_c[int(np.argmax(self.scan_gains(i, omega, zeta, lag, w_c, z_c)))])


def _scan_candidates(omega: float, zeta: float, grid: NDArray[np.float64],
                     zeta_scan: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    return (np.concatenate([[omega], grid]),
            np.concatenate([[zeta], np.full(grid.size, zeta_scan)]))


def _bounds(band_list: Sequence[tuple[float, float]], estimate_lag: bool,
            lag_bounds: tuple[float, float]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Bounds of x = [ln omega_i, ln zeta_i, (T_l / T)]."""
    n = len(band_list)
    lb = [*np.log([lo for lo, _ in band_list]), *np.full(n, math.log(_MIN_DAMPING))]
    ub = [*np.log([hi for _, hi in band_list]), *np.full(n, math.log(_MAX_DAMPING))]
    if estimate_lag:
        lb.append(lag_bounds[0])
        ub.append(lag_bounds[1])
    return np.array(lb), np.array(ub)


def _start_vector(prob: _Problem | _JointProblem, model: ModalModel, lower: NDArray[np.float64],
                  upper: NDArray[np.float64], *, damping_start: float, lag: float,
                  lag_bounds: tuple[float, float]) -> NDArray[np.float64]:
    """Starting x from a model: its frequencies, damping raised to ``damping_start``."""
    omega = np.array(model.natural_frequencies, dtype=float)
    zeta = np.maximum(np.array(model.damping_ratios, dtype=float), damping_start)
    t = prob.t
    lag0 = min(max(lag / t, lag_bounds[0]), lag_bounds[1]) * t
    x0 = prob.pack(omega, np.minimum(zeta, 0.5 * _MAX_DAMPING), lag0)
    span = upper - lower
    return np.clip(x0, lower + 1e-3 * span, upper - 1e-3 * span)


def _inflate_unresolved(cov: NDArray[np.float64], unresolved: Sequence[int],
                        band_list: Sequence[tuple[float, float]], n: int) -> None:
    """Give the unresolved modes' omega and zeta (in place) at least a uniform prior's std."""
    for i in unresolved:
        lo, hi = band_list[i]
        for j, floor in ((1 + n + i, (hi - lo) / math.sqrt(12.0)),
                         (1 + 2 * n + i, _MAX_DAMPING / math.sqrt(12.0))):
            var = max(float(cov[j, j]), floor * floor)
            cov[j, :] = 0.0
            cov[:, j] = 0.0
            cov[j, j] = var


def _edge_mode(params: tuple[NDArray[np.float64], NDArray[np.float64], float],
               band_list: Sequence[tuple[float, float]]) -> int | None:
    """Index of the first mode stuck at a band edge or at the damping bound, else None."""
    omega, zeta, _ = params
    for i, ((lo, hi), w, z) in enumerate(zip(band_list, omega, zeta, strict=True)):
        if not lo * 1.0005 < w < hi / 1.0005 or z > 0.99 * _MAX_DAMPING:
            return i
    return None


def _validate(current: ArrayLike, encoder: ArrayLike) -> tuple[NDArray[np.float64],
                                                                NDArray[np.float64]]:
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


def _bands_for(initial: ModalModel, bands: Sequence[tuple[float, float]] | None,
               sample_period: float) -> list[tuple[float, float]]:
    if bands is None:
        bands = default_bands(initial, sample_period=sample_period)
    out = [(float(lo), float(hi)) for lo, hi in bands]
    if len(out) != initial.n_modes:
        raise ConfigurationError(f'{len(out)} bands for {initial.n_modes} modes')
    nyquist = math.pi / sample_period
    for lo, hi in out:
        if not 0 < lo < hi <= nyquist:
            raise ConfigurationError(f'bad band ({lo:.4g}, {hi:.4g}) rad/s (Nyquist {nyquist:.4g})')
    return out


MIN_SAMPLES = 64
"""Fewest samples per record the refined fit accepts."""


def refine_fit(current: ArrayLike, encoder: ArrayLike, *, sample_period: float,
               initial: ModalModel, lag_time_constant: float = 0.6 * TAU,
               estimate_lag: bool = True, computation_delay: int = 1, dead_time: float = 0.0,
               bands: Sequence[tuple[float, float]] | None = None,
               damping_start: float = DEFAULT_DAMPING_START,
               extra_starts: Sequence[ModalModel] = (),
               lag_bounds: tuple[float, float] = DEFAULT_LAG_BOUNDS,
               scan_points: int = DEFAULT_SCAN_POINTS, resolve_z: float = DEFAULT_RESOLVE_Z,
               whiten_order: int = DEFAULT_WHITEN_ORDER,
               adequacy_limit: float = DEFAULT_ADEQUACY_LIMIT,
               max_nfev: int = 100) -> RefinedFit:
    """Fit the modal model with exact input dynamics to a window of moves (averaged).

    Args:
        current: Current records [A], shape (M, N) (or one record (N,)).
        encoder: Encoder records [deg], same shape, raw (the start angle cancels).
        sample_period: Sampling period T [s].
        initial: Starting model (e.g. the paper pipeline's); only its frequencies and damping
            ratios are used.
        lag_time_constant: Starting (or, with ``estimate_lag=False``, fixed) amplifier lag [s].
        estimate_lag: Estimate the lag (True) or keep it fixed.
        computation_delay: Whole samples of computation delay.
        dead_time: Extra pure delay [s] (0 for the physical lag model; e.g. ``0.6 T`` with
            ``lag_time_constant=0, estimate_lag=False`` for the paper's pure 1.6 T delay).
        bands: Frequency band [rad/s] of each mode; the fit fails if a mode ends at a band
            edge. Default: :func:`galvo_sysid.ident.decompose.default_bands`.
        damping_start: Damping ratio the modes start from (continuation; see module docs).
        extra_starts: Further starting models (e.g. the previous window's result).
        scan_points: Frequencies per band of the starting scan (0: no scan, start from
            ``initial`` only).
        lag_bounds: Bounds of the estimated lag [sample periods].
        resolve_z: A mode whose |k_i| is below ``resolve_z`` times its std counts as not
            resolved (see :attr:`RefinedFit.unresolved_modes`); such a mode may end at a band
            edge without an error.
        whiten_order: Order of the AR noise model of the second, prewhitened stage
            (generalised least squares; 0: ordinary least squares only). Needs M > 2 records.
        adequacy_limit: Largest accepted ratio of the averaged residual's energy to the noise's
            (estimated from the moves' scatter) in any interval between band edges; above it
            the model lacks dynamics the data hold (0: no check). Needs M > 2 records.
        max_nfev: Iteration limit of each start.

    Returns:
        The fit with its covariance.

    Raises:
        InvalidDataError: Bad shapes, too short, NaN/Inf.
        ConfigurationError: Bad options.
        IdentificationError: The fit failed, a resolved mode ended at its band edge, or the
            residual between the band edges is far above the noise (no physical mode in a
            band).
    """
    cur, enc = _validate(current, encoder)
    if not (np.isfinite(sample_period) and sample_period > 0):
        raise ConfigurationError(f'sample_period must be positive and finite, got {sample_period}')
    if initial.n_modes < 1:
        raise ConfigurationError('the initial model needs at least one resonant mode')
    if not (np.isfinite(lag_time_constant) and lag_time_constant >= 0 and dead_time >= 0):
        raise ConfigurationError('lag_time_constant and dead_time must be finite and >= 0')
    lo_lag, hi_lag = lag_bounds
    if not 0 <= lo_lag < hi_lag:
        raise ConfigurationError(f'bad lag_bounds {lag_bounds}')
    if not 0 < damping_start < _MAX_DAMPING:
        raise ConfigurationError(f'damping_start must be in (0, {_MAX_DAMPING})')
    band_list = _bands_for(initial, bands, sample_period)
    delay, frac = _split_delay(computation_delay, dead_time, sample_period)
    n = initial.n_modes
    u_avg = cur.mean(axis=0)
    y_avg = enc.mean(axis=0)
    if not np.any(u_avg - u_avg[0]):
        raise InvalidDataError('no excitation: the averaged current is constant')
    prob = _Problem(u_avg, y_avg, sample_period=sample_period, delay=delay, fraction=frac,
                    n_modes=n, fixed_lag=None if estimate_lag else lag_time_constant)
    lower, upper = _bounds(band_list, estimate_lag, lag_bounds)

    def start_vector(model: ModalModel) -> NDArray[np.float64]:
        return _start_vector(prob, model, lower, upper, damping_start=damping_start,
                             lag=lag_time_constant, lag_bounds=lag_bounds)

    for model in extra_starts:
        if model.n_modes != n:
            raise ConfigurationError('every starting model needs the same number of modes')
    # Start 1: every mode's frequency scanned over its band at a large damping ratio.
    x_init = start_vector(initial)
    omega0, zeta0, lag0 = prob.unpack(x_init)
    omega_scan = omega0.copy()
    if scan_points > 1:
        # The other modes keep the initial model's damping (inflating a strongly excited mode's
        # damping would leave a misfit the scanned mode then chases).
        zeta_init = np.clip(np.array(initial.damping_ratios, dtype=float), 1e-4,
                            0.5 * _MAX_DAMPING)
        for i, (lo, hi) in enumerate(band_list):
            grid = np.geomspace(lo * 1.01, hi / 1.01, scan_points)
            omega_scan[i] = prob.scan_mode(i, omega_scan, zeta_init, lag0, grid,
                                           damping_start)
    starts = [prob.pack(omega_scan, zeta0, lag0)]
    # Start 2: the initial model itself (if its frequencies differ), then any extra starts.
    if np.max(np.abs(np.log(omega_scan / omega0))) > 0.01:
        starts.append(x_init)
    starts += [start_vector(model) for model in extra_starts]
    # Stage 1 only has to find the basin when the prewhitened stage 2 polishes afterwards.
    tol = _STAGE1_TOL if whiten_order > 0 and cur.shape[0] > 2 else 1e-8
    best = None
    for x0 in starts:
        try:
            sol = least_squares(prob.residual, x0, jac=prob.jacobian, bounds=(lower, upper),
                                x_scale='jac', max_nfev=max_nfev, method='trf', ftol=tol,
                                xtol=tol)
        except (ValueError, LinAlgError) as exc:
            raise IdentificationError(f'refined fit failed: {exc}') from exc
        edge = _edge_mode(prob.unpack(sol.x), band_list)
        key = (edge is not None, float(sol.cost))
        if best is None or key < best[0]:
            best = (key, sol, edge)
    assert best is not None
    _, sol, edge = best
    x = sol.x
    if whiten_order > 0 and cur.shape[0] > 2:
        # Stage 2 (generalised least squares): prewhiten data and model by an AR model of the
        # per-move noise at the stage-1 optimum, and polish from there.
        coef1 = prob.factor(x)[4]
        dev1 = _per_move_deviations(prob, x, coef1, cur, enc)
        prob.set_whitening(_whitening_filter(
            dev1, whiten_order, float(np.sqrt(np.mean(prob.yf_raw**2)))))
        try:
            sol2 = least_squares(prob.residual, x, jac=prob.jacobian, bounds=(lower, upper),
                                 x_scale='jac', max_nfev=max_nfev, method='trf')
        except (ValueError, LinAlgError) as exc:
            raise IdentificationError(f'refined fit failed: {exc}') from exc
        x = sol2.x
        edge = _edge_mode(prob.unpack(x), band_list)
    m = cur.shape[0]
    profiles: list[_ModeProfile] = []
    if m > 2:
        # Each mode's profile over its band: a clearly better basin is polished (the global
        # search of a weakly excited mode); the plausible region widens the std below.
        x, profiles = _profile_and_search(prob, x, band_list, cur, enc, lower, upper,
                                          max_nfev=max_nfev)
        edge = _edge_mode(prob.unpack(x), band_list)
    omega, zeta, lag = prob.unpack(x)
    phi, _, _, _, coef, _ = prob.factor(x)
    resid = prob.yf_raw - prob.columns(omega, zeta, lag, whitened=False) @ coef
    model_out = ModalModel(k0=float(coef[0]), residues=tuple(float(c) for c in coef[1: 1 + n]),
                           natural_frequencies=tuple(float(w) for w in omega),
                           damping_ratios=tuple(float(z) for z in zeta))
    names = (*model_out.parameters(), *(('lag',) if estimate_lag else ()))
    dev = _per_move_deviations(prob, x, coef, cur, enc) if m > 2 else None
    cov, method = _covariance(prob, x, phi, coef, resid, dev)
    _widen_to_profiles(cov, profiles, list(model_out.parameters().values()), n)
    noisy = dev is not None and float(np.mean(dev**2)) > 1e-20 * float(np.mean(prob.yf_raw**2))
    ratios = _residual_to_noise(resid, dev, band_list, sample_period) \
        if dev is not None and noisy else ()
    for (lo, hi), ratio in ratios:
        if adequacy_limit > 0 and ratio > adequacy_limit:
            raise ModelMismatchError(
                f'the residual between {lo:.4g} and {hi:.4g} rad/s is {ratio:.3g} times the '
                f'noise: the data hold dynamics the model lacks there (no physical mode in a '
                f'band, or a mode outside its band)')
    # A mode whose residue is not significant is not resolved by these data: its frequency and
    # damping are a noise fit, so their linearised std would mislead (e.g. a pooled mean).
    k_std = np.sqrt(np.clip(np.diag(cov)[1: 1 + n], 0.0, None))
    unresolved = tuple(i for i in range(n) if abs(coef[1 + i]) < resolve_z * k_std[i]
                       or (profiles and not profiles[i].resolved(band_list[i])))
    if edge is not None and edge not in unresolved:
        lo, hi = band_list[edge]
        raise ModelMismatchError(
            f'no physical mode {edge + 1} in the band {lo:.4g}..{hi:.4g} rad/s (the fit ended at '
            f'omega = {omega[edge]:.4g} rad/s, zeta = {zeta[edge]:.3g})')
    _inflate_unresolved(cov, unresolved, band_list, n)
    return RefinedFit(
        model=model_out, lag_time_constant=float(lag), lag_estimated=estimate_lag,
        computation_delay=computation_delay, dead_time=float(dead_time),
        sample_period=float(sample_period), parameter_names=tuple(names), covariance=cov,
        covariance_method=method,
        initial_conditions=tuple(float(c) for c in coef[1 + n: 1 + 3 * n]),
        offset=float(coef[1 + 3 * n]), fit_percent=filtered_fit_percent(prob.yf_raw, resid),
        cost=float(resid @ resid), n_evaluations=prob.n_eval, starts=len(starts),
        unresolved_modes=tuple(i + 1 for i in unresolved), residual_to_noise=ratios)


PROFILE_LEVEL = 9.21
"""Cost increase, in units of the averaged (whitened) noise variance, within which another
frequency and damping of a mode are as plausible as the fit's (chi-square, 2 dof, 99 %)."""

MODE_EVIDENCE = 25.0
"""Cost reduction (same units) a mode must bring, the others fixed, to count as resolved."""

STRONG_EVIDENCE = 400.0
"""A mode bringing this much cost reduction (20 sigma) is placed sharply: its linearised std
holds and its profile is not scanned (saves time)."""

_PROFILE_DAMPING = tuple(float(z) for z in np.geomspace(3e-4, 0.2, 8))
_PROFILE_POINTS = 32


@dataclass(frozen=True)
class _ModeProfile:
    """What one mode's profile over its band says (costs in noise-variance units).

    Attributes:
        evidence: Cost reduction the mode brings at the fit, the other modes fixed.
        better: A (omega, zeta) of the scan with a lower cost than the fit's, if any.
        omega_span: Smallest and largest plausible frequency [rad/s].
        zeta_span: Smallest and largest plausible damping ratio.
        k_span: Smallest and largest residue over the plausible points.
    """

    evidence: float
    better: tuple[float, float] | None
    omega_span: tuple[float, float]
    zeta_span: tuple[float, float]
    k_span: tuple[float, float]

    def resolved(self, band: tuple[float, float]) -> bool:
        """Whether the data place the mode: it brings enough evidence and its plausible
        frequencies do not cover half its band (in log frequency)."""  # noqa: D205, D209
        lo, hi = band
        covered = math.log(self.omega_span[1] / self.omega_span[0]) / math.log(hi / lo)
        return self.evidence >= MODE_EVIDENCE and covered < 0.5


def _profile_modes(prob: _Problem, x: NDArray[np.float64],
                   band_list: Sequence[tuple[float, float]],
                   sigma2: float) -> list[_ModeProfile]:
    """Profile each mode over a grid of its band and damping, the other modes fixed."""
    omega, zeta, lag = prob.unpack(x)
    out = []
    damping = np.array(_PROFILE_DAMPING)
    for i, (lo, hi) in enumerate(band_list):
        gain0 = float(prob.scan(i, omega, zeta, lag, omega[i:i + 1], zeta[i:i + 1])[0][0])
        if gain0 / sigma2 >= STRONG_EVIDENCE:
            w, z = float(omega[i]), float(zeta[i])
            out.append(_ModeProfile(evidence=gain0 / sigma2, better=None, omega_span=(w, w),
                                    zeta_span=(z, z), k_span=(0.0, 0.0)))
            continue
        grid = np.geomspace(lo * 1.001, hi / 1.001, _PROFILE_POINTS)
        w_c = np.concatenate([[omega[i]], np.repeat(grid, damping.size)])
        z_c = np.concatenate([[zeta[i]], np.tile(damping, grid.size)])
        gain, k = prob.scan(i, omega, zeta, lag, w_c, z_c)
        delta = (gain[0] - gain) / sigma2
        ok = delta < PROFILE_LEVEL
        best = int(np.argmin(delta))
        better = (float(w_c[best]), float(z_c[best])) if delta[best] < -1.0 else None
        out.append(_ModeProfile(
            evidence=float(gain[0] / sigma2), better=better,
            omega_span=(float(w_c[ok].min()), float(w_c[ok].max())),
            zeta_span=(float(z_c[ok].min()), float(z_c[ok].max())),
            k_span=(float(k[ok].min()), float(k[ok].max()))))
    return out


def _profile_and_search(prob: _Problem, x: NDArray[np.float64],
                        band_list: Sequence[tuple[float, float]], cur: NDArray[np.float64],
                        enc: NDArray[np.float64], lower: NDArray[np.float64],
                        upper: NDArray[np.float64], *,
                        max_nfev: int) -> tuple[NDArray[np.float64], list[_ModeProfile]]:
    """Profiles of the modes at x; if a mode has a clearly better basin, polish from there
    (kept if the cost is lower) and profile again."""  # noqa: D205, D209
    def profiles_at(xx: NDArray[np.float64]) -> list[_ModeProfile] | None:
        dev = prob.apply_whitening(
            _per_move_deviations(prob, xx, prob.factor(xx)[4], cur, enc), axis=1)
        sigma2 = float(np.mean(dev**2)) / (cur.shape[0] - 1)
        if not sigma2 > 1e-20 * float(np.mean(prob.yf**2)):
            return None  # noise-free data: nothing to weigh the profiles with
        return _profile_modes(prob, xx, band_list, sigma2)

    profiles = profiles_at(x)
    if profiles is None:
        return x, []
    if any(p.better is not None for p in profiles):
        omega, zeta, lag = prob.unpack(x)
        for i, p in enumerate(profiles):
            if p.better is not None:
                omega[i], zeta[i] = p.better
        span = upper - lower
        start = np.clip(prob.pack(omega, zeta, lag), lower + 1e-3 * span, upper - 1e-3 * span)
        try:
            sol = least_squares(prob.residual, start, jac=prob.jacobian, bounds=(lower, upper),
                                x_scale='jac', max_nfev=max_nfev, method='trf')
        except (ValueError, LinAlgError) as exc:
            raise IdentificationError(f'refined fit failed: {exc}') from exc
        if prob.cost(sol.x) < prob.cost(x):
            x = sol.x
            profiles = profiles_at(x) or []
    return x, profiles


def _widen_to_profiles(cov: NDArray[np.float64], profiles: Sequence[_ModeProfile],
                       estimate: Sequence[float], n: int) -> None:
    """Raise each mode's std (in place) to a third of the farthest plausible value's distance.

    The linearised covariance holds near the optimum only; a weakly excited mode whose cost
    is flat over a wide region (or has two basins) gets the std of that region (the farthest
    point of its 99 % region read as 3 std away), its correlations dropped.
    """
    for i, p in enumerate(profiles):
        for j, (a, b) in ((1 + i, p.k_span), (1 + n + i, p.omega_span),
                          (1 + 2 * n + i, p.zeta_span)):
            floor = max(abs(b - estimate[j]), abs(estimate[j] - a)) / 3.0 if b > a else 0.0
            if floor * floor > cov[j, j]:
                cov[j, :] = 0.0
                cov[:, j] = 0.0
                cov[j, j] = floor * floor


def _per_move_deviations(prob: _Problem, x: NDArray[np.float64], coef: NDArray[np.float64],
                         cur: NDArray[np.float64], enc: NDArray[np.float64]) -> NDArray[
                             np.float64]:
    """Each move's filtered residual minus the window mean (unwhitened rows), (M, rows).

    By linearity this is the residual of the moves' deviations from the window mean, whose
    forced response is one convolution with the model's combined impulse response; the
    deviations' transforms are computed once per window (cached on ``prob``).
    """
    n = prob.n_modes
    omega, zeta, lag = prob.unpack(x)
    cached = prob.move_data
    if cached is None or cached[0] is not cur or cached[1] is not enc:
        regs = _Regressors(cur - cur.mean(axis=0), sample_period=prob.t,
                           delay=prob.regs.delay, fraction=prob.regs.fraction)
        cached = (cur, enc, regs, second_difference(enc - enc.mean(axis=0)))
        prob.move_data = cached
    _, _, regs, enc_f = cached
    h_lag = regs.lag_impulse(lag)
    h = coef[1: 1 + n] @ regs.mode_impulses(omega, zeta, lag, h_lag=h_lag) \
        + coef[0] * lag * h_lag
    forced = regs.convolve(h[None, :])[0] \
        + coef[0] * (regs.rigid_double - lag * regs.rigid_single)
    return np.asarray((enc_f - forced)[:, prob.first:], dtype=np.float64)


def _whitening_filter(dev: NDArray[np.float64], order: int,
                      scale: float) -> NDArray[np.float64]:
    """FIR A(q) = 1 + a_1 q^-1 + .. making the per-move noise ``dev`` white (Yule-Walker).

    ``scale`` is the rms of the filtered output: noise below 1e-10 of it is not modelled.
    """
    n = dev.shape[1]
    r = np.array([np.sum(dev[:, lag:] * dev[:, : n - lag]) for lag in range(order + 1)])
    if not r[0] > scale * scale * 1e-20 * dev.size:  # no noise to model (noise-free data)
        return np.array([1.0])
    r = r / r[0] * (1.0 - 1e-9 * np.arange(order + 1) / order)  # slight taper, stays PD
    try:
        a = solve_toeplitz(r[:-1], -r[1:])
    except (ValueError, LinAlgError):
        return np.array([1.0])
    return np.concatenate([[1.0], a]) if np.all(np.isfinite(a)) else np.array([1.0])


def _residual_to_noise(resid: NDArray[np.float64], dev: NDArray[np.float64],
                       band_list: Sequence[tuple[float, float]],
                       sample_period: float) -> tuple[tuple[tuple[float, float], float], ...]:
    """Energy of the averaged residual over that expected from the noise, per interval.

    The intervals cut [lowest band edge, highest band edge] at every band edge (so the gaps
    between bands are checked too). About 1 for an adequate model.
    """
    m = dev.shape[0]
    win = np.hanning(resid.size)
    res_psd = np.abs(np.fft.rfft(resid * win)) ** 2
    noise_psd = np.mean(np.abs(np.fft.rfft(dev * win, axis=1)) ** 2, axis=0) / m
    freq = np.fft.rfftfreq(resid.size, sample_period) * 2 * math.pi
    edges = sorted({e for band in band_list for e in band})
    out = []
    for lo, hi in itertools.pairwise(edges):
        sel = (freq >= lo) & (freq < hi)
        noise = float(np.sum(noise_psd[sel]))
        if noise > 0 and np.count_nonzero(sel) >= 3:
            out.append(((lo, hi), float(np.sum(res_psd[sel])) / noise))
    return tuple(out)


def _covariance(prob: _Problem, x: NDArray[np.float64], phi: NDArray[np.float64],
                coef: NDArray[np.float64], resid: NDArray[np.float64],
                dev: NDArray[np.float64] | None) -> tuple[NDArray[np.float64], str]:
    """Covariance of [k0, k_i, omega_i, zeta_i, (lag)] (sandwich over the moves if M > 2)."""
    n = prob.n_modes
    omega, zeta, _ = prob.unpack(x)
    # Jacobian of the filtered model output w.r.t. [k0, k_i, omega_i, zeta_i, (lag), nuisance]
    derivs = prob.column_derivatives(x, phi)
    n_nl = len(derivs)
    jac = np.empty((phi.shape[0], n_nl + phi.shape[1]))
    jac[:, : 1 + n] = phi[:, : 1 + n]
    phys = np.concatenate([omega, zeta, [prob.t]])  # d x_j -> d physical parameter
    for j, (idx, dphi) in enumerate(derivs):
        jac[:, 1 + n + j] = (dphi @ coef[idx]) / phys[j]
    jac[:, 1 + n + n_nl:] = phi[:, 1 + n:]
    scale = np.linalg.norm(jac, axis=0)
    scale[scale == 0] = 1.0
    js = jac / scale
    # Gram + Cholesky (the columns are normalised): cheaper than QR and never multithreaded.
    try:
        chol = cholesky(js.T @ js, lower=True, check_finite=False)
        l_inv = solve_triangular(chol, np.eye(chol.shape[0]), lower=True, check_finite=False)
    except (ValueError, LinAlgError) as exc:
        raise IdentificationError(f'singular Jacobian at the optimum: {exc}') from exc
    a_inv = l_inv.T @ l_inv  # (Js^T Js)^-1
    if dev is not None:
        m = dev.shape[0]
        g = prob.apply_whitening(dev, axis=1) @ js  # (M, p)
        b = g.T @ g / (m * (m - 1))
        cov_s = a_inv @ b @ a_inv
        method = 'sandwich'
    else:
        dof = max(resid.size - js.shape[1], 1)
        cov_s = a_inv * float(resid @ resid) / dof
        method = 'white'
    cov = cov_s / np.outer(scale, scale)
    keep = 1 + n + n_nl
    return np.asarray(cov[:keep, :keep], dtype=np.float64), method



class _JointProblem:
    """Variable projection over several windows of one plant.

    The windows share omega_i, zeta_i, the lag, k0 and k_i; each keeps its own nuisance
    columns (free responses, offset, lag state), which are projected out window by window
    before the shared coefficients are solved. Each window's rows are scaled by ``weights``
    (the inverse rms of its averaged noise).
    """

    def __init__(self, problems: Sequence[_Problem], weights: Floats) -> None:
        self.problems = list(problems)
        self.t = self.problems[0].t
        self.n_modes = self.problems[0].n_modes
        self.n_eval = 0
        self.set_weights(weights)

    def set_weights(self, weights: Floats) -> None:
        self.weights = np.asarray(weights, dtype=float)
        self.y_scale = float(np.sqrt(sum(w * w * float(p.yf @ p.yf) for p, w in
                                         zip(self.problems, self.weights, strict=True)))) or 1.0
        self._key: bytes | None = None
        self._cache: tuple[NDArray[np.float64], NDArray[np.float64]] = (np.zeros(0),
                                                                          np.zeros(0))
        # per window (phi, Q, R, column scale) of the nuisance QR, and Q of the shared columns
        self._parts: tuple[list[tuple[NDArray[np.float64], ...]], NDArray[np.float64]] = (
            [], np.zeros((0, 0)))

    def unpack(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64],
                                                      NDArray[np.float64], float]:
        return self.problems[0].unpack(x)

    def pack(self, omega: Floats, zeta: Floats, lag: float) -> NDArray[np.float64]:
        return self.problems[0].pack(omega, zeta, lag)

    def solve(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(shared coefficients [k0, k_i], stacked weighted residual)."""
        key = x.tobytes()
        if key == self._key:
            return self._cache
        self.n_eval += 1
        n = self.n_modes
        omega, zeta, lag = self.unpack(x)
        f_parts, y_parts = [], []
        parts: list[tuple[NDArray[np.float64], ...]] = []
        for prob, wt in zip(self.problems, self.weights, strict=True):
            phi = prob.columns(omega, zeta, lag)
            nuis = phi[:, 1 + n:]
            scale = np.linalg.norm(nuis, axis=0)
            scale[scale == 0] = 1.0
            q, r = qr(nuis / scale, mode='economic', check_finite=False)
            f_parts.append(wt * (phi[:, : 1 + n] - q @ (q.T @ phi[:, : 1 + n])))
            y_parts.append(wt * (prob.yf - q @ (q.T @ prob.yf)))
            parts.append((phi, q, r, scale))
        f_all = np.vstack(f_parts)
        y_all = np.concatenate(y_parts)
        scale = np.linalg.norm(f_all, axis=0)
        scale[scale == 0] = 1.0
        q_f, r_f = qr(f_all / scale, mode='economic', check_finite=False)
        shared = solve_triangular(r_f, q_f.T @ y_all, check_finite=False) / scale
        self._key = key
        self._cache = (shared, y_all - f_all @ shared)
        self._parts = (parts, q_f)
        return self._cache

    def residual(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        return self.solve(x)[1] / self.y_scale

    def jacobian(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Kaufman's variable-projection Jacobian of :meth:`residual`.

        ``-P (d Phi / d x_j) c`` with P the projection onto the orthogonal complement of all
        linear columns (each window's nuisance, then the shared columns left after it), c the
        coefficients at x; the Golub-Pereyra term that Kaufman drops is second order at the
        optimum.
        """
        shared = self.solve(x)[0]
        parts, q_f = self._parts
        n = self.n_modes
        v_parts = []
        for prob, wt, (phi, q, r, scale) in zip(self.problems, self.weights, parts,
                                                 strict=True):
            nuis = solve_triangular(r, q.T @ (prob.yf - phi[:, : 1 + n] @ shared),
                                    check_finite=False) / scale
            coef = np.concatenate([shared, nuis])
            derivs = prob.column_derivatives(x, phi)
            v = np.empty((phi.shape[0], len(derivs)))
            for j, (idx, dphi) in enumerate(derivs):
                v[:, j] = dphi @ coef[idx]
            v_parts.append(wt * (v - q @ (q.T @ v)))
        v_all = np.vstack(v_parts)
        v_all -= q_f @ (q_f.T @ v_all)
        return np.asarray(-v_all / self.y_scale, dtype=np.float64)

    def coefficients(self, x: NDArray[np.float64]) -> list[NDArray[np.float64]]:
        """Each window's full coefficient vector [shared, its nuisance] at x."""
        n = self.n_modes
        omega, zeta, lag = self.unpack(x)
        shared = self.solve(x)[0]
        out = []
        for prob in self.problems:
            phi = prob.columns(omega, zeta, lag)
            nuis = np.linalg.lstsq(phi[:, 1 + n:], prob.yf - phi[:, : 1 + n] @ shared,
                                   rcond=None)[0]
            out.append(np.concatenate([shared, nuis]))
        return out


def _window_noise_rms(cur: NDArray[np.float64], enc: NDArray[np.float64],
                      prob: _Problem | None = None) -> float:
    """Rms of a window's averaged filtered noise (the moves' scatter / sqrt(M - 1)), whitened
    by ``prob``'s filter if given."""  # noqa: D205, D209
    yf = second_difference(enc)[:, _FIRST_ROW:]
    dev = yf - yf.mean(axis=0)
    if prob is not None:
        dev = prob.apply_whitening(dev, axis=1)
    m = yf.shape[0]
    return float(np.sqrt(np.mean(dev**2) / max(m - 1, 1)))


def window_noise_filters(windows: Sequence[tuple[ArrayLike, ArrayLike]], *,
                         order: int = DEFAULT_WHITEN_ORDER) -> list[NDArray[np.float64]]:
    """A prewhitening filter per window from its moves' scatter alone (no model needed).

    The AR model of the (1 - q^-1)^2-filtered encoder deviations from the window's mean: the
    noise the averaged window carries, up to the small part the input deviations explain.
    """
    out = []
    for current, encoder in windows:
        _, enc = _validate(current, encoder)
        dev = second_difference(enc - enc.mean(axis=0))[:, _FIRST_ROW:]
        out.append(_whitening_filter(dev, order, float(np.sqrt(np.mean(
            second_difference(enc.mean(axis=0)) ** 2)))))
    return out


def added_mode_gains(windows: Sequence[tuple[ArrayLike, ArrayLike]], fit: RefinedFit, *,
                     noise_filters: Sequence[NDArray[np.float64]],
                     candidates: tuple[NDArray[np.float64], NDArray[np.float64]]) -> (
                         NDArray[np.float64]):
    """Drop of a joint fit's ``chi2`` if one more mode were added at each candidate.

    The fit's modes and lag stay fixed, all linear coefficients are solved again; the same
    ``noise_filters`` as the fit's must be given, so the drops are in its ``chi2`` units.

    Args:
        windows: The fit's windows.
        fit: A joint fit made with ``noise_filters``.
        noise_filters: Its filters.
        candidates: ``(omega, zeta)`` of the candidate modes.

    Returns:
        The drop of chi2 per candidate.
    """
    w_c, z_c = (np.asarray(c, dtype=float) for c in candidates)
    m = fit.model
    omega = np.array(m.natural_frequencies, dtype=float)
    zeta = np.array(m.damping_ratios, dtype=float)
    delay, frac = _split_delay(fit.computation_delay, fit.dead_time, fit.sample_period)
    total = np.zeros(w_c.size)
    for (current, encoder), filt in zip(windows, noise_filters, strict=True):
        cur, enc = _validate(current, encoder)
        prob = _Problem(cur.mean(axis=0), enc.mean(axis=0), sample_period=fit.sample_period,
                        delay=delay, fraction=frac, n_modes=m.n_modes, fixed_lag=None)
        prob.set_whitening(np.asarray(filt, dtype=float))
        weight = 1.0 / max(_window_noise_rms(cur, enc, prob), 1e-300)
        total += weight * weight * prob.scan_new(omega, zeta, fit.lag_time_constant, w_c, z_c)
    return total


def refine_joint(windows: Sequence[tuple[ArrayLike, ArrayLike]], *, sample_period: float,
                 initial: ModalModel, lag_time_constant: float = 0.6 * TAU,
                 estimate_lag: bool = True, computation_delay: int = 1, dead_time: float = 0.0,
                 bands: Sequence[tuple[float, float]] | None = None,
                 damping_start: float = DEFAULT_DAMPING_START,
                 lag_bounds: tuple[float, float] = DEFAULT_LAG_BOUNDS,
                 scan_points: int = DEFAULT_SCAN_POINTS, resolve_z: float = DEFAULT_RESOLVE_Z,
                 whiten_order: int = DEFAULT_WHITEN_ORDER, max_nfev: int = 100,
                 keep_initial_damping: bool = False,
                 noise_filters: Sequence[NDArray[np.float64]] | None = None) -> RefinedFit:
    """Fit one modal model to several windows of the same plant at once (the pooled estimate).

    Like :func:`refine_fit`, on every window's average, with omega_i, zeta_i, the lag, k0 and
    k_i shared and each window's initial conditions and offset its own. Windows of different
    target angles, move counts and lengths may be mixed. A weakly excited mode that no single
    window resolves is resolved by the windows together.

    Args:
        windows: ``(current, encoder)`` records per window, each (M_w, N_w) (M_w > 2).
        sample_period: Sampling period [s].
        initial: Starting model (e.g. :func:`galvo_sysid.ident.identify.pool_results` of the
            windows' single fits).
        lag_time_constant: Starting (or fixed) amplifier lag [s].
        estimate_lag: Estimate the lag.
        computation_delay: Whole samples of computation delay.
        dead_time: Extra pure delay [s].
        bands: Frequency band per mode [rad/s] (default
            :func:`galvo_sysid.ident.decompose.default_bands`).
        damping_start: Damping ratio the modes start from.
        lag_bounds: Bounds of the lag [sample periods].
        scan_points: Frequencies per band of the joint starting scan (0: none).
        resolve_z: Significance below which a mode counts as not resolved.
        whiten_order: Order of each window's AR noise model for the prewhitened second stage.
        noise_filters: Fixed prewhitening filters, one per window (e.g.
            :func:`window_noise_filters`): the fit is then one prewhitened stage, and fits of
            different models to the same windows have comparable ``chi2``.
        max_nfev: Iteration limit of each stage.
        keep_initial_damping: Start from ``initial`` as it is (its damping ratios too) rather
            than from the continuation's ``damping_start``: for a good start, e.g. the pooled
            single-window results. If the scan moves no frequency by over 1 %, the first
            (ordinary least-squares) stage is left out: the noise models of the prewhitened
            stage are estimated at the start (the moves' deviations from their mean hardly
            depend on the model). Otherwise the scanned start (at ``damping_start``) is tried
            too, as without this option.

    Returns:
        The joint fit (``initial_conditions`` empty, ``offset`` nan: they are per window;
        ``fit_percent`` over all windows' filtered averaged outputs).

    Raises:
        InvalidDataError: No windows, or a window with bad records or fewer than 3 moves.
        ConfigurationError: Bad options.
        IdentificationError: The fit failed or a resolved mode ended at its band edge.
    """
    if not windows:
        raise InvalidDataError('no windows to fit')
    if not (np.isfinite(sample_period) and sample_period > 0):
        raise ConfigurationError(f'sample_period must be positive and finite, got {sample_period}')
    if not 0 < damping_start < _MAX_DAMPING:
        raise ConfigurationError(f'damping_start must be in (0, {_MAX_DAMPING})')
    if not 0 <= lag_bounds[0] < lag_bounds[1]:
        raise ConfigurationError(f'bad lag_bounds {lag_bounds}')
    band_list = _bands_for(initial, bands, sample_period)
    delay, frac = _split_delay(computation_delay, dead_time, sample_period)
    n = initial.n_modes
    records = []
    for j, (current, encoder) in enumerate(windows):
        try:
            cur, enc = _validate(current, encoder)
        except InvalidDataError as exc:
            raise InvalidDataError(f'window {j}: {exc}') from exc
        if cur.shape[0] < 3:
            raise InvalidDataError(f'window {j}: a joint fit needs at least 3 moves per window')
        if not np.any(cur.mean(axis=0) - cur[:, 0].mean()):
            raise InvalidDataError(f'window {j}: no excitation (constant averaged current)')
        records.append((cur, enc))
    problems = [_Problem(cur.mean(axis=0), enc.mean(axis=0), sample_period=sample_period,
                         delay=delay, fraction=frac, n_modes=n,
                         fixed_lag=None if estimate_lag else lag_time_constant)
                for cur, enc in records]
    if noise_filters is not None:
        if len(noise_filters) != len(problems):
            raise ConfigurationError('one noise filter per window')
        for prob, filt in zip(problems, noise_filters, strict=True):
            prob.set_whitening(np.asarray(filt, dtype=float))
        noise = np.array([_window_noise_rms(cur, enc, prob) for (cur, enc), prob
                          in zip(records, problems, strict=True)])
        whiten_order = 0  # already whitened: one stage
    else:
        noise = np.array([_window_noise_rms(cur, enc) for cur, enc in records])
    noise[~(noise > 0)] = float(np.max(noise)) if np.any(noise > 0) else 1.0
    joint = _JointProblem(problems, 1.0 / noise)
    lower, upper = _bounds(band_list, estimate_lag, lag_bounds)
    x_init = _start_vector(joint, initial, lower, upper, damping_start=damping_start,
                           lag=lag_time_constant, lag_bounds=lag_bounds)
    omega0, zeta0, lag0 = joint.unpack(x_init)
    omega_scan = omega0.copy()
    if scan_points > 1:
        zeta_init = np.clip(np.array(initial.damping_ratios, dtype=float), 1e-4,
                            0.5 * _MAX_DAMPING)
        for i, (lo, hi) in enumerate(band_list):
            grid = np.geomspace(lo * 1.01, hi / 1.01, scan_points)
            w_c, z_c = _scan_candidates(omega_scan[i], zeta_init[i], grid, damping_start)
            gains = sum(wt * wt * prob.scan_gains(i, omega_scan, zeta_init, lag0, w_c, z_c)
                        for prob, wt in zip(problems, joint.weights, strict=True))
            omega_scan[i] = float(w_c[int(np.argmax(gains))])
    moved = bool(omega0.size) and np.max(np.abs(np.log(omega_scan / omega0))) > 0.01
    if keep_initial_damping:
        span = upper - lower
        as_is = joint.pack(np.array(initial.natural_frequencies, dtype=float),
                           np.clip(np.array(initial.damping_ratios, dtype=float), _MIN_DAMPING,
                                   0.5 * _MAX_DAMPING), lag0)
        starts = [np.clip(as_is, lower + 1e-3 * span, upper - 1e-3 * span)]
        if moved:
            starts.append(joint.pack(omega_scan, zeta0, lag0))
    else:
        starts = [joint.pack(omega_scan, zeta0, lag0)]
        if moved:
            starts.append(x_init)
    # Stage 1 only has to find the basin when the prewhitened stage 2 polishes afterwards.
    tol = _STAGE1_TOL if whiten_order > 0 else 1e-8

    def polish(x0: NDArray[np.float64], tol: float = 1e-8) -> Any:
        try:
            return least_squares(joint.residual, x0, jac=joint.jacobian, bounds=(lower, upper),
                                 x_scale='jac', max_nfev=max_nfev, method='trf', ftol=tol,
                                 xtol=tol)
        except (ValueError, LinAlgError) as exc:
            raise IdentificationError(f'joint refined fit failed: {exc}') from exc

    best = None
    for x0 in starts if len(starts) > 1 or not keep_initial_damping or whiten_order == 0 else ():
        sol = polish(x0, tol)
        edge = _edge_mode(joint.unpack(sol.x), band_list)
        key = (edge is not None, float(sol.cost))
        if best is None or key < best[0]:
            best = (key, sol)
    x = best[1].x if best is not None else starts[0]
    if whiten_order > 0:
        weights = []
        for prob, coef, (cur, enc) in zip(problems, joint.coefficients(x), records,
                                          strict=True):
            dev = _per_move_deviations(prob, x, coef, cur, enc)
            prob.set_whitening(_whitening_filter(dev, whiten_order,
                                                 float(np.sqrt(np.mean(prob.yf_raw**2)))))
            wdev = prob.apply_whitening(dev, axis=1)
            weights.append(1.0 / max(float(np.sqrt(np.mean(wdev**2) / (cur.shape[0] - 1))),
                                     1e-300))
        joint.set_weights(weights)
        x = polish(x).x
    edge = _edge_mode(joint.unpack(x), band_list)
    omega, zeta, lag = joint.unpack(x)
    coefs = joint.coefficients(x)
    shared = coefs[0][: 1 + n]
    cov = _joint_covariance(joint, x, coefs, records)
    k_std = np.sqrt(np.clip(np.diag(cov)[1: 1 + n], 0.0, None))
    unresolved = tuple(i for i in range(n) if abs(shared[1 + i]) < resolve_z * k_std[i])
    if edge is not None and edge not in unresolved:
        lo, hi = band_list[edge]
        raise ModelMismatchError(
            f'no physical mode {edge + 1} in the band {lo:.4g}..{hi:.4g} rad/s (the joint fit '
            f'ended at omega = {omega[edge]:.4g} rad/s, zeta = {zeta[edge]:.3g})')
    _inflate_unresolved(cov, unresolved, band_list, n)
    res2 = den2 = 0.0
    for prob, coef in zip(problems, coefs, strict=True):
        r = prob.yf_raw - prob.columns(omega, zeta, lag, whitened=False) @ coef
        res2 += float(r @ r)
        den2 += float(np.sum((prob.yf_raw - prob.yf_raw.mean()) ** 2))
    model_out = ModalModel(k0=float(shared[0]), residues=tuple(float(c) for c in shared[1:]),
                           natural_frequencies=tuple(float(w) for w in omega),
                           damping_ratios=tuple(float(z) for z in zeta))
    names = (*model_out.parameters(), *(('lag',) if estimate_lag else ()))
    return RefinedFit(
        model=model_out, lag_time_constant=float(lag), lag_estimated=estimate_lag,
        computation_delay=computation_delay, dead_time=float(dead_time),
        sample_period=float(sample_period), parameter_names=tuple(names), covariance=cov,
        covariance_method='sandwich', initial_conditions=(), offset=float('nan'),
        fit_percent=100.0 * (1.0 - math.sqrt(res2 / den2)) if den2 > 0 else float('nan'),
        cost=res2, n_evaluations=joint.n_eval, starts=len(starts),
        unresolved_modes=tuple(i + 1 for i in unresolved),
        chi2=float(np.sum(joint.solve(x)[1] ** 2)),
        rows=int(sum(prob.yf.size for prob in problems)))


def _joint_covariance(joint: _JointProblem, x: NDArray[np.float64],
                      coefs: Sequence[NDArray[np.float64]],
                      records: Sequence[tuple[NDArray[np.float64], NDArray[np.float64]]]) -> (
                          NDArray[np.float64]):
    """Sandwich covariance of the shared parameters, each window's nuisance partialled out."""
    n = joint.n_modes
    omega, zeta, lag = joint.unpack(x)
    phys = np.concatenate([omega, zeta, [joint.t]])
    a_mat: NDArray[np.float64] | None = None
    b_mat: NDArray[np.float64] | None = None
    for prob, wt, coef, (cur, enc) in zip(joint.problems, joint.weights, coefs, records,
                                          strict=True):
        phi = prob.columns(omega, zeta, lag)
        derivs = prob.column_derivatives(x, phi)
        jac = np.empty((phi.shape[0], 1 + n + len(derivs)))
        jac[:, : 1 + n] = phi[:, : 1 + n]
        for j, (idx, dphi) in enumerate(derivs):
            jac[:, 1 + n + j] = (dphi @ coef[idx]) / phys[j]
        nuis = phi[:, 1 + n:]
        scale = np.linalg.norm(nuis, axis=0)
        scale[scale == 0] = 1.0
        q, _ = qr(nuis / scale, mode='economic', check_finite=False)
        jt = wt * (jac - q @ (q.T @ jac))
        dev = prob.apply_whitening(_per_move_deviations(prob, x, coef, cur, enc), axis=1)
        g = wt * (dev @ jt)
        m = dev.shape[0]
        a_w = jt.T @ jt
        b_w = g.T @ g / (m * (m - 1))
        a_mat = a_w if a_mat is None else a_mat + a_w
        b_mat = b_w if b_mat is None else b_mat + b_w
    assert a_mat is not None
    assert b_mat is not None
    d = np.sqrt(np.diag(a_mat))
    d[d == 0] = 1.0
    try:
        a_inv = np.linalg.inv(a_mat / np.outer(d, d)) / np.outer(d, d)
    except np.linalg.LinAlgError as exc:
        raise IdentificationError(f'singular joint Jacobian: {exc}') from exc
    return np.asarray(a_inv @ b_mat @ a_inv, dtype=np.float64)
