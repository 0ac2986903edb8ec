"""The repository as a ROS user builds it: both packages with colcon, the nodes run after sourcing.

A user clones the repository into ``ws/src/galvo_sysid`` and runs, in ``ws``, what the README
says: ``colcon build --base-paths src src/galvo_sysid/msg_defs`` (colcon stops crawling at a
directory holding a ``package.xml``, and the repository root is the galvo_sysid package, so
``msg_defs/``, the galvo_sysid_msgs package, is named as a base path of its own), then
``source install/setup.bash`` and ``ros2 run galvo_sysid sysid`` (which executes
``install/galvo_sysid/lib/galvo_sysid/sysid``). ``ros2 run`` and ``launch`` are not installable
here; the venv stands in for ``/opt/ros/jazzy`` (``PATH``, ``AMENT_PREFIX_PATH``,
``CMAKE_PREFIX_PATH``). One build (module fixture) serves every check; the installed node is
checked to load the workspace's galvo_sysid and galvo_sysid_msgs, not the venv's copies.
"""

from __future__ import annotations

import ast
import os
import shlex
import shutil
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from ros_graph import Graph

REPO = Path(__file__).resolve().parents[1]
VENV = Path(sys.prefix)
EXECUTABLES = ('galvo_driver', 'sysid', 'watchdog', 'galvo-sysid')
BASE_PATHS = ('src', 'src/galvo_sysid/msg_defs')
"""The build command of the README: ``colcon build --base-paths src src/galvo_sysid/msg_defs``."""

_NOT_COPIED = {'.git', '.venv', 'build', 'install', 'log', 'out'}  # at the root: not in a clone
_NEVER_COPIED = shutil.ignore_patterns('__pycache__', '*.egg-info', '.pytest_cache',
                                       '.mypy_cache', '.ruff_cache', '.hypothesis')


@dataclass(frozen=True)
class Workspace:
    """A colcon workspace with this repository in ``src/galvo_sysid``, built."""

    root: Path
    seconds: float

    @property
    def install(self) -> Path:
        return self.root / 'install'


def _clone(ws: Path) -> Path:
    """The repository's files in ``ws/src/galvo_sysid``, as a clone has them."""
    target = ws / 'src' / 'galvo_sysid'

    def ignore(directory: str, names: list[str]) -> set[str]:
        skip = set(_NEVER_COPIED(directory, names))
        if Path(directory) == REPO:
            skip |= _NOT_COPIED & set(names)
        return skip

    shutil.copytree(REPO, target, ignore=ignore, symlinks=True)
    return target


def _user_env() -> dict[str, str]:
    """A ROS user's shell after ``source /opt/ros/jazzy/setup.bash`` (the venv stands in)."""
    env = {k: v for k, v in os.environ.items()
           if k not in ('PYTHONPATH', 'AMENT_PREFIX_PATH', 'CMAKE_PREFIX_PATH',
                        'COLCON_PREFIX_PATH', 'COLCON_DEFAULTS_FILE', 'COLCON_HOME')}
    env.update(PATH=f'{VENV / "bin"}{os.pathsep}{os.environ.get("PATH", "")}',
               AMENT_PREFIX_PATH=str(VENV), CMAKE_PREFIX_PATH=str(VENV))
    return env


def _colcon(ws: Path, *args: str, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(VENV / 'bin' / 'colcon'), *args], cwd=ws, env=_user_env(),
                          capture_output=True, text=True, timeout=timeout, check=False)


def _sourced(ws: Path, command: str) -> list[str]:
    """``bash -c 'source install/setup.bash && COMMAND'`` in ``ws``, as argv."""
    return ['bash', '-c', f'cd {shlex.quote(str(ws))} && source install/setup.bash && {command}']


@pytest.fixture(scope='module')
def workspace(tmp_path_factory: pytest.TempPathFactory) -> Workspace:
    """The repository cloned into a fresh workspace and built with the README's command."""
    ws = tmp_path_factory.mktemp('ws')
    _clone(ws)
    start = time.monotonic()
    result = _colcon(ws, 'build', '--base-paths', *BASE_PATHS,
                     '--event-handlers', 'console_direct-',
                     # here only: the venv's Python stands in for the ROS install's
                     '--cmake-args', '-DBUILD_TESTING=OFF',
                     f'-DPython3_EXECUTABLE={sys.executable}')
    seconds = time.monotonic() - start
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    print(f'\ncolcon build of both packages: {seconds:.1f} s')  # shown with pytest -s
    return Workspace(ws, seconds)


