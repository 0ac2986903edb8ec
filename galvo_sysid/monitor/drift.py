"""Drift of the identified plant from its reference model: one verdict per window.

:class:`DriftMonitor` is a small task object (like the monitors of ros/diagnostics): the
watchdog node feeds it each window's identification result and publishes the
:class:`~galvo_sysid.monitor.verdict.DriftVerdict`; ``galvo-sysid identify --json`` uses the
same object for each window's ``drift`` entry.

Each parameter's relative deviation ``d = (identified - reference) / reference`` is judged
against a relative tolerance and against the estimate's own noise: a deviation is significant
only when ``|d| > n_sigma * hypot(s, f)``, with ``s`` the identified standard deviation
relative to the reference and ``f`` the parameter's noise floor (the window-to-window scatter
of the identification, which the reported std of a poorly observable parameter may
understate), so a deviation well inside the estimate's noise is never drift.

- MISMATCH: the window was not identified because its data do not match the plant model
  (``status`` not OK), or it has another number of modes than the reference: the scanner is
  not the one the reference describes. Never reported as parameter drift.
- ERROR: a significant deviation beyond the tolerance.
- WARN: a significant deviation beyond ``warn_fraction`` of the tolerance, a drift building up
  (below), or a window the model fits poorly (``fit_percent < min_fit_percent``).
- OK: otherwise.

The parameters of a mode the result marks unresolved (``resolved``: its residue is not
significant, so its numbers say nothing) are not judged: the message says ``mode 3
unresolved`` and their deviations are NaN.

Drift that builds up over several windows is found by a weighted linear trend test over the
last ``trend_windows`` windows, pooled over target angles: a parameter whose deviation has a
slope ``trend_sigma`` standard errors from zero, moving away from the reference and already
beyond ``trend_fraction`` of its tolerance (fitted and latest value), is flagged (WARN) before
any single window crosses the tolerance. A jump between consecutive windows beyond
``step_fraction`` of the tolerance restarts that parameter's trend history (a step is not a
trend, and the windows before it would fake one). The window-to-window scatter of the
identification (``noise_floor``, relative) is added to the reported standard deviations, and
the slope's standard error is widened when the residual scatter is larger than expected, so
angle-dependent identification biases do not look like a trend.

Tolerances and noise floors are relative, per parameter name or kind; the rule that picks
them is :mod:`galvo_sysid.monitor.tolerances`. The verdict itself, its levels and the result
statuses are :mod:`galvo_sysid.monitor.verdict`; the watchdog's monitor from its parameters is
:func:`galvo_sysid.monitor.reference.monitor_from_parameters`.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model import REFERENCE_MODEL, ModalModel, model_label
from galvo_sysid.monitor.parameters import WATCHDOG_PARAMETERS, defaults
from galvo_sysid.monitor.tolerances import (
    DEFAULT_KIND_NOISE_FLOOR,
    DEFAULT_KIND_TOLERANCES,
    DEFAULT_NOISE_FLOOR,
    DEFAULT_TOLERANCES,
    KINDS,
    parameter_names,
    resolve,
)
from galvo_sysid.monitor.verdict import (
    ERROR,
    LEVEL_NAMES,
    MISMATCH,
    OK,
    STALE,
    STATUS_FAILED,
    STATUS_NAMES,
    STATUS_OK,
    WARN,
    DriftVerdict,
)

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

__all__ = ['DriftMonitor', 'ModalEstimate']

_DEFAULTS = defaults('watchdog')
"""The watchdog node's parameter defaults: the monitor's defaults (one source)."""

_RANGES: dict[str, tuple[float, float]] = {
    s.name: (s.low, s.high) for s in WATCHDOG_PARAMETERS
    if s.low is not None and s.high is not None}
"""The watchdog parameters' ranges: what the monitor accepts (one source)."""

OTHER_UNITS = 10.0
"""A rigid-body gain k0 this many times larger or smaller than the reference's is not drift
(a coil's torque constant and a mirror's inertia age by percents): the window is a MISMATCH,
another scanner or a current or encoder in other units, not an ERROR of the same scanner."""


