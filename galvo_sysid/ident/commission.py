"""Commissioning: learn a healthy scanner's model from its own moves, with no prior model.

What a servo analyzer's curve fit did for the paper (Table I), from ordinary positioning
moves instead (windows of moves of one target angle, as the sysid node collects them):

1. **Measured frequency response** (:func:`frequency_response`): the H1 estimate over the
   windows' averaged moves (both signals filtered by (1 - q^-1)^2), its standard deviation
   (move-to-move scatter, or the windows' disagreement where larger) and the coherence that
   follows; what the Bode plot shows. The model itself is fitted in the time domain.
2. **Input dynamics**: the whole samples of computation delay are chosen by the fit of the
   rigid body alone (0-3 samples, the amplifier lag free within 0-1.5 samples); the split
   between a last sample of delay and the lag is checked again after each mode is added, and
   a mode that does not fit under the current split is tried under the split one sample
   either side (a split chosen while a mode is missing can be the one under which that mode
   cannot be fitted).
3. **Modes, one at a time**: every frequency of the search range (300 Hz, or a record's
   length, up to 0.95 x Nyquist) and damping is scanned for the mode that lowers the joint
   fit's chi-square most; the mode is added and all are fitted again (joint refined fit,
   each window weighed by one fixed noise model, so fits of different orders compare: the
   stationary noise of the rigid body's residual, which counts the current disturbance that
   the controller cancels in the readings; the moves' scatter alone where that model
   cannot be made, and to choose the delay the first time). The number of modes is the one
   with the lowest Bayesian information criterion ``chi2 + parameters x ln(rows)``; a mode
   that would be unresolved, or end at its band's edge, is not added.
4. **Pooled fit**: the chosen model fitted jointly to every window (up to
   ``max_windows``), its covariance giving each parameter's standard deviation; bands
   around the modes.

A coil current measured when the encoder is read (``measured_current``) is first made into
the held current that drives it with no lag (the next reading) and commissioned; the amplifier
lag is then searched (:func:`~galvo_sysid.ident.measured.search_lag`: the pooled fit of the
selection's windows repeated on held currents made with trial lags until it finds the lag
they were made with), and the held current made with it is commissioned afresh.

The result (:class:`Commissioning`) holds the :class:`~galvo_sysid.model.plant.PlantModel`
(with its uncertainty and bands, ready for the file), the measured response and the steps
of the order selection; :mod:`galvo_sysid.field.commission` reads the bag and writes the file
and the plot.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from itertools import pairwise
from typing import TYPE_CHECKING, Any

import numpy as np

from galvo_sysid.errors import (
    ConfigurationError,
    GalvoSysidError,
    InvalidDataError,
    ModelMismatchError,
)
from galvo_sysid.ident.measured import LagSearch, held_windows, search_lag
from galvo_sysid.ident.preprocess import validate_records
from galvo_sysid.ident.refine import (
    RefinedFit,
    RefineOptions,
    added_mode_gains,
    refine_joint,
    second_difference,
    window_noise_filters,
)
from galvo_sysid.model.dynamics import InputDynamics, check_sample_period
from galvo_sysid.model.modal import ModalModel, default_bands
from galvo_sysid.model.plant import PlantModel

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from numpy.typing import ArrayLike, NDArray

    from galvo_sysid.ident.refine.whitener import NoiseModel, Whitener

__all__ = [
    'Commissioning',
    'FrequencyResponse',
    'OrderStep',
    'commission',
    'frequency_response',
]

_SCAN_POINTS = 240
_SCAN_DAMPING = (0.003, 0.01, 0.03)
_MAX_DELAY = 3
_LAG_BOUNDS = (0.0, 1.5)
_OPTIONS = RefineOptions(lag_bounds=_LAG_BOUNDS, scan_points=0, keep_initial_damping=True,
                         adequacy_limit=0.0)
"""Joint fits of commissioning: from the previous order's model as it is, the lag within
1.5 samples (beyond it the split from a whole sample of delay is ambiguous), no adequacy check
(a model of too low an order is expected to leave dynamics)."""
_MIN_SEPARATION = 1.08  # a new mode this close to a found one is the same mode
INADEQUATE_CHI2 = 3.0
"""The pooled fit's chi2 per row (about 1 for a model that explains the data to their noise)
above which commissioning warns that the model does not describe the data."""
_LEAD_GAIN = 4.0
"""The rigid body's chi2 this many times lower with the current one sample earlier, where the
pooled fit is inadequate (:data:`INADEQUATE_CHI2`): the current record leads the encoder."""
_PINNED_LEAD_GAIN = 2.0
"""The same where the pooled fit ends at no delay and no lag (it asks for less than none):
said whatever its chi2. A measured current can leave a chi2 per row below
:data:`INADEQUATE_CHI2` by a model with spurious modes (independent scanners 40 and 43: 4 and
6 modes for 3 and 1, chi2 per row 1.4 and 2.8, delay 0 and lag 0; their ratios 2.8 and 4.1),
while from a command the ratio stays at or below 1.12 (8 independent and 8 family scanners).
Not asked of every fit: a held current of scanner 43 (no delay, lag 0.43 T, fitted right)
gave a ratio above 2 (the rigid body alone, its mode left out)."""
_PINNED_LAG = 0.02
"""A fitted lag at most this many sample periods counts as none (its bound is 0)."""
_RIGID = ModalModel(k0=1.0, residues=(), natural_frequencies=(), damping_ratios=())
"""The rigid body alone: the start of the order selection and of the lead's test."""
_EVIDENCE = 25.0        # chi2 drop (5 sigma) a new mode needs before it is tried


