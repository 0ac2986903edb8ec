"""What the live tools read and print, without ROS: parameter values as ``ros2 param`` reads
them, parameter files (``param dump``), ``echo --field`` paths, ``topic hz`` statistics."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
import yaml

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.field.live.parameter_text import (
    format_value,
    parameters_yaml,
    parse_value,
    value_line,
)
from galvo_sysid.field.live.text import field_path, select_field
from galvo_sysid.field.live.topic_hz import RateWindow
from galvo_sysid.schema import parse_yaml

ROS2_PARAM_CASES = [  # what rclpy.parameter.get_parameter_value (ros2 param set) gives
    ('true', ('boolean', True)),
    ('False', ('boolean', False)),
    ('100', ('integer', 100)),
    ('-3', ('integer', -3)),
    ('2.5', ('double', 2.5)),
    ('.inf', ('double', math.inf)),
    ('refined', ('string', 'refined')),
    ('"100"', ('string', '100')),
    ('', ('string', '')),
    ('[0.3, 0.6]', ('double array', [0.3, 0.6])),
    ('[1, 2]', ('integer array', [1, 2])),
    ('[true, false]', ('boolean array', [True, False])),
    ('[a, b]', ('string array', ['a', 'b'])),
    ('[0.3, 1]', ('string', '[0.3, 1]')),  # mixed: the text itself
    ('[{"effect": "gain_change"}]', ('string', '[{"effect": "gain_change"}]')),
    ('{a: 1}', ('string', '{a: 1}')),
    ('[1, 2', ('string', '[1, 2')),  # not YAML: the text itself
]


@pytest.mark.parametrize(('text', 'expected'), ROS2_PARAM_CASES, ids=[c[0] or "''"
                                                                       for c in ROS2_PARAM_CASES])
def test_values_read_as_ros2_param_reads_them(text: str, expected: tuple[str, Any]) -> None:
    assert parse_value(text) == expected


def test_values_agree_with_rclpy_where_yaml_1_1_and_ros_agree() -> None:
    from rclpy.parameter import get_parameter_value, parameter_value_to_python

    from galvo_sysid.field.live.parameter_text import KINDS

    for text, expected in ROS2_PARAM_CASES:
        if text in ('[1, 2', '{a: 1}'):  # rclpy raises on the first (a YAML scanner error,
            continue  # not a parser error) and keeps a mapping as a 'string' on the second
        msg = get_parameter_value(text)
        assert (KINDS[msg.type], parameter_value_to_python(msg)) == expected, text


def test_exponent_numbers_are_numbers_as_on_the_command_line() -> None:
    # PyYAML (so ros2 param set) reads 1e-6 as text; rcl reads it as a float, as -p does
    assert parse_value('1e-6') == ('double', 1e-6)
    assert parse_value('[1e-3, 2.0]') == ('double array', [1e-3, 2.0])


def test_values_fitted_to_the_declared_kind() -> None:
    assert parse_value('2', declared='double') == ('double', 2.0)
    assert parse_value('2', declared='integer') == ('integer', 2)
    assert parse_value('[0.3, 1]', declared='double array') == ('double array', [0.3, 1.0])
    assert parse_value('[1, 2]', declared='double array') == ('double array', [1.0, 2.0])
    assert parse_value('[]', declared='string') == ('string', '[]')  # effects
    assert parse_value('123', declared='string') == ('string', '123')
    assert parse_value('true', declared='string') == ('string', 'true')
    # a value of another kind stays what it is: the node refuses it with its reason
    assert parse_value('2.5', declared='integer') == ('double', 2.5)
    assert parse_value('abc', declared='double') == ('string', 'abc')
    assert parse_value('1' + '0' * 400, declared='double')[0] == 'string'  # too long a number


@pytest.mark.parametrize(('kind', 'value', 'line'), [
    ('double', 5.0, 'Double value is: 5.0'),
    ('integer', 100, 'Integer value is: 100'),
    ('boolean', False, 'Boolean value is: false'),
    ('string', 'refined', 'String value is: refined'),
    ('string', '', 'String value is: ""'),
    ('string', '[]', 'String value is: "[]"'),
    ('string', '1e-6', 'String value is: "1e-6"'),
    ('double array', [0.03, 3.0], 'Double values are: [0.03, 3.0]'),
    ('string array', ['a', 'b c'], 'String values are: ["a", "b c"]'),
    ('not set', None, 'Parameter not set.'),
])
def test_get_lines(kind: str, value: Any, line: str) -> None:
    assert value_line(kind, value) == line
    if kind != 'not set':  # what get prints, set reads back as the same value
        assert parse_value(format_value(kind, value), declared=kind) == (kind, value)


def test_dump_is_a_parameter_file_that_reads_back_the_same() -> None:
    values = {'window_size': 100, 'pair_timeout': 1.0, 'stats_period': 1e-6,
              'method': 'refined', 'model': '', 'hardware_id': 'scanner "A"\nline 2',
              'number_text': '1e-6', 'flag': True, 'angles': [0.03, 3.0],
              'names': ['a', 'b'], 'tolerances.k0': 0.05, 'tolerances.omega_1': 0.01,
              'drift.rate': -0.001, 'big': math.inf, 'nan': math.nan}
    text = parameters_yaml('/scanner_1/sysid', values)
    assert text.startswith('/scanner_1/sysid:\n  ros__parameters:\n')
    assert '    tolerances:\n      k0: 0.05\n      omega_1: 0.01\n' in text
    assert '    stats_period: 1e-06\n' in text
    for loader in (lambda t: parse_yaml(t, source='dump'), yaml.safe_load):
        doc = loader(text)
        params = doc['/scanner_1/sysid']['ros__parameters']
        flat = {**{k: v for k, v in params.items() if not isinstance(v, dict)},
                **{f'{k}.{n}': v for k, sub in params.items() if isinstance(sub, dict)
                   for n, v in sub.items()}}
        if loader is yaml.safe_load:  # YAML 1.1 reads 1e-06 as text; ROS as a float
            flat['stats_period'] = float(flat['stats_period'])
        assert set(flat) == set(values)
        for name, value in values.items():
            if isinstance(value, float) and math.isnan(value):
                assert math.isnan(flat[name])
            else:
                assert flat[name] == value, name
                assert type(flat[name]) is type(value), name


def test_dump_keeps_a_name_flat_below_a_parameter_of_its_prefix() -> None:
    text = parameters_yaml('/n', {'a': 1, 'a.b': 2, 'c.d.e': 3})
    doc = parse_yaml(text, source='dump')['/n']['ros__parameters']
    assert doc == {'a': 1, 'a.b': 2, 'c': {'d': {'e': 3}}}
    assert parameters_yaml('/n', {}) == '/n:\n  ros__parameters: {}\n'


def test_field_paths() -> None:
    data = {'header': {'stamp': {'sec': 3, 'nanosec': 4}}, 'data': [1.0, 2.0], 'level': 2}
    assert select_field(data, field_path('header.stamp')) == {'sec': 3, 'nanosec': 4}
    assert select_field(data, field_path('header.stamp.sec')) == 3
    assert select_field(data, field_path('data.1')) == 2.0
    assert select_field(data, field_path('data.-1')) == 2.0
    assert select_field(data, field_path('level')) == 2
    with pytest.raises(ConfigurationError, match=r"header has no field 'stmp' \(fields: stamp\)"):
        select_field(data, field_path('header.stmp'))
    with pytest.raises(ConfigurationError, match='data has 2 elements, no element 2'):
        select_field(data, field_path('data.2'))
    assert select_field({'data': []}, ['data', '5', 'x'], known_only=True) is None
    with pytest.raises(ConfigurationError, match='select an element by its index'):
        select_field(data, field_path('data.x'))
    with pytest.raises(ConfigurationError, match="single value, it has no field 'x'"):
        select_field(data, field_path('level.x'))
    for bad in ('', 'a..b', '.a', 'a.'):
        with pytest.raises(ConfigurationError, match='not a field path'):
            field_path(bad)


def test_rate_window() -> None:
    rates = RateWindow(3)
    assert rates.stats() is None
    for t in (0.0, 0.1, 0.3, 0.4, 0.5):  # intervals 0.1 0.2 0.1 0.1: the last 3 kept
        rates.add(t)
    stats = rates.stats()
    assert stats is not None
    assert stats.window == 4
    assert stats.received == 5
    assert stats.rate == pytest.approx(3 / 0.4)
    assert stats.min_interval == pytest.approx(0.1)
    assert stats.max_interval == pytest.approx(0.2)
    assert stats.std_dev == pytest.approx(float(np.std([0.2, 0.1, 0.1])))
    assert stats.text().splitlines() == ['average rate: 7.500',
                                         '\tmin: 0.100s max: 0.200s std dev: 0.04714s window: 4']
    with pytest.raises(ConfigurationError):
        RateWindow(0)
