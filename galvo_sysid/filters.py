"""Digital filtering without :mod:`scipy.signal`, for every part of the package.

Importing :mod:`scipy.signal` takes 0.3-1.7 s (it pulls in :mod:`scipy.stats` and
:mod:`scipy.optimize`), the larger part of a process start (``galvo-sysid identify``, the
driver node, ``galvo-sysid simulate``), for the two functions the package needs:

- :func:`lfilter`: ``y = B(q^-1) / A(q^-1) x`` along an axis, from rest or from an initial
  state, as ``scipy.signal.lfilter(b, a, x, axis, zi)``: the FIR part by shifted sums,
  the recursive part as the banded lower-triangular Toeplitz system ``A y = B x`` solved by
  LAPACK's ``dtbtrs`` (forward substitution, every record at once);
- :func:`bilinear`: the bilinear (Tustin) transform of a continuous transfer function, as
  ``scipy.signal.bilinear``.

Both agree with :mod:`scipy.signal` to rounding; the first-order filter of the simulator's
noise to the bit (``test/test_filters.py``). A first-order filter of many short rows is 4x
slower than :mod:`scipy.signal`'s (LAPACK's band solver steps one element at a time): the
discrepancy plant, whose analyses take seconds, keeps :mod:`scipy.signal`.
A top-level module (below ``model``): the simulator and the identification, on one layer,
both use it.
"""

from __future__ import annotations

from math import comb
from typing import TYPE_CHECKING

import numpy as np
from scipy.linalg.lapack import dtbtrs

from galvo_sysid.errors import ConfigurationError

if TYPE_CHECKING:
    from numpy.typing import ArrayLike, NDArray

__all__ = ['bilinear', 'fir', 'lfilter']


def _coefficients(c: ArrayLike, name: str) -> NDArray[np.float64]:
    arr = np.atleast_1d(np.asarray(c, dtype=float))
    if arr.ndim != 1 or arr.size == 0:
        raise ConfigurationError(f'{name} must be a non-empty 1-D sequence of coefficients')
    return arr


def fir(b: ArrayLike, x: ArrayLike, *, axis: int = -1) -> NDArray[np.float64]:
    """Return ``sum_j b_j x[k - j]`` along ``axis``, x zero before the record.

    Short filters on many rows are the use (prewhitening the fit's columns): the sum of
    shifted slices, along the first or the last axis without moving axes.
    """
    b_arr = _coefficients(b, 'b')
    xs = np.asarray(x, dtype=float)
    ax = axis % xs.ndim
    n = xs.shape[ax]
    out = np.zeros_like(xs)
    dst = [slice(None)] * xs.ndim
    src = [slice(None)] * xs.ndim
    for j, bj in enumerate(b_arr):
        if bj != 0 and j < n:
            dst[ax], src[ax] = slice(j, None), slice(0, n - j)
            out[tuple(dst)] += bj * xs[tuple(src)]
    return out


def lfilter(b: ArrayLike, a: ArrayLike, x: ArrayLike, *, axis: int = -1,
            zi: ArrayLike | None = None) -> NDArray[np.float64]:
    """Filter ``x`` by ``B(q^-1) / A(q^-1)`` along ``axis``, from rest or from a state.

    Args:
        b: Numerator coefficients in powers of q^-1.
        a: Denominator coefficients in powers of q^-1, ``a[0] != 0``.
        x: Data; filtered along ``axis``.
        axis: The time axis.
        zi: The filter's initial state as ``scipy.signal.lfilter``'s (transposed direct
            form II, of the filter normalised to ``a[0] == 1``), ``max(len(a), len(b)) - 1``
            values, the same for every record; None: from rest. It adds ``zi[k]`` to the
            right side of ``A y = B x`` at sample ``k``.

    Returns:
        The filtered data, same shape as ``x`` (``scipy.signal.lfilter(b, a, x, axis=axis,
        zi=zi)[0]`` to rounding; only the output, not the final state).

    Raises:
        ConfigurationError: Empty or multi-dimensional coefficients, ``a[0] == 0`` or a
            state of the wrong length.
    """
    b_arr = _coefficients(b, 'b')
    a_arr = _coefficients(a, 'a')
    if a_arr[0] == 0:
        raise ConfigurationError('a[0] must not be 0')
    order = max(a_arr.size, b_arr.size) - 1
    state = None if zi is None else np.atleast_1d(np.asarray(zi, dtype=float))
    if state is not None and (state.ndim != 1 or state.size != order):
        raise ConfigurationError(f'zi must hold {order} value(s) (the filter order), got '
                                 f'shape {state.shape}')
    b_arr = b_arr / a_arr[0]
    a_arr = np.trim_zeros(a_arr / a_arr[0], 'b')
    xs = np.moveaxis(np.asarray(x, dtype=float), axis, -1)
    v = fir(b_arr, xs)
    n = xs.shape[-1]
    if state is not None and n > 0:
        head = min(order, n)
        v[..., :head] += state[:head]
    if a_arr.size == 1 or n == 0 or v.size == 0:
        return np.moveaxis(v, -1, axis)
    a_arr = a_arr[:n]
    # A y = v, A lower triangular banded Toeplitz; LAPACK band storage ab[i, j] = A[j + i, j]
    band = np.repeat(a_arr[:, None], n, axis=1)
    rhs = np.asfortranarray(v.reshape(-1, n).T)
    y, info = dtbtrs(band, rhs, uplo='L')
    if info != 0:  # cannot happen with a[0] == 1; say it rather than return garbage
        raise ConfigurationError(f'LAPACK dtbtrs failed (info {info})')
    return np.moveaxis(np.asarray(y, dtype=float).T.reshape(v.shape), -1, axis)


def bilinear(b: ArrayLike, a: ArrayLike, *, fs: float) -> tuple[NDArray[np.float64],
                                                                 NDArray[np.float64]]:
    """Bilinear transform ``s = 2 fs (1 - z^-1) / (1 + z^-1)`` of ``B(s) / A(s)``.

    Args:
        b: Numerator in descending powers of s.
        a: Denominator in descending powers of s.
        fs: Sampling frequency [Hz] (or a prewarped equivalent).

    Returns:
        ``(bz, az)`` in powers of z^-1, both of length ``max(len(b), len(a))``, normalised
        to ``az[0] == 1`` (as ``scipy.signal.bilinear(b, a, fs=fs)``).

    Raises:
        ConfigurationError: Empty coefficients, ``fs <= 0`` or a transform with ``az[0] == 0``.
    """
    b_arr = _coefficients(b, 'b')
    a_arr = _coefficients(a, 'a')
    if not (np.isfinite(fs) and fs > 0):
        raise ConfigurationError(f'fs must be positive and finite, got {fs}')
    m = max(b_arr.size, a_arr.size) - 1
    k = 2.0 * fs

    def transform(c: NDArray[np.float64]) -> NDArray[np.float64]:
        """sum_p c_p (2 fs)^p (1 - w)^p (1 + w)^(m - p), coefficients of w = z^-1."""
        out = np.zeros(m + 1)
        for p, cp in enumerate(c[::-1]):  # c_p: coefficient of s^p
            if cp == 0:
                continue
            minus = np.array([comb(p, i) * (-1.0) ** i for i in range(p + 1)])
            plus = np.array([float(comb(m - p, i)) for i in range(m - p + 1)])
            out += cp * k**p * np.convolve(minus, plus)
        return out

    bz, az = transform(b_arr), transform(a_arr)
    if az[0] == 0:
        raise ConfigurationError('the transformed denominator has a zero leading coefficient')
    return bz / az[0], az / az[0]
