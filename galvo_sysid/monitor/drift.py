"""Drift of the identified plant from its reference model: one verdict per window.

:class:`DriftMonitor` is a small task object (like the monitors of ros/diagnostics): the
watchdog node feeds it each window's identification result and publishes the
:class:`DriftVerdict`; ``galvo-sysid identify --json`` uses the same object for each window's
``drift`` entry.

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

Tolerances (and noise floors) are relative and given per parameter name (``omega_2``) or per
kind (``k`` for the residues k1.., ``omega``, ``zeta``), so any number of modes works. The
tolerance of a parameter is, first found:

1. its own entry (``omega_2``);
2. the entry of its kind (``omega``; k0, the rigid body, has no kind);
3. the built-in default of its name, :data:`DEFAULT_TOLERANCES` (k0 and modes 1-3: set for
   the paper's scanner, so it is judged as before);
4. the built-in default of its kind, :data:`DEFAULT_KIND_TOLERANCES` (modes 4 and up).

The per-name defaults reflect what one window of 100 moves identifies reliably on the paper's
scanner: omega_1,2 to a few hundredths of a percent, k0..k2 and zeta_1,2 to a few percent, the
third mode hardly at all (the paper's Table II has zeta_3 off by +655 %; in the simulated
closed loop the mode sits under a notch filter), so its tolerances are wide enough never to
fire. For another scanner, give the kinds (and names where needed) in the watchdog's YAML.
"""

from __future__ import annotations

import math
import re
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model import REFERENCE_MODEL, ModalModel, PlantModel, load_model, model_label

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

__all__ = [
    'DEFAULT_KIND_NOISE_FLOOR',
    'DEFAULT_KIND_TOLERANCES',
    'DEFAULT_NOISE_FLOOR',
    'DEFAULT_TOLERANCES',
    'ERROR',
    'KINDS',
    'LEVEL_NAMES',
    'MISMATCH',
    'MONITOR_PARAMETERS',
    'OK',
    'STALE',
    'STATUS_FAILED',
    'STATUS_MISMATCH',
    'STATUS_NAMES',
    'STATUS_OK',
    'WARN',
    'DriftMonitor',
    'DriftVerdict',
    'ModalEstimate',
    'monitor_from_parameters',
    'parameter_kind',
    'parameter_names',
    'reference_from_parameters',
]

OK, WARN, ERROR, STALE, MISMATCH = 0, 1, 2, 3, 4
"""Verdict levels, the same numbers as ``DriftStatus.msg`` (OK..STALE also as
``DiagnosticStatus``; MISMATCH is reported there as ERROR)."""

LEVEL_NAMES = ('OK', 'WARN', 'ERROR', 'STALE', 'MISMATCH')
"""Names of the levels, indexed by level."""

STATUS_OK, STATUS_MISMATCH, STATUS_FAILED = 0, 1, 2
"""Status of a window's result, the same numbers as ``ModalParameters.msg``: identified, the
data do not match the plant model, the fit failed."""

STATUS_NAMES = ('OK', 'MISMATCH', 'FAILED')
"""Names of the statuses, indexed by status."""

KINDS = ('k', 'omega', 'zeta')
"""Kinds of the resonant modes' parameters (residues k1.., omega_i, zeta_i)."""

DEFAULT_TOLERANCES: dict[str, float] = {
    'k0': 0.02, 'k1': 0.05, 'k2': 0.08, 'k3': 5.0,
    'omega_1': 0.01, 'omega_2': 0.01, 'omega_3': 0.6,
    'zeta_1': 0.20, 'zeta_2': 0.20, 'zeta_3': 100.0,
}
"""Default relative tolerance per parameter of the 3-mode model (0.01 = 1 %).

Set from what one window of 100 moves identifies on the simulated closed loop (refined
method, 75 windows over the paper's 19 angles, both signs): scatter (sd, max) of the relative
error k0 0.1 % (0.4 %), k1 0.6 % (1.7 %), k2 1.2 % (4.7 %), omega_1 0.004 % (0.015 %),
omega_2 0.008 % (0.03 %), zeta_1 0.9 % (4 %), zeta_2 1.4 % (6 %). The third mode sits under
the controller's notch and is hardly excited: k3 off by up to 370 %, omega_3 by 30 % (its
band's edge), zeta_3 by 5000 %, so its tolerances effectively switch it off.
"""

