"""Property tests of the live parameter services (issue 12): random values of random types.

The real driver, sysid and watchdog nodes run in this process (their own rclpy context and
executor thread, sysid fitting on a thread); a client in another context sets parameters
over the standard rcl_interfaces ``SetParameters`` service, one request per example
(hypothesis, seeded, a few dozen examples per node). Each example is drawn either from a
parameter's documented domain (its default's type, its range, its choices; for the
driver's ``effects`` an effect of the registry with a value the scanner can run) or from
outside it (another type, an unknown type code, NaN, infinity, out of range, a list too
long or holding NaN/0, control characters, text too long, hostile JSON, a read-only or an
undeclared parameter, an attempt to unset one). Asserted:

- the nodes stay alive: no exception leaves a callback of theirs;
- every value outside the domain is refused with a reason (one line, at most
  ``MAX_REASON`` characters) and the node keeps its old value;
- every value inside is accepted and takes effect: the node's value, ROS's value and what
  the node does with it (the sysid windower's settings, the fit's method and orders, the
  counters' timer; the watchdog's monitor options and stale timeout; the driver's plant
  effects and step change).
"""

from __future__ import annotations

import json
import math
import threading
from typing import TYPE_CHECKING, Any

import pytest
from hypothesis import HealthCheck, Phase, example, given, seed, settings
from hypothesis import strategies as st
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter

from galvo_sysid.model import load_model
from galvo_sysid.model.effects import effects_from_list
from galvo_sysid.monitor.parameters import (
    MONITOR_PARAMETERS,
    NODE_PARAMETERS,
    WINDOWER_PARAMETERS,
    ParamSpec,
)

if TYPE_CHECKING:
    from collections.abc import Iterator

    from ros_graph import Graph

NS = '/param_properties'
MAX_REASON = 300  # galvo_sysid.nodes.framework.MAX_REASON
EXAMPLES = 50

# Parameters whose valid values depend on others (drawn only invalid here: the node-level
# relations are tested in test_reliability_faults and test_parameter_services), or that
# would make the in-process driver start moving or exit.
RELATED = {
    'sysid': {'samples', 'max_samples', 'max_buffered_samples', 'max_buffered_bytes'},
    'galvo_driver': {'wait_for_subscribers', 'wait_timeout', 'exit_when_done', 'cycles'},
    'watchdog': set(),
}
T = ParameterType


class Servers:
    """The three nodes in their own context, spun on a thread that records any exception."""

    def __init__(self) -> None:
        import rclpy

        from galvo_sysid.nodes.driver_node import DriverNode
        from galvo_sysid.nodes.sysid_node import SysidNode
        from galvo_sysid.nodes.watchdog_node import WatchdogNode

        self.context = Context()
        rclpy.init(context=self.context)
        common = {'context': self.context, 'namespace': NS}
        self.nodes: dict[str, Any] = {
            'galvo_driver': DriverNode(**common, parameter_overrides=[
                Parameter('wait_for_subscribers', value=1000)]),
            'sysid': SysidNode(**common, parameter_overrides=[
                Parameter('fit_processes', value=0), Parameter('stats_period', value=0.0)]),
            'watchdog': WatchdogNode(**common),
        }
        self.errors: list[BaseException] = []
        self.executor = SingleThreadedExecutor(context=self.context)
        for n in self.nodes.values():
            self.executor.add_node(n)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except Exception as err:  # a crash of a node: what the test looks for
                self.errors.append(err)

    def close(self) -> None:
        import rclpy

        self._stop.set()
        self._thread.join(timeout=10)
        for n in self.nodes.values():
            n.close() if hasattr(n, 'close') else None
            n.destroy_node()
        self.executor.shutdown()
        rclpy.shutdown(context=self.context)


@pytest.fixture(scope='module')
def servers() -> Iterator[Servers]:
    s = Servers()
    try:
        yield s
    finally:
        s.close()


# -- values as messages ------------------------------------------------------------------

