"""The refined fit's checks: bands, bounds, modes at a band edge, unresolved modes, adequacy.

Adequacy is whether the residual is noise over the whole spectrum: below the first band,
between the bands and above the last one.
"""

from __future__ import annotations

import itertools
import math
from typing import TYPE_CHECKING

import numpy as np
from scipy import fft as sp_fft
from scipy.special import log_ndtr

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.ident.refine.options import MAX_DAMPING, MIN_DAMPING
from galvo_sysid.model.modal import default_bands

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import NDArray

    from galvo_sysid.model.modal import ModalModel

__all__ = ['bands_for', 'bounds', 'edge_mode', 'inflate_unresolved', 'residual_to_noise',
           'selection_bias', 'widen_selected']


def bands_for(initial: ModalModel, bands: Sequence[tuple[float, float]] | None,
              sample_period: float) -> list[tuple[float, float]]:
    """Each mode's band [rad/s], checked (default: around ``initial``'s modes)."""
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


def bounds(band_list: Sequence[tuple[float, float]], estimate_lag: bool,
           lag_bounds: tuple[float, float]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Bounds of x = [ln omega_i, ln zeta_i, (T_l / T)]."""
    n = len(band_list)
    lb = [*np.log([lo for lo, _ in band_list]), *np.full(n, math.log(MIN_DAMPING))]
    ub = [*np.log([hi for _, hi in band_list]), *np.full(n, math.log(MAX_DAMPING))]
    if estimate_lag:
        lb.append(lag_bounds[0])
        ub.append(lag_bounds[1])
    return np.array(lb), np.array(ub)


def edge_mode(params: tuple[NDArray[np.float64], NDArray[np.float64], float],
              band_list: Sequence[tuple[float, float]]) -> int | None:
    """Index of the first mode stuck at a band edge or at the damping bound, else None."""
    omega, zeta, _ = params
    for i, ((lo, hi), w, z) in enumerate(zip(band_list, omega, zeta, strict=True)):
        if not lo * 1.0005 < w < hi / 1.0005 or z > 0.99 * MAX_DAMPING:
            return i
    return None


def inflate_unresolved(cov: NDArray[np.float64], unresolved: Sequence[int],
                       band_list: Sequence[tuple[float, float]], n: int) -> None:
    """Give the unresolved modes' omega and zeta (in place) at least a uniform prior's std."""
    for i in unresolved:
        lo, hi = band_list[i]
        for j, floor in ((1 + n + i, (hi - lo) / math.sqrt(12.0)),
                         (1 + 2 * n + i, MAX_DAMPING / math.sqrt(12.0))):
            var = max(float(cov[j, j]), floor * floor)
            cov[j, :] = 0.0
            cov[:, j] = 0.0
            cov[j, j] = var


def selection_bias(z: float, threshold: float) -> float:
    """Expected excess of a residue that passed the resolution test, in its std.

    A residue is reported only where ``|k| >= threshold * std`` (the "winner's curse"): one
    that just passes is likely to have been pushed over by the noise. The true residue mu (in
    std units) given the observed z and the test has the conditional likelihood
    ``phi(z - mu) / P(|Z| >= threshold | mu)`` (Ghosh, Zou and Wright, Am. J. Hum. Genet.
    2008); under a flat prior, ``|z|`` less its mean is how much nearer zero the truth is
    expected to lie. Returns that excess (>= 0, in std): 2.98 at a threshold of 5, 1.06 one
    std above it, 0.04 three std above it; 0 below the threshold or without a test
    (threshold 0).
    """
    a = abs(z)
    if threshold <= 0 or not math.isfinite(a) or a < threshold or a > threshold + 8.0:
        return 0.0  # (8 std above the threshold the excess is below 1e-7)
    mu = np.linspace(-threshold - 10.0, a + 10.0, 1201)
    log_pass = np.logaddexp(log_ndtr(-threshold - mu), log_ndtr(mu - threshold))
    log_l = -0.5 * (a - mu) ** 2 - log_pass
    w = np.exp(log_l - log_l.max())
    return max(0.0, a - float(np.sum(mu * w) / np.sum(w)))


def widen_selected(cov: NDArray[np.float64], residues: Sequence[float],
                   resolved: Sequence[bool], *, threshold: float, n: int) -> None:
    """Raise each resolved residue's std (in place) by the bias of its selection.

    The std becomes ``std * sqrt(1 + b^2)``, b the residue's :func:`selection_bias`: the root
    mean square error of a residue that passed the test. Its correlations are kept (its row
    and column are scaled). The other parameters keep their std: carrying the bias over to
    them by their regression on the residue made the dampings' std too wide in trials on
    ``benchmarks/efficiency.py``'s conditions, because a mode is selected by its evidence,
    not by its residue alone. A residue far above the threshold is unchanged.
    """
    for i in range(n):
        j = 1 + i
        var = float(cov[j, j])
        if not (resolved[i] and var > 0 and math.isfinite(var)):
            continue
        b = selection_bias(residues[i] / math.sqrt(var), threshold)
        if b > 0:
            f = math.sqrt(1.0 + b * b)
            cov[j, :] *= f
            cov[:, j] *= f


def residual_to_noise(resid: NDArray[np.float64], dev: NDArray[np.float64],
                      band_list: Sequence[tuple[float, float]],
                      sample_period: float) -> tuple[tuple[tuple[float, float], float], ...]:
    """Energy of the averaged residual over that expected from the noise, per interval.

    The intervals cut the spectrum at every band edge: below the first band (from four
    periods per record on), between the bands, and above the last one up to 0.98 x Nyquist,
    so a mode outside every band shows too; without bands (a model of the rigid body alone)
    the whole of that range is one interval. About 1 for an adequate model.
    """
    m = dev.shape[0]
    win = np.hanning(resid.size)
    res_psd = np.abs(sp_fft.rfft(resid * win)) ** 2
    noise_psd = np.mean(np.abs(sp_fft.rfft(dev * win, axis=1)) ** 2, axis=0) / m
    freq = np.fft.rfftfreq(resid.size, sample_period) * 2 * math.pi
    lowest = 2 * math.pi * 4 / (resid.size * sample_period)
    top = 0.98 * math.pi / sample_period
    cuts = {e for band in band_list for e in band}
    if cuts:
        cuts |= {e for e in (lowest, top) if e < min(cuts) or e > max(cuts)}
    else:  # a model of the rigid body alone: the whole spectrum is one interval
        cuts = {lowest, top}
    edges = sorted(cuts)
    out = []
    for lo, hi in itertools.pairwise(edges):
        sel = (freq >= lo) & (freq < hi)
        noise = float(np.sum(noise_psd[sel]))
        if noise > 0 and np.count_nonzero(sel) >= 3:
            out.append(((lo, hi), float(np.sum(res_psd[sel])) / noise))
    return tuple(out)