DEFAULT_NOISE_FLOOR: dict[str, float] = {
    'k0': 0.0015, 'k1': 0.008, 'k2': 0.015, 'k3': 1.5,
    'omega_1': 0.0001, 'omega_2': 0.0002, 'omega_3': 0.15,
    'zeta_1': 0.012, 'zeta_2': 0.02, 'zeta_3': 10.0,
}
"""Default window-to-window scatter of each relative deviation (added to the reported std;
about 1.5 times the scatter measured for :data:`DEFAULT_TOLERANCES`)."""

DEFAULT_KIND_TOLERANCES: dict[str, float] = {'k': 0.08, 'omega': 0.01, 'zeta': 0.3}
"""Default relative tolerance of the modes without a per-name default (mode 4 and up): those
of a well-excited mode of the paper's scanner, zeta a little wider."""

DEFAULT_KIND_NOISE_FLOOR: dict[str, float] = {'k': 0.015, 'omega': 0.0002, 'zeta': 0.02}
"""Default window-to-window scatter of the modes without a per-name default."""


class ModalEstimate(Protocol):
    """What the monitor reads from an identification result (IdentificationResult fits).

    An optional ``resolved`` attribute (per mode, as
    :attr:`~galvo_sysid.ident.identify.IdentificationResult.resolved`) is read too: the
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


def parameter_names(n_modes: int) -> tuple[str, ...]:
    """Return the parameter names of a model with ``n_modes`` resonant modes, in order."""
    return ('k0', *(f'k{i}' for i in range(1, n_modes + 1)),
            *(f'omega_{i}' for i in range(1, n_modes + 1)),
            *(f'zeta_{i}' for i in range(1, n_modes + 1)))


_NAME = re.compile(r'^(?:k0|k([1-9][0-9]*)|(omega|zeta)_([1-9][0-9]*))$')


def _split_name(name: str) -> tuple[str, int] | None:
    """(kind, mode) of a parameter name (('k0', 0) for k0), None if it is no parameter name."""
    m = _NAME.match(name)
    if m is None:
        return None
    if name == 'k0':
        return 'k0', 0
    if m.group(1):
        return 'k', int(m.group(1))
    return m.group(2), int(m.group(3))


def parameter_kind(name: str) -> str:
    """The kind of a parameter name: ``'k'`` (k1, k2, ..), ``'omega'``, ``'zeta'``, or ``'k0'``.

    Raises:
        ConfigurationError: Not a parameter name.
    """
    split = _split_name(name)
    if split is None:
        raise ConfigurationError(f'{name!r} is not a parameter name (k0, k<i>, omega_<i>, '
                                 f'zeta_<i>)')
    return split[0]


def _resolve(names: Sequence[str], given: Mapping[str, float], table: Mapping[str, float],
             kinds: Mapping[str, float]) -> list[float]:
    """Per name: its own entry, its kind's entry, its built-in default, its kind's default."""
    out = []
    for n in names:
        kind = parameter_kind(n)
        if n in given:
            out.append(float(given[n]))
        elif kind in given:
            out.append(float(given[kind]))
        elif n in table:
            out.append(float(table[n]))
        else:
            out.append(float(kinds[kind]))
    return out


def _values(result: ModalEstimate) -> tuple[list[float], list[float]]:
    values = [result.k0, *result.residues, *result.natural_frequencies, *result.damping_ratios]
    stds = [result.k0_std, *result.residues_std, *result.natural_frequencies_std,
            *result.damping_ratios_std]
    return [float(v) for v in values], [float(v) for v in stds]


def _pct(x: float) -> str:
    return f'{100 * x:+.2f} %'


@dataclass(frozen=True)
class DriftVerdict:
    """The monitor's verdict on one window.

    Attributes:
        window_index: The window judged.
        level: 0 OK, 1 WARN, 2 ERROR, 3 STALE, 4 MISMATCH.
        names: Parameter names (k0, k1.., omega_1.., zeta_1..).
        relative_deviation: (identified - reference) / reference per parameter.
        tolerance: Relative tolerance per parameter.
        message: One human-readable line.
        relative_std: Identified standard deviation relative to the reference.
        trend_per_window: Fitted slope of the relative deviation per window (NaN until the
            trend test has enough windows).
        flagged: The parameters that raised the level.
        target_angle: Target angle of the window [deg].
    """

    window_index: int
    level: int
    names: tuple[str, ...]
    relative_deviation: tuple[float, ...]
    tolerance: tuple[float, ...]
    message: str
    relative_std: tuple[float, ...] = ()
    trend_per_window: tuple[float, ...] = ()
    flagged: tuple[str, ...] = ()
    target_angle: float = math.nan

    @property
    def level_name(self) -> str:
        """'OK', 'WARN', 'ERROR', 'STALE' or 'MISMATCH'."""
        return LEVEL_NAMES[self.level]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form; NaN becomes None."""
        def clean(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        def by_name(values: Sequence[float]) -> dict[str, float | None]:
            return {n: clean(v) for n, v in zip(self.names, values, strict=False)}

        return {
            'window_index': int(self.window_index),
            'level': self.level_name,
            'message': self.message,
            'target_angle': clean(self.target_angle),
            'flagged': list(self.flagged),
            'deviations': by_name(self.relative_deviation),
            'tolerances': by_name(self.tolerance),
            'relative_std': by_name(self.relative_std),
            'trend_per_window': by_name(self.trend_per_window),
        }


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
            take :data:`DEFAULT_NOISE_FLOOR`, then :data:`DEFAULT_KIND_NOISE_FLOOR`.
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
                 noise_floor: Mapping[str, float] | None = None, warn_fraction: float = 0.5,
                 n_sigma: float = 3.0, trend_windows: int = 8, trend_min_windows: int = 3,
                 trend_sigma: float = 4.0, trend_fraction: float = 0.3,
                 step_fraction: float = 0.5, min_fit_percent: float = 75.0,
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
            tol = _resolve(self.names, given_tol, DEFAULT_TOLERANCES, DEFAULT_KIND_TOLERANCES)
            floor = _resolve(self.names, given_floor, DEFAULT_NOISE_FLOOR,
                             DEFAULT_KIND_NOISE_FLOOR)
        except (TypeError, ValueError) as err:
            raise ConfigurationError(f'tolerances and noise floors must be numbers: {err}') \
                from None
        for n, t, f in zip(self.names, tol, floor, strict=True):
            if not (math.isfinite(t) and t > 0):
                raise ConfigurationError(f'tolerance of {n} must be > 0, got {t}')
            if not (math.isfinite(f) and f >= 0):
                raise ConfigurationError(f'noise floor of {n} must be >= 0, got {f}')
        checks = (('warn_fraction', warn_fraction, 0.0, 1.0), ('n_sigma', n_sigma, 0.0, 100.0),
                  ('trend_sigma', trend_sigma, 0.0, 100.0),
                  ('trend_fraction', trend_fraction, 0.0, 1.0),
                  ('step_fraction', step_fraction, 0.0, 1e6),
                  ('min_fit_percent', min_fit_percent, -1e9, 100.0))
        for name, value, lo, hi in checks:
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
            status: The result's status (:data:`STATUS_OK`, ...); not OK gives a MISMATCH
                verdict (the parameters are not judged).
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
        for name, d, s, t in zip(self.names, dev, rel_std, tol, strict=True):
            if name in skip:
                continue
            significant = abs(d) > self.n_sigma * math.hypot(s, self.noise_floor[name])
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
        return DriftVerdict(
            window_index=window_index, level=level, names=self.names,
            relative_deviation=tuple(dev), tolerance=tol, message=message,
            relative_std=tuple(rel_std),
            trend_per_window=tuple(self._last_slope.get(n, math.nan) for n in self.names),
            flagged=tuple(flagged), target_angle=angle)

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


MONITOR_PARAMETERS = ('warn_fraction', 'n_sigma', 'trend_windows', 'trend_min_windows',
                      'trend_sigma', 'trend_fraction', 'step_fraction', 'min_fit_percent')
"""Options of :class:`DriftMonitor` that are watchdog node parameters of the same name."""


def reference_from_parameters(values: Mapping[str, Any]) -> PlantModel:
    """The reference model from watchdog parameters: the model file ``model`` ('' or missing:
    the packaged model of the paper's scanner).

    Raises:
        ConfigurationError: The file is not a valid plant model, or the parameters still
            hold the ``reference.*`` values of older versions (the model file replaced them).
        InvalidDataError: The file cannot be read.
    """  # noqa: D205
    old = sorted(k for k in values if k.startswith('reference.'))
    if old:
        raise ConfigurationError(
            f'watchdog parameters {", ".join(old)} are no longer read: the reference is the '
            f'plant-model file of parameter model (e.g. one written by galvo-sysid commission)')
    path = values.get('model') or ''
    if not isinstance(path, str):
        raise ConfigurationError(f'watchdog parameter model must be a file name, got {path!r}')
    return load_model(path or None)


def monitor_from_parameters(values: Mapping[str, Any], *,
                            model: PlantModel | None = None) -> DriftMonitor:
    """The watchdog node's :class:`DriftMonitor` from its parameters, by name.

    The one definition used by the watchdog node and by ``galvo-sysid identify
    --watchdog-params``: the reference model (the file of ``model``, see
    :func:`reference_from_parameters`), the tolerances ``tolerances.<name>`` and
    ``tolerances.<kind>`` given (the rule of the module docs; None means not given; names of
    modes the reference lacks are ignored, as the node does not declare them), and the
    options of :data:`MONITOR_PARAMETERS`; other names are ignored and missing ones take
    :class:`DriftMonitor`'s defaults (the node's).

    Args:
        values: Parameter values by name.
        model: The reference model already read from the file of ``values['model']`` (saves
            reading it again); None reads it.

    Raises:
        ConfigurationError: A value is not a number or out of range, an unknown tolerance
            name, or a bad model file.
        InvalidDataError: The model file cannot be read.
    """
    reference = reference_from_parameters(values) if model is None else model
    tolerances: dict[str, float] = {}
    for key, value in values.items():
        if not key.startswith('tolerances.') or value is None:
            continue
        name = key.split('.', 1)[1]
        split = _split_name(name)
        if name not in KINDS and split is None:
            raise ConfigurationError(
                f'unknown watchdog parameter {key}: tolerances are named tolerances.k0, '
                f'tolerances.<kind> (k, omega, zeta) or tolerances.<parameter> (k1, omega_2, '
                f'zeta_3, ...)')
        if split is not None and split[1] > reference.n_modes:
            continue  # a mode this reference has not
        if isinstance(value, bool) or not isinstance(value, int | float | str):
            raise ConfigurationError(f'bad watchdog parameter {key}: not a number: {value!r}')
        try:
            tolerances[name] = float(value)
        except ValueError:
            raise ConfigurationError(f'bad watchdog parameter {key}: not a number: '
                                     f'{value!r}') from None
    options = {k: values[k] for k in MONITOR_PARAMETERS if k in values}
    return DriftMonitor(reference=reference.modal, tolerances=tolerances,
                        reference_name=model_label(values.get('model') or None), **options)