# ------------------------------------------------------------------------ manifests

def test_package_xml_is_format_3(repo: Path) -> None:
    root = ET.parse(repo / 'package.xml').getroot()
    assert root.get('format') == '3'
    assert root.findtext('name') == 'galvo_sysid'
    assert root.findtext('export/build_type') == 'ament_python'
    msgs = ET.parse(repo / 'msg_defs' / 'package.xml').getroot()
    assert msgs.findtext('name') == 'galvo_sysid_msgs'
    assert msgs.findtext('member_of_group') == 'rosidl_interface_packages'


IMPORT_KEYS = {
    'rclpy': 'rclpy', 'rcl_interfaces': 'rcl_interfaces',
    'builtin_interfaces': 'builtin_interfaces', 'diagnostic_msgs': 'diagnostic_msgs',
    'galvo_sysid_msgs': 'galvo_sysid_msgs', 'numpy': 'python3-numpy', 'scipy': 'python3-scipy',
    'yaml': 'python3-yaml', 'matplotlib': 'python3-matplotlib',
    'rosbags': 'python3-rosbags-pip', 'control': 'python-control-pip',
    'lz4': 'python3-rosbags-pip', 'backports': 'python3-rosbags-pip',  # rosbags brings them
    'compression': None,  # the standard library's zstd from Python 3.14 (else backports)
}
"""The rosdep key of each top-level module galvo_sysid imports (not the standard library's)."""

USED_WITHOUT_IMPORT = {
    'std_msgs': 'the messages carry std_msgs/Header (interfaces/messages.py fills it)',
    'rosgraph_msgs': 'replay publishes /clock, its type looked up by name',
    'launch': 'launch/monitor.launch.py', 'launch_ros': 'launch/monitor.launch.py',
    'ros2launch': 'ros2 launch galvo_sysid monitor.launch.py',
}


