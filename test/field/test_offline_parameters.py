"""galvo_sysid.field.parameter_file, field.jobs: node parameter files read strictly, fit
processes capped (issue 12: defects 13 and 14, `identify --jobs 40`)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.field.offline import identify_bag
from galvo_sysid.field.parameter_file import load_node_parameters

BAGS = Path(__file__).resolve().parents[2] / 'bags'


def params(tmp_path: Path, body: str, section: str = '/**') -> Path:
    path = tmp_path / 'p.yaml'
    path.write_text(f'{section}:\n  ros__parameters:\n' + ''.join(
        f'    {line}\n' for line in body.splitlines()))
    return path


@pytest.mark.parametrize(('node', 'body', 'needle'), [
    ('sysid', 'window_size: abc', 'window_size must be an integer, got text'),  # repro
    ('watchdog', 'warn_fraction: abc', 'warn_fraction must be a floating-point number'),
    ('sysid', 'window_size: null', 'window_size must be an integer, got null'),
    ('sysid', 'window_size: [1, 2]', 'got a list'),
    ('sysid', 'window_size: 10.7', 'got a floating-point number 10.7'),  # was read as 10
    ('sysid', 'window_size: true', 'got a boolean'),
    ('sysid', 'window_size: 1', 'window_size must be >= 2'),
    ('sysid', 'pair_timeout: 2', 'write 2.0'),  # ROS refuses an integer for a double
    ('sysid', 'method: magic', 'method must be one of'),
    ('sysid', 'model: 5', 'model must be text'),
    ('sysid', 'window_sise: 50', "sysid has no parameter 'window_sise'"),  # a typo
    ('sysid', 'window_size: {a: 1}', "no parameter 'window_size.a'"),
    ('watchdog', 'tolerances: {k0: abc}', 'tolerances.k0 must be a number'),
    ('watchdog', 'tolerances: {k0: -1.0}', 'tolerances.k0 must be >'),
    ('watchdog', 'tolerances: {omega_17: 0.1}', "no parameter 'tolerances.omega_17'"),
    ('galvo_driver', 'angles: [0.3, .nan]', 'angles must be finite'),
    ('galvo_driver', 'angles: [0.3, 1]', 'angles must be a list of floating-point numbers'),
])
def test_bad_values_are_one_error_line(tmp_path: Path, node: str, body: str,
                                       needle: str) -> None:
    path = params(tmp_path, body)
    with pytest.raises(ConfigurationError) as err:
        load_node_parameters(path, node)
    text = str(err.value)
    assert '\n' not in text
    assert text.startswith(f'parameter file {path}: /**: ')
    assert needle in text


def test_good_files_are_read_as_written(tmp_path: Path) -> None:
    path = params(tmp_path, 'window_size: 50\npair_timeout: 2.0\nwarn_fraction: 0.4\n'
                            'use_sim_time: false\nqos_overrides: {/galvo/current: {depth: 5}}')
    # another node's parameter in /** is for that node; ROS's own are not galvo_sysid's
    assert load_node_parameters(path, 'sysid') == {'window_size': 50, 'pair_timeout': 2.0}
    assert load_node_parameters(path, 'watchdog') == {'warn_fraction': 0.4}
    path = params(tmp_path, 'tolerances: {k4: 0.2, zeta: null}', section='/left/watchdog')
    assert load_node_parameters(path, 'watchdog') == {'tolerances.k4': 0.2,
                                                      'tolerances.zeta': None}
    # a section naming the node is the node's alone: another node's name is a mistake there
    path = params(tmp_path, 'warn_fraction: 0.4', section='sysid')
    with pytest.raises(ConfigurationError, match="sysid has no parameter 'warn_fraction'"):
        load_node_parameters(path, 'sysid')


@pytest.mark.parametrize('text', [
    '/**:\n  ros__parameters: 5\n',
    '/**:\n  ros__parameter:\n    window_size: 5\n',  # typo in the section
    '/**:\n  ros__parameters: {window_size: 50}\n  extra: 1\n',
    '/**: [1, 2]\n',
    '/**:\n  ros__parameters: {5: 1}\n',
    '/**:\n  ros__parameters: ' + '{a: ' * 20 + '1' + '}' * 20 + '\n',
])
def test_bad_layout_is_one_error_line(tmp_path: Path, text: str) -> None:
    path = tmp_path / 'p.yaml'
    path.write_text(text)
    with pytest.raises(ConfigurationError) as err:
        load_node_parameters(path, 'sysid')
    assert '\n' not in str(err.value)
    assert str(path) in str(err.value)


def test_job_limit_is_the_cpus_at_most() -> None:
    from galvo_sysid.field.jobs import job_limit

    limit, why = job_limit()
    assert 1 <= limit <= len(os.sched_getaffinity(0))
    assert 'CPU' in why or 'memory' in why


def test_identify_starts_no_more_processes_than_the_limit(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """`identify --jobs 40` started 41 processes (2.45 GB) on two cores."""
    from galvo_sysid.monitor import scheduler

    asked: list[int] = []
    original = scheduler.WindowScheduler.__init__

    def spy(self: scheduler.WindowScheduler, *args: object, **kwargs: object) -> None:
        asked.append(int(kwargs['processes']))  # type: ignore[call-overload]
        kwargs['processes'] = 0  # fit on a thread here: the test is about the count asked
        original(self, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(scheduler.WindowScheduler, '__init__', spy)
    found = identify_bag(BAGS / 'nominal', jobs=40, pooling='inverse-variance')
    assert len(found.windows) == 4
    assert asked
    assert max(asked) <= len(os.sched_getaffinity(0))
