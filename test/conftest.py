"""Test-wide settings: keep ROS 2 traffic on this machine and apart from parallel runs."""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
VENV_BIN = Path(sys.executable).parent

# Set before any test (and every child process) touches rclpy.
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 100))
os.environ.setdefault('ROS_LOG_DIR', tempfile.mkdtemp(prefix='galvo_sysid_roslog_'))


@pytest.fixture
def repo() -> Path:
    """The repository root."""
    return REPO


@pytest.fixture
def venv_bin() -> Path:
    """The bin directory of the Python running the tests (the project venv)."""
    return VENV_BIN
