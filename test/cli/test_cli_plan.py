"""`galvo-sysid plan` from the command line: JSON, one-line errors, usage errors."""

from __future__ import annotations

import json
import subprocess

from conftest import VENV_BIN


def _plan(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(VENV_BIN / 'galvo-sysid'), 'plan', *args], capture_output=True,
                          text=True, timeout=120, check=False)


def test_plan_json_and_errors() -> None:
    proc = _plan('--json', '--change', 'omega_3=-0.01', '--dither', '10mA',
                 '--dither-modes', '3')
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out['dither']['amplitude'] == 0.01
    assert out['moves_to_detect']['omega_3'] > 1
    assert 0 < out['position_error_counts'] < 1
    bad = _plan('--dither-modes', '7')
    assert bad.returncode == 1
    assert bad.stderr.startswith('galvo-sysid plan: error: ')
    assert len(bad.stderr.strip().splitlines()) == 1
    assert "dither modes must be 'all' or distinct mode numbers 1..3" in bad.stderr
    usage = _plan('--change', 'omega_3')
    assert usage.returncode == 2
    assert 'expected PARAM=RELATIVE' in usage.stderr
    assert _plan('--dither', '2A').returncode == 2


def test_plan_refuses_a_change_below_zero_and_an_absurd_noise() -> None:
    """omega_3=-5 (to -4 times it) was planned as 171 moves; an encoder noise of 1e300 deg
    ended in a singular matrix."""
    for args, words in ((('--change', 'omega_3=-5'), 'omega_3 is positive'),
                        (('--change', 'k0=-1'), 'k0 is positive'),
                        (('--encoder-noise', '1e300'), 'must be > 0 and <= 10 deg'),
                        (('--current-noise', 'inf'), 'must be > 0 and <= 10 A')):
        proc = _plan(*args)
        assert proc.returncode == 2, proc.stderr
        assert words in proc.stderr.strip().splitlines()[-1]
    assert _plan('--change', 'k2=-3').returncode == 0  # a residue may change its sign