@dataclass(frozen=True)
class FrequencyResponse:
    """The measured frequency response of the averaged moves (from command to angle).

    Attributes:
        omega: Angular frequencies [rad/s].
        response: The discrete response H(e^{j omega T}) (delay and ZOH included) [deg/A].
        std: Standard deviation of ``response`` [deg/A]: the larger of the move-to-move
            scatter's and the windows' disagreement's (which also holds what the records'
            start and end leave: ringing carried over from the previous move, leakage).
        coherence: |H|^2 / (|H|^2 + std^2): 1 where the data determine H, 0 in the noise.
    """

    omega: NDArray[np.float64]
    response: NDArray[np.complex128]
    std: NDArray[np.float64]
    coherence: NDArray[np.float64]


@dataclass(frozen=True)
class OrderStep:
    """One step of the order selection.

    Attributes:
        modes: Resonant modes of this fit.
        chi2: Its chi-square (about ``rows`` for an adequate model).
        bic: ``chi2 + parameters x ln(rows)``.
        added: Frequency of the mode added at this step [rad/s] (nan for the first).
        note: Why the step ended the search, if it did.
    """

    modes: int
    chi2: float
    bic: float
    added: float
    note: str = ''


@dataclass(frozen=True)
class Commissioning:
    """What commissioning learnt.

    Attributes:
        model: The scanner's model, with bands and standard deviations.
        fit: The pooled joint fit behind it.
        response: The measured frequency response.
        steps: The order selection, one entry per number of modes tried.
        windows: Windows in the pooled fit.
        selection_windows: Windows the order selection used.
        rows: Residual rows of the selection fits (for the criterion).
        warnings: What makes the model doubtful, one line each: it fits the data far worse
            than their noise (:data:`INADEQUATE_CHI2`), and why if that can be told; the
            current record leading the encoder by a sample (said also under that chi2 where
            the fit ends at no delay and no lag).
        measured_lag: With ``measured_current``: the amplifier lag the held current was made
            with, and how it was found (the model describes that held current); else None.
    """

    model: PlantModel
    fit: RefinedFit
    response: FrequencyResponse
    steps: tuple[OrderStep, ...]
    windows: int
    selection_windows: int
    rows: int
    warnings: tuple[str, ...] = ()
    measured_lag: LagSearch | None = None

    @property
    def n_modes(self) -> int:
        """Resonant modes found."""
        return self.model.n_modes


