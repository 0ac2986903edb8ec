"""A window's refined fit started from the previous window of the same moves (warm start).

The sysid node identifies window after window of the same signed angles. The previous
window's result already holds what a fit searches for afresh: the basin of every mode (the
paper pipeline's ARX start and the frequency scans) and the stationary noise model (the
expectation-maximisation over the moves' scatter). :class:`WarmStart` carries them to the next
window's fit (:func:`~galvo_sysid.ident.identify.identify_window`'s ``warm_start``), which then

- starts the prewhitened polish from the previous estimate as it is (no ARX start, no scan,
  no first unwhitened stage), except that a mode the previous window did not resolve starts
  from the scanner's reference model (its frequency and damping there were a noise fit, and
  a polish from a noise fit of a weakly excited mode wanders: the slowest warm fits);
- leaves a weakly excited mode where it is when its band profile finds a better basin that
  would not place it either (``RefineOptions.search_unplaced`` off: it ends unresolved both
  ways, and the second polish and profile are saved);
- reuses the previous noise model with its level rescaled to this window's moves, unless this
  window's noise differs from it by more than a factor
  :data:`~galvo_sysid.ident.refine.joint.REUSE_LEVEL` (then it is estimated as usual);
- still profiles the weakly excited modes over their bands and checks the fit as usual.

The fit is kept only if its cost is what the noise allows (:func:`plausible`): a plant that
moved to another basin since the previous window (a step change) leaves a misfit far above
the noise, and the window is fitted afresh. Both ways the estimate is the same optimum, to a
fraction of a std: ``benchmarks/efficiency.py --warm 20`` measures the warm fits' efficiency
and calibration against the Cramer-Rao bound, ``benchmarks/fit_stages.py --warm`` the time
saved.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from galvo_sysid.model.modal import ModalModel

if TYPE_CHECKING:
    from galvo_sysid.ident.refine.whitener import NoiseModel
    from galvo_sysid.ident.result import IdentificationResult
    from galvo_sysid.model import PlantModel

__all__ = ['WARM_CHI2_Z', 'WarmStart', 'plausible', 'reference_start']

WARM_CHI2_Z = 5.0
"""A warm-started fit is kept when its cost (in noise units) exceeds its rows by at most this
many standard deviations of a chi-square of that many rows (``sqrt(2 rows)``)."""


@dataclass(frozen=True)
class WarmStart:
    """What the next window of the same moves starts from.

    Attributes:
        model: The previous window's modal model (its frequencies and damping ratios start
            the fit; the residues are solved anew).
        lag_time_constant: Its amplifier lag [s] (the start, when the lag is estimated).
        noise_model: Its stationary noise model (None: estimated anew).
        resolved: Per mode, whether the previous window resolved it (empty: all).
        from_model: The start is a model file's (:func:`reference_start`), no fit to data: a
            weakly excited mode is then moved to the better basin its band profile finds even
            where that basin would not place it either, as a fit afresh does (the model's
            frequency may be far from the plant's since it drifted).
    """

    model: ModalModel
    lag_time_constant: float
    noise_model: NoiseModel | None = None
    resolved: tuple[bool, ...] = ()
    from_model: bool = False

    def start(self, reference: ModalModel) -> ModalModel:
        """The model the fit starts from: the previous estimate, each mode it did not resolve
        at ``reference``'s frequency and damping (where the mode counts agree)."""  # noqa: D205, D209
        m = self.model
        if reference.n_modes != m.n_modes or all(self.resolved) or \
                len(self.resolved) != m.n_modes:
            return m
        pick = [(w, z) if ok else (w_ref, z_ref) for ok, w, z, w_ref, z_ref in zip(
            self.resolved, m.natural_frequencies, m.damping_ratios,
            reference.natural_frequencies, reference.damping_ratios, strict=True)]
        return replace(m, natural_frequencies=tuple(w for w, _ in pick),
                       damping_ratios=tuple(z for _, z in pick))

    @classmethod
    def from_result(cls, result: IdentificationResult) -> WarmStart | None:
        """The warm start a refined window result gives (None for the paper methods' or a
        result without finite frequencies)."""  # noqa: D205, D209
        if result.method != 'refined':
            return None
        values = (*result.natural_frequencies, *result.damping_ratios,
                  result.lag_time_constant)
        if not all(math.isfinite(v) for v in values):
            return None
        return cls(model=result.model, lag_time_constant=float(result.lag_time_constant),
                   noise_model=result.noise_model, resolved=tuple(result.resolved))


def reference_start(model: PlantModel) -> WarmStart:
    """The start of a window no earlier result of the same plant precedes: the scanner's
    model file itself (its modes and amplifier lag; the noise model estimated anew).

    Its fit is kept as a warm fit's is, only if its cost is what the noise allows
    (:func:`plausible`): a plant far from its model is fitted afresh.
    """  # noqa: D205
    return WarmStart(model=model.modal, lag_time_constant=model.physics().lag_time_constant,
                     from_model=True)


def plausible(chi2: float, rows: int) -> bool:
    """Whether a fit's cost of ``rows`` rows in noise units is what the noise allows."""
    return math.isfinite(chi2) and chi2 <= rows + WARM_CHI2_Z * math.sqrt(2.0 * max(rows, 1))
