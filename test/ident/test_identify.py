"""The identification entry point: methods compared, the result type, pooling, typed errors."""

from __future__ import annotations

import ast
import json
import math
import re
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from openloop_data import open_loop_window

from galvo_sysid.errors import (
    ConfigurationError,
    IdentificationError,
    InvalidDataError,
    ModelMismatchError,
)
from galvo_sysid.ident.identify import identify_joint, identify_window
from galvo_sysid.ident.paper import paper_pipeline
from galvo_sysid.ident.pool import pool_results
from galvo_sysid.ident.result import IdentificationResult
from galvo_sysid.model import (
    PAPER_MODEL,
    PSI,
    REFERENCE_MODEL,
    TAU,
    ModalModel,
    relative_errors,
)
from galvo_sysid.sim.simulator import simulate_window

FIELDS = ('target_angle', 'moves', 'input_delay', 'lag_time_constant', 'k0', 'residues',
          'natural_frequencies', 'damping_ratios', 'k0_std', 'residues_std',
          'natural_frequencies_std', 'damping_ratios_std', 'fit_percent', 'method',
          'resolved', 'set_aside', 'crlb_std')


def test_refined_beats_the_paper_pipeline(windows_1psi: list) -> None:
    # Closed-loop data at 1 psi, 8 noise seeds: the refined fit's median |relative error| is
    # below the paper pipeline's (method A, 1.6 T delay) for every parameter but k0, where
    # both are at the noise limit (~0.005 %, 20x below the target) and may only tie.
    paper, refined = [], []
    for cur, enc in windows_1psi:
        paper.append(relative_errors(identify_window(
            cur, enc, sample_period=TAU, method='paper-A', jackknife_groups=0).model))
        refined.append(relative_errors(identify_window(cur, enc, sample_period=TAU).model))
    for name in REFERENCE_MODEL.parameters():
        p = np.abs([e[name] for e in paper])
        r = np.abs([e[name] for e in refined])
        if name == 'k0':
            assert np.sqrt(np.mean(r**2)) < 1.5 * np.sqrt(np.mean(p**2))
            assert np.median(r) < 1e-3
        else:
            assert np.median(r) < np.median(p), name
    # the paper's qualitative failures, gone: k2 about -20 % from the pure-delay assumption
    assert np.median([e['k2'] for e in paper]) < -0.15
    assert abs(np.median([e['k2'] for e in refined])) < 0.015


def _accuracy_targets() -> dict[str, float]:
    """``TARGET_WINDOW`` of benchmarks/accuracy.py (the README's targets, one place)."""
    path = Path(__file__).resolve().parents[2] / 'benchmarks' / 'accuracy.py'
    tree = ast.parse(path.read_text())
    for node in tree.body:
        if (isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Name)
                and node.targets[0].id == 'TARGET_WINDOW'):
            return {str(k): float(v) for k, v in ast.literal_eval(node.value).items()}
    raise AssertionError('TARGET_WINDOW not found in benchmarks/accuracy.py')


def test_refined_meets_every_single_window_target_at_1_psi(windows_1psi: list) -> None:
    # README "Accuracy": the refined fit meets issue 3's target (median |error| % of single
    # windows of 100 moves at 1 psi) for all ten parameters; accuracy.py prints it over 30
    # windows, these 8 hold it with a margin of 2.3-24x (k2 2.3x, zeta_3 2.7x, k3 2.9x).
    # The paper pipeline misses k1, k2, k3 and zeta_3 here.
    targets = _accuracy_targets()
    assert set(targets) == set(REFERENCE_MODEL.parameters())
    errors = [relative_errors(identify_window(cur, enc, sample_period=TAU).model)
              for cur, enc in windows_1psi]
    for name, target in targets.items():
        median = 100 * float(np.median(np.abs([e[name] for e in errors])))
        assert median < target, (name, median, target)


def test_result_fields_and_serialisation(windows_1psi: list) -> None:
    cur, enc = windows_1psi[0]
    res = identify_window(cur, enc, sample_period=TAU)
    assert res.method == 'refined'
    assert res.moves == 100
    assert res.target_angle == pytest.approx(PSI, abs=2e-3)
    assert res.lag_time_constant == pytest.approx(0.6 * TAU, rel=0.1)
    assert res.input_delay == pytest.approx(TAU + res.lag_time_constant)
    assert 80 < res.fit_percent < 100
    assert res.model.n_modes == 3
    std = res.std_by_name()
    assert list(std) == list(REFERENCE_MODEL.parameters())
    assert all(math.isfinite(v) and v > 0 for v in std.values())
    d = res.to_dict()
    assert tuple(d) == FIELDS
    assert json.loads(json.dumps(d))['residues'] == list(res.residues)
    given = identify_window(cur, enc, sample_period=TAU, target_angle=0.25)
    assert given.target_angle == 0.25