class ModalEstimate(Protocol):
    """What the monitor reads from an identification result (IdentificationResult fits).

    An optional ``resolved`` attribute (per mode, as
    :attr:`~galvo_sysid.ident.result.IdentificationResult.resolved`) is read too: the
    parameters of an unresolved mode are not judged.
    """

    @property
    def target_angle(self) -> float: ...  # noqa: D102
    @property
    def k0(self) -> float: ...  # noqa: D102
    @property
    def residues(self) -> tuple[float, ...]: ...  # noqa: D102
    @property
    def natural_frequencies(self) -> tuple[float, ...]: ...  # noqa: D102
    @property
    def damping_ratios(self) -> tuple[float, ...]: ...  # noqa: D102
    @property
    def k0_std(self) -> float: ...  # noqa: D102
    @property
    def residues_std(self) -> tuple[float, ...]: ...  # noqa: D102
    @property
    def natural_frequencies_std(self) -> tuple[float, ...]: ...  # noqa: D102
    @property
    def damping_ratios_std(self) -> tuple[float, ...]: ...  # noqa: D102
    @property
    def fit_percent(self) -> float: ...  # noqa: D102


def _values(result: ModalEstimate) -> tuple[list[float], list[float]]:
    values = [result.k0, *result.residues, *result.natural_frequencies, *result.damping_ratios]
    stds = [result.k0_std, *result.residues_std, *result.natural_frequencies_std,
            *result.damping_ratios_std]
    return [float(v) for v in values], [float(v) for v in stds]


def _pct(x: float) -> str:
    return f'{100 * x:+.2f} %'


@dataclass(frozen=True)
class _Point:
    x: int
    d: float
    sigma: float


