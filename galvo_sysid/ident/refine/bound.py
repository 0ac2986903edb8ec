"""The Cramer-Rao bound of windows at given parameters (no fit): what data could tell.

:func:`crlb_at` evaluates the bound that the refined fit reports (the Fisher matrix with the
stationary noise the moves' scatter shows, their own nuisance taken out, every nuisance
parameter partialled out: :func:`~galvo_sysid.ident.refine.joint.covariance`) at parameters
one gives, e.g.
the true ones of a simulated scanner: the information a move mix, a number of moves and a
dither carry, before any data are recorded (:mod:`galvo_sysid.ident.plan`). The shared
linear parameters are solved from the data at the given nonlinear ones.

:func:`crlb_known_noise` is the same bound with the noise's autocovariance given rather than
estimated: the bound with the true noise spectrum where that is known (a simulator's,
:func:`galvo_sysid.sim.noise.residual_noise_autocovariance`), the yardstick the estimated one
is checked against.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from scipy.linalg import LinAlgError, cholesky, solve_triangular

from galvo_sysid.errors import InvalidDataError
from galvo_sysid.ident.refine.joint import (
    JointProblem,
    _inverse,
    _jacobian,
    _partialled,
    covariance,
)
from galvo_sysid.ident.refine.options import DEFAULT_WHITEN_ORDER
from galvo_sysid.ident.refine.window import WindowProblem, window_records
from galvo_sysid.model.dynamics import InputDynamics, check_sample_period, split_delay

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import ArrayLike, NDArray

    from galvo_sysid.model.modal import ModalModel

__all__ = ['crlb_at', 'crlb_known_noise']


def crlb_at(windows: Sequence[tuple[ArrayLike, ArrayLike]], *, sample_period: float,
            model: ModalModel, dynamics: InputDynamics, estimate_lag: bool = True,
            whiten_order: int = DEFAULT_WHITEN_ORDER) -> dict[str, float]:
    """Cramer-Rao standard deviation of each parameter from these windows at ``model``.

    Args:
        windows: ``(current, encoder)`` records per window, each (M, N) with M >= 3.
        sample_period: Sampling period [s].
        model: The modal parameters at which the bound is evaluated (frequencies and damping
            ratios; the residues and k0 are solved from the data).
        dynamics: Input dynamics (the lag at which the bound is evaluated).
        estimate_lag: Whether the lag counts as unknown.
        whiten_order: Lags of the noise model (of the fit's prewhitening and of the bound's
            noise estimate).

    Returns:
        Standard deviation by parameter name (``k0``, ``k1``.., ``omega_1``.., ``zeta_1``..,
        and ``lag`` if estimated).

    Raises:
        InvalidDataError: Bad records, fewer than 3 moves per window, or no noise.
    """
    t = check_sample_period(sample_period)
    n = model.n_modes
    delay, frac = split_delay(dynamics.pure_delay(t), t)
    problems = [WindowProblem(cur, enc, sample_period=t, delay=delay, fraction=frac, n_modes=n)
                for cur, enc in window_records(windows, 3)]
    joint, x = _problem(problems, model, dynamics, estimate_lag)
    joint.prewhiten(x, whiten_order)
    if any(prob.whiten is None for prob in problems):
        raise InvalidDataError('the moves do not scatter: no noise to bound the error with')
    _, _, bound = covariance(joint, x, joint.coefficients(x))
    assert bound is not None
    return _by_name(bound, n, estimate_lag)


def crlb_known_noise(windows: Sequence[tuple[ArrayLike, ArrayLike]], *, sample_period: float,
                     model: ModalModel, dynamics: InputDynamics,
                     autocovariance: ArrayLike, estimate_lag: bool = True) -> dict[str, float]:
    """Cramer-Rao standard deviation of each parameter with the noise's covariance known.

    The Fisher matrix ``sum_w J_w^T Sigma_w^-1 J_w`` of the window averages at ``model``,
    every nuisance parameter partialled out, with Sigma_w the Toeplitz matrix of
    ``autocovariance`` (one move's residual noise, stationary) divided by the window's moves.

    Args:
        windows: ``(current, encoder)`` records per window, each (M, N).
        sample_period: Sampling period [s].
        model: The modal parameters at which the bound is evaluated.
        dynamics: Input dynamics (the lag at which the bound is evaluated).
        autocovariance: r[0..] of one move's residual noise [deg^2 per sample^4], at least
            as many lags as a record's rows (e.g.
            :func:`galvo_sysid.sim.noise.residual_noise_autocovariance`).
        estimate_lag: Whether the lag counts as unknown.

    Returns:
        Standard deviation by parameter name, as :func:`crlb_at`.

    Raises:
        InvalidDataError: Bad records, too few lags, or a covariance that is not positive
            definite.
    """
    t = check_sample_period(sample_period)
    n = model.n_modes
    r = np.asarray(autocovariance, dtype=float)
    delay, frac = split_delay(dynamics.pure_delay(t), t)
    problems = [WindowProblem(cur, enc, sample_period=t, delay=delay, fraction=frac, n_modes=n)
                for cur, enc in window_records(windows, 1)]
    joint, x = _problem(problems, model, dynamics, estimate_lag)
    omega, zeta, lag = joint.unpack(x)
    phys = np.concatenate([omega, zeta, [t]])
    info = None
    for prob, coef in zip(problems, joint.coefficients(x), strict=True):
        rows = prob.k.size
        if r.ndim != 1 or r.size < rows:
            raise InvalidDataError(f'the autocovariance needs {rows} lags, got {r.size}')
        sigma = r[np.abs(np.arange(rows)[:, None] - np.arange(rows)[None, :])] / prob.moves
        try:
            chol = cholesky(sigma, lower=True, check_finite=False)
        except LinAlgError as exc:
            raise InvalidDataError(f'the noise covariance is not positive definite: {exc}') \
                from exc
        jac, nuis = _jacobian(prob, omega, zeta, lag, coef, phys, joint.estimate_lag, False)
        jt = _partialled(solve_triangular(chol, jac, lower=True, check_finite=False),
                         solve_triangular(chol, nuis, lower=True, check_finite=False))
        info = jt.T @ jt if info is None else info + jt.T @ jt
    assert info is not None
    return _by_name(_inverse(info), n, estimate_lag)


def _problem(problems: list[WindowProblem], model: ModalModel, dynamics: InputDynamics,
             estimate_lag: bool) -> tuple[JointProblem, NDArray[np.float64]]:
    """The joint problem of the windows and its x at the model."""
    joint = JointProblem(problems, np.ones(len(problems)),
                         fixed_lag=None if estimate_lag else dynamics.lag_time_constant)
    x = joint.pack(np.array(model.natural_frequencies, dtype=float),
                   np.array(model.damping_ratios, dtype=float), dynamics.lag_time_constant)
    return joint, x


def _by_name(cov: NDArray[np.float64], n: int, estimate_lag: bool) -> dict[str, float]:
    """Standard deviations of a covariance of [k0, k_i, omega_i, zeta_i, (lag)] by name."""
    names = [*(f'k{i}' if i else 'k0' for i in range(n + 1)),
             *(f'omega_{i}' for i in range(1, n + 1)), *(f'zeta_{i}' for i in range(1, n + 1)),
             *(('lag',) if estimate_lag else ())]
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return {name: float(s) for name, s in zip(names, sd, strict=True)}
