"""The refined fit: one code path for one window and for several windows of one plant.

:func:`refine_fit` fits a window's average; :func:`refine_joint` fits several windows at once
(shared modal parameters, each window's nuisance its own): the pooled estimate, which
resolves a mode no single window does. Both are :func:`fit_windows`:

1. **Starts.** The output-error cost has local minima in the frequency of a weakly excited,
   lightly damped mode (ripples about 2 pi / (N T) apart); with a large damping ratio the
   same cost is one broad bowl around the true frequency. So each mode's frequency is first
   scanned over its band at a large damping ratio (``damping_start``), the others held at
   the starting model's values; the fit then starts every mode at that damping and lets the
   optimiser reduce it (a continuation that avoids the ripples). The starting model itself
   and ``extra_starts`` are tried too; the lowest cost wins.
2. **Two stages.** Stage 1 is ordinary least squares on the filtered data; stage 2
   prewhitens data and model with an AR model of each window's per-move noise (generalised
   least squares) and weighs each window by its noise.
3. **Profiles** (:mod:`~galvo_sysid.ident.refine.profile`): a weakly excited mode is scanned
   over its band: a better basin is polished, its std widened to the plausible region.
4. **Checks.** A resolved mode ending at its band edge, or a residual between the band edges
   far above the noise (``adequacy_limit``), raises
   :class:`~galvo_sysid.errors.ModelMismatchError`: the data hold dynamics the model does not
   place in its bands. A mode whose residue is below ``resolve_z`` of its std, or that the
   profile does not place, is reported unresolved with an uninformative std for its
   frequency and damping.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.linalg import LinAlgError
from scipy.optimize import least_squares

from galvo_sysid.errors import ConfigurationError, IdentificationError, ModelMismatchError
from galvo_sysid.ident.refine.joint import JointProblem, covariance
from galvo_sysid.ident.refine.profile import ModeProfile, profile_modes, widen_to_profiles
from galvo_sysid.ident.refine.regressors import (
    FIRST_ROW,
    free_responses,
    modal_regressors,
    second_difference,
)
from galvo_sysid.ident.refine.window import WindowProblem, validate, whitening_filter
from galvo_sysid.model.dynamics import check_sample_period, split_delay
from galvo_sysid.model.modal import ModalModel, default_bands

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import ArrayLike, NDArray

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
    'fit_windows',
    'model_fit_percent',
    'refine_fit',
    'refine_joint',
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
    cur, enc = validate(current, encoder)
    u_avg, y_avg = cur.mean(axis=0), enc.mean(axis=0)
    regs = modal_regressors(u_avg, model.natural_frequencies, model.damping_ratios,
                            sample_period=sample_period, lag_time_constant=lag_time_constant,
                            computation_delay=computation_delay, dead_time=dead_time)
    forced = np.tensordot(np.array([model.k0, *model.residues]), regs, axes=1)[FIRST_ROW:]
    yf = second_difference(y_avg)[FIRST_ROW:]
    cols = [free_responses(model.natural_frequencies, model.damping_ratios, u_avg.size,
                           sample_period).T, np.ones((yf.size, 1))]
    if lag_time_constant > 0:
        k = np.arange(yf.size, dtype=float)
        cols.append(np.exp(-k * sample_period / lag_time_constant)[:, None])
    nuisance = np.hstack(cols)
    target = yf - forced
    coef = np.linalg.lstsq(nuisance, target, rcond=None)[0]
    return filtered_fit_percent(yf, target - nuisance @ coef)


def refine_fit(current: ArrayLike, encoder: ArrayLike, *, sample_period: float,
               initial: ModalModel, lag_time_constant: float = 6e-6,
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
            edge. Default: :func:`galvo_sysid.model.modal.default_bands` around ``initial``.
        damping_start: Damping ratio the modes start from (continuation; see module docs).
        extra_starts: Further starting models (e.g. the previous window's result).
        lag_bounds: Bounds of the estimated lag [sample periods].
        scan_points: Frequencies per band of the starting scan (0: no scan, start from
            ``initial`` only).
        resolve_z: A mode whose |k_i| is below ``resolve_z`` times its std counts as not
            resolved; such a mode may end at a band edge without an error.
        whiten_order: Order of the AR noise model of the second, prewhitened stage
            (generalised least squares; 0: ordinary least squares only). Needs M > 2 records.
        adequacy_limit: Largest accepted ratio of the averaged residual's energy to the noise's
            (estimated from the moves' scatter) in any interval between band edges; above it
            the model lacks dynamics the data hold (0: no check). Needs M > 2 records.
        max_nfev: Iteration limit of each start.

    Returns:
        The fit with its covariance.

    Raises:
        InvalidDataError: Bad shapes, too short, NaN/Inf, no excitation.
        ConfigurationError: Bad options.
        ModelMismatchError: A resolved mode ended at its band edge, or the residual between the
            band edges is far above the noise.
        IdentificationError: The fit failed.
    """
    return fit_windows(
        [(current, encoder)], sample_period=sample_period, initial=initial,
        lag_time_constant=lag_time_constant, estimate_lag=estimate_lag,
        computation_delay=computation_delay, dead_time=dead_time, bands=bands,
        damping_start=damping_start, extra_starts=extra_starts, lag_bounds=lag_bounds,
        scan_points=scan_points, resolve_z=resolve_z, whiten_order=whiten_order,
        adequacy_limit=adequacy_limit, max_nfev=max_nfev)


