"""Variable projection over one or several windows of one plant, and its covariance.

The windows share omega_i, zeta_i, the amplifier lag (the nonlinear parameters, in ``x``)
and k0, k_i (linear); each keeps its own nuisance columns (free responses, offset, lag state),
which are projected out window by window before the shared coefficients are solved. Each
window's rows are scaled by its weight (the inverse rms of its averaged, prewhitened noise),
so the cost is in units of the noise: about the number of rows for an adequate model. One
window is the single-window fit; several the pooled (joint) fit.

Uncertainty (:func:`covariance`): the sandwich covariance ``A^-1 B A^-1`` of the shared
parameters, each window's nuisance partialled out, with ``A = J^T J`` from the Jacobian J of
the weighted (prewhitened) residual and ``B = J^T S J``, S the covariance of the averaged
residual estimated from the per-move residuals (their scatter over the moves divided by M).
It holds for coloured noise and closed-loop input noise; without per-move records (M <= 2)
it falls back to the white-noise formula ``sigma^2 A^-1``.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, TypeAlias

import numpy as np
from scipy.linalg import qr, solve_triangular

from galvo_sysid.errors import IdentificationError
from galvo_sysid.ident.refine.options import DEFAULT_WHITEN_ORDER
from galvo_sysid.ident.refine.whitener import (
    BOUND_ORDER_DIVISOR,
    NoiseModel,
    noise_whitener,
    stationary_noise_model,
)

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from numpy.typing import NDArray

    from galvo_sysid.ident.refine.window import WindowProblem

    Floats: TypeAlias = Sequence[float] | NDArray[np.float64]

__all__ = ['MAP_SCAN_SIZE', 'REUSE_LEVEL', 'JointProblem', 'MapWindows', 'Scan', 'covariance']

Scan: TypeAlias = 'tuple[NDArray[np.float64], NDArray[np.float64]]'
"""One window's scan: the cost reductions at the candidates and their residues."""

MapWindows: TypeAlias = (
    'Callable[[Callable[[WindowProblem], Scan], Sequence[WindowProblem]], list[Scan]]')
"""How the windows' scans are shared out (:attr:`JointProblem.map_windows`): as ``map``, but
returning a list."""

MAP_SCAN_SIZE = 200
"""The fewest window x candidate pairs of a scan given to :attr:`JointProblem.map_windows`.
A fork and the return of its results took 3-5 ms here (from a process of 320 MB), about what
a scan of this many pairs takes (the paper bag's joint fit: 38 windows x 41 candidates in
about 0.1 s); a smaller scan is made here."""

REUSE_LEVEL = 1.1
"""A noise model of other moves (:meth:`JointProblem.prewhiten` with ``check``) is reused
while the ratio of these moves' noise to its own lies within a factor of this of 1 (the std
then within 5 % of a fresh model's, whose own error over 100 moves is about 1 %); beyond, a
model is estimated anew."""


