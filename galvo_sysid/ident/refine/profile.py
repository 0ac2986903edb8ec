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
  (:func:`widen_to_profiles`); so that the farthest point within :data:`ELSEWHERE_LEVEL`
  lies 4 std away too (a quadratic cost's std is the same by both; a long flat shoulder,
  where a lightly damped fit sits on a noise peak beside a broad true resonance, is not cut
  at the lower level: :func:`_span`);
- the other residues and k0, solved anew at each of those points, widen likewise (after
  the test of which modes are resolved): where the mode could lie elsewhere, a neighbour
  sharing its response could have another residue (:attr:`ModeProfile.residue_spans`);
- a mode that lowers the cost by less than :data:`MODE_EVIDENCE`, or whose plausible
  frequencies cover half its band, is not resolved; nor is a fit at its band's edge that is
  as plausible a grid step inside (:meth:`ModeProfile.open_at_edge`: held there by the band,
  not by the data, so no sign of a mode outside the band either);
- the band's grid steps about 1 % in frequency, coarser than a lightly damped mode's basin:
  a resolved mode is profiled again one grid step either side of its fit, finely, and its
  span reaches where that profile crosses the level (:func:`check_linearised`).

A mode with :data:`STRONG_EVIDENCE` has its linearised std (its band is still scanned up to
:data:`SEARCHED_EVIDENCE`: a better basin or a shoulder count as above), checked
(:func:`check_linearised`): the cost, the damping minimised out, is evaluated 1 and 3
linearised std either side of its frequency. Where it has not risen 3 std out by most of the
9 times its rise at 1 std that a quadratic cost would (a heavily damped mode near Nyquist,
whose cost is flat on one side), the mode's frequency is profiled locally and its std
widened by how much farther out the cost reaches that level. Its damping is checked the same
way (:func:`_damping_span`): a lightly damped fit's cost is steep near the fit and flat
beyond, so a damping ten times the fit's can be as plausible as it.

Costs are those of :class:`~galvo_sysid.ident.refine.joint.JointProblem`: weighted by each
window's noise, so in units of the averaged noise's variance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from galvo_sysid.ident.refine.options import MAX_DAMPING, MIN_DAMPING

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import NDArray

    from galvo_sysid.ident.refine.joint import JointProblem

__all__ = [
    'MODE_EVIDENCE',
    'PLACED_SHARE',
    'PROFILE_LEVEL',
    'SEARCHED_EVIDENCE',
    'STRONG_EVIDENCE',
    'ModeProfile',
    'check_linearised',
    'evidence',
    'profile_modes',
    'unprofiled',
    'widen_to_profiles',
]

PROFILE_LEVEL = 9.21
"""Cost increase (noise-variance units) within which another frequency and damping of a
mode are as plausible as the fit's (chi-square, 2 degrees of freedom, 99 %)."""

MODE_EVIDENCE = 25.0
"""Cost reduction (same units) a mode must bring, the others fixed, to count as resolved."""

PLACED_SHARE = 0.5
"""A mode whose plausible frequencies cover this share of its band (in log frequency) or more
is not placed by the data: not resolved (:meth:`ModeProfile.resolved`)."""

STRONG_EVIDENCE = 400.0
"""A mode bringing this much cost reduction (20 sigma) is placed sharply: its std is the
linearised one, checked near the fit (:func:`check_linearised`), not its band profile's."""

SEARCHED_EVIDENCE = 1600.0
"""Up to this cost reduction (40 sigma) a strong mode's band is still scanned, for a better
basin and for a flat shoulder below :data:`ELSEWHERE_LEVEL`: a lightly damped fit of
evidence 526 sat on a noise peak 4.9 % from the truth on ``random_scanner(14)``, on a
shoulder that rose only 11-16 above it out to the truth. Above it the scan is skipped (saves
time)."""

QUADRATIC_SHORTFALL = 0.75
"""A strong mode's cost must rise, at 3 linearised std of its frequency either side (the
damping minimised out), by this share of what the parabola through its rises at -1, 0 and +1
std gives there (9 times the rise at 1 std when the parabola's minimum is at the fit); else
its linearised std does not stand and it is profiled locally."""

