"""The checks of the windower: its settings, a move half, the two halves of a move.

:class:`~galvo_sysid.monitor.pairing.MoveWindower` refuses out-of-range settings
(:func:`check_settings`). It sets aside a half whose fields (:func:`field_problem`), sample
period (:func:`period_problem`) or samples (:func:`record_problem`) are unusable, in that
order, and a move whose two halves disagree (:func:`pair_problem`). Each of these returns the
reason, said in the rejection, or None.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.monitor.moves import SIGNALS

if TYPE_CHECKING:
    from galvo_sysid.monitor.moves import MoveHalf

__all__ = ['check_settings', 'field_problem', 'pair_problem', 'period_problem',
           'record_problem']


def _finite_positive(value: float) -> bool:
    return math.isfinite(value) and value > 0


def check_settings(*, window_size: int, samples: int, max_samples: int, min_samples: int,
                   pair_timeout: float, time_jump: float, angle_resolution: float,
                   max_pending: int, max_windows: int, max_buffered_bytes: int,
                   window_timeout: float, sample_period: float) -> None:
    """Check the settings of a :class:`~galvo_sysid.monitor.pairing.MoveWindower`.

    The arguments are the windower's, as given (see there).

    Raises:
        ConfigurationError: On an out-of-range setting (the first found).
    """
    if int(window_size) < 2:
        raise ConfigurationError(f'window_size must be >= 2, got {window_size}')
    if int(min_samples) < 1 or int(max_samples) < int(min_samples):
        raise ConfigurationError('need 1 <= min_samples <= max_samples')
    if samples and not int(min_samples) <= int(samples) <= int(max_samples):
        raise ConfigurationError(
            f'samples must be 0 or within [{min_samples}, {max_samples}], got {samples}')
    for name, value in (('pair_timeout', pair_timeout), ('time_jump', time_jump),
                        ('angle_resolution', angle_resolution),
                        ('window_timeout', window_timeout)):
        if not _finite_positive(float(value)):
            raise ConfigurationError(f'{name} must be positive and finite, got {value}')
    if int(max_pending) < 1 or int(max_windows) < 1:
        raise ConfigurationError('max_pending and max_windows must be >= 1')
    budget = int(max_buffered_bytes)
    smallest = int(samples) or int(min_samples)
    if budget - budget // 4 < 16 * int(window_size) * smallest:
        raise ConfigurationError(f'max_buffered_bytes ({budget}) cannot hold one window '
                                 f'of {window_size} moves of {smallest} samples')
    if budget // 4 < 16 * int(max_samples):
        raise ConfigurationError(f'max_buffered_bytes ({budget}) cannot hold a waiting '
                                 f'pair of the largest records ({max_samples} samples): a '
                                 f'quarter of it must')
    period = float(sample_period)
    if not (period == 0 or _finite_positive(period)):
        raise ConfigurationError(f'sample_period must be 0 or positive and finite, got '
                                 f'{sample_period}')


def field_problem(half: MoveHalf, *, angle_resolution: float) -> str | None:
    """Return why the half's fields (signal, id, stamp, angle, period) are unusable, or None.

    Args:
        half: The half.
        angle_resolution: Smaller target angle magnitudes [deg] count as a zero angle.
    """
    if half.signal not in SIGNALS:
        return f'unknown signal {half.signal!r}'
    if half.move_id < 0:
        return 'negative move_id'
    if not math.isfinite(half.stamp):
        return f'non-finite stamp in {half.signal}'
    if not math.isfinite(half.target_angle):
        return f'non-finite target angle in {half.signal}'
    if abs(half.target_angle) < angle_resolution:
        return 'zero target angle'
    if not _finite_positive(half.sample_period):
        return f'bad sample period {half.sample_period!r} s in {half.signal}'
    return None


def period_problem(half: MoveHalf, expected: float) -> str | None:
    """Return why the half's sample period is not ``expected`` (0: any), or None.

    Args:
        half: The half (its sample period positive and finite).
        expected: The model's sample period [s]; a relative difference over 1e-6 is refused.
    """
    if expected and abs(half.sample_period - expected) > 1e-6 * expected:
        return (f"the data's sample period {half.sample_period:.6g} s "
                f"differs from the model's {expected:.6g} s")
    return None


def record_problem(half: MoveHalf, *, samples: int, min_samples: int,
                   max_samples: int) -> str | None:
    """Return why the half's samples are unusable, or None.

    Args:
        half: The half.
        samples: Expected samples per record (0: any length).
        min_samples: Smallest accepted record.
        max_samples: Largest accepted record.
    """
    data = half.data
    if data.ndim != 1:
        return f'{half.signal} record is not one-dimensional'
    n = data.shape[0]
    if n == 0:
        return f'empty {half.signal} record'
    if n > max_samples:
        return f'{half.signal} record too long ({n} > {max_samples} samples)'
    if n < min_samples:
        return f'{half.signal} record too short ({n} < {min_samples} samples)'
    if samples and n != samples:
        return f'{half.signal} record has {n} samples, expected {samples}'
    if not np.isfinite(data).all():
        return f'NaN or Inf in {half.signal}'
    return None


def pair_problem(current: MoveHalf, encoder: MoveHalf, *,
                 angle_resolution: float) -> str | None:
    """Return why two checked halves of one move disagree (length, angle, period), or None.

    Args:
        current: The current half.
        encoder: The encoder half.
        angle_resolution: Target angles this far apart [deg] or more disagree.
    """
    n = current.data.shape[0]
    if encoder.data.shape[0] != n:
        return (f'current and encoder lengths differ ({n} and '
                f'{encoder.data.shape[0]} samples)')
    if abs(current.target_angle - encoder.target_angle) >= angle_resolution:
        return (f'current and encoder disagree on target angle '
                f'({current.target_angle:g} and {encoder.target_angle:g} deg)')
    if abs(current.sample_period - encoder.sample_period) > 1e-9 * current.sample_period:
        return 'current and encoder disagree on sample period'
    return None
