"""The Cramer-Rao bound of windows at given parameters (no fit): what data could tell.

:func:`crlb_at` evaluates the bound that the refined fit reports (the Fisher matrix with the
stationary noise the moves' scatter shows, their own nuisance taken out, every nuisance
parameter partialled out: :func:`~galvo_sysid.ident.refine.joint.covariance`) at parameters
one gives, e.g.
the true ones of a simulated scanner: the information a move mix, a number of moves and a
dither carry, before any data are recorded (:mod:`galvo_sysid.ident.plan`). The shared
linear parameters are solved from the data at the given nonlinear ones.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from galvo_sysid.errors import InvalidDataError
from galvo_sysid.ident.refine.joint import JointProblem, covariance
from galvo_sysid.ident.refine.options import DEFAULT_WHITEN_ORDER
from galvo_sysid.ident.refine.window import WindowProblem, window_records
from galvo_sysid.model.dynamics import InputDynamics, check_sample_period, split_delay

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import ArrayLike

    from galvo_sysid.model.modal import ModalModel

__all__ = ['crlb_at']


def crlb_at(windows: Sequence[tuple[ArrayLike, ArrayLike]], *, sample_period: float,
            model: ModalModel, dynamics: InputDynamics, estimate_lag: bool = True,
            whiten_order: int = DEFAULT_WHITEN_ORDER) -> dict[str, float]:
    """Cramer-Rao standard deviation of each parameter from these windows at ``model``.

    Args:
        windows: ``(current, encoder)`` records per window, each (M, N) with M >= 3.
        sample_period: Sampling period [s].
        model: The modal parameters at which the bound is evaluated (frequencies and damping
            ratios; the residues and k0 are solved from the data).
        dynamics: Input dynamics (the lag at which the bound is evaluated).
        estimate_lag: Whether the lag counts as unknown.
        whiten_order: Lags of the noise model (of the fit's prewhitening and of the bound's
            noise estimate).

    Returns:
        Standard deviation by parameter name (``k0``, ``k1``.., ``omega_1``.., ``zeta_1``..,
        and ``lag`` if estimated).

    Raises:
        InvalidDataError: Bad records, fewer than 3 moves per window, or no noise.
    """
    t = check_sample_period(sample_period)
    n = model.n_modes
    delay, frac = split_delay(dynamics.pure_delay(t), t)
    problems = [WindowProblem(cur, enc, sample_period=t, delay=delay, fraction=frac, n_modes=n)
                for cur, enc in window_records(windows, 3)]
    joint = JointProblem(problems, np.ones(len(problems)),
                         fixed_lag=None if estimate_lag else dynamics.lag_time_constant)
    x = joint.pack(np.array(model.natural_frequencies, dtype=float),
                   np.array(model.damping_ratios, dtype=float), dynamics.lag_time_constant)
    joint.prewhiten(x, whiten_order)
    if any(prob.whiten is None for prob in problems):
        raise InvalidDataError('the moves do not scatter: no noise to bound the error with')
    _, _, bound = covariance(joint, x, joint.coefficients(x))
    assert bound is not None
    names = [*(f'k{i}' if i else 'k0' for i in range(n + 1)),
             *(f'omega_{i}' for i in range(1, n + 1)), *(f'zeta_{i}' for i in range(1, n + 1)),
             *(('lag',) if estimate_lag else ())]
    sd = np.sqrt(np.clip(np.diag(bound), 0.0, None))
    return {name: float(s) for name, s in zip(names, sd, strict=True)}
