"""The warm start: a window's refined fit started from the previous window of the same moves."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from openloop_data import open_loop_window
from test_identify import CALIBRATION_WINDOWS, assert_calibrated

import galvo_sysid.ident.identify as identify_module
from galvo_sysid.ident.identify import identify_window
from galvo_sysid.ident.refine import refine_fit
from galvo_sysid.ident.refine.joint import REUSE_LEVEL
from galvo_sysid.ident.warm import WARM_CHI2_Z, WarmStart, plausible, reference_start
from galvo_sysid.model import PAPER_MODEL, PSI, REFERENCE_MODEL, TAU
from galvo_sysid.sim.config import SimulatorConfig
from galvo_sysid.sim.simulator import simulate_window

STRONG = ('k0', 'k1', 'k2', 'omega_1', 'omega_2', 'zeta_1', 'zeta_2')
"""The paper scanner's parameters every window of 100 moves at 1 psi resolves."""


def _z(a: dict[str, float], b: dict[str, float], std: dict[str, float]) -> dict[str, float]:
    return {k: (a[k] - b[k]) / std[k] for k in STRONG}


def test_the_next_window_starts_where_the_last_ended_and_lands_at_the_same_optimum(
        windows_1psi: list, monkeypatch: pytest.MonkeyPatch) -> None:
    """Started from window 0's result, window 1's fit skips the ARX start and the scans and
    ends within 0.3 std of its own fresh fit, with the same std to 5 %."""
    first = identify_window(*windows_1psi[0], sample_period=TAU, target_angle=PSI)
    fresh = identify_window(*windows_1psi[1], sample_period=TAU, target_angle=PSI)
    start = WarmStart.from_result(first)
    assert start is not None
    assert start.noise_model is first.noise_model

    def no_search(*args: object, **kwargs: object) -> None:
        raise AssertionError('the warm start searched afresh')

    monkeypatch.setattr(identify_module, 'paper_pipeline', no_search)
    warm = identify_window(*windows_1psi[1], sample_period=TAU, target_angle=PSI,
                           warm_start=start)
    assert warm.warm_started
    assert not fresh.warm_started
    std = fresh.std_by_name()
    z = _z(warm.model.parameters(), fresh.model.parameters(), std)
    assert max(abs(v) for v in z.values()) < 0.3, z
    ratio = {k: warm.std_by_name()[k] / std[k] for k in STRONG}
    assert all(0.95 < r < 1.05 for r in ratio.values()), ratio
    assert warm.resolved[:2] == (True, True)
    assert warm == replace(warm)  # a plain result: the flag is no part of its data
    assert 'warm_started' not in warm.to_dict()


def test_a_warm_fit_the_noise_does_not_explain_is_fitted_afresh(
        windows_1psi: list, monkeypatch: pytest.MonkeyPatch) -> None:
    """Where the warm fit's cost is not plausible, the result is exactly the fresh fit's."""
    start = WarmStart.from_result(
        identify_window(*windows_1psi[0], sample_period=TAU, target_angle=PSI))
    fresh = identify_window(*windows_1psi[2], sample_period=TAU, target_angle=PSI)
    monkeypatch.setattr(identify_module, 'plausible', lambda chi2, rows: False)
    again = identify_window(*windows_1psi[2], sample_period=TAU, target_angle=PSI,
                            warm_start=start)
    assert not again.warm_started
    assert again == fresh


def test_a_plant_that_moved_is_found_from_the_old_start() -> None:
    """The scanner's first mode 3 % lower than the window the start came from (a step far
    beyond the drift between two windows): the result is still within 0.5 std of the fresh fit
    of the new window, warm or not."""
    start = WarmStart.from_result(identify_window(*simulate_window(PSI, moves=100, seed=40),
                                                  sample_period=TAU, target_angle=PSI))
    assert start is not None
    modal = PAPER_MODEL.modal
    omega = list(modal.natural_frequencies)
    omega[0] *= 0.97
    moved = replace(PAPER_MODEL, modal=replace(modal, natural_frequencies=tuple(omega)))
    cur, enc = simulate_window(PSI, moves=100, seed=41,
                               config=SimulatorConfig(plant=moved, design=PAPER_MODEL))
    fresh = identify_window(cur, enc, sample_period=TAU, target_angle=PSI)
    warm = identify_window(cur, enc, sample_period=TAU, target_angle=PSI, warm_start=start)
    z = _z(warm.model.parameters(), fresh.model.parameters(), fresh.std_by_name())
    assert max(abs(v) for v in z.values()) < 0.5, z
    assert abs(fresh.natural_frequencies[0] / omega[0] - 1) < 1e-3


