"""The whitener's closed forms and the window's shortcuts give what whitening the columns gives."""

from __future__ import annotations

import numpy as np
import pytest

from galvo_sysid.ident.refine.regressors import free_responses, powers, second_difference
from galvo_sysid.ident.refine.whitener import Whitener, noise_whitener
from galvo_sysid.ident.refine.window import WindowProblem, window_records
from galvo_sysid.model import PSI, TAU
from galvo_sysid.sim.simulator import simulate_window

LAG = 6e-6


@pytest.fixture(scope='module')
def problem() -> WindowProblem:
    """A short window of the paper's scanner, whitened by its moves' scatter."""
    cur, enc = simulate_window(PSI, moves=12, seed=5)
    ((cur, enc),) = window_records([(cur, enc)], 3)
    prob = WindowProblem(cur, enc, sample_period=TAU, delay=1, fraction=0.6, n_modes=3)
    dev = second_difference(enc - enc.mean(axis=0))[:, prob.first:]
    prob.set_whitening(noise_whitener(dev, 40, 1.0))
    return prob


def _candidates() -> tuple[np.ndarray, np.ndarray]:
    w_c = np.geomspace(2e4, 1.5e5, 30)
    z_c = np.tile([3e-4, 0.01, 0.2], 10)  # light to heavy damping: the powers span decades
    return w_c, z_c


def test_exponential_tail_is_the_whitened_tail_of_powers() -> None:
    wh = Whitener.from_autocovariance(np.exp(-np.arange(9) / 3.0)).then(
        Whitener.from_autocovariance(np.exp(-np.arange(6) / 2.0)))
    w_c, z_c = _candidates()
    _, e = powers(w_c, z_c, 60, TAU)
    start, rows = 2, 58
    plain = wh.apply(e[:, start: start + rows].real.T).T + 1j * wh.apply(
        e[:, start: start + rows].imag.T).T
    tail = wh.exponential_tail(e, start, rows)
    assert tail.shape == (w_c.size, rows - wh.order)
    scale = np.max(np.abs(plain), axis=1, keepdims=True)
    assert np.max(np.abs(tail - plain[:, wh.order:]) / scale) < 1e-12


def test_convolve_filtered_is_the_filtered_convolution(problem: WindowProblem) -> None:
    regs = problem.regs
    w_c, z_c = _candidates()
    h = regs.mode_impulses(w_c, z_c, LAG)
    taps = problem.whiten.filter  # type: ignore[union-attr]
    forced, filtered = regs.convolve_filtered(regs.transform(h), taps)
    plain = regs.convolve(h)
    assert np.array_equal(forced, plain) or np.max(np.abs(forced - plain)) < 1e-12 * np.max(
        np.abs(plain))
    direct = np.array([np.convolve(row, taps)[: plain.shape[1]] for row in plain])
    exact = slice(taps.size - 1, None)
    assert np.max(np.abs(filtered[:, exact] - direct[:, exact])) < 1e-10 * np.max(
        np.abs(direct))


def test_candidate_columns_equal_whitening_the_columns(problem: WindowProblem) -> None:
    w_c, z_c = _candidates()
    _, e = powers(w_c, z_c, problem.n, problem.t)
    forced = problem.regs.convolve(problem.regs.mode_impulses(w_c, z_c, LAG, e))[:, problem.first:]
    free = free_responses(w_c, z_c, problem.n, problem.t, e, first=problem.first)
    plain = problem.apply_whitening(np.stack([forced, free[0::2], free[1::2]], axis=-1), axis=1)
    fast = np.moveaxis(problem._candidates(LAG, w_c, z_c), 0, 2)  # (rows, 3, m) -> (3, m, rows)
    fast = np.moveaxis(fast, 0, 2)                             # -> (m, rows, 3)
    assert fast.shape == plain.shape
    for c in range(3):
        scale = np.max(np.abs(plain[..., c]))
        assert np.max(np.abs(fast[..., c] - plain[..., c])) < 1e-12 * scale


def test_cached_columns_follow_the_whitening(problem: WindowProblem) -> None:
    omega = np.array([2.5e4, 6e4, 1.2e5])
    zeta = np.array([0.01, 0.02, 0.005])
    first = problem.columns(omega, zeta, LAG)
    assert not first.flags.writeable
    assert problem.columns(omega, zeta, LAG) is first
    raw = problem.columns(omega, zeta, LAG, whitened=False)
    assert np.allclose(problem.apply_whitening(raw), first)
    old = problem.whiten
    try:
        problem.set_whitening(None)
        assert np.array_equal(problem.columns(omega, zeta, LAG), raw)
    finally:
        problem.set_whitening(old)
    assert np.allclose(problem.columns(omega, zeta, LAG), first)
    other = problem.columns(omega * 1.01, zeta, LAG)
    assert not np.allclose(other, first)


