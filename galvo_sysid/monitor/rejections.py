"""Moves set aside: one :class:`Rejection` per move, and the lines that say them grouped.

:class:`~galvo_sysid.monitor.pairing.MoveWindower` issues a rejection for every move it
cannot use (once per move); :func:`summarize_rejections` turns a batch of them into one
readable line per reason, what the sysid node logs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Iterable

__all__ = ['Rejection', 'summarize_rejections']


@dataclass(frozen=True)
class Rejection:
    """A move set aside, reported once.

    Attributes:
        move_id: The move's id.
        target_angle: Its signed target angle [deg] (NaN if unknown).
        stamp: Its stamp [s] (NaN if unknown).
        reason: Short human-readable reason, e.g. ``'NaN in encoder'``.
    """

    move_id: int
    target_angle: float
    stamp: float
    reason: str


def summarize_rejections(rejections: Iterable[Rejection], *, max_ids: int = 5) -> list[str]:
    """Group rejections by reason into one readable line per reason.

    Example: ``'3 moves set aside (ids 4, 9, 12; 0.3 deg): NaN in encoder'``.
    """
    groups: dict[str, list[Rejection]] = {}
    for r in rejections:
        groups.setdefault(r.reason, []).append(r)
    lines = []
    for reason, rs in groups.items():
        ids = ', '.join(str(r.move_id) for r in rs[:max_ids])
        if len(rs) > max_ids:
            ids += f', ... {rs[-1].move_id}'
        angles = sorted({r.target_angle for r in rs if math.isfinite(r.target_angle)})
        where = ''
        if len(angles) == 1:
            where = f'; {angles[0]:g} deg'
        elif angles:
            where = f'; {len(angles)} angles'
        noun = 'move' if len(rs) == 1 else 'moves'
        label = 'id' if len(rs) == 1 else 'ids'
        lines.append(f'{len(rs)} {noun} set aside ({label} {ids}{where}): {reason}')
    return lines
