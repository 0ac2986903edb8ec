"""The process set-up of galvo_sysid's entry points (``galvo_sysid/__init__.py``)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

_PROBE = ('import galvo_sysid, sys; ok = galvo_sysid.keep_freed_memory(); '
          'sys.stdout.write(str(ok))')


def _probe(**env: str) -> str:
    clean = {k: v for k, v in os.environ.items() if not k.startswith('MALLOC_')}
    out = subprocess.run([sys.executable, '-c', _PROBE], env={**clean, **env},
                         capture_output=True, text=True, timeout=60, check=True)
    return out.stdout


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='glibc only')
def test_freed_memory_is_kept_on_glibc() -> None:
    assert _probe() == 'True'


@pytest.mark.parametrize('name', ['MALLOC_TRIM_THRESHOLD_', 'MALLOC_MMAP_THRESHOLD_'])
def test_a_users_allocator_setting_is_kept(name: str) -> None:
    assert _probe(**{name: '131072'}) == 'False'


def test_the_entry_points_call_it() -> None:
    from pathlib import Path

    root = Path(__file__).resolve().parents[1] / 'galvo_sysid'
    for path in ('nodes/__init__.py', 'cli/main.py', 'cli/discrepancy.py', 'field/demo.py',
                 'monitor/scheduler.py'):
        assert 'keep_freed_memory()' in (root / path).read_text(), path
