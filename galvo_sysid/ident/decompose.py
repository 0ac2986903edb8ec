"""From a discrete ARX model to the modal model of paper Eq. 1 (paper Sec. V-C).

The paper converts the identified ARX model to continuous time by the zero-order hold (ZOH)
and decomposes it into modes. Converting the whole 15th-order model at once (a matrix
logarithm of its state-space realisation) is fragile: an ARX model that also describes the
noise has spurious poles, and a negative-real pole has no real logarithm. So the default route
separates the modes first, in the z domain, and converts each selected block exactly:

1. Partial fractions: the transfer function H(z) = B(z)/A(z) is split into 2nd-order blocks
   ``(c1 z + c0) / ((z - p1)(z - p2))``; a block's numerator is the linear interpolant of
   ``g(z) = H(z) (z - p1)(z - p2)`` through the two poles, which stays accurate when the poles
   nearly coincide (the rigid body's double pole at z = 1).
2. Rigid body: the two poles nearest z = 1 (two real poles or one complex pair). The ZOH of
   ``k0 / s^2`` is ``k0 T^2 (z + 1) / (2 (z - 1)^2)``; k0 is the least-squares fit of the block
   numerator (c1, c0) to ``k0 T^2 / 2 (1, 1)``, i.e. ``k0 = (c1 + c0) / T^2``.
3. Resonant modes: in each frequency band, among the lightly damped pole pairs (complex,
   inside the unit circle, damping ratio <= ``max_damping``), the one with the largest modal
   contribution is taken as the physical mode; the others are spurious. The contribution is
   by default the mode's resonance peak ``|k| / (2 zeta omega^2)`` (``selection='peak'``);
   ``'h2'`` uses its H2 norm ``|k| / (2 omega^1.5 zeta^0.5)`` and ``'residue'`` its impulse
   response amplitude ``|k| / omega`` (which picks a heavily damped noise pole pair over a
   weakly excited third mode more often). Its continuous poles are ``s = log(p) / T``, so
   ``omega = |s|``, ``zeta = -Re(s) / |s|``, and k is the least-squares fit of the block
   numerator to the ZOH numerator ``(beta1, beta0)`` of the unit mode
   ``1 / (s^2 + 2 zeta omega s + omega^2)`` (exact when the block is a ZOH mode; any
   first-order numerator term in s, which Eq. 1 does not have, is projected away).

The whole-model route (:func:`arx_to_continuous`, :func:`continuous_modal_decomposition`) is
kept for the Bode plots of the paper's Fig. 10/11 and for comparison.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import scipy.linalg

from galvo_sysid.errors import ConfigurationError, IdentificationError
from galvo_sysid.filters import lfilter
from galvo_sysid.ident.arx import ArxModel
from galvo_sysid.model import REFERENCE_MODEL, InputDynamics, ModalModel
from galvo_sysid.model.modal import Band, default_bands

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import ArrayLike, NDArray

__all__ = [
    'DEFAULT_MAX_DAMPING',
    'ContinuousModel',
    'ModalDecomposition',
    'arx_to_continuous',
    'arx_to_modal',
    'bode_data',
    'continuous_modal_decomposition',
    'modal_decomposition',
    'simulate_zoh',
    'zoh_blocks',
    'zoh_mode_numerator',
]

DEFAULT_MAX_DAMPING = 0.3
"""Largest damping ratio a pole pair may have to count as a resonant mode."""

def zoh_mode_numerator(omega: float, zeta: float, sample_period: float) -> tuple[float, float]:
    """Return (beta1, beta0): ZOH of 1/(s^2 + 2 zeta omega s + omega^2) is (beta1 z + beta0)/den.

    From the step response h(t) of the mode (0 < zeta < 1): the pulse response of the ZOH
    model is g[k] = h(kT) - h((k-1)T), so beta1 = h(T) and beta0 = h(2T) + (a1 - 1) h(T) with
    a1 = -2 exp(-zeta omega T) cos(omega_d T) the denominator's z^1 coefficient.
    """
    if not (omega > 0 and 0 < zeta < 1):
        raise ConfigurationError(f'need omega > 0 and 0 < zeta < 1, got {omega}, {zeta}')
    sigma = zeta * omega
    wd = omega * np.sqrt(1.0 - zeta * zeta)

    def h(t: float) -> float:
        return float((1.0 - np.exp(-sigma * t) * (np.cos(wd * t) + sigma / wd * np.sin(wd * t)))
                     / omega**2)

    t = sample_period
    a1 = -2.0 * np.exp(-sigma * t) * np.cos(wd * t)
    h1 = h(t)
    return h1, float(h(2 * t) + (a1 - 1.0) * h1)


def zoh_blocks(model: ModalModel, sample_period: float) -> list[tuple[NDArray[np.float64],
                                                                      NDArray[np.float64]]]:
    """The ZOH discretisation of a modal model as parallel 2nd-order blocks ``(b, a)``.

    Rigid body ``k0 T^2 / 2 (z^-1 + z^-2) / (1 - z^-1)^2``, then each mode
    ``k (beta1 z^-1 + beta0 z^-2) / (1 + a1 z^-1 + a0 z^-2)`` (powers of z^-1, lfilter
    convention). The sum of the blocks is the exact ZOH model of Eq. 1.
    """
    t = sample_period
    blocks = [(np.array([0.0, 0.5, 0.5]) * model.k0 * t * t, np.array([1.0, -2.0, 1.0]))]
    for k, w, z in zip(model.residues, model.natural_frequencies, model.damping_ratios,
                       strict=True):
        beta1, beta0 = zoh_mode_numerator(w, z, t)
        r = np.exp(-z * w * t)
        a1 = -2.0 * r * np.cos(w * np.sqrt(1.0 - z * z) * t)
        blocks.append((k * np.array([0.0, beta1, beta0]), np.array([1.0, a1, r * r])))
    return blocks


def simulate_zoh(model: ModalModel, u: ArrayLike, *, sample_period: float) -> NDArray[np.float64]:
    """Response of the ZOH-discretised modal model to ``u`` from rest, along the last axis."""
    u_arr = np.asarray(u, dtype=float)
    y = np.zeros_like(u_arr)
    for b, a in zoh_blocks(model, sample_period):
        y += lfilter(b, a, u_arr)
    return y


def _block_numerator(num: NDArray[np.float64], lead: float, poles: NDArray[np.complex128],
                     block: tuple[int, int]) -> tuple[float, float]:
    """Numerator (c1, c0) of the partial-fraction block of H = num / (lead prod(z - poles))."""
    i, j = block
    rest = np.delete(poles, [i, j])

    def g(z: complex) -> complex:
        return complex(np.polyval(num, z) / (lead * np.prod(z - rest)))

    p1, p2 = complex(poles[i]), complex(poles[j])
    g1, g2 = g(p1), g(p2)
    if p1 == p2:
        raise IdentificationError('exactly repeated poles; cannot split the block')
    c1 = (g1 - g2) / (p1 - p2)
    c0 = g1 - c1 * p1
    return float(c1.real), float(c0.real)


@dataclass(frozen=True)
class ModalDecomposition:
    """Outcome of :func:`modal_decomposition`.

    Attributes:
        model: The modal model (k0 and the selected modes).
        rigid_poles: The two z-plane poles taken as the rigid body.
        mode_poles: The selected pole (upper half plane) of each mode, in band order.
        spurious_poles: All other poles.
        contributions: Modal contribution of each selected mode (see ``selection``).
    """

    model: ModalModel
    rigid_poles: tuple[complex, complex]
    mode_poles: tuple[complex, ...]
    spurious_poles: tuple[complex, ...]
    contributions: tuple[float, ...]


def _rigid_block(poles: NDArray[np.complex128], center: complex,
                 tol: float) -> tuple[int, int]:
    """Indices of the conjugation-closed pole pair nearest ``center`` (1 in z, 0 in s).

    Poles with ``|imag| <= tol`` count as real; the pair is either the two nearest real poles
    or the nearest complex pair, whichever lies closer.
    """
    dist = np.abs(poles - center)
    order = np.argsort(dist)
    real_idx = [int(i) for i in order if abs(poles[i].imag) <= tol]
    upper = [int(i) for i in order if poles[i].imag > tol]
    candidates: list[tuple[float, tuple[int, int]]] = []
    if len(real_idx) >= 2:
        a, b = real_idx[0], real_idx[1]
        candidates.append((float(max(dist[a], dist[b])), (a, b)))
    if upper:
        a = upper[0]
        partner = int(np.argmin(np.abs(poles - np.conj(poles[a]))))
        if partner != a:
            candidates.append((float(dist[a]), (a, partner)))
    if not candidates:
        raise IdentificationError('no pole pair for the rigid-body mode')
    return min(candidates)[1]


def _contribution(k: float, omega: float, zeta: float, selection: str) -> float:
    if selection == 'peak':
        return abs(k) / (2.0 * zeta * omega**2)
    if selection == 'h2':
        return abs(k) / (2.0 * omega * float(np.sqrt(omega * zeta)))
    return abs(k) / omega


def modal_decomposition(arx: ArxModel, *, bands: Sequence[Band] | None = None,
                        max_damping: float = DEFAULT_MAX_DAMPING,
                        reference: ModalModel = REFERENCE_MODEL,
                        selection: str = 'peak') -> ModalDecomposition:
    """Decompose an ARX model into rigid body + one resonant mode per band (ZOH, exact).

    Args:
        arx: The identified model (of the mechanics, input delay already removed).
        bands: One (low, high) angular-frequency band [rad/s] per expected mode; default
            :func:`default_bands` of ``reference``.
        max_damping: Largest damping ratio accepted for a mode.
        reference: Model whose natural frequencies set the default bands.
        selection: How to rank the candidate pole pairs of a band: ``'peak'``, ``'h2'`` or
            ``'residue'`` (see the module docs).

    Returns:
        The decomposition.

    Raises:
        IdentificationError: No rigid-body pole pair near z = 1, or a band without a lightly
            damped pole pair.
    """
    t = arx.sample_period
    band_list = (default_bands(reference, sample_period=t) if bands is None
                 else tuple((float(lo), float(hi)) for lo, hi in bands))
    for lo, hi in band_list:
        if not 0 < lo < hi:
            raise ConfigurationError(f'band ({lo}, {hi}) must satisfy 0 < low < high')
    if not 0 < max_damping < 1:
        raise ConfigurationError(f'max_damping must be in (0, 1), got {max_damping}')
    if selection not in ('peak', 'h2', 'residue'):
        raise ConfigurationError(f"selection must be 'peak', 'h2' or 'residue', got {selection!r}")
    num, den = arx.transfer_function()
    lead = float(den[0])
    poles = np.roots(den).astype(np.complex128)
    if poles.size < 2 + 2 * len(band_list):
        raise IdentificationError(f'ARX model of order {poles.size} cannot hold a rigid body and '
                                  f'{len(band_list)} modes')
    ri, rj = _rigid_block(poles, 1.0, 1e-9)
    rigid_freq = max(abs(np.log(poles[ri])), abs(np.log(poles[rj]))) / t
    first_low = min((lo for lo, _ in band_list), default=np.pi / t)
    if rigid_freq > 0.5 * first_low:
        raise IdentificationError(f'no rigid-body pole pair near z = 1 (nearest poles at '
                                  f'{rigid_freq:.3g} rad/s)')
    c1, c0 = _block_numerator(num, lead, poles, (ri, rj))
    k0 = (c1 + c0) / t**2
    used = {ri, rj}
    residues: list[float] = []
    freqs: list[float] = []
    damps: list[float] = []
    selected: list[complex] = []
    contributions: list[float] = []
    for lo, hi in band_list:
        best: tuple[float, int, float, float, float] | None = None
        for i, p in enumerate(poles):
            if i in used or p.imag <= 1e-9 or abs(p) >= 1:
                continue
            s = np.log(p) / t
            w = float(abs(s))
            z = float(-s.real / w)
            if not (lo <= w <= hi and 0 < z <= max_damping):
                continue
            partner = int(np.argmin(np.abs(poles - np.conj(p))))
            d1, d0 = _block_numerator(num, lead, poles, (i, partner))
            beta1, beta0 = zoh_mode_numerator(w, z, t)
            k = (d1 * beta1 + d0 * beta0) / (beta1**2 + beta0**2)
            amp = _contribution(k, w, z, selection)
            if best is None or amp > best[0]:
                best = (amp, i, k, w, z)
        if best is None:
            raise IdentificationError(f'no lightly damped mode (zeta <= {max_damping}) in band '
                                      f'{lo:.4g} .. {hi:.4g} rad/s')
        amp, i, k, w, z = best
        partner = int(np.argmin(np.abs(poles - np.conj(poles[i]))))
        used.update((i, partner))
        residues.append(k)
        freqs.append(w)
        damps.append(z)
        selected.append(complex(poles[i]))
        contributions.append(amp)
    model = ModalModel(k0=float(k0), residues=tuple(residues), natural_frequencies=tuple(freqs),
                       damping_ratios=tuple(damps))
    spurious = tuple(complex(p) for i, p in enumerate(poles) if i not in used)
    return ModalDecomposition(model=model, rigid_poles=(complex(poles[ri]), complex(poles[rj])),
                              mode_poles=tuple(selected), spurious_poles=spurious,
                              contributions=tuple(contributions))


def arx_to_modal(arx: ArxModel, *, bands: Sequence[Band] | None = None,
                 max_damping: float = DEFAULT_MAX_DAMPING,
                 reference: ModalModel = REFERENCE_MODEL, selection: str = 'peak') -> ModalModel:
    """Return the modal model of :func:`modal_decomposition`."""
    return modal_decomposition(arx, bands=bands, max_damping=max_damping, reference=reference,
                               selection=selection).model


@dataclass(frozen=True)
class ContinuousModel:
    """Continuous state space dx/dt = a x + b u, y = c x + d u (possibly complex).

    Attributes:
        a: System matrix.
        b: Input vector.
        c: Output vector.
        d: Feed-through.
        imag_ratio: max |Im| / max |Re| of the matrix logarithm that produced ``a``, ``b``;
            not small when the discrete model has a pole on the negative real axis (no real
            continuous equivalent).
    """

    a: NDArray[np.complex128]
    b: NDArray[np.complex128]
    c: NDArray[np.float64]
    d: float
    imag_ratio: float

    @property
    def is_real(self) -> bool:
        """Whether the conversion gave a real continuous model (imag_ratio < 1e-8)."""
        return self.imag_ratio < 1e-8

    def poles(self) -> NDArray[np.complex128]:
        """Eigenvalues of ``a`` [rad/s]."""
        return np.asarray(np.linalg.eigvals(self.a), dtype=np.complex128)

    def frequency_response(self, omega: ArrayLike) -> NDArray[np.complex128]:
        """Return c (j w I - a)^-1 b + d at angular frequencies ``omega`` [rad/s]."""
        w = np.atleast_1d(np.asarray(omega, dtype=float))
        n = self.a.shape[0]
        out = np.empty(w.shape, dtype=np.complex128)
        eye = np.eye(n)
        for idx, wi in np.ndenumerate(w):
            out[idx] = self.c @ np.linalg.solve(1j * wi * eye - self.a, self.b) + self.d
        return out


def arx_to_continuous(arx: ArxModel) -> ContinuousModel:
    """Whole-model ZOH inverse by the matrix logarithm of a state-space realisation.

    ``logm([[Phi, Gamma], [0, 1]]) / T = [[A, B], [0, 0]]``. Fragile by nature: the result is
    complex when the ARX model has poles on the negative real axis (check
    :attr:`ContinuousModel.is_real`), and inaccurate for poles near z = 0.
    """
    num, den = arx.transfer_function()
    # Controllable canonical form of the strictly proper H(z) = num / den (den[0] == 1).
    n = den.size - 1
    m = np.zeros((n + 1, n + 1))
    m[0, :n] = -den[1:]
    m[1:n, : n - 1] = np.eye(n - 1)
    m[0, n] = 1.0
    m[n, n] = 1.0
    c_d = num[1:]
    log_m = np.asarray(scipy.linalg.logm(m), dtype=np.complex128) / arx.sample_period
    re = float(np.max(np.abs(log_m.real)))
    im = float(np.max(np.abs(log_m.imag)))
    return ContinuousModel(a=log_m[:n, :n], b=log_m[:n, n], c=np.asarray(c_d, dtype=float),
                           d=0.0, imag_ratio=im / re if re > 0 else float('inf'))


def continuous_modal_decomposition(model: ContinuousModel, *,
                                   bands: Sequence[Band] | None = None,
                                   max_damping: float = DEFAULT_MAX_DAMPING,
                                   reference: ModalModel = REFERENCE_MODEL) -> ModalModel:
    """Modal decomposition of a whole-model continuous conversion (for comparison).

    Eigen-decomposition residues r_i; rigid body: the two eigenvalues nearest s = 0,
    ``k0 = -(r1 l2 + r2 l1)``; a mode's pair (l, conj l) gives ``k = -2 Re(r conj(l))``, the
    s^0 coefficient of its block numerator. Selection as in :func:`modal_decomposition`.

    Raises:
        IdentificationError: The conversion is complex (spurious negative-real poles), or no
            rigid body / mode in a band.
    """
    if not model.is_real:
        raise IdentificationError(f'whole-model conversion is complex (imag ratio '
                                  f'{model.imag_ratio:.2g}): spurious negative-real poles')
    band_list = default_bands(reference) if bands is None else tuple(bands)
    lam, vec = np.linalg.eig(model.a)
    left = np.linalg.solve(vec, model.b)
    r = (model.c @ vec) * left
    tol = 1e-6 * float(np.max(np.abs(lam)))
    ri, rj = _rigid_block(lam, 0.0, tol)
    if max(abs(lam[ri]), abs(lam[rj])) > 0.5 * min(lo for lo, _ in band_list):
        raise IdentificationError('no rigid-body eigenvalue pair near s = 0')
    k0 = -(r[ri] * lam[rj] + r[rj] * lam[ri])
    used = {ri, rj}
    out: list[tuple[float, float, float]] = []
    for lo, hi in band_list:
        best: tuple[float, int, float, float, float] | None = None
        for i, l_i in enumerate(lam):
            if i in used or l_i.imag <= tol:
                continue
            w = float(abs(l_i))
            z = float(-l_i.real / w)
            if not (lo <= w <= hi and 0 < z <= max_damping):
                continue
            k = float(-2 * (r[i] * np.conj(l_i)).real)
            amp = _contribution(k, w, z, 'peak')
            if best is None or amp > best[0]:
                best = (amp, i, k, w, z)
        if best is None:
            raise IdentificationError(f'no lightly damped mode in band {lo:.4g} .. {hi:.4g}')
        _, i, k, w, z = best
        used.update((i, int(np.argmin(np.abs(lam - np.conj(lam[i]))))))
        out.append((k, w, z))
    return ModalModel(k0=float(k0.real), residues=tuple(o[0] for o in out),
                      natural_frequencies=tuple(o[1] for o in out),
                      damping_ratios=tuple(o[2] for o in out))


def bode_data(system: ModalModel | ArxModel | ContinuousModel, omega: ArrayLike, *,
              input_dynamics: InputDynamics | None = None,
              sample_period: float | None = None) -> tuple[NDArray[np.float64],
                                                           NDArray[np.float64]]:
    """Magnitude [dB] and unwrapped phase [deg] of a model at ``omega`` [rad/s].

    Args:
        system: A modal model (continuous, Eq. 1), an ARX model (its discrete response,
            for omega below pi/T) or a whole-model continuous conversion.
        omega: Angular frequencies [rad/s], ascending.
        input_dynamics: For a modal model: multiply by these input dynamics (delay and lag),
            to plot u -> y like the paper's Fig. 10; needs ``sample_period``.
        sample_period: Sample period [s] for ``input_dynamics``.

    Returns:
        ``(magnitude_db, phase_deg)``; the phase is unwrapped along ``omega`` and shifted by a
        multiple of 360 deg so that it starts in (-360, 0] deg (a rigid body starts at -180).
    """
    w = np.asarray(omega, dtype=float)
    h = system.frequency_response(w)
    if input_dynamics is not None:
        if not isinstance(system, ModalModel):
            raise ConfigurationError('input_dynamics applies to a ModalModel only')
        if sample_period is None:
            raise ConfigurationError('input_dynamics needs sample_period')
        h = h * input_dynamics.frequency_response(w, sample_period)
    with np.errstate(divide='ignore'):
        mag = 20 * np.log10(np.abs(h))
    phase = np.degrees(np.unwrap(np.angle(h)))
    if phase.size:
        phase = phase - 360.0 * np.floor(phase.flat[0] / 360.0 + 1.0 - 1e-9)
    return np.asarray(mag, dtype=float), np.asarray(phase, dtype=float)