class JointProblem:
    """Variable projection over windows of one plant (see the module docs).

    Args:
        problems: The windows.
        weights: One weight per window (its rows are multiplied by it).
        fixed_lag: The amplifier lag [s] if it is not estimated (None: ``x`` holds it).

    Attributes:
        map_windows: How the windows' scans (:meth:`scan`, :meth:`scan_residues`) of at
            least :data:`MAP_SCAN_SIZE` window x candidate pairs are shared out, as ``map``
            but returning a list (e.g. :func:`galvo_sysid.field.jobs.fork_map`); None: in
            turn, here. The sums are made here in window order either way: the same numbers.
    """

    def __init__(self, problems: Sequence[WindowProblem], weights: Floats, *,
                 fixed_lag: float | None) -> None:
        self.problems = list(problems)
        self.t = self.problems[0].t
        self.n_modes = self.problems[0].n_modes
        self.fixed_lag = fixed_lag
        self.n_eval = 0
        self.whiten_order = DEFAULT_WHITEN_ORDER
        self.stationary = False  # set by prewhiten (see there)
        self.noise_models: tuple[NoiseModel | None, ...] = ()  # set by prewhiten
        # how the windows' scans may be shared out (e.g. field.jobs.fork_map); None: in turn
        self.map_windows: MapWindows | None = None
        self.set_weights(weights)

    def prewhiten(self, x: NDArray[np.float64], order: int,
                  models: Sequence[NoiseModel | None] = (), *, check: bool = False) -> None:
        """Whiten each window by its noise model at x, and weigh it by its noise.

        ``models``: per window, a noise model already estimated from the same moves (e.g. by
        the window's own fit, at its own estimate: :attr:`RefinedFit.noise_models`), used as
        it is instead of estimating one at x; None (or a model of other moves or rows, or of
        other lags than this fit's): estimated here. With ``check``, the models are of other
        moves of the same kind (the previous window of the same angle): each is checked
        against this window's deviations (:meth:`NoiseModel.level_ratio`) and used with its
        level rescaled to them if that ratio is within :data:`REUSE_LEVEL` of 1, else
        estimated anew.

        The noise model is the stationary noise of the moves' deviations from the window's
        mean at x, each move's own nuisance (the ringing, lag state and offset it starts
        with) taken out by expectation-maximisation
        (:func:`~galvo_sysid.ident.refine.whitener.stationary_noise_model`: first pass with
        ``order`` lags, second with ``order`` or a third of the rows if more): the
        maximum-likelihood weighting of the window's average, whose own nuisance columns
        absorb that ringing. (The deviations whole would count the ringing as noise: on a
        short record where a mode rings through, it fills the valley the mode's antiresonance
        cuts into the noise spectrum, and the fit weighs down the rows that carry the mode:
        omega_1 of ``random_scanner(1)`` came out with 6 times the bound's rms error, now
        1.3.) The window is whitened by one map of that model: its prediction-error map with
        as many lags as the second pass
        (:meth:`~galvo_sysid.ident.refine.whitener.WhitenerChain.single`; the two passes composed
        have both passes' lags, a head of rows half again as long for the same estimates:
        ``benchmarks/efficiency.py`` gave the same errors and bounds to a few percent, each
        window's fit 8 % faster). Where that model cannot be made, the deviations' two-pass
        model whole
        (:func:`~galvo_sysid.ident.refine.whitener.noise_whitener`); a window without noise
        is left unwhitened. Sets :attr:`stationary` when every window has the first kind:
        the fit's ``A`` is then the Fisher information (see :func:`covariance`).
        """
        omega, zeta, lag = self.unpack(x)
        self.whiten_order = order
        n = self.n_modes
        weights = []
        stationary = True
        given = list(models) + [None] * (len(self.problems) - len(models))
        used: list[NoiseModel | None] = []
        for prob, coef, model in zip(self.problems, self.coefficients(x), given, strict=True):
            lags = max(order, prob.k.size // BOUND_ORDER_DIVISOR)
            dev = nuis = None
            if model is not None and (model.moves, model.rows, len(model.autocovariance)) \
                    == (prob.moves, prob.k.size, lags + 1):
                whitener = model.whitener()
                if check:
                    dev = prob.deviations(omega, zeta, lag, coef)
                    nuis = prob.columns(omega, zeta, lag, whitened=False)[:, 1 + n:]
                    ratio = model.level_ratio(whitener, dev, nuis)
                    model = (replace(model, variance=model.variance * ratio)
                             if 1.0 / REUSE_LEVEL <= ratio <= REUSE_LEVEL else None)
                if model is not None:
                    prob.set_whitening(whitener)
                    weights.append(model.weight())
                    used.append(model)
                    continue
            if dev is None or nuis is None:
                dev = prob.deviations(omega, zeta, lag, coef)
                nuis = prob.columns(omega, zeta, lag, whitened=False)[:, 1 + n:]
            found = stationary_noise_model(dev, nuis, lags, first_order=order)
            if found is not None:
                chain, var = found
                model = NoiseModel(tuple(float(v) for v in chain.autocovariance(lags)), var,
                                   prob.moves, prob.k.size)
                prob.set_whitening(model.whitener())
                weights.append(model.weight())
                used.append(model)
                continue
            used.append(None)
            stationary = False
            prob.set_whitening(noise_whitener(dev, order,
                                              float(np.sqrt(np.mean(prob.yf_raw**2)))))
            wdev = prob.apply_whitening(dev, axis=1)
            weights.append(1.0 / max(float(np.sqrt(np.mean(wdev**2) / (prob.moves - 1))),
                                     1e-300))
        self.set_weights(weights)
        self.stationary = stationary
        self.noise_models = tuple(used)

    def set_weights(self, weights: Floats) -> None:
        """Use new window weights (e.g. after prewhitening); forgets the cached solution."""
        self.weights = np.asarray(weights, dtype=float)
        self.y_scale = float(np.sqrt(sum(w * w * float(p.yf @ p.yf) for p, w in
                                         zip(self.problems, self.weights, strict=True)))) or 1.0
        self._key: bytes | None = None
        self._cache: tuple[NDArray[np.float64], NDArray[np.float64]] = (np.zeros(0),
                                                                          np.zeros(0))
        # per window (phi, Q, R, column scale) of the nuisance QR, and Q of the shared columns
        self._parts: tuple[list[tuple[NDArray[np.float64], ...]], NDArray[np.float64]] = (
            [], np.zeros((0, 0)))

    def scan(self, i: int, omega: NDArray[np.float64], zeta: NDArray[np.float64], lag: float,
             w_c: NDArray[np.float64], z_c: NDArray[np.float64]) -> tuple[
                 NDArray[np.float64], NDArray[np.float64]]:
        """Joint cost reduction of mode i at candidates (w_c, z_c), the other modes fixed, and
        the candidates' residues (the windows' weighted mean).

        The windows' :meth:`WindowProblem.scan` summed with their weights; windows whose
        records have one length share the candidates' transforms (made once, not once per
        window: the same numbers).
        """  # noqa: D205
        gain, k = self._scan(i, omega, zeta, lag, w_c, z_c, others=False)
        return gain, k[1 + i]

    def scan_residues(self, i: int, omega: NDArray[np.float64], zeta: NDArray[np.float64],
                      lag: float, w_c: NDArray[np.float64],
                      z_c: NDArray[np.float64]) -> tuple[NDArray[np.float64],
                                                         NDArray[np.float64]]:
        """:meth:`scan` with all shared residues [k0, k_1 .. k_n] at each candidate, (1 + n, m).

        The other modes' residues and k0 are solved anew with each candidate in place of
        mode i (:meth:`WindowProblem.scan_residues`; the windows' weighted mean).
        """
        return self._scan(i, omega, zeta, lag, w_c, z_c, others=True)

    def _scan(self, i: int, omega: NDArray[np.float64], zeta: NDArray[np.float64], lag: float,
              w_c: NDArray[np.float64], z_c: NDArray[np.float64], *,
              others: bool) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        gain = np.zeros(w_c.size)
        k_sum = np.zeros((1 + self.n_modes, w_c.size))
        total = 0.0
        shared = {}
        for prob in self.problems:
            if prob.n not in shared:
                shared[prob.n] = prob.candidate_transforms(lag, w_c, z_c)

        def one(prob: WindowProblem) -> Scan:
            return prob.scan_residues(i, omega, zeta, lag, w_c, z_c, shared=shared[prob.n],
                                      others=others)

        mapper = self.map_windows
        if mapper is not None and len(self.problems) * w_c.size >= MAP_SCAN_SIZE:
            parts = mapper(one, self.problems)
        else:
            parts = [one(prob) for prob in self.problems]
        for (g, k), wt in zip(parts, self.weights, strict=True):
            gain += wt * wt * g
            k_sum += wt * wt * k
            total += wt * wt
        return gain, k_sum / total

    # -- parameters ----------------------------------------------------------------------
    @property
    def estimate_lag(self) -> bool:
        """Whether the lag is a parameter of ``x``."""
        return self.fixed_lag is None

    def unpack(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64],
                                                      NDArray[np.float64], float]:
        """(omega, zeta, lag) from x = [ln omega_i, ln zeta_i, (T_l / T)]."""
        n = self.n_modes
        lag = self.fixed_lag if self.fixed_lag is not None else float(x[2 * n]) * self.t
        return np.exp(x[:n]), np.exp(x[n: 2 * n]), lag

    def pack(self, omega: Floats, zeta: Floats, lag: float) -> NDArray[np.float64]:
        """The parameter vector of (omega, zeta, lag)."""
        parts = [np.log(np.asarray(omega, dtype=float)), np.log(np.asarray(zeta, dtype=float))]
        if self.fixed_lag is None:
            parts.append(np.array([lag / self.t]))
        return np.concatenate(parts)

    # -- solve -----------------------------------------------------------------------------
    def solve(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(shared coefficients [k0, k_i], stacked weighted residual)."""
        key = x.tobytes()
        if key == self._key:
            return self._cache
        self.n_eval += 1
        n = self.n_modes
        omega, zeta, lag = self.unpack(x)
        if len(self.problems) == 1:  # one window: one factorisation of all its columns
            prob, wt = self.problems[0], float(self.weights[0])
            phi = prob.columns(omega, zeta, lag)
            scale = np.linalg.norm(phi, axis=0)
            scale[scale == 0] = 1.0
            q, r = qr(phi / scale, mode='economic', check_finite=False)
            qty = q.T @ prob.yf
            coef = solve_triangular(r, qty, check_finite=False) / scale
            self._key = key
            self._cache = (coef[: 1 + n], wt * (prob.yf - q @ qty))
            self._parts = ([(q, coef)], np.zeros((0, 0)))
            return self._cache
        f_parts, y_parts = [], []
        parts: list[tuple[NDArray[np.float64], ...]] = []
        for prob, wt in zip(self.problems, self.weights, strict=True):
            phi = prob.columns(omega, zeta, lag)
            nuis = phi[:, 1 + n:]
            scale = np.linalg.norm(nuis, axis=0)
            scale[scale == 0] = 1.0
            q, r = qr(nuis / scale, mode='economic', check_finite=False)
            f_parts.append(wt * (phi[:, : 1 + n] - q @ (q.T @ phi[:, : 1 + n])))
            y_parts.append(wt * (prob.yf - q @ (q.T @ prob.yf)))
            parts.append((phi, q, r, scale))
        f_all = np.vstack(f_parts)
        y_all = np.concatenate(y_parts)
        scale = np.linalg.norm(f_all, axis=0)
        scale[scale == 0] = 1.0
        q_f, r_f = qr(f_all / scale, mode='economic', check_finite=False)
        shared = solve_triangular(r_f, q_f.T @ y_all, check_finite=False) / scale
        self._key = key
        self._cache = (shared, y_all - f_all @ shared)
        self._parts = (parts, q_f)
        return self._cache

    def residual(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Weighted residual, scaled by the data's norm (what the optimiser minimises)."""
        return self.solve(x)[1] / self.y_scale

    def cost(self, x: NDArray[np.float64]) -> float:
        """Sum of squared weighted residuals (in noise units once weighted by the noise)."""
        r = self.solve(x)[1]
        return float(r @ r)

    def jacobian(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Kaufman's variable-projection Jacobian of :meth:`residual`.

        ``-P (d Phi / d x_j) c`` with P the projection onto the orthogonal complement of all
        linear columns (each window's nuisance, then the shared columns left after it), c the
        coefficients at x; the Golub-Pereyra term that Kaufman drops is second order at the
        optimum.
        """
        shared = self.solve(x)[0]
        parts, q_f = self._parts
        n = self.n_modes
        omega, zeta, lag = self.unpack(x)
        if len(self.problems) == 1:  # P: the complement of all the window's columns
            prob, wt = self.problems[0], float(self.weights[0])
            q, coef = parts[0]
            v = prob.model_derivatives(omega, zeta, lag, coef, lag_free=self.estimate_lag)
            return np.asarray(-wt * (v - q @ (q.T @ v)) / self.y_scale, dtype=np.float64)
        v_parts = []
        for prob, wt, (phi, q, r, scale) in zip(self.problems, self.weights, parts,
                                                 strict=True):
            nuis = solve_triangular(r, q.T @ (prob.yf - phi[:, : 1 + n] @ shared),
                                    check_finite=False) / scale
            coef = np.concatenate([shared, nuis])
            v = prob.model_derivatives(omega, zeta, lag, coef, lag_free=self.estimate_lag)
            v_parts.append(wt * (v - q @ (q.T @ v)))
        v_all = np.vstack(v_parts)
        v_all -= q_f @ (q_f.T @ v_all)
        return np.asarray(-v_all / self.y_scale, dtype=np.float64)

    def coefficients(self, x: NDArray[np.float64]) -> list[NDArray[np.float64]]:
        """Each window's full coefficient vector [shared, its nuisance] at x."""
        n = self.n_modes
        omega, zeta, lag = self.unpack(x)
        shared = self.solve(x)[0]
        if len(self.problems) == 1:
            return [self._parts[0][0][1].copy()]
        out = []
        for prob in self.problems:
            phi = prob.columns(omega, zeta, lag)
            nuis = np.linalg.lstsq(phi[:, 1 + n:], prob.yf - phi[:, : 1 + n] @ shared,
                                   rcond=None)[0]
            out.append(np.concatenate([shared, nuis]))
        return out


def covariance(joint: JointProblem, x: NDArray[np.float64],
               coefs: Sequence[NDArray[np.float64]], *, bound: bool = True) -> tuple[
                   NDArray[np.float64], str, NDArray[np.float64] | None]:
    """Covariance of [k0, k_i, omega_i, zeta_i, (lag)] and how it was made (see module docs).

    Also the Cramer-Rao bound of the same parameters: the inverse of the Fisher matrix
    ``sum_w J_w^T Sigma_w^-1 J_w`` of the window averages, every nuisance parameter (free
    responses, offset, lag state) partialled out (the Schur complement), with Sigma_w the
    window's stationary noise covariance as
    :func:`~galvo_sysid.ident.refine.whitener.stationary_noise_model` estimates it from the
    moves' deviations, their own nuisance taken out. When the fit was prewhitened with that
    model (:meth:`JointProblem.prewhiten`; :attr:`JointProblem.stationary`), its ``A`` is
    that Fisher matrix and the bound is ``A^-1``; otherwise (a window whose model could not
    be made, fixed noise filters) the model is estimated here. A whitener from the
    deviations whole would count each move's ringing as noise (``A^-1`` of omega_1 ten times
    the bound on ``random_scanner(1)``). The sandwich is this estimator's own covariance; it
    lies above the bound where the fit's noise model is not the noise's.

    Returns:
        ``(covariance, 'sandwich' | 'white', Cramer-Rao bound)``; the bound is None when
        ``bound`` is false (its noise model not estimated).

    Raises:
        IdentificationError: The Jacobian is singular.
    """
    n = joint.n_modes
    omega, zeta, lag = joint.unpack(x)
    phys = np.concatenate([omega, zeta, [joint.t]])   # d x_j -> d physical parameter
    a_mat: NDArray[np.float64] | None = None
    b_mat: NDArray[np.float64] | None = None
    white = any(prob.moves <= 2 for prob in joint.problems)
    res2 = 0.0
    rows = 0
    info: list[NDArray[np.float64]] = []
    for prob, wt, coef in zip(joint.problems, joint.weights, coefs, strict=True):
        jac, nuis = _jacobian(prob, omega, zeta, lag, coef, phys, joint.estimate_lag, True)
        jt = wt * _partialled(jac, nuis)
        a_w = jt.T @ jt
        a_mat = a_w if a_mat is None else a_mat + a_w
        if white:
            resid = wt * (prob.yf - prob.columns(omega, zeta, lag) @ coef)
            res2 += float(resid @ resid)
            rows += resid.size
            continue
        fisher = bound and not joint.stationary
        raw = prob.deviations(omega, zeta, lag, coef) if fisher else None
        # the whitened deviations' products with jt: the deviations times W^T jt (no
        # whitening of every move; nor, where no one made them, the deviations themselves)
        g = wt * prob.deviations_times(omega, zeta, lag, coef, prob.whitening_transposed(jt))
        m = g.shape[0]
        b_w = g.T @ g / (m * (m - 1))
        b_mat = b_w if b_mat is None else b_mat + b_w
        if raw is not None:
            info.append(_fisher(prob, raw, omega, zeta, lag, coef, phys, joint, a_w))
    assert a_mat is not None
    a_inv = _inverse(a_mat)
    if white:
        dof = max(rows - a_mat.shape[0] - sum(p.n_linear - 1 - n for p in joint.problems), 1)
        cov = np.asarray(a_inv * res2 / dof, dtype=np.float64)
        return cov, 'white', cov.copy() if bound else None
    assert b_mat is not None
    if not bound:
        crlb = None
    elif joint.stationary:  # the fit's weighting is the stationary noise's: A is the Fisher
        crlb = a_inv.copy()
    else:
        crlb = _inverse(np.sum(info, axis=0))
    return np.asarray(a_inv @ b_mat @ a_inv, dtype=np.float64), 'sandwich', crlb


def _inverse(a_mat: NDArray[np.float64]) -> NDArray[np.float64]:
    """Inverse of an information matrix, equilibrated (its parameters' scales differ)."""
    d = np.sqrt(np.diag(a_mat))
    d[d == 0] = 1.0
    try:
        return np.asarray(np.linalg.inv(a_mat / np.outer(d, d)) / np.outer(d, d),
                          dtype=np.float64)
    except np.linalg.LinAlgError as exc:
        raise IdentificationError(f'singular Jacobian at the optimum: {exc}') from exc


def _jacobian(prob: WindowProblem, omega: NDArray[np.float64], zeta: NDArray[np.float64],
              lag: float, coef: NDArray[np.float64], phys: NDArray[np.float64],
              lag_free: bool, whitened: bool) -> tuple[NDArray[np.float64],
                                                       NDArray[np.float64]]:
    """(d model / d [k0, k_i, omega_i, zeta_i, (lag)], nuisance columns) of a window."""
    n = prob.n_modes
    phi = prob.columns(omega, zeta, lag, whitened=whitened)
    v = prob.model_derivatives(omega, zeta, lag, coef, lag_free=lag_free, whitened=whitened)
    jac = np.empty((phi.shape[0], 1 + n + v.shape[1]))
    jac[:, : 1 + n] = phi[:, : 1 + n]
    jac[:, 1 + n:] = v / phys[: v.shape[1]]
    return jac, phi[:, 1 + n:]


def _partialled(jac: NDArray[np.float64], nuis: NDArray[np.float64]) -> NDArray[np.float64]:
    """``jac`` less its projection onto the nuisance columns."""
    scale = np.linalg.norm(nuis, axis=0)
    scale[scale == 0] = 1.0
    q, _ = qr(nuis / scale, mode='economic', check_finite=False)
    return np.asarray(jac - q @ (q.T @ jac), dtype=np.float64)


def _fisher(prob: WindowProblem, dev: NDArray[np.float64], omega: NDArray[np.float64],
            zeta: NDArray[np.float64], lag: float, coef: NDArray[np.float64],
            phys: NDArray[np.float64], joint: JointProblem,
            fallback: NDArray[np.float64]) -> NDArray[np.float64]:
    """A window's Fisher information of the shared parameters, its nuisance partialled out.

    ``J^T Sigma^-1 J`` (J of the unwhitened average, Sigma its noise covariance) less the
    nuisance's share (the Schur complement), with the stationary noise model that
    :func:`~galvo_sysid.ident.refine.whitener.stationary_noise_model` estimates from the
    moves' deviations ``dev`` (unwhitened) under their own nuisance: its first pass with the
    fit's lags, its second with those or a third of the rows if more (a long record resolves
    the noise's sharp resonance peaks, where the modes' information is, only with that many:
    with 128 the bound of ``random_scanner(0)``'s omega_1 is 0.65 of the exact one, with 554
    0.81). ``fallback`` (the fit's ``J^T J``) when the deviations do not
    scatter.
    """
    jac, nuis = _jacobian(prob, omega, zeta, lag, coef, phys, joint.estimate_lag, False)
    found = stationary_noise_model(
        dev, nuis, max(joint.whiten_order, dev.shape[1] // BOUND_ORDER_DIVISOR),
        first_order=joint.whiten_order)
    if found is None:
        return fallback
    wh, var = found
    jt = _partialled(wh.apply(jac), wh.apply(nuis))
    return np.asarray(jt.T @ jt * ((dev.shape[0] - 1) / var), dtype=np.float64)
