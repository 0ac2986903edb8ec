"""The running plant sampled exactly, with sub-steps for the nonlinear effects (simulator).

:func:`continuous_plant` builds the continuous state space of a
:class:`~galvo_sysid.model.physics.Physics` (amplifier lag, rigid body with its pivot, every
mode, the gain ratio); :func:`sample_plant` samples it at the DSP's period with the exact
zero-order hold of :func:`galvo_sysid.model.dynamics.zoh`, the pure delay split inside the
sample by :func:`galvo_sysid.model.dynamics.split_delay`, and sub-steps over which a
disturbance current (friction, the saturation's correction) is held.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model.dynamics import modal_state_space, split_delay, zoh

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from galvo_sysid.model.physics import Physics

__all__ = ['ContinuousPlant', 'SampledPlant', 'continuous_plant', 'sample_plant']


@dataclass(frozen=True)
class ContinuousPlant:
    """Continuous-time state space of the plant from the delayed command to the angle.

    x' = a x + b_u u_applied + b_d d, y = c x, where d is a current entering the mechanics
    directly (noise, friction, saturation correction) at the nominal torque constant.

    Attributes:
        a: State matrix.
        b_u: Drive of the delayed command (through the lag if there is one).
        b_d: Drive of the disturbance current d.
        c: Encoder angle output.
        current_index: Index of the amplifier current state (None without a lag).
        position_index: Index of the rigid-body position.
        velocity_index: Index of the rigid-body velocity.
    """

    a: NDArray[np.float64]
    b_u: NDArray[np.float64]
    b_d: NDArray[np.float64]
    c: NDArray[np.float64]
    current_index: int | None
    position_index: int
    velocity_index: int


def continuous_plant(physics: Physics) -> ContinuousPlant:
    """Build the continuous state space of a plant (lag state first, then mode pairs)."""
    ph = physics
    lag = ph.lag_time_constant
    off = 1 if lag > 0 else 0
    a, b_u, b_d, c = modal_state_space(gains=[ph.k0, *ph.residues],
                                       frequencies=[ph.pivot_frequency, *ph.natural_frequencies],
                                       dampings=[0.0, *ph.damping_ratios],
                                       lag_time_constant=lag, input_gain=ph.gain_ratio,
                                       rigid_damping=ph.rigid_damping)
    return ContinuousPlant(a=a, b_u=b_u, b_d=b_d, c=c, current_index=0 if lag > 0 else None,
                           position_index=off, velocity_index=off + 1)


@dataclass(frozen=True)
class SampledPlant:
    """The plant sampled at the DSP's period, exactly, with sub-steps for nonlinear effects.

    Over sample k the applied (delayed) command is u[k - whole - 1] for the first
    ``split`` seconds and u[k - whole] after it (``split`` = 0 without a fractional delay).
    With d held per sub-step j (of ``substeps``)::

        x[k+1] = phi x[k] + g_old u_old + g_new u_new + gamma_d @ d_substeps

    and for d held over the whole sample ``gamma_d.sum(axis=1) == g_d``.

    Attributes:
        continuous: The continuous plant.
        sample_period: Sampling period [s].
        whole: Whole samples of pure delay.
        split: Fractional delay [s] (0 if the delay is a whole number of samples).
        substeps: Sub-steps per sample.
        phi: Full-sample transition.
        g_old: Full-sample drive of u[k - whole - 1].
        g_new: Full-sample drive of u[k - whole].
        g_d: Full-sample drive of d held over the sample.
        gamma_d: (n, substeps) drive of d held per sub-step.
        sub_phi: Sub-step transition.
        sub_g_old: (substeps, n) sub-step drives of u_old.
        sub_g_new: (substeps, n) sub-step drives of u_new.
    """

    continuous: ContinuousPlant
    sample_period: float
    whole: int
    split: float
    substeps: int
    phi: NDArray[np.float64]
    g_old: NDArray[np.float64]
    g_new: NDArray[np.float64]
    g_d: NDArray[np.float64]
    gamma_d: NDArray[np.float64]
    sub_phi: NDArray[np.float64]
    sub_g_old: NDArray[np.float64]
    sub_g_new: NDArray[np.float64]



def sample_plant(physics: Physics, *, substeps: int = 1) -> SampledPlant:
    """Sample the plant exactly at its sample period (fractional delay split exactly).

    Args:
        physics: The plant.
        substeps: Sub-steps per sample over which a disturbance current may be held.

    Returns:
        The sampled plant.
    """
    if substeps < 1:
        raise ConfigurationError('substeps must be >= 1')
    sample_period = physics.sample_period
    cp = continuous_plant(physics)
    n = cp.a.shape[0]
    drives = np.stack([cp.b_u, cp.b_d], axis=1)

    def zoh_u_d(t: float) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                   NDArray[np.float64]]:
        phi, gamma = zoh(cp.a, drives, t)
        return phi, gamma[:, 0], gamma[:, 1]

    # Pure input delay: the computation delay and the dead time (effects included).
    whole, fraction = split_delay(physics.pure_delay, sample_period)
    frac = fraction * sample_period
    h = sample_period / substeps
    sub_phi, sub_g_u, sub_g_d = zoh_u_d(h)
    sub_g_old = np.zeros((substeps, n))
    sub_g_new = np.zeros((substeps, n))
    for j in range(substeps):  # u_old before the split, u_new after it
        t0, t1 = j * h, (j + 1) * h
        if frac <= t0:
            sub_g_new[j] = sub_g_u
        elif frac >= t1:
            sub_g_old[j] = sub_g_u
        else:
            phi_rest, g_rest, _ = zoh_u_d(t1 - frac)
            sub_g_old[j] = phi_rest @ zoh_u_d(frac - t0)[1]
            sub_g_new[j] = g_rest
    powers = [np.eye(n)]
    for _ in range(substeps - 1):
        powers.append(sub_phi @ powers[-1])
    phi = sub_phi @ powers[-1]
    rev = powers[::-1]  # rev[j] = sub_phi^(substeps - 1 - j)
    g_old = sum((rev[j] @ sub_g_old[j] for j in range(substeps)), np.zeros(n))
    g_new = sum((rev[j] @ sub_g_new[j] for j in range(substeps)), np.zeros(n))
    gamma_d = np.stack([rev[j] @ sub_g_d for j in range(substeps)], axis=1)
    return SampledPlant(continuous=cp, sample_period=sample_period, whole=whole, split=frac,
                        substeps=substeps, phi=phi, g_old=g_old, g_new=g_new,
                        g_d=gamma_d.sum(axis=1), gamma_d=gamma_d, sub_phi=sub_phi,
                        sub_g_old=sub_g_old, sub_g_new=sub_g_new)

