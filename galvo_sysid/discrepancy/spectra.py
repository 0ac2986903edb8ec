"""The residual's spectrum and the numbers made from it: gap, noise gap, band excess.

The comparison (:mod:`galvo_sysid.discrepancy.compare`) works on the spectrum of each
record's second difference (which removes the unknown start offset and velocity of the rigid
body), its first :data:`_SKIP` values left out; the candidate fits
(:mod:`galvo_sysid.discrepancy.candidates`) and the localisation
(:mod:`galvo_sysid.discrepancy.localise`) use the same bins, gap and bands. Everything here is
private to the subpackage.
"""

from __future__ import annotations

import itertools
import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from numpy.typing import NDArray

__all__: list[str] = []

# --------------------------------------------------------------------------- spectra


_SKIP = 2
"""Second differences left out at the start of each record: they hold the kick of the
unrecorded commands just before the record (the command in flight and the amplifier's
current), which the dwell's held current only approximates."""


def _analysed(n: int) -> int:
    """Second differences analysed of records of n samples: an even number, L."""
    return (n - 2 - _SKIP) // 2 * 2


def _second_difference_spectrum(x: NDArray[np.float64]) -> NDArray[np.complex128]:
    """Spectrum (bins 1 .. L/2 - 1) of the second difference of records (..., N).

    The first :data:`_SKIP` second differences are left out, one more if that leaves an odd
    number (L = :func:`_analysed` (N)).
    """
    n = x.shape[-1]
    d2 = np.diff(x, 2, axis=-1)[..., n - 2 - _analysed(n):]
    spec = np.fft.rfft(d2, axis=-1)
    return np.asarray(spec[..., 1:-1], dtype=np.complex128)


def _stack(z: NDArray[np.complex128]) -> NDArray[np.float64]:
    """Complex (..., F) -> real (..., 2F): real parts, then imaginary parts."""
    return np.concatenate([z.real, z.imag], axis=-1)


def _power(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """Stacked real (..., 2F) -> squared magnitude (..., F) (the inverse of :func:`_stack`)."""
    f = x.shape[-1] // 2
    return np.asarray(x[..., :f]**2 + x[..., f:]**2, dtype=np.float64)


def _orthonormal(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """Orthonormal basis of the column space of a (rank-revealing)."""
    if a.shape[1] == 0:
        return np.zeros((a.shape[0], 0))
    u, sv, _ = np.linalg.svd(a, full_matrices=False)
    keep = sv > 1e-10 * sv[0]
    return np.asarray(u[:, keep], dtype=np.float64)


def _fft_conv(x: NDArray[np.float64], h: NDArray[np.float64], lo: int,
              hi: int) -> NDArray[np.float64]:
    """Samples lo:hi of the causal convolutions of records x (..., L) with h (..., L)."""
    nfft = 1 << (x.shape[-1] + h.shape[-1] - 1).bit_length()
    out = np.fft.irfft(np.fft.rfft(x, nfft, axis=-1) * np.fft.rfft(h, nfft, axis=-1), nfft,
                       axis=-1)
    return np.asarray(out[..., lo:hi], dtype=np.float64)


# --------------------------------------------------------------------------- gap and bands


def _gap(cost: float, noise: float) -> float:
    """sqrt(max(0, J / J_noise - 1)): the systematic residual in noise-floor units."""
    return math.sqrt(max(0.0, cost / noise - 1.0)) if noise > 0 else math.nan


def _noise_gap(noise: float) -> float:
    """The largest gap noise alone gives for J_noise = ``noise`` (three standard deviations)."""
    return math.sqrt(3.0 / math.sqrt(noise))


def _band_excess(z2: NDArray[np.float64], *, bands: int) -> list[tuple[int, int, float, int]]:
    """(first bin, bin after the last, excess, count) of ``bands`` log-spaced bands of bins.

    z2 (G, F) is the noise-normalised squared residual per group and bin 1 .. F; a band's
    excess is its sum of z^2 over bins and groups less its count (bins x G), about
    0 +- sqrt(count) for noise alone.
    """
    groups, nb = z2.shape
    total = z2.sum(axis=0)
    edges = np.unique(np.geomspace(1, nb + 1, bands + 1).astype(int))
    out = []
    for lo, hi in itertools.pairwise(int(e) for e in edges):
        n = (hi - lo) * groups
        out.append((lo, hi, float(total[lo - 1:hi - 1].sum()) - n, n))
    return out


def _where_it_acts(without: NDArray[np.float64], with_: NDArray[np.float64]) -> tuple[
        float, float]:
    """Whether an effect leaves a residual consistent with the noise where it acts.

    ``without`` and ``with_`` are the whitened residuals (G, 2F) of the model without and
    with the effect. Where it acts is weighted per bin by w = c / (c + 1), c the power of its
    correction (``without - with_``) in noise units: about 1 where the correction stands
    above the noise, about c where it is lost in it. Returns

    - the weighted excess of the residual with the effect over the noise, in its standard
      deviations: sum w (z^2 - 1) / sqrt(sum w^2), about 0 +- 1 when the residual is noise
      where the effect acts (z^2 of noise has mean and standard deviation 1);
    - the share of the excess there that the effect leaves: sum w (z^2 - 1) over the same
      sum without the effect (about 0 for the right effect, 0.15-1 for a wrong one).
    """
    c = _power(without - with_)
    w = c / (c + 1.0)
    norm = math.sqrt(float(np.sum(w * w)))
    if norm == 0:
        return 0.0, 1.0
    left = float(np.sum(w * (_power(with_) - 1.0)))
    before = float(np.sum(w * (_power(without) - 1.0)))
    return left / norm, (left / before if before > 0 else math.inf)