@pytest.mark.parametrize(('angle', 'words'), [
    (-0.3, 'travel +0.3 deg against their target angle -0.3 deg'),
    (0.3 * 57.3, 'travels 0.01745 times the target angle'),   # an encoder in radians
    (0.3 / 57.3, 'travels 57.31 times the target angle'),
    (1e300, 'beyond +-90 deg'),
    (0.0, 'target angle 0 deg: a move needs a non-zero target angle'),
])
def test_a_target_angle_the_moves_do_not_travel_is_refused_in_words(
        windows_1psi: list, angle: float, words: str) -> None:
    """The moves of a closed loop travel their target angle whatever the plant: a window whose
    encoder travels otherwise has its units, its sign or its topics wrong, and is refused as
    such (it was identified, and judged a 98 % drift of k0)."""
    cur, enc = windows_1psi[0]
    with pytest.raises(InvalidDataError, match=re.escape(words)):
        identify_window(cur, enc, sample_period=TAU, target_angle=angle)


def test_paper_methods(windows_1psi: list) -> None:
    cur, enc = windows_1psi[1]
    res = identify_window(cur, enc, sample_period=TAU, method='paper-A')
    assert res.method == 'paper-A'
    assert res.lag_time_constant == 0.0
    assert res.input_delay == pytest.approx(1.6 * TAU)
    assert all(math.isfinite(v) and v > 0 for v in res.std_by_name().values())
    # jackknife std of the well-determined parameters is of the size of their error scatter
    assert res.std_by_name()['omega_1'] < 1e-3 * REFERENCE_MODEL.natural_frequencies[0]
    no_std = identify_window(cur, enc, sample_period=TAU, method='paper-A', jackknife_groups=0)
    assert math.isnan(no_std.k0_std)
    assert no_std.k0 == res.k0


CALIBRATION_WINDOWS = 36
"""Windows of the std calibration test (about 0.1 s each)."""

CALIBRATION_RMS = (0.86, 1.16)
"""Bounds of the pooled rms(error / reported std) of CALIBRATION_WINDOWS windows.

The claim (README, Uncertainty): the std are calibrated, rms(error/std) 0.92-1.08 over 114
windows. For calibrated std, rms^2 = chi^2_n / n with n the effective number of independent
z: the 10 parameters of one window are correlated (n = 7.0 per window measured over 200
windows, from their correlation matrix: 10^2 / sum(rho_ij^2)), so n = 250 here, and ln(rms)
has a standard deviation of 1 / sqrt(2 n) = 0.045. The bounds are 1 / 1.16 .. 1.16, 3.3 of
those each side of 1; all std 1.34 times too large (rms 0.75) or 0.75 times too small
(rms 1.33) fall 3.3 beyond them. Measured on 2 x 200 windows: 0.986 and 1.026."""

CALIBRATION_RMS_EACH = (0.66, 1.5)
"""Bounds of each parameter's rms over the same windows: chi^2 with 36 degrees of freedom,
ln(rms) standard deviation 1 / sqrt(72) = 0.118, 3.5 of those each side of 1."""


def test_reported_std_is_calibrated_over_many_windows() -> None:
    """rms(error / reported std) of identify_window's refined fit over 36 independent windows
    of 100 open-loop moves at 1 psi (the paper's scanner, coloured current and encoder noise,
    quantisation): near 1 within the chi-square bounds of CALIBRATION_RMS, pooled over the 10
    modal parameters, and each parameter within CALIBRATION_RMS_EACH."""
    truth = REFERENCE_MODEL.parameters()
    moves = 100
    cur, enc = open_loop_window(PSI, moves=moves * CALIBRATION_WINDOWS, seed=1616)
    z = []
    for w in range(CALIBRATION_WINDOWS):
        rows = slice(w * moves, (w + 1) * moves)
        res = identify_window(cur[rows], enc[rows], sample_period=TAU, target_angle=PSI)
        assert all(res.resolved)
        est, std = res.model.parameters(), res.std_by_name()
        z.append([(est[n] - truth[n]) / std[n] for n in truth])
    assert_calibrated(np.array(z), list(truth))


