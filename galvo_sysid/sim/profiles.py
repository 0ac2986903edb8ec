"""Point-to-point move profiles: the reference and feed-forward of the 2-DOF controller.

A move's acceleration is a pulse accelerating over the first half of the move and its mirror
image braking over the second half, sampled at the centres of the DSP's sample periods, so
the velocity returns exactly to zero. The pulse's shape (``ProfileConfig.shape``):
``'scurve'`` (default: jerk-limited bang-bang, a trapezoidal pulse with ramps of
``jerk_time``), ``'sine-squared'`` (a sin^2 pulse: smooth, little energy at high
frequencies) or ``'minimum-jerk'`` (the acceleration of the quintic minimum-jerk path,
60 tau (1 - tau) (1 - 2 tau) over the whole move). The move's duration grows with the square
root of the angle (constant peak acceleration ``peak_current * k0``) but is at least
``min_duration``. The time defaults
scale with the sample period (20 and 3 samples): on the paper's scanner (10 us; 1 A peak,
0.2 ms minimum, 30 us ramps) a 0.03 deg move takes 0.2 ms, 0.3 deg 0.62 ms and 3 deg 1.9 ms,
well inside the 5.12 ms record.

The feed-forward current is u_ff = a_ref / k0 (nominal k0). The position reference the
feedback compares with is the nominal rigid body's response to u_ff through the nominal input
dynamics (delay + amplifier lag), so on a rigid nominal plant the feedback has nothing to do;
it sees only the resonances, the noise and any difference between the plant and the design.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model import ModalModel
from galvo_sysid.model.dynamics import InputDynamics, discretize

if TYPE_CHECKING:
    from numpy.typing import NDArray

__all__ = ['PROFILE_SHAPES', 'MoveProfile', 'ProfileConfig', 'move_profile']

PROFILE_SHAPES = ('scurve', 'sine-squared', 'minimum-jerk')
"""Acceleration shapes a move may have (see the module docs)."""


@dataclass(frozen=True)
class ProfileConfig:
    """Shape and timing of the move profiles.

    Attributes:
        peak_current: Peak feed-forward current [A]; with the design k0 it sets the peak
            acceleration of the moves that are not limited by ``min_duration``.
        min_duration: Shortest move [s] (None: 20 sample periods).
        jerk_time: Acceleration ramp time [s] (at most a quarter of the move; None: 3 sample
            periods).
        max_fraction: Longest move as a fraction of the recorded samples.
        shape: Acceleration shape, one of :data:`PROFILE_SHAPES`.
    """

    peak_current: float = 1.0
    min_duration: float | None = None
    jerk_time: float | None = None
    max_fraction: float = 0.6
    shape: str = 'scurve'

    def __post_init__(self) -> None:
        for name in ('peak_current', 'min_duration', 'max_fraction'):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value > 0):
                raise ConfigurationError(f'{name} must be positive and finite, got {value!r}')
        if self.jerk_time is not None and not (math.isfinite(self.jerk_time)
                                               and self.jerk_time >= 0):
            raise ConfigurationError(f'jerk_time must be >= 0, got {self.jerk_time!r}')
        if self.max_fraction > 1:
            raise ConfigurationError('max_fraction must be <= 1')
        if self.shape not in PROFILE_SHAPES:
            raise ConfigurationError(f'shape must be one of {", ".join(PROFILE_SHAPES)}, got '
                                     f'{self.shape!r}')

    def times(self, sample_period: float) -> tuple[float, float]:
        """(min_duration, jerk_time) [s] at a sample period (the defaults scale with it)."""
        scale = sample_period / 1e-5   # the defaults are the paper's 0.2 ms and 30 us at 10 us
        return (2e-4 * scale if self.min_duration is None else self.min_duration,
                3e-5 * scale if self.jerk_time is None else self.jerk_time)


@dataclass(frozen=True)
class MoveProfile:
    """One move's feed-forward and reference, relative to its start.

    Attributes:
        angle: Signed rotation [deg].
        duration: Samples of acceleration and braking.
        feedforward: Feed-forward current u_ff [A], one value per sample.
        reference: Position reference relative to the start [deg]; ends at ``angle``.
    """

    angle: float
    duration: int
    feedforward: NDArray[np.float64]
    reference: NDArray[np.float64]


def _shape(samples: int, sample_period: float, jerk_time: float,
           kind: str = 'scurve') -> NDArray[np.float64]:
    """Unit-peak acceleration at the sample centres (antisymmetric in time)."""
    total = samples * sample_period
    half = total / 2
    ramp = min(jerk_time, half / 2)
    t = (np.arange(samples) + 0.5) * sample_period
    tt = np.where(t < half, t, t - half)
    if kind == 'minimum-jerk':
        tau = t / total
        acc = tau * (1 - tau) * (1 - 2 * tau)
        return np.asarray(acc / np.max(np.abs(acc)), dtype=np.float64)
    if kind == 'sine-squared':
        pulse = np.sin(np.pi * tt / half) ** 2
    elif ramp > 0:
        up = np.clip(tt / ramp, 0, 1)
        down = np.clip((half - tt) / ramp, 0, 1)
        pulse = np.minimum(up, down)
    else:
        pulse = np.ones(samples)
    return np.where(t < half, pulse, -pulse)


@functools.lru_cache(maxsize=16)
def _rigid_impulse(k0: float, dynamics: InputDynamics, sample_period: float,
                   length: int) -> NDArray[np.float64]:
    """Impulse response of the nominal rigid body with its input dynamics."""
    rigid = discretize(ModalModel(k0=k0, residues=(), natural_frequencies=(),
                                  damping_ratios=()), dynamics, sample_period)
    impulse = np.zeros(length)
    x = rigid.b.copy()
    for k in range(1, length):
        impulse[k] = rigid.c @ x
        x = rigid.a @ x
    impulse.setflags(write=False)
    return impulse


def move_profile(angle: float, *, length: int, record_length: int, k0: float,
                 dynamics: InputDynamics, sample_period: float,
                 config: ProfileConfig | None = None) -> MoveProfile:
    """Design the profile of one move.

    Args:
        angle: Signed rotation [deg].
        length: Samples to produce (the move plus its dwell).
        record_length: Recorded samples; the move must fit in ``max_fraction`` of them.
        k0: Nominal rigid-body gain [deg/(A s^2)] of the feed-forward.
        dynamics: Nominal input dynamics of the reference.
        sample_period: Sampling period [s].
        config: Profile parameters.

    Returns:
        The profile.
    """
    cfg = config or ProfileConfig()
    if not math.isfinite(angle):
        raise ConfigurationError(f'angle must be finite, got {angle!r}')
    if not (math.isfinite(k0) and k0 > 0):
        raise ConfigurationError('the design k0 must be positive')
    max_samples = math.floor(cfg.max_fraction * record_length)
    peak_acc = cfg.peak_current * k0
    # A bang-bang move (no ramps) is the shortest: start the search there.
    bang_bang = 2 * math.sqrt(abs(angle) / peak_acc) / sample_period
    min_duration, jerk_time = cfg.times(sample_period)
    samples = max(2, math.ceil(min_duration / sample_period - 1e-9),
                  math.floor(bang_bang) - 2)
    samples += samples % 2
    while True:
        shape = _shape(samples, sample_period, jerk_time, cfg.shape)
        unit_distance = sample_period**2 * float(
            np.sum(shape * (samples - np.arange(samples) - 0.5)))
        if abs(angle) / unit_distance <= peak_acc * (1 + 1e-12):
            break
        samples += 2
        if samples > max_samples:
            raise ConfigurationError(
                f'a move of {angle!r} deg does not fit in {cfg.max_fraction} of the '
                f'{record_length}-sample record at {cfg.peak_current} A peak current')
    if samples > min(max_samples, length):
        raise ConfigurationError('min_duration does not fit in the record')
    acc = shape * (angle / unit_distance)
    ff = np.zeros(length)
    ff[:samples] = acc / k0
    impulse = _rigid_impulse(k0, dynamics, sample_period, length)
    ref = np.convolve(ff[:samples], impulse)[:length]
    return MoveProfile(angle=float(angle), duration=samples, feedforward=ff, reference=ref)