def _msg(kind: int, value: Any = None) -> ParameterValue:
    field = {T.PARAMETER_BOOL: 'bool_value', T.PARAMETER_INTEGER: 'integer_value',
             T.PARAMETER_DOUBLE: 'double_value', T.PARAMETER_STRING: 'string_value',
             T.PARAMETER_BYTE_ARRAY: 'byte_array_value',
             T.PARAMETER_BOOL_ARRAY: 'bool_array_value',
             T.PARAMETER_INTEGER_ARRAY: 'integer_array_value',
             T.PARAMETER_DOUBLE_ARRAY: 'double_array_value',
             T.PARAMETER_STRING_ARRAY: 'string_array_value'}.get(kind)
    v = ParameterValue()
    v.type = kind
    if field is not None:
        setattr(v, field, value)
    return v


def _as_msg(value: Any) -> ParameterValue:
    """A Python value (of a declared type) as the message that carries it."""
    if isinstance(value, bool):
        return _msg(T.PARAMETER_BOOL, value)
    if isinstance(value, int):
        return _msg(T.PARAMETER_INTEGER, value)
    if isinstance(value, float):
        return _msg(T.PARAMETER_DOUBLE, value)
    if isinstance(value, str):
        return _msg(T.PARAMETER_STRING, value)
    return _msg(T.PARAMETER_DOUBLE_ARRAY, [float(v) for v in value])


ANY_TYPED = st.one_of(
    st.builds(lambda v: _msg(T.PARAMETER_BOOL, v), st.booleans()),
    st.builds(lambda v: _msg(T.PARAMETER_INTEGER, v), st.integers(-2**63, 2**63 - 1)),
    st.builds(lambda v: _msg(T.PARAMETER_DOUBLE, v), st.floats()),
    st.builds(lambda v: _msg(T.PARAMETER_STRING, v), st.text(max_size=200)),
    st.builds(lambda v: _msg(T.PARAMETER_BYTE_ARRAY, v), st.lists(st.binary(min_size=1,
                                                                           max_size=1))),
    st.builds(lambda v: _msg(T.PARAMETER_BOOL_ARRAY, v), st.lists(st.booleans())),
    st.builds(lambda v: _msg(T.PARAMETER_INTEGER_ARRAY, v),
              st.lists(st.integers(-2**63, 2**63 - 1))),
    st.builds(lambda v: _msg(T.PARAMETER_DOUBLE_ARRAY, v), st.lists(st.floats())),
    st.builds(lambda v: _msg(T.PARAMETER_STRING_ARRAY, v), st.lists(st.text(max_size=20))),
)
"""A value of any ROS type (the wrong one for most parameters)."""


def _ros_type(spec: ParamSpec) -> int | None:
    d = spec.default
    if d is None:
        return None  # dynamically typed: any number
    if isinstance(d, bool):
        return T.PARAMETER_BOOL
    if isinstance(d, int):
        return T.PARAMETER_INTEGER
    if isinstance(d, float):
        return T.PARAMETER_DOUBLE
    if isinstance(d, str):
        return T.PARAMETER_STRING
    return T.PARAMETER_DOUBLE_ARRAY


# -- the domain of each parameter ---------------------------------------------------------

_SAFE_EFFECTS = st.one_of(
    st.builds(lambda x: ('coulomb_friction', {'friction_current': x}),
              st.floats(0.0, 1.0)),
    st.builds(lambda x: ('current_saturation', {'current_limit': x}), st.floats(0.5, 1e3)),
    st.builds(lambda x: ('gain_change', {'gain_ratio': x}), st.floats(0.9, 1.1)),
    st.builds(lambda x: ('pivot_stiffness', {'natural_frequency': x}), st.floats(1.0, 1e3)),
    st.builds(lambda w, z, r: ('unmodeled_resonance', {'natural_frequency': w,
                                                       'damping_ratio': z, 'residue': r}),
              st.floats(2e5, 4e5), st.floats(0.05, 0.5), st.floats(-1e5, 1e5)),
    st.builds(lambda x: ('input_delay', {'delay': x}), st.floats(1.6e-5, 1.8e-5)),
)
"""Effects of the registry with values the paper's scanner runs with a stable loop."""