def refine_joint(windows: Sequence[tuple[ArrayLike, ArrayLike]], *, sample_period: float,
                 initial: ModalModel, lag_time_constant: float = 6e-6,
                 estimate_lag: bool = True, computation_delay: int = 1, dead_time: float = 0.0,
                 bands: Sequence[tuple[float, float]] | None = None,
                 damping_start: float = DEFAULT_DAMPING_START,
                 lag_bounds: tuple[float, float] = DEFAULT_LAG_BOUNDS,
                 scan_points: int = DEFAULT_SCAN_POINTS, resolve_z: float = DEFAULT_RESOLVE_Z,
                 whiten_order: int = DEFAULT_WHITEN_ORDER, max_nfev: int = 100,
                 keep_initial_damping: bool = False,
                 noise_filters: Sequence[NDArray[np.float64]] | None = None,
                 adequacy_limit: float = 0.0) -> RefinedFit:
    """Fit one modal model to several windows of the same plant at once (the pooled estimate).

    Like :func:`refine_fit`, on every window's average, with omega_i, zeta_i, the lag, k0 and
    k_i shared and each window's initial conditions and offset its own. Windows of different
    target angles, move counts and lengths may be mixed.

    Args:
        windows: ``(current, encoder)`` records per window, each (M_w, N_w) (M_w > 2).
        sample_period: Sampling period [s].
        initial: Starting model (e.g. the pooled single-window results).
        lag_time_constant: Starting (or fixed) amplifier lag [s].
        estimate_lag: Estimate the lag.
        computation_delay: Whole samples of computation delay.
        dead_time: Extra pure delay [s].
        bands: Frequency band per mode [rad/s] (default around ``initial``).
        damping_start: Damping ratio the modes start from.
        lag_bounds: Bounds of the lag [sample periods].
        scan_points: Frequencies per band of the joint starting scan (0: none).
        resolve_z: Significance below which a mode counts as not resolved.
        whiten_order: Order of each window's AR noise model for the prewhitened second stage.
        max_nfev: Iteration limit of each stage.
        keep_initial_damping: Start from ``initial`` as it is (its damping ratios too) rather
            than from the continuation's ``damping_start``: for a good start, e.g. the pooled
            single-window results; without a scan that moves a frequency by over 1 %, the
            first (ordinary least-squares) stage is left out.
        noise_filters: Fixed prewhitening filters, one per window (e.g.
            :func:`window_noise_filters`): the fit is then one prewhitened stage, and fits of
            different models to the same windows have comparable ``chi2``.
        adequacy_limit: As for :func:`refine_fit` (default 0: no check).

    Returns:
        The joint fit (``initial_conditions`` empty, ``offset`` nan: they are per window).

    Raises:
        InvalidDataError: No windows, or a window with bad records or fewer than 3 moves.
        ConfigurationError: Bad options.
        ModelMismatchError: A resolved mode ended at its band edge.
        IdentificationError: The fit failed.
    """
    if not windows:
        from galvo_sysid.errors import InvalidDataError

        raise InvalidDataError('no windows to fit')
    return fit_windows(
        windows, sample_period=sample_period, initial=initial,
        lag_time_constant=lag_time_constant, estimate_lag=estimate_lag,
        computation_delay=computation_delay, dead_time=dead_time, bands=bands,
        damping_start=damping_start, lag_bounds=lag_bounds, scan_points=scan_points,
        resolve_z=resolve_z, whiten_order=whiten_order, max_nfev=max_nfev,
        keep_initial_damping=keep_initial_damping, noise_filters=noise_filters,
        adequacy_limit=adequacy_limit, min_moves=3)


