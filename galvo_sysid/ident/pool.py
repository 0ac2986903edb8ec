"""Pooling finished results of windows of the same plant (inverse-variance, robust)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from galvo_sysid.errors import InvalidDataError
from galvo_sysid.ident.refine import DEFAULT_RESOLVE_Z as RESOLVE_Z
from galvo_sysid.ident.result import IdentificationResult, result_from_vectors

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import NDArray

__all__ = ['pool_results']


def _pool_parameter(v: NDArray[np.float64], s: NDArray[np.float64], *,
                    reject: float) -> tuple[float, float]:
    """Inverse-variance mean and std of one parameter, with outlier rejection."""
    ok = np.isfinite(s) & (s > 0) & np.isfinite(v)
    if not np.any(ok):
        finite = v[np.isfinite(v)]
        return (float(np.mean(finite)) if finite.size else float('nan')), float('nan')
    v, s = v[ok], s[ok]
    if reject > 0 and v.size > 2:
        # Robust centre: the median of the better-determined half of the windows (a weighted
        # median would follow a single outlier with a tiny std); drop windows farther from it
        # than ``reject`` of their own std.
        centre = float(np.median(v[s <= np.median(s)]))
        keep = np.abs(v - centre) <= reject * s
        if np.count_nonzero(keep) >= max(2, v.size // 2):
            v, s = v[keep], s[keep]
    # weights relative to the smallest std (in (0, 1]): 1/std^2 itself under- or overflows
    # for extreme stds
    scale = float(np.min(s))
    with np.errstate(under='ignore'):
        w = (scale / s) ** 2
    mean = float(np.sum(w * v) / np.sum(w))
    std = scale / math.sqrt(float(np.sum(w)))
    if v.size > 1:
        with np.errstate(over='ignore', invalid='ignore'):
            chi2 = float(np.sum(w * ((v - mean) / scale) ** 2))
        std *= max(1.0, math.sqrt(chi2 / (v.size - 1)))
    return mean, std


def pool_results(results: Sequence[IdentificationResult], *,
                 reject: float = 5.0) -> IdentificationResult:
    """Combine windows of the same plant: inverse-variance weighted mean per parameter.

    Per parameter: windows farther than ``reject`` of their own std from a robust centre (the
    median of the better-determined half of the windows) are left out (a window whose weak
    mode locked onto a noise peak reports a small std far from the others); the rest are
    averaged with weights 1/std^2. The pooled std is the
    inverse-variance std scaled by the Birge ratio ``sqrt(chi^2 / (n - 1))`` when that exceeds
    1 (the windows scatter more than their std say, e.g. an angle-dependent bias). Windows
    without a finite positive std for a parameter are left out of it (plain mean and nan std
    if none has one).

    Args:
        results: Windows of one method and one number of modes.
        reject: Outlier threshold in std (0: keep every window).

    Returns:
        The pooled result: ``target_angle`` is the common angle or nan, ``moves`` the total,
        ``fit_percent`` the move-weighted mean, delays the means.

    Raises:
        InvalidDataError: No results, different methods or numbers of modes.
    """
    items = list(results)
    if not items:
        raise InvalidDataError('nothing to pool')
    methods = {r.method for r in items}
    if len(methods) != 1:
        raise InvalidDataError(f'cannot pool different methods: {sorted(methods)}')
    n_modes = {r.n_modes for r in items}
    if len(n_modes) != 1:
        raise InvalidDataError('cannot pool results with different numbers of modes')
    values = [r.model.parameters() for r in items]
    stds = [r.std_by_name() for r in items]
    pooled: dict[str, float] = {}
    pooled_std: dict[str, float] = {}
    for name in values[0]:
        v = np.array([p[name] for p in values])
        s = np.array([p[name] for p in stds])
        pooled[name], pooled_std[name] = _pool_parameter(v, s, reject=reject)
    angles = {r.target_angle for r in items}
    angle = items[0].target_angle if len(angles) == 1 else float('nan')
    moves = int(sum(r.moves for r in items))
    weights = np.array([r.moves for r in items], dtype=float)
    fits = np.array([r.fit_percent for r in items])
    fit = float(np.sum(weights * fits) / np.sum(weights)) if np.all(np.isfinite(fits)) \
        else float(np.nanmean(fits)) if np.any(np.isfinite(fits)) else float('nan')
    n = n_modes.pop()
    resolved = tuple(not abs(pooled[f'k{i}']) < RESOLVE_Z * pooled_std[f'k{i}']
                     for i in range(1, n + 1))
    return result_from_vectors(pooled, pooled_std, n_modes=n, target_angle=angle,
                         moves=moves,
                         input_delay=float(np.mean([r.input_delay for r in items])),
                         lag_time_constant=float(np.mean([r.lag_time_constant for r in items])),
                         fit_percent=fit, method=methods.pop(), resolved=resolved)
