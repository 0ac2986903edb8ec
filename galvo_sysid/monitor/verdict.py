"""Verdict levels, result statuses, and :class:`DriftVerdict`: what the drift monitor says.

The numbers are those of the messages: the levels those of ``DriftStatus.msg`` (OK..STALE
also those of ``diagnostic_msgs/DiagnosticStatus``; MISMATCH is reported there as ERROR), the
statuses those of ``ModalParameters.msg``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from galvo_sysid.jsonsafe import finite_or_none

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = [
    'ERROR',
    'LEVEL_NAMES',
    'MISMATCH',
    'OK',
    'STALE',
    'STATUS_FAILED',
    'STATUS_MISMATCH',
    'STATUS_NAMES',
    'STATUS_OK',
    'WARN',
    'DriftVerdict',
]

OK, WARN, ERROR, STALE, MISMATCH = 0, 1, 2, 3, 4
"""Verdict levels, the same numbers as ``DriftStatus.msg`` (OK..STALE also as
``DiagnosticStatus``; MISMATCH is reported there as ERROR)."""

LEVEL_NAMES = ('OK', 'WARN', 'ERROR', 'STALE', 'MISMATCH')
"""Names of the levels, indexed by level."""

STATUS_OK, STATUS_MISMATCH, STATUS_FAILED = 0, 1, 2
"""Status of a window's result, the same numbers as ``ModalParameters.msg``: identified, the
data do not match the plant model, the fit failed."""

STATUS_NAMES = ('OK', 'MISMATCH', 'FAILED')
"""Names of the statuses, indexed by status."""


@dataclass(frozen=True)
class DriftVerdict:
    """The monitor's verdict on one window.

    Attributes:
        window_index: The window judged.
        level: 0 OK, 1 WARN, 2 ERROR, 3 STALE, 4 MISMATCH.
        names: Parameter names (k0, k1.., omega_1.., zeta_1..).
        relative_deviation: (identified - reference) / reference per parameter.
        tolerance: Relative tolerance per parameter.
        message: One human-readable line.
        relative_std: Identified standard deviation relative to the reference.
        trend_per_window: Fitted slope of the relative deviation per window (NaN until the
            trend test has enough windows).
        flagged: The parameters that raised the level.
        target_angle: Target angle of the window [deg].
        unresolvable: Judged parameters whose tolerance is tighter than the window resolves
            (``n_sigma`` of its std, with the noise floor, beyond the tolerance): a drift up
            to the tolerance cannot be told from noise there (said in the message too).
    """

    window_index: int
    level: int
    names: tuple[str, ...]
    relative_deviation: tuple[float, ...]
    tolerance: tuple[float, ...]
    message: str
    relative_std: tuple[float, ...] = ()
    trend_per_window: tuple[float, ...] = ()
    flagged: tuple[str, ...] = ()
    target_angle: float = math.nan
    unresolvable: tuple[str, ...] = ()

    @property
    def level_name(self) -> str:
        """'OK', 'WARN', 'ERROR', 'STALE' or 'MISMATCH'."""
        return LEVEL_NAMES[self.level]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form; NaN becomes None."""
        def by_name(values: Sequence[float]) -> dict[str, float | None]:
            return {n: finite_or_none(v) for n, v in zip(self.names, values, strict=False)}

        return {
            'window_index': int(self.window_index),
            'level': self.level_name,
            'message': self.message,
            'target_angle': finite_or_none(self.target_angle),
            'flagged': list(self.flagged),
            'tolerance_unresolvable': list(self.unresolvable),
            'deviations': by_name(self.relative_deviation),
            'tolerances': by_name(self.tolerance),
            'relative_std': by_name(self.relative_std),
            'trend_per_window': by_name(self.trend_per_window),
        }
