"""The node parameters, one source (galvo_sysid.monitor.parameters): the nodes, the windower
and the monitor, the command line and config/*.yaml all agree with it."""

from __future__ import annotations

import inspect
import math
from pathlib import Path

import pytest

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.field.parameter_file import load_node_parameters
from galvo_sysid.ident.methods import METHODS
from galvo_sysid.monitor.drift import DriftMonitor
from galvo_sysid.monitor.pairing import MoveWindower
from galvo_sysid.monitor.parameters import (
    DECLARED_MODES,
    MONITOR_PARAMETERS,
    NODE_PARAMETERS,
    SYSID_PARAMETERS,
    WATCHDOG_PARAMETERS,
    WINDOWER_PARAMETERS,
    ParamSpec,
    defaults,
    tolerance_specs,
)
from galvo_sysid.monitor.tolerances import DEFAULT_KIND_TOLERANCES, DEFAULT_TOLERANCES

CONFIG_FILES = {'galvo_driver': 'driver.yaml', 'sysid': 'sysid.yaml',
                'watchdog': 'watchdog.yaml'}


@pytest.mark.parametrize('node', sorted(CONFIG_FILES))
def test_config_files_declare_every_parameter_with_its_default(node: str, repo: Path) -> None:
    values = load_node_parameters(repo / 'config' / CONFIG_FILES[node], node)
    specs = {s.name: s for s in NODE_PARAMETERS[node]}
    assert sorted(set(values) - set(specs)) == []  # no key the node does not declare
    assert sorted(set(specs) - set(values)) == []  # every parameter spelled out
    for name, value in values.items():
        spec = specs[name]
        # an optional number (the tolerances) is spelled out with the value it stands for
        expected = spec.default if spec.default is not None else spec.builtin
        assert value == expected, (node, name)
        # ROS takes a parameter's type from its default: a file giving 0 for 0.0 is refused
        assert type(value) is type(expected), (node, name)
        if isinstance(expected, list):
            assert [type(v) for v in value] == [type(v) for v in expected], (node, name)


@pytest.mark.parametrize('node', sorted(NODE_PARAMETERS))
def test_every_default_passes_its_own_check(node: str) -> None:
    specs = NODE_PARAMETERS[node]
    assert len({s.name for s in specs}) == len(specs)  # no name twice
    for s in specs:
        assert s.check(s.default) is None, s.name
        if s.builtin is not None:
            assert s.default is None
            assert s.check(s.builtin) is None, s.name
        if s.low is not None and s.high is not None:
            assert s.low <= s.high, s.name
        if s.choices:
            assert s.default in s.choices, s.name


def test_the_windower_and_the_monitor_take_their_defaults_from_here() -> None:
    sysid, watchdog = defaults('sysid'), defaults('watchdog')
    windower = inspect.signature(MoveWindower).parameters
    monitor = inspect.signature(DriftMonitor).parameters
    assert WINDOWER_PARAMETERS == ('window_size', 'samples', 'max_samples', 'pair_timeout',
                                   'time_jump', 'max_pending', 'max_windows',
                                   'max_buffered_bytes', 'window_timeout')
    assert MONITOR_PARAMETERS == ('warn_fraction', 'n_sigma', 'trend_windows',
                                  'trend_min_windows', 'trend_sigma', 'trend_fraction',
                                  'step_fraction', 'min_fit_percent')
    for name in WINDOWER_PARAMETERS:
        assert windower[name].default == sysid[name], name
    for name in MONITOR_PARAMETERS:
        assert monitor[name].default == watchdog[name], name
    # the ranges the monitor checks are the parameters'
    specs = {s.name: s for s in WATCHDOG_PARAMETERS}
    with pytest.raises(ConfigurationError, match=r'warn_fraction must be within \[0.0, 1.0\]'):
        DriftMonitor(warn_fraction=1.5)
    assert (specs['n_sigma'].low, specs['n_sigma'].high) == (0.0, 100.0)


def test_defaults_for_the_command_line() -> None:
    sysid = defaults('sysid')
    # what galvo-sysid identify started from before (cli/main.py)
    assert {k: sysid[k] for k in ('window_size', 'method', 'na', 'nb', 'model')} == \
        {'window_size': 100, 'method': 'refined', 'na': 15, 'nb': 15, 'model': ''}
    driver = defaults('galvo_driver')
    driver['angles'].append(9.0)  # a copy: the spec's list is left alone
    assert defaults('galvo_driver')['angles'][-1] == 3.0
    assert defaults('watchdog')['tolerances.k0'] is None  # not set: the built-in rule
    with pytest.raises(ConfigurationError, match='unknown node'):
        defaults('driver')


