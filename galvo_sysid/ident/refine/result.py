"""What the refined fit returns (:class:`RefinedFit`) and the fit measure of a fixed model."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from galvo_sysid.ident.refine.regressors import (
    FIRST_ROW,
    free_responses,
    modal_regressors,
    second_difference,
)
from galvo_sysid.ident.refine.window import validate
from galvo_sysid.model.dynamics import InputDynamics

if TYPE_CHECKING:
    from numpy.typing import ArrayLike, NDArray

    from galvo_sysid.ident.refine.whitener import NoiseModel
    from galvo_sysid.model.modal import ModalModel

__all__ = ['RefinedFit', 'filtered_fit_percent', 'model_fit_percent']


@dataclass(frozen=True, eq=False)
class RefinedFit:
    """Outcome of the refined fit of one window or several.

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
            averaged output yf and residual r (over all windows).
        cost: Sum of squared filtered (unwhitened, unweighted) residuals.
        n_evaluations: Residual evaluations spent by the optimiser (all starts).
        starts: Number of starting points tried.
        unresolved_modes: Modes (1-based) the data do not place (see the module docs); their
            omega and zeta std are raised to at least those of a uniform distribution over
            the band and over (0, 0.3).
        residual_to_noise: ``((lo, hi), ratio)`` per interval between band edges: energy of
            the averaged residual over the noise's, the largest over the windows (about 1 for
            an adequate model; empty without per-move records or noise).
        chi2: The sum of squared residuals, prewhitened and weighted by each window's noise
            (about ``rows`` for an adequate model).
        rows: Residual rows over all windows.
        crlb_covariance: Cramer-Rao bound of the same parameters as ``covariance`` (see
            :func:`~galvo_sysid.ident.refine.joint.covariance`); not widened for unresolved
            modes (it is the local bound at the estimate).
        noise_models: Per window, the stationary noise model the fit weighed it with (None
            where it could not be made; empty without prewhitening): a joint fit of the same
            moves can reuse it (``refine_joint(noise_models=...)``).
        cut_short: The fit passed its deadline and left out stages
            (:attr:`~galvo_sysid.ident.refine.options.RefineOptions.deadline`): the modes they
            would have placed are among :attr:`unresolved_modes`.
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
    crlb_covariance: NDArray[np.float64] | None = field(default=None, repr=False)
    noise_models: tuple[NoiseModel | None, ...] = field(default=(), repr=False)
    cut_short: bool = False

    @property
    def resolved(self) -> tuple[bool, ...]:
        """Per mode, whether the data resolve it (see :attr:`unresolved_modes`)."""
        return tuple(i not in self.unresolved_modes
                     for i in range(1, self.model.n_modes + 1))

    @property
    def dynamics(self) -> InputDynamics:
        """The input dynamics of the fit (the lag as estimated)."""
        return InputDynamics(computation_delay=self.computation_delay,
                             lag_time_constant=self.lag_time_constant, dead_time=self.dead_time)

    @property
    def input_delay(self) -> float:
        """Low-frequency equivalent input delay [s]: computation delay + dead time + lag."""
        return self.computation_delay * self.sample_period + self.dead_time \
            + self.lag_time_constant

    def std_by_name(self) -> dict[str, float]:
        """Standard deviation of every parameter, by name (incl. ``'lag'`` if estimated)."""
        return _diagonal_std(self.parameter_names, self.covariance)

    def crlb_by_name(self) -> dict[str, float]:
        """Cramer-Rao standard deviation of every parameter, by name (empty if not known)."""
        if self.crlb_covariance is None:
            return {}
        return _diagonal_std(self.parameter_names, self.crlb_covariance)


def _diagonal_std(names: tuple[str, ...], cov: NDArray[np.float64]) -> dict[str, float]:
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return {n: float(s) for n, s in zip(names, sd, strict=True)}


def filtered_fit_percent(yf: NDArray[np.float64], residual: NDArray[np.float64]) -> float:
    """100 (1 - ||residual|| / ||yf - mean(yf)||)."""
    den = float(np.linalg.norm(yf - yf.mean()))
    return 100.0 * (1.0 - float(np.linalg.norm(residual)) / den) if den > 0 else float('nan')


def model_fit_percent(model: ModalModel, current: ArrayLike, encoder: ArrayLike, *,
                      sample_period: float, dynamics: InputDynamics) -> float:
    """Fit [%] of a fixed model on the (1 - q^-1)^2-filtered averaged output.

    The model (with the given input dynamics) is driven by the averaged current; the modes'
    initial conditions and an offset are fitted by least squares, as in the refined fit.

    Args:
        model: The modal model.
        current: Current records (M, N) or one record (N,).
        encoder: Encoder records, same shape.
        sample_period: Sampling period [s].
        dynamics: Input dynamics between the current and the torque.

    Returns:
        ``100 (1 - ||yf - yf_model|| / ||yf - mean(yf)||)``.
    """
    cur, enc = validate(current, encoder)
    u_avg, y_avg = cur.mean(axis=0), enc.mean(axis=0)
    regs = modal_regressors(u_avg, model.natural_frequencies, model.damping_ratios,
                            sample_period=sample_period,
                            lag_time_constant=dynamics.lag_time_constant,
                            computation_delay=dynamics.computation_delay,
                            dead_time=dynamics.dead_time)
    forced = np.tensordot(np.array([model.k0, *model.residues]), regs, axes=1)[FIRST_ROW:]
    yf = second_difference(y_avg)[FIRST_ROW:]
    cols = [free_responses(model.natural_frequencies, model.damping_ratios, u_avg.size,
                           sample_period).T, np.ones((yf.size, 1))]
    if dynamics.lag_time_constant > 0:
        k = np.arange(yf.size, dtype=float)
        cols.append(np.exp(-k * sample_period / dynamics.lag_time_constant)[:, None])
    nuisance = np.hstack(cols)
    target = yf - forced
    coef = np.linalg.lstsq(nuisance, target, rcond=None)[0]
    return filtered_fit_percent(yf, target - nuisance @ coef)
