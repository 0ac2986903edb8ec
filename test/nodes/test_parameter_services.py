"""Hostile parameters against the node executables (issue 12: defects 1, 12, 13, the log flood).

- Start-up: a malformed ``--params-file`` (not YAML, missing, an alias, not a mapping of
  nodes), a ``-p`` without ``:=``, an unknown ROS argument, an array with NaN or 0 or
  nothing, an integer given as 10.7, ``stats_period:=1e-6``: exit code 2 and one line
  ``error: ...`` on the console, no traceback (rcl's own RCLError gave exit 1 and one).
- Run time, over the standard rcl_interfaces SetParameters service: the galvo_driver's
  ``effects`` set to what killed it (an integer beyond float range, JSON nested 50,000 deep,
  parameters of the wrong type, a string for a number, an absurd delay), a parameter
  message of an unknown type code (rclpy itself raised in the service), angles that do not
  fit the scanner's record, a step that leaves the loop unstable: each refused with a
  one-line reason, the driver alive with its old values and no traceback; a valid effect is
  then accepted and takes effect.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters

from galvo_sysid.model.files import save_model
from galvo_sysid.sim.family import random_scanner

if TYPE_CHECKING:
    from ros_graph import Graph

VENV_BIN = Path(sys.executable).parent
MAX_REASON = 300  # galvo_sysid.nodes.framework.MAX_REASON: a reason is one line, this short


def _start(exe: str, *ros_args: str, timeout: float = 30.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(VENV_BIN / exe), '--ros-args', *ros_args], capture_output=True,
                          text=True, timeout=timeout, check=False)


def _console_lines(out: subprocess.CompletedProcess[str]) -> list[str]:
    """What the process said besides rclpy's INFO lines."""
    text = out.stdout + out.stderr
    return [line for line in text.splitlines() if line.strip() and not line.startswith('[INFO')]