def assert_calibrated(z: np.ndarray, names: list[str]) -> None:
    """z (windows, parameters) of CALIBRATION_WINDOWS windows: the pooled rms within
    CALIBRATION_RMS, each parameter's within CALIBRATION_RMS_EACH."""
    rms = float(np.sqrt(np.mean(z**2)))
    assert CALIBRATION_RMS[0] < rms < CALIBRATION_RMS[1], rms
    each = dict(zip(names, np.sqrt(np.mean(z**2, axis=0)), strict=True))
    lo, hi = CALIBRATION_RMS_EACH
    assert all(lo < r < hi for r in each.values()), each


def test_pool_is_sharper_than_a_window() -> None:
    results = [identify_window(*simulate_window(a * PSI, moves=100, seed=40 + i),
                               sample_period=TAU)
               for i, a in enumerate((0.5, 1.0, 2.0, 4.0, 8.0))]
    pooled = pool_results(results)
    assert math.isnan(pooled.target_angle)
    assert pooled.moves == 500
    assert pooled.method == 'refined'
    for name in ('k0', 'k1', 'k2', 'omega_1', 'omega_2', 'zeta_1', 'zeta_2'):
        single = min(r.std_by_name()[name] for r in results)
        assert pooled.std_by_name()[name] < single, name
        truth = REFERENCE_MODEL.parameters()[name]
        assert abs(pooled.model.parameters()[name] - truth) < 4 * pooled.std_by_name()[name]
    same = pool_results(results[:1] * 3)
    assert same.target_angle == results[0].target_angle


def test_pool_rejects_a_locked_on_outlier() -> None:
    base = identify_window(*simulate_window(PSI, moves=100, seed=3), sample_period=TAU)
    good = [replace(base, natural_frequencies=(*base.natural_frequencies[:2], 1.674e5 + d),
                    natural_frequencies_std=(*base.natural_frequencies_std[:2], 60.0))
            for d in (-40.0, -10.0, 0.0, 20.0, 50.0)]
    bad = replace(base, natural_frequencies=(*base.natural_frequencies[:2], 1.98e5),
                  natural_frequencies_std=(*base.natural_frequencies_std[:2], 5.0))
    pooled = pool_results([*good, bad])
    assert pooled.natural_frequencies[2] == pytest.approx(1.674e5, abs=100)
    kept = pool_results([*good, bad], reject=0)
    assert kept.natural_frequencies[2] > 1.69e5


def test_joint_fit_resolves_the_weak_mode() -> None:
    windows = [simulate_window(a * PSI, moves=100, seed=60 + i)
               for i, a in enumerate((0.5, 1.0, 2.0, 4.0, 6.0, 8.0))]
    singles = [identify_window(c, e, sample_period=TAU) for c, e in windows]
    pooled = pool_results(singles)
    joint = identify_joint(windows, sample_period=TAU, initial=pooled)
    assert joint.moves == 600
    assert joint.method == 'refined'
    std = joint.std_by_name()
    assert std['k3'] < 0.12 * abs(REFERENCE_MODEL.residues[2])
    assert std['k3'] < min(r.std_by_name()['k3'] for r in singles)
    errors = relative_errors(joint.model)
    for name, value in joint.model.parameters().items():
        truth = REFERENCE_MODEL.parameters()[name]
        assert abs(value - truth) < 4 * std[name], (name, errors[name])
    # started from the pooled results as they are (what identify_bag does): the same optimum
    quick = identify_joint(windows, sample_period=TAU, initial=pooled,
                           keep_initial_damping=True)
    for name, value in quick.model.parameters().items():
        assert abs(value - joint.model.parameters()[name]) < 0.2 * std[name], name
    assert quick.std_by_name()['k3'] == pytest.approx(std['k3'], rel=0.05)


