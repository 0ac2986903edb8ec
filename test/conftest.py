"""Test-wide settings: keep ROS 2 traffic on this machine and apart from parallel runs."""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from galvo_sysid import limit_blas_threads

# The numerics run as the entry points run them: one BLAS thread (a different count changes
# the last bits of the fits, and the tests compare the command line's results with direct
# calls exactly). Before anything imports numpy.
limit_blas_threads()

if TYPE_CHECKING:
    from collections.abc import Iterator

    from ros_graph import Graph

REPO = Path(__file__).resolve().parents[1]
VENV_BIN = Path(sys.executable).parent


def _domain_id() -> int:
    """A ROS domain of this run's own: one per pytest-xdist worker (``gw0``, ``gw1``, ...) of
    one run, so that the workers' nodes never see each other; 1-200 (Linux allows up to 232)."""
    worker = os.environ.get('PYTEST_XDIST_WORKER', '')
    if worker.startswith('gw') and worker[2:].isdigit():
        # the workers share their parent, the run's controller
        return 1 + (os.getppid() % 40) * 5 + int(worker[2:]) % 5
    return 1 + (os.getpid() % 40) * 5


# Set before any test (and every child process) touches rclpy.
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
if 'PYTEST_XDIST_WORKER' in os.environ:
    # not setdefault: a worker inherits the controller's variables, this one included
    os.environ['ROS_DOMAIN_ID'] = str(_domain_id())
else:
    os.environ.setdefault('ROS_DOMAIN_ID', str(_domain_id()))
os.environ.setdefault('ROS_LOG_DIR', tempfile.mkdtemp(prefix='galvo_sysid_roslog_'))


@pytest.fixture
def repo() -> Path:
    """The repository root."""
    return REPO


@pytest.fixture
def venv_bin() -> Path:
    """The bin directory of the Python running the tests (the project venv)."""
    return VENV_BIN


@pytest.fixture
def graph(venv_bin: Path, tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[Graph]:
    """A test rclpy node plus the node processes it starts; everything stopped afterwards."""
    from ros_graph import Graph  # imports rclpy: only for the tests that talk ROS

    g = Graph(venv_bin, tmp_path, name=request.module.__name__.removeprefix('test_'))
    try:
        yield g
    finally:
        g.close()


# The modules whose tests take longest (`pytest --durations`, 2026-11-28: 37-105 s each):
# handed out first. `make test` runs two xdist workers with ``--dist loadscope``, which hands
# out whole modules in collection order; in alphabetical order the colcon build and the
# multi-process node tests came last, and one worker ran them while the other had finished.
_LONGEST_FIRST = ('test_package_layout.py', 'test_workflow.py', 'test_independent_scanner.py',
                  'test_commission.py', 'test_fallback.py', 'test_cli_commission.py',
                  'test_nodes_integration.py', 'test_reliability_faults.py')


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Run the longest modules first (see :data:`_LONGEST_FIRST`); the rest keep their order."""
    rank = {name: i for i, name in enumerate(_LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))