@pytest.fixture(scope='module')
def files(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp('params')
    (d / 'syntax.yaml').write_text('sysid:\n  ros__parameters:\n    window_size: [1, {a: 2}\n')
    (d / 'alias.yaml').write_text('sysid:\n  ros__parameters: &p\n    window_size: 20\n'
                                  'galvo_driver:\n  ros__parameters: *p\n')
    (d / 'list.yaml').write_text('- 1\n- 2\n')
    (d / 'sections.yaml').write_text('sysid:\n  window_size: 20\n')
    (d / 'fraction.yaml').write_text('sysid:\n  ros__parameters:\n    window_size: 10.7\n')
    (d / 'flood.yaml').write_text('sysid:\n  ros__parameters:\n    stats_period: 1.0e-6\n')
    (d / 'model_format.yaml').write_text('format: galvo-scanner-model\n')
    (d / 'model_version.yaml').write_text('version: 7\n')
    (d / 'model_syntax.yaml').write_text('mechanics: [1, {a: 2}\n')
    save_model(random_scanner(2).model, d / 'one_mode.yaml')  # a scanner of one mode
    return d


START_CASES = [
    ('sysid', ('--params-file', '{d}/syntax.yaml'), 'cannot read parameter file'),
    ('sysid', ('--params-file', '{d}/missing.yaml'), 'missing.yaml'),
    ('sysid', ('--params-file', '{d}/alias.yaml'), 'alias'),
    ('sysid', ('--params-file', '{d}/list.yaml'), 'expected node names'),
    ('sysid', ('--params-file', '{d}/sections.yaml'), 'ros__parameters'),
    ('sysid', ('--params-file', '{d}/fraction.yaml'), 'window_size'),
    ('sysid', ('--params-file', '{d}/flood.yaml'), 'stats_period must be >= 0.1'),
    ('sysid', ('-p', 'stats_period:=1e-6'), 'stats_period must be >= 0.1'),
    ('sysid', ('-p', 'diagnostics_period:=1e-6'), 'diagnostics_period must be >= 0.1'),
    ('sysid', ('-p', 'window_size'), 'needs NAME:=VALUE'),
    ('sysid', ('-p', 'window_size:=10.7'), 'window_size'),
    ('sysid', ('--bogus',), 'unknown ROS arguments'),
    ('galvo_driver', ('-p', 'angles:=[nan]'), 'angles must be finite'),
    ('galvo_driver', ('-p', 'angles:=[0.0]'), 'angles must be >= 1e-06'),
    ('galvo_driver', ('-p', 'angles:=[0.3, 15.0]'), 'does not fit'),
    ('galvo_driver', ('-p', 'angles:=[]'), 'angles'),
    ('galvo_driver', ('-p', 'rate_factor:=1e-9'), 'rate_factor must be >= 0.001'),
    ('galvo_driver', ('-p', 'effects:=[{"effect": "coulomb_friction", "parameters": 5}]'),
     'quote text'),
    ('galvo_driver', ('-p', 'effects:=\'[{"effect": "coulomb_friction", "parameters": 5}]\''),
     'parameters must be a mapping'),
    ('galvo_driver', ('-p', 'angles:=[0.3, "a"]'), 'a list of one of them'),
    ('watchdog', ('-p', 'publish_rate:=1000.0'), 'publish_rate must be <= 10'),
    # a bad plant-model file (README: "a bad file: one line on stderr, exit code 2")
    ('sysid', ('-p', 'model:={d}/absent_model.yaml'), 'absent_model.yaml'),
    ('sysid', ('-p', 'model:={d}/model_format.yaml'), "format 'galvo-scanner-model' is not"),
    ('galvo_driver', ('-p', 'model:={d}/model_version.yaml'), 'unsupported version 7'),
    ('watchdog', ('-p', 'model:={d}/model_syntax.yaml'), 'model_syntax.yaml'),
    # a tolerance of a mode the model lacks (it was ignored without a word)
    ('watchdog', ('-p', 'model:={d}/one_mode.yaml', '-p', 'tolerances.omega_3:=0.01'),
     'has 1 mode(s): no mode 3 to judge'),
]


@pytest.mark.parametrize(('exe', 'args', 'said'), START_CASES,
                         ids=[f'{e}-{" ".join(a)[-40:]}' for e, a, _ in START_CASES])
def test_bad_start_up_parameters_exit_2_with_one_line(files: Path, exe: str,
                                                      args: tuple[str, ...], said: str) -> None:
    out = _start(exe, *(a.replace('{d}', str(files)) for a in args))
    lines = _console_lines(out)
    assert out.returncode == 2, (out.returncode, lines[-5:])
    assert len(lines) == 1, lines[:5]
    assert lines[0].startswith('error: '), lines
    assert said in lines[0], lines
    assert 'Traceback' not in out.stderr


def _value(kind: int, **fields: Any) -> ParameterValue:
    v = ParameterValue()
    v.type = kind
    for k, x in fields.items():
        setattr(v, k, x)
    return v


def _string(text: str) -> ParameterValue:
    return _value(ParameterType.PARAMETER_STRING, string_value=text)


def _friction(value: str) -> str:
    return '[{"effect": "coulomb_friction", "parameters": {"friction_current": ' + value + '}}]'


HOSTILE = [  # (name, value, a word of the reason)
    ('effects', _string(_friction('1' + '0' * 400)), 'too long'),  # OverflowError killed it
    ('effects', _value(200, string_value='[]'), 'Parameter.Type'),  # rclpy raised in the service
    ('angles', _value(ParameterType.PARAMETER_DOUBLE_ARRAY, double_array_value=[float('nan')]),
     'finite'),  # accepted: stopped the driver at the next cycle
    ('effects', _string('[{"effect": "coulomb_friction", "parameters": 5}]'), 'mapping'),
    ('effects', _string(_friction('"x"')), 'must be a number'),
    ('effects', _string('[' * 50_000 + ']' * 50_000), 'effects'),
    ('effects', _string('[' * 5_000 + ']' * 5_000), 'nested'),
    ('effects', _string(_friction('"' + 'x' * 60_000 + '"')), 'must be a number'),
    ('effects', _string(_friction('"1e2"')), 'must be a number'),
    ('effects', _string(_friction('NaN')), 'NaN'),
    ('effects', _string(_friction('1e400')), 'finite'),
    ('effects', _string('[{"effect": "input_delay", "parameters": {"delay": 1e8}}]'), 'delay'),
    ('effects', _string('[{"effect": "input_delay", "parameters": {"delay": 0.01}}]'),
     'unstable'),
    ('effects', _string('[{"effect": "gain_change", "parameters": {"gain_ratio": 100}}]'),
     'unstable'),
    ('effects', _value(ParameterType.PARAMETER_NOT_SET), 'undeclared'),
    ('angles', _value(ParameterType.PARAMETER_DOUBLE_ARRAY, double_array_value=[0.0]), '>='),
    ('angles', _value(ParameterType.PARAMETER_DOUBLE_ARRAY, double_array_value=[]), 'empty'),
    ('angles', _value(ParameterType.PARAMETER_DOUBLE_ARRAY, double_array_value=[0.3, 15.0]),
     'does not fit'),  # stopped the simulation at the next cycle
    ('angles', _value(ParameterType.PARAMETER_DOUBLE_ARRAY, double_array_value=[0.3] * 10_000),
     'at most 256'),
    ('rate_factor', _value(ParameterType.PARAMETER_DOUBLE, double_value=1e-300), '>= 0.001'),
    ('step.factor', _value(ParameterType.PARAMETER_DOUBLE, double_value=100.0), 'unstable'),
]


def _set(graph: Graph, node: str, params: list[ParameterMsg]) -> list[Any]:
    client = graph.node.create_client(SetParameters, f'{node}/set_parameters')
    graph.spin_until(client.service_is_ready, 30, f'{node}/set_parameters')
    request = SetParameters.Request(parameters=params)
    # one resend (a fresh client's first request can be lost); no answer: the node is gone
    response = graph._call(lambda: client.call_async(request), 'set_parameters', attempts=2,
                           timeout=10.0)
    graph.node.destroy_client(client)
    return list(response.results)


def test_driver_refuses_hostile_parameters_and_keeps_running(graph: Graph) -> None:
    ns = '/hostile_params'
    node = f'{ns}/galvo_driver'
    driver = graph.start('galvo_driver', 'driver', '-r', f'__ns:={ns}',
                         '-p', 'wait_for_subscribers:=5')
    names = ['effects', 'angles', 'rate_factor', 'step.factor', 'step.parameter']
    old = graph.get_parameters(node, names)
    ok = _set(graph, node, [ParameterMsg(name='step.parameter', value=_string('k0'))])
    assert ok[0].successful, ok[0].reason
    old['step.parameter'] = 'k0'
    for name, value, said in HOSTILE:
        result = _set(graph, node, [ParameterMsg(name=name, value=value)])[0]
        shown = f'{name} := {str(value)[:80]}: {result.reason}'
        print(shown)
        assert driver.running, f'{shown}\n{graph.logs()}'
        assert not result.successful, shown
        assert said in result.reason, shown
        assert '\n' not in result.reason
        assert len(result.reason) <= MAX_REASON
    # several parameters in one request: each answered, a bad type code among them
    mixed = _set(graph, node, [ParameterMsg(name='angles', value=_value(42)),
                               ParameterMsg(name='rate_factor', value=_value(
                                   ParameterType.PARAMETER_DOUBLE, double_value=2.0))])
    assert [r.successful for r in mixed] == [False, True]
    old['rate_factor'] = 2.0
    assert driver.running
    assert graph.get_parameters(node, names) == old  # nothing else changed
    # a valid effect is still accepted and acts on the plant from the next move
    valid = json.dumps([{'effect': 'coulomb_friction', 'parameters': {'friction_current': 0.05}}])
    ok = _set(graph, node, [ParameterMsg(name='effects', value=_string(valid))])
    assert ok[0].successful, ok[0].reason
    assert graph.get_parameters(node, ['effects']) == {'effects': valid}
    graph.spin_until(lambda: '"friction_current": 0.05' in driver.text(), 10,
                     'the plant effect applied')
    assert driver.running
    assert 'Traceback' not in driver.text()
    assert driver.stop() == 0
