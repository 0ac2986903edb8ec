"""Per-move screening: a move that disagrees with its window's other moves is set aside.

The moves of a window repeat the same command, so apart from the noise they differ only by
what the plant model explains: the response to each move's own current (the controller
reacts to noise) and the free response left by the previous move (its initial conditions).
:func:`screen_moves` takes each move's deviation from the window's mean, removes both with
the scanner's model (the forced response of the current's deviation; the free responses of
the modes, the rigid body's offset and the amplifier lag, fitted per move), and compares what
is left, sample by sample, with the robust scatter of the moves (1.4826 x the median absolute
deviation over the moves). A glitch (a current spike that did not move the mirror, an encoder
jump, a corrupted or rescaled record) stands out; a move that merely started from other
initial conditions does not. A move whose largest deviation exceeds ``limit`` robust
standard deviations is set aside with its reason. With Gaussian noise the largest of a
record's N deviations rarely passes 5; the default limit of 10 keeps healthy moves, and a
glitch below it shifts the average of M moves by less than about 10 / sqrt(M) of its noise.

The per-sample scatter is at least the running median of its neighbours' (15 samples: the
MAD of a few moves scatters by about 30 % at 20 moves, and over hundreds of samples some would
come out far too small) and has a floor (a share of its median over the record, and the
encoder's quantisation step), so samples where every move reads the same count do not make the
last count of noise an outlier.

A move orders of magnitude larger than the others (a rescaled or corrupted record) is set
aside first, before it can swamp the window's mean. If more than ``max_fraction`` of the
moves would be set aside, the window is broken more widely than by single glitches: nothing
is set aside and :class:`~galvo_sysid.errors.InvalidDataError` says so. (The test looks for
local deviations; a small plant change inside a window is not what it finds.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from galvo_sysid.errors import ConfigurationError, InvalidDataError
from galvo_sysid.ident.preprocess import MAX_SAMPLE_MAGNITUDE
from galvo_sysid.ident.refine.regressors import FIRST_ROW, free_responses
from galvo_sysid.ident.refine.window import WindowProblem
from galvo_sysid.model.dynamics import split_delay

if TYPE_CHECKING:
    from numpy.typing import ArrayLike, NDArray

    from galvo_sysid.model.plant import PlantModel

__all__ = ['DEFAULT_MAX_FRACTION', 'DEFAULT_SCREEN_LIMIT', 'Screening', 'screen_moves']

DEFAULT_SCREEN_LIMIT = 10.0
"""Largest deviation of a kept move from the window's median, in robust standard deviations."""

DEFAULT_MAX_FRACTION = 0.2
"""Largest share of a window's moves that screening sets aside (more: the window is refused)."""

_MIN_MOVES = 5        # fewer moves: no robust median to screen against
_GROSS = 100.0        # a move this many times larger than the typical one is not the same move
_FLOOR_SHARE = 0.2    # the per-sample scatter is at least this share of its median
_POOL = 15            # samples whose scatter is pooled (running median) with each sample's


@dataclass(frozen=True)
class Screening:
    """Outcome of :func:`screen_moves`.

    Attributes:
        keep: Per move, whether it is kept.
        reasons: ``(move index, reason)`` of every move set aside, in move order.
    """

    keep: NDArray[np.bool_]
    reasons: tuple[tuple[int, str], ...]

    @property
    def set_aside(self) -> tuple[int, ...]:
        """Indices of the moves set aside."""
        return tuple(i for i, _ in self.reasons)


def _quantum(x: NDArray[np.float64]) -> float:
    """The smallest nonzero step between samples (an encoder's count), 0 if none."""
    steps = np.abs(np.diff(x, axis=-1)).ravel()
    steps = steps[steps > 0]
    return float(np.min(steps)) if steps.size else 0.0


def _pooled(scale: NDArray[np.float64]) -> NDArray[np.float64]:
    """Running median of the per-sample scatter over ``_POOL`` neighbouring samples."""
    half = _POOL // 2
    padded = np.pad(scale, half, mode='edge')
    windows = np.lib.stride_tricks.sliding_window_view(padded, _POOL)
    return np.asarray(np.median(windows, axis=1), dtype=np.float64)


def _worst(x: NDArray[np.float64], floor: float) -> tuple[NDArray[np.float64],
                                                           NDArray[np.intp]]:
    """Per move: largest |deviation from the per-sample median| / robust scatter, and where."""
    dev = x - np.median(x, axis=0)
    scale = 1.4826 * np.median(np.abs(dev), axis=0)
    # the MAD of a few moves scatters (about 30 % for 20 moves): over hundreds of samples some
    # come out far too small and make the last sigma of noise an outlier; pooled with its
    # neighbours (a glitch in one move barely moves either median) it stays near the truth
    scale = np.maximum(scale, _pooled(scale))
    positive = scale[scale > 0]
    typical = float(np.median(positive)) if positive.size else 0.0
    scale = np.maximum(scale, max(_FLOOR_SHARE * typical, floor, 1e-300))
    z = np.abs(dev) / scale
    where = np.argmax(z, axis=1)
    return z[np.arange(z.shape[0]), where], where


