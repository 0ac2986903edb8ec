"""Moves set aside and the lines that say them (galvo_sysid.monitor.rejections)."""

from __future__ import annotations

import math

from galvo_sysid.monitor.rejections import Rejection, summarize_rejections


def test_one_line_per_reason_with_ids_and_angles() -> None:
    rejections = [Rejection(i, 0.3 if i < 4 else -0.3, 1.0, 'NaN or Inf in encoder')
                  for i in range(7)]
    rejections.append(Rejection(9, math.nan, math.nan, 'unpaired'))
    assert summarize_rejections(rejections, max_ids=3) == [
        '7 moves set aside (ids 0, 1, 2, ... 6; 2 angles): NaN or Inf in encoder',
        '1 move set aside (id 9): unpaired']
    assert summarize_rejections([]) == []
