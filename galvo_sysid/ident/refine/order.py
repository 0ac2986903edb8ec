"""Choosing a model's order: fixed noise filters and the gain of one more mode.

The filters make fits of different orders to the same windows comparable (one ``chi2``
scale); commissioning adds the mode whose candidate lowers it most. Fixed noise models
(:class:`~galvo_sysid.ident.refine.whitener.NoiseModel`, e.g. a rigid-body fit's) do the same
with the noise as a model's residual sees it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from galvo_sysid.ident.refine.options import DEFAULT_WHITEN_ORDER
from galvo_sysid.ident.refine.regressors import FIRST_ROW, second_difference
from galvo_sysid.ident.refine.whitener import NoiseModel, Whitener, noise_whitener
from galvo_sysid.ident.refine.window import WindowProblem, validate, window_records
from galvo_sysid.model.dynamics import split_delay

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import ArrayLike, NDArray

    from galvo_sysid.ident.refine.result import RefinedFit

__all__ = ['added_mode_gains', 'window_noise_filters']


def window_noise_filters(windows: Sequence[tuple[ArrayLike, ArrayLike]], *,
                         order: int = DEFAULT_WHITEN_ORDER) -> list[Whitener | None]:
    """A prewhitening map per window from its moves' scatter alone (no model needed).

    The :class:`~galvo_sysid.ident.refine.whitener.Whitener` of the (1 - q^-1)^2-filtered
    encoder deviations from the window's mean: the noise the averaged window carries, up to
    the small part the input deviations explain.
    """
    out = []
    for current, encoder in windows:
        _, enc = validate(current, encoder)
        dev = second_difference(enc - enc.mean(axis=0))[:, FIRST_ROW:]
        out.append(noise_whitener(dev, order, float(np.sqrt(np.mean(
            second_difference(enc.mean(axis=0)) ** 2)))))
    return out


def added_mode_gains(windows: Sequence[tuple[ArrayLike, ArrayLike]], fit: RefinedFit, *,
                     noise_filters: Sequence[Whitener | None],
                     candidates: tuple[NDArray[np.float64], NDArray[np.float64]],
                     noise_models: Sequence[NoiseModel | None] = ()) -> NDArray[np.float64]:
    """Drop of a joint fit's ``chi2`` if one more mode were added at each candidate.

    The fit's modes and lag stay fixed, all linear coefficients are solved again; the same
    ``noise_filters`` as the fit's must be given, so the drops are in its ``chi2`` units.

    Args:
        windows: The fit's windows.
        fit: A joint fit made with ``noise_filters``.
        noise_filters: Its filters.
        candidates: ``(omega, zeta)`` of the candidate modes.
        noise_models: Per window, the fixed noise model the fit weighed it with instead of
            its filter (its whitener and weight), if any.

    Returns:
        The drop of chi2 per candidate.
    """
    w_c, z_c = (np.asarray(c, dtype=float) for c in candidates)
    m = fit.model
    omega = np.array(m.natural_frequencies, dtype=float)
    zeta = np.array(m.damping_ratios, dtype=float)
    t = fit.sample_period
    delay, frac = split_delay(fit.computation_delay * t + fit.dead_time, t)
    total = np.zeros(w_c.size)
    models = list(noise_models) + [None] * (len(noise_filters) - len(noise_models))
    for (cur, enc), filt, model in zip(window_records(windows, 1), noise_filters, models,
                                       strict=True):
        prob = WindowProblem(cur, enc, sample_period=t, delay=delay, fraction=frac,
                             n_modes=m.n_modes)
        if model is not None:
            prob.set_whitening(model.whitener())
            weight = model.weight()
        else:
            prob.set_whitening(filt)
            weight = 1.0 / max(prob.raw_noise_rms(), 1e-300)
        total += weight * weight * prob.scan_new(omega, zeta, fit.lag_time_constant, w_c, z_c)
    return total
