"""Test-wide settings: keep ROS 2 traffic on this machine and apart from parallel runs."""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

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


# `make test` runs two pytest-xdist workers with ``--dist loadscope``: whole modules go to a
# worker. xdist's own order (most tests first) handed out the colcon build and the
# multi-process node tests, a few slow tests each, last: one worker ran them while the other
# had finished. The modules go out longest first instead (test/durations.json, written by
# tools/test_durations.py), and the discrepancy modules that share the cached analyses of
# test/discrepancy/discrepancy_cases.py go to one worker, which then runs each analysis once.
_SHARED_ANALYSES = 'test/discrepancy (the cached analyses of discrepancy_cases.py)'
_SHARING = frozenset(f'test/discrepancy/test_{name}.py'
                     for name in ('candidates', 'localise', 'report', 'workflow'))


def _scope(nodeid: str) -> str:
    """The work unit of a test: its module, or the discrepancy modules' shared unit."""
    module = nodeid.split('::', 1)[0]
    return _SHARED_ANALYSES if module in _SHARING else module


def _seconds() -> dict[str, float]:
    """Each work unit's seconds in a recent run (0 for a module the file does not list)."""
    import json

    path = REPO / 'test' / 'durations.json'
    try:
        modules: dict[str, float] = json.loads(path.read_text(encoding='utf-8'))
    except (OSError, ValueError):
        return {}
    units: dict[str, float] = {}
    for module, seconds in modules.items():
        unit = _scope(module)
        units[unit] = units.get(unit, 0.0) + float(seconds)
    return units


@pytest.hookimpl(optionalhook=True)  # pytest -p no:xdist has no such hook
def pytest_xdist_make_scheduler(config: pytest.Config, log: Any) -> Any:
    """With ``--dist loadscope``: the longest work unit first, each worker taking the next
    when it is nearly done (another ``--dist`` keeps xdist's own scheduler)."""
    from xdist.scheduler import LoadScopeScheduling

    if config.getvalue('dist') != 'loadscope':
        return None
    seconds = _seconds()

    class LongestFirst(LoadScopeScheduling):  # type: ignore[misc]
        def _split_scope(self, nodeid: str) -> str:
            return _scope(nodeid)

        def _assign_work_unit(self, node: Any) -> None:
            longest = max(self.workqueue, key=lambda unit: seconds.get(unit, 0.0))
            self.workqueue.move_to_end(longest, last=False)
            super()._assign_work_unit(node)

    return LongestFirst(config, log)
