"""ARX models fitted by least squares (paper Sec. III, Eq. 3-7).

The model is::

    y[k] + a_1 y[k-1] + ... + a_na y[k-na] = b_1 u[k-1] + ... + b_nb u[k-nb] + w[k]

and theta = [a_1 .. a_na, b_1 .. b_nb] minimises the mean squared equation error over the
rows k = n .. N-1 (n = max(na, nb), so every regressor holds measured samples). The paper
solves the normal equations R theta = f (``solver='normal'``); the QR factorisation of the
regressor matrix (``solver='qr'``) gives the same minimiser with about the square root of the
condition number. Either way :attr:`ArxModel.cond` reports cond(R) of the normal equations.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import scipy.linalg

from galvo_sysid.errors import ConfigurationError, IdentificationError, InvalidDataError
from galvo_sysid.filters import fir, lfilter

if TYPE_CHECKING:
    from numpy.typing import ArrayLike, NDArray

__all__ = [
    'MAX_ORDER',
    'ArxModel',
    'fit_arx',
    'min_data_length',
    'regressors',
]

MAX_ORDER = 60
"""Largest accepted ARX order na or nb."""


def min_data_length(na: int, nb: int) -> int:
    """Fewest samples :func:`fit_arx` accepts: twice as many equations as parameters.

    The regression has N - max(na, nb) rows and na + nb unknowns.
    """
    return max(na, nb) + 2 * (na + nb)


def _check_orders(na: int, nb: int) -> None:
    for name, n in (('na', na), ('nb', nb)):
        if not isinstance(n, int | np.integer) or not 1 <= n <= MAX_ORDER:
            raise ConfigurationError(f'{name} must be an integer in 1..{MAX_ORDER}, got {n!r}')


@dataclass(frozen=True)
class ArxModel:
    """A fitted ARX model A[q] y = B[q] u + w.

    Attributes:
        a: a_1 .. a_na.
        b: b_1 .. b_nb.
        sample_period: Sample period T [s].
        cond: Condition number of the normal-equation matrix R (2-norm).
        residual_variance: Sum of squared equation errors / (rows - parameters).
        n_samples: Samples of data used.
        solver: ``'normal'`` or ``'qr'``.
    """

    a: tuple[float, ...]
    b: tuple[float, ...]
    sample_period: float
    cond: float
    residual_variance: float
    n_samples: int
    solver: str = 'normal'

    @property
    def na(self) -> int:
        """Denominator order."""
        return len(self.a)

    @property
    def nb(self) -> int:
        """Numerator order."""
        return len(self.b)

    @property
    def den(self) -> NDArray[np.float64]:
        """A as [1, a_1, .., a_na] in powers of z^-1."""
        return np.array([1.0, *self.a])

    @property
    def num(self) -> NDArray[np.float64]:
        """B as [0, b_1, .., b_nb] in powers of z^-1."""
        return np.array([0.0, *self.b])

    def transfer_function(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Return (num, den) in descending powers of z, both of degree max(na, nb)."""
        n = max(self.na, self.nb)
        num = np.zeros(n + 1)
        den = np.zeros(n + 1)
        num[: self.nb + 1] = self.num
        den[: self.na + 1] = self.den
        return num, den

    def poles(self) -> NDArray[np.complex128]:
        """Return the poles in the z plane (including poles at 0 when nb > na)."""
        return np.asarray(np.roots(self.transfer_function()[1]), dtype=np.complex128)

    def frequency_response(self, omega: ArrayLike) -> NDArray[np.complex128]:
        """Return B(e^{-j w T}) / A(e^{-j w T}) at angular frequencies ``omega`` [rad/s]."""
        zinv = np.exp(-1j * np.asarray(omega, dtype=float) * self.sample_period)
        num = np.polyval(self.num[::-1], zinv)
        den = np.polyval(self.den[::-1], zinv)
        return np.asarray(num / den, dtype=np.complex128)

    def simulate(self, u: ArrayLike) -> NDArray[np.float64]:
        """Simulate y = B/A u from rest along the last axis of ``u``."""
        return np.asarray(lfilter(self.num, self.den, np.asarray(u, dtype=float)),
                          dtype=float)

    def predict(self, u: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
        """One-step-ahead prediction from measured ``u`` and ``y`` (1-D), zero before k = 0."""
        u_arr = np.asarray(u, dtype=float)
        y_arr = np.asarray(y, dtype=float)
        if u_arr.shape != y_arr.shape or u_arr.ndim != 1:
            raise InvalidDataError('u and y must be 1-D of equal length')
        return np.asarray(fir(self.num, u_arr) - fir(np.array([0.0, *self.a]), y_arr),
                          dtype=float)


def regressors(u: NDArray[np.float64], y: NDArray[np.float64], na: int,
               nb: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Return (Phi, target): rows phi[k]^T = [-y[k-1] .. -y[k-na], u[k-1] .. u[k-nb]]."""
    n = max(na, nb)
    rows = y.size - n
    phi = np.empty((rows, na + nb))
    for i in range(1, na + 1):
        phi[:, i - 1] = -y[n - i: n - i + rows]
    for i in range(1, nb + 1):
        phi[:, na + i - 1] = u[n - i: n - i + rows]
    return phi, y[n:]


def fit_arx(u: ArrayLike, y: ArrayLike, *, sample_period: float, na: int = 15, nb: int = 15,
            solver: str = 'normal') -> ArxModel:
    """Fit an ARX(na, nb) model by least squares.

    Args:
        u: Input, shape (N,).
        y: Output, shape (N,).
        sample_period: Sample period T [s].
        na: Order of A, 1..60.
        nb: Order of B, 1..60.
        solver: ``'normal'``: the paper's normal equations R theta = f (Eq. 6-7);
            ``'qr'``: economic QR of the regressor matrix.

    Returns:
        The fitted model.

    Raises:
        ConfigurationError: Bad orders, solver or sample period.
        InvalidDataError: Shapes differ, too short, NaN/Inf.
        IdentificationError: R is singular (e.g. no excitation).
    """
    _check_orders(na, nb)
    if solver not in ('normal', 'qr'):
        raise ConfigurationError(f"solver must be 'normal' or 'qr', got {solver!r}")
    if not (np.isfinite(sample_period) and sample_period > 0):
        raise ConfigurationError(f'sample_period must be positive and finite, got {sample_period}')
    try:
        u_arr = np.asarray(u, dtype=float)
        y_arr = np.asarray(y, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InvalidDataError(f'u and y must be numeric arrays: {exc}') from exc
    if u_arr.ndim != 1 or y_arr.shape != u_arr.shape:
        raise InvalidDataError(f'u and y must be 1-D of equal length, got shapes {u_arr.shape} '
                               f'and {y_arr.shape}')
    need = min_data_length(na, nb)
    if u_arr.size < need:
        raise InvalidDataError(f'ARX({na}, {nb}) needs at least {need} samples, got {u_arr.size}')
    if not (np.all(np.isfinite(u_arr)) and np.all(np.isfinite(y_arr))):
        raise InvalidDataError('u or y contains NaN or Inf')
    phi, target = regressors(u_arr, y_arr, na, nb)
    rows, m = phi.shape
    singular = 'regression is singular (cond(R) infinite): is the input exciting?'
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore', scipy.linalg.LinAlgWarning)
            if solver == 'normal':
                r = phi.T @ phi / rows
                f = phi.T @ target / rows
                sv = np.linalg.svd(r, compute_uv=False)
                if not sv[-1] > 0:
                    raise IdentificationError(singular)
                cond = float(sv[0] / sv[-1])
                theta = np.asarray(scipy.linalg.solve(r, f, assume_a='sym', check_finite=False))
            else:
                q, rr = scipy.linalg.qr(phi, mode='economic', check_finite=False)
                sv = np.linalg.svd(rr, compute_uv=False)
                if not sv[-1] > 0:
                    raise IdentificationError(singular)
                cond = float((sv[0] / sv[-1]) ** 2)
                theta = np.asarray(scipy.linalg.solve_triangular(rr, q.T @ target,
                                                                 check_finite=False))
    except (np.linalg.LinAlgError, scipy.linalg.LinAlgError) as exc:
        raise IdentificationError(f'{singular} ({exc})') from exc
    if not np.all(np.isfinite(theta)):
        raise IdentificationError('least-squares solution is not finite (singular regression)')
    resid = target - phi @ theta
    return ArxModel(a=tuple(float(v) for v in theta[:na]),
                    b=tuple(float(v) for v in theta[na:]),
                    sample_period=float(sample_period), cond=cond,
                    residual_variance=float(resid @ resid / max(rows - m, 1)),
                    n_samples=int(u_arr.size), solver=solver)
