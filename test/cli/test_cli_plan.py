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
