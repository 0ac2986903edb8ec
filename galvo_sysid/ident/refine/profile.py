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
  frequencies cover half its band, is not resolved;
- the band's grid steps about 1 % in frequency, coarser than a lightly damped mode's basin:
  a resolved mode is profiled again one grid step either side of its fit, finely, and its
  span reaches where that profile crosses the level (:func:`check_linearised`).

A mode with :data:`STRONG_EVIDENCE` is not scanned over its band, but its linearised std is
checked (:func:`check_linearised`): the cost, the damping minimised out, is evaluated 1 and 3
linearised std either side of its frequency. Where it has not risen 3 std out by most of the
9 times its rise at 1 std that a quadratic cost would (a heavily damped mode near Nyquist,
whose cost is flat on one side), the mode's frequency is profiled locally and its std
widened by how much farther out the cost reaches that level.

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
    'check_linearised',
    'evidence',
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

QUADRATIC_SHORTFALL = 0.75
"""A strong mode's cost must rise, at 3 linearised std of its frequency either side (the
damping minimised out), by this share of what the parabola through its rises at -1, 0 and +1
std gives there (9 times the rise at 1 std when the parabola's minimum is at the fit); else
its linearised std does not stand and it is profiled locally."""

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
        local: A strong mode profiled near its fit (:func:`check_linearised`), not over its
            band.
    """

    evidence: float
    better: tuple[float, float] | None
    omega_span: tuple[float, float]
    zeta_span: tuple[float, float]
    k_span: tuple[float, float]
    local: bool = False

    def resolved(self, band: tuple[float, float]) -> bool:
        """Whether the data place the mode: it brings enough evidence and its plausible
        frequencies do not cover half its band (in log frequency). A strong mode's local
        profile places it however wide: its std says how well."""  # noqa: D205, D209
        lo, hi = band
        covered = math.log(self.omega_span[1] / self.omega_span[0]) / math.log(hi / lo)
        return self.evidence >= MODE_EVIDENCE and (self.local or covered < 0.5)


def evidence(joint: JointProblem, omega: NDArray[np.float64], zeta: NDArray[np.float64],
             lag: float) -> NDArray[np.float64]:
    """Cost reduction each mode brings at (omega, zeta, lag), the other modes fixed.

    What :meth:`JointProblem.scan` gives with the mode's own point as the one candidate (the
    cost of the regression without the mode's three columns less the cost with them), for all
    modes from one factorisation per window: the drop in cost of a column group G is
    ``c_G^T (C_GG)^-1 c_G``, c the least-squares coefficients and C = (Phi^T Phi)^-1. A
    mode whose columns are degenerate there is scanned.
    """
    n = joint.n_modes
    out = np.zeros(n)
    redo = np.zeros(n, dtype=bool)
    for prob, wt in zip(joint.problems, joint.weights, strict=True):
        phi = prob.columns(omega, zeta, lag)
        scale = np.linalg.norm(phi, axis=0)
        scale[scale == 0] = 1.0
        q, r = np.linalg.qr(phi / scale)
        try:
            r_inv = np.linalg.inv(r)
        except np.linalg.LinAlgError:
            redo[:] = True
            continue
        c = r_inv @ (q.T @ prob.yf)
        cov = r_inv @ r_inv.T
        for i in range(n):
            g = np.array([1 + i, 1 + n + 2 * i, 2 + n + 2 * i])
            try:
                out[i] += wt * wt * float(c[g] @ np.linalg.solve(cov[np.ix_(g, g)], c[g]))
            except np.linalg.LinAlgError:
                redo[i] = True
    for j in np.flatnonzero(redo | ~np.isfinite(out)):
        k = int(j)
        out[k] = float(joint.scan(k, omega, zeta, lag, omega[k:k + 1], zeta[k:k + 1])[0][0])
    return out


def profile_modes(joint: JointProblem, x: NDArray[np.float64],
                  band_list: Sequence[tuple[float, float]]) -> list[ModeProfile]:
    """Profile each mode over a grid of its band and damping, the other modes fixed."""
    omega, zeta, lag = joint.unpack(x)
    out = []
    damping = np.array(_DAMPING)
    gains = evidence(joint, omega, zeta, lag)
    for i, (lo, hi) in enumerate(band_list):
        gain0 = float(gains[i])
        if gain0 >= STRONG_EVIDENCE:
            w, z = float(omega[i]), float(zeta[i])
            out.append(ModeProfile(evidence=gain0, better=None, omega_span=(w, w),
                                   zeta_span=(z, z), k_span=(0.0, 0.0)))
            continue
        grid = np.geomspace(lo * 1.001, hi / 1.001, _POINTS)
        w_c = np.concatenate([[omega[i]], np.repeat(grid, damping.size)])
        z_c = np.concatenate([[zeta[i]], np.tile(damping, grid.size)])
        gain, k = joint.scan(i, omega, zeta, lag, w_c, z_c)
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


def _omega_profile(joint: JointProblem, i: int, x: NDArray[np.float64], u: NDArray[np.float64],
                   ridge: tuple[float, float, float], band: tuple[float, float], *,
                   spread: int = 4, damping: NDArray[np.float64] | None = None) -> tuple[
                       NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                       NDArray[np.float64]]:
    """Cost rise of mode i at log-frequency offsets u (in linearised std), its damping minimised.

    Dampings are tried along the linearised ridge (the damping's regression on the frequency)
    and ``spread`` conditional std either side of it, one std apart, and at every offset the
    fixed ``damping`` values if given. Returns, per offset: the rise (a parabola through the
    best ridge damping and its neighbours), the frequency, and the best damping and its
    residue.
    """
    omega, zeta, lag = joint.unpack(x)
    s_w, s_z, rho = ridge
    lo, hi = band
    w = np.clip(omega[i] * np.exp(s_w * u), lo * 1.0001, hi / 1.0001)
    v = np.linspace(-float(spread), float(spread), 2 * spread + 1)
    logz = (math.log(zeta[i]) + rho * s_z * u[:, None]
            + s_z * math.sqrt(max(1.0 - rho * rho, 1e-6)) * v[None, :])
    z = np.exp(np.clip(logz, math.log(1e-5), math.log(0.9)))
    if damping is not None:
        z = np.concatenate([z, np.broadcast_to(damping, (u.size, damping.size))], axis=1)
    w_c = np.concatenate([[omega[i]], np.repeat(w, z.shape[1])])
    z_c = np.concatenate([[zeta[i]], z.ravel()])
    gain, k = joint.scan(i, omega, zeta, lag, w_c, z_c)
    delta = (gain[0] - gain[1:]).reshape(u.size, -1)
    rows = np.arange(u.size)
    best = np.argmin(delta, axis=1)
    rise = delta[rows, best]
    inner = (best > 0) & (best < v.size - 1)
    for r in np.flatnonzero(inner):  # parabola through the best damping and its neighbours
        a, b, c = delta[r, best[r] - 1: best[r] + 2]
        curv = a - 2 * b + c
        if curv > 0:
            rise[r] = b - (a - c) ** 2 / (8 * curv)
    return np.maximum(rise, 0.0), w, z[rows, best], k[1:].reshape(u.size, -1)[rows, best]


def _near_fit(joint: JointProblem, i: int, x: NDArray[np.float64],
              ridge: tuple[float, float, float], band: tuple[float, float],
              p: ModeProfile) -> ModeProfile:
    """A band-scanned mode's profile near its fit, where the band's grid is too coarse.

    The band's grid steps about 1 % in frequency; a lightly damped mode's basin can be
    narrower, so a plausible frequency next to the fit's can fall between two grid points and
    the mode's span collapse to the fit. The cost is profiled one grid step (at least 12
    linearised std) either side of the fit, the damping minimised over the linearised ridge
    and over the grid's dampings whose basins the grid cannot see (narrower than its step);
    the plausible points found widen ``p``'s spans.
    """
    lo, hi = band
    step = (hi / lo) ** (1.0 / (_POINTS - 1)) - 1.0
    s_w = ridge[0]
    reach = max(12.0, step / s_w)
    side = reach * np.array([1.5, 3.0, 4.5, 6.5, 9.0, 12.0]) / 12.0
    damping = np.array([z for z in _DAMPING if s_w <= z <= step])
    rise, w, z, k = _omega_profile(joint, i, x, np.concatenate([-side[::-1], side]), ridge,
                                   band, spread=2, damping=damping)
    ok = rise < PROFILE_LEVEL
    if not ok.any():
        return p
    # the span's ends where the rise crosses the level between two samples (linearly)
    first, last = int(np.argmax(ok)), int(ok.size - 1 - np.argmax(ok[::-1]))
    w_lo, w_hi = float(w[first]), float(w[last])
    if first > 0:
        a = (rise[first - 1] - PROFILE_LEVEL) / (rise[first - 1] - rise[first])
        w_lo = float(w[first - 1] + a * (w[first] - w[first - 1]))
    if last < ok.size - 1:
        a = (rise[last + 1] - PROFILE_LEVEL) / (rise[last + 1] - rise[last])
        w_hi = float(w[last + 1] + a * (w[last] - w[last + 1]))
    return ModeProfile(
        evidence=p.evidence, better=p.better,
        omega_span=(min(w_lo, p.omega_span[0]), max(w_hi, p.omega_span[1])),
        zeta_span=(min(float(z[ok].min()), p.zeta_span[0]),
                   max(float(z[ok].max()), p.zeta_span[1])),
        k_span=(min(float(k[ok].min()), p.k_span[0]), max(float(k[ok].max()), p.k_span[1])))


def _quadratic(rise: NDArray[np.float64]) -> bool:
    """Whether a cost's rises at -3, -1, +1 and +3 std are those of a parabola (to
    :data:`QUADRATIC_SHORTFALL`).

    The parabola ``c u^2 + b u`` through the rises at -1, 0 and +1 may have its minimum up
    to one std from the fit: a joint fit's profile lets each window's residue of the mode
    free (:meth:`JointProblem.scan`), a looser model whose minimum lies a fraction of a std
    beside the joint optimum. Beyond, or where the rises at 3 std fall short of the
    parabola's, the cost is not the quadratic the linearised std stands for. No rise at
    either 1 std (the rises are clipped at 0) leaves no parabola to compare with: passed, as
    the local profile's level (9 times that rise) would be 0.
    """  # noqa: D205
    c = 0.5 * float(rise[2] + rise[1])
    b = 0.5 * float(rise[2] - rise[1])
    if not c > 0:
        return True
    return bool(abs(b) <= 2.0 * c
                and rise[0] >= QUADRATIC_SHORTFALL * (9.0 * c - 3.0 * b)
                and rise[3] >= QUADRATIC_SHORTFALL * (9.0 * c + 3.0 * b))


def check_linearised(joint: JointProblem, x: NDArray[np.float64], cov: NDArray[np.float64],
                     profiles: Sequence[ModeProfile],
                     band_list: Sequence[tuple[float, float]], *,
                     unresolved: Sequence[int] = ()) -> list[ModeProfile]:
    """Profiles near the fit, where the linearised std or the band's grid may not stand.

    Args:
        joint: The problem, prewhitened as at the fit.
        x: The fit.
        cov: Its linearised covariance (k0, residues, frequencies, dampings, ...).
        profiles: :func:`profile_modes` at x; strong modes have a zero-width span.
        band_list: The modes' bands [rad/s].
        unresolved: Modes found unresolved (their std is their band's): not profiled.

    Returns:
        ``profiles`` with each strong mode whose check fails replaced by its local profile:
        the frequencies where the cost, damping minimised out, rises by less than it does at
        3 std by its curvature at the fit (9 for a quadratic cost in noise units), and the
        dampings and residues along that path; and each band-scanned mode with evidence
        enough to be resolved widened by its profile one grid step either side of the fit
        (the points below :data:`PROFILE_LEVEL`, the ends interpolated).
    """
    omega, zeta, _ = joint.unpack(x)
    n = joint.n_modes
    out = list(profiles)
    for i, p in enumerate(profiles):
        if p.evidence < MODE_EVIDENCE or i in unresolved:
            continue  # not resolved: its std is the band's
        jw, jz = 1 + n + i, 1 + 2 * n + i
        var_w, var_z = float(cov[jw, jw]), float(cov[jz, jz])
        if not (var_w > 0 and var_z > 0 and math.isfinite(var_w + var_z)):
            continue
        s_w = math.sqrt(var_w) / omega[i]
        s_z = math.sqrt(var_z) / zeta[i]
        rho = float(np.clip(cov[jw, jz] / math.sqrt(var_w * var_z), -1.0, 1.0))
        ridge = (s_w, s_z, rho)
        if not p.local and p.evidence < STRONG_EVIDENCE:  # scanned over its band
            out[i] = _near_fit(joint, i, x, ridge, band_list[i], p)
            continue
        rise = _omega_profile(joint, i, x, np.array([-3.0, -1.0, 1.0, 3.0]), ridge,
                              band_list[i], spread=2)[0]
        if _quadratic(rise):
            continue
        # The level of 3 std by the cost's own curvature at the fit: the linearised
        # (sandwich) std stands for a quadratic cost, and is scaled by how much farther
        # than 3 std the cost's rise reaches that level.
        level = 9.0 * 0.5 * float(rise[1] + rise[2])
        reach = 12.0
        for _ in range(4):  # widen the scan while the plausible region reaches its ends
            u = np.linspace(-reach, reach, 25)
            rise, w, z, k = _omega_profile(joint, i, x, u, ridge, band_list[i])
            ok = rise < level
            if not (ok[0] or ok[-1]) or reach * s_w > 1.0:
                break
            reach *= 2.0
        out[i] = ModeProfile(
            evidence=p.evidence, better=None,
            omega_span=(float(min(w[ok].min(), omega[i])), float(max(w[ok].max(), omega[i]))),
            zeta_span=(float(min(z[ok].min(), zeta[i])), float(max(z[ok].max(), zeta[i]))),
            k_span=(float(k[ok].min()), float(k[ok].max())),
            local=True)
    return out