def _check_options(sample_period: float, lag_time_constant: float, dead_time: float,
                   lag_bounds: tuple[float, float],
                   damping_start: float) -> float:
    t = check_sample_period(sample_period)
    if not (np.isfinite(lag_time_constant) and lag_time_constant >= 0 and dead_time >= 0):
        raise ConfigurationError('lag_time_constant and dead_time must be finite and >= 0')
    if not 0 <= lag_bounds[0] < lag_bounds[1]:
        raise ConfigurationError(f'bad lag_bounds {lag_bounds}')
    if not 0 < damping_start < _MAX_DAMPING:
        raise ConfigurationError(f'damping_start must be in (0, {_MAX_DAMPING})')
    return t


def _records(windows: Sequence[tuple[ArrayLike, ArrayLike]], min_moves: int) -> list[
        tuple[NDArray[np.float64], NDArray[np.float64]]]:
    from galvo_sysid.errors import InvalidDataError

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


def fit_windows(windows: Sequence[tuple[ArrayLike, ArrayLike]], *, sample_period: float,
                initial: ModalModel, lag_time_constant: float = 6e-6,
                estimate_lag: bool = True, computation_delay: int = 1, dead_time: float = 0.0,
                bands: Sequence[tuple[float, float]] | None = None,
                damping_start: float = DEFAULT_DAMPING_START,
                extra_starts: Sequence[ModalModel] = (),
                lag_bounds: tuple[float, float] = DEFAULT_LAG_BOUNDS,
                scan_points: int = DEFAULT_SCAN_POINTS, resolve_z: float = DEFAULT_RESOLVE_Z,
                whiten_order: int = DEFAULT_WHITEN_ORDER,
                adequacy_limit: float = DEFAULT_ADEQUACY_LIMIT, max_nfev: int = 100,
                keep_initial_damping: bool = False,
                noise_filters: Sequence[NDArray[np.float64]] | None = None,
                min_moves: int = 1) -> RefinedFit:
    """The refined fit of one or several windows (see the module docs and :func:`refine_fit`,
    :func:`refine_joint` for the options)."""  # noqa: D205, D209
    t = _check_options(sample_period, lag_time_constant, dead_time, lag_bounds, damping_start)
    band_list = _bands_for(initial, bands, t)
    n = initial.n_modes
    for model in extra_starts:
        if model.n_modes != n:
            raise ConfigurationError('every starting model needs the same number of modes')
    records = _records(windows, min_moves)
    delay, frac = split_delay(computation_delay * t + dead_time, t)
    problems = [WindowProblem(cur, enc, sample_period=t, delay=delay, fraction=frac, n_modes=n)
                for cur, enc in records]
    if noise_filters is not None:
        if len(noise_filters) != len(problems):
            raise ConfigurationError('one noise filter per window')
        for prob, filt in zip(problems, noise_filters, strict=True):
            prob.set_whitening(np.asarray(filt, dtype=float))
        whiten_order = 0  # already whitened: one stage
    noise = np.array([prob.raw_noise_rms() for prob in problems])
    scale = max(float(np.sqrt(np.mean(prob.yf_raw**2))) for prob in problems) or 1.0
    noisy = bool(np.all(noise > 1e-10 * scale)) and all(p.moves > 2 for p in problems)
    if not noisy:  # noise-free or single records: the windows weigh alike
        noise = np.full(len(problems), scale)
    joint = JointProblem(problems, 1.0 / noise,
                         fixed_lag=None if estimate_lag else lag_time_constant)
    lower, upper = _bounds(band_list, estimate_lag, lag_bounds)
    x_init = _start_vector(joint, initial, lower, upper, damping_start=damping_start,
                           lag=lag_time_constant, lag_bounds=lag_bounds)
    starts = _starts(joint, initial, x_init, band_list, lower, upper, scan_points=scan_points,
                     damping_start=damping_start, keep_initial_damping=keep_initial_damping)
    starts += [_start_vector(joint, model, lower, upper, damping_start=damping_start,
                             lag=lag_time_constant, lag_bounds=lag_bounds)
               for model in extra_starts]
    two_stage = whiten_order > 0 and noisy
    # Stage 1 only has to find the basin when the prewhitened stage 2 polishes afterwards.
    tol = _STAGE1_TOL if two_stage else 1e-8

    def polish(x0: NDArray[np.float64], tol: float = 1e-8) -> NDArray[np.float64]:
        try:
            sol = least_squares(joint.residual, x0, jac=joint.jacobian, bounds=(lower, upper),
                                x_scale='jac', max_nfev=max_nfev, method='trf', ftol=tol,
                                xtol=tol)
        except (ValueError, LinAlgError) as exc:
            raise IdentificationError(f'refined fit failed: {exc}') from exc
        return np.asarray(sol.x, dtype=np.float64)

    skip_stage1 = keep_initial_damping and len(starts) == 1 and two_stage
    best: tuple[tuple[bool, float], NDArray[np.float64]] | None = None
    for x0 in () if skip_stage1 else starts:
        x1 = polish(x0, tol)
        key = (_edge_mode(joint.unpack(x1), band_list) is not None, joint.cost(x1))
        if best is None or key < best[0]:
            best = (key, x1)
    x = best[1] if best is not None else starts[0]
    if two_stage:
        _prewhiten(joint, x, whiten_order)
        x = polish(x)
    profiles: list[ModeProfile] = []
    if noisy and n:
        x, profiles = _profile_and_search(joint, x, band_list, polish)
    return _result(joint, x, band_list, profiles, resolve_z=resolve_z,
                   adequacy_limit=adequacy_limit if noisy else 0.0,
                   computation_delay=computation_delay, dead_time=dead_time,
                   starts=len(starts))


