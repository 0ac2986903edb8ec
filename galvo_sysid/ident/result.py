"""What identification returns: :class:`IdentificationResult`, modal parameters with their std."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any

from galvo_sysid.jsonsafe import json_safe
from galvo_sysid.model import ModalModel

if TYPE_CHECKING:
    from galvo_sysid.ident.refine.whitener import NoiseModel

__all__ = ['IdentificationResult', 'result_from_vectors']


@dataclass(frozen=True)
class IdentificationResult:
    """Modal parameters of one window (or a pool of windows) with their uncertainty.

    Attributes:
        target_angle: Signed commanded rotation of the window's moves [deg] (nan for a pool
            of different angles).
        moves: Moves used.
        input_delay: Equivalent input delay removed before the fit or modelled in it [s]
            (computation delay + dead time + amplifier lag).
        lag_time_constant: Amplifier lag used or estimated [s] (0 if a pure delay was assumed).
        k0: Rigid-body gain [deg/(A s^2)].
        residues: k_i, ascending frequency.
        natural_frequencies: omega_i [rad/s].
        damping_ratios: zeta_i.
        k0_std: Standard deviation of k0.
        residues_std: Standard deviations of k_i.
        natural_frequencies_std: Standard deviations of omega_i.
        damping_ratios_std: Standard deviations of zeta_i.
        fit_percent: Fit of the (1 - q^-1)^2-filtered averaged output [%] (see module docs).
        method: ``'paper-A'``, ``'paper-B'`` or ``'refined'``.
        resolved: Per mode, whether the data place it (its residue is significant, at least
            5 standard deviations of the fit); an unresolved mode's numbers say nothing (its
            std is widened to its band). The refined method's reported std of a residue that only
            just passed also counts the bias of having passed (up to 3.1 times the fit's std
            at the threshold, see :func:`~galvo_sysid.ident.refine.checks.widen_selected`).
        set_aside: ``(move index, reason)`` of the window's moves left out by the screening
            (:func:`~galvo_sysid.ident.screen.screen_moves`); ``moves`` counts the rest.
        crlb_std: Cramer-Rao lower bound of each parameter's standard deviation, keyed like
            :meth:`std_by_name` (the refined method; empty otherwise): what these data allow
            any unbiased estimator, with the stationary noise estimated from the moves' scatter
            (their own initial conditions taken out); a std above it means the fit's own
            noise model is not that noise (the fit is not efficient there).
        noise_model: The stationary noise model the refined fit weighed the window with
            (None otherwise): a joint fit of the same moves reuses it
            (:func:`~galvo_sysid.ident.identify.identify_joint`'s ``noise_models``). Not
            part of the result's data: left out of :meth:`to_dict` and of comparisons.
        warm_started: Whether the refined fit is the one started from the previous window's
            result (:class:`~galvo_sysid.ident.warm.WarmStart`) rather than from its own
            search. Not part of the result's data either.
        cut_short: Whether the refined fit ran past its deadline and left out the weakly
            excited modes' band profiles (:class:`~galvo_sysid.ident.refine.RefineOptions`'s
            ``deadline``; the sysid node's ``fit_budget_ms``): the modes they would have
            placed are reported unresolved. Not part of the result's data either.
    """

    target_angle: float
    moves: int
    input_delay: float
    lag_time_constant: float
    k0: float
    residues: tuple[float, ...]
    natural_frequencies: tuple[float, ...]
    damping_ratios: tuple[float, ...]
    k0_std: float
    residues_std: tuple[float, ...]
    natural_frequencies_std: tuple[float, ...]
    damping_ratios_std: tuple[float, ...]
    fit_percent: float
    method: str
    resolved: tuple[bool, ...] = ()
    set_aside: tuple[tuple[int, str], ...] = ()
    crlb_std: dict[str, float] = field(default_factory=dict)
    noise_model: NoiseModel | None = field(default=None, compare=False, repr=False)
    warm_started: bool = field(default=False, compare=False, repr=False)
    cut_short: bool = field(default=False, compare=False, repr=False)

    @property
    def model(self) -> ModalModel:
        """The identified modal model."""
        return ModalModel(k0=self.k0, residues=self.residues,
                          natural_frequencies=self.natural_frequencies,
                          damping_ratios=self.damping_ratios)

    @property
    def n_modes(self) -> int:
        """Number of resonant modes."""
        return len(self.residues)

    def std_by_name(self) -> dict[str, float]:
        """Standard deviation of every parameter, keyed like :meth:`ModalModel.parameters`."""
        out = {'k0': float(self.k0_std)}
        for prefix, values in (('k', self.residues_std), ('omega_', self.natural_frequencies_std),
                               ('zeta_', self.damping_ratios_std)):
            for i, v in enumerate(values, start=1):
                out[f'{prefix}{i}'] = float(v)
        return out

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict keyed by the field names (tuples as lists, non-finite as None)."""
        out: dict[str, Any] = json_safe({f.name: getattr(self, f.name) for f in fields(self)
                                         if f.compare})
        return out


def result_from_vectors(values: dict[str, float], stds: dict[str, float], *, n_modes: int,
                        **meta: Any) -> IdentificationResult:
    """A result from parameter and std dicts keyed like :meth:`ModalModel.parameters`."""

    def pick(src: dict[str, float], prefix: str) -> tuple[float, ...]:
        return tuple(float(src[f'{prefix}{i}']) for i in range(1, n_modes + 1))

    return IdentificationResult(
        k0=float(values['k0']), residues=pick(values, 'k'),
        natural_frequencies=pick(values, 'omega_'), damping_ratios=pick(values, 'zeta_'),
        k0_std=float(stds['k0']), residues_std=pick(stds, 'k'),
        natural_frequencies_std=pick(stds, 'omega_'), damping_ratios_std=pick(stds, 'zeta_'),
        **meta)
