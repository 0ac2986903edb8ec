"""The paper's identification pipeline, end to end (paper Sec. IV-V).

:func:`paper_pipeline` takes one window of records (M moves of the same rotation) and runs:

1. validation (:func:`galvo_sysid.ident.preprocess.validate_records`) and start-angle removal;
2. pre-processing: method A (average of the records) or method B (records concatenated);
3. the fictitious input u~ = P_delay[z] u (:func:`galvo_sysid.ident.delay.paper_delay_filter`,
   Tustin of the 3rd-order Pade approximation, for the paper's 1.6 T or an estimated delay);
4. ARX(15, 15) by the normal equations (or QR);
5. zero-order-hold conversion and modal decomposition
   (:func:`galvo_sysid.ident.decompose.modal_decomposition`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from galvo_sysid.errors import ConfigurationError, GalvoSysidError
from galvo_sysid.ident.arx import ArxModel, fit_arx
from galvo_sysid.ident.decompose import DEFAULT_MAX_DAMPING, modal_decomposition, simulate_zoh
from galvo_sysid.ident.delay import estimate_delay, fictitious_input, paper_delay_filter
from galvo_sysid.ident.preprocess import (
    MIN_ANGLE_SPAN,
    MIN_RECORDS,
    average_records,
    concatenate_records,
    validate_records,
)
from galvo_sysid.model import (
    REFERENCE_MODEL,
    TAU,
    ModalModel,
    relative_errors,
)

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from numpy.typing import ArrayLike, NDArray

__all__ = [
    'PAPER_DELAY',
    'PaperResult',
    'format_error_table',
    'group_deleted_models',
    'paper_pipeline',
    'relative_error_table',
]

PAPER_DELAY = 1.6 * TAU
"""The paper's equivalent input delay [s] (1.6 sample periods of 10 us)."""

@dataclass(frozen=True)
class PaperResult:
    """Outcome of :func:`paper_pipeline`.

    Attributes:
        model: The identified modal model P_mech (k0, k_i, omega_i, zeta_i).
        arx: The ARX model of P_mech[z] (from the fictitious input).
        delay: The equivalent input delay removed [s] (given or estimated).
        method: ``'A'`` or ``'B'``.
        cond: cond(R) of the normal equations.
        fit_percent: ``100 (1 - ||y - y_m|| / ||y - mean(y)||)`` on the window's averaged
            output, y_m the identified modal model (ZOH) driven by the averaged fictitious input.
    """

    model: ModalModel
    arx: ArxModel
    delay: float
    method: str
    cond: float
    fit_percent: float

    def relative_errors(self, reference: ModalModel = REFERENCE_MODEL) -> dict[str, float]:
        """Relative errors of :attr:`model` against ``reference`` (fractions, not %)."""
        return relative_errors(self.model, reference)


def _fit_percent(model: ModalModel, u_tilde: NDArray[np.float64], y: NDArray[np.float64],
                 sample_period: float) -> float:
    y_m = simulate_zoh(model, u_tilde, sample_period=sample_period)
    den = float(np.linalg.norm(y - np.mean(y)))
    if den == 0:
        return float('nan')
    return float(100.0 * (1.0 - np.linalg.norm(y - y_m) / den))