VALID_EFFECTS = st.lists(_SAFE_EFFECTS, max_size=3).map(
    lambda items: json.dumps([{'effect': n, 'parameters': p} for n, p in items]))

HOSTILE_EFFECTS = st.sampled_from([
    '[{"effect": "coulomb_friction", "parameters": 5}]',
    '[{"effect": "coulomb_friction", "parameters": {"friction_current": "x"}}]',
    '[{"effect": "coulomb_friction", "parameters": {"friction_current": "0.1"}}]',
    '[{"effect": "coulomb_friction", "parameters": {"friction_current": 1' + '0' * 400 + '}}]',
    '[{"effect": "coulomb_friction", "parameters": {"friction_current": NaN}}]',
    '[{"effect": "coulomb_friction", "parameters": {"friction_current": -1}}]',
    '[' * 50_000 + ']' * 50_000,
    '[' * 20 + ']' * 20,
    '[{"effect": "input_delay", "parameters": {"delay": 1e8}}]',
    '[{"effect": "input_delay", "parameters": {"delay": 0.01}}]',
    '[{"effect": "input_delay", "parameters": {"delay": 1e-9}}]',
    '[{"effect": "gain_change", "parameters": {"gain_ratio": 100}}]',
    '[{"effect": "warp_drive", "parameters": {}}]',
    '[{"effect": "coulomb_friction"}]',
    '{"effect": "coulomb_friction", "parameters": {"friction_current": 0.1}}',
    '[1, 2, 3]', 'null', '{not json', '"[]"',
    json.dumps([{'effect': 'none', 'parameters': {}}] * 40),
])


def _zero_off(spec: ParamSpec) -> bool:
    return bool(getattr(spec, 'zero_off', False))


def _numbers(spec: ParamSpec, *, integer: bool) -> st.SearchStrategy[Any]:
    lo = -1e9 if spec.low is None else spec.low
    hi = 1e9 if spec.high is None else spec.high
    if integer:
        out: st.SearchStrategy[Any] = st.integers(int(lo), int(hi))
        if spec.name == 'moves_per_angle':
            out = out.map(lambda v: v - v % 2 if v - v % 2 >= lo else v + 1)
    else:
        out = st.floats(lo, hi, exclude_min=spec.exclusive_low)
    if _zero_off(spec):
        out = st.one_of(st.just(0 if integer else 0.0), out)
    return out


def valid_values(node: str, spec: ParamSpec) -> st.SearchStrategy[Any] | None:
    """Values inside the parameter's documented domain (None: none drawn here)."""
    if spec.read_only or spec.name in RELATED[node]:
        return None
    d = spec.default
    if d is None:  # an optional tolerance: any positive number
        return st.one_of(st.floats(0.0, 1e6, exclude_min=True), st.integers(1, 10**6))
    if isinstance(d, bool):
        return st.booleans()
    if isinstance(d, int):
        if spec.name == 'trend_windows':
            return st.one_of(st.just(0), st.integers(8, 1000))
        if spec.name == 'trend_min_windows':
            return st.integers(3, 8)
        return _numbers(spec, integer=True)
    if isinstance(d, float):
        if spec.name == 'step.factor':
            return st.floats(0.95, 1.05)
        return _numbers(spec, integer=False)
    if isinstance(d, list):
        return st.lists(st.floats(0.01, 5.0), min_size=1, max_size=20)
    if spec.choices:
        return st.sampled_from(spec.choices)
    if spec.name == 'effects':
        return VALID_EFFECTS
    if spec.name in ('drift.parameter', 'step.parameter'):
        return st.sampled_from(['', 'k0', 'k1', 'omega_2', 'zeta_3', 'lag_time_constant',
                                'gain_ratio'])
    return st.text(st.characters(codec='utf-8', categories=('L', 'N', 'P', 'Zs')),
                   max_size=80)