def test_one_list_of_methods_and_tolerances() -> None:
    method = next(s for s in SYSID_PARAMETERS if s.name == 'method')
    assert method.choices is METHODS
    assert method.text == 'identification method (one of: refined, paper-A, paper-B)'
    declared = {s.name: s for s in WATCHDOG_PARAMETERS}
    for name, value in DEFAULT_TOLERANCES.items():
        assert declared[f'tolerances.{name}'].builtin == value
    for kind, value in DEFAULT_KIND_TOLERANCES.items():
        assert declared[f'tolerances.{kind}'].builtin == value
    more = tolerance_specs(5, first_mode=DECLARED_MODES + 1)
    assert [s.name for s in more] == ['tolerances.k4', 'tolerances.k5', 'tolerances.omega_4',
                                      'tolerances.omega_5', 'tolerances.zeta_4',
                                      'tolerances.zeta_5']
    assert more[0].description == ('relative tolerance of k4 (0.01 = 1 %; not set: '
                                   'tolerances.k, else 8 %)')
    assert more[0].builtin == DEFAULT_KIND_TOLERANCES['k']


def test_check_says_why() -> None:
    count = ParamSpec('count', 3, 'a count', 1, 10)
    assert count.check(5) is None
    assert count.check(0) == 'count must be >= 1, got 0'
    assert count.check(11) == 'count must be <= 10, got 11'
    period = ParamSpec('period', 1.0, 'a period', 0.0, None, exclusive_low=True)
    assert period.check(1e9) is None
    assert period.check(0.0) == 'period must be > 0, got 0.0'
    assert period.check(math.inf) == 'period must be finite, got inf'
    angles = ParamSpec('angles', [1.0], 'angles', 1e-6, 20.0)
    assert angles.check([0.5, 30.0]) == 'angles must be <= 20, got 30.0'
    mode = ParamSpec('mode', 'a', 'a mode', choices=('a', 'b'))
    assert mode.check('c') == "mode must be one of ['a', 'b'], got 'c'"
    optional = ParamSpec('tolerances.k0', None, 'tolerance', 0.0, 1e6, exclusive_low=True)
    assert optional.check(None) is None
    assert optional.check('tight') == "tolerances.k0 must be a number, got 'tight'"
    assert optional.check(True) == 'tolerances.k0 must be a number, got True'
    assert optional.check(-1.0) == 'tolerances.k0 must be > 0, got -1.0'


# -- issue 12: one validation layer for every parameter value (defects 12, 14; the log flood) --

def _spec(node: str, name: str) -> ParamSpec:
    return next(s for s in NODE_PARAMETERS[node] if s.name == name)


def test_arrays_are_checked_element_by_element() -> None:
    """Defect 12: `angles := [nan]` stopped the driver, `[0.0]` published zero-angle moves."""
    angles = _spec('galvo_driver', 'angles')
    assert angles.check([0.3, 1.0]) is None
    assert angles.check([math.nan]) == 'angles must be finite, got nan'
    assert angles.check([0.3, math.inf]) == 'angles must be finite, got inf'
    assert angles.check([0.0]) == 'angles must be >= 1e-06, got 0.0'
    assert angles.check([-0.3]) == 'angles must be >= 1e-06, got -0.3'
    assert angles.check([0.3, 25.0]) == 'angles must be <= 20, got 25.0'
    assert angles.check([]) == 'angles must not be empty'
    assert angles.check([0.3] * 257) == 'angles must have at most 256 elements, got 257'
    assert angles.check([0.3, 'x']) == "angles must be a list of floating-point numbers, got " \
        "text 'x'"
    assert angles.check([1, 2]).startswith('angles must be a list of floating-point numbers '
                                           '(write 2.0 for 2)')
    assert angles.check('0.3') == 'angles must be a list of numbers, got text'