def test_a_first_window_started_from_the_model_file_lands_at_its_fresh_optimum(
        windows_1psi: list, monkeypatch: pytest.MonkeyPatch) -> None:
    """A window without an earlier result (the sysid node's first of each sign, identify's
    first of each chain) starts from the model file's modes and lag: no ARX start or scan,
    within 0.3 std of its fresh fit. A scanner whose modes all drifted 5 % from its model
    file ends within 0.5 std of its fresh fit too: its unresolved third mode is moved to the
    better basin of its band (``from_model``); left at the model's frequency, as a start from
    a fit leaves it, it pulls k2 1.5 std away (seed 59; seed 40 showed it, 2.3 std, with
    the noise model before its first pass was made coarse)."""
    start = reference_start(PAPER_MODEL)
    assert (start.model, start.noise_model, start.resolved) == (PAPER_MODEL.modal, None, ())
    assert start.lag_time_constant == PAPER_MODEL.physics().lag_time_constant
    assert start.from_model
    fresh = identify_window(*windows_1psi[3], sample_period=TAU, target_angle=PSI)
    with monkeypatch.context() as patch:
        patch.setattr(identify_module, 'paper_pipeline', lambda *a, **k: 1 / 0)
        warm = identify_window(*windows_1psi[3], sample_period=TAU, target_angle=PSI,
                               warm_start=start)
    assert warm.warm_started
    z = _z(warm.model.parameters(), fresh.model.parameters(), fresh.std_by_name())
    assert max(abs(v) for v in z.values()) < 0.3, z
    assert warm.resolved == fresh.resolved

    modal = PAPER_MODEL.modal
    omega = tuple(1.05 * w for w in modal.natural_frequencies)
    drifted = replace(PAPER_MODEL, modal=replace(modal, natural_frequencies=omega))
    cur, enc = simulate_window(PSI, moves=100, seed=59,
                               config=SimulatorConfig(plant=drifted, design=PAPER_MODEL))
    fresh = identify_window(cur, enc, sample_period=TAU, target_angle=PSI)
    assert fresh.resolved == (True, True, False)
    std = fresh.std_by_name()
    for begin, most in ((start, 0.5), (replace(start, from_model=False), math.inf)):
        warm = identify_window(cur, enc, sample_period=TAU, target_angle=PSI,
                               warm_start=begin)
        assert warm.warm_started
        assert warm.resolved == fresh.resolved
        z = _z(warm.model.parameters(), fresh.model.parameters(), std)
        worst = max(abs(v) for v in z.values())
        assert worst < most, z
    assert worst > 1.0, z  # without from_model


def test_the_noise_model_is_reused_rescaled_or_estimated_anew(windows_1psi: list) -> None:
    """The previous window's noise model is used with its level rescaled to these moves; a
    window with twice the encoder noise gets a model of its own."""
    initial = PAPER_MODEL.modal
    first = refine_fit(*windows_1psi[0], sample_period=TAU, initial=initial)
    model = first.noise_models[0]
    assert model is not None
    same = refine_fit(*windows_1psi[1], sample_period=TAU, initial=initial, noise_model=model)
    reused = same.noise_models[0]
    assert reused is not None
    assert reused.autocovariance == model.autocovariance
    assert reused.variance != model.variance
    assert 1 / REUSE_LEVEL < reused.variance / model.variance < REUSE_LEVEL
    own = refine_fit(*windows_1psi[1], sample_period=TAU, initial=initial).noise_models[0]
    assert own is not None
    assert abs(reused.variance * reused.autocovariance[0]
               / (own.variance * own.autocovariance[0]) - 1) < 0.05

    noisy = SimulatorConfig(measurement_noise_std=2 * SimulatorConfig().measurement_noise_std)
    cur, enc = simulate_window(PSI, moves=100, seed=1, config=noisy)
    louder = refine_fit(cur, enc, sample_period=TAU, initial=initial, noise_model=model)
    fresh = louder.noise_models[0]
    assert fresh is not None
    assert fresh.autocovariance != model.autocovariance


