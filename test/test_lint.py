"""The code base passes ruff and strict mypy (the same checks as `make lint`)."""

from __future__ import annotations

import subprocess
from pathlib import Path


def _run(args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(args, cwd=cwd, capture_output=True, text=True, timeout=600, check=False)


def test_ruff_clean(repo: Path, venv_bin: Path) -> None:
    result = _run([str(venv_bin / 'ruff'), 'check', 'galvo_sysid', 'test', 'benchmarks', 'tools',
                   'launch'], repo)
    assert result.returncode == 0, result.stdout + result.stderr


def test_mypy_strict_clean(repo: Path, venv_bin: Path) -> None:
    result = _run([str(venv_bin / 'mypy'), 'galvo_sysid'], repo)
    assert result.returncode == 0, result.stdout + result.stderr