def test_bad_input_raises_typed_errors(windows_1psi: list) -> None:
    cur, enc = windows_1psi[0]
    bad = enc.copy()
    bad[3, 100] = np.inf
    # a move with Inf is set aside by the screening (issue 12: no other data lost) ...
    assert identify_window(cur, bad, sample_period=TAU).set_aside == (
        (3, 'move has NaN or Inf samples'),)
    # ... and refused without it
    with pytest.raises(InvalidDataError, match='NaN or Inf'):
        identify_window(cur, bad, sample_period=TAU, screen_limit=0)
    with pytest.raises(InvalidDataError, match='shapes differ'):
        identify_window(cur[:, :-1], enc, sample_period=TAU)
    with pytest.raises(InvalidDataError, match='at least'):
        identify_window(cur[:1], enc[:1], sample_period=TAU)
    with pytest.raises(InvalidDataError, match='samples'):
        identify_window(cur[:, :40], enc[:, :40], sample_period=TAU)
    with pytest.raises(InvalidDataError, match='2-D'):
        identify_window(cur[0], enc[0], sample_period=TAU)
    zero_cur, zero_enc = simulate_window(0.0, moves=10, seed=0)
    with pytest.raises(InvalidDataError, match='excitation'):
        identify_window(zero_cur, zero_enc, sample_period=TAU)
    with pytest.raises(ConfigurationError, match='method'):
        identify_window(cur, enc, sample_period=TAU, method='magic')
    with pytest.raises(ConfigurationError, match='unknown options'):
        identify_window(cur, enc, sample_period=TAU, whiten=3)
    with pytest.raises(ConfigurationError):
        identify_window(cur, enc, sample_period=0.0)
    with pytest.raises(ConfigurationError, match='bands'):
        identify_window(cur, enc, sample_period=TAU, n_modes=2)
    with pytest.raises(InvalidDataError):
        pool_results([])
    res = identify_window(cur, enc, sample_period=TAU)
    with pytest.raises(InvalidDataError, match='methods'):
        pool_results([res, replace(res, method='paper-A')])
    with pytest.raises(InvalidDataError):
        identify_joint([], sample_period=TAU)


def test_band_without_a_mode_raises_identification_error(windows_1psi: list) -> None:
    cur, enc = windows_1psi[2]
    bands = ((5.5e4, 9.2e4), (1.3e5, 1.6e5), (1.7e5, 2.1e5))  # mode 2 is at 1.193e5
    for method in ('refined', 'paper-A'):
        with pytest.raises(IdentificationError):
            identify_window(cur, enc, sample_period=TAU, method=method, bands=bands)


def test_result_model_round_trip() -> None:
    model = ModalModel(k0=1.0, residues=(2.0,), natural_frequencies=(3.0,),
                       damping_ratios=(0.1,))
    res = IdentificationResult(
        target_angle=float('nan'), moves=1, input_delay=0.0, lag_time_constant=0.0, k0=1.0,
        residues=(2.0,), natural_frequencies=(3.0,), damping_ratios=(0.1,), k0_std=0.1,
        residues_std=(0.2,), natural_frequencies_std=(0.3,), damping_ratios_std=(0.01,),
        fit_percent=float('nan'), method='refined')
    assert res.model == model
    assert res.to_dict()['target_angle'] is None
    assert res.std_by_name() == {'k0': 0.1, 'k1': 0.2, 'omega_1': 0.3, 'zeta_1': 0.01}


# -- what the mutation run of tools/mutate.py found untested (docs/mutation.md) -------------

def test_paper_std_is_the_delete_a_group_jackknife(windows_1psi: list) -> None:
    """The paper methods' std: sqrt((k - 1) / k sum (theta_j - mean)^2) over the k fits that
    leave one group of moves out (move i in group i mod k), here k = 3 on 9 moves."""
    cur, enc = (a[:9] for a in windows_1psi[1])
    res = identify_window(cur, enc, sample_period=TAU, method='paper-A', jackknife_groups=3)
    assert res.set_aside == ()
    labels = np.arange(9) % 3
    fits = np.array([list(paper_pipeline(
        cur[labels != j], enc[labels != j], sample_period=TAU, method='A',
        delay=PAPER_MODEL.equivalent_delay, bands=PAPER_MODEL.mode_bands(),
        reference=PAPER_MODEL.modal).model.parameters().values()) for j in range(3)])
    expected = np.sqrt(2 / 3 * np.sum((fits - fits.mean(axis=0)) ** 2, axis=0))
    got = np.array(list(res.std_by_name().values()))
    np.testing.assert_allclose(got, expected, rtol=1e-9)


