"""Tests of galvo_sysid.ident.preprocess: window validation and the paper's methods A and B."""

from __future__ import annotations

import numpy as np
import pytest
from openloop_data import open_loop_window

from galvo_sysid.errors import ConfigurationError, InvalidDataError
from galvo_sysid.ident.arx import min_data_length
from galvo_sysid.ident.preprocess import (
    average_records,
    concatenate_records,
    preprocess,
    remove_start_angle,
    validate_records,
)


@pytest.fixture(scope='module')
def window():
    return open_loop_window(0.3, moves=6, seed=2, start_angle=2.5)


def test_remove_start_angle():
    enc = np.array([[1.0, 1.5, 2.0], [-3.0, -2.0, -2.5]])
    np.testing.assert_allclose(remove_start_angle(enc), [[0, 0.5, 1.0], [0, 1.0, 0.5]])


def test_method_a_is_the_samplewise_mean(window):
    cur, enc = window
    u, y = average_records(cur, enc)
    assert u.shape == (cur.shape[1],)
    np.testing.assert_allclose(u, cur.mean(axis=0))
    np.testing.assert_allclose(y, (enc - enc[:, :1]).mean(axis=0))
    assert y[0] == 0
    assert y[-1] == pytest.approx(0.3, abs=2e-3)


def test_method_b_is_continuous(window):
    cur, enc = window
    m, n = cur.shape
    u, y = concatenate_records(cur, enc)
    assert u.shape == y.shape == (m * n,)
    np.testing.assert_allclose(u, cur.reshape(-1))
    rel = enc - enc[:, :1]
    for i in range(m):
        seg = y[i * n:(i + 1) * n]
        # each record keeps its shape, offset by the end angles of the records before it
        np.testing.assert_allclose(seg - seg[0], rel[i])
        assert seg[0] == pytest.approx(rel[:i, -1].sum())
        if i:
            assert seg[0] == pytest.approx(y[i * n - 1])  # continuous at the junction
    # the paper's offset is (i - 1) Psi; the measured end angles are close to it
    assert y[(m - 1) * n] == pytest.approx((m - 1) * 0.3, abs=0.03)


def test_preprocess_dispatch(window):
    cur, enc = window
    np.testing.assert_allclose(preprocess(cur, enc, method='A')[1], average_records(cur, enc)[1])
    np.testing.assert_allclose(preprocess(cur, enc, method='B')[1],
                               concatenate_records(cur, enc)[1])
    with pytest.raises(ConfigurationError):
        preprocess(cur, enc, method='C')


def test_valid_window_passes_unchanged(window):
    cur, enc = window
    c2, e2 = validate_records(cur.tolist(), enc)
    assert c2.dtype == np.float64
    np.testing.assert_array_equal(c2, cur)
    np.testing.assert_array_equal(e2, enc)


def _bad(window, what):
    cur, enc = (a.copy() for a in window)
    if what == 'one record':
        return cur[:1], enc[:1]
    if what == 'too short':
        n = min_data_length(15, 15) - 1
        return cur[:, :n], enc[:, :n]
    if what == 'nan current':
        cur[2, 100] = np.nan
    elif what == 'inf encoder':
        enc[0, 7] = np.inf
    elif what == 'mismatched':
        return cur[:, :-1], enc
    elif what == 'mismatched records':
        return cur[:-1], enc
    elif what == '1-D':
        return cur[0], enc[0]
    elif what == 'zero-angle move':
        rng = np.random.default_rng(0)
        enc = 2.5 + np.round(rng.normal(0, 2e-5, enc.shape) / 4e-5) * 4e-5
        cur = rng.normal(0, 1e-4, cur.shape)
    elif what == 'zero current':
        cur[:] = 0
    elif what == 'text':
        return [['a', 'b']], enc
    return cur, enc


@pytest.mark.parametrize(('what', 'match'), [
    ('one record', 'at least 2 records'),
    ('too short', 'needs at least'),
    ('nan current', 'current contains NaN'),
    ('inf encoder', 'encoder contains NaN or Inf'),
    ('mismatched', 'shapes differ'),
    ('mismatched records', 'shapes differ'),
    ('1-D', '2-D'),
    ('zero-angle move', 'no excitation'),
    ('zero current', 'no excitation'),
    ('text', 'not numeric'),
])
def test_bad_windows_raise(window, what, match):
    cur, enc = _bad(window, what)
    with pytest.raises(InvalidDataError, match=match):
        validate_records(cur, enc)
    with pytest.raises(InvalidDataError):
        preprocess(cur, enc)


def test_short_records_allowed_for_low_orders(window):
    cur, enc = window
    n = min_data_length(2, 2)
    part = np.s_[:, 20:20 + n]  # mid-move, where the angle changes
    validate_records(cur[part], enc[part], na=2, nb=2)
    with pytest.raises(InvalidDataError):
        validate_records(cur[part], enc[part])