def _model_residuals(cur: NDArray[np.float64], rel: NDArray[np.float64], *,
                     model: PlantModel) -> NDArray[np.float64]:
    """Per move: filtered encoder deviation minus the model's forced and free responses."""
    ph = model.physics()
    t = model.sample_period
    modal = model.modal
    omega = np.array(modal.natural_frequencies, dtype=float)
    zeta = np.array(modal.damping_ratios, dtype=float)
    lag = float(ph.lag_time_constant)
    delay, frac = split_delay(ph.computation_delay * t + ph.dead_time, t)
    prob = WindowProblem(cur, rel, sample_period=t, delay=delay, fraction=frac,
                         n_modes=modal.n_modes)
    coef = np.array([modal.k0, *modal.residues], dtype=float)
    dev = prob.deviations(omega, zeta, lag, coef)
    n_rows = dev.shape[1]
    cols = [free_responses(omega, zeta, cur.shape[1], t).T, np.ones((n_rows, 1)),
            prob.lag_free(lag)[:, None]]
    basis = np.hstack(cols)
    scale = np.linalg.norm(basis, axis=0)
    q, _ = np.linalg.qr(basis / np.where(scale > 0, scale, 1.0))
    return np.asarray(dev - (dev @ q) @ q.T, dtype=np.float64)


def screen_moves(current: ArrayLike, encoder: ArrayLike, *, model: PlantModel,
                 limit: float = DEFAULT_SCREEN_LIMIT,
                 max_fraction: float = DEFAULT_MAX_FRACTION) -> Screening:
    """Find the moves of a window that disagree with the others (see the module docs).

    Args:
        current: Current records [A], shape (M, N).
        encoder: Encoder records [deg], shape (M, N), raw.
        model: The scanner's model (its modes, input dynamics and sample period explain
            what may differ between healthy moves).
        limit: Largest deviation of a kept move, in robust standard deviations (0: keep all
            finite moves).
        max_fraction: Largest share of the moves that may be set aside for disagreeing.

    Returns:
        Which moves are kept, and why the others are not. A move with NaN or Inf samples is
        always set aside. Windows of fewer than 5 finite moves are only checked for NaN/Inf.

    Raises:
        InvalidDataError: Not (M, N) arrays of one shape, no finite move, or more than
            ``max_fraction`` of the moves disagree with the others.
        ConfigurationError: Bad ``limit`` or ``max_fraction``.
    """
    if not (math.isfinite(limit) and limit >= 0):
        raise ConfigurationError(f'the screening limit must be finite and >= 0, got {limit}')
    if not 0 <= max_fraction < 1:
        raise ConfigurationError(f'max_fraction must be in [0, 1), got {max_fraction}')
    try:
        cur = np.asarray(current, dtype=float)
        enc = np.asarray(encoder, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InvalidDataError(f'records are not numeric arrays: {exc}') from exc
    if cur.ndim != 2 or cur.shape != enc.shape or cur.shape[1] <= FIRST_ROW:
        raise InvalidDataError(f'current and encoder must be (M, N) arrays of one shape, got '
                               f'{cur.shape} and {enc.shape}')
    m = cur.shape[0]
    finite = np.all(np.isfinite(cur), axis=1) & np.all(np.isfinite(enc), axis=1)
    reasons = {int(i): 'move has NaN or Inf samples' for i in np.flatnonzero(~finite)}
    huge = finite & ((np.max(np.abs(cur), axis=1) > MAX_SAMPLE_MAGNITUDE)
                     | (np.max(np.abs(enc), axis=1) > MAX_SAMPLE_MAGNITUDE))
    reasons.update({int(i): f'move has samples beyond +-{MAX_SAMPLE_MAGNITUDE:g} (A or deg): '
                            f'no measurement of a scanner' for i in np.flatnonzero(huge)})
    good = np.flatnonzero(finite & ~huge)
    if not good.size:
        first = next(iter(reasons.values())).removeprefix('move ')
        raise InvalidDataError(f'no move of the window is usable: the first {first}')
    if limit > 0 and good.size >= _MIN_MOVES:
        # gross first: a move orders of magnitude larger than the others (a rescaled or
        # corrupted record) would swamp the window's mean the model-based test starts from
        for name, data in (('current', cur), ('encoder', enc - enc[:, :1])):
            size = np.max(np.abs(data[good]), axis=1)
            typical = float(np.median(size))
            for j in np.flatnonzero(size > _GROSS * max(typical, 1e-300)):
                i = int(good[j])
                reasons.setdefault(i, f'{name} {size[j] / max(typical, 1e-300):.3g} times '
                                      f'larger than in the other moves')
        good = np.array([i for i in good if int(i) not in reasons], dtype=np.intp)
    if limit > 0 and good.size >= _MIN_MOVES:
        disagree: dict[int, str] = {}
        with np.errstate(over='ignore', invalid='ignore', divide='ignore'):
            rel = enc[good] - enc[good, :1]
            resid = _model_residuals(cur[good], rel, model=model)
            z, where = _worst(resid, _quantum(enc[good]))
        for j in np.flatnonzero(~(z <= limit)):
            disagree[int(good[j])] = (f'sample {int(where[j]) + FIRST_ROW} is {z[j]:.3g} '
                                      f'robust std off the other moves')
        if len(disagree) > max(1.0, max_fraction * m):
            raise InvalidDataError(
                f'{len(disagree)} of {m} moves disagree with the others (over '
                f'{max_fraction:.0%}): more than single glitches, the window is not used')
        reasons.update(disagree)
    keep = np.ones(m, dtype=bool)
    keep[list(reasons)] = False
    return Screening(keep=keep, reasons=tuple(sorted(reasons.items())))
