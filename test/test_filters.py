"""lfilter and bilinear without scipy.signal: the same numbers, and no scipy.signal import
where a process does not need it (identification, the simulator, the driver and watchdog
nodes, the command line's help)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import scipy.signal

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.filters import bilinear, fir, lfilter


@pytest.mark.parametrize(('b', 'a'), [
    ([1.0, 2.0], [2.0]),                              # FIR, a[0] != 1
    ([0.5, 0.2], [1.0, -0.9]),                        # first-order lag
    ([0.0, 0.0, 1.0], [1.0, 0.5, 0.1]),               # leading zeros (a delay)
    ([1.0], [1.0, -1.8, 0.81, 0.0, 0.0]),             # double pole, trailing zeros in a
    ([0.3, -0.2, 0.1, 0.05], [2.0, -1.0, 0.3, 0.05]),
])
@pytest.mark.parametrize('axis', [-1, 0, 1])
def test_lfilter_is_scipys(b: list[float], a: list[float], axis: int) -> None:
    x = np.random.default_rng(0).standard_normal((3, 4, 60))
    want = scipy.signal.lfilter(b, a, x, axis=axis)
    got = lfilter(b, a, x, axis=axis)
    assert got.shape == x.shape
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.abs(want).max())


def test_lfilter_of_a_high_order_model_and_short_records() -> None:
    rng = np.random.default_rng(1)
    poles = 0.97 * np.exp(1j * rng.uniform(0.1, 3.0, 7))
    a = np.poly(np.concatenate([poles, poles.conj(), [0.5]])).real  # 15th order, stable
    b = rng.standard_normal(16)
    x = rng.standard_normal((5, 512))
    want = scipy.signal.lfilter(b, a, x)
    np.testing.assert_allclose(lfilter(b, a, x), want, rtol=0,
                               atol=1e-10 * np.abs(want).max())
    # records shorter than the filter, one sample, a 1-D record
    for n in (1, 3, 10):
        np.testing.assert_allclose(lfilter(b, a, x[:, :n]), scipy.signal.lfilter(b, a, x[:, :n]),
                                   rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(lfilter(b, a, x[0]), want[0], rtol=0,
                               atol=1e-10 * np.abs(want).max())


@pytest.mark.parametrize(('b', 'a'), [
    ([0.5], [1.0, -0.9]),                             # the simulator's AR(1) noise
    ([0.3, -0.2, 0.1], [2.0, -1.0, 0.3]),
    ([1.0, 2.0, 3.0, 4.0], [1.0, 0.2]),               # order from the numerator
])
def test_lfilter_from_a_state_is_scipys(b: list[float], a: list[float]) -> None:
    rng = np.random.default_rng(3)
    zi = rng.standard_normal(max(len(a), len(b)) - 1)
    x = rng.standard_normal((2, 50))
    want = scipy.signal.lfilter(b, a, x, axis=1, zi=np.tile(zi, (2, 1)))[0]
    np.testing.assert_allclose(lfilter(b, a, x, axis=1, zi=zi), want, rtol=0,
                               atol=1e-13 * np.abs(want).max())
    # a record shorter than the state: only its samples
    short = scipy.signal.lfilter(b, a, x[0, :1], zi=zi)[0]
    np.testing.assert_allclose(lfilter(b, a, x[0, :1], zi=zi), short, rtol=1e-13, atol=1e-15)
    with pytest.raises(ConfigurationError, match='zi must hold'):
        lfilter(b, a, x, zi=np.append(zi, 0.0))


def test_the_simulators_first_order_filter_is_scipys_to_the_bit() -> None:
    """The seeded simulator's noise (an AR(1) filter from the last move's state, over all
    moves at once) is what scipy.signal gave before: every seeded figure stands (and a
    delayed first-order filter of many rows, the discrepancy plant's amplifier lag, too)."""
    rng = np.random.default_rng(4)
    x = rng.standard_normal(100_000)
    a = 0.93
    gain = 0.014 * np.sqrt(1 - a * a)
    want = scipy.signal.lfilter([gain], [1.0, -a], x, zi=[a * 0.3])[0]
    np.testing.assert_array_equal(lfilter([gain], [1.0, -a], x, zi=[a * 0.3]), want)
    u = rng.standard_normal((40, 800))
    np.testing.assert_array_equal(lfilter([0.0, 1.0], [1.0, -a], u, axis=1),
                                  scipy.signal.lfilter([0.0, 1.0], [1.0, -a], u, axis=1))


def test_fir_from_rest() -> None:
    np.testing.assert_array_equal(fir([1.0, -1.0], [[1.0, 3.0, 6.0]]), [[1.0, 2.0, 3.0]])
    np.testing.assert_array_equal(fir([0.0, 0.0, 0.0, 2.0], [1.0, 2.0]), [0.0, 0.0])


@pytest.mark.parametrize(('b', 'a', 'fs'), [
    ([1.0], [6e-6, 1.0], 1e5),                        # the amplifier lag
    ([-1.0, 12.0, -60.0, 120.0], [1.0, 12.0, 60.0, 120.0], 3.0),  # a Pade all-pass
    ([1.0, 2.0, 3.0], [1.0, 0.5, 2.0, 7.0], 3.0),     # numerator of lower degree
    ([2.0], [1.0], 5.0),
])
def test_bilinear_is_scipys(b: list[float], a: list[float], fs: float) -> None:
    want_b, want_a = scipy.signal.bilinear(b, a, fs=fs)
    got_b, got_a = bilinear(b, a, fs=fs)
    np.testing.assert_allclose(got_b, want_b, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(got_a, want_a, rtol=1e-12, atol=1e-15)
    assert got_a[0] == 1.0


def test_bad_coefficients() -> None:
    with pytest.raises(ConfigurationError, match='a\\[0\\]'):
        lfilter([1.0], [0.0, 1.0], np.ones(4))
    with pytest.raises(ConfigurationError, match='non-empty'):
        lfilter([], [1.0], np.ones(4))
    with pytest.raises(ConfigurationError, match='fs'):
        bilinear([1.0], [1.0, 1.0], fs=0.0)


def _imported(code: str, prefixes: tuple[str, ...]) -> list[str]:
    """The modules starting with one of ``prefixes`` a fresh Python has after ``code``."""
    probe = (f'{code}\nimport json, sys\n'
             f'print(json.dumps(sorted(m for m in sys.modules if m.startswith({prefixes!r}))))')
    out = subprocess.run([sys.executable, '-c', probe], capture_output=True, text=True,
                         check=True, timeout=60)
    return json.loads(out.stdout.splitlines()[-1])


def test_identification_path_does_not_import_scipy_signal() -> None:
    code = ('import galvo_sysid.field.offline, galvo_sysid.ident.identify\n'
            'import galvo_sysid.monitor.scheduler, galvo_sysid.monitor.tasks\n'
            'import galvo_sysid.ident.paper, galvo_sysid.ident.refine, galvo_sysid.field.bags\n'
            'import galvo_sysid.sim.simulator\n')
    assert _imported(code, ('scipy.signal', 'scipy.stats')) == []


def test_the_driver_the_watchdog_and_the_help_import_no_fit() -> None:
    """The nodes that fit nothing, and the command line's help, start without the fits'
    :mod:`scipy.optimize` (half a second of every start here)."""
    code = ('import galvo_sysid.nodes.driver_node, galvo_sysid.nodes.watchdog_node\n'
            'import galvo_sysid.monitor.parameters\n'
            'from galvo_sysid.cli.main import main\n'
            'try:\n    main(["--help"])\nexcept SystemExit:\n    pass\n')
    assert _imported(code, ('scipy.optimize', 'scipy.signal', 'scipy.stats',
                            'galvo_sysid.ident.refine', 'galvo_sysid.discrepancy.workflow')) == []