def test_options_are_those_of_the_method(windows_1psi: list) -> None:
    """The refined fit's options are accepted by method 'refined' only."""
    cur, enc = windows_1psi[2]
    with pytest.raises(ConfigurationError, match='unknown options'):
        identify_window(cur, enc, sample_period=TAU, method='paper-A', scan_points=4)
    res = identify_window(cur[:20], enc[:20], sample_period=TAU, scan_points=4,
                          whiten_order=16, estimate_lag=False)
    assert res.lag_time_constant == PAPER_MODEL.dynamics.lag_time_constant


def test_joint_fit_of_another_mode_count_needs_bands(windows_1psi: list) -> None:
    with pytest.raises(ConfigurationError, match='pass bands'):
        identify_joint(windows_1psi[:2], sample_period=TAU, n_modes=2)


@pytest.mark.parametrize('samples', [2, 74])
def test_records_shorter_than_arx_15_15_needs_are_refused_saying_so(windows_1psi: list,
                                                                     samples: int) -> None:
    """ARX(15, 15) needs 15 + 2 (15 + 15) = 75 samples; shorter records are refused by the
    validation, which says why (records too short to be screened are passed on to it)."""
    cur, enc = (a[:6, :samples] for a in windows_1psi[0])
    with pytest.raises(InvalidDataError, match=r'ARX\(15, 15\) needs at least 75'):
        identify_window(cur, enc, sample_period=TAU)


def test_records_of_75_samples_are_fitted(windows_1psi: list) -> None:
    cur, enc = (a[:6, :75] for a in windows_1psi[0])
    assert identify_window(cur, enc, sample_period=TAU).model.n_modes == 3


def test_joint_fit_of_another_mode_count_with_bands(windows_1psi: list) -> None:
    bands = PAPER_MODEL.mode_bands()[:2]
    windows = [(c[:20], e[:20]) for c, e in windows_1psi[:2]]
    joint = identify_joint(windows, sample_period=TAU, n_modes=2, bands=bands)
    assert joint.model.n_modes == 2
    assert joint.moves == 40


def test_joint_fit_starts_from_the_reference_when_no_window_fits_alone(
        windows_1psi: list, monkeypatch: pytest.MonkeyPatch) -> None:
    def fails(*args: object, **kwargs: object) -> IdentificationResult:
        raise IdentificationError('no single-window fit')

    monkeypatch.setattr('galvo_sysid.ident.identify.identify_window', fails)
    windows = [(c[:20], e[:20]) for c, e in windows_1psi[:2]]
    joint = identify_joint(windows, sample_period=TAU)
    assert joint.model.n_modes == 3
    assert joint.moves == 40


def test_a_model_of_the_rigid_body_alone_does_not_pass_a_scanner_with_resonances(
        windows_1psi: list) -> None:
    """Without bands the residual's check had no interval and a model with no modes fitted
    the paper's scanner at 28 % with a warning at most; the whole spectrum is one interval."""
    cur, enc = windows_1psi[0]
    rigid = replace(PAPER_MODEL, modal=ModalModel(k0=PAPER_MODEL.modal.k0, residues=(),
                                                  natural_frequencies=(), damping_ratios=()))
    with pytest.raises(ModelMismatchError, match=r'the residual between .* times the noise'):
        identify_window(cur, enc, sample_period=TAU, model=rigid, target_angle=PSI)


def test_a_joint_fit_with_its_scans_shared_out_is_the_same_fit(
        windows_1psi: list, monkeypatch: pytest.MonkeyPatch) -> None:
    """``map_windows`` (identify_bag gives it fork_map): every scan goes through it here and
    the fit is the same, bit for bit (the sums are made in window order either way)."""
    import galvo_sysid.ident.refine.joint as joint_module
    from galvo_sysid.field.jobs import fork_map

    monkeypatch.setattr(joint_module, 'MAP_SCAN_SIZE', 1)
    windows = windows_1psi[:3]
    sizes: list[int] = []

    def mapper(fn: Any, items: Any) -> Any:
        sizes.append(len(items))
        return fork_map(fn, items)

    plain = identify_joint(windows, sample_period=TAU, initial=PAPER_MODEL.modal)
    shared = identify_joint(windows, sample_period=TAU, initial=PAPER_MODEL.modal,
                            map_windows=mapper)
    assert sizes
    assert set(sizes) == {3}
    assert shared.to_dict() == plain.to_dict()
    assert shared.std_by_name() == plain.std_by_name()
