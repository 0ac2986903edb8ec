"""Strict JSON from plain values (galvo_sysid.jsonsafe)."""

from __future__ import annotations

import json
import math

import numpy as np

from galvo_sysid.jsonsafe import finite_or_none, json_safe


def test_json_safe_makes_strict_json() -> None:
    value = {'a': math.nan, 'b': [1.0, math.inf, (2, -math.inf)], 'c': 'x', 'd': None}
    assert json_safe(value) == {'a': None, 'b': [1.0, None, [2, None]], 'c': 'x', 'd': None}
    assert json.dumps(json_safe({'e': (np.float64(math.nan), True)}), allow_nan=False) == \
        '{"e": [null, true]}'


def test_finite_or_none() -> None:
    assert finite_or_none(2) == 2.0
    assert isinstance(finite_or_none(np.float32(1.5)), float)
    assert finite_or_none(math.nan) is None
    assert finite_or_none(-math.inf) is None