def _top_level_imports(paths: list[Path]) -> set[str]:
    found: set[str] = set()
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'))):
            if isinstance(node, ast.Import):
                found |= {a.name.split('.')[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                found.add(node.module.split('.')[0])
    return found - set(sys.stdlib_module_names) - {'galvo_sysid'}


def test_exec_depends_are_what_the_code_uses(repo: Path) -> None:
    root = ET.parse(repo / 'package.xml').getroot()
    depends = {e.text for e in root.findall('exec_depend')}
    imported = _top_level_imports(sorted((repo / 'galvo_sysid').rglob('*.py')))
    assert imported <= set(IMPORT_KEYS), f'no rosdep key known for {imported - set(IMPORT_KEYS)}'
    needed = {IMPORT_KEYS[m] for m in imported} - {None}
    assert depends == needed | set(USED_WITHOUT_IMPORT)
    assert _top_level_imports([repo / 'launch' / 'monitor.launch.py']) == {'launch', 'launch_ros'}
    assert 'sensor_msgs' not in (repo / 'requirements.txt').read_text().replace('-', '_')


# ------------------------------------------------------------------------ finding the packages

def test_colcon_finds_msg_defs_only_where_it_is_named(tmp_path: Path, repo: Path) -> None:
    """Crawling src alone stops at the repository root; the README's base paths, or the
    workspace defaults file of tools/, find both packages (and the other packages of src)."""
    ws = tmp_path / 'ws'
    (ws / 'src').mkdir(parents=True)
    (ws / 'src' / 'galvo_sysid').symlink_to(repo)
    other = ws / 'src' / 'other_pkg'
    other.mkdir()
    (other / 'package.xml').write_text(
        '<?xml version="1.0"?>\n<package format="3"><name>other_pkg</name><version>0.0.0'
        '</version><description>x</description><maintainer email="a@b.c">a</maintainer>'
        '<license>MIT</license><export><build_type>ament_cmake</build_type></export></package>\n')
    (other / 'CMakeLists.txt').write_text('project(other_pkg)\n')

    def names(*args: str) -> list[str]:
        result = _colcon(ws, 'list', '--names-only', *args, timeout=120)
        assert result.returncode == 0, result.stderr
        return sorted(result.stdout.split())

    assert names('--base-paths', 'src') == ['galvo_sysid', 'other_pkg']
    assert names('--base-paths', *BASE_PATHS) == ['galvo_sysid', 'galvo_sysid_msgs', 'other_pkg']
    shutil.copy(repo / 'tools' / 'colcon_defaults.yaml', ws / 'colcon_defaults.yaml')
    assert names() == ['galvo_sysid', 'galvo_sysid_msgs', 'other_pkg']


# ------------------------------------------------------------------------ the installed packages

def test_colcon_build_installs_both_packages(workspace: Workspace) -> None:
    prefix = workspace.install / 'galvo_sysid'
    for exe in EXECUTABLES:
        path = prefix / 'lib' / 'galvo_sysid' / exe
        assert path.is_file(), f'{exe} missing from {path.parent}'
        assert os.access(path, os.X_OK)
    for package in ('galvo_sysid', 'galvo_sysid_msgs'):
        assert (workspace.install / package / 'share' / 'ament_index' / 'resource_index'
                / 'packages' / package).is_file()
        assert (workspace.install / package / 'share' / package / 'package.xml').is_file()
    share = prefix / 'share' / 'galvo_sysid'
    assert {p.name for p in (share / 'config').iterdir()} >= {
        'driver.yaml', 'sysid.yaml', 'watchdog.yaml', 'fastdds_localhost.xml'}
    assert (share / 'models' / 'paper_table1.yaml').is_file()
    launch_file = share / 'launch' / 'monitor.launch.py'
    compile(launch_file.read_text(), str(launch_file), 'exec')  # launch itself is not here
    assert (workspace.install / 'galvo_sysid_msgs' / 'share' / 'galvo_sysid_msgs' / 'msg'
            / 'MoveSamples.msg').is_file()


def test_installed_executables_print_their_usage(workspace: Workspace) -> None:
    from galvo_sysid.nodes.command_line import usage

    lib = 'install/galvo_sysid/lib/galvo_sysid'
    command = ' && '.join(f'{lib}/{exe} --help > {exe}.txt' for exe in EXECUTABLES)
    result = subprocess.run(_sourced(workspace.root, command), env=_user_env(),
                            capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 0, result.stderr
    for exe in ('galvo_driver', 'sysid', 'watchdog'):
        assert (workspace.root / f'{exe}.txt').read_text() == usage(exe)
    assert (workspace.root / 'galvo-sysid.txt').read_text().startswith('usage: galvo-sysid')


def test_sourced_workspace_runs_its_own_packages(workspace: Workspace) -> None:
    """After sourcing, Python imports galvo_sysid and galvo_sysid_msgs from the workspace."""
    python = (workspace.install / 'galvo_sysid' / 'lib' / 'galvo_sysid' / 'sysid'
              ).read_text().splitlines()[0].removeprefix('#!')
    script = 'import galvo_sysid, galvo_sysid_msgs.msg; print(galvo_sysid.__file__); ' \
             'print(galvo_sysid_msgs.__file__)'
    result = subprocess.run(_sourced(workspace.root, f'{python} -c {shlex.quote(script)}'),
                            env=_user_env(), capture_output=True, text=True, timeout=120,
                            check=False)
    assert result.returncode == 0, result.stderr
    files = result.stdout.split()
    assert files[0].startswith(str(workspace.install / 'galvo_sysid' / 'lib'))
    assert files[1].startswith(str(workspace.install / 'galvo_sysid_msgs' / 'lib'))


def test_installed_sysid_runs_and_publishes(workspace: Workspace, graph: Graph) -> None:
    """``ros2 run galvo_sysid sysid`` as it runs: the installed executable after sourcing,
    its diagnostics on /diagnostics, the workspace's message libraries loaded; Ctrl-C: 0."""
    from diagnostic_msgs.msg import DiagnosticArray

    scanner = f'layout_{os.getpid()}'
    seen: list[str] = []
    graph.node.create_subscription(
        DiagnosticArray, '/diagnostics',
        lambda m: seen.extend(s.name for s in m.status if s.hardware_id == scanner), 10)
    node = graph.run(_sourced(workspace.root, 'exec install/galvo_sysid/lib/galvo_sysid/sysid '
                              f'--ros-args -r __ns:=/{scanner}'), 'installed_sysid',
                     env=_user_env())
    graph.spin_until(lambda: f'{scanner}: identification' in seen, 60,
                     'diagnostics from the installed sysid')
    maps = Path(f'/proc/{node.pid}/maps').read_text()
    libs = {line.split()[-1] for line in maps.splitlines() if 'galvo_sysid_msgs' in line}
    assert libs, 'no galvo_sysid_msgs library loaded'
    assert all(lib.startswith(str(workspace.install / 'galvo_sysid_msgs')) for lib in libs), libs
    assert node.stop() == 0, node.text()
    assert 'Traceback' not in node.text()
