"""The commissioning report and figure (galvo_sysid.field.commission) of a rigid body alone."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from galvo_sysid.field.commission import (
    BagCommissioning,
    commission_figure,
    format_commissioning,
)
from galvo_sysid.ident.commission import commission
from galvo_sysid.ident.measured import LagSearch
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
    # had the current been measured: the lag found, and how to identify with it
    lag = LagSearch(lag=7e-6, steps=((0.0, 4e-6), (7e-6, 7e-6)), converged=True)
    measured = replace(found, result=replace(result, measured_lag=lag))
    text = format_commissioning(measured, out='scanner44.yaml')
    t = scanner.model.sample_period
    assert (f'measured current: amplifier lag 7 us ({7e-6 / t:.3g} T), found in 2 fits'
            in text)
    assert 'galvo-sysid identify BAG --model MODEL --measured-current 7e-06' in text
    out = json.loads(json.dumps(measured.to_dict()))
    assert out['measured_current_lag'] == 7e-6
    assert out['lag_search'] == [{'assumed': 0.0, 'fitted': 4e-6},
                                 {'assumed': 7e-6, 'fitted': 7e-6}]
    assert found.to_dict()['measured_current_lag'] is None
