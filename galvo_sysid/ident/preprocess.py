"""Validation and pre-processing of a window of move records (paper Sec. IV).

A window is M records of the same commanded rotation, each N samples: ``current`` [A] and
``encoder`` [deg], both shape (M, N). Records start at rest at their start angle, which is
subtracted (:func:`remove_start_angle`). The paper's two pre-processing methods turn the window
into one input/output pair for the ARX fit:

- method A (:func:`average_records`): the sample-wise average of the records (length N);
- method B (:func:`concatenate_records`): the records in series (length M N), each record's
  output offset by the end angle of the ones before it so that the output is continuous.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from galvo_sysid.errors import ConfigurationError, InvalidDataError
from galvo_sysid.ident.arx import min_data_length

if TYPE_CHECKING:
    from numpy.typing import ArrayLike, NDArray

__all__ = [
    'MAX_ANGLE',
    'MAX_SAMPLE_MAGNITUDE',
    'MIN_ANGLE_SPAN',
    'MIN_RECORDS',
    'TRAVEL_FACTOR',
    'Records',
    'average_records',
    'check_travel',
    'concatenate_records',
    'preprocess',
    'remove_start_angle',
    'travels',
    'validate_records',
]

MIN_RECORDS = 2
"""Fewest records a window must hold."""

MIN_ANGLE_SPAN = 1e-3
"""Default smallest encoder span [deg] of the averaged record that counts as a move
(25 steps of a 4e-5 deg encoder; the paper's smallest move is 0.03 deg)."""

MAX_ANGLE = 90.0
"""Largest target angle magnitude a move may have [deg] (a galvo turns a few tens of degrees)."""

MAX_SAMPLE_MAGNITUDE = 1e6
"""Largest magnitude of a sample taken as a measurement: current [A], encoder angle [deg].

A galvano scanner's currents stay below 100 A and its angles within +-30 deg; a record beyond
this is corrupt or rescaled (1e300-scaled records overflowed the discrepancy comparison's
spectra, and a window's fit, into a LinAlgError). Such a move is set aside with the reason
(:func:`~galvo_sysid.ident.screen.screen_moves`, the discrepancy workflow's moves), the others
are used."""

TRAVEL_FACTOR = 10.0
"""The moves' median encoder travel may be this many times larger or smaller than their target
angle: beyond, the encoder is in other units (radians are 57.3 times smaller, counts far
larger), not a plant that moved differently (a closed loop reaches its target whatever the
plant)."""

Records = tuple['NDArray[np.float64]', 'NDArray[np.float64]']


def travels(encoder: NDArray[np.float64]) -> NDArray[np.float64]:
    """Each move's travel [deg]: the mean of its record's last sixteenth minus its first
    sample, (M,) of records (M, N)."""  # noqa: D205, D209
    tail = max(1, encoder.shape[-1] // 16)
    return np.asarray(encoder[..., -tail:].mean(axis=-1) - encoder[..., 0], dtype=np.float64)


def check_travel(encoder: NDArray[np.float64], target_angle: float) -> None:
    """Refuse a window whose moves do not travel their target angle.

    Raises:
        InvalidDataError: The target angle is 0 or beyond :data:`MAX_ANGLE`; the moves travel
            against it (its sign is wrong); or their median travel is more than
            :data:`TRAVEL_FACTOR` times off it (the encoder in radians or counts, or the
            current and encoder topics swapped): one line, saying which.
    """
    if target_angle == 0:
        raise InvalidDataError('target angle 0 deg: a move needs a non-zero target angle')
    if not abs(target_angle) <= MAX_ANGLE:
        raise InvalidDataError(f'target angle {target_angle:.6g} deg is beyond '
                               f'+-{MAX_ANGLE:g} deg: not a move of a galvano scanner')
    travel = float(np.median(travels(encoder)))
    ratio = travel / target_angle
    if ratio < -0.5:
        raise InvalidDataError(
            f'the moves travel {travel:+.4g} deg against their target angle '
            f'{target_angle:+g} deg: moves that go back need a negative target angle (or '
            f'are the current and encoder topics swapped?)')
    if not 1.0 / TRAVEL_FACTOR <= ratio <= TRAVEL_FACTOR:
        raise InvalidDataError(
            f'the encoder travels {ratio:.4g} times the target angle {target_angle:+g} deg '
            f'(median over the moves): is the encoder in degrees (radians are 57.3 times '
            f'smaller), and are the current and encoder topics the right way round?')


def validate_records(current: ArrayLike, encoder: ArrayLike, *, na: int = 15, nb: int = 15,
                     min_records: int = MIN_RECORDS,
                     min_angle_span: float = MIN_ANGLE_SPAN) -> Records:
    """Check a window of records and return them as float arrays of shape (M, N).

    Args:
        current: Current records [A], shape (M, N).
        encoder: Encoder records [deg], shape (M, N), raw (start angle not yet removed).
        na: ARX denominator order the data are meant for (sets the shortest record).
        nb: ARX numerator order.
        min_records: Fewest records accepted (>= 2).
        min_angle_span: Smallest peak-to-peak angle [deg] of the averaged record (start angle
            removed) that counts as excitation.

    Returns:
        ``(current, encoder)`` as float64 arrays, unchanged values.

    Raises:
        InvalidDataError: Wrong shapes, too few or too short records (fewer than
            :func:`galvo_sysid.ident.arx.min_data_length` samples), NaN/Inf, or no excitation
            (averaged encoder span below ``min_angle_span`` or a current that is identically
            zero).
    """
    if min_records < MIN_RECORDS:
        raise ConfigurationError(f'min_records must be >= {MIN_RECORDS}, got {min_records}')
    try:
        cur = np.asarray(current, dtype=float)
        enc = np.asarray(encoder, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InvalidDataError(f'records are not numeric arrays: {exc}') from exc
    if cur.ndim != 2 or enc.ndim != 2:
        raise InvalidDataError(f'current and encoder must be 2-D (M records, N samples), got '
                               f'shapes {cur.shape} and {enc.shape}')
    if cur.shape != enc.shape:
        raise InvalidDataError(f'current and encoder shapes differ: {cur.shape} vs {enc.shape}')
    m, n = cur.shape
    if m < min_records:
        raise InvalidDataError(f'need at least {min_records} records, got {m}')
    need = min_data_length(na, nb)
    if n < need:
        raise InvalidDataError(f'records have {n} samples; ARX({na}, {nb}) needs at least {need}')
    for name, arr in (('current', cur), ('encoder', enc)):
        if not np.all(np.isfinite(arr)):
            bad = np.argwhere(~np.isfinite(arr))[0]
            raise InvalidDataError(f'{name} contains NaN or Inf (first at record {bad[0]}, '
                                   f'sample {bad[1]})')
    if not np.any(cur):
        raise InvalidDataError('no excitation: the current is identically zero')
    span = float(np.ptp(np.mean(enc - enc[:, :1], axis=0)))
    if span < min_angle_span:
        raise InvalidDataError(f'no excitation: the averaged move spans {span:.3g} deg '
                               f'(< {min_angle_span:.3g} deg); zero-angle moves?')
    return cur, enc


def remove_start_angle(encoder: ArrayLike) -> NDArray[np.float64]:
    """Subtract each record's first sample (its start angle, at rest) from the record."""
    enc = np.asarray(encoder, dtype=float)
    if enc.ndim < 1 or enc.shape[-1] == 0:
        raise InvalidDataError('encoder records must hold at least one sample')
    return np.asarray(enc - enc[..., :1], dtype=float)


def average_records(current: ArrayLike, encoder: ArrayLike) -> Records:
    """Method A: the sample-wise average of the records (start angles removed).

    Args:
        current: Current records (M, N).
        encoder: Encoder records (M, N), raw.

    Returns:
        ``(u, y)``, each shape (N,).
    """
    cur = np.asarray(current, dtype=float)
    enc = remove_start_angle(encoder)
    if cur.ndim != 2 or cur.shape != enc.shape:
        raise InvalidDataError('current and encoder must both be (M, N)')
    return np.mean(cur, axis=0), np.mean(enc, axis=0)


def concatenate_records(current: ArrayLike, encoder: ArrayLike) -> Records:
    """Method B: the records in series, outputs offset to make the concatenation continuous.

    Record i's output (start angle removed) is offset by the sum of the end angles of records
    0 .. i-1, so it starts where the previous record ended (the paper adds (i-1) Psi, the
    nominal rotation; the measured end angles make it exactly continuous).

    Args:
        current: Current records (M, N).
        encoder: Encoder records (M, N), raw.

    Returns:
        ``(u, y)``, each shape (M N,).
    """
    cur = np.asarray(current, dtype=float)
    enc = remove_start_angle(encoder)
    if cur.ndim != 2 or cur.shape != enc.shape:
        raise InvalidDataError('current and encoder must both be (M, N)')
    ends = enc[:, -1]
    offsets = np.concatenate([[0.0], np.cumsum(ends[:-1])])
    return cur.reshape(-1).copy(), (enc + offsets[:, None]).reshape(-1)


def preprocess(current: ArrayLike, encoder: ArrayLike, *, method: str = 'A', na: int = 15,
               nb: int = 15, min_angle_span: float = MIN_ANGLE_SPAN) -> Records:
    """Validate a window and apply method ``'A'`` (average) or ``'B'`` (concatenation).

    Args:
        current: Current records [A], (M, N).
        encoder: Encoder records [deg], (M, N), raw.
        method: ``'A'`` or ``'B'``.
        na: ARX denominator order (for the length check).
        nb: ARX numerator order.
        min_angle_span: See :func:`validate_records`.

    Returns:
        ``(u, y)`` ready for the ARX fit.
    """
    if method not in ('A', 'B'):
        raise ConfigurationError(f"method must be 'A' or 'B', got {method!r}")
    cur, enc = validate_records(current, encoder, na=na, nb=nb, min_angle_span=min_angle_span)
    if method == 'A':
        return average_records(cur, enc)
    return concatenate_records(cur, enc)