def test_kept_derivatives_follow_their_arguments_and_the_whitening(
        problem: WindowProblem) -> None:
    """The last derivatives are given again for the same point, coefficients and kind; a
    change of any of them, or of the whitening, computes them anew (a stale Jacobian would
    silently misplace the covariance)."""
    omega = np.array([2.5e4, 6e4, 1.2e5])
    zeta = np.array([0.01, 0.02, 0.005])
    coef = np.linspace(1.0, 2.0, problem.n_linear)
    first = problem.model_derivatives(omega, zeta, LAG, coef, lag_free=True)
    assert not first.flags.writeable
    assert problem.model_derivatives(omega, zeta, LAG, coef, lag_free=True) is first
    for args, kwargs in (((omega, zeta, LAG, 2 * coef), {'lag_free': True}),
                         ((omega * 1.01, zeta, LAG, coef), {'lag_free': True}),
                         ((omega, zeta, LAG, coef), {'lag_free': False}),
                         ((omega, zeta, LAG, coef), {'lag_free': True, 'whitened': False})):
        other = problem.model_derivatives(*args, **kwargs)
        assert other.shape != first.shape or not np.allclose(other, first)
    raw = problem.model_derivatives(omega, zeta, LAG, coef, lag_free=True, whitened=False)
    old = problem.whiten
    try:
        problem.set_whitening(None)
        np.testing.assert_array_equal(
            problem.model_derivatives(omega, zeta, LAG, coef, lag_free=True), raw)
    finally:
        problem.set_whitening(old)
    np.testing.assert_array_equal(
        problem.model_derivatives(omega, zeta, LAG, coef, lag_free=True), first)


@pytest.mark.parametrize('columns', [1, 47, 48, 300])
@pytest.mark.parametrize('rows', [5, 130])
def test_lower_times_is_the_product_with_the_lower_triangle(rows: int, columns: int) -> None:
    """Both paths of ``lower_times`` (a plain product for few columns, BLAS trmm for many)
    give ``L @ A`` for a lower-triangular L, also for a Fortran-ordered ``A``, and a
    Whitener's ``apply`` (head rows, then the FIR filter) is its definition."""
    from galvo_sysid.ident.refine.whitener import lower_times

    rng = np.random.default_rng(rows + columns)
    low = np.tril(rng.standard_normal((rows, rows)))
    arr = rng.standard_normal((columns, rows)).T  # Fortran-ordered
    want = low @ arr
    np.testing.assert_allclose(lower_times(low, arr), want, rtol=1e-12, atol=1e-12)
    filt = rng.standard_normal(4)
    wh = Whitener(low, filt[: min(4, rows + 1)])
    direct = np.array([np.convolve(col, wh.filter)[: 2 * rows] for col in
                       np.vstack([arr, arr]).T]).T
    direct[:rows] = want
    np.testing.assert_allclose(wh.apply(np.vstack([arr, arr])), direct, rtol=1e-10,
                               atol=1e-10)


