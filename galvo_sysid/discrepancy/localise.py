"""Where a model and the moves disagree: frequency band, phase of the move, move size.

:func:`localise` reads the :class:`~galvo_sysid.discrepancy.compare.Diagnostics` of one model:
the excess of z^2 over the noise in log-spaced frequency bands, how the excess of the
acceleration residual divides among acceleration, deceleration and settling (the phases of
the mean move current, :func:`_phase_bounds`), and how the gap depends on the move size
(:func:`_size_trend`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from galvo_sysid.discrepancy.spectra import _band_excess, _gap, _noise_gap
from galvo_sysid.jsonsafe import finite_or_none

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from galvo_sysid.discrepancy.compare import Diagnostics

__all__ = ['Band', 'Localisation', 'localise']

_PHASES = ('acceleration', 'deceleration', 'settling')

_BAND_SIGNIFICANCE = 5.0
"""Band excess (noise standard deviations) that counts as significant (noise alone passes
it in any of 16 bands with a probability below 0.01 %)."""


@dataclass(frozen=True)
class Band:
    """The residual's excess over the noise in one frequency band.

    Attributes:
        low: Lower edge [Hz].
        high: Upper edge [Hz].
        excess: (sum z^2 - count) / sqrt(count): noise standard deviations (about 0 +- 1
            for noise alone).
        share: Fraction of the total positive excess.
    """

    low: float
    high: float
    excess: float
    share: float

    def to_dict(self) -> dict[str, float]:
        """JSON-ready."""
        return {'low_hz': self.low, 'high_hz': self.high, 'excess': self.excess,
                'share': self.share}


@dataclass(frozen=True)
class Localisation:
    """Where a model and the moves disagree: frequency, phase of the move, move size.

    Attributes:
        bands: Every band, ascending frequency.
        phases: How the excess of the acceleration residual over its noise floor (per
            sample) divides among ``acceleration``, ``deceleration`` and ``settling`` (after
            the current has died down); shares of 1.
        main_phase: The phase with the largest share (``none`` if nothing is significant).
        angles: Target angle magnitudes [deg], ascending.
        gaps: Gap at each angle magnitude (both signs together), the 0 Hz bin included
            (a residual building up steadily over the record; the overall gap leaves it out).
        size_trend: How the gap depends on the angle: ``grows with the angle``, ``grows
            faster than the angle``, ``about constant``, ``shrinks with the angle``, ``only
            large moves``, ``only small moves``, ``none`` or ``single angle``.
        size_exponent: Slope of log(gap) over log(angle) (nan if undefined).
    """

    bands: tuple[Band, ...]
    phases: dict[str, float]
    main_phase: str
    angles: tuple[float, ...]
    gaps: tuple[float, ...]
    size_trend: str
    size_exponent: float

    @property
    def main_bands(self) -> tuple[Band, ...]:
        """Significant bands (excess > 5), largest first, at most three."""
        sig = sorted((b for b in self.bands if b.excess > _BAND_SIGNIFICANCE),
                     key=lambda b: -b.excess)
        return tuple(sig[:3])

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {
            'main_bands': [b.to_dict() for b in self.main_bands],
            'bands': [b.to_dict() for b in self.bands],
            'phases': dict(self.phases),
            'main_phase': self.main_phase,
            'sizes': [{'angle': a, 'gap': g} for a, g in zip(self.angles, self.gaps,
                                                             strict=True)],
            'size_trend': self.size_trend,
            'size_exponent': finite_or_none(self.size_exponent),
        }

    def phrase(self) -> str:
        """Where, in one clause: bands, phase of the move and move size (for one sentence)."""
        parts = []
        bands = self.main_bands
        if bands:
            parts.append('at ' + ', '.join(f'{_hz(b.low)}-{_hz(b.high)} ({100 * b.share:.0f} %)'
                                          for b in bands))
        else:
            parts.append('spread over the frequencies (no band above the noise)')
        if self.main_phase != 'none':
            parts.append(f'mostly in the {self.main_phase} '
                         f'({100 * self.phases[self.main_phase]:.0f} %)')
        if self.size_trend not in ('none', 'single angle'):
            sizes = ', '.join(f'{a:g} deg: {g:.2g}' for a, g in zip(self.angles, self.gaps,
                                                                      strict=True))
            parts.append(f'by move size {self.size_trend} (gap {sizes})')
        return ', '.join(parts)

    def summary(self) -> list[str]:
        """Short human-readable lines."""
        lines = []
        bands = self.main_bands
        if bands:
            lines.append('frequency: ' + ', '.join(
                f'{_hz(b.low)}-{_hz(b.high)} ({100 * b.share:.0f} %)' for b in bands))
        else:
            lines.append('frequency: no band above the noise')
        if self.main_phase != 'none':
            lines.append('time: mostly ' + self.main_phase + ' (' + ', '.join(
                f'{k} {100 * v:.0f} %' for k, v in self.phases.items()) + ')')
        else:
            lines.append('time: no phase above the noise')
        sizes = ', '.join(f'{a:g} deg: {g:.2f}' for a, g in zip(self.angles, self.gaps,
                                                                   strict=True))
        lines.append(f'move size: {self.size_trend} (gap by angle, 0 Hz included: {sizes})')
        return lines


def _hz(f: float) -> str:
    return f'{f / 1e3:.3g} kHz' if f >= 1e3 else f'{f:.3g} Hz'


def _phase_bounds(current: NDArray[np.float64]) -> tuple[int, int]:
    """(start of braking, start of settling) sample indices of a mean move current.

    Acceleration runs from the first large current to its first reversal, braking from there
    to the last large current (above 5 % of the peak); settling is the rest.
    """
    mag = np.abs(current)
    peak = float(mag.max())
    n = current.shape[0]
    if peak == 0:
        return 0, 0
    big = np.flatnonzero(mag > 0.3 * peak)
    start = int(big[0])
    sign = np.sign(current[start])
    after = np.flatnonzero(current[start:] * sign < 0)
    brake = start + int(after[0]) if after.size else n
    tail = np.flatnonzero(mag > 0.05 * peak)
    settle = int(tail[-1]) + 1 if tail.size else n
    return min(brake, settle), settle


def localise(diag: Diagnostics, *, bands: int = 16) -> Localisation:
    """Where the residual of :class:`Diagnostics` exceeds the noise."""
    df = float(diag.frequencies[0])
    raw = [(lo * df - df / 2, (hi - 1) * df + df / 2, e / math.sqrt(n), e)
           for lo, hi, e, n in _band_excess(diag.z2, bands=bands)]
    g = diag.z2.shape[0]
    total = sum(max(r[3], 0.0) for r in raw)
    band_list = tuple(Band(low=lo, high=hi, excess=ex,
                           share=(max(e, 0.0) / total if total > 0 else 0.0))
                      for lo, hi, ex, e in raw)
    # time: excess of the acceleration residual's (residual / floor)^2 over 1 in each phase
    sums = dict.fromkeys(_PHASES, 0.0)
    counts = dict.fromkeys(_PHASES, 0)
    for k in range(g):
        brake, settle = _phase_bounds(diag.current[k])
        fl = diag.acceleration_floor[k]
        with np.errstate(divide='ignore', invalid='ignore'):
            zt = np.where(fl > 0, diag.acceleration_residual[k] / fl, 0.0)
        ex = zt**2 - 1.0
        idx = np.arange(1, zt.shape[0] + 1)   # the second difference at k is centred on k
        for name, mask in (('acceleration', idx < brake),
                           ('deceleration', (idx >= brake) & (idx < settle)),
                           ('settling', idx >= settle)):
            sums[name] += float(ex[mask].sum())
            counts[name] += int(mask.sum())
    # significant if the time-domain excess is well above its rough noise spread
    n_total = sum(counts.values())
    total = sum(sums.values())
    significant = diag.gap > diag.noise_gap and total > 5 * math.sqrt(2 * max(n_total, 1))
    density = {k: max(v, 0.0) / counts[k] if counts[k] else 0.0 for k, v in sums.items()}
    tot = sum(density.values())
    phases = {k: (v / tot if tot > 0 else 0.0) for k, v in density.items()}
    main_phase = max(phases, key=lambda k: phases[k]) if significant else 'none'
    # move size: pool both signs of each magnitude; the 0 Hz bin (a residual building up
    # steadily over the record, as friction's does in one-way moves) counts here too, with
    # its own floor from the moves' scatter (E[z^2] = (M - 1) / (M - 3) for M moves)
    mags = np.round(np.abs(diag.angles), 9)
    angles = tuple(float(a) for a in np.unique(mags))
    m = diag.counts.astype(float)
    drift2 = diag.drift_z**2 * np.where(m > 3, (m - 3) / np.maximum(m - 1, 1), 1.0)
    gaps, floors = [], []
    for a in angles:
        sel = np.flatnonzero(mags == a)
        noise = float(diag.group_cost_noise[sel].sum()) + sel.size
        gaps.append(_gap(float(diag.group_cost[sel].sum() + drift2[sel].sum()), noise))
        floors.append(_noise_gap(noise))
    trend, slope = _size_trend(angles, gaps, floors)
    return Localisation(bands=band_list, phases=phases, main_phase=main_phase, angles=angles,
                        gaps=tuple(gaps), size_trend=trend, size_exponent=slope)


def _size_trend(angles: Sequence[float], gaps: Sequence[float],
                floors: Sequence[float]) -> tuple[str, float]:
    """Classify how the gap depends on the move size (``floors``: noise gap per angle)."""
    sig = [g > f for g, f in zip(gaps, floors, strict=True)]
    if not any(sig):
        return 'none', math.nan
    if len(angles) < 2:
        return 'single angle', math.nan
    if not sig[0] and sig[-1] and gaps[-1] > 3 * floors[-1]:
        return 'only large moves', math.nan
    if sig[0] and not sig[-1] and gaps[0] > 3 * floors[0]:
        return 'only small moves', math.nan
    x = np.log([a for a, s in zip(angles, sig, strict=True) if s])
    y = np.log([g for g, s in zip(gaps, sig, strict=True) if s])
    if x.shape[0] < 2:
        return 'only at ' + ', '.join(f'{a:g} deg' for a, s in zip(angles, sig, strict=True)
                                      if s), math.nan
    slope = float(np.polyfit(x, y, 1)[0])
    if slope > 1.2:
        return 'grows faster than the angle', slope
    if slope > 0.3:
        return 'grows with the angle', slope
    if slope >= -0.3:
        return 'about constant', slope
    return 'shrinks with the angle', slope
