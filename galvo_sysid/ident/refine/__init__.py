"""The refined fit: a structured output-error fit of the physical modal model (past the paper).

The paper fits a 15th-order ARX model to the averaged window and decomposes it; its third
mode is poor (Table II: zeta_3 +655 %) and the amplifier lag is treated as a pure delay,
which biases the residues (k_2 about -20 %). This subpackage fits the physical model itself::

    y[k] = P_mech(s) L(s) z^-d u[k]  (exact zero-order hold)  + free response + offset

with the input dynamics of :class:`galvo_sysid.model.dynamics.InputDynamics`: ``d`` whole
samples of DSP computation delay, an optional fractional dead time, and the current
amplifier's first-order lag ``L(s) = 1 / (1 + s T_l)``, whose time constant is estimated.
The rigid-body gain k0, the residues k_i, the modes' initial conditions (the residual
vibration of the previous move), an offset and the lag state's initial value enter linearly
and are solved inside the loop (variable projection); only omega_i, zeta_i and T_l are
optimised nonlinearly (:func:`scipy.optimize.least_squares`, Kaufman's Jacobian).

Modules: ``options`` (the tuning and its defaults), ``regressors`` (exact ZOH responses of
the modes, filtered), ``window`` (one window's averaged moves and their scatter), ``joint``
(variable projection over one or several windows, the sandwich covariance), ``profile`` (weak
modes over their band), ``checks`` (bands, band edges, unresolved modes, the residual against
the noise), ``fit`` (the one fit: :func:`refine_fit` for a window, :func:`refine_joint` for
several), ``result`` (:class:`RefinedFit`), ``order`` (noise filters and the gain of one more
mode, for choosing a model's order).
"""

from galvo_sysid.ident.refine.fit import refine_fit, refine_joint
from galvo_sysid.ident.refine.options import (
    DEFAULT_ADEQUACY_LIMIT,
    DEFAULT_DAMPING_START,
    DEFAULT_LAG_BOUNDS,
    DEFAULT_RESOLVE_Z,
    DEFAULT_SCAN_POINTS,
    DEFAULT_WHITEN_ORDER,
    RefineOptions,
)
from galvo_sysid.ident.refine.order import added_mode_gains, window_noise_filters
from galvo_sysid.ident.refine.regressors import modal_regressors, second_difference
from galvo_sysid.ident.refine.result import RefinedFit, filtered_fit_percent, model_fit_percent
from galvo_sysid.ident.refine.window import MIN_SAMPLES

__all__ = [
    'DEFAULT_ADEQUACY_LIMIT',
    'DEFAULT_DAMPING_START',
    'DEFAULT_LAG_BOUNDS',
    'DEFAULT_RESOLVE_Z',
    'DEFAULT_SCAN_POINTS',
    'DEFAULT_WHITEN_ORDER',
    'MIN_SAMPLES',
    'RefineOptions',
    'RefinedFit',
    'added_mode_gains',
    'filtered_fit_percent',
    'modal_regressors',
    'model_fit_percent',
    'refine_fit',
    'refine_joint',
    'second_difference',
    'window_noise_filters',
]