def paper_pipeline(current: ArrayLike, encoder: ArrayLike, *, sample_period: float,
                   method: str = 'A', delay: float | None = PAPER_DELAY, na: int = 15,
                   nb: int = 15, solver: str = 'normal',
                   bands: Sequence[tuple[float, float]] | None = None,
                   max_damping: float = DEFAULT_MAX_DAMPING,
                   reference: ModalModel = REFERENCE_MODEL,
                   min_angle_span: float = MIN_ANGLE_SPAN,
                   input_filter: tuple[ArrayLike, ArrayLike] | None = None) -> PaperResult:
    """Identify P_mech from one window of move records the paper's way.

    Args:
        current: Current records [A], shape (M, N).
        encoder: Encoder records [deg], shape (M, N), raw (start angles are removed here).
        sample_period: Sample period T [s].
        method: ``'A'`` (average the records) or ``'B'`` (concatenate them).
        delay: Equivalent input delay [s] removed by the fictitious input; default the paper's
            1.6 tau = 16 us; ``None`` estimates it
            (:func:`galvo_sysid.ident.delay.estimate_delay` on the method-A average); ``0`` removes
            nothing (the raw input).
        na: ARX denominator order.
        nb: ARX numerator order.
        solver: ``'normal'`` (the paper's normal equations) or ``'qr'``.
        bands: Frequency band [rad/s] of each mode; default around ``reference``.
        max_damping: Largest damping ratio of a mode.
        reference: Model setting the default bands.
        min_angle_span: Smallest averaged move [deg] that counts as excitation.
        input_filter: ``(b, a)`` (powers of z^-1) to use for the fictitious input instead of
            the paper's Pade filter for ``delay`` (e.g.
            :func:`galvo_sysid.ident.delay.lag_delay_filter`); ``delay`` is then only reported.

    Returns:
        The identified model and fit details.

    Raises:
        InvalidDataError: Bad records (see :func:`galvo_sysid.ident.preprocess.validate_records`).
        IdentificationError: Singular regression, no rigid body or no mode in a band.
        ConfigurationError: Bad method, solver, orders or delay.
    """
    _check_method(method, sample_period)
    cur, enc = validate_records(current, encoder, na=na, nb=nb, min_angle_span=min_angle_span)
    u_avg, y_avg = average_records(cur, enc)
    d = _delay_of(u_avg, y_avg, sample_period=sample_period, delay=delay, na=na, nb=nb,
                  reference=reference)
    b, a = _input_filter(d, sample_period=sample_period, given=input_filter)
    u, y = (u_avg, y_avg) if method == 'A' else concatenate_records(cur, enc)
    u_tilde = fictitious_input(u, b, a)
    model, arx = _fit(u_tilde, y, sample_period=sample_period, na=na, nb=nb, solver=solver,
                      bands=bands, max_damping=max_damping, reference=reference)
    u_avg_tilde = u_tilde if method == 'A' else fictitious_input(u_avg, b, a)
    fit = _fit_percent(model, u_avg_tilde, y_avg, sample_period)
    return PaperResult(model=model, arx=arx, delay=d, method=method, cond=arx.cond,
                       fit_percent=fit)


def group_deleted_models(current: ArrayLike, encoder: ArrayLike, *, groups: int,
                         sample_period: float, method: str = 'A',
                         delay: float | None = PAPER_DELAY, na: int = 15, nb: int = 15,
                         solver: str = 'normal',
                         bands: Sequence[tuple[float, float]] | None = None,
                         max_damping: float = DEFAULT_MAX_DAMPING,
                         reference: ModalModel = REFERENCE_MODEL,
                         min_angle_span: float = MIN_ANGLE_SPAN,
                         input_filter: tuple[ArrayLike, ArrayLike] | None = None,
                         ) -> list[ModalModel | None]:
    """The models of :func:`paper_pipeline` with one group of moves left out, for a jackknife.

    Move i is in group ``i % groups``; entry j is the model of the window without group j, or
    None where that fit fails (as :func:`paper_pipeline` would raise). The models are
    :func:`paper_pipeline`'s on the same moves, bit for bit; what is saved is its work not
    needed for a jackknife: the records are validated once (of each part only what a part
    of valid records can fail: too few records, no current, no excitation), and no fit
    percentage is computed.
    (Group-deleted averages from the groups' sums would save a little more but change the
    models by about 1e-6 relative: the normal equations amplify the rounding.)

    Args:
        current: Current records [A], shape (M, N), M >= ``groups``.
        encoder: Encoder records [deg], shape (M, N), raw.
        groups: Number of groups (>= 2).
        sample_period: Sample period T [s].
        method: ``'A'`` or ``'B'``.
        delay: As for :func:`paper_pipeline` (None: estimated per group-deleted window).
        na: ARX denominator order.
        nb: ARX numerator order.
        solver: ``'normal'`` or ``'qr'``.
        bands: Frequency band [rad/s] of each mode.
        max_damping: Largest damping ratio of a mode.
        reference: Model setting the default bands.
        min_angle_span: Smallest averaged move [deg] that counts as excitation.
        input_filter: As for :func:`paper_pipeline`.

    Returns:
        ``groups`` models (or None).

    Raises:
        InvalidDataError: The whole window's records are bad.
        ConfigurationError: Bad method, groups, solver, orders or delay.
    """
    _check_method(method, sample_period)
    cur, enc = validate_records(current, encoder, na=na, nb=nb, min_angle_span=min_angle_span)
    m = cur.shape[0]
    if not 2 <= groups <= m:
        raise ConfigurationError(f'groups must be in 2..{m} (the moves), got {groups}')
    labels = np.arange(m) % groups
    out: list[ModalModel | None] = []
    fixed = None  # a given delay's filter is every group's
    if delay is not None:
        fixed = _input_filter(_given_delay(delay), sample_period=sample_period,
                              given=input_filter)
    for j in range(groups):
        c, e = cur[labels != j], enc[labels != j]
        u_avg, y_avg = average_records(c, e)
        # validate_records' checks that a part of valid records can fail
        if c.shape[0] < MIN_RECORDS or not np.any(c) or float(np.ptp(y_avg)) < min_angle_span:
            out.append(None)
            continue
        u, y = (u_avg, y_avg) if method == 'A' else concatenate_records(c, e)
        try:
            b, a = fixed if fixed is not None else _input_filter(
                _delay_of(u_avg, y_avg, sample_period=sample_period, delay=None, na=na, nb=nb,
                          reference=reference), sample_period=sample_period, given=input_filter)
            out.append(_fit(fictitious_input(u, b, a), y, sample_period=sample_period, na=na,
                            nb=nb, solver=solver, bands=bands, max_damping=max_damping,
                            reference=reference)[0])
        except GalvoSysidError:
            out.append(None)
    return out


