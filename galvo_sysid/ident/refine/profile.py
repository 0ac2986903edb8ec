"""Each weakly excited mode's cost over its band: a global search and an honest std.

The output-error cost of a weakly excited, lightly damped mode is flat over a wide region or
has several basins; the linearised covariance at the optimum then claims far too much (a
narrow noise peak looks sharp). For every mode that does not bring overwhelming evidence,
the cost is scanned over a grid of its band and of damping ratios, the other modes fixed
(:func:`profile_modes`):

- a grid point with a clearly lower cost than the fit's starts another polish (the global
  search; kept if it lowers the cost);
- the points within :data:`PROFILE_LEVEL` of the fit's cost are as plausible as it: the
  mode's std is raised so that the farthest of them lies 3 std away
  (:func:`widen_to_profiles`);
- a mode that lowers the cost by less than :data:`MODE_EVIDENCE`, or whose plausible
  frequencies cover half its band, is not resolved.

Costs are those of :class:`~galvo_sysid.ident.refine.joint.JointProblem`: weighted by each
window's noise, so in units of the averaged noise's variance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import NDArray

    from galvo_sysid.ident.refine.joint import JointProblem

__all__ = [
    'MODE_EVIDENCE',
    'PROFILE_LEVEL',
    'STRONG_EVIDENCE',
    'ModeProfile',
    'profile_modes',
    'widen_to_profiles',
]

PROFILE_LEVEL = 9.21
"""Cost increase (noise-variance units) within which another frequency and damping of a
mode are as plausible as the fit's (chi-square, 2 degrees of freedom, 99 %)."""

MODE_EVIDENCE = 25.0
"""Cost reduction (same units) a mode must bring, the others fixed, to count as resolved."""

STRONG_EVIDENCE = 400.0
"""A mode bringing this much cost reduction (20 sigma) is placed sharply: its linearised std
holds and its profile is not scanned (saves time)."""

_DAMPING = tuple(float(z) for z in np.geomspace(3e-4, 0.2, 8))
_POINTS = 32


@dataclass(frozen=True)
class ModeProfile:
    """What one mode's profile over its band says (costs in noise-variance units).

    Attributes:
        evidence: Cost reduction the mode brings at the fit, the other modes fixed.
        better: A (omega, zeta) of the scan with a clearly lower cost than the fit's, if any.
        omega_span: Smallest and largest plausible frequency [rad/s].
        zeta_span: Smallest and largest plausible damping ratio.
        k_span: Smallest and largest residue over the plausible points.
    """

    evidence: float
    better: tuple[float, float] | None
    omega_span: tuple[float, float]
    zeta_span: tuple[float, float]
    k_span: tuple[float, float]

    def resolved(self, band: tuple[float, float]) -> bool:
        """Whether the data place the mode: it brings enough evidence and its plausible
        frequencies do not cover half its band (in log frequency)."""  # noqa: D205, D209
        lo, hi = band
        covered = math.log(self.omega_span[1] / self.omega_span[0]) / math.log(hi / lo)
        return self.evidence >= MODE_EVIDENCE and covered < 0.5


def _scan(joint: JointProblem, i: int, omega: NDArray[np.float64], zeta: NDArray[np.float64],
          lag: float, w_c: NDArray[np.float64],
          z_c: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Joint cost reduction of mode i at the candidates, and their (weighted mean) residue."""
    gain = np.zeros(w_c.size)
    k_sum = np.zeros(w_c.size)
    total = 0.0
    for prob, wt in zip(joint.problems, joint.weights, strict=True):
        g, k = prob.scan(i, omega, zeta, lag, w_c, z_c)
        gain += wt * wt * g
        k_sum += wt * wt * k
        total += wt * wt
    return gain, k_sum / total


def profile_modes(joint: JointProblem, x: NDArray[np.float64],
                  band_list: Sequence[tuple[float, float]]) -> list[ModeProfile]:
    """Profile each mode over a grid of its band and damping, the other modes fixed."""
    omega, zeta, lag = joint.unpack(x)
    out = []
    damping = np.array(_DAMPING)
    for i, (lo, hi) in enumerate(band_list):
        gain0 = float(_scan(joint, i, omega, zeta, lag, omega[i:i + 1], zeta[i:i + 1])[0][0])
        if gain0 >= STRONG_EVIDENCE:
            w, z = float(omega[i]), float(zeta[i])
            out.append(ModeProfile(evidence=gain0, better=None, omega_span=(w, w),
                                   zeta_span=(z, z), k_span=(0.0, 0.0)))
            continue
        grid = np.geomspace(lo * 1.001, hi / 1.001, _POINTS)
        w_c = np.concatenate([[omega[i]], np.repeat(grid, damping.size)])
        z_c = np.concatenate([[zeta[i]], np.tile(damping, grid.size)])
        gain, k = _scan(joint, i, omega, zeta, lag, w_c, z_c)
        delta = gain[0] - gain
        ok = delta < PROFILE_LEVEL
        best = int(np.argmin(delta))
        better = (float(w_c[best]), float(z_c[best])) if delta[best] < -1.0 else None
        out.append(ModeProfile(
            evidence=float(gain[0]), better=better,
            omega_span=(float(w_c[ok].min()), float(w_c[ok].max())),
            zeta_span=(float(z_c[ok].min()), float(z_c[ok].max())),
            k_span=(float(k[ok].min()), float(k[ok].max()))))
    return out


def widen_to_profiles(cov: NDArray[np.float64], profiles: Sequence[ModeProfile],
                      estimate: Sequence[float], n: int) -> None:
    """Raise each mode's std (in place) to a third of the farthest plausible value's distance.

    The farthest point of the mode's 99 % region is read as 3 std away; where that is wider
    than the linearised std, the parameter's correlations are dropped.
    """
    for i, p in enumerate(profiles):
        for j, (a, b) in ((1 + i, p.k_span), (1 + n + i, p.omega_span),
                          (1 + 2 * n + i, p.zeta_span)):
            floor = max(abs(b - estimate[j]), abs(estimate[j] - a)) / 3.0 if b > a else 0.0
            if floor * floor > cov[j, j]:
                cov[j, :] = 0.0
                cov[:, j] = 0.0
                cov[j, j] = floor * floor