def invalid_values(spec: ParamSpec) -> st.SearchStrategy[ParameterValue]:
    """Messages outside the parameter's domain."""
    kind = _ros_type(spec)
    wrong = ANY_TYPED.filter(
        lambda m: m.type != kind if kind is not None
        else m.type not in (T.PARAMETER_INTEGER, T.PARAMETER_DOUBLE))
    options = [wrong, st.integers(10, 255).map(lambda k: _msg(k)),
               st.just(_msg(T.PARAMETER_NOT_SET))]
    d = spec.default
    numbers: list[float] = [math.nan, math.inf, -math.inf]
    if spec.low is not None:
        numbers.append(spec.low - 1.0 if spec.low - 1.0 != 0 or not _zero_off(spec) else -1.0)
        if spec.exclusive_low:
            numbers.append(spec.low)
    if spec.high is not None:
        numbers.append(spec.high * 2 + 1)
    if _zero_off(spec) and spec.low is not None and spec.low > 0:
        numbers.append(spec.low / 2)
    if d is None or isinstance(d, float):
        options.append(st.sampled_from(numbers).map(lambda v: _msg(T.PARAMETER_DOUBLE, v)))
    elif isinstance(d, int) and not isinstance(d, bool):
        ints = [int(v) for v in numbers if math.isfinite(v) and abs(v) < 2**63]
        if spec.name == 'moves_per_angle':
            ints.append(3)
        if ints:
            options.append(st.sampled_from(ints).map(lambda v: _msg(T.PARAMETER_INTEGER, v)))
    elif isinstance(d, list):
        bad = st.one_of(st.just([math.nan]), st.just([0.0]), st.just([]), st.just([0.3] * 300),
                        st.just([0.3, -1.0]), st.just([0.3, 15.0]), st.just([math.inf]))
        options.append(bad.map(lambda v: _msg(T.PARAMETER_DOUBLE_ARRAY, v)))
    elif isinstance(d, str):
        texts = st.one_of(st.just('x' * 70_000), st.just('a\nb'), st.just('\x00'),
                          st.text(min_size=1, max_size=30).map(lambda t: t + '\x07'))
        if spec.choices:
            texts = st.one_of(texts, st.text(max_size=30).filter(
                lambda t: t not in spec.choices))
        if spec.name == 'effects':
            texts = st.one_of(texts, HOSTILE_EFFECTS)
        if spec.name in ('drift.parameter', 'step.parameter'):
            texts = st.one_of(texts, st.sampled_from(['k99', 'omega_0', 'nonsense', 'k']))
        options.append(texts.map(lambda v: _msg(T.PARAMETER_STRING, v)))
    return st.one_of(*options)


@st.composite
def examples(draw: st.DrawFn, node: str) -> tuple[str, ParameterValue, Any]:
    """(name, message, valid python value or the marker INVALID)."""
    specs = list(NODE_PARAMETERS[node])
    choice = draw(st.integers(0, 9))
    if choice == 0:  # a parameter the node does not have
        name = draw(st.sampled_from(['no_such_parameter', 'window_sise', 'tolerances.k99',
                                     '', 'a' * 300]))
        return name, draw(ANY_TYPED), INVALID
    spec = draw(st.sampled_from(specs))
    valid = valid_values(node, spec)
    if spec.read_only:
        return spec.name, _as_msg(spec.default if spec.default is not None else 1.0), INVALID
    if valid is not None and choice <= 6:
        value = draw(valid)
        return spec.name, _as_msg(value), value
    return spec.name, draw(invalid_values(spec)), INVALID


INVALID = object()


