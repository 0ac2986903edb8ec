"""The records of online monitoring: one half of a move, and a window of moves.

A positioning move arrives as two halves (``MoveSamples`` on ``galvo/current`` and on
``galvo/encoder``) that share a ``move_id``: each is a :class:`MoveHalf`.
:class:`~galvo_sysid.monitor.pairing.MoveWindower` pairs them and hands out a :class:`Window`
of moves of one signed target angle, what the identification averages.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from numpy.typing import ArrayLike, NDArray

    from galvo_sysid.ident.warm import WarmStart

__all__ = ['SIGNALS', 'MoveHalf', 'Window', 'too_long']

SIGNALS = ('current', 'encoder')
"""The two halves of a move."""


@dataclass(frozen=True)
class MoveHalf:
    """One ``MoveSamples`` message as plain values.

    Attributes:
        signal: ``'current'`` or ``'encoder'``.
        move_id: Shared by the two halves of one move.
        target_angle: Signed commanded rotation [deg].
        sample_period: Sampling period [s].
        stamp: Time of the first sample [s].
        data: The samples, shape (N,).
    """

    signal: str
    move_id: int
    target_angle: float
    sample_period: float
    stamp: float
    data: NDArray[np.float64]

    @classmethod
    def create(cls, signal: str, *, move_id: int, target_angle: float, sample_period: float,
               stamp: float, data: ArrayLike) -> MoveHalf:
        """Build a half from loosely typed values (``data`` is viewed as float64, not checked)."""
        arr = np.asarray(data, dtype=np.float64)
        return cls(signal=signal, move_id=int(move_id), target_angle=float(target_angle),
                   sample_period=float(sample_period), stamp=float(stamp), data=arr)


@dataclass(frozen=True)
class Window:
    """A window of moves of one signed target angle, ready to identify.

    Attributes:
        index: Running number of the windows handed out by this windower (from 0).
        target_angle: Signed commanded rotation of the moves [deg].
        sample_period: Sampling period [s].
        current: Commanded current, shape (M, N).
        encoder: Encoder angle, shape (M, N).
        move_ids: The moves' ids in arrival order.
        first_stamp: Stamp of the earliest move [s].
        last_stamp: Stamp of the latest move [s].
        partial: True when handed out by
            :meth:`~galvo_sysid.monitor.pairing.MoveWindower.flush` before it was full.
        warm_start: What its refined fit starts from (the previous window of its angle, set
            by the sysid node: :class:`~galvo_sysid.ident.warm.WarmStart`), None: afresh.
        deadline: The :func:`time.monotonic` time past which its refined fit leaves out
            what it can do without (set by the sysid node from ``fit_budget_ms`` when the
            window completes; :class:`~galvo_sysid.ident.refine.RefineOptions`), None:
            no deadline. The clock is the machine's, so it holds in the fit processes too.
    """

    index: int
    target_angle: float
    sample_period: float
    current: NDArray[np.float64]
    encoder: NDArray[np.float64]
    move_ids: tuple[int, ...]
    first_stamp: float
    last_stamp: float
    partial: bool = False
    warm_start: WarmStart | None = None
    deadline: float | None = None

    @property
    def moves(self) -> int:
        """Number of moves in the window."""
        return len(self.move_ids)

    def held(self, lag: float) -> Window:
        """This window of measured coil currents with each made into the held current that
        drives it, behind an amplifier lag of ``lag`` [s], against the encoder's samples but
        the last (:func:`galvo_sysid.ident.measured.held_current`).

        Raises:
            ConfigurationError: A bad lag.
        """  # noqa: D205
        from galvo_sysid.ident.measured import held_current  # the numerics when asked

        return replace(self, current=held_current(self.current, sample_period=self.sample_period,
                                                  lag=lag), encoder=self.encoder[:, :-1])


def too_long(signal: str, samples: int, limit: int) -> str:
    """Why a record of ``samples`` samples, over ``limit``, is refused before it is decoded
    (the sysid node and the bag reader say it alike)."""  # noqa: D205, D209
    return f'{signal} record too long ({samples} > {limit} samples), refused before decoding'
