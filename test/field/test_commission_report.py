"""The commissioning report and figure (galvo_sysid.field.commission) of a rigid body alone."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from galvo_sysid.field.commission import (
    BagCommissioning,
    commission_figure,
    format_commissioning,
)
from galvo_sysid.ident.commission import commission
from galvo_sysid.sim.family import random_scanner
from galvo_sysid.sim.simulator import GalvoSimulator


def test_a_model_without_modes_is_reported_with_the_reason_and_plotted() -> None:
    """random_scanner(44) with its modes looked for below 15 kHz, where it has none (its two
    are at 22 and 27 kHz): the report says there is no resonant mode, why, and what would
    excite one; the JSON and the Bode figure are made all the same."""
    scanner = random_scanner(44)
    moves = list(GalvoSimulator(config=scanner.config, seed=44).moves(
        angles=list(scanner.angles), moves_per_angle=200))
    windows = []
    for angle in scanner.angles:
        for sign in (1.0, -1.0):
            ms = [m for m in moves if m.target_angle == sign * angle]
            windows.append((np.array([m.current for m in ms]),
                            np.array([m.encoder for m in ms])))
    result = commission(windows, sample_period=scanner.model.sample_period,
                        search=(2 * np.pi * 300.0, 2 * np.pi * 15e3))
    found = BagCommissioning(bag=Path('scanner44.mcap'), result=result, set_aside=(),
                             rejected=0, seconds=1.0)
    text = format_commissioning(found, out='scanner44.yaml')
    assert 'model: 0 resonant mode(s)' in text
    assert 'no resonant mode found' in text
    assert result.steps[-1].note  # why no mode was added, said in the report
    assert result.steps[-1].note in text
    assert 'dither' in text
    assert json.loads(json.dumps(found.to_dict()))['model']['mechanics']['modes'] == []
    figure = commission_figure(found)
    assert figure.axes
