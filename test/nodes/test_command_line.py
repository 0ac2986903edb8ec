"""The node executables' ``--help``: usage from the parameter registry and the topic table,
printed before ROS starts; ROS arguments still reach rcl."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from galvo_sysid.interfaces.topics import NODE_TOPICS
from galvo_sysid.monitor.parameters import NODE_PARAMETERS
from galvo_sysid.nodes.command_line import NODES, usage, wants_help

REPO = Path(__file__).resolve().parents[2]


def _env(log_dir: Path) -> dict[str, str]:
    path = os.environ.get('PYTHONPATH', '')
    return dict(os.environ, ROS_LOG_DIR=str(log_dir),
                PYTHONPATH=f'{REPO}{os.pathsep}{path}' if path else str(REPO))


def test_every_node_has_parameters_topics_and_a_module() -> None:
    assert set(NODES) == set(NODE_PARAMETERS) == set(NODE_TOPICS)
    setup = (REPO / 'setup.py').read_text()
    for node in NODES:  # the console script is the light entry point
        assert f"f'{node} = {{PACKAGE}}.nodes.command_line:{node}'" in setup


@pytest.mark.parametrize('node', sorted(NODES))
def test_usage_shows_every_parameter_and_topic(node: str) -> None:
    text = usage(node)
    lines = text.splitlines()
    assert lines[0].startswith(f'usage: {node} [-h] [--ros-args')
    for topic, msgtype in (*NODE_TOPICS[node].subscribes, *NODE_TOPICS[node].publishes):
        assert any(topic in line and line.rstrip().endswith(msgtype) for line in lines), topic
    for spec in NODE_PARAMETERS[node]:
        starts = [i for i, line in enumerate(lines) if line.startswith(f'  {spec.name} = ')]
        assert len(starts) == 1, spec.name
        end = starts[0] + 1
        while lines[end].startswith('    ') and not lines[end].startswith('      '):
            end += 1  # the head line, wrapped
        head = ' '.join(lines[starts[0]:end])
        assert ('read-only' in head) is spec.read_only, spec.name
        assert all(choice in head for choice in spec.choices), spec.name
        assert lines[end].startswith('      '), spec.name  # the description follows


def test_usage_states_defaults_and_ranges() -> None:
    sysid = usage('sysid')
    assert '  window_size = 100   (integer, 2..100000)\n' in sysid
    assert '  pair_timeout = 1.0   (float, > 0 and <= 3600)\n' in sysid
    assert '  stats_period = 30.0   (float, 0 (off) or 0.1..1e+06)\n' in sysid
    assert ('  qos_reliability = "reliable"   (text, one of reliable, best_effort, read-only: set '
            'at start-up)\n') in sysid
    watchdog = usage('watchdog')
    assert '  tolerances.omega_2 = (not set)   (number, optional, > 0 and <= 1e+06)\n' in watchdog
    driver = usage('galvo_driver')
    assert '(list of floats, 1..256 values, each 1e-06..20)' in driver
    assert '  exit_when_done = false   (boolean)\n' in driver


@pytest.mark.parametrize(('argv', 'expected'), [
    (['sysid', '--help'], True),
    (['sysid', '-h'], True),
    (['sysid', '--help', '--ros-args', '-p', 'window_size:=50'], True),
    (['sysid', '--ros-args', '-r', '__ns:=/a', '--', '--help'], True),
    (['sysid'], False),
    (['sysid', '--ros-args', '--help'], False),  # a ROS argument: rcl's to refuse
    (['sysid', '--ros-args', '-p', 'window_size:=50'], False),
    (['--help'], False),  # the program name is not an argument
])
def test_wants_help(argv: list[str], expected: bool) -> None:
    assert wants_help(argv) is expected


@pytest.mark.parametrize('node', sorted(NODES))
def test_help_exits_0_before_ros(node: str, tmp_path: Path) -> None:
    """The console script's entry point prints the usage without importing rclpy; a node
    module's own main (``python -m``) prints it without initialising rclpy (no log file)."""
    script = (f'import sys\nfrom galvo_sysid.nodes.command_line import {node}\n'
              f'sys.argv = ["/opt/bin/{node}", "--help"]\ncode = {node}()\n'
              f'assert "rclpy" not in sys.modules, "rclpy imported"\nsys.exit(code)\n')
    logs = tmp_path / 'log'
    proc = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                          env=_env(logs), timeout=60, check=False)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == usage(node)
    assert proc.stderr == ''
    if node == 'sysid':  # the node modules' main share print_help: one of them is enough
        proc = subprocess.run([sys.executable, '-m', NODES[node].module, '--help'],
                              capture_output=True, text=True, env=_env(logs), timeout=60,
                              check=False)
        assert proc.returncode == 0, proc.stderr
        assert proc.stdout == usage(node)
    assert not logs.exists() or not any(logs.iterdir()), 'rclpy was initialised'


def test_ros_arguments_still_reach_rclpy(tmp_path: Path) -> None:
    """Through the light entry point: a ROS parameter out of range is refused by the node."""
    script = ('import sys\nfrom galvo_sysid.nodes.command_line import sysid\n'
              'sys.argv = ["sysid", "--ros-args", "-p", "window_size:=1"]\nsys.exit(sysid())\n')
    proc = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                          env=_env(tmp_path / 'log'), timeout=60, check=False)
    assert proc.returncode == 2, proc.stderr
    assert 'window_size' in proc.stderr
    assert 'out of range' in proc.stderr
    proc = subprocess.run([sys.executable, '-m', NODES['sysid'].module, '--ros-args', '--help'],
                          capture_output=True, text=True, env=_env(tmp_path / 'log'),
                          timeout=60, check=False)
    assert proc.returncode == 2
    assert proc.stderr.strip() == ("error: unknown ROS arguments ['--help'] (the usage: --help "
                                   'before --ros-args)')


def test_a_measured_currents_lag_the_model_cannot_take_stops_the_start(tmp_path: Path) -> None:
    """current:=measured with a lag of 1,000 sample periods of the model (1e-5 s): one line
    naming it, exit code 2, before any move is taken."""
    script = ('import sys\nfrom galvo_sysid.nodes.command_line import sysid\n'
              'sys.argv = ["sysid", "--ros-args", "-p", "current:=measured", "-p", '
              '"measured_current_lag:=0.01"]\nsys.exit(sysid())\n')
    proc = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                          env=_env(tmp_path / 'log'), timeout=60, check=False)
    assert proc.returncode == 2, proc.stderr
    assert 'an amplifier lag of 0.01 s is 1e+03 sample periods: above 20' in proc.stderr
    assert 'Traceback' not in proc.stderr
