"""Drift verdicts against the reference model (galvo_sysid.monitor.drift)."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace

import numpy as np
import pytest

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model import REFERENCE_MODEL, ModalModel
from galvo_sysid.monitor.drift import DriftMonitor, _Point, _weighted_line
from galvo_sysid.monitor.parameters import WATCHDOG_PARAMETERS
from galvo_sysid.monitor.tolerances import (
    DEFAULT_KIND_TOLERANCES,
    DEFAULT_NOISE_FLOOR,
    DEFAULT_TOLERANCES,
    parameter_names,
)
from galvo_sysid.monitor.verdict import (
    ERROR,
    MISMATCH,
    OK,
    STALE,
    STATUS_FAILED,
    STATUS_MISMATCH,
    STATUS_NAMES,
    WARN,
)

NAMES = parameter_names(3)


@dataclass(frozen=True)
class FakeResult:
    target_angle: float
    k0: float
    residues: tuple[float, ...]
    natural_frequencies: tuple[float, ...]
    damping_ratios: tuple[float, ...]
    k0_std: float
    residues_std: tuple[float, ...]
    natural_frequencies_std: tuple[float, ...]
    damping_ratios_std: tuple[float, ...]
    fit_percent: float = 99.9
    resolved: tuple[bool, ...] = ()


def result(rel: dict[str, float] | None = None, *, rel_std: float | dict[str, float] = 1e-4,
           fit: float = 99.9, angle: float = 0.3) -> FakeResult:
    """A result whose parameters deviate from Table I by ``rel`` (relative)."""
    ref = REFERENCE_MODEL.parameters()
    rel = rel or {}
    v = {n: ref[n] * (1 + rel.get(n, 0.0)) for n in NAMES}
    s = {n: abs(ref[n]) * (rel_std if isinstance(rel_std, float) else rel_std.get(n, 1e-4))
         for n in NAMES}
    return FakeResult(
        target_angle=angle, k0=v['k0'], residues=(v['k1'], v['k2'], v['k3']),
        natural_frequencies=(v['omega_1'], v['omega_2'], v['omega_3']),
        damping_ratios=(v['zeta_1'], v['zeta_2'], v['zeta_3']), k0_std=s['k0'],
        residues_std=(s['k1'], s['k2'], s['k3']),
        natural_frequencies_std=(s['omega_1'], s['omega_2'], s['omega_3']),
        damping_ratios_std=(s['zeta_1'], s['zeta_2'], s['zeta_3']), fit_percent=fit)


def test_reference_itself_is_ok() -> None:
    v = DriftMonitor().assess(result(), window_index=4)
    assert v.level == OK
    assert v.window_index == 4
    assert v.names == NAMES
    assert v.relative_deviation == pytest.approx([0.0] * 10, abs=1e-12)
    assert v.tolerance == tuple(DEFAULT_TOLERANCES[n] for n in NAMES)
    assert v.message.startswith('OK')
    assert v.flagged == ()


def test_deviation_beyond_tolerance_is_error() -> None:
    v = DriftMonitor().assess(result({'omega_1': -0.02}), window_index=0)
    assert v.level == ERROR
    assert v.flagged == ('omega_1',)
    assert v.relative_deviation[NAMES.index('omega_1')] == pytest.approx(-0.02)
    assert 'omega_1 -2.00 %' in v.message


def test_deviation_past_warn_fraction_is_warn() -> None:
    v = DriftMonitor().assess(result({'k2': 0.06}), window_index=0)
    assert v.level == WARN
    assert v.flagged == ('k2',)


def test_deviation_inside_the_estimates_own_noise_is_not_drift() -> None:
    # 2 % off, but identified with a 1 % standard deviation: within 3 sigma
    v = DriftMonitor().assess(result({'omega_1': 0.02}, rel_std={'omega_1': 0.01}),
                              window_index=0)
    assert v.level == OK
    # the same deviation identified precisely is drift
    v = DriftMonitor().assess(result({'omega_1': 0.02}, rel_std={'omega_1': 0.001}),
                              window_index=0)
    assert v.level == ERROR


def test_zeta3_has_a_wide_tolerance() -> None:
    assert DEFAULT_TOLERANCES['zeta_3'] >= 10 * DEFAULT_TOLERANCES['zeta_1'] / 3
    v = DriftMonitor().assess(result({'zeta_3': 0.4}), window_index=0)
    assert v.level == OK


def test_custom_tolerances_and_reference() -> None:
    assert DriftMonitor().assess(result({'k0': 0.01}), window_index=0).level == OK
    mon = DriftMonitor(tolerances={'k0': 0.005})
    assert mon.assess(result({'k0': 0.01}), window_index=0).level == ERROR
    with pytest.raises(ConfigurationError, match='unknown'):
        DriftMonitor(tolerances={'omega_9': 0.1})
    with pytest.raises(ConfigurationError, match='> 0'):
        DriftMonitor(tolerances={'k1': 0.0})
    with pytest.raises(ConfigurationError):
        DriftMonitor(warn_fraction=1.5)
    with pytest.raises(ConfigurationError):
        DriftMonitor(trend_windows=4, trend_min_windows=5)


def drifting_sequence(rate: float, windows: int, seed: int = 0) -> list[FakeResult]:
    """omega_1 moving ``rate`` (relative) per window; the parameters scatter as measured on
    the simulator (the noise floors are 1.5 times that), reported std alike."""
    rng = np.random.default_rng(seed)
    scatter = {n: DEFAULT_NOISE_FLOOR[n] / 1.5 for n in NAMES}
    out = []
    for i in range(windows):
        rel = {n: rng.normal(0, scatter[n]) for n in NAMES}
        rel['omega_1'] += rate * (i + 1)
        angle = 0.03 * (1 + i % 19) * (1 if i % 2 == 0 else -1)
        out.append(result(rel, rel_std=scatter, angle=angle))
    return out


@pytest.mark.parametrize('warn_fraction', [0.5, 0.95])
@pytest.mark.parametrize('seed', range(5))
def test_drift_building_up_is_flagged_before_the_tolerance_is_crossed(
        seed: int, warn_fraction: float) -> None:
    # with warn_fraction 0.95 only the trend test can speak before the tolerance is crossed
    mon = DriftMonitor(warn_fraction=warn_fraction)
    tol = DEFAULT_TOLERANCES['omega_1']
    first_flag = None
    for i, r in enumerate(drifting_sequence(-0.002, 8, seed)):
        v = mon.assess(r, window_index=i)
        dev = v.relative_deviation[NAMES.index('omega_1')]
        if 'omega_1' in v.flagged and first_flag is None:
            first_flag = i
            assert abs(dev) < tol, 'flagged only once the tolerance was crossed'
            assert v.level == WARN
            if warn_fraction > 0.9:
                assert 'omega_1 drifting' in v.message
            assert v.trend_per_window[NAMES.index('omega_1')] == pytest.approx(-0.002, rel=0.5)
    assert first_flag is not None
    assert first_flag <= 3  # 0.2 % per window against a 1 % tolerance


def test_healthy_plant_raises_no_trend_alarm() -> None:
    mon = DriftMonitor()
    levels = [mon.assess(r, window_index=i).level
              for i, r in enumerate(drifting_sequence(0.0, 300, seed=11))]
    assert levels.count(OK) >= 298
    assert ERROR not in levels


def test_angle_dependent_bias_is_not_a_trend() -> None:
    # k0 identified exactly at small angles and up to 0.45 tolerance low at large ones, the
    # angles swept in order: a saw-tooth in the deviation, not a drift
    mon = DriftMonitor()
    flagged = []
    for i in range(60):
        frac = (i % 10) / 9
        bias = -0.45 * DEFAULT_TOLERANCES['k0'] * frac
        v = mon.assess(result({'k0': bias}, rel_std=0.003), window_index=i)
        flagged += list(v.flagged)
    assert 'k0' not in flagged


def test_poor_fit_warns_and_stays_out_of_the_trend() -> None:
    mon = DriftMonitor(min_fit_percent=95.0)
    v = mon.assess(result(fit=60.0), window_index=0)
    assert v.level == WARN
    assert 'poor fit' in v.message
    assert all(math.isnan(x) for x in v.trend_per_window)


def test_wrong_mode_count_is_a_mismatch_and_nan_an_error_verdict() -> None:
    r = result()
    two = FakeResult(r.target_angle, r.k0, r.residues[:2], r.natural_frequencies[:2],
                     r.damping_ratios[:2], r.k0_std, r.residues_std[:2],
                     r.natural_frequencies_std[:2], r.damping_ratios_std[:2])
    v = DriftMonitor().assess(two, window_index=1)
    assert v.level == MISMATCH
    assert v.level_name == 'MISMATCH'
    assert 'do not match the reference model' in v.message
    assert '2 resonant mode(s), the reference 3' in v.message
    assert v.flagged == ()  # no parameter is said to drift
    bad = FakeResult(r.target_angle, math.nan, *[getattr(r, f) for f in (
        'residues', 'natural_frequencies', 'damping_ratios', 'k0_std', 'residues_std',
        'natural_frequencies_std', 'damping_ratios_std')])
    assert DriftMonitor().assess(bad, window_index=2).level == ERROR


@pytest.mark.parametrize('scale', [1e-3, 0.05, 20.0])
def test_a_gain_off_by_more_than_ten_times_is_another_scanner_or_unit_not_drift(
        scale: float) -> None:
    """A current in mA (k0 1000 times too small) was judged an ERROR drift of -99.9 %; ten
    times and more either way is a MISMATCH that names units; five times is still drift."""
    ref = REFERENCE_MODEL.parameters()
    rel = {n: scale - 1.0 for n in ('k0', 'k1', 'k2', 'k3')}
    v = DriftMonitor().assess(result(rel), window_index=0)
    assert v.level == MISMATCH
    assert f"k0 is {scale:.3g} times the reference's" in v.message
    assert 'mA are 1000 times A' in v.message
    assert v.flagged == ()
    five = DriftMonitor().assess(result({'k0': 4.0}), window_index=1)
    assert five.level == ERROR
    assert five.relative_deviation[NAMES.index('k0')] == pytest.approx(4.0)
    assert ref['k0'] > 0


def test_stale_and_json() -> None:
    mon = DriftMonitor()
    s = mon.stale(window_index=3, age=12.5)
    assert s.level == STALE
    assert s.level_name == 'STALE'
    assert '12.5 s' in s.message
    d = mon.assess(result({'omega_2': 0.03}), window_index=9).to_dict()
    text = json.dumps(d, allow_nan=False)
    back = json.loads(text)
    assert back['level'] == 'ERROR'
    assert back['deviations']['omega_2'] == pytest.approx(0.03)
    assert back['tolerances']['zeta_3'] == DEFAULT_TOLERANCES['zeta_3']
    json.dumps(s.to_dict(), allow_nan=False)


def test_a_step_and_its_recovery_are_no_trend_and_a_later_drift_still_is() -> None:
    # the demo's sequence: healthy, omega_1 steps -2 % (ERROR), back to nominal, then drifting
    mon = DriftMonitor(warn_fraction=0.95)
    seq = drifting_sequence(0.0, 30, seed=4)
    deviations = [0.0] * 6 + [-0.02] * 6 + [0.0] * 4 + [-0.002 * k for k in range(1, 15)]
    first_trend = None
    for i, (r, d) in enumerate(zip(seq, deviations, strict=True)):
        w = r.natural_frequencies
        r = FakeResult(r.target_angle, r.k0, r.residues, (w[0] * (1 + d), *w[1:]),
                       *[getattr(r, f) for f in ('damping_ratios', 'k0_std', 'residues_std',
                                                 'natural_frequencies_std',
                                                 'damping_ratios_std')])
        v = mon.assess(r, window_index=i)
        if 6 <= i < 12:
            assert v.level == ERROR
        elif i < 16:
            assert v.level == OK, (i, v.message)  # no trend faked by the step's recovery
        elif first_trend is None and 'omega_1 drifting' in v.message:
            first_trend = i
    assert first_trend is not None
    assert abs(deviations[first_trend]) < DEFAULT_TOLERANCES['omega_1']


def modes_model(n: int) -> ModalModel:
    return ModalModel(k0=2e6, residues=tuple(1e5 * (i + 1) for i in range(n)),
                      natural_frequencies=tuple(2e4 * (i + 1) for i in range(n)),
                      damping_ratios=(0.01,) * n)


def test_tolerance_rule_with_a_five_mode_model() -> None:
    """Own entry, else the kind's, else the built-in per-name default (modes 1-3), else the
    built-in kind default: any number of modes works."""
    from galvo_sysid.monitor.reference import monitor_from_parameters

    ref = modes_model(5)
    plain = DriftMonitor(reference=ref)
    assert plain.names == parameter_names(5)
    for n in ('k0', 'k1', 'omega_2', 'zeta_3', 'k3'):
        assert plain.tolerances[n] == DEFAULT_TOLERANCES[n]  # the paper's, as before
    for i in (4, 5):
        assert plain.tolerances[f'k{i}'] == DEFAULT_KIND_TOLERANCES['k']
        assert plain.tolerances[f'omega_{i}'] == DEFAULT_KIND_TOLERANCES['omega']
        assert plain.tolerances[f'zeta_{i}'] == DEFAULT_KIND_TOLERANCES['zeta']
    mon = DriftMonitor(reference=ref, tolerances={'omega': 0.004, 'omega_5': 0.03, 'k': 0.2,
                                                  'k0': 0.05})
    assert [mon.tolerances[f'omega_{i}'] for i in range(1, 6)] == [0.004] * 4 + [0.03]
    assert [mon.tolerances[f'k{i}'] for i in range(1, 6)] == [0.2] * 5
    assert mon.tolerances['k0'] == 0.05
    assert mon.tolerances['zeta_5'] == DEFAULT_KIND_TOLERANCES['zeta']
    with pytest.raises(ConfigurationError, match='unknown'):
        DriftMonitor(reference=ref, tolerances={'omega_6': 0.1})
    # the same rule through the parameters (None: not set, as a node parameter left unset)
    from galvo_sysid.model import PAPER_MODEL

    model = PAPER_MODEL.with_modal(ref)
    values = {'tolerances.omega': 0.004, 'tolerances.omega_5': 0.03, 'tolerances.zeta': None}
    via = monitor_from_parameters(values, model=model)
    assert via.tolerances == {**plain.tolerances, **{f'omega_{i}': 0.004 for i in range(1, 5)},
                              'omega_5': 0.03}
    # judged with them: omega_5 off by 1 % is well within its own 3 %, omega_4 by 1 % is
    # beyond the kind's 0.4 %
    r = FakeResult(0.3, ref.k0, ref.residues,
                   (*ref.natural_frequencies[:3], ref.natural_frequencies[3] * 1.01,
                    ref.natural_frequencies[4] * 1.01), ref.damping_ratios, 1.0, (1.0,) * 5,
                   (1.0,) * 5, (1e-6,) * 5)
    v = via.assess(r, window_index=0)
    assert v.level == ERROR
    assert v.flagged == ('omega_4',)


def test_unresolved_modes_are_not_judged() -> None:
    r = result({'k3': 3.0, 'omega_3': -0.5, 'zeta_3': 500.0})  # mode 3: noise, far off
    judged = DriftMonitor().assess(r, window_index=0)
    assert judged.level == ERROR
    unresolved = FakeResult(*[getattr(r, f) for f in (
        'target_angle', 'k0', 'residues', 'natural_frequencies', 'damping_ratios', 'k0_std',
        'residues_std', 'natural_frequencies_std', 'damping_ratios_std', 'fit_percent')],
        resolved=(True, True, False))
    mon = DriftMonitor()
    v = mon.assess(unresolved, window_index=0)
    assert v.level == OK, v.message
    assert 'mode 3 unresolved' in v.message
    assert 'k3' not in v.message
    assert v.flagged == ()
    for n in ('k3', 'omega_3', 'zeta_3'):
        assert math.isnan(v.relative_deviation[NAMES.index(n)])
    assert v.relative_deviation[NAMES.index('omega_1')] == pytest.approx(0.0, abs=1e-12)
    # a resolved mode is still judged next to an unresolved one
    r2 = result({'omega_1': -0.02, 'omega_3': -0.5})
    off = FakeResult(*[getattr(r2, f) for f in (
        'target_angle', 'k0', 'residues', 'natural_frequencies', 'damping_ratios', 'k0_std',
        'residues_std', 'natural_frequencies_std', 'damping_ratios_std', 'fit_percent')],
        resolved=(True, True, False))
    v = mon.assess(off, window_index=1)
    assert v.level == ERROR
    assert v.flagged == ('omega_1',)
    assert v.message.endswith('mode 3 unresolved (not judged)')
    json.dumps(v.to_dict(), allow_nan=False)


def test_a_result_that_did_not_match_the_model_is_a_mismatch_never_drift() -> None:
    mon = DriftMonitor(reference_name='scanner7.yaml')
    nan = FakeResult(0.3, math.nan, (math.nan,) * 3, (math.nan,) * 3, (math.nan,) * 3,
                     math.nan, (math.nan,) * 3, (math.nan,) * 3, (math.nan,) * 3, math.nan)
    why = ('the data do not match model scanner7.yaml: no physical mode 2 in the band '
           '5e4..9e4 rad/s; run galvo-sysid commission')
    v = mon.assess(nan, window_index=3, status=STATUS_MISMATCH, status_message=why)
    assert v.level == MISMATCH
    assert v.message.startswith('MISMATCH: the data do not match the reference model '
                                'scanner7.yaml')
    assert 'no physical mode 2 in the band' in v.message
    assert 'drift' in v.message
    assert v.flagged == ()
    assert all(math.isnan(d) for d in v.relative_deviation)
    # even with finite parameters: the status decides, and the trend history stays clean
    ok = result({'omega_1': -0.05})
    v = mon.assess(ok, window_index=4, status=STATUS_MISMATCH, status_message='another scanner')
    assert v.level == MISMATCH
    assert 'omega_1' not in v.message
    assert mon.assess(result(), window_index=5).level == OK
    failed = mon.assess(nan, window_index=6, status=STATUS_FAILED,
                        status_message='singular Jacobian')
    assert failed.level == MISMATCH
    assert 'identification failed: singular Jacobian' in failed.message
    back = json.loads(json.dumps(v.to_dict(), allow_nan=False))
    assert back['level'] == 'MISMATCH'


def test_a_tolerance_tighter_than_the_data_resolve_is_said() -> None:
    # zeta_2 identified with a 10 % std against a 20 % tolerance: 3 std = 30 % > 20 %
    v = DriftMonitor().assess(result(rel_std={'zeta_2': 0.1}), window_index=0)
    assert v.level == OK
    assert v.unresolvable == ('zeta_2',)
    assert 'tolerance tighter than the data resolve (zeta_2: 3 std = 30 % > 20 %)' in v.message
    assert json.loads(json.dumps(v.to_dict()))['tolerance_unresolvable'] == ['zeta_2']
    assert DriftMonitor().assess(result(), window_index=0).unresolvable == ()


# -- what the mutation run of tools/mutate.py found untested -------------

CHECKED_OPTIONS = ('warn_fraction', 'n_sigma', 'trend_sigma', 'trend_fraction',
                   'step_fraction', 'min_fit_percent')


def test_options_are_accepted_over_their_whole_range_and_refused_beyond() -> None:
    """The monitor takes every value the watchdog's parameters allow, the ends included."""
    specs = {s.name: s for s in WATCHDOG_PARAMETERS}
    for name in CHECKED_OPTIONS:
        low, high = specs[name].low, specs[name].high
        assert low is not None
        assert high is not None
        for value in (low, high):
            DriftMonitor(**{name: float(value)})
        for value in (math.nextafter(low, -math.inf), math.nextafter(high, math.inf)):
            with pytest.raises(ConfigurationError, match=name):
                DriftMonitor(**{name: value})


