"""The refined fit's regressors: exact zero-order-hold responses of the modes, filtered.

Every block is a sum of first-order pole terms whose impulse responses are closed-form
powers of the discrete poles (partial fractions; the computation delay, a fractional dead
time and the amplifier lag ``1 / (1 + s T_l)`` included), convolved with the
(1 - q^-1)^2-filtered input by FFT, all blocks in one batch. The data are filtered the same
way, which removes the start angle, a slow drift and the rigid-body initial velocity; a fit
uses the rows from :data:`FIRST_ROW` on.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from scipy import fft as sp_fft

from galvo_sysid.errors import ConfigurationError, InvalidDataError
from galvo_sysid.filters import fir
from galvo_sysid.model.dynamics import split_delay

if TYPE_CHECKING:
    from collections.abc import Sequence
    from typing import TypeAlias

    from numpy.typing import ArrayLike, NDArray

    Floats: TypeAlias = Sequence[float] | NDArray[np.float64]

__all__ = [
    'FIRST_ROW',
    'Regressors',
    'filtered_input',
    'free_responses',
    'modal_regressors',
    'powers',
    'pulse_numerator',
    'rigid_taps',
    'second_difference',
]

FIRST_ROW = 2
"""(1 - q^-1)^2 needs two past samples: the first row of any filtered record."""

_MAX_DECAY = 700.0  # exp(-700) is about 1e-304: a lag's decay per sample beyond it is 0


def second_difference(x: ArrayLike) -> NDArray[np.float64]:
    """Return (1 - q^-1)^2 x along the last axis, x held at its first value before the record."""
    arr = np.asarray(x, dtype=float)
    d = np.diff(arr, n=1, axis=-1, prepend=arr[..., :1])
    return np.asarray(np.diff(d, n=1, axis=-1, prepend=0.0 * d[..., :1]), dtype=np.float64)


def pulse_numerator(p: complex, fraction: float, t: float) -> tuple[complex, complex]:
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


def powers(omega: Floats, zeta: Floats, n: int,
           sample_period: float) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    """Continuous poles p_j of the modes and E[j, k] = exp(p_j T k), k = 0 .. n-1."""
    w = np.asarray(omega, dtype=float)
    z = np.asarray(zeta, dtype=float)
    p = -z * w + 1j * w * np.sqrt(np.maximum(1.0 - z * z, 1e-12))
    # powers of the discrete pole by doubling (E[:, k:2k] = E[:, :k] lambda^k): far cheaper
    # than n complex exponentials or a running product, and accurate to ~n eps
    e = np.empty((p.size, n), dtype=np.complex128)
    e[:, 0] = 1.0
    if n > 1:
        e[:, 1] = np.exp(p * sample_period)
    k = 2
    while k < n:
        c = min(k, n - k)
        np.multiply(e[:, :c], (e[:, k - 1] * e[:, 1])[:, None], out=e[:, k: k + c])
        k += c
    return p, e


def filtered_input(u: NDArray[np.float64], pre: ArrayLike | None = None) -> tuple[
        NDArray[np.float64], NDArray[np.float64]]:
    """``(u0, uf)`` of input records u (..., N): u less its level ``pre`` before the record
    (default: its first sample), and (1 - q^-1)^2 u with that level held before it (what
    :class:`Regressors` convolves)."""  # noqa: D205, D209
    before = u[..., :1] if pre is None else np.broadcast_to(
        np.asarray(pre, dtype=float), u[..., :1].shape)
    d1 = np.diff(u, axis=-1, prepend=before)
    uf = np.asarray(np.diff(d1, axis=-1, prepend=0.0 * d1[..., :1]), dtype=np.float64)
    return np.asarray(u - before, dtype=np.float64), uf


def rigid_taps(*, sample_period: float, delay: int, fraction: float) -> tuple[
        NDArray[np.float64], NDArray[np.float64]]:
    """FIR taps of the rigid body's double and single integrator behind the pure delay
    (``delay`` samples and ``fraction`` of one), filtered by (1 - q^-1)^2, on the input less
    its level before the record (:attr:`Regressors.rigid_double`, ``rigid_single``)."""  # noqa: D205, D209
    f, t = fraction, sample_period
    pad = [0.0] * delay
    double = [*pad, 0.0, t * t * (1 - f) ** 2 / 2, t * t * (0.5 + f - f * f), t * t * f * f / 2]
    single = [*pad, 0.0, t * (1 - f), t * (2 * f - 1), -t * f]
    return np.array(double, dtype=float), np.array(single, dtype=float)


class Regressors:
    """Filtered exact-ZOH responses of the unit modes to a fixed input (records (..., N)).

    The input before the record is taken as ``pre`` (default: the record's first sample),
    held constant: the plant is at rest in it.

    Every block is a sum of first-order pole terms whose impulse responses are closed-form
    powers of the discrete poles; they are convolved with the filtered input by FFT, all
    blocks in one batch.
    """

    def __init__(self, u: NDArray[np.float64], *, sample_period: float, delay: int,
                 fraction: float, pre: ArrayLike | None = None) -> None:
        if delay < 0:
            raise ConfigurationError('the input delay must be >= 0')
        self.t = sample_period
        self.delay = delay
        self.fraction = fraction
        self.n = u.shape[-1]
        self.nfft = int(sp_fft.next_fast_len(2 * self.n - 1, real=True))  # no wrap-around
        u0, self.uf = filtered_input(u, pre)
        self.uf_hat = sp_fft.rfft(self.uf, self.nfft, axis=-1)
        self._lag_cache: tuple[float, NDArray[np.float64]] | None = None
        self._taps_cache: tuple[NDArray[np.float64], NDArray[np.complex128]] | None = None
        # Fixed FIR parts of the rigid body (double and single integrator, see rigid()).
        double, single = rigid_taps(sample_period=sample_period, delay=delay,
                                    fraction=fraction)
        self.rigid_double = fir(double, u0)
        self.rigid_single = fir(single, u0)

    def transform(self, h: NDArray[np.float64]) -> NDArray[np.complex128]:
        """The transform of impulse responses h (m, N) that :meth:`convolve` takes: the same
        for every record of N samples (several windows' scans share it)."""  # noqa: D205, D209
        return np.asarray(sp_fft.rfft(h, self.nfft, axis=-1), dtype=np.complex128)

    def convolve(self, h: NDArray[np.float64]) -> NDArray[np.float64]:
        """Responses to the filtered input of the impulse responses h (m, N): (m,) + u.shape."""
        return self.convolve_transformed(self.transform(h))

    def convolve_transformed(self, hh: NDArray[np.complex128]) -> NDArray[np.float64]:
        """:meth:`convolve` of the impulse responses whose :meth:`transform` is ``hh``."""
        prod = hh * self.uf_hat if self.uf_hat.ndim == 1 else hh[:, None, :] * self.uf_hat[None]
        return np.asarray(sp_fft.irfft(prod, self.nfft, axis=-1)[..., : self.n],
                          dtype=np.float64)

    def convolve_filtered(self, hh: NDArray[np.complex128], taps: NDArray[np.float64]) -> tuple[
            NDArray[np.float64], NDArray[np.float64]]:
        """:meth:`convolve` for one record of the impulse responses (m, N) whose
        :meth:`transform` is ``hh``, and the same filtered by the FIR ``taps``: both (m, N).

        The filtered responses are exact from sample ``taps.size - 1`` on (earlier samples
        may hold the wrap-around of the circular convolution).
        """  # noqa: D205
        if self.uf_hat.ndim != 1:
            raise ConfigurationError('convolve_filtered needs a single input record')
        cached = self._taps_cache  # read once (see lag_impulse)
        if cached is None or cached[0] is not taps:
            cached = self._taps_cache = (taps, sp_fft.rfft(taps, self.nfft))
        prod = np.empty((2, *hh.shape), dtype=hh.dtype)
        np.multiply(hh, self.uf_hat, out=prod[0])
        np.multiply(prod[0], cached[1], out=prod[1])
        both = sp_fft.irfft(prod, self.nfft, axis=-1, overwrite_x=True)[..., : self.n]
        return np.asarray(both[0], dtype=np.float64), np.asarray(both[1], dtype=np.float64)

    def _pulse(self, p: NDArray[np.complex128]) -> tuple[NDArray[np.complex128],
                                                          NDArray[np.complex128]]:
        """Vectorised :func:`pulse_numerator` for nonzero poles p."""
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
            h[:, d + 1] = 2.0 * a1.real
        if d + 2 < n:
            # a1 E[k-1-d] + a2 E[k-2-d] = (a1 lambda + a2) E[k-2-d]: one product per sample
            a = 2.0 * (a1 * e[:, 1] + a2)
            h[:, d + 2:] = (a[:, None] * e[:, : n - d - 2]).real
        return h

    def lag_impulse(self, lag: float) -> NDArray[np.float64]:
        """Impulse response of the lag pole term 1/(s + 1/T_l) (zeros without lag).

        The last one is cached (each evaluation asks for the same lag several times); the
        caller must not modify the returned array.
        """
        cached = self._lag_cache  # read once: a Regressors may be shared between threads
        if cached is not None and cached[0] == lag:
            return cached[1]
        h = np.zeros(self.n)
        if lag > 0:
            g1, g2 = pulse_numerator(-1.0 / lag, self.fraction, self.t)
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
        p, e_all = powers(w, z, self.n, self.t) if e is None else (
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
                     lag_time_constant: float = 6e-6, computation_delay: int = 1,
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
    delay, frac = split_delay(computation_delay * sample_period + dead_time, sample_period)
    regs = Regressors(u_arr, sample_period=sample_period, delay=delay, fraction=frac)
    return regs.all(natural_frequencies, damping_ratios, lag_time_constant)


def free_responses(omega: Floats, zeta: Floats, n: int, sample_period: float,
                    e: NDArray[np.complex128] | None = None, *,
                    first: int = FIRST_ROW) -> NDArray[np.float64]:
    """Free-response columns of every mode: Re and Im of exp(p_i T k) over rows k >= first.

    Shape (2 n_modes, n - first); ``e`` is :func:`powers`' E if already computed.
    """
    if e is None:
        _, e = powers(omega, zeta, n, sample_period)
    out = np.empty((2 * e.shape[0], n - first))
    out[0::2] = e[:, first:].real
    out[1::2] = e[:, first:].imag
    return out
