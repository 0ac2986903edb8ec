"""The identification plot: measured response against the models, trends over time."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from matplotlib.colors import to_rgba

from galvo_sysid.errors import InvalidDataError
from galvo_sysid.field.offline import identify_bag
from galvo_sysid.field.plots import LEVEL_COLORS, bode_data, identification_figure
from galvo_sysid.field.results import BagIdentification

DRIFTING = Path(__file__).resolve().parents[2] / 'bags' / 'drifting'


@pytest.fixture(scope='module')
def drifting() -> BagIdentification:
    return identify_bag(DRIFTING, jobs=1, response_windows=4)


def _axes(fig: object, ylabel: str) -> list[object]:
    return [ax for ax in fig.axes if ax.get_ylabel() == ylabel]  # type: ignore[attr-defined]


def test_the_measured_response_is_drawn_on_the_models_basis(
        drifting: BagIdentification) -> None:
    resp = drifting.response
    assert resp is not None
    f = resp.omega / (2 * np.pi)
    assert drifting.pooled is not None
    assert drifting.dynamics is not None
    mag, phase = bode_data(drifting.pooled.model, f, dynamics=drifting.dynamics,
                           sample_period=drifting.sample_period)
    # where the data determine it, the measured response is the pooled model's as drawn
    # (current command to angle, input dynamics and hold included; P_mech alone would be
    # 16 us of delay, 58 deg at 10 kHz, away): median within 0.5 dB and 5 deg
    sure = (resp.coherence > 0.999) & (f > 2e3) & (f < 2e4)
    assert sure.sum() > 20
    measured = resp.response[sure]
    assert np.median(np.abs(20 * np.log10(np.abs(measured)) - mag[sure])) < 0.5
    model = np.exp(1j * np.radians(phase[sure]))
    assert np.median(np.abs(np.degrees(np.angle(measured / model)))) < 5.0
    fig = identification_figure(drifting)
    (ax_mag,) = _axes(fig, '|angle / current| [dB re 1 deg/A]')
    labels = [line.get_label() for line in ax_mag.get_lines()]  # type: ignore[attr-defined]
    assert 'measured (averaged moves)' in labels
    assert 'reference model' in labels
    (ax_coh,) = _axes(fig, 'coherence [-]')
    assert ax_coh.get_lines()  # type: ignore[attr-defined]


def test_trends_over_time_with_bands_and_unresolved_marks(drifting: BagIdentification) -> None:
    fig = identification_figure(drifting)
    by_title = {ax.get_title().split(' ')[0].rstrip(';'): ax
                for ax in fig.axes  # type: ignore[attr-defined]
                if ax.get_ylabel() == '[%]'}
    omega_1 = by_title['omega_1']
    assert by_title['zeta_3'].get_xlabel() == "time since the bag's first move [s]"
    # the drift raised ERROR on omega_1 in the last windows: drawn in the ERROR colour
    colors = {to_rgba(line.get_markeredgecolor()) for line in omega_1.get_lines()
              if line.get_marker() == 'o'}
    assert to_rgba(LEVEL_COLORS['ERROR']) in colors
    # k3 is unresolved in most windows: marked as such, not drawn as a number
    assert 'unresolved' in by_title['k3'].get_title()
    marks = [line for line in by_title['k3'].get_lines() if line.get_marker() == 'x']
    assert marks
    # the wide zeta_2 tolerance (20 %) does not flatten the points: it is said off scale
    assert 'tolerance +-20 % off scale' in by_title['zeta_2'].get_title()
    _low, high = by_title['zeta_2'].get_ylim()
    assert high < 20


def test_no_window_no_plot(drifting: BagIdentification, tmp_path: Path) -> None:
    from dataclasses import replace

    from galvo_sysid.field.plots import save_identification_plot

    empty = replace(drifting, windows=(), pooled=None)
    with pytest.raises(InvalidDataError, match='no window identified'):
        save_identification_plot(empty, tmp_path / 'p.png')
    assert not (tmp_path / 'p.png').exists()
