"""The identification entry point: one window of moves in, modal parameters with their std out.

:func:`identify_window` takes M move records of one target angle (current and encoder, each
record starting at rest at its start angle) and returns an :class:`IdentificationResult`:
the modal parameters of P_mech (paper Eq. 1), one standard deviation per parameter, the input
delay that was removed or modelled, and a fit measure. Methods:

- ``'refined'`` (default): the structured output-error fit of :mod:`galvo_sysid.ident.refine`
  (exact ZOH with one sample of computation delay and the estimated amplifier lag), started
  from the paper pipeline's model; std from the sandwich covariance over the moves.
- ``'paper-A'`` / ``'paper-B'``: the paper's pipeline
  (:func:`galvo_sysid.ident.paper.paper_pipeline`, method A or B, 1.6 T pure delay); std
  from a delete-a-group jackknife over the moves.

Pooled estimates of windows of the same plant:

- :func:`~galvo_sysid.ident.pool.pool_results` combines finished results (inverse-variance
  weighting per parameter, outliers rejected, the std scaled up when the windows scatter more
  than their std say);
- :func:`identify_joint` fits one model to the windows' data at once (shared modal parameters,
  per-window initial conditions): sharper for a weakly excited mode that single windows hardly
  resolve (the third mode under smooth moves).

``fit_percent`` is ``100 (1 - ||yf - yf_model|| / ||yf - mean(yf)||)`` on the window's
averaged output **filtered by (1 - q^-1)^2** (the same for every method): the raw output is
dominated by the rigid-body motion (every model fits it to 99.9 %), the filtered one by the
acceleration and the vibrations the modal parameters describe. The model output includes the
identified input dynamics and least-squares initial conditions of the modes and an offset.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from galvo_sysid.errors import (
    ConfigurationError,
    GalvoSysidError,
    InvalidDataError,
    ModelMismatchError,
)
from galvo_sysid.ident.methods import METHODS
from galvo_sysid.ident.paper import group_deleted_models, paper_pipeline
from galvo_sysid.ident.pool import pool_results
from galvo_sysid.ident.preprocess import (
    MIN_ANGLE_SPAN,
    check_travel,
    travels,
    validate_records,
)
from galvo_sysid.ident.refine import DEFAULT_RESOLVE_Z as RESOLVE_Z
from galvo_sysid.ident.refine import RefineOptions, model_fit_percent, refine_fit, refine_joint
from galvo_sysid.ident.result import IdentificationResult, result_from_vectors
from galvo_sysid.ident.screen import DEFAULT_SCREEN_LIMIT, screen_moves
from galvo_sysid.ident.warm import WarmStart, plausible
from galvo_sysid.model import PAPER_MODEL, ModalModel, PlantModel
from galvo_sysid.model.dynamics import InputDynamics, check_sample_period

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import ArrayLike, NDArray

    from galvo_sysid.ident.refine import RefinedFit
    from galvo_sysid.ident.refine.joint import MapWindows
    from galvo_sysid.ident.refine.whitener import NoiseModel

__all__ = ['check_model_period', 'identify_joint', 'identify_window']

_JACKKNIFE_GROUPS = 10


def _estimated_angle(enc: NDArray[np.float64]) -> float:
    """Median over the moves of the final angle minus the start angle [deg]."""
    return float(np.median(travels(enc)))


def _paper_window(cur: NDArray[np.float64], enc: NDArray[np.float64], *, sample_period: float,
                  method: str, options: dict[str, Any]) -> tuple[ModalModel, float, float]:
    """Paper pipeline on a window: (model, delay, fit_percent)."""
    res = paper_pipeline(cur, enc, sample_period=sample_period, method=method, **options)
    fit = model_fit_percent(res.model, cur, enc, sample_period=sample_period,
                            dynamics=InputDynamics(computation_delay=0, lag_time_constant=0.0,
                                                   dead_time=float(res.delay)))
    return res.model, float(res.delay), fit


def _jackknife_std(cur: NDArray[np.float64], enc: NDArray[np.float64], *, sample_period: float,
                   method: str, options: dict[str, Any], groups: int) -> dict[str, float]:
    """Delete-a-group jackknife std of the paper pipeline's parameters
    (:func:`~galvo_sysid.ident.paper.group_deleted_models`: move i in group i mod groups)."""  # noqa: D205, D209
    g = min(groups, cur.shape[0])
    if g < 3:
        return {}
    models = [m for m in group_deleted_models(cur, enc, groups=g, sample_period=sample_period,
                                              method=method, **options) if m is not None]
    if len(models) < 3:
        return {}
    names = list(models[0].parameters())
    est = np.array([list(m.parameters().values()) for m in models])
    k = est.shape[0]
    var = (k - 1) / k * np.sum((est - est.mean(axis=0)) ** 2, axis=0)
    return {n: float(math.sqrt(v)) for n, v in zip(names, var, strict=True)}


def identify_window(current: ArrayLike, encoder: ArrayLike, *, sample_period: float,
                    method: str = 'refined', target_angle: float | None = None,
                    model: PlantModel | None = None, n_modes: int | None = None,
                    warm_start: WarmStart | None = None,
                    **options: Any) -> IdentificationResult:
    """Identify the modal model from one window of moves.

    The scanner's model (default: the paper's) sets what is identified: the number of modes,
    each mode's frequency band, the starting point, the input dynamics (the paper methods'
    fictitious input uses its equivalent delay; the refined fit its computation delay, dead
    time and, as the start, its amplifier lag) and the sample period the data must have.

    Args:
        current: Current records [A], shape (M, N): M moves of one target angle.
        encoder: Encoder records [deg], shape (M, N), raw (each starts at rest at its start
            angle, which is subtracted).
        sample_period: Sampling period [s] of the records.
        method: ``'refined'`` (default), ``'paper-A'`` or ``'paper-B'``.
        target_angle: Signed commanded rotation [deg]; estimated from the encoder if None.
        model: The scanner's model (:class:`~galvo_sysid.model.plant.PlantModel`).
        n_modes: Resonant modes to identify (default: the model's; another number needs
            ``bands``). 0 (a model of the rigid body alone, as commissioning gives where the
            moves excite no resonance) only with the refined method.
        warm_start: The refined fit starts from the previous window of the same moves
            (:mod:`galvo_sysid.ident.warm`: its estimate and noise model), and searches
            afresh only if that fit's cost is above what the noise allows; ignored by the
            paper methods.
        **options: Passed on. Common: ``bands`` (per-mode frequency bands [rad/s], default
            the model's), ``reference`` (modal model of the start and the paper pipeline's
            mode selection, default the model's), ``min_angle_span`` [deg],
            ``screen_limit`` (moves deviating from the others by more robust standard
            deviations are set aside, :func:`~galvo_sysid.ident.screen.screen_moves`;
            default 10, 0: none). Paper methods:
            ``delay`` (default the model's equivalent delay; None estimates it), ``na``,
            ``nb``, ``solver``, ``max_damping``, ``jackknife_groups`` (default 10; 0 for no
            std, reported as nan). Refined: the input dynamics ``lag_time_constant`` (the
            start), ``computation_delay``, ``dead_time`` (default the model's),
            ``estimate_lag``, ``extra_starts`` and the fields of
            :class:`~galvo_sysid.ident.refine.RefineOptions` (``scan_points``,
            ``whiten_order``, ``adequacy_limit``, ...).

    Returns:
        The identified parameters with their standard deviations.

    Raises:
        InvalidDataError: Wrong shapes, too few or too short records, NaN/Inf, no excitation.
        ModelMismatchError: The data do not match the model (another sample period, a mode at
            its band edge, a residual far above the noise).
        IdentificationError: The fit failed.
        ConfigurationError: Unknown method or options.
    """
    if method not in METHODS:
        raise ConfigurationError(f'unknown method {method!r}; choose one of {", ".join(METHODS)}')
    t = check_sample_period(sample_period)
    plant = PAPER_MODEL if model is None else model
    check_model_period(plant, t)
    opts = dict(options)
    reference: ModalModel = opts.pop('reference', plant.modal)
    n = reference.n_modes if n_modes is None else int(n_modes)
    bands = opts.pop('bands', None)
    if bands is None:
        if n != plant.n_modes or reference.n_modes != plant.n_modes:
            raise ConfigurationError(f'{n} modes asked but the model has {plant.n_modes}; '
                                     f'pass bands')
        bands = plant.mode_bands()
    min_span = float(opts.pop('min_angle_span', MIN_ANGLE_SPAN))
    if n < 0 or (n == 0 and method != 'refined'):
        raise ConfigurationError(f'n_modes must be >= 1 (>= 0 with the refined method), got {n}')
    if len(bands) != n:
        raise ConfigurationError(f'{len(bands)} bands for {n} modes')
    groups = int(opts.pop('jackknife_groups', _JACKKNIFE_GROUPS))
    screen_limit = float(opts.pop('screen_limit', DEFAULT_SCREEN_LIMIT))
    allowed = _PAPER_KEYS | (_REFINED_KEYS if method == 'refined' else set())
    unknown = set(opts) - allowed
    if unknown:
        raise ConfigurationError(f'unknown options for method {method!r}: {sorted(unknown)}')
    paper_opts = {k: opts[k] for k in _PAPER_KEYS & set(opts)}
    paper_opts.setdefault('delay', plant.equivalent_delay)
    paper_opts.update(bands=bands, reference=reference, min_angle_span=min_span)
    current, encoder, set_aside = _screen(current, encoder, model=plant, limit=screen_limit)
    cur, enc = validate_records(current, encoder, na=paper_opts.get('na', 15),
                                nb=paper_opts.get('nb', 15), min_angle_span=min_span)
    enc = enc - enc[:, :1]
    if target_angle is not None:
        check_travel(enc, float(target_angle))
    angle = _estimated_angle(enc) if target_angle is None else float(target_angle)
    moves = cur.shape[0]
    if method in ('paper-A', 'paper-B'):
        which = method[-1]
        found, delay, fit = _paper_window(cur, enc, sample_period=t, method=which,
                                          options=paper_opts)
        stds = _jackknife_std(cur, enc, sample_period=t, method=which,
                              options=paper_opts, groups=groups) if groups else {}
        if not stds:
            stds = dict.fromkeys(found.parameters(), float('nan'))
        resolved = tuple(not abs(k) < RESOLVE_Z * stds.get(f'k{i}', math.nan)
                         for i, k in enumerate(found.residues, start=1))
        return result_from_vectors(found.parameters(), stds, n_modes=found.n_modes,
                             target_angle=angle, moves=moves, input_delay=delay,
                             lag_time_constant=0.0, fit_percent=fit, method=method,
                             resolved=resolved, set_aside=set_aside)
    dynamics, tuning = _refine_setup(plant, opts, base=RefineOptions())
    estimate_lag = bool(opts.get('estimate_lag', True))
    refined = None
    if warm_start is not None and warm_start.model.n_modes == n:
        refined = _warm_fit(cur, enc, t, warm_start, bands=bands, dynamics=dynamics,
                            estimate_lag=estimate_lag, tuning=tuning, reference=reference)
    warm = refined is not None
    if refined is None:
        # Start from the paper pipeline (method A); its failure is not fatal because the
        # refined fit scans every band for its own start.
        try:
            initial = paper_pipeline(cur, enc, sample_period=t, method='A', **paper_opts).model
        except GalvoSysidError:
            initial = reference
        if initial.n_modes != n:
            raise ConfigurationError(f'the starting model has {initial.n_modes} modes, not {n}')
        refined = refine_fit(cur, enc, sample_period=t, initial=initial, bands=bands,
                             dynamics=dynamics, estimate_lag=estimate_lag,
                             extra_starts=opts.get('extra_starts', ()), options=tuning)
    return result_from_vectors(refined.model.parameters(), refined.std_by_name(), n_modes=n,
                         target_angle=angle, moves=moves, input_delay=refined.input_delay,
                         lag_time_constant=refined.lag_time_constant,
                         fit_percent=refined.fit_percent, method='refined',
                         resolved=refined.resolved, set_aside=set_aside,
                         crlb_std=_modal_only(refined.crlb_by_name()),
                         noise_model=refined.noise_models[0] if refined.noise_models else None,
                         warm_started=warm, cut_short=refined.cut_short)


def _warm_fit(cur: NDArray[np.float64], enc: NDArray[np.float64], t: float, warm: WarmStart, *,
              bands: Sequence[tuple[float, float]], dynamics: InputDynamics,
              estimate_lag: bool, tuning: RefineOptions,
              reference: ModalModel) -> RefinedFit | None:
    """The refined fit started from ``warm`` (:mod:`galvo_sysid.ident.warm`; its unresolved
    modes from ``reference``), or None where it fails or its cost is above what the noise
    allows (the caller then fits afresh)."""  # noqa: D205, D209
    if estimate_lag:
        dynamics = replace(dynamics, lag_time_constant=warm.lag_time_constant)
    try:
        fit = refine_fit(cur, enc, sample_period=t, initial=warm.start(reference), bands=bands,
                         dynamics=dynamics, estimate_lag=estimate_lag,
                         options=replace(tuning, keep_initial_damping=True, scan_points=0,
                                         search_unplaced=warm.from_model),
                         noise_model=warm.noise_model)
    except GalvoSysidError:
        return None
    return fit if plausible(fit.chi2, fit.rows) else None


def _screen(current: ArrayLike, encoder: ArrayLike, *, model: PlantModel,
            limit: float) -> tuple[ArrayLike, ArrayLike, tuple[tuple[int, str], ...]]:
    """The window without the moves :func:`~galvo_sysid.ident.screen.screen_moves` sets aside.

    Records that are not two numeric (M, N) arrays of one shape are passed on unscreened (the
    validation says what is wrong with them).
    """
    try:
        cur = np.asarray(current, dtype=float)
        enc = np.asarray(encoder, dtype=float)
    except (TypeError, ValueError):
        return current, encoder, ()
    if cur.ndim != 2 or cur.shape != enc.shape or cur.shape[1] <= 2 or limit == 0:
        return current, encoder, ()
    found = screen_moves(cur, enc, model=model, limit=limit)
    if not found.reasons:
        return cur, enc, ()
    return cur[found.keep], enc[found.keep], found.reasons


def _modal_only(values: dict[str, float]) -> dict[str, float]:
    return {k: v for k, v in values.items() if k != 'lag'}


def check_model_period(model: PlantModel, sample_period: float) -> None:
    """Raise ModelMismatchError if data of ``sample_period`` cannot be the model's."""
    if abs(sample_period - model.sample_period) > 1e-6 * model.sample_period:
        raise ModelMismatchError(
            f"the data's sample period {sample_period:.6g} s differs from the model's "
            f'{model.sample_period:.6g} s')


_PAPER_KEYS = frozenset({'delay', 'na', 'nb', 'solver', 'max_damping'})
"""Options of the paper pipeline (:func:`galvo_sysid.ident.paper.paper_pipeline`)."""

_REFINED_KEYS = frozenset({'lag_time_constant', 'computation_delay', 'dead_time',
                           'estimate_lag', 'extra_starts'}) | RefineOptions.names()
"""Options of the refined fit: the input dynamics, the lag's estimation, extra starts and
:class:`~galvo_sysid.ident.refine.RefineOptions`."""


def _refine_setup(model: PlantModel, opts: dict[str, Any], *,
                  base: RefineOptions) -> tuple[InputDynamics, RefineOptions]:
    """The refined fit's input dynamics (the model's, the lag as the start) and tuning, both
    overridden by ``opts``; the lag's bounds reach three times the model's lag."""  # noqa: D205, D209
    ph = model.physics()
    dynamics = InputDynamics(
        computation_delay=opts.get('computation_delay', ph.computation_delay),
        lag_time_constant=float(opts.get('lag_time_constant', ph.lag_time_constant)),
        dead_time=float(opts.get('dead_time', ph.dead_time)))
    lag_bounds = (0.0, max(3.0, 3.0 * ph.lag_time_constant / model.sample_period))
    tuning = RefineOptions.from_options(opts, base=replace(base, lag_bounds=lag_bounds))
    return dynamics, tuning


def identify_joint(windows: Sequence[tuple[ArrayLike, ArrayLike]], *, sample_period: float,
                   initial: IdentificationResult | ModalModel | None = None,
                   target_angle: float | None = None, model: PlantModel | None = None,
                   n_modes: int | None = None, noise_models: Sequence[NoiseModel | None] = (),
                   map_windows: MapWindows | None = None,
                   **options: Any) -> IdentificationResult:
    """Identify one modal model from several windows of the same plant (joint refined fit).

    The model (default: the paper's) sets modes, bands and input dynamics as for
    :func:`identify_window`.

    Args:
        windows: ``(current, encoder)`` per window, each (M_w, N_w) raw records as for
            :func:`identify_window` (M_w >= 3).
        sample_period: Sampling period [s].
        initial: Starting model; default: :func:`pool_results` of :func:`identify_window`
            on each window (windows whose single fit fails still enter the joint fit), whose
            noise models the joint fit then reuses (unless ``noise_models`` are given).
        target_angle: Reported angle (default: the common estimated angle, nan if they differ).
        model: The scanner's model (:class:`~galvo_sysid.model.plant.PlantModel`).
        n_modes: Resonant modes (default the model's; another number needs ``bands``).
        noise_models: Per window, the noise model its own refined fit weighed it with
            (:attr:`IdentificationResult.noise_model`), reused instead of estimated anew (see
            :func:`~galvo_sysid.ident.refine.refine_joint`); only for windows of exactly the
            moves that fit had (e.g. screened already: ``screen_limit=0``).
        map_windows: How the windows' large scans are shared out (e.g.
            :func:`galvo_sysid.field.jobs.fork_map`); None: in turn. The same fit either way.
        **options: ``bands``, ``reference``, ``min_angle_span`` and the refined options of
            :func:`identify_window` (``scan_points``, ``whiten_order``, ...), and
            ``keep_initial_damping`` (start from ``initial`` as it is; see
            :func:`galvo_sysid.ident.refine.refine_joint`).

    Returns:
        The joint estimate (``method='refined'``, ``moves`` the total).

    Raises:
        InvalidDataError: No windows or a bad window.
        IdentificationError: The joint fit failed.
        ConfigurationError: Bad options.
    """
    if not windows:
        raise InvalidDataError('no windows to fit')
    t = check_sample_period(sample_period)
    plant = PAPER_MODEL if model is None else model
    check_model_period(plant, t)
    opts = dict(options)
    reference: ModalModel = opts.get('reference', plant.modal)
    if n_modes is None:
        n_modes = reference.n_modes
    bands = opts.get('bands')
    if bands is None:
        if n_modes != plant.n_modes:
            raise ConfigurationError(f'{n_modes} modes asked but the model has '
                                     f'{plant.n_modes}; pass bands')
        bands = plant.mode_bands()
    min_span = float(opts.get('min_angle_span', MIN_ANGLE_SPAN))
    unknown = set(opts) - _REFINED_KEYS - _PAPER_KEYS - {'reference', 'bands',
                                                          'min_angle_span', 'screen_limit'}
    if unknown:
        raise ConfigurationError(f'unknown options for identify_joint: {sorted(unknown)}')
    screen_limit = float(opts.get('screen_limit', DEFAULT_SCREEN_LIMIT))
    records = []
    for j, (current, encoder) in enumerate(windows):
        try:
            current, encoder, _ = _screen(current, encoder, model=plant, limit=screen_limit)
            cur, enc = validate_records(current, encoder, min_records=3, min_angle_span=min_span)
        except InvalidDataError as exc:
            raise InvalidDataError(f'window {j}: {exc}') from exc
        records.append((cur, enc - enc[:, :1]))
    if isinstance(initial, IdentificationResult):
        start = initial.model
    elif isinstance(initial, ModalModel):
        start = initial
    else:
        singles = []
        models: list[NoiseModel | None] = []  # theirs, reused (one of other moves is not)
        for cur, enc in records:
            try:
                singles.append(identify_window(
                    cur, enc, sample_period=sample_period, model=plant, n_modes=n_modes,
                    **{k: v for k, v in opts.items() if k != 'keep_initial_damping'}))
            except GalvoSysidError:
                models.append(None)
                continue
            models.append(singles[-1].noise_model)
        start = pool_results(singles).model if singles else reference
        noise_models = noise_models or models
    if start.n_modes != n_modes:
        raise ConfigurationError(f'the starting model has {start.n_modes} modes, not {n_modes}')
    dynamics, tuning = _refine_setup(plant, opts, base=RefineOptions(adequacy_limit=0.0))
    fit = refine_joint(records, sample_period=t, initial=start, bands=bands, dynamics=dynamics,
                       estimate_lag=bool(opts.get('estimate_lag', True)), options=tuning,
                       noise_models=noise_models, map_windows=map_windows)
    if target_angle is None:
        est = np.array([_estimated_angle(enc) for _, enc in records])
        same = np.ptp(est) <= 0.01 * float(np.median(np.abs(est)))
        angle = float(np.median(est)) if same else float('nan')
    else:
        angle = float(target_angle)
    return result_from_vectors(fit.model.parameters(), fit.std_by_name(), n_modes=n_modes,
                         target_angle=angle, moves=int(sum(c.shape[0] for c, _ in records)),
                         input_delay=fit.input_delay, lag_time_constant=fit.lag_time_constant,
                         fit_percent=fit.fit_percent, method='refined', resolved=fit.resolved,
                         crlb_std=_modal_only(fit.crlb_by_name()))