def test_a_status_the_monitor_does_not_know_is_a_mismatch_naming_it() -> None:
    for status in (len(STATUS_NAMES), 200, -1):
        v = DriftMonitor().assess(result(), window_index=0, status=status)
        assert v.level == MISMATCH
        assert f'identification status {status}' in v.message


def test_a_fit_exactly_at_min_fit_percent_is_good() -> None:
    mon = DriftMonitor(min_fit_percent=90.0)
    assert mon.assess(result(fit=90.0), window_index=0).level == OK
    v = mon.assess(result(fit=math.nextafter(90.0, 0.0)), window_index=1)
    assert v.level == WARN
    assert 'poor fit' in v.message


def test_poor_fit_windows_never_enter_the_trend_history() -> None:
    """A drift seen only in poorly fitting windows is no trend, and good windows after them
    start from an empty history: the first slope needs three good windows."""
    mon = DriftMonitor(min_fit_percent=95.0, warn_fraction=0.95)
    i_omega = NAMES.index('omega_1')
    for i in range(6):
        v = mon.assess(result({'omega_1': -0.001 * (i + 1)}, fit=60.0), window_index=i)
        assert 'drifting' not in v.message
        assert all(math.isnan(x) for x in v.trend_per_window)
    for i in range(6, 9):
        v = mon.assess(result({'omega_1': -0.001 * (i + 1)}), window_index=i)
        assert math.isnan(v.trend_per_window[i_omega]) == (i < 8), i