def _check_method(method: str, sample_period: float) -> None:
    if method not in ('A', 'B'):
        raise ConfigurationError(f"method must be 'A' or 'B', got {method!r}")
    if not (np.isfinite(sample_period) and sample_period > 0):
        raise ConfigurationError(f'sample_period must be positive and finite, got {sample_period}')


def _delay_of(u_avg: NDArray[np.float64], y_avg: NDArray[np.float64], *, sample_period: float,
              delay: float | None, na: int, nb: int, reference: ModalModel) -> float:
    """The delay removed [s]: ``delay``, or None estimated on the averaged records."""
    if delay is None:
        return estimate_delay(u_avg, y_avg, sample_period=sample_period, na=na, nb=nb,
                              reference=reference).delay
    return _given_delay(delay)


def _given_delay(delay: float) -> float:
    """``delay`` [s], checked."""
    if isinstance(delay, int | float) and np.isfinite(delay) and delay >= 0:
        return float(delay)
    raise ConfigurationError(f'delay must be a finite number >= 0 or None, got {delay!r}')


def _input_filter(delay: float, *, sample_period: float,
                  given: tuple[ArrayLike, ArrayLike] | None,
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The fictitious input's filter ``(b, a)``: ``given``, or the paper's for ``delay``."""
    if given is None:
        return paper_delay_filter(sample_period=sample_period, delay=delay)
    b, a = (np.asarray(c, dtype=float) for c in given)
    return b, a


def _fit(u_tilde: NDArray[np.float64], y: NDArray[np.float64], *, sample_period: float,
         na: int, nb: int, solver: str, bands: Sequence[tuple[float, float]] | None,
         max_damping: float, reference: ModalModel) -> tuple[ModalModel, ArxModel]:
    """ARX on the fictitious input, then the modal decomposition."""
    arx = fit_arx(u_tilde, y, sample_period=sample_period, na=na, nb=nb, solver=solver)
    model = modal_decomposition(arx, bands=bands, max_damping=max_damping,
                                reference=reference).model
    return model, arx


def relative_error_table(models: Mapping[str, ModalModel], *,
                         reference: ModalModel = REFERENCE_MODEL) -> dict[str, dict[str, float]]:
    """Relative errors [%] of several models: ``{label: {parameter: error_percent}}``."""
    return {label: {k: 100.0 * v for k, v in relative_errors(m, reference).items()}
            for label, m in models.items()}


def format_error_table(table: Mapping[str, Mapping[str, float]], *, digits: int = 4) -> str:
    """Format :func:`relative_error_table` output (or the paper's Table II) as text columns."""
    labels = list(table)
    if not labels:
        return ''
    names = list(table[labels[0]])
    width = max(12, digits + 8)
    lines = ['parameter'.ljust(10) + ''.join(label.rjust(width) for label in labels)]
    for name in names:
        cells = ''.join(f'{table[label][name]:{width}.{digits}g}' for label in labels)
        lines.append(name.ljust(10) + cells)
    return '\n'.join(lines)