def _starts(joint: JointProblem, initial: ModalModel, x_init: NDArray[np.float64],
            band_list: Sequence[tuple[float, float]], lower: NDArray[np.float64],
            upper: NDArray[np.float64], *, scan_points: int, damping_start: float,
            keep_initial_damping: bool) -> list[NDArray[np.float64]]:
    """The scanned start, and the initial model's (see the module docs)."""
    omega0, zeta0, lag0 = joint.unpack(x_init)
    omega_scan = omega0.copy()
    if scan_points > 1:
        # The other modes keep the initial model's damping (inflating a strongly excited mode's
        # damping would leave a misfit the scanned mode then chases).
        zeta_init = np.clip(np.array(initial.damping_ratios, dtype=float), 1e-4,
                            0.5 * _MAX_DAMPING)
        for i, (lo, hi) in enumerate(band_list):
            grid = np.geomspace(lo * 1.01, hi / 1.01, scan_points)
            w_c = np.concatenate([[omega_scan[i]], grid])
            z_c = np.concatenate([[zeta_init[i]], np.full(grid.size, damping_start)])
            gains = sum(wt * wt * prob.scan(i, omega_scan, zeta_init, lag0, w_c, z_c)[0]
                        for prob, wt in zip(joint.problems, joint.weights, strict=True))
            omega_scan[i] = float(w_c[int(np.argmax(gains))])
    moved = bool(omega0.size) and float(np.max(np.abs(np.log(omega_scan / omega0)))) > 0.01
    if keep_initial_damping:
        span = upper - lower
        as_is = joint.pack(np.array(initial.natural_frequencies, dtype=float),
                           np.clip(np.array(initial.damping_ratios, dtype=float), _MIN_DAMPING,
                                   0.5 * _MAX_DAMPING), lag0)
        starts = [np.clip(as_is, lower + 1e-3 * span, upper - 1e-3 * span)]
        if moved:
            starts.append(joint.pack(omega_scan, zeta0, lag0))
        return starts
    starts = [joint.pack(omega_scan, zeta0, lag0)]
    if moved:
        starts.append(x_init)
    return starts


def _prewhiten(joint: JointProblem, x: NDArray[np.float64], order: int) -> None:
    """Stage 2: each window's AR noise filter from its per-move deviations at x, weights."""
    omega, zeta, lag = joint.unpack(x)
    weights = []
    for prob, coef in zip(joint.problems, joint.coefficients(x), strict=True):
        dev = prob.deviations(omega, zeta, lag, coef)
        prob.set_whitening(whitening_filter(dev, order,
                                            float(np.sqrt(np.mean(prob.yf_raw**2)))))
        wdev = prob.apply_whitening(dev, axis=1)
        weights.append(1.0 / max(float(np.sqrt(np.mean(wdev**2) / (prob.moves - 1))),
                                 1e-300))
    joint.set_weights(weights)


