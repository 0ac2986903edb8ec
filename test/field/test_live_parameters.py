"""``galvo-sysid param`` against the real nodes over Fast DDS (issue 15: field tools).

Each command is a separate process, as a user runs it; independent commands run side by side
(each new process discovers the graph afresh, which takes up to a few seconds). The node's
values are checked through the test's own parameter client, not through the tool.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from rclpy.parameter import Parameter
from ros_graph import together

from galvo_sysid.field.parameter_file import load_node_parameters
from galvo_sysid.monitor.parameters import SYSID_PARAMETERS, ParamSpec
from galvo_sysid.schema import load_yaml

if TYPE_CHECKING:
    from ros_graph import Graph

WAIT = ('--timeout', '20')  # generous: the machine may be loaded


def spec(name: str) -> ParamSpec:
    return next(s for s in SYSID_PARAMETERS if s.name == name)


def test_param_list_get_set_on_the_sysid_node(graph: Graph, venv_bin: Path) -> None:
    graph.start('sysid', 'sysid', '-p', 'fit_processes:=0')
    graph.get_parameters('/sysid', ['window_size'])  # the node is up
    listed, got, unknown = together(
        venv_bin, ('param', 'list', '/sysid', *WAIT),
        ('param', 'get', 'sysid', 'window_size', *WAIT),  # a name without / is taken from /
        ('param', 'get', '/sysid', 'window_sise', *WAIT))
    assert listed.returncode == 0, listed.stderr
    assert listed.stdout.split() == sorted({s.name for s in SYSID_PARAMETERS} |
                                           {'use_sim_time', 'start_type_description_service'})
    assert (got.returncode, got.stdout) == (0, 'Integer value is: 100\n'), got.stderr
    assert unknown.returncode == 1
    assert unknown.stderr.splitlines() == [
        "param: node /sysid has no parameter 'window_sise' (galvo-sysid param list /sysid)"]

    accepted, integer, negative, too_often = together(
        venv_bin, ('param', 'set', '/sysid', 'max_pending', '500', *WAIT),
        ('param', 'set', '/sysid', 'pair_timeout', '2', *WAIT),  # an integer for a double
        ('param', 'set', '/sysid', 'window_size', '-5', *WAIT),  # refused by its ROS range
        ('param', 'set', '/sysid', 'stats_period', '0.01', *WAIT))  # by the node's check
    for ok in (accepted, integer):
        assert (ok.returncode, ok.stdout, ok.stderr) == (0, 'Set parameter successful\n', '')
    assert negative.returncode == 1
    assert negative.stdout == ''
    [line] = negative.stderr.splitlines()
    # the node's reason (from rclpy's check of the declared range)
    assert line.startswith('Set parameter failed: Parameter window_size out of range'), line
    assert 'Min: 2,' in line, line
    assert line.endswith('value: -5'), line
    assert too_often.returncode == 1
    reason = spec('stats_period').check(0.01)
    assert reason is not None
    assert too_often.stderr == f'Set parameter failed: {reason}\n'
    # what the node holds now: the accepted values, the refused ones as they were
    assert graph.get_parameters('/sysid', ['max_pending', 'pair_timeout', 'window_size',
                                           'stats_period']) == {
        'max_pending': 500, 'pair_timeout': 2.0, 'window_size': 100, 'stats_period': 30.0}


def test_param_of_a_missing_node_is_one_line(venv_bin: Path) -> None:
    for call in (('param', 'get', '/no_such_node', 'window_size', '--timeout', '1'),
                 ('param', 'dump', 'no_such_node', '--timeout', '1')):
        [out] = together(venv_bin, call)
        assert out.returncode == 1
        assert out.stdout == ''
        assert out.stderr.splitlines() == [
            'param: node /no_such_node not found on the graph within 1 s']


def test_param_dump_round_trips_as_a_params_file(graph: Graph, venv_bin: Path,
                                                 tmp_path: Path) -> None:
    first = graph.start('watchdog', 'watchdog')
    changed = [Parameter('stale_timeout', Parameter.Type.DOUBLE, 2.5),
               Parameter('trend_windows', Parameter.Type.INTEGER, 5),
               Parameter('tolerances.k0', Parameter.Type.DOUBLE, 0.05),
               Parameter('hardware_id', Parameter.Type.STRING, 'line "A": 1e-6')]
    assert all(r.successful for r in graph.set_parameters('/watchdog', changed))
    [dump] = together(venv_bin, ('param', 'dump', '/watchdog', *WAIT))
    assert dump.returncode == 0, dump.stderr
    path = tmp_path / 'watchdog_now.yaml'
    path.write_text(dump.stdout)
    doc = load_yaml(path, what='dump')
    assert list(doc) == ['/watchdog']
    params = doc['/watchdog']['ros__parameters']
    assert params['stale_timeout'] == 2.5
    assert params['trend_windows'] == 5
    assert params['hardware_id'] == 'line "A": 1e-6'
    assert params['tolerances'] == {'k0': 0.05}  # the other tolerances are not set: left out
    # the strict offline reader (galvo-sysid identify --watchdog-params) takes it too
    offline = load_node_parameters(path, 'watchdog')
    assert offline['tolerances.k0'] == 0.05
    assert offline['stale_timeout'] == 2.5

    assert first.stop() == 0
    graph.start('watchdog', 'watchdog_again', '--params-file', str(path))
    names = [p.name for p in changed]
    assert graph.get_parameters('/watchdog', names) == {p.name: p.value for p in changed}
    [again] = together(venv_bin, ('param', 'dump', '/watchdog', *WAIT))
    assert again.returncode == 0, again.stderr
    assert again.stdout == dump.stdout