def _took_effect(node_name: str, node: Any, name: str, value: Any) -> None:
    """What the node does with an accepted value."""
    if node_name == 'sysid':
        windower = node.task.windower
        if name in WINDOWER_PARAMETERS and hasattr(windower, name):
            assert getattr(windower, name) == value, name
        if name in ('method', 'na', 'nb'):
            fit = node.task.fitter._fit
            got = fit.keywords['method'] if name == 'method' else \
                fit.keywords['options'][name]
            assert got == value, name
        if name == 'stats_period':
            timer = node._stats_timer
            assert (timer is None) == (value == 0), value
            if timer is not None:
                assert timer.timer_period_ns == pytest.approx(value * 1e9, abs=1), value
    elif node_name == 'watchdog':
        if name in MONITOR_PARAMETERS:
            assert getattr(node.task.monitor, name) == value, name
        if name == 'stale_timeout':
            assert node.task.stale_timeout == value
        short = name.removeprefix('tolerances.')
        if name.startswith('tolerances.') and short in node.task.monitor.tolerances:
            assert node.task.monitor.tolerances[short] == value, name
    elif node_name == 'galvo_driver':
        if name == 'effects':
            expected = load_model(None).with_effects(effects_from_list(json.loads(value))).physics()
            assert node.sim._base == expected
        values = node.params.values
        if name.startswith('step.'):
            steps = node.sim._steps
            wanted = bool(values['step.parameter']) and values['step.factor'] != 1.0
            assert len(steps) == (1 if wanted else 0), (values, steps)
            if wanted:
                assert (steps[0].parameter, steps[0].value) == \
                    (values['step.parameter'], values['step.factor'])


def _same(a: Any, b: Any) -> bool:
    if hasattr(a, 'tolist'):
        a = a.tolist()
    if hasattr(b, 'tolist'):
        b = b.tolist()
    return bool(a == b)


@pytest.mark.parametrize('node_name', ['galvo_driver', 'sysid', 'watchdog'])
def test_random_values_over_the_set_parameters_service(servers: Servers, graph: Graph,
                                                       node_name: str) -> None:
    node = servers.nodes[node_name]
    client = graph.node.create_client(SetParameters, f'{NS}/{node_name}/set_parameters')
    graph.spin_until(client.service_is_ready, 30, f'{node_name} set_parameters')
    seen = {'valid': 0, 'invalid': 0}

    @seed(12)
    @settings(max_examples=EXAMPLES, deadline=None, database=None,
              phases=[Phase.explicit, Phase.generate],  # no shrinking: bounded time
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                     HealthCheck.function_scoped_fixture])
    @given(example=examples(node_name))
    def run(example: tuple[str, ParameterValue, Any]) -> None:
        name, message, value = example
        before = dict(node.params.values)
        request = SetParameters.Request(parameters=[ParameterMsg(name=name, value=message)])
        response = graph._call(lambda: client.call_async(request), f'set {name}',
                               attempts=2, timeout=10.0)
        result = response.results[0]
        shown = f'{node_name} {name[:40]} := {str(message)[:160]} -> {result.reason!r}'
        assert not servers.errors, f'{shown}: {servers.errors!r}'
        if value is INVALID:
            seen['invalid'] += 1
            assert not result.successful, shown
            assert result.reason, shown
            assert '\n' not in result.reason, shown
            assert len(result.reason) <= MAX_REASON, shown
            assert node.params.values == before, shown
        else:
            seen['valid'] += 1
            assert result.successful, shown
            assert _same(node.params.values[name], value), shown
            assert _same(node.get_parameter(name).value, value), shown
            _took_effect(node_name, node, name, value)

    # the classes that ended a node before, always tried (besides the drawn ones)
    specs = NODE_PARAMETERS[node_name]
    name = specs[-1].name
    optional = next((s.name for s in specs if s.default is None), name)  # dynamically typed
    for case in ((name, _msg(200), INVALID), ('', _msg(T.PARAMETER_BOOL, False), INVALID),
                 (optional, _msg(T.PARAMETER_NOT_SET), INVALID)):
        run = example(case)(run)
    run()
    graph.node.destroy_client(client)
    assert not servers.errors
    print(node_name, seen)
    assert min(seen.values()) >= 5, seen  # both kinds were drawn
