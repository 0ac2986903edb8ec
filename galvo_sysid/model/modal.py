"""The modal model of the scanner's mechanics (paper Eq. 1).

The mechanical part is a rigid-body mode plus resonant modes::

    P_mech(s) = k0 / s^2 + sum_i k_i / (s^2 + 2 zeta_i omega_i s + omega_i^2)

from the commanded current u [A] to the motor-shaft angle y [deg]. Parameters are named
``k0``, ``k1``.., ``omega_1``.., ``zeta_1``.. (:func:`parameter_names`); each mode has a
frequency band in which identification looks for it (:func:`default_bands`).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise
from typing import TYPE_CHECKING

import numpy as np

from galvo_sysid.errors import ConfigurationError

if TYPE_CHECKING:
    from numpy.typing import ArrayLike, NDArray

__all__ = [
    'MAX_DAMPING_RATIO',
    'MAX_MAGNITUDE',
    'Band',
    'ModalModel',
    'default_bands',
    'parameter_mode',
    'parameter_names',
    'parameter_unit',
    'relative_errors',
]

Band = tuple[float, float]
"""A frequency band (low, high) [rad/s]."""

MAX_MAGNITUDE = 1e15
"""Largest magnitude of any modal parameter (gains of real scanners are below 1e9 deg/(A s^2)
and frequencies below 1e7 rad/s); beyond it a value is a typo or an attack."""

MAX_DAMPING_RATIO = 1.0
"""Largest damping ratio of a mode a model file or a simulated plant may have (above it a mode
is two real poles, not a resonance)."""


def parameter_names(n_modes: int) -> tuple[str, ...]:
    """Return the parameter names of a model with ``n_modes`` resonant modes, in order."""
    return ('k0', *(f'k{i}' for i in range(1, n_modes + 1)),
            *(f'omega_{i}' for i in range(1, n_modes + 1)),
            *(f'zeta_{i}' for i in range(1, n_modes + 1)))


def parameter_mode(name: str) -> int:
    """The 1-based resonant mode of a parameter name (``k2``, ``omega_2``, ``zeta_2``: 2), 0
    for ``k0``."""  # noqa: D205, D209
    tail = name.rsplit('_', 1)[-1] if '_' in name else name[1:]
    return int(tail) if tail.isdigit() else 0


def parameter_unit(name: str) -> str:
    """The unit of a modal parameter: ``deg/(A s^2)`` (gains), ``rad/s``, ``-`` (damping)."""
    if name.startswith('omega_'):
        return 'rad/s'
    if name.startswith('zeta_'):
        return '-'
    return 'deg/(A s^2)'


@dataclass(frozen=True)
class ModalModel:
    """Rigid-body mode plus resonant modes (paper Eq. 1), modes in ascending frequency.

    Attributes:
        k0: Rigid-body gain [deg/(A s^2)].
        residues: Residues k_i of the resonant modes [deg/(A s^2)].
        natural_frequencies: Natural frequencies omega_i [rad/s].
        damping_ratios: Damping ratios zeta_i.
    """

    k0: float
    residues: tuple[float, ...]
    natural_frequencies: tuple[float, ...]
    damping_ratios: tuple[float, ...]

    def __post_init__(self) -> None:
        n = len(self.residues)
        if len(self.natural_frequencies) != n or len(self.damping_ratios) != n:
            msg = 'residues, natural_frequencies and damping_ratios must have equal lengths'
            raise ConfigurationError(msg)
        values = np.array([self.k0, *self.residues, *self.natural_frequencies,
                           *self.damping_ratios], dtype=float)
        if not np.all(np.isfinite(values)):
            raise ConfigurationError('modal parameters must be finite')
        if any(w <= 0 for w in self.natural_frequencies):
            raise ConfigurationError('natural frequencies must be positive')
        if any(z <= 0 for z in self.damping_ratios):
            raise ConfigurationError('damping ratios must be positive')
        if np.max(np.abs(values)) > MAX_MAGNITUDE:
            raise ConfigurationError(f'modal parameters must stay within +-{MAX_MAGNITUDE:g}')

    @property
    def n_modes(self) -> int:
        """Number of resonant modes."""
        return len(self.residues)

    def parameters(self) -> dict[str, float]:
        """Return the parameters by name: k0, k1.., omega_1.., zeta_1.."""
        out = {'k0': float(self.k0)}
        for prefix, values in (('k', self.residues), ('omega_', self.natural_frequencies),
                               ('zeta_', self.damping_ratios)):
            for i, v in enumerate(values, start=1):
                out[f'{prefix}{i}'] = float(v)
        return out

    def frequency_response(self, omega: ArrayLike) -> NDArray[np.complex128]:
        """Return P_mech(j omega) at the angular frequencies ``omega`` [rad/s]."""
        s = 1j * np.asarray(omega, dtype=float)
        with np.errstate(divide='ignore', invalid='ignore'):
            h = self.k0 / s**2
        for k, w, z in zip(self.residues, self.natural_frequencies, self.damping_ratios,
                           strict=True):
            h = h + k / (s**2 + 2 * z * w * s + w**2)
        return np.asarray(h, dtype=np.complex128)


def default_bands(reference: ModalModel, *, outer_ratio: float | None = None,
                  sample_period: float | None = None) -> tuple[Band, ...]:
    """Frequency bands [rad/s] that partition the axis around the reference modes.

    Neighbouring bands meet at the geometric mean of neighbouring natural frequencies. The
    outer edges are ``omega_1 / outer_ratio`` and ``omega_n * outer_ratio``; by default
    (``None``) they mirror the inner edges, so the first and last bands are symmetric in log
    frequency (for Table I: omega_1 / 1.296 and omega_3 * 1.185, i.e. 54.9e3 .. 198.4e3 rad/s;
    a single mode gets a ratio of 1.3). The upper edge is capped at 0.98 of the Nyquist
    frequency when ``sample_period`` is given.
    """
    if outer_ratio is not None and not outer_ratio > 1:
        raise ConfigurationError(f'outer_ratio must be > 1, got {outer_ratio}')
    w = reference.natural_frequencies
    if not w:
        raise ConfigurationError('reference model has no resonant modes')
    if outer_ratio is None and len(w) == 1:
        outer_ratio = 1.3
    low_ratio = float(np.sqrt(w[1] / w[0])) if outer_ratio is None else outer_ratio
    high_ratio = float(np.sqrt(w[-1] / w[-2])) if outer_ratio is None else outer_ratio
    edges = [w[0] / low_ratio, *(float(np.sqrt(a * b)) for a, b in pairwise(w)),
             w[-1] * high_ratio]
    if sample_period is not None:
        edges[-1] = min(edges[-1], 0.98 * np.pi / sample_period)
    return tuple((float(lo), float(hi)) for lo, hi in pairwise(edges))


def relative_errors(identified: ModalModel,
                    reference: ModalModel | None = None) -> dict[str, float]:
    """Return (identified - reference) / reference for every parameter, by name.

    The reference defaults to the paper's Table I.
    """
    if reference is None:
        from galvo_sysid.model.paper import REFERENCE_MODEL

        reference = REFERENCE_MODEL
    ref = reference.parameters()
    ident = identified.parameters()
    if ref.keys() != ident.keys():
        raise ConfigurationError('models have different numbers of modes')
    return {name: (ident[name] - ref[name]) / ref[name] for name in ref}