def test_warm_started_windows_in_a_row_stay_calibrated() -> None:
    """rms(error / reported std) over CALIBRATION_WINDOWS windows of 100 open-loop moves,
    each started from the previous one's result (the sysid node's chain): within the same
    bounds as the fresh fits' (``test_identify.py``)."""
    truth = REFERENCE_MODEL.parameters()
    moves = 100
    cur, enc = open_loop_window(PSI, moves=moves * CALIBRATION_WINDOWS, seed=1616)
    z = []
    start = None
    kept = 0
    for w in range(CALIBRATION_WINDOWS):
        rows = slice(w * moves, (w + 1) * moves)
        res = identify_window(cur[rows], enc[rows], sample_period=TAU, target_angle=PSI,
                              warm_start=start)
        kept += res.warm_started
        start = WarmStart.from_result(res)
        assert all(res.resolved)
        est, std = res.model.parameters(), res.std_by_name()
        z.append([(est[n] - truth[n]) / std[n] for n in truth])
    assert kept == CALIBRATION_WINDOWS - 1
    assert_calibrated(np.array(z), list(truth))


def test_what_starts_a_window() -> None:
    """Only a refined result with finite frequencies starts the next window; the cost test."""
    cur, enc = simulate_window(PSI, moves=100, seed=3)
    paper = identify_window(cur, enc, sample_period=TAU, method='paper-A', jackknife_groups=0)
    assert WarmStart.from_result(paper) is None
    refined = identify_window(cur, enc, sample_period=TAU)
    assert WarmStart.from_result(refined) is not None
    broken = replace(refined, natural_frequencies=(math.nan, *refined.natural_frequencies[1:]))
    assert WarmStart.from_result(broken) is None
    rows = 500
    limit = rows + WARM_CHI2_Z * math.sqrt(2 * rows)
    assert plausible(rows, rows)
    assert plausible(limit - 1, rows)
    assert not plausible(limit + 1, rows)
    assert not plausible(math.nan, rows)


def test_a_mode_the_last_window_did_not_resolve_starts_from_the_reference() -> None:
    """Its frequency and damping there were a noise fit: the next fit starts that mode at the
    scanner's reference model, the resolved modes where the last window put them."""
    w = REFERENCE_MODEL.natural_frequencies
    last = replace(REFERENCE_MODEL, natural_frequencies=(1.001 * w[0], 1.002 * w[1], 1.07 * w[2]),
                   damping_ratios=(0.005, 0.008, 0.0004))
    start = WarmStart(model=last, lag_time_constant=0.6 * TAU, resolved=(True, True, False))
    begun = start.start(REFERENCE_MODEL)
    assert begun.natural_frequencies[:2] == last.natural_frequencies[:2]
    assert begun.damping_ratios[:2] == last.damping_ratios[:2]
    assert begun.natural_frequencies[2] == REFERENCE_MODEL.natural_frequencies[2]
    assert begun.damping_ratios[2] == REFERENCE_MODEL.damping_ratios[2]
    assert begun.residues == last.residues
    # every mode resolved, no flags (an older start), or another number of modes: as it was
    assert replace(start, resolved=(True,) * 3).start(REFERENCE_MODEL) is last
    assert replace(start, resolved=()).start(REFERENCE_MODEL) is last
    two = replace(REFERENCE_MODEL, residues=REFERENCE_MODEL.residues[:2],
                  natural_frequencies=REFERENCE_MODEL.natural_frequencies[:2],
                  damping_ratios=REFERENCE_MODEL.damping_ratios[:2])
    assert start.start(two) is last


def test_the_result_carries_which_modes_started_the_next_window_resolved(
        windows_1psi: list) -> None:
    result = identify_window(*windows_1psi[0], sample_period=TAU, target_angle=PSI)
    start = WarmStart.from_result(result)
    assert start is not None
    assert start.resolved == result.resolved
