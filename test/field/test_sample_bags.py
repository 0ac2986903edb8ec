"""The sample bags in bags/ hold what the README says they hold."""

from __future__ import annotations

from pathlib import Path

import pytest

from galvo_sysid.field.offline import identify_bag
from galvo_sysid.model import REFERENCE_MODEL

BAGS = Path(__file__).resolve().parents[2] / 'bags'


def test_sample_bags_are_small() -> None:
    for name in ('nominal', 'drifting'):
        size = sum(p.stat().st_size for p in (BAGS / name).iterdir())
        assert size < 4e6, f'{name}: {size / 1e6:.1f} MB'


def test_nominal_bag_identifies_the_reference_plant() -> None:
    found = identify_bag(BAGS / 'nominal')
    assert [w.target_angle for w in found.windows] == [0.3, -0.3, 1.5, -1.5]
    assert all(w.result.moves == 100 and not w.partial for w in found.windows)
    assert [w.drift.level_name for w in found.windows] == ['OK'] * 4
    assert found.rejected == ()
    assert found.pooled is not None
    pooled = found.pooled.model.parameters()
    truth = REFERENCE_MODEL.parameters()
    for name, rel in (('k0', 0.005), ('k1', 0.03), ('k2', 0.03), ('omega_1', 0.001),
                      ('omega_2', 0.001), ('zeta_1', 0.05), ('zeta_2', 0.05)):
        assert pooled[name] == pytest.approx(truth[name], rel=rel), name


def test_drifting_bag_is_flagged_on_omega_1() -> None:
    found = identify_bag(BAGS / 'drifting')
    assert len(found.windows) == 6
    j = found.windows[0].drift.names.index('omega_1')
    deviation = [w.drift.relative_deviation[j] for w in found.windows]
    # omega_1 falls 1.5 % over the bag: each pair of windows lower than the one before
    assert deviation[0] > deviation[2] > deviation[4]
    assert deviation[1] > deviation[3] > deviation[5]
    assert deviation[-1] == pytest.approx(-0.0125, abs=0.002)
    assert found.windows[0].drift.level_name == 'OK'
    assert found.windows[-1].drift.level_name == 'ERROR'
    assert 'omega_1' in found.windows[-1].drift.flagged