def test_integers_are_not_truncated_and_types_follow_the_default() -> None:
    """Defect 14: `window_size: 10.7` became 10. A value has its default's type, as in ROS."""
    window = _spec('sysid', 'window_size')
    assert window.check(10) is None
    assert window.check(10.7) == 'window_size must be an integer, got 10.7'
    assert window.check(10.0) == 'window_size must be an integer, got 10.0'
    assert window.check(True) == 'window_size must be an integer, got a boolean True'
    assert window.check('10') == "window_size must be an integer, got text '10'"
    timeout = _spec('sysid', 'pair_timeout')
    assert timeout.check(2) == ('pair_timeout must be a floating-point number (ROS refuses an '
                                'integer here: write 2.0), got an integer 2')
    assert _spec('galvo_driver', 'exit_when_done').check(1) == \
        'exit_when_done must be a boolean, got an integer 1'
    assert _spec('sysid', 'method').check(3) == 'method must be text, got an integer 3'
    assert _spec('sysid', 'method').check(['refined']).startswith('method must be text')


def test_texts_are_bounded_one_line_values() -> None:
    hardware = _spec('sysid', 'hardware_id')
    assert hardware.check('scanner_1') is None
    assert hardware.check('a\nb') == "hardware_id must not hold control characters, got '\\n'"
    assert hardware.check('a\x00b') == \
        "hardware_id must not hold control characters, got '\\x00'"
    assert hardware.check('x' * 5000) == 'hardware_id must be at most 4096 characters, got 5000'
    effects = _spec('galvo_driver', 'effects')
    assert effects.check('[\n  {"effect": "none", "parameters": {}}\n]') is None  # JSON text
    assert effects.check('[' * 70_000) == 'effects must be at most 65536 characters, got 70000'
    method = _spec('sysid', 'method')
    reason = method.check('m' * 10_000)  # the value is quoted short
    assert reason is not None
    assert len(reason) < 150


def test_no_period_or_rate_can_flood_the_log() -> None:
    """`stats_period:=1e-6` wrote 55,000 log lines in 27 s: periods are 0 (off) or >= 0.1 s,
    rates at most 10 per second (log lines: at most 100 a second)."""
    stats = _spec('sysid', 'stats_period')
    assert stats.check(0.0) is None  # never
    assert stats.check(0.1) is None
    assert stats.check(1e-6) == 'stats_period must be >= 0.1 (or 0: off), got 1e-06'
    assert stats.check(-1.0) == 'stats_period must be >= 0.1 (or 0: off), got -1.0'
    for node, specs in NODE_PARAMETERS.items():
        for s in specs:
            if s.name.endswith('period'):
                assert s.check(1e-6) is not None, (node, s.name)
                assert s.check(0.1) is None, (node, s.name)
            if s.name.endswith(('_rate', 'per_second')) and s.name != 'drift.rate':
                assert s.check(1000 if isinstance(s.default, int) else 1000.0) is not None, \
                    (node, s.name)
    rate = _spec('galvo_driver', 'rate_factor')
    assert rate.check(0.0) is None  # as fast as possible
    assert rate.check(1e-9) == 'rate_factor must be >= 0.001 (or 0: off), got 1e-09'


def test_a_zero_off_parameter_has_no_ros_range() -> None:
    """ROS ranges cannot say '0 or 0.1..1e6': the check is ParamSpec's (no rclpy here)."""
    stats = _spec('sysid', 'stats_period')
    assert stats.zero_off
    assert (stats.low, stats.high) == (0.1, 1e6)


@pytest.mark.parametrize('node', sorted(NODE_PARAMETERS))
def test_check_never_raises_and_says_why_in_one_short_line(node: str) -> None:
    """Any value of any type into every spec's check: None or one line of at most 200
    characters (hypothesis, seeded)."""
    from hypothesis import given, seed, settings
    from hypothesis import strategies as st

    scalars = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(),
                        st.text(max_size=300), st.binary(max_size=20))
    values = st.one_of(scalars, st.lists(scalars, max_size=300),
                       st.recursive(scalars, lambda inner: st.lists(inner, max_size=4) |
                                    st.dictionaries(st.text(max_size=5), inner, max_size=4),
                                    max_leaves=30))

    @seed(12)
    @settings(max_examples=150, deadline=None, database=None)
    @given(spec=st.sampled_from(NODE_PARAMETERS[node]), value=values)
    def run(spec: ParamSpec, value: object) -> None:
        reason = spec.check(value)
        if reason is not None:
            assert isinstance(reason, str)
            assert reason
            assert '\n' not in reason
            assert len(reason) <= 200, reason

    run()