def test_an_unresolved_mode_does_not_stop_the_trend_test_of_the_others() -> None:
    """As test_drift_building_up_is_flagged_before_the_tolerance_is_crossed, with mode 3
    unresolved in every window: omega_1's drift is still flagged, by the trend test."""
    for seed in range(5):
        mon = DriftMonitor(warn_fraction=0.95)
        first = None
        for i, r in enumerate(drifting_sequence(-0.002, 8, seed)):
            v = mon.assess(replace(r, resolved=(True, True, False)), window_index=i)
            if 'omega_1 drifting' in v.message:
                first = i
                break
        assert first is not None, seed
        assert first <= 3, seed


@pytest.mark.parametrize('min_windows', [3, 5])
def test_the_trend_test_speaks_once_it_has_trend_min_windows(min_windows: int) -> None:
    """A clean drift of 0.15 % per window (1 % tolerance, warnings from 95 % of it only):
    flagged as drifting at the trend_min_windows-th window, not a window later."""
    mon = DriftMonitor(warn_fraction=0.95, trend_min_windows=min_windows)
    first = None
    for i in range(8):
        v = mon.assess(result({'omega_1': -0.0015 * (i + 1)}), window_index=i)
        if 'omega_1 drifting' in v.message:
            first = i
            break
    assert first == min_windows - 1