def test_then_is_the_two_maps_in_turn() -> None:
    """A composed whitener maps any record (shorter or longer than its head) as the first
    map and then the second, and ``matrix`` is the map as a matrix."""
    first = Whitener.from_autocovariance(np.exp(-np.arange(12) / 3.0) * np.cos(np.arange(12)))
    second = Whitener.from_autocovariance(np.exp(-np.arange(7) / 2.0))
    both = first.then(second)
    assert both.order == first.order + second.order
    rng = np.random.default_rng(5)
    for rows in (10, 40):
        rec = rng.standard_normal((rows, 3))
        np.testing.assert_allclose(both.apply(rec), second.apply(first.apply(rec)),
                                   rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(first.matrix(rows) @ rec, first.apply(rec), rtol=1e-12,
                                   atol=1e-12)


def test_the_moves_regressors_are_kept_for_the_same_records_only() -> None:
    """The screening and the fit of a window share its moves' transforms; other records, a
    changed sample or another delay get their own (the kept ones are not stale)."""
    from galvo_sysid.ident.refine.window import _moves_regressors

    cur, _ = simulate_window(PSI, moves=12, seed=2)
    first = _moves_regressors(cur, sample_period=TAU, delay=1, fraction=0.0)
    assert _moves_regressors(cur.copy(), sample_period=TAU, delay=1, fraction=0.0) is first
    changed = cur.copy()
    changed[3, 40] += 1e-3
    other = _moves_regressors(changed, sample_period=TAU, delay=1, fraction=0.0)
    assert other is not first
    assert not np.allclose(other.uf, first.uf)
    assert _moves_regressors(changed, sample_period=TAU, delay=2, fraction=0.0) is not other
    cur[0, 0] += 1.0  # the caller's array changed in place after the call
    assert _moves_regressors(cur, sample_period=TAU, delay=1, fraction=0.0) is not first


def test_one_whitener_of_a_chain_is_its_noise_model() -> None:
    """Two short stages in series whiten an AR noise of their summed order: one whitener of
    at least that many lags has their filters in series as its filter (scaled so the noise
    leaves it with the returned variance), nothing beyond; with fewer lags it is the best
    predictor of that order: its output on a long record of the noise is nearly white with
    that variance."""
    from galvo_sysid.ident.refine.whitener import WhitenerChain

    first = Whitener.from_autocovariance(np.array([1.0, 0.8, 0.5, 0.3]))
    second = Whitener.from_autocovariance(np.array([1.0, -0.4, 0.1]))
    chain = WhitenerChain(first, second)
    single, variance = chain.single(9)
    series = np.convolve(first.filter, second.filter)
    np.testing.assert_allclose(single.filter[: series.size], np.sqrt(variance) * series,
                               rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(single.filter[series.size:], 0.0, atol=1e-9)
    # the noise itself: white noise through the inverse of the series filter
    from scipy.signal import lfilter

    rng = np.random.default_rng(3)
    noise = lfilter([1.0], series, rng.standard_normal(200_000))
    short, var_short = chain.single(3)
    out = short.apply(noise)[1000:]
    assert np.var(out) == pytest.approx(var_short, rel=0.03)
    np.testing.assert_allclose(chain.apply(noise)[1000:].var(), 1.0, rtol=0.02)


@pytest.mark.parametrize('n', [1, 2, 3, 5, 64, 513])
def test_powers_are_the_exponentials(n: int) -> None:
    """E[j, k] = exp(p_j T k), by doubling, to a few eps times the record length."""
    w_c, z_c = _candidates()
    p, e = powers(w_c, z_c, n, TAU)
    want = np.exp(p[:, None] * TAU * np.arange(n))
    assert e.shape == (w_c.size, n)
    np.testing.assert_allclose(e, want, rtol=0, atol=4 * n * np.finfo(float).eps + 1e-300)


@pytest.mark.parametrize('rows', [30, 300])
def test_the_transposed_map_is_the_matrix_transposed(problem: WindowProblem, rows: int) -> None:
    """``Whitener.transposed`` (the covariance's shortcut) is ``W^T`` of the map ``apply``
    is: rows fewer than the head's order too."""
    w = problem.whiten
    assert w is not None
    cols = np.random.default_rng(rows).standard_normal((rows, 4))
    y = np.random.default_rng(rows + 1).standard_normal(rows)
    np.testing.assert_allclose(w.matrix(rows) @ y, w.apply(y), rtol=0, atol=1e-12 * w.order)
    want = w.matrix(rows).T @ cols
    np.testing.assert_allclose(w.transposed(cols), want, rtol=0,
                               atol=1e-13 * float(np.max(np.abs(want))))
    np.testing.assert_array_equal(WindowProblem.whitening_transposed(problem, cols),
                                  w.transposed(cols))


@pytest.mark.parametrize(('delay', 'fraction', 'lag'), [(1, 0.0, LAG), (2, 0.3, 0.0),
                                                        (1, 0.7, 2.5 * LAG)])
def test_the_deviations_times_columns_need_no_deviations(delay: int, fraction: float,
                                                         lag: float) -> None:
    """``deviations_times`` by correlation (no move convolved) gives the deviations' product
    with the columns, for any delay, dead time and lag; and from the kept deviations once
    they are made."""
    from galvo_sysid.model import REFERENCE_MODEL

    cur, enc = simulate_window(0.9, moves=20, seed=1)
    prob = WindowProblem(cur, enc - enc[:, :1], sample_period=TAU, delay=delay,
                         fraction=fraction, n_modes=3)
    rng = np.random.default_rng(delay)
    omega = np.array(REFERENCE_MODEL.natural_frequencies)
    zeta = np.array(REFERENCE_MODEL.damping_ratios)
    coef = rng.standard_normal(prob.n_linear)
    coef[0] = REFERENCE_MODEL.k0
    cols = rng.standard_normal((prob.k.size, 5))
    got = prob.deviations_times(omega, zeta, lag, coef, cols)
    assert prob._deviations is None  # not made on the way
    want = prob.deviations(omega, zeta, lag, coef) @ cols
    scale = float(np.max(np.abs(want)))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(prob.deviations_times(omega, zeta, lag, coef, cols), want,
                               rtol=0, atol=1e-14 * scale)
    assert not np.allclose(prob.deviations_times(omega, zeta, 2 * lag + LAG, coef, cols), want,
                           rtol=0, atol=1e-6 * scale)


@pytest.mark.parametrize(('rows', 'order', 'first_order', 'taps'),
                         [(300, 128, None, (129, 129)), (300, 200, 128, (129, 151)),
                          (600, 200, 128, (129, 201)), (600, 100, 128, (101, 101))])
def test_the_noise_models_passes_have_their_lags_up_to_half_the_rows(
        rows: int, order: int, first_order: int | None, taps: tuple[int, int]) -> None:
    """The first pass has ``first_order`` lags (``order`` if None or more), the second
    ``order``; neither more than half the rows (a lag needs that many products per move)."""
    from galvo_sysid.ident.refine.whitener import stationary_noise_model

    rng = np.random.default_rng(5)
    dev = rng.standard_normal((20, rows))
    nuisance = np.ones((rows, 1))
    found = stationary_noise_model(dev - dev.mean(axis=1, keepdims=True), nuisance, order,
                                   1, first_order=first_order)
    assert found is not None
    assert tuple(stage.filter.size for stage in found[0].stages) == taps