class DriftMonitor:
    """Judge identification results against a reference model, window by window.

    Args:
        reference: The reference model (default: the paper's Table I).
        tolerances: Relative tolerance per parameter name or kind (``'k'``, ``'omega'``,
            ``'zeta'``); the rest take the defaults (see the module docs for the rule).
        noise_floor: Relative window-to-window scatter per parameter name or kind; the rest
            take :data:`~galvo_sysid.monitor.tolerances.DEFAULT_NOISE_FLOOR`, then
            :data:`~galvo_sysid.monitor.tolerances.DEFAULT_KIND_NOISE_FLOOR`.
        reference_name: How messages name the reference (its model file).
        warn_fraction: Fraction of the tolerance beyond which a significant deviation warns.
        n_sigma: A deviation within ``n_sigma`` standard deviations (reported std combined
            with the noise floor) is not drift.
        trend_windows: Windows in the trend test (0 disables it).
        trend_min_windows: Fewest windows before the trend test speaks.
        trend_sigma: Slope significance (in standard errors) needed to flag a trend.
        trend_fraction: Fraction of the tolerance the fitted and the latest deviation must
            have reached.
        step_fraction: A jump between consecutive windows larger than this fraction of the
            tolerance (and than the noise) restarts the parameter's trend history: a step is
            judged by the tolerance check, and the windows before it would fake a trend.
        min_fit_percent: Windows fitting worse than this warn and stay out of the trend test.

    Raises:
        ConfigurationError: On an unknown parameter name or an out-of-range setting.
    """

    def __init__(self, *, reference: ModalModel = REFERENCE_MODEL,
                 tolerances: Mapping[str, float] | None = None,
                 noise_floor: Mapping[str, float] | None = None,
                 warn_fraction: float = _DEFAULTS['warn_fraction'],
                 n_sigma: float = _DEFAULTS['n_sigma'],
                 trend_windows: int = _DEFAULTS['trend_windows'],
                 trend_min_windows: int = _DEFAULTS['trend_min_windows'],
                 trend_sigma: float = _DEFAULTS['trend_sigma'],
                 trend_fraction: float = _DEFAULTS['trend_fraction'],
                 step_fraction: float = _DEFAULTS['step_fraction'],
                 min_fit_percent: float = _DEFAULTS['min_fit_percent'],
                 reference_name: str = model_label(None)) -> None:
        self.reference = reference
        self.reference_name = str(reference_name)
        self.names = parameter_names(reference.n_modes)
        given_tol = dict(tolerances or {})
        given_floor = dict(noise_floor or {})
        for label, given in (('tolerances', given_tol), ('noise_floor', given_floor)):
            unknown = sorted(set(given) - set(self.names) - set(KINDS))
            if unknown:
                raise ConfigurationError(f'{label}: unknown parameter(s) {unknown}; '
                                         f'known: {list(self.names)} and the kinds '
                                         f'{list(KINDS)}')
        try:
            tol = resolve(self.names, given_tol, DEFAULT_TOLERANCES, DEFAULT_KIND_TOLERANCES)
            floor = resolve(self.names, given_floor, DEFAULT_NOISE_FLOOR,
                             DEFAULT_KIND_NOISE_FLOOR)
        except (TypeError, ValueError) as err:
            raise ConfigurationError(f'tolerances and noise floors must be numbers: {err}') \
                from None
        for n, t, f in zip(self.names, tol, floor, strict=True):
            if not (math.isfinite(t) and t > 0):
                raise ConfigurationError(f'tolerance of {n} must be > 0, got {t}')
            if not (math.isfinite(f) and f >= 0):
                raise ConfigurationError(f'noise floor of {n} must be >= 0, got {f}')
        checks = (('warn_fraction', warn_fraction), ('n_sigma', n_sigma),
                  ('trend_sigma', trend_sigma), ('trend_fraction', trend_fraction),
                  ('step_fraction', step_fraction), ('min_fit_percent', min_fit_percent))
        for name, value in checks:
            lo, hi = _RANGES[name]
            if not (math.isfinite(value) and lo <= value <= hi):
                raise ConfigurationError(f'{name} must be within [{lo}, {hi}], got {value}')
        if int(trend_windows) < 0 or (trend_windows and not
                                      3 <= int(trend_min_windows) <= int(trend_windows)):
            raise ConfigurationError('need trend_windows = 0 or 3 <= trend_min_windows <= '
                                     'trend_windows')
        self.tolerances = dict(zip(self.names, tol, strict=True))
        self.noise_floor = dict(zip(self.names, floor, strict=True))
        self.warn_fraction = float(warn_fraction)
        self.n_sigma = float(n_sigma)
        self.trend_windows = int(trend_windows)
        self.trend_min_windows = int(trend_min_windows)
        self.trend_sigma = float(trend_sigma)
        self.trend_fraction = float(trend_fraction)
        self.step_fraction = float(step_fraction)
        self.min_fit_percent = float(min_fit_percent)
        self._ref = [float(v) for v in reference.parameters().values()]
        self._history: dict[str, deque[_Point]] = {
            n: deque(maxlen=max(self.trend_windows, 1)) for n in self.names}
        self._count = 0
        self._last_slope: dict[str, float] = {}

    def reset(self) -> None:
        """Forget the trend history (e.g. after the plant was deliberately changed)."""
        for h in self._history.values():
            h.clear()
        self._count = 0

    def stale(self, *, window_index: int, age: float | None) -> DriftVerdict:
        """A STALE verdict: no result for ``age`` seconds (None: none yet)."""
        why = ('no identification result yet' if age is None
               else f'no identification result for {age:.1f} s')
        n = len(self.names)
        return DriftVerdict(window_index=window_index, level=STALE, names=self.names,
                            relative_deviation=(math.nan,) * n,
                            tolerance=tuple(self.tolerances.values()), message=f'STALE: {why}')

    def assess(self, result: ModalEstimate, *, window_index: int, status: int = STATUS_OK,
               status_message: str = '') -> DriftVerdict:
        """Judge one window's result; updates the trend history.

        Args:
            result: The window's identification result.
            window_index: Its window number.
            status: The result's status (:data:`~galvo_sysid.monitor.verdict.STATUS_OK`,
                ...); not OK gives a MISMATCH verdict (the parameters are not judged).
            status_message: Why the status is not OK.

        A result with another number of modes than the reference gives a MISMATCH verdict
        too; one with non-finite parameters an ERROR verdict. Neither enters the trend.
        """
        n_modes = len(result.residues)
        tol = tuple(self.tolerances.values())
        angle = float(result.target_angle)
        if status != STATUS_OK:
            what = STATUS_NAMES[status] if 0 <= status < len(STATUS_NAMES) else str(status)
            why = status_message or f'identification status {what}'
            if status == STATUS_FAILED:
                why = f'identification failed: {why}'
            return self._mismatch(window_index, angle, why)
        values, stds = _values(result)
        if n_modes != self.reference.n_modes or len(values) != len(self._ref) or \
                len(stds) != len(values):
            return self._mismatch(window_index, angle,
                                  f'the result has {n_modes} resonant mode(s), the reference '
                                  f'{self.reference.n_modes}')
        gain = values[0] / self._ref[0] if self._ref[0] else math.nan
        if math.isfinite(gain) and not 1.0 / OTHER_UNITS <= abs(gain) <= OTHER_UNITS:
            return self._mismatch(
                window_index, angle,
                f"k0 is {gain:.3g} times the reference's: not drift but another scanner, or "
                f'the current or the encoder in other units (mA are 1000 times A, radians '
                f'57.3 times smaller than degrees)')
        resolved = tuple(bool(r) for r in getattr(result, 'resolved', ()) or ())
        unresolved = [i for i, r in enumerate(resolved, start=1) if not r] \
            if len(resolved) == n_modes else []
        skip = {n for i in unresolved for n in (f'k{i}', f'omega_{i}', f'zeta_{i}')}
        judged = [n not in skip for n in self.names]
        dev = [(v - r) / abs(r) if r else v - r for v, r in zip(values, self._ref, strict=True)]
        rel_std = [abs(s) / abs(r) if r else abs(s) for s, r in zip(stds, self._ref, strict=True)]
        rel_std = [s if math.isfinite(s) else math.inf for s in rel_std]
        dev = [d if j else math.nan for d, j in zip(dev, judged, strict=True)]
        rel_std = [s if j else math.nan for s, j in zip(rel_std, judged, strict=True)]
        if not all(math.isfinite(d) for d, j in zip(dev, judged, strict=True) if j):
            return DriftVerdict(
                window_index=window_index, level=ERROR, names=self.names,
                relative_deviation=tuple(dev), tolerance=tol,
                message='ERROR: identified parameters are not finite', target_angle=angle)
        unresolved_note = (f'mode{"s" if len(unresolved) > 1 else ""} '
                           f'{", ".join(str(i) for i in unresolved)} unresolved (not judged)'
                           if unresolved else '')
        level = OK
        flagged: list[str] = []
        notes: list[str] = []
        coarse: list[str] = []  # tolerances the window's data cannot tell apart from noise
        for name, d, s, t in zip(self.names, dev, rel_std, tol, strict=True):
            if name in skip:
                continue
            reach = self.n_sigma * math.hypot(s, self.noise_floor[name])
            if reach > t:
                coarse.append(name)
            significant = abs(d) > reach
            if significant and abs(d) > t:
                level = ERROR
                flagged.append(name)
                notes.append(f'{name} {_pct(d)} beyond tolerance {100 * t:g} %')
            elif significant and abs(d) > self.warn_fraction * t:
                level = max(level, WARN)
                flagged.append(name)
                notes.append(f'{name} {_pct(d)} (tolerance {100 * t:g} %)')
        fit = float(result.fit_percent)
        good_fit = math.isfinite(fit) and fit >= self.min_fit_percent
        if not good_fit:
            level = max(level, WARN)
            notes.append(f'poor fit {fit:.1f} % (< {self.min_fit_percent:g} %)')
        slopes = self._trend(dev, rel_std, use=good_fit, skip=skip)
        for name, t in zip(self.names, tol, strict=True):
            slope, now = slopes[name]
            if math.isnan(slope) or name in flagged:
                continue
            level = max(level, WARN)
            flagged.append(name)
            notes.append(f'{name} drifting {_pct(slope)}/window, now {_pct(now)} '
                         f'(tolerance {100 * t:g} %)')
        coarse_note = ('tolerance tighter than the data resolve (' + ', '.join(
            f'{n}: {self.n_sigma:g} std = {100 * self.n_sigma * rel_std[self.names.index(n)]:.3g}'
            f' % > {100 * self.tolerances[n]:g} %' for n in coarse) + ')') if coarse else ''
        if notes:
            message = f'{LEVEL_NAMES[level]}: ' + '; '.join(notes)
            if unresolved_note:
                message += f'; {unresolved_note}'
        else:
            checked = [i for i, j in enumerate(judged) if j]
            worst = max(checked, key=lambda i: abs(dev[i]) / tol[i])
            message = (f'OK: {len(checked)} parameters within tolerance (closest: '
                       f'{self.names[worst]} {_pct(dev[worst])} of {100 * tol[worst]:g} %)')
            if unresolved_note:
                message += f'; {unresolved_note}'
        if coarse_note:
            message += f'; {coarse_note}'
        return DriftVerdict(
            window_index=window_index, level=level, names=self.names,
            relative_deviation=tuple(dev), tolerance=tol, message=message,
            relative_std=tuple(rel_std),
            trend_per_window=tuple(self._last_slope.get(n, math.nan) for n in self.names),
            flagged=tuple(flagged), target_angle=angle, unresolvable=tuple(coarse))

    def _mismatch(self, window_index: int, angle: float, why: str) -> DriftVerdict:
        """A MISMATCH verdict: the data do not match the reference model, and why."""
        n = len(self.names)
        return DriftVerdict(
            window_index=window_index, level=MISMATCH, names=self.names,
            relative_deviation=(math.nan,) * n, tolerance=tuple(self.tolerances.values()),
            message=(f'MISMATCH: the data do not match the reference model '
                     f'{self.reference_name} ({" ".join(why.split())}); not judged for drift'),
            target_angle=angle)

    def _trend(self, dev: Sequence[float], rel_std: Sequence[float], *, use: bool,
               skip: set[str] | None = None) -> dict[str, tuple[float, float]]:
        """Update the history; return per parameter (slope, fitted now) if flagged, else NaN.

        Parameters in ``skip`` (of unresolved modes) keep their history as it was.
        """
        out = {n: (math.nan, math.nan) for n in self.names}
        self._last_slope = {}
        if not self.trend_windows or not use:
            return out
        x = self._count
        self._count += 1
        for name, d, s in zip(self.names, dev, rel_std, strict=True):
            if skip and name in skip:
                continue
            sigma = math.hypot(s, self.noise_floor[name]) if math.isfinite(s) else math.inf
            hist = self._history[name]
            tol = self.tolerances[name]
            if hist and self._is_step(hist[-1], d, sigma, tol):
                hist.clear()  # a step (judged by the tolerance check) is no trend: start over
            hist.append(_Point(x, d, sigma))
            fitted = _weighted_line(hist)
            if fitted is None:
                continue
            slope, slope_se, now = fitted
            self._last_slope[name] = slope
            if (len(hist) >= self.trend_min_windows and slope_se > 0
                    and abs(slope) > self.trend_sigma * slope_se
                    and slope * now > 0 and slope * d > 0
                    and min(abs(now), abs(d)) > self.trend_fraction * tol):
                out[name] = (slope, now)
        return out

    def _is_step(self, last: _Point, d: float, sigma: float, tol: float) -> bool:
        """Did the deviation jump since the last window (beyond noise and step_fraction)?"""
        jump = abs(d - last.d)
        noise = math.hypot(sigma, last.sigma)
        return jump > self.step_fraction * tol and jump > self.n_sigma * noise


def _weighted_line(points: Sequence[_Point]) -> tuple[float, float, float] | None:
    """Weighted straight line through the points: (slope, its standard error, value at last x).

    The standard error uses the given sigmas, widened by the residual scatter when that is
    larger than they explain. None when fewer than 3 usable points.
    """
    pts = [p for p in points if math.isfinite(p.sigma) and p.sigma > 0]
    if len(pts) < 3:
        return None
    x = np.array([p.x for p in pts], dtype=float)
    y = np.array([p.d for p in pts])
    w = 1.0 / np.array([p.sigma for p in pts]) ** 2
    sw = w.sum()
    xm = float((w * x).sum() / sw)
    ym = float((w * y).sum() / sw)
    sxx = float((w * (x - xm) ** 2).sum())
    if sxx <= 0:
        return None
    slope = float((w * (x - xm) * (y - ym)).sum() / sxx)
    resid = y - (ym + slope * (x - xm))
    chi2 = float((w * resid**2).sum()) / (len(pts) - 2)
    se = math.sqrt(max(1.0, chi2) / sxx)
    return slope, se, ym + slope * (float(x[-1]) - xm)