@pytest.mark.parametrize('scatter', [0.1, 3.0])
@pytest.mark.parametrize('sigma_scale', [1e-3, 5.0])
def test_the_trend_line_is_weighted_least_squares_with_its_standard_error(
        scatter: float, sigma_scale: float) -> None:
    """_weighted_line against numpy's weighted polyfit: slope, value at the last window and
    the slope's standard error from the sigmas, widened by the residual scatter where that is
    larger than they explain (scatter 3) and not narrowed where smaller (scatter 0.1)."""
    rng = np.random.default_rng(16)
    n = 6
    x = np.arange(4, 4 + n, dtype=float)
    sigma = sigma_scale * rng.uniform(0.5, 2.0, n)
    d = 0.01 * x + scatter * sigma * rng.standard_normal(n)
    fitted = _weighted_line([_Point(int(xi), float(di), float(si))
                             for xi, di, si in zip(x, d, sigma, strict=True)])
    assert fitted is not None
    slope, se, now = fitted
    coef, cov = np.polyfit(x, d, 1, w=1 / sigma, cov='unscaled')
    chi2 = float(np.sum(((d - np.polyval(coef, x)) / sigma) ** 2)) / (n - 2)
    assert (chi2 > 1) == (scatter > 1)
    assert slope == pytest.approx(coef[0], rel=1e-9)
    assert se == pytest.approx(math.sqrt(max(1.0, chi2) * cov[0, 0]), rel=1e-9)
    assert now == pytest.approx(np.polyval(coef, x[-1]), rel=1e-9)