FLAT_CURVATURE = 0.5
"""A strong mode's cost rising by less than this at 1 linearised std of its frequency (1 where
the noise model and the sandwich covariance agree) is flatter than that std says: it is profiled
locally, out to a rise of 9 (3 std by the cost itself). On ``random_scanner(52)``'s 8.45 kHz
mode (0.59 x Nyquist) a window's fit sat in a narrow dip at zeta 0.001 (truth 0.005) on a
plateau whose rise stayed below 10 over 2.5 % of frequency: the rise at 1 std was 0.17, the
parabola's shape passed, and the frequency came out 7 linearised std off. On
``benchmarks/efficiency.py``'s family the rise at 1 std lies within 0.75-2.1."""

_DAMPING = tuple(float(z) for z in np.geomspace(3e-4, 0.2, 8))
_POINTS = 32

ELSEWHERE_LEVEL = PROFILE_LEVEL + 2.0 * math.log(_POINTS)
"""Cost rise (16.1) within which a point of the band's grid is plausible too, as 4 std of a
quadratic cost (:func:`_span`): :data:`PROFILE_LEVEL` with a Bonferroni correction for the
grid's :data:`_POINTS` frequencies. A weakly excited mode's fit is the best of many noisy
basins or a sharp noise peak on a broad one; on the scanner family (``random_scanner``,
half the reference move) the truth rose more than 9.21 above such a fit in 10 % of the
windows that resolved the mode, never more than 16."""


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
        better_coverage: With ``better``: the share of the band (in log frequency) that the
            scan's points within :data:`PROFILE_LEVEL` of the better point cover; at
            :data:`PLACED_SHARE` or more the mode is not placed in that basin either.
        residue_spans: Of a mode whose band was scanned: the smallest and largest of every
            shared residue [k0, k_1 .. k_n] over the same plausible points, each solved anew
            with the mode there (empty where the band was not scanned). Where the mode
            could lie elsewhere in its band, the other modes' residues could too
            (:func:`widen_to_profiles`).
    """

    evidence: float
    better: tuple[float, float] | None
    omega_span: tuple[float, float]
    zeta_span: tuple[float, float]
    k_span: tuple[float, float]
    local: bool = False
    better_coverage: float = 0.0
    residue_spans: tuple[tuple[float, float], ...] = ()

    def resolved(self, band: tuple[float, float]) -> bool:
        """Whether the data place the mode: it brings enough evidence and its plausible
        frequencies do not cover half its band (in log frequency). A strong mode's local
        profile places it however wide: its std says how well."""  # noqa: D205, D209
        lo, hi = band
        covered = math.log(self.omega_span[1] / self.omega_span[0]) / math.log(hi / lo)
        return self.evidence >= MODE_EVIDENCE and (self.local or covered < PLACED_SHARE)

    def open_at_edge(self, band: tuple[float, float], omega: float) -> bool:
        """Whether a fit at an edge of its band is held there by the band, not by the data.

        True where the fit's frequency ``omega`` lies at the band's edge and the plausible
        frequencies reach a step of the band's grid or more inside it: the cost is lowest at
        the boundary of what was searched but as plausible within, so the data do not place
        the mode (nor ask for one outside the band). False where they stay at the edge (the
        data ask for a mode beyond it) or the fit lies inside.
        """
        lo, hi = band
        step = (hi / lo) ** (1.0 / (_POINTS - 1))
        if omega >= hi / 1.0005:
            return bool(self.omega_span[0] <= hi / step)
        if omega <= lo * 1.0005:
            return bool(self.omega_span[1] >= lo * step)
        return False


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
        w, z = float(omega[i]), float(zeta[i])
        if gain0 >= SEARCHED_EVIDENCE:
            out.append(ModeProfile(evidence=gain0, better=None, omega_span=(w, w),
                                   zeta_span=(z, z), k_span=(0.0, 0.0)))
            continue
        grid = np.geomspace(lo * 1.001, hi / 1.001, _POINTS)
        w_c = np.concatenate([[omega[i]], np.repeat(grid, damping.size)])
        z_c = np.concatenate([[zeta[i]], np.tile(damping, grid.size)])
        gain, residues = joint.scan_residues(i, omega, zeta, lag, w_c, z_c)
        k = residues[1 + i]
        delta = gain[0] - gain
        best = int(np.argmin(delta))
        better = (float(w_c[best]), float(z_c[best])) if delta[best] < -1.0 else None
        coverage = 0.0
        if better is not None:  # how much of the band the better basin would leave open
            near = w_c[delta < delta[best] + PROFILE_LEVEL]
            coverage = math.log(float(near.max()) / float(near.min())) / math.log(hi / lo)
        # the plausible points: below PROFILE_LEVEL (3 std), and below ELSEWHERE_LEVEL drawn
        # in to 3 std of a quadratic cost (a long flat shoulder, that the lower level cuts)
        ok = delta < PROFILE_LEVEL
        wide = delta < ELSEWHERE_LEVEL
        out.append(ModeProfile(
            evidence=float(gain[0]), better=better, omega_span=_span(w_c, w, ok, wide),
            zeta_span=_span(z_c, z, ok, wide), k_span=_span(k, float(k[0]), ok, wide),
            better_coverage=coverage,
            residue_spans=tuple(_span(r, float(r[0]), ok, wide) for r in residues)))
    return out


def unprofiled(joint: JointProblem, x: NDArray[np.float64],
               band_list: Sequence[tuple[float, float]]) -> list[ModeProfile]:
    """What can be said of each mode at x without :func:`profile_modes`' band scans.

    For a fit out of time (:attr:`~galvo_sysid.ident.refine.options.RefineOptions.deadline`):
    a mode with :data:`SEARCHED_EVIDENCE` gets the profile :func:`profile_modes` gives it
    (not scanned there either); any other mode is not placed, its plausible frequencies
    its whole band (so not resolved, its std its band's): without its scan, a better basin or
    a flat shoulder cannot be ruled out.
    """
    omega, zeta, lag = joint.unpack(x)
    gains = evidence(joint, omega, zeta, lag)
    out = []
    for i, (lo, hi) in enumerate(band_list):
        w, z = float(omega[i]), float(zeta[i])
        span = (w, w) if gains[i] >= SEARCHED_EVIDENCE else (float(lo), float(hi))
        out.append(ModeProfile(evidence=float(gains[i]), better=None, omega_span=span,
                               zeta_span=(z, z), k_span=(0.0, 0.0)))
    return out


def _span(values: NDArray[np.float64], fit: float, ok: NDArray[np.bool_],
          wide: NDArray[np.bool_]) -> tuple[float, float]:
    """Smallest and largest of ``values`` over the plausible points (see :func:`profile_modes`).

    The points below :data:`PROFILE_LEVEL` lie within 3 std of a quadratic cost, those below
    :data:`ELSEWHERE_LEVEL` within 4; the latter are drawn in to 3/4 of their distance from
    the fit, so a quadratic cost's span is unchanged and a flat shoulder's is not cut at the
    lower level.
    """
    wide = wide | ok
    shoulder = 3.0 / math.sqrt(max(ELSEWHERE_LEVEL, PROFILE_LEVEL))
    lo = min(float(values[ok].min()), fit + shoulder * (float(values[wide].min()) - fit))
    hi = max(float(values[ok].max()), fit + shoulder * (float(values[wide].max()) - fit))
    return lo, hi


def widen_to_profiles(cov: NDArray[np.float64], profiles: Sequence[ModeProfile],
                      estimate: Sequence[float], n: int, *, neighbours: bool = True) -> None:
    """Raise each mode's std (in place) to a third of the farthest plausible value's distance.

    The farthest point of the mode's 99 % region is read as 3 std away; where that is wider
    than the linearised std, the parameter's correlations are dropped. The other residues
    (k0 and the other modes') likewise, by their spans over the mode's band profile
    (:attr:`ModeProfile.residue_spans`): where a weakly excited mode could lie elsewhere in its
    band, a neighbour sharing its response could have another residue too. (On
    ``random_scanner(14)``, whose fifth mode, at 0.59 x Nyquist, a window resolves in 114 of 400
    seeds, the fourth mode's residue had rms(error / std) 1.37, over the windows that leave
    the fifth unresolved 1.22; with the spans 1.21 and 1.01.) Without ``neighbours`` only
    each mode's own parameters (as before the test of which modes are resolved: a neighbour's
    uncertainty does not make a mode's residue insignificant).
    """
    for i, p in enumerate(profiles):
        others = [(j, span) for j, span in enumerate(p.residue_spans)
                  if neighbours and j != 1 + i]
        for j, (a, b) in ((1 + i, p.k_span), (1 + n + i, p.omega_span),
                          (1 + 2 * n + i, p.zeta_span), *others):
            floor = max(abs(b - estimate[j]), abs(estimate[j] - a)) / 3.0 if b > a else 0.0
            if floor * floor > cov[j, j]:
                cov[j, :] = 0.0
                cov[:, j] = 0.0
                cov[j, j] = floor * floor


def _scan_blocks(joint: JointProblem, i: int, x: NDArray[np.float64],
                 blocks: Sequence[tuple[NDArray[np.float64], NDArray[np.float64]]]) -> list[
                     tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """Cost rise and residue of mode i at blocks of candidates ``(w, z)`` (each (rows, c)),
    the others fixed: one scan for all blocks (the other modes' columns are made once)."""  # noqa: D205, D209
    omega, zeta, lag = joint.unpack(x)
    w_c = np.concatenate([[omega[i]], *(np.ravel(w) for w, _ in blocks)])
    z_c = np.concatenate([[zeta[i]], *(np.ravel(z) for _, z in blocks)])
    gain, k = joint.scan(i, omega, zeta, lag, w_c, z_c)
    out = []
    at = 1
    for w, _ in blocks:
        size = int(np.size(w))
        out.append(((gain[0] - gain[at: at + size]).reshape(np.shape(w)),
                    k[at: at + size].reshape(np.shape(w))))
        at += size
    return out


def _omega_block(joint: JointProblem, i: int, x: NDArray[np.float64], u: NDArray[np.float64],
                 ridge: tuple[float, float, float], band: tuple[float, float], *,
                 spread: int = 4, damping: NDArray[np.float64] | None = None) -> tuple[
                     NDArray[np.float64], NDArray[np.float64]]:
    """:func:`_omega_profile`'s candidates, (offsets, dampings) each."""
    omega, zeta, _ = joint.unpack(x)
    s_w, s_z, rho = ridge
    lo, hi = band
    w = np.clip(omega[i] * np.exp(s_w * u), lo * 1.0001, hi / 1.0001)
    v = np.linspace(-float(spread), float(spread), 2 * spread + 1)
    logz = (math.log(zeta[i]) + rho * s_z * u[:, None]
            + s_z * math.sqrt(max(1.0 - rho * rho, 1e-6)) * v[None, :])
    z = np.exp(np.clip(logz, math.log(1e-5), math.log(0.9)))
    if damping is not None:
        z = np.concatenate([z, np.broadcast_to(damping, (u.size, damping.size))], axis=1)
    return np.repeat(w[:, None], z.shape[1], axis=1), z


def _omega_rises(block: tuple[NDArray[np.float64], NDArray[np.float64]],
                 scanned: tuple[NDArray[np.float64], NDArray[np.float64]], spread: int) -> tuple[
                     NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                     NDArray[np.float64]]:
    """:func:`_omega_profile`'s result from its block's scan."""
    w, z = block
    delta, k = scanned
    rows = np.arange(w.shape[0])
    best = np.argmin(delta, axis=1)
    rise = delta[rows, best]
    inner = (best > 0) & (best < 2 * spread)
    for r in np.flatnonzero(inner):  # parabola through the best damping and its neighbours
        a, b, c = delta[r, best[r] - 1: best[r] + 2]
        curv = a - 2 * b + c
        if curv > 0:
            rise[r] = b - (a - c) ** 2 / (8 * curv)
    return np.maximum(rise, 0.0), w[:, 0], z[rows, best], k[rows, best]


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
    block = _omega_block(joint, i, x, u, ridge, band, spread=spread, damping=damping)
    return _omega_rises(block, _scan_blocks(joint, i, x, [block])[0], spread)


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
        k_span=(min(float(k[ok].min()), p.k_span[0]), max(float(k[ok].max()), p.k_span[1])),
        residue_spans=p.residue_spans)


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


_ZETA_SPREAD = np.array([-1.0, -0.5, 0.0, 0.5, 1.0])
_CHECK = np.array([-3.0, -1.0, 1.0, 3.0])  # offsets of the linearised std's checks [std]


def _zeta_offsets(zeta: float, s_z: float, u: NDArray[np.float64]) -> tuple[
        NDArray[np.float64], NDArray[np.bool_]]:
    """The dampings ``u`` linearised std (relative ``s_z``) from ``zeta``, and which of them lie
    in ``[MIN_DAMPING, MAX_DAMPING]``."""  # noqa: D205, D209
    z = zeta * (1.0 + s_z * u)
    return z, (z >= MIN_DAMPING) & (z <= MAX_DAMPING)


def _k_span(p: ModeProfile, k: NDArray[np.float64]) -> tuple[float, float]:
    """The residues ``k`` spanned, with ``p``'s own span if its band was scanned (a strong
    mode's is empty)."""  # noqa: D205, D209
    lo, hi = float(k.min()), float(k.max())
    return (min(lo, p.k_span[0]), max(hi, p.k_span[1])) if p.k_span[1] > p.k_span[0] else (lo, hi)


def _zeta_block(joint: JointProblem, i: int, x: NDArray[np.float64], u: NDArray[np.float64],
                ridge: tuple[float, float, float], band: tuple[float, float]) -> tuple[
                    NDArray[np.float64], NDArray[np.float64]]:
    """:func:`_zeta_profile`'s candidates, (offsets, frequencies) each; an offset whose
    damping leaves ``[MIN_DAMPING, MAX_DAMPING]`` is put at the fit's damping."""  # noqa: D205, D209
    omega, zeta, _ = joint.unpack(x)
    s_w, s_z, rho = ridge
    lo, hi = band
    z, valid = _zeta_offsets(float(zeta[i]), s_z, u)
    z = np.where(valid, z, zeta[i])
    centre = omega[i] * np.exp(rho * s_w * u)
    w = np.clip(centre[:, None] * (1.0 + z[:, None] * _ZETA_SPREAD[None, :]), lo * 1.0001,
                hi / 1.0001)
    return w, np.repeat(z[:, None], _ZETA_SPREAD.size, axis=1)


def _zeta_rises(joint: JointProblem, i: int, x: NDArray[np.float64], u: NDArray[np.float64],
                ridge: tuple[float, float, float],
                block: tuple[NDArray[np.float64], NDArray[np.float64]],
                scanned: tuple[NDArray[np.float64], NDArray[np.float64]]) -> tuple[
                    NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                    NDArray[np.float64]]:
    """:func:`_zeta_profile`'s result from its block's scan."""
    _, zeta, _ = joint.unpack(x)
    valid = _zeta_offsets(float(zeta[i]), ridge[1], u)[1]
    w, z = block
    delta, k = scanned
    rows = np.arange(u.size)
    best = np.argmin(delta, axis=1)
    rise = np.where(valid, np.maximum(delta[rows, best], 0.0), np.nan)
    return rise, w[rows, best], z[:, 0], k[rows, best]


def _zeta_profile(joint: JointProblem, i: int, x: NDArray[np.float64], u: NDArray[np.float64],
                  ridge: tuple[float, float, float], band: tuple[float, float]) -> tuple[
                      NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                      NDArray[np.float64]]:
    """Cost rise of mode i at damping offsets u (in linearised std of zeta), its frequency
    minimised: along the linearised ridge (the frequency's regression on the damping) and
    at fractions of the candidate's half-power width either side (a damper mode's peak is
    wider, and its best frequency moves more than the fit's linearisation says).

    Offsets whose damping leaves ``[MIN_DAMPING, MAX_DAMPING]`` are not evaluated (their
    rise is nan). Returns, per offset: the rise, and the best frequency, damping and residue.
    """  # noqa: D205
    block = _zeta_block(joint, i, x, u, ridge, band)
    return _zeta_rises(joint, i, x, u, ridge, block, _scan_blocks(joint, i, x, [block])[0])


def _damping_span(joint: JointProblem, i: int, x: NDArray[np.float64],
                  ridge: tuple[float, float, float], band: tuple[float, float],
                  p: ModeProfile, rise: NDArray[np.float64] | None = None) -> ModeProfile:
    """A strong mode's profile in its damping, where its linearised std may not stand.

    A lightly damped mode's peak is narrow: the cost is steep near the fit and then flat, so
    a damping ten times the fit's can be as plausible (a noise peak fitted sharper than the
    mode). The damping's cost is checked at 1 and 3 linearised std either side, the
    frequency minimised out, as the frequency's is (:func:`_quadratic`); where one side lies
    beyond the damping's bounds, the other side's rise at 3 std must reach
    :data:`QUADRATIC_SHORTFALL` of 9 times its rise at 1 std. Where the check fails (or the
    cost does not rise at 1 std), the damping is profiled outwards in steps of sqrt(2) up to
    its bounds, and ``p``'s spans are widened to where the rise crosses 9 times the rise at
    1 std (at least :data:`PROFILE_LEVEL`). ``rise``: the check's rises at -3, -1, +1 and +3
    std, if already scanned.
    """
    _, zeta, _ = joint.unpack(x)
    if rise is None:
        rise = _zeta_profile(joint, i, x, _CHECK, ridge, band)[0]
    ones = [float(r) for r in rise[1:3] if math.isfinite(r)]
    c = max(ones) if ones else 0.0
    if np.all(np.isfinite(rise)):
        quadratic = c > 0 and _quadratic(rise)  # both sides: a minimum beside the fit allowed
    else:  # one side below the damping's bound: that side's ratio alone
        outer = [(float(r3), float(r1)) for r3, r1 in ((rise[0], rise[1]), (rise[3], rise[2]))
                 if math.isfinite(r3) and math.isfinite(r1)]
        quadratic = c > 0 and all(r3 >= QUADRATIC_SHORTFALL * 9.0 * r1 for r3, r1 in outer)
    if quadratic:
        return p
    level = max(9.0 * c, PROFILE_LEVEL)
    side = 3.0 * math.sqrt(2.0) ** np.arange(24)
    u = np.concatenate([-side[::-1], [0.0], side])
    rise, w, z, k = _zeta_profile(joint, i, x, u, ridge, band)
    rise[side.size] = 0.0
    ok = np.isfinite(rise) & (rise < level)
    # the span's ends where the rise crosses the level between two offsets (linearly)
    first, last = int(np.argmax(ok)), int(ok.size - 1 - np.argmax(ok[::-1]))
    z_ends = [float(z[first]), float(z[last])]
    for end, out in ((first, first - 1), (last, last + 1)):
        if 0 <= out < ok.size and math.isfinite(rise[out]):
            a = (rise[out] - level) / (rise[out] - rise[end])
            z_ends.append(float(z[out] + a * (z[end] - z[out])))
    return ModeProfile(
        evidence=p.evidence, better=p.better, local=p.local, residue_spans=p.residue_spans,
        omega_span=(min(float(w[ok].min()), p.omega_span[0]),
                    max(float(w[ok].max()), p.omega_span[1])),
        zeta_span=(min(*z_ends, p.zeta_span[0], float(zeta[i])),
                   max(*z_ends, p.zeta_span[1], float(zeta[i]))),
        k_span=_k_span(p, k[ok]))


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
        3 std by its curvature at the fit (9 for a quadratic cost in noise units; 9 too where
        the cost rises by less than :data:`FLAT_CURVATURE` at 1 linearised std), and the
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
        # the frequency's and the damping's checks: one scan
        b_w = _omega_block(joint, i, x, _CHECK, ridge, band_list[i], spread=2)
        b_z = _zeta_block(joint, i, x, _CHECK, ridge, band_list[i])
        s_w_scan, s_z_scan = _scan_blocks(joint, i, x, [b_w, b_z])
        rise = _omega_rises(b_w, s_w_scan, 2)[0]
        rise_z = _zeta_rises(joint, i, x, _CHECK, ridge, b_z, s_z_scan)[0]
        curvature = 0.5 * float(rise[1] + rise[2])
        flat = curvature < FLAT_CURVATURE
        if _quadratic(rise) and not flat:
            out[i] = _damping_span(joint, i, x, ridge, band_list[i], p, rise_z)
            continue
        # The level of 3 std by the cost's own curvature at the fit: the linearised
        # (sandwich) std stands for a quadratic cost, and is scaled by how much farther
        # than 3 std the cost's rise reaches that level; a cost flatter than that std says
        # is taken at its own 3 std (a rise of 9).
        level = 9.0 if flat else 9.0 * curvature
        reach = 12.0
        for _ in range(4):  # widen the scan while the plausible region reaches its ends
            u = np.linspace(-reach, reach, 25)
            rise, w, z, k = _omega_profile(joint, i, x, u, ridge, band_list[i])
            ok = rise < level
            if not (ok[0] or ok[-1]) or reach * s_w > 1.0:
                break
            reach *= 2.0
        # (a strong mode whose band was scanned keeps that profile's span too)
        out[i] = _damping_span(joint, i, x, ridge, band_list[i], ModeProfile(
            evidence=p.evidence, better=None,
            omega_span=(float(min(w[ok].min(), omega[i], p.omega_span[0])),
                        float(max(w[ok].max(), omega[i], p.omega_span[1]))),
            zeta_span=(float(min(z[ok].min(), zeta[i], p.zeta_span[0])),
                       float(max(z[ok].max(), zeta[i], p.zeta_span[1]))),
            k_span=_k_span(p, k[ok]), local=True, residue_spans=p.residue_spans), rise_z)
    return out
