"""``galvo-sysid launch``: the nodes of launch/monitor.launch.py as child processes, stopped as one.

The commands (no processes), the launch file's nodes against them (with stand-ins for the
``launch`` packages, which are not installable here), the supervision of plain child
processes (signals, early ends, exit codes), and the real three nodes on a DDS graph.
"""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import subprocess
import sys
import time
import types
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.field.launcher import (
    LAUNCH_ARGUMENTS,
    NODE_MODULES,
    node_commands,
    normalize_namespace,
    parse_params_file,
)

if TYPE_CHECKING:
    from ros_graph import Graph

REPO = Path(__file__).resolve().parents[2]
LAUNCH_FILE = REPO / 'launch' / 'monitor.launch.py'


def _ros_args(argv: tuple[str, ...]) -> list[str]:
    return list(argv[argv.index('--ros-args') + 1:])


def test_default_commands_run_the_node_modules() -> None:
    commands = node_commands(python='/py')
    assert [c.name for c in commands] == ['galvo_driver', 'sysid', 'watchdog']
    for c in commands:
        assert c.argv == ('/py', '-m', NODE_MODULES[c.name], '--ros-args')
    assert [c.name for c in node_commands(driver=False)] == ['sysid', 'watchdog']


def test_commands_carry_namespace_files_and_model() -> None:
    commands = node_commands(namespace='scanner_1', model='/m/a b.yaml', params_files=[
        ('sysid', 's.yaml'), ('', 'all.yaml'), ('', 'all2.yaml'), ('watchdog', 'w.yaml')])
    args = {c.name: _ros_args(c.argv) for c in commands}
    model = ['-p', 'model:="/m/a b.yaml"']
    assert args['galvo_driver'] == ['-r', '__ns:=/scanner_1', '--params-file', 'all.yaml',
                                    '--params-file', 'all2.yaml', *model]
    assert args['sysid'] == ['-r', '__ns:=/scanner_1', '--params-file', 'all.yaml',
                             '--params-file', 'all2.yaml', '--params-file', 's.yaml', *model]
    assert args['watchdog'][-4:] == ['--params-file', 'w.yaml', *model]


@pytest.mark.parametrize(('text', 'expected'), [
    ('scanner_1', '/scanner_1'), ('/scanner_1/', '/scanner_1'), ('a/b_2', '/a/b_2'),
    ('', ''), ('/', '')])
def test_namespace(text: str, expected: str) -> None:
    assert normalize_namespace(text) == expected


@pytest.mark.parametrize('bad', ['1a', 'a-b', 'a//b', 'a b'])
def test_bad_namespace(bad: str) -> None:
    with pytest.raises(ConfigurationError, match='not a ROS namespace'):
        normalize_namespace(bad)


def test_params_file_for_all_or_one() -> None:
    assert parse_params_file('p.yaml') == ('', 'p.yaml')
    assert parse_params_file('sysid=p.yaml') == ('sysid', 'p.yaml')
    assert parse_params_file('./a=b.yaml') == ('', './a=b.yaml')
    for bad, reason in (('sysidd=p.yaml', "unknown node 'sysidd'"), ('sysid=', 'no parameter')):
        with pytest.raises(ConfigurationError, match=reason):
            parse_params_file(bad)


# ------------------------------------------------------------------------ the launch file

class _Argument:
    def __init__(self, name: str, *, default_value: str, description: str) -> None:
        self.name, self.default_value, self.description = name, default_value, description


class _Opaque:
    def __init__(self, *, function: Any) -> None:
        self.function = function


class _Configuration:
    def __init__(self, name: str) -> None:
        self.name = name

    def perform(self, context: dict[str, str]) -> str:
        return context[self.name]


class _Node:
    def __init__(self, **kwargs: Any) -> None:
        self.kwargs = kwargs


def _load_launch_file(monkeypatch: pytest.MonkeyPatch) -> types.ModuleType:
    """The launch file with stand-ins for the few launch classes it uses."""
    stand_ins = {
        'launch': {'LaunchDescription': list},
        'launch.actions': {'DeclareLaunchArgument': _Argument, 'OpaqueFunction': _Opaque},
        'launch.substitutions': {'LaunchConfiguration': _Configuration},
        'launch_ros': {},
        'launch_ros.actions': {'Node': _Node},
    }
    for name, attributes in stand_ins.items():
        module = types.ModuleType(name)
        for key, value in attributes.items():
            setattr(module, key, value)
        monkeypatch.setitem(sys.modules, name, module)
    spec = importlib.util.spec_from_file_location('monitor_launch', LAUNCH_FILE)
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _as_ros_args(node: _Node) -> list[str]:
    """What launch_ros gives a Node on its command line, in galvo-sysid launch's spelling."""
    kw = node.kwargs
    out = ['-r', f'__ns:=/{kw["namespace"]}'] if kw['namespace'] else []
    for p in kw['parameters']:
        out += ['--params-file', p] if isinstance(p, str) else \
            [x for k, v in p.items() for x in ('-p', f'{k}:={json.dumps(v)}')]
    return out