def _profile_and_search(joint: JointProblem, x: NDArray[np.float64],
                        band_list: Sequence[tuple[float, float]], polish: Any) -> tuple[
                            NDArray[np.float64], list[ModeProfile]]:
    """Profiles of the modes at x; if a mode has a clearly better basin, polish from there
    (kept if the cost is lower) and profile again."""  # noqa: D205, D209
    profiles = profile_modes(joint, x, band_list)
    if any(p.better is not None for p in profiles):
        omega, zeta, lag = joint.unpack(x)
        for i, p in enumerate(profiles):
            if p.better is not None:
                omega[i], zeta[i] = p.better
        x_new = polish(joint.pack(omega, zeta, lag))
        if joint.cost(x_new) < joint.cost(x):
            x = x_new
            profiles = profile_modes(joint, x, band_list)
    return x, profiles


def _result(joint: JointProblem, x: NDArray[np.float64],
            band_list: Sequence[tuple[float, float]], profiles: list[ModeProfile], *,
            resolve_z: float, adequacy_limit: float, computation_delay: int,
            dead_time: float, starts: int) -> RefinedFit:
    """The fit at x: covariance, checks, resolved modes."""
    n = joint.n_modes
    omega, zeta, lag = joint.unpack(x)
    coefs = joint.coefficients(x)
    shared = coefs[0][: 1 + n]
    model = ModalModel(k0=float(shared[0]), residues=tuple(float(c) for c in shared[1:]),
                       natural_frequencies=tuple(float(w) for w in omega),
                       damping_ratios=tuple(float(z) for z in zeta))
    names = (*model.parameters(), *(('lag',) if joint.estimate_lag else ()))
    cov, method = covariance(joint, x, coefs)
    widen_to_profiles(cov, profiles, [*shared, *omega, *zeta], n)
    res2 = den2 = 0.0
    ratios: dict[tuple[float, float], float] = {}
    for prob, coef in zip(joint.problems, coefs, strict=True):
        resid = prob.yf_raw - prob.columns(omega, zeta, lag, whitened=False) @ coef
        res2 += float(resid @ resid)
        den2 += float(np.sum((prob.yf_raw - prob.yf_raw.mean()) ** 2))
        if adequacy_limit > 0:
            dev = prob.deviations(omega, zeta, lag, coef)
            for band, ratio in residual_to_noise(resid, dev, band_list, joint.t):
                ratios[band] = max(ratio, ratios.get(band, 0.0))
    for (lo, hi), ratio in ratios.items():
        if ratio > adequacy_limit:
            raise ModelMismatchError(
                f'the residual between {lo:.4g} and {hi:.4g} rad/s is {ratio:.3g} times the '
                f'noise: the data hold dynamics the model lacks there (no physical mode in a '
                f'band, or a mode outside its band)')
    # A mode whose residue is not significant, or that its profile does not place, is not
    # resolved by these data: its frequency and damping are a noise fit.
    k_std = np.sqrt(np.clip(np.diag(cov)[1: 1 + n], 0.0, None))
    unresolved = tuple(i for i in range(n) if abs(shared[1 + i]) < resolve_z * k_std[i]
                       or (profiles and not profiles[i].resolved(band_list[i])))
    edge = _edge_mode((omega, zeta, lag), band_list)
    if edge is not None and edge not in unresolved:
        lo, hi = band_list[edge]
        raise ModelMismatchError(
            f'no physical mode {edge + 1} in the band {lo:.4g}..{hi:.4g} rad/s (the fit ended at '
            f'omega = {omega[edge]:.4g} rad/s, zeta = {zeta[edge]:.3g})')
    _inflate_unresolved(cov, unresolved, band_list, n)
    single = len(coefs) == 1
    return RefinedFit(
        model=model, lag_time_constant=float(lag), lag_estimated=joint.estimate_lag,
        computation_delay=computation_delay, dead_time=float(dead_time),
        sample_period=float(joint.t), parameter_names=tuple(names), covariance=cov,
        covariance_method=method,
        initial_conditions=tuple(float(c) for c in coefs[0][1 + n: 1 + 3 * n]) if single
        else (),
        offset=float(coefs[0][1 + 3 * n]) if single else float('nan'),
        fit_percent=100.0 * (1.0 - math.sqrt(res2 / den2)) if den2 > 0 else float('nan'),
        cost=res2, n_evaluations=joint.n_eval, starts=starts,
        unresolved_modes=tuple(i + 1 for i in unresolved),
        residual_to_noise=tuple(sorted(ratios.items())),
        chi2=joint.cost(x), rows=int(sum(prob.yf.size for prob in joint.problems)))


