"""Offline identification of bags: the same objects as the nodes, in the same order."""

from __future__ import annotations

from pathlib import Path

import pytest

from galvo_sysid.bagio import BagReader, SetAside
from galvo_sysid.drift import DriftMonitor
from galvo_sysid.errors import ConfigurationError
from galvo_sysid.offline import identify_bag
from galvo_sysid.online import fit_window
from galvo_sysid.pairing import MoveWindower
from galvo_sysid.simtools import simulate_bag


@pytest.fixture(scope='module')
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp('offline') / 'bag'
    simulate_bag(path, angles=[0.3, 0.9], moves_per_angle=200, seed=12)
    return path


def test_same_as_the_node_objects_by_hand(bag: Path) -> None:
    found = identify_bag(bag)
    # the sysid node's path, spelled out: MoveWindower -> fit_window -> DriftMonitor
    windower = MoveWindower(window_size=100)
    monitor = DriftMonitor()
    expected = []
    with BagReader(bag) as reader:
        for half in reader.move_halves():
            assert not isinstance(half, SetAside)
            for window in windower.add(half):
                result = fit_window(window, method='refined', options={'na': 15, 'nb': 15})
                expected.append((window.index, result, monitor.assess(
                    result, window_index=window.index)))
    assert [w.window_index for w in found.windows] == [i for i, _, _ in expected]
    for w, (_, result, verdict) in zip(found.windows, expected, strict=True):
        assert w.result == result
        assert w.drift == verdict


def test_parallel_fits_give_identical_results(bag: Path) -> None:
    one = identify_bag(bag, jobs=1)
    two = identify_bag(bag, jobs=2)
    assert one.to_dict() == two.to_dict()
    assert len(one.windows) == 4


def test_partial_windows_and_progress(bag: Path) -> None:
    calls: list[tuple[int, int]] = []
    found = identify_bag(bag, window_size=150, progress=lambda d, t: calls.append((d, t)))
    assert calls[-1] == (800, 800)
    assert len(calls) == 800
    # 100 moves per signed angle: no complete window of 150, four partial ones (>= 75)
    assert [w.partial for w in found.windows] == [True] * 4
    assert [w.result.moves for w in found.windows] == [100] * 4
    too_strict = identify_bag(bag, window_size=150, min_partial=101)
    assert too_strict.windows == ()
    assert too_strict.pooled is None
    assert len(too_strict.rejected) == 400
    assert 'incomplete at end' in too_strict.rejected[0]['reason']


def test_paper_method(bag: Path) -> None:
    found = identify_bag(bag, method='paper-A')
    assert {w.result.method for w in found.windows} == {'paper-A'}
    assert found.pooled is not None
    assert found.pooled.method == 'paper-A'


@pytest.mark.parametrize(('kwargs', 'match'), [
    ({'method': 'fancy'}, 'unknown method'),
    ({'min_partial': 1}, 'min_partial'),
    ({'jobs': 0}, 'jobs'),
])
def test_bad_settings(bag: Path, kwargs: dict, match: str) -> None:
    with pytest.raises(ConfigurationError, match=match):
        identify_bag(bag, **kwargs)
