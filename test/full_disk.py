"""A small disk that fills up, for the tests of what a full disk keeps: :func:`tmpfs`."""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from collections.abc import Iterator
    from pathlib import Path


@contextlib.contextmanager
def tmpfs(where: Path, size: str = '2m') -> Iterator[Path]:
    """A tmpfs of ``size`` mounted at ``where`` (created), unmounted at the end.

    Skips the test where mounting is not allowed (not root, no ``mount``).
    """
    where.mkdir()
    if os.geteuid() != 0 or shutil.which('mount') is None:
        pytest.skip('mounting a small tmpfs needs root')
    done = subprocess.run(['mount', '-t', 'tmpfs', '-o', f'size={size}', 'tmpfs', str(where)],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        pytest.skip(f'cannot mount a tmpfs here: {done.stderr.strip()}')
    try:
        yield where
    finally:
        subprocess.run(['umount', '-l', str(where)], check=False)
