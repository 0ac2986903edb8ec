"""Tests of benchmarks/efficiency.py: its family of conditions and its arithmetic (no fits)."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import pytest

from galvo_sysid.model import PAPER_MODEL, PSI

_PATH = Path(__file__).resolve().parents[2] / 'benchmarks' / 'efficiency.py'
_SPEC = importlib.util.spec_from_file_location('benchmark_efficiency', _PATH)
assert _SPEC is not None
assert _SPEC.loader is not None
eff = importlib.util.module_from_spec(_SPEC)
sys.modules['benchmark_efficiency'] = eff
_SPEC.loader.exec_module(eff)


def _window(errors: dict[str, float], bounds: dict[str, float], z: dict[str, float],
            resolved: tuple[bool, ...] = (True,)):
    return eff.Window(errors=errors, bounds=bounds, z=z, reported=bounds, resolved=resolved,
                      seconds=0.0, excitation=math.nan)


def test_the_family_builds_by_its_rules() -> None:
    family = eff.conditions((2,))
    names = [c.name for c in family]
    assert len(names) == len(set(names)) == 12
    assert names[0] == 'default'
    assert names[-1] == 'scanner-2'
    by_name = {c.name: c for c in family}
    weak = by_name['weak'].config
    assert (weak.profile.shape, weak.profile.min_duration) == ('minimum-jerk', pytest.approx(
        80 * PAPER_MODEL.sample_period))
    assert by_name['weak+dither'].config.dither.amplitude == 0.01
    assert by_name['weak+dither'].config.dither.frequencies == (
        PAPER_MODEL.modal.natural_frequencies[2],)
    assert by_name['no-notch-600Hz'].config.controller.notch_frequencies == ()
    step = by_name['default'].config.encoder_resolution
    assert by_name['encoder-3step'].config.measurement_noise_std == pytest.approx(3 * step)
    assert all(c.angle == PSI for c in family[:-1])
    assert by_name['scanner-2'].truth is by_name['scanner-2'].config.plant
    # every condition has a stable controller and a move that fits (describe designs both)
    assert 'samples' in eff.describe(by_name['no-notch-600Hz'])


def test_the_family_alone_is_its_scanners_in_order() -> None:
    family = eff.conditions((5, 2), family_only=True)
    assert [c.name for c in family] == ['scanner-5', 'scanner-2']
    assert family == eff.conditions((5, 2))[-2:]


def test_parameter_stats_arithmetic() -> None:
    # errors +-1, +-3 (relative), bound 2 everywhere, reported std 1 (z = error)
    wins = [_window({'k0': e, 'k1': e}, {'k0': 2.0, 'k1': 2.0}, {'k0': e, 'k1': e},
                    resolved=(r,))
            for e, r in ((1.0, True), (-1.0, True), (3.0, False), (-3.0, True))]
    s = eff.parameter_stats('k0', wins)
    assert s.median_error == 2.0
    assert s.limit == pytest.approx(1.25 * 0.674 * 2)
    assert s.efficiency == pytest.approx(math.sqrt(5) / 2)
    assert s.bias == 0.0
    assert s.worst == 1.5
    assert s.calibration == pytest.approx(math.sqrt(5))
    assert s.reported == 1.0
    assert (s.resolved, s.counted) == (4, True)
    assert s.failures() == ['median', 'calibration']
    k1 = eff.parameter_stats('k1', wins)      # mode 1 unresolved in one window
    assert (k1.resolved, k1.counted, k1.failures()) == (3, False, [])
    assert k1.calibration == pytest.approx(math.sqrt((1 + 1 + 9) / 3))
    # every figure over the windows that resolve the mode: the +3 of the unresolved window
    # (a noise fit) is in none of them
    assert k1.efficiency == pytest.approx(math.sqrt((1 + 1 + 9) / 3) / 2)
    assert k1.bias == pytest.approx((1 - 1 - 3) / 3 / 2)
    assert (k1.median_error, k1.worst) == (1.0, 1.5)
    # and over every window, the noise fit of the unresolved one included
    assert k1.efficiency_all == pytest.approx(math.sqrt((1 + 1 + 9 + 9) / 4) / 2)
    assert s.efficiency_all == pytest.approx(s.efficiency)  # resolved everywhere: the same
    assert not k1.partial  # 3 windows resolve it: too few to summarise
    assert not s.partial  # resolved in every window: counted
    many = eff.parameter_stats('k1', wins * 4)
    assert (many.resolved, many.windows, many.partial) == (12, 16, True)
    none = eff.parameter_stats('k1', [w for w in wins if not w.resolved[0]])
    assert none.resolved == 0
    assert math.isnan(none.efficiency)
    assert math.isnan(none.calibration)


def test_the_partial_modes_line_names_those_outside_the_must_show() -> None:
    def stats(name: str, efficiency: float, calibration: float) -> eff.Stats:
        return eff.Stats(name=name, resolved=14, windows=400, median_error=0.1, limit=0.1,
                         efficiency=efficiency, bias=0.0, worst=2.0, calibration=calibration,
                         reported=1.0)

    line = eff.partial_summary([('a', stats('k3', 2.2, 1.0)), ('b', stats('omega_3', 1.1, 0.7)),
                                ('b', stats('zeta_3', 1.0, 1.0))])
    assert 'efficiency 1-2.2, calibration 0.7-1' in line
    assert 'a k3 (14/400) eff 2.2;' in line
    assert 'b omega_3 (14/400) calib 0.7' in line
    assert 'zeta_3' not in line
    fine = eff.partial_summary([('b', stats('zeta_3', 1.0, 1.0))])
    assert fine.endswith('all within the must-show')


def test_an_efficient_estimator_passes() -> None:
    s = eff.parameter_stats('k0', [_window({'k0': e}, {'k0': 1.0}, {'k0': e})
                                   for e in (0.5, -0.6, 1.2, -1.3, 0.1, 1.0)])
    assert s.failures() == []


def test_the_false_fail_rate_falls_with_the_seeds() -> None:
    few, many = eff.false_fail_rate(6, draws=4000), eff.false_fail_rate(60, draws=4000)
    assert 0.3 < few < 0.9
    assert many < few / 3


def test_the_estimated_bound_is_scored_against_the_true_one() -> None:
    # crlb/b: the median of the estimated bound over the yardstick, per parameter
    wins = [eff.Window(errors={'k0': 0.0}, bounds={'k0': 1.0}, z={'k0': 0.0},
                       reported={'k0': 1.0}, resolved=(), seconds=0.0, excitation=math.nan,
                       estimated={'k0': r}) for r in (0.8, 0.9, 1.3)]
    assert eff.parameter_stats('k0', wins).estimated == pytest.approx(0.9)
    assert math.isnan(eff.parameter_stats('k0', [_window({'k0': 0.0}, {'k0': 1.0},
                                                         {'k0': 0.0})]).estimated)


def test_scored_divides_the_estimated_bound_by_the_true_one() -> None:
    from galvo_sysid.ident.result import result_from_vectors
    truth = PAPER_MODEL.modal
    names = list(truth.parameters())
    res = result_from_vectors(truth.parameters(), dict.fromkeys(names, 1.0), n_modes=3,
                              target_angle=PSI, moves=100, input_delay=0.0,
                              lag_time_constant=0.0, fit_percent=100.0, method='refined',
                              resolved=(True, True, True))
    exact = dict.fromkeys(names, 2.0)
    win = eff.scored(res, exact, truth, seconds=0.0, estimated=dict.fromkeys(names, 1.0))
    assert win.estimated == dict.fromkeys(names, 0.5)
    assert win.bounds['k0'] == pytest.approx(2.0 / truth.k0)
    assert eff.scored(res, exact, truth, seconds=0.0).estimated == {}
