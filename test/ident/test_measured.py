"""A measured coil current made into the held current behind it; the amplifier lag's search."""

from __future__ import annotations

import math

import numpy as np
import pytest

from galvo_sysid.errors import ConfigurationError, InvalidDataError
from galvo_sysid.ident.measured import (
    LAG_TOLERANCE,
    MAX_LAG_SAMPLES,
    check_lag,
    held_current,
    held_windows,
    search_lag,
)

T = 1e-5


def _lagged(held: np.ndarray, first: np.ndarray, lag: float) -> np.ndarray:
    """The amplifier's current at the sample instants, its held input ``held``."""
    a = math.exp(-T / lag) if lag > 0 else 0.0
    out = np.empty((held.shape[0], held.shape[1] + 1))
    out[:, 0] = first
    for k in range(held.shape[1]):
        out[:, k + 1] = a * out[:, k] + (1 - a) * held[:, k]
    return out


@pytest.mark.parametrize('lag', [0.0, 0.3 * T, 1.7 * T, 12 * T])
def test_the_held_current_is_the_input_the_lag_followed(lag: float) -> None:
    rng = np.random.default_rng(5)
    held = rng.normal(size=(3, 60))
    measured = _lagged(held, rng.normal(size=3), lag)
    np.testing.assert_allclose(held_current(measured, sample_period=T, lag=lag), held,
                               rtol=1e-9, atol=1e-9)
    # one record (1-D) the same; the windows keep the encoder's samples but the last
    np.testing.assert_allclose(held_current(measured[1], sample_period=T, lag=lag), held[1],
                               rtol=1e-9, atol=1e-9)
    enc = rng.normal(size=measured.shape)
    [(cur, kept)] = held_windows([(measured, enc)], sample_period=T, lag=lag)
    assert cur.shape == kept.shape == (3, 60)
    np.testing.assert_array_equal(kept, enc[:, :-1])


def test_a_wrong_lag_leaves_part_of_the_lag_in_the_held_current() -> None:
    # what the search relies on: made with half the lag, the held current is smoothed
    rng = np.random.default_rng(6)
    held = rng.normal(size=(1, 400))
    measured = _lagged(held, np.zeros(1), 0.8 * T)
    half = held_current(measured, sample_period=T, lag=0.4 * T)
    assert np.std(np.diff(half)) < 0.9 * np.std(np.diff(held))


def test_bad_lags_and_records_are_refused() -> None:
    assert check_lag(0) == 0.0
    assert check_lag(MAX_LAG_SAMPLES * T, T) == MAX_LAG_SAMPLES * T
    for bad in (-1e-9, math.nan, math.inf, True, '1e-6', None):
        with pytest.raises(ConfigurationError, match='must be a time >= 0'):
            check_lag(bad)  # type: ignore[arg-type]
    with pytest.raises(ConfigurationError, match='sample periods: above 20'):
        check_lag(21 * T, T)
    for short in (np.ones((4, 1)), 2.0):
        with pytest.raises(InvalidDataError, match='2 samples or more'):
            held_current(short, sample_period=T, lag=T)
    assert held_current([1.0, 3.0], sample_period=T, lag=0.0).tolist() == [3.0]  # 2 samples


@pytest.mark.parametrize('slope', [0.1, 0.5, 0.9, 0.94])
def test_the_search_finds_where_the_fit_agrees_with_the_lag(slope: float) -> None:
    # a fit that finds a lag between the assumed one and the truth, as commissioning's does
    truth = 0.77 * T
    calls: list[float] = []

    def fitted(lag: float) -> float:
        calls.append(lag)
        return truth + slope * (lag - truth) - 0.3 * T * (lag - truth) ** 2 / T
    found = search_lag(fitted, sample_period=T, upper=1.5 * T)
    assert found.converged
    assert found.lag == pytest.approx(truth, abs=2 * LAG_TOLERANCE * T / (1 - slope))
    assert [s[0] for s in found.steps] == calls
    assert found.steps[0] == (0.0, fitted(0.0))
    assert len(found.steps) <= 8


def test_a_lag_beyond_the_range_ends_at_the_bound_unsettled() -> None:
    found = search_lag(lambda lag: lag + 0.5 * T, sample_period=T, upper=1.5 * T)
    assert not found.converged
    assert found.lag == 1.5 * T
    # given the first step, it is not fitted again
    seen: list[float] = []
    search_lag(lambda lag: seen.append(lag) or 0.2 * T, sample_period=T, upper=T,
               first=(0.0, 0.2 * T))
    assert seen[0] == pytest.approx(0.2 * T)


def test_a_search_that_does_not_settle_stops_after_its_most_steps() -> None:
    # a fit whose lag jumps about the assumed one by 10 tolerances: never within it
    steps = iter(range(100))
    found = search_lag(lambda lag: lag + (-1) ** next(steps) * 0.01 * T, sample_period=T,
                       upper=1.5 * T, first=(0.5 * T, 0.51 * T))
    assert not found.converged
    assert len(found.steps) == 1 + 12
