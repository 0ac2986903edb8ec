"""Point the ros-jazzy wheels' CMake exports at this venv's Python and numpy headers.

The PyPI wheels were built in a manylinux container; their exported CMake files name that
container's include directories, so building an interface package against them fails with
"includes non-existent path" until those strings are rewritten (see ROS2_FROM_PYPI.md).
Idempotent: run it with the venv's Python after every dependency install.
"""

from __future__ import annotations

import re
import sys
import sysconfig
from pathlib import Path

import numpy as np

BUILD_HOST_PYTHON = re.compile(r'/opt/python/cp3\d+-cp3\d+/include/python3\.\d+')
BUILD_HOST_NUMPY = re.compile(
    r'/opt/python/cp3\d+-cp3\d+/lib/python3\.\d+/site-packages/numpy/_core/include')


def main() -> int:
    """Rewrite the build host's include paths in every ``share/**/*.cmake`` of the venv."""
    share = Path(sys.prefix) / 'share'
    py_inc = sysconfig.get_paths()['include']
    np_inc = np.get_include()
    changed = 0
    for path in share.rglob('*.cmake'):
        text = path.read_text(encoding='utf-8', errors='surrogateescape')
        new = BUILD_HOST_NUMPY.sub(np_inc, text)
        new = BUILD_HOST_PYTHON.sub(py_inc, new)
        if new != text:
            path.write_text(new, encoding='utf-8', errors='surrogateescape')
            changed += 1
    print(f'fix_cmake_paths: {changed} CMake files now use {py_inc} and {np_inc}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