def residual_to_noise(resid: NDArray[np.float64], dev: NDArray[np.float64],
                      band_list: Sequence[tuple[float, float]],
                      sample_period: float) -> tuple[tuple[tuple[float, float], float], ...]:
    """Energy of the averaged residual over that expected from the noise, per interval.

    The intervals cut the spectrum at every band edge: below the first band (from four
    periods per record on), between the bands, and above the last one up to 0.98 x Nyquist,
    so a mode outside every band shows too. About 1 for an adequate model.
    """
    m = dev.shape[0]
    win = np.hanning(resid.size)
    res_psd = np.abs(np.fft.rfft(resid * win)) ** 2
    noise_psd = np.mean(np.abs(np.fft.rfft(dev * win, axis=1)) ** 2, axis=0) / m
    freq = np.fft.rfftfreq(resid.size, sample_period) * 2 * math.pi
    lowest = 2 * math.pi * 4 / (resid.size * sample_period)
    top = 0.98 * math.pi / sample_period
    cuts = {e for band in band_list for e in band}
    if cuts:
        cuts |= {e for e in (lowest, top) if e < min(cuts) or e > max(cuts)}
    edges = sorted(cuts)
    out = []
    for lo, hi in itertools.pairwise(edges):
        sel = (freq >= lo) & (freq < hi)
        noise = float(np.sum(noise_psd[sel]))
        if noise > 0 and np.count_nonzero(sel) >= 3:
            out.append(((lo, hi), float(np.sum(res_psd[sel])) / noise))
    return tuple(out)


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


def _start_vector(joint: JointProblem, model: ModalModel, lower: NDArray[np.float64],
                  upper: NDArray[np.float64], *, damping_start: float, lag: float,
                  lag_bounds: tuple[float, float]) -> NDArray[np.float64]:
    """Starting x from a model: its frequencies, damping raised to ``damping_start``."""
    omega = np.array(model.natural_frequencies, dtype=float)
    zeta = np.maximum(np.array(model.damping_ratios, dtype=float), damping_start)
    t = joint.t
    lag0 = min(max(lag / t, lag_bounds[0]), lag_bounds[1]) * t
    x0 = joint.pack(omega, np.minimum(zeta, 0.5 * _MAX_DAMPING), lag0)
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


def _bands_for(initial: ModalModel, bands: Sequence[tuple[float, float]] | None,
               sample_period: float) -> list[tuple[float, float]]:
    if bands is None:
        bands = default_bands(initial, sample_period=sample_period) if initial.n_modes else ()
    out = [(float(lo), float(hi)) for lo, hi in bands]
    if len(out) != initial.n_modes:
        raise ConfigurationError(f'{len(out)} bands for {initial.n_modes} modes')
    nyquist = math.pi / sample_period
    for lo, hi in out:
        if not 0 < lo < hi <= nyquist:
            raise ConfigurationError(f'bad band ({lo:.4g}, {hi:.4g}) rad/s (Nyquist {nyquist:.4g})')
    return out


def window_noise_filters(windows: Sequence[tuple[ArrayLike, ArrayLike]], *,
                         order: int = DEFAULT_WHITEN_ORDER) -> list[NDArray[np.float64]]:
    """A prewhitening filter per window from its moves' scatter alone (no model needed).

    The AR model of the (1 - q^-1)^2-filtered encoder deviations from the window's mean: the
    noise the averaged window carries, up to the small part the input deviations explain.
    """
    out = []
    for current, encoder in windows:
        _, enc = validate(current, encoder)
        dev = second_difference(enc - enc.mean(axis=0))[:, FIRST_ROW:]
        out.append(whitening_filter(dev, order, float(np.sqrt(np.mean(
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
    t = fit.sample_period
    delay, frac = split_delay(fit.computation_delay * t + fit.dead_time, t)
    total = np.zeros(w_c.size)
    for (cur, enc), filt in zip(_records(windows, 1), noise_filters, strict=True):
        prob = WindowProblem(cur, enc, sample_period=t, delay=delay, fraction=frac,
                             n_modes=m.n_modes)
        prob.set_whitening(np.asarray(filt, dtype=float))
        weight = 1.0 / max(prob.raw_noise_rms(), 1e-300)
        total += weight * weight * prob.scan_new(omega, zeta, fit.lag_time_constant, w_c, z_c)
    return total
