"""The refined fit's tuning options and their defaults, in one place.

:class:`RefineOptions` holds every knob of :func:`~galvo_sysid.ident.refine.refine_fit` and
:func:`~galvo_sysid.ident.refine.refine_joint` that is not the data, the starting model, the
bands or the input dynamics. Its field names are the option names callers pass by keyword
(e.g. ``identify_window(..., scan_points=0)``), so :meth:`RefineOptions.from_options` can take
them out of a mapping and refuse what it does not know.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any

from galvo_sysid.errors import ConfigurationError

if TYPE_CHECKING:
    from collections.abc import Mapping

__all__ = [
    'DEFAULT_ADEQUACY_LIMIT',
    'DEFAULT_DAMPING_START',
    'DEFAULT_LAG_BOUNDS',
    'DEFAULT_RESOLVE_Z',
    'DEFAULT_SCAN_POINTS',
    'DEFAULT_WHITEN_ORDER',
    'MAX_DAMPING',
    'MIN_DAMPING',
    'RefineOptions',
]

DEFAULT_DAMPING_START = 0.03
"""Damping ratio every mode starts from (the continuation start; see :mod:`.fit`)."""

DEFAULT_LAG_BOUNDS = (0.0, 3.0)
"""Bounds of the estimated amplifier lag, in sample periods."""

DEFAULT_SCAN_POINTS = 24
"""Frequencies per band scanned for the first starting point."""

DEFAULT_WHITEN_ORDER = 128
"""Lags of the per-move noise's autocovariance the second stage's whitening uses (the order of
its prediction-error filter; the first rows of a record are whitened exactly)."""

DEFAULT_ADEQUACY_LIMIT = 20.0
"""Residual-to-noise energy ratio (per interval between band edges) above which the model is
rejected; about 1 for an adequate model."""

DEFAULT_RESOLVE_Z = 5.0
"""Significance |k_i| / std(k_i) below which a mode counts as not resolved."""

MAX_DAMPING = 0.3
"""Largest damping ratio the fit considers (a mode at it is a fit failure)."""

MIN_DAMPING = 1e-5
"""Smallest damping ratio the fit considers."""


@dataclass(frozen=True, kw_only=True)
class RefineOptions:
    """Tuning of the refined fit.

    Attributes:
        damping_start: Damping ratio the modes start from (continuation; see :mod:`.fit`).
        lag_bounds: Bounds of the estimated lag [sample periods].
        scan_points: Frequencies per band of the starting scan (0: start from the initial
            model only).
        resolve_z: A mode whose |k_i| is below ``resolve_z`` times its std counts as not
            resolved; such a mode may end at a band edge without an error.
        whiten_order: Lags of the noise model of the second, prewhitened stage (generalised
            least squares; 0: ordinary least squares only). Needs 3 moves.
        adequacy_limit: Largest accepted ratio of the averaged residual's energy to the
            noise's (from the moves' scatter) in any interval between band edges; above it
            the model lacks dynamics the data hold (0: no check). Needs 3 moves.
        max_nfev: Iteration limit of each start and stage.
        keep_initial_damping: Start from the initial model as it is (its damping ratios too)
            rather than from ``damping_start``: for a good start (e.g. pooled single-window
            results); without a scan that moves a frequency by over 1 %, the first (ordinary
            least-squares) stage is then left out.
        search_unplaced: Polish from a better basin that a weakly excited mode's band
            profile finds even where the mode could not be placed there either (the scan's
            points within the profile level of that basin cover half its band): the mode
            ends unresolved either way, and only its noise-fitted values and, by a fraction
            of their std, the other modes' estimates depend on it. False saves that second
            polish and profile (the sysid node's warm fits, :mod:`galvo_sysid.ident.warm`).
        bound: Also report the Cramer-Rao bound (``crlb_std``: the fit's ``A^-1`` when it
            was weighed by the stationary noise model, else a noise model estimated for it,
            about a sixth of a window's fit). The sysid node, whose messages do not carry
            it, leaves it out.
        deadline: A :func:`time.monotonic` time past which the fit leaves out the stages
            it can do without (None: none): the weakly excited modes' band profiles and a
            better basin's second polish. A mode they would have placed is then reported
            unresolved (its band is its std), and the fit says it was cut short
            (:attr:`~galvo_sysid.ident.refine.result.RefinedFit.cut_short`). The screening,
            the polish, the noise model and the covariance always run, so a fit can still
            end past it (the sysid node's ``fit_budget_ms``).
    """

    damping_start: float = DEFAULT_DAMPING_START
    lag_bounds: tuple[float, float] = DEFAULT_LAG_BOUNDS
    scan_points: int = DEFAULT_SCAN_POINTS
    resolve_z: float = DEFAULT_RESOLVE_Z
    whiten_order: int = DEFAULT_WHITEN_ORDER
    adequacy_limit: float = DEFAULT_ADEQUACY_LIMIT
    max_nfev: int = 100
    keep_initial_damping: bool = False
    search_unplaced: bool = True
    bound: bool = True
    deadline: float | None = None

    def __post_init__(self) -> None:
        lo, hi = self.lag_bounds
        if not 0 <= lo < hi:
            raise ConfigurationError(f'bad lag_bounds {self.lag_bounds}')
        if not 0 < self.damping_start < MAX_DAMPING:
            raise ConfigurationError(f'damping_start must be in (0, {MAX_DAMPING})')
        for name in ('scan_points', 'whiten_order', 'max_nfev'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ConfigurationError(f'{name} must be a whole number >= 0, got {value!r}')
        if self.max_nfev < 1:
            raise ConfigurationError('max_nfev must be >= 1')
        for name in ('bound', 'search_unplaced', 'keep_initial_damping'):
            if not isinstance(getattr(self, name), bool):
                raise ConfigurationError(f'{name} must be true or false, got '
                                         f'{getattr(self, name)!r}')
        if self.deadline is not None and (isinstance(self.deadline, bool) or not isinstance(
                self.deadline, (int, float)) or not math.isfinite(self.deadline)):
            raise ConfigurationError(f'deadline must be a finite time or None, got '
                                     f'{self.deadline!r}')
        if not (self.resolve_z >= 0 and self.adequacy_limit >= 0):
            raise ConfigurationError('resolve_z and adequacy_limit must be >= 0')

    @classmethod
    def names(cls) -> frozenset[str]:
        """The option names."""
        return frozenset(f.name for f in fields(cls))

    @classmethod
    def from_options(cls, options: Mapping[str, Any], *,
                     base: RefineOptions | None = None) -> RefineOptions:
        """The options named in ``options`` (other keys are ignored) over ``base``."""
        given = {k: v for k, v in options.items() if k in cls.names()}
        if 'lag_bounds' in given:
            lo, hi = given['lag_bounds']
            given['lag_bounds'] = (float(lo), float(hi))
        return replace(base if base is not None else cls(), **given)