def frequency_response(windows: Sequence[tuple[ArrayLike, ArrayLike]], *,
                       sample_period: float) -> FrequencyResponse:
    """The H1 estimate over the windows' averaged moves, with its std and coherence.

    Args:
        windows: ``(current, encoder)`` records per window, each (M_w, N) with the same N.
        sample_period: Sampling period [s].

    Returns:
        The response at the FFT frequencies of the records (DC left out).

    Raises:
        InvalidDataError: No windows, records of different lengths, or fewer than 3 moves.
    """
    t = check_sample_period(sample_period)
    records = _records(windows)
    n = records[0][0].shape[1]
    if any(c.shape[1] != n for c, _ in records):
        raise InvalidDataError('all windows need records of the same length')
    # a half-Hann taper over the last 10 % of both signals: the records end before the
    # ringing has died out, which would leak across the band (their start, the move's own
    # start, is left as it is)
    edge = max(1, n // 10)
    taper = np.ones(n)
    taper[n - edge:] = 0.5 * (1 + np.cos(np.pi * (np.arange(edge) + 0.5) / edge))
    us, ys, noise = [], [], np.zeros(n // 2 + 1)
    for cur, enc in records:
        m = cur.shape[0]
        u = np.fft.rfft(taper * second_difference(cur.mean(axis=0)))
        dev = np.fft.rfft(taper * second_difference(enc - enc.mean(axis=0)), axis=1)
        var = np.sum(np.abs(dev) ** 2, axis=0) / (m * (m - 1))   # of the averaged y
        us.append(u)
        ys.append(np.fft.rfft(taper * second_difference(enc.mean(axis=0))))
        noise += np.abs(u) ** 2 * var
    u_all, y_all = np.array(us), np.array(ys)
    suu = np.sum(np.abs(u_all) ** 2, axis=0)
    omega = 2 * math.pi * np.fft.rfftfreq(n, t)
    keep = (omega > 0) & (suu > 0)
    u_all, y_all, suu = u_all[:, keep], y_all[:, keep], suu[keep]
    h = np.sum(y_all * np.conj(u_all), axis=0) / suu
    # Two spreads, the larger counts: the move-to-move scatter (noise), and the windows'
    # disagreement (also what a record's start and end leave: carried-over ringing, leakage).
    scatter = np.sqrt(noise[keep]) / suu
    w = len(records)
    if w > 1:
        spread = np.sum(np.abs(y_all - h * u_all) ** 2, axis=0) / suu**2 * w / (w - 1)
        std = np.maximum(scatter, np.sqrt(spread / w))
    else:
        std = scatter
    coherence = np.abs(h) ** 2 / (np.abs(h) ** 2 + std**2)
    return FrequencyResponse(omega=np.asarray(omega[keep], dtype=np.float64),
                             response=np.asarray(h, dtype=np.complex128),
                             std=np.asarray(std, dtype=np.float64),
                             coherence=np.asarray(coherence, dtype=np.float64))


def commission(windows: Sequence[tuple[ArrayLike, ArrayLike]], *, sample_period: float,
               max_modes: int = 6, search: tuple[float, float] | None = None,
               selection_windows: int = 8, max_windows: int = 64,
               record_length: int | None = None, dwell_length: int = 0,
               description: str = '', measured_current: bool = False,
               progress: Callable[[str], None] | None = None) -> Commissioning:
    """Learn the scanner's model from windows of its moves (see the module docs).

    Args:
        windows: ``(current, encoder)`` records per window of one target angle, (M_w, N).
        sample_period: Sampling period [s].
        max_modes: Most resonant modes looked for.
        search: Frequency range the modes are looked for in [rad/s] (default: 300 Hz or two
            periods per record, whichever is higher, to 0.95 x Nyquist).
        selection_windows: Windows the order selection fits (spread over the list).
        max_windows: Windows of the pooled fit at most (spread over the list).
        record_length: Samples per record for the model file (default: the records').
        dwell_length: Samples between a record and the next move, for the model file.
        description: Free text for the model file.
        measured_current: The current records are the coil current measured when the
            encoder is read: the amplifier lag is searched (:func:`.measured.search_lag`:
            commissioned as the next reading first, then the pooled model refitted to held
            currents made with trial lags) and the model learnt from the held current made
            with it (:func:`.measured.held_windows`), behind no computation delay.
        progress: Called with a line of text at each step.

    Returns:
        The commissioned model with its fit and the measured response.

    Raises:
        InvalidDataError: Too few windows or moves, bad records.
        IdentificationError: No fit succeeded.
        ConfigurationError: Bad options.
    """
    t = check_sample_period(sample_period)
    say = progress or (lambda _text: None)
    if not 1 <= int(max_modes) <= 16:
        raise ConfigurationError(f'max_modes must be within 1..16, got {max_modes}')
    records = _records(windows)
    if measured_current:
        return _commission_measured(records, t=t, max_modes=max_modes, search=search,
                                    selection_windows=selection_windows,
                                    max_windows=max_windows, record_length=record_length,
                                    dwell_length=dwell_length, description=description,
                                    say=say)
    return _commission(records, t=t, max_modes=max_modes, search=search,
                       selection_windows=selection_windows, max_windows=max_windows,
                       record_length=record_length, dwell_length=dwell_length,
                       description=description, say=say)


def _commission(records: list[tuple[NDArray[np.float64], NDArray[np.float64]]], *, t: float,
                max_modes: int, search: tuple[float, float] | None, selection_windows: int,
                max_windows: int, record_length: int | None, dwell_length: int,
                description: str, say: Callable[[str], None]) -> Commissioning:
    """Commissioning of checked records (see :func:`commission`)."""
    n_samples = records[0][0].shape[1]
    lo, hi = _search_range(search, t, n_samples)
    chosen = _spread(records, selection_windows)
    filters = window_noise_filters(chosen)
    response = frequency_response(records, sample_period=t)
    say(f'{len(records)} windows, {sum(c.shape[0] for c, _ in records)} moves; order selection '
        f'on {len(chosen)} windows, modes looked for in {lo / (2e3 * math.pi):.3g}..'
        f'{hi / (2e3 * math.pi):.3g} kHz')

    models: tuple[NoiseModel, ...] = ()  # the noise the selection weighs by, once found

    def fit(modal: ModalModel, delay: int, lag: float) -> RefinedFit:
        return refine_joint(chosen, sample_period=t, initial=modal,
                            dynamics=InputDynamics(computation_delay=delay,
                                                   lag_time_constant=lag),
                            bands=_bands(modal, lo, hi), options=_OPTIONS,
                            noise_filters=None if models else filters, noise_models=models)

    current, delay = _rigid_body(fit, t)
    # The moves' scatter is not the noise a model's residual carries in a closed loop: below
    # the crossover the controller cancels the current disturbance, so the readings scatter
    # little while the residual (that disturbance through the plant) is large, and every
    # low-frequency candidate seems to lower chi2 more than a real resonance does (a scanner
    # of the independent simulator, test/independent_scanner.py seed 10: its one mode was
    # never tried). The selection weighs each window by the noise the rigid body's residual
    # shows (its stationary noise model) and chooses the delay again with it.
    models = _residual_noise(chosen, current, t)
    if models:
        current, delay = _rigid_body(fit, t)
    rows = current.rows
    windows_used = len(chosen)

    def bic(f: RefinedFit) -> float:
        params = 1 + 4 * f.model.n_modes + 1 + windows_used * (2 + 2 * f.model.n_modes)
        return f.chi2 + params * math.log(rows)

    steps = [OrderStep(modes=0, chi2=current.chi2, bic=bic(current), added=math.nan)]
    kept = [current]  # the fit of each number of modes kept
    say(f'rigid body: computation delay {delay} sample(s), lag '
        f'{current.lag_time_constant / t:.2f} T, chi2/rows {current.chi2 / rows:.3g}')
    while current.model.n_modes < max_modes:
        candidate, note = _add_mode(chosen, current, (filters, models), lo, hi, fit, delay, t)
        if candidate is None:
            steps[-1] = replace(steps[-1], note=note)
            break
        added = _new_frequency(current.model, candidate.model)
        step = OrderStep(modes=candidate.model.n_modes, chi2=candidate.chi2,
                         bic=bic(candidate), added=added)
        say(f'{step.modes} mode(s): added {added / (2e3 * math.pi):.4g} kHz, chi2/rows '
            f'{step.chi2 / rows:.3g}, BIC {step.bic:.6g}')
        if step.bic >= steps[-1].bic:
            steps.append(replace(step, note='the information criterion rose: not kept'))
            break
        current = _check_delay_split(candidate, fit, candidate.computation_delay, t)
        if current.computation_delay != delay:
            delay = current.computation_delay
            step = replace(step, chi2=current.chi2, bic=bic(current))
            say(f'  computation delay now {delay} sample(s), lag '
                f'{current.lag_time_constant / t:.2f} T, chi2/rows {current.chi2 / rows:.3g}')
        steps.append(step)
        kept.append(current)
    else:
        steps[-1] = replace(steps[-1], note=f'stopped at max_modes={max_modes}')
    pooled_records = _spread(records, max_windows)
    while True:  # a mode the pooled fit ends at its band's edge: the order below it
        try:
            final = _pooled(pooled_records, kept[-1], lo, hi, t)
            break
        except ModelMismatchError as err:
            if len(kept) == 1:
                raise
            n = kept.pop().model.n_modes
            j = max(j for j, st in enumerate(steps) if st.modes == n)
            steps[j] = replace(steps[j], note=f'not kept: the pooled fit over every window '
                                              f'said {err}')
            say(f'{n} mode(s) not kept: the pooled fit said {err}')
    warnings = _adequacy(final, chosen, t)
    for text in warnings:
        say(f'warning: {text}')
    say(f'pooled fit over {len(pooled_records)} windows: {final.model.n_modes} mode(s), fit '
        f'{final.fit_percent:.2f} %')
    model = _to_model(final, t, record_length=record_length or n_samples,
                      dwell_length=dwell_length, description=description)
    return Commissioning(model=model, fit=final, response=response, steps=tuple(steps),
                         windows=len(pooled_records), selection_windows=len(chosen),
                         rows=rows, warnings=warnings)


def _search_range(search: tuple[float, float] | None, t: float,
                  n_samples: int) -> tuple[float, float]:
    """The frequency range the modes are looked for in [rad/s] (see :func:`commission`)."""
    nyquist = math.pi / t
    lo, hi = search if search is not None else (
        2 * math.pi * max(300.0, 2.0 / (n_samples * t)), 0.95 * nyquist)
    if not 0 < lo < hi <= nyquist:
        raise ConfigurationError(f'search range {lo:.4g}..{hi:.4g} rad/s must lie below '
                                 f'Nyquist ({nyquist:.4g} rad/s)')
    return lo, hi


def _commission_measured(records: list[tuple[NDArray[np.float64], NDArray[np.float64]]], *,
                         t: float, say: Callable[[str], None],
                         **options: Any) -> Commissioning:
    """Commissioning of measured currents: the amplifier lag searched, then the held current's.

    The held current made with no lag (the next reading) is commissioned first; its order and
    computation delay then stay while the pooled fit of the selection's windows is repeated
    on held currents made with trial lags until the fit finds the lag they were made with
    (where a trial's fit fails, a mode the next reading needed ending at its band's edge, the
    trial's held current is commissioned afresh and its model kept for the next trials); the
    held current made with that lag is commissioned afresh.
    """
    say('measured current: commissioned as the next reading first, to find the amplifier lag')
    first = _commission(held_windows(records, sample_period=t, lag=0.0), t=t, say=say,
                        **options)
    chosen = _spread(records, int(options['selection_windows']))
    lo, hi = _search_range(options['search'], t, records[0][0].shape[1] - 1)
    models = [first.fit]  # the latest model the trial fits start from

    def fitted_lag(lag: float) -> float:
        fit = models[-1]
        try:
            refit = refine_joint(
                held_windows(chosen, sample_period=t, lag=lag), sample_period=t,
                initial=fit.model, dynamics=InputDynamics(
                    computation_delay=fit.computation_delay,
                    lag_time_constant=fit.lag_time_constant),
                bands=_bands(fit.model, lo, hi), options=_OPTIONS)
        except GalvoSysidError as err:
            # a mode the next reading needed is not in this held current (it ends at its
            # band's edge): the modes are chosen again for it, and kept for the next trials
            say(f'  held current made with a lag of {lag / t:.3f} T: {err}; its modes chosen '
                f'again')
            refit = _commission(held_windows(records, sample_period=t, lag=lag), t=t,
                                say=say, **options).fit
            models.append(refit)
        say(f'  held current made with a lag of {lag / t:.3f} T: the fit finds '
            f'{refit.lag_time_constant / t:.3f} T')
        return refit.lag_time_constant

    found = search_lag(fitted_lag, sample_period=t, upper=_LAG_BOUNDS[1] * t,
                       first=(0.0, first.fit.lag_time_constant))
    say(f'amplifier lag {found.lag / t:.3f} T ({found.lag * 1e6:.3g} us)'
        + ('' if found.converged else ': the search did not settle'))
    final = _commission(held_windows(records, sample_period=t, lag=found.lag), t=t, say=say,
                        **options)
    warnings = final.warnings
    if not found.converged:
        warnings += (f'the amplifier lag of the measured current did not settle (last '
                     f'{found.lag / t:.3g} T, the fit finding '
                     f'{found.steps[-1][1] / t:.3g} T): the held current may be wrong',)
    return replace(final, warnings=warnings, measured_lag=found)


def _adequacy(final: RefinedFit,
              chosen: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
              t: float) -> tuple[str, ...]:
    """Warnings on a pooled fit far worse than the noise, and on a current record that leads
    the encoder (see :attr:`Commissioning.warnings`).

    A current record that leads the encoder by a sample (a measured coil current sampled at
    the encoder's instant: the current flowing over a sample period is the next sample's,
    which no delay of the model can express) is told by the rigid body fitting
    :data:`_LEAD_GAIN` times better with the current one sample earlier; where the pooled
    fit ends at no delay and no lag, :data:`_PINNED_LEAD_GAIN` times, whatever its chi2.
    """  # noqa: D205
    ratio = final.chi2 / max(final.rows, 1)
    inadequate = ratio > INADEQUATE_CHI2
    pinned = final.computation_delay == 0 and final.lag_time_constant <= _PINNED_LAG * t
    if not (inadequate or pinned):
        return ()
    out = [f'the model fits these data {ratio:.3g} times worse than their noise (chi2 per '
           f'row; about 1 for a model that explains them): its parameters and standard '
           f'deviations do not hold'] if inadequate else []

    def rigid_chi2(records: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
                   delay: int) -> float:
        try:
            fit = refine_joint(records, sample_period=t, initial=_RIGID,
                               dynamics=InputDynamics(computation_delay=delay,
                                                      lag_time_constant=0.5 * t),
                               bands=(), options=_OPTIONS)
        except GalvoSysidError:
            return math.inf
        return fit.chi2 / max(fit.rows, 1)

    as_is = min(rigid_chi2(chosen, d) for d in range(2))
    led = rigid_chi2([(c[:, 1:], e[:, :-1]) for c, e in chosen], 0)
    if led * (_PINNED_LEAD_GAIN if pinned else _LEAD_GAIN) < as_is:
        out.append(f'the current record leads the encoder by one sample (the rigid body fits '
                   f'{as_is / led:.3g} times better with it one sample earlier: a measured '
                   f'current sampled with the encoder?); commission again with '
                   f"--measured-current (the amplifier's lag is then found from the data)")
    elif inadequate:
        out.append('the data hold dynamics the model cannot describe (a mode outside the '
                   'search range, friction, saturation, a current record not aligned with '
                   'the encoder): galvo-sysid discrepancy compares a model with them; a coil '
                   'current measured when the encoder is read (not the command) is '
                   'commissioned with --measured-current')
    return tuple(out)


def _records(windows: Sequence[tuple[ArrayLike, ArrayLike]]) -> list[
        tuple[NDArray[np.float64], NDArray[np.float64]]]:
    if not windows:
        raise InvalidDataError('no windows to commission from')
    out = []
    for j, (current, encoder) in enumerate(windows):
        try:
            cur, enc = validate_records(current, encoder, min_records=3)
        except InvalidDataError as exc:
            raise InvalidDataError(f'window {j}: {exc}') from exc
        out.append((cur, enc - enc[:, :1]))
    return out


def _spread(records: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
            count: int) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """At most ``count`` of the records, evenly spread over the list."""
    if len(records) <= count:
        return list(records)
    picks = np.unique(np.linspace(0, len(records) - 1, count).round().astype(int))
    return [records[i] for i in picks]


def _bands(modal: ModalModel, lo: float, hi: float) -> tuple[tuple[float, float], ...]:
    """Bands meeting between the modes, the outer ones reaching the search range's ends."""
    w = modal.natural_frequencies
    if not w:
        return ()
    edges = [lo, *(math.sqrt(a * b) for a, b in pairwise(w)), hi]
    return tuple(pairwise(edges))


def _rigid_body(fit: Callable[[ModalModel, int, float], RefinedFit], t: float) -> tuple[
        RefinedFit, int]:
    """The rigid body's best fit over the whole samples of delay, and its delay."""
    fits = []
    for delay in range(_MAX_DELAY + 1):
        try:
            fits.append((fit(_RIGID, delay, 0.5 * t), delay))
        except GalvoSysidError:
            continue
    if not fits:
        raise InvalidDataError('not even the rigid body fits these windows')
    return min(fits, key=lambda f: f[0].chi2)


def _residual_noise(chosen: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
                    current: RefinedFit, t: float) -> tuple[NoiseModel, ...]:
    """Each window's stationary noise model under ``current``'s model (empty if one of them
    cannot be made: the selection then keeps the moves' scatter)."""  # noqa: D205, D209
    try:
        free = refine_joint(chosen, sample_period=t, initial=current.model,
                            dynamics=current.dynamics, options=_OPTIONS)
    except GalvoSysidError:
        return ()
    found = tuple(m for m in free.noise_models if m is not None)
    return found if len(found) == len(chosen) else ()


def _add_mode(chosen: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
              current: RefinedFit,
              noise: tuple[list[Whitener | None], tuple[NoiseModel, ...]], lo: float, hi: float,
              fit: Callable[[ModalModel, int, float], RefinedFit],
              delay: int, t: float) -> tuple[RefinedFit | None, str]:
    """The fit with one more mode at the best scanned candidate, or (None, why not).

    Where that fit fails or leaves a mode unresolved with the current split of the delay into
    samples and lag, the splits one sample either side are tried too (the same equivalent
    delay): a split chosen while a mode was missing can be the wrong one, and then the mode
    does not fit (``random_scanner(29)``: 1 sample + 1.07 T chosen without its 7.3 kHz mode,
    which then ended at the damping bound; the truth is 2 samples + 0.04 T).
    """
    grid = np.geomspace(lo * 1.01, hi / 1.01, _SCAN_POINTS)
    w_c = np.repeat(grid, len(_SCAN_DAMPING))
    z_c = np.tile(np.array(_SCAN_DAMPING), grid.size)
    found = np.array(current.model.natural_frequencies)
    if found.size:
        near = np.min(np.abs(np.log(w_c[:, None] / found[None, :])), axis=1)
        far = near > math.log(_MIN_SEPARATION)
        w_c, z_c = w_c[far], z_c[far]
    gains = added_mode_gains(chosen, current, noise_filters=noise[0], candidates=(w_c, z_c),
                             noise_models=noise[1])
    best = int(np.argmax(gains))
    if not gains[best] > _EVIDENCE:
        return None, f'no further mode lowers chi2 by {_EVIDENCE:g} (best {gains[best]:.3g})'
    m = current.model
    order = np.argsort([*m.natural_frequencies, w_c[best]])
    freqs = np.array([*m.natural_frequencies, w_c[best]])[order]
    damps = np.array([*m.damping_ratios, z_c[best]])[order]
    start = ModalModel(k0=m.k0, residues=(0.0,) * freqs.size,
                       natural_frequencies=tuple(float(f) for f in freqs),
                       damping_ratios=tuple(float(z) for z in damps))
    why = ''
    kept: RefinedFit | None = None
    splits = [(delay, current.lag_time_constant),
              *_other_splits(delay, delay * t + current.lag_time_constant, t)]
    for split_delay, lag in splits:
        try:
            candidate = fit(start, split_delay, lag)
        except GalvoSysidError as err:
            why = why or f'the fit with one more mode failed ({err})'
            continue
        if candidate.unresolved_modes:
            why = why or (f'one more mode would leave mode(s) '
                          f'{list(candidate.unresolved_modes)} unresolved')
            continue
        if kept is None or candidate.chi2 < kept.chi2:
            kept = candidate
        if split_delay == delay:
            break  # the current split takes the mode: the others are tried afterwards
    if kept is None:
        return None, why
    return kept, ''


def _other_splits(delay: int, equivalent: float, t: float) -> list[tuple[int, float]]:
    """One sample of pure delay more and one less, each with the lag that keeps the
    equivalent delay (within the lag's bounds)."""  # noqa: D205, D209
    out = []
    for other in (delay - 1, delay + 1):
        if 0 <= other <= _MAX_DELAY:
            out.append((other, min(max(equivalent - other * t, 0.05 * t),
                                   (_LAG_BOUNDS[1] - 0.05) * t)))
    return out


def _new_frequency(old: ModalModel, new: ModalModel) -> float:
    """The frequency of ``new`` farthest from every frequency of ``old``."""
    if not old.natural_frequencies:
        return float(new.natural_frequencies[0])
    dist = [min(abs(math.log(w / v)) for v in old.natural_frequencies)
            for w in new.natural_frequencies]
    return float(new.natural_frequencies[int(np.argmax(dist))])


def _check_delay_split(current: RefinedFit, fit: Callable[[ModalModel, int, float], RefinedFit],
                       delay: int, t: float) -> RefinedFit:
    """Try one sample more and one less of pure delay (the lag starting from the rest of the
    equivalent delay); keep the lowest chi2."""  # noqa: D205, D209
    best = current
    for other, lag in _other_splits(delay, delay * t + current.lag_time_constant, t):
        try:
            trial = fit(current.model, other, lag)
        except GalvoSysidError:
            continue
        if trial.chi2 < best.chi2 and not trial.unresolved_modes:
            best = trial
    return best


def _pooled(records: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
            current: RefinedFit, lo: float, hi: float, t: float) -> RefinedFit:
    """The chosen model fitted jointly to the pooled windows (prewhitened per window)."""
    return refine_joint(records, sample_period=t, initial=current.model,
                        dynamics=current.dynamics, bands=_bands(current.model, lo, hi),
                        options=_OPTIONS)


def _to_model(fit: RefinedFit, t: float, *, record_length: int,
              dwell_length: int, description: str) -> PlantModel:
    """The plant model of a fit: its modes, their std and bands around them."""
    modal = fit.model
    std = fit.std_by_name()
    uncertainty = {name: std[name] for name in modal.parameters() if name in std}
    if 'lag' in std:
        uncertainty['lag_time_constant'] = std['lag']
    bands = default_bands(modal, sample_period=t) if modal.n_modes else None
    return PlantModel(modal=modal, dynamics=InputDynamics(
        computation_delay=fit.computation_delay, lag_time_constant=fit.lag_time_constant),
        sample_period=t, bands=bands, uncertainty=tuple(uncertainty.items()),
        record_length=record_length, dwell_length=dwell_length, description=description)
