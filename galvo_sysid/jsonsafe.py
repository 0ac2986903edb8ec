"""Plain values for strict JSON: NaN and infinity become None (imports nothing heavy).

The results' ``to_dict`` and the ``--json`` objects of ``galvo-sysid`` go through these two,
so the output is strict JSON (``json.dump(..., allow_nan=False)`` accepts it).
"""

from __future__ import annotations

import math
from typing import Any

__all__ = ['finite_or_none', 'json_safe']


def finite_or_none(x: float) -> float | None:
    """A number for JSON: ``float(x)``, or None for NaN and infinity."""
    return float(x) if math.isfinite(x) else None


def json_safe(value: Any) -> Any:
    """Replace NaN/Inf by None (in dicts, lists and tuples too) so the output is strict JSON.

    Tuples become lists; floats are returned as they are when finite; other values are kept.
    """
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    return value