@pytest.mark.parametrize(('given', 'options'), [
    ({}, {}),
    ({'namespace': '/scanner_1', 'model': '/m/s.yaml'},
     {'namespace': 'scanner_1', 'model': '/m/s.yaml'}),
    ({'driver': 'false', 'params_file': 'all.yaml', 'sysid_params_file': 's.yaml',
      'galvo_driver_params_file': 'd.yaml'},
     {'driver': False, 'params_files': [('', 'all.yaml'), ('sysid', 's.yaml'),
                                        ('galvo_driver', 'd.yaml')]}),
    ({'driver': 'true', 'watchdog_params_file': 'w.yaml', 'params_file': 'a.yaml'},
     {'params_files': [('watchdog', 'w.yaml'), ('', 'a.yaml')]}),
])
def test_launch_file_starts_what_galvo_sysid_launch_starts(
        monkeypatch: pytest.MonkeyPatch, given: dict[str, str], options: dict[str, Any]) -> None:
    launch = _load_launch_file(monkeypatch)
    description = launch.generate_launch_description()
    arguments = {a.name: a for a in description if isinstance(a, _Argument)}
    assert tuple(arguments) == LAUNCH_ARGUMENTS
    assert all(a.description for a in arguments.values())
    (opaque,) = [a for a in description if isinstance(a, _Opaque)]
    context = {name: a.default_value for name, a in arguments.items()} | given
    nodes = opaque.function(context)
    assert all(n.kwargs['package'] == 'galvo_sysid' and n.kwargs['executable'] ==
               n.kwargs['name'] for n in nodes)
    launched = {n.kwargs['executable']: _as_ros_args(n) for n in nodes}
    expected = {c.name: _ros_args(c.argv) for c in node_commands(**options)}
    assert launched == expected


def test_launch_file_compiles_and_is_installed(repo: Path) -> None:
    compile(LAUNCH_FILE.read_text(), str(LAUNCH_FILE), 'exec')
    assert "(f'share/{PACKAGE}/launch', glob('launch/*.launch.py'))" in \
        (repo / 'setup.py').read_text()


# ------------------------------------------------------------------------ supervision

def _child(tmp: Path, name: str, *, on_sigint: str = 'sys.exit(0)', code: int | None = None
           ) -> str:
    """A child's Python: says it is ready (a file), then waits for SIGINT (or exits)."""
    body = (f'import signal, sys, time\n'
            f'signal.signal(signal.SIGINT, lambda *a: {on_sigint})\n'
            f'open({str(tmp / name)!r}, "w").close()\n')
    body += f'sys.exit({code})\n' if code is not None else 'time.sleep(120)\n'
    return body


def _supervisor(tmp: Path, children: dict[str, str], *, stop_timeout: float = 0.5
                ) -> subprocess.Popen[str]:
    commands = [(n, (sys.executable, '-c', body)) for n, body in children.items()]
    script = ('import sys\nfrom galvo_sysid.field.launcher import Command, supervise\n'
              f'sys.exit(supervise([Command(n, a) for n, a in {commands!r}], '
              f'stop_timeout={stop_timeout}, label="launch"))\n')
    return subprocess.Popen([sys.executable, '-c', script], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _wait_ready(tmp: Path, names: list[str], timeout: float = 30) -> None:
    end = time.monotonic() + timeout
    while not all((tmp / n).exists() for n in names):
        assert time.monotonic() < end, f'children not ready: {names}'
        time.sleep(0.05)


def _pids_of(parent: int) -> list[int]:
    from ros_graph import children

    return children(parent)


def test_sigint_stops_every_child_with_exit_code_0(tmp_path: Path) -> None:
    proc = _supervisor(tmp_path, {'a': _child(tmp_path, 'a'), 'b': _child(tmp_path, 'b')})
    _wait_ready(tmp_path, ['a', 'b'])
    kids = _pids_of(proc.pid)
    assert len(kids) == 2
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    lines = err.splitlines()
    assert lines[0].startswith('launch: started a (pid ')
    assert lines[-1] == 'launch: stopped: a, b'
    assert not any(Path(f'/proc/{pid}').exists() for pid in kids)


def test_a_child_ignoring_sigint_gets_sigterm_and_the_exit_code_says_so(tmp_path: Path) -> None:
    proc = _supervisor(tmp_path, {'good': _child(tmp_path, 'good'),
                                  'deaf': _child(tmp_path, 'deaf', on_sigint='None')})
    _wait_ready(tmp_path, ['good', 'deaf'])
    start = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 1
    assert 'launch: deaf still running: sending SIGTERM' in err.splitlines()
    assert 'launch: deaf was ended by SIGTERM while stopping' in err.splitlines()
    assert time.monotonic() - start < 10


def test_a_child_ending_early_is_said_in_one_line_and_the_rest_runs_on(tmp_path: Path) -> None:
    proc = _supervisor(tmp_path, {'early': _child(tmp_path, 'early', code=3),
                                  'late': _child(tmp_path, 'late')})
    _wait_ready(tmp_path, ['early', 'late'])
    time.sleep(0.5)
    assert proc.poll() is None  # 'late' still runs
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 1
    said = [line for line in err.splitlines() if 'early' in line and 'started' not in line]
    assert said == ['launch: early exited with code 3 (its output is above)']


def test_children_all_done_by_themselves(tmp_path: Path) -> None:
    proc = _supervisor(tmp_path, {'x': _child(tmp_path, 'x', code=0),
                                  'y': _child(tmp_path, 'y', code=0)})
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert 'launch: x exited with code 0' in err.splitlines()


# ------------------------------------------------------------------------ the real nodes

def test_galvo_sysid_launch_runs_the_three_nodes_and_stops_them(graph: Graph,
                                                               tmp_path: Path) -> None:
    """The three nodes appear in the namespace with the topics of NODE_TOPICS, the driver's
    moves, sysid's windows and both diagnostics flow (per-node parameter files taken);
    SIGINT stops everything (the fit processes too), exit code 0."""
    from diagnostic_msgs.msg import DiagnosticArray
    from galvo_sysid_msgs.msg import ModalParameters, MoveSamples
    from ros_graph import MOVES_QOS, RESULTS_QOS, alive, descendants

    from galvo_sysid.interfaces.topics import NODE_TOPICS, absolute_topic

    ns = f'launch_test_{os.getpid()}'
    driver = tmp_path / 'driver.yaml'  # a slow scanner, small windows: a few fits, soon
    driver.write_text('/**:\n  ros__parameters:\n    rate_factor: 0.05\n    angles: [0.3]\n')
    sysid = tmp_path / 'sysid.yaml'
    sysid.write_text('/**:\n  ros__parameters:\n    window_size: 4\n')
    statuses: set[str] = set()
    moves: list[int] = []
    windows: list[int] = []
    graph.node.create_subscription(
        ModalParameters, absolute_topic('galvo/modal_parameters', namespace=ns),
        lambda m: windows.append(m.window_index), RESULTS_QOS)
    graph.node.create_subscription(
        DiagnosticArray, '/diagnostics',
        lambda m: statuses.update(s.name for s in m.status if s.hardware_id == ns), 50)
    graph.node.create_subscription(MoveSamples, absolute_topic('galvo/current', namespace=ns),
                                   lambda m: moves.append(m.move_id), MOVES_QOS)
    launcher = graph.run([sys.executable, '-m', 'galvo_sysid.cli.main', 'launch',
                          '--namespace', ns, '--params-file', f'galvo_driver={driver}',
                          '--params-file', f'sysid={sysid}'], 'launch')

    def names() -> set[str]:
        return {n for n, space in graph.node.get_node_names_and_namespaces()
                if space == f'/{ns}'}

    graph.spin_until(lambda: names() >= set(NODE_TOPICS), 60, 'the three nodes on the graph')
    graph.spin_until(lambda: len(moves) >= 2 and windows and statuses >= {
        f'{ns}: identification', f'{ns}: plant drift'}, 60, 'moves, a window, both diagnostics')
    own = {'/rosout', '/parameter_events'}
    for node, topics in NODE_TOPICS.items():
        pubs = {t for t, _ in graph.node.get_publisher_names_and_types_by_node(node, f'/{ns}')}
        subs = {t for t, _ in graph.node.get_subscriber_names_and_types_by_node(node, f'/{ns}')}
        assert pubs - own == {absolute_topic(t, namespace=ns) for t, _ in topics.publishes}
        assert subs - own == {absolute_topic(t, namespace=ns) for t, _ in topics.subscribes}

    family = descendants(launcher.pid)  # the nodes, sysid's fork server and fit processes
    assert len(family) >= 6, family  # three nodes, a fork server, two fit processes
    launcher.popen.send_signal(signal.SIGINT)
    assert launcher.popen.wait(timeout=60) == 0, graph.logs()
    assert not [pid for pid in family if alive(pid)]
    text = launcher.text()
    assert 'galvo-sysid launch: stopped: galvo_driver, sysid, watchdog' in text
    assert 'Traceback' not in text
