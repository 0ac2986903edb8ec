"""``galvo-sysid topic list|hz`` and ``echo --field`` against a running galvo_driver over
Fast DDS (issue 15: field tools).

One driver for the module (one angle, a tenth of real time: 16.5 moves/s); each command is a
separate process, as a user runs it, and independent ones run side by side.
"""

from __future__ import annotations

import json
import re
from typing import TYPE_CHECKING

import pytest
import yaml
from ros_graph import together

from galvo_sysid.interfaces.topics import MOVE_SAMPLES
from galvo_sysid.model import load_model

if TYPE_CHECKING:
    from collections.abc import Iterator
    from pathlib import Path

    from ros_graph import Proc

RATE_FACTOR = 0.1
WAIT = ('--timeout', '20')
TEARDOWN_KILLED = ('galvo-sysid: error: the ROS middleware did not shut down within 10 s; '
                   'killed (the output above is complete)')


@pytest.fixture(scope='module')
def driver(venv_bin_module: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Proc]:
    from ros_graph import Proc

    proc = Proc([str(venv_bin_module / 'galvo_driver'), '--ros-args', '-p', 'angles:=[0.3]',
                 '-p', f'rate_factor:={RATE_FACTOR}', '-p', 'wait_for_subscribers:=0'],
                tmp_path_factory.mktemp('driver') / 'driver.log')
    try:
        yield proc
    finally:
        proc.stop()


@pytest.fixture(scope='module')
def venv_bin_module() -> Path:
    import sys
    from pathlib import Path

    return Path(sys.executable).parent


def test_topic_list_puts_the_galvo_topics_first(driver: Proc, venv_bin: Path) -> None:
    typed, galvo = together(venv_bin, ('topic', 'list', '-t', '--spin-time', '6'),
                            ('topic', 'list', '--galvo', '-v', '--spin-time', '6'))
    assert typed.returncode == 0, typed.stderr
    lines = typed.stdout.splitlines()
    assert lines[:2] == [f'/galvo/current [{MOVE_SAMPLES}]', f'/galvo/encoder [{MOVE_SAMPLES}]']
    assert '/rosout [rcl_interfaces/msg/Log]' in lines  # the driver's, after the galvo ones
    assert lines[2:] == sorted(lines[2:])
    assert not any('galvo' in line for line in lines[2:]), lines
    assert galvo.returncode == 0, galvo.stderr
    assert galvo.stdout.splitlines() == [
        f'/galvo/current [{MOVE_SAMPLES}] 1 publisher, 0 subscribers',
        f'/galvo/encoder [{MOVE_SAMPLES}] 1 publisher, 0 subscribers']


def test_topic_hz_measures_the_driver_rate(driver: Proc, venv_bin: Path) -> None:
    model = load_model(None)
    expected = RATE_FACTOR / ((model.record_length + model.dwell_length) * model.sample_period)
    timed, counted = together(
        venv_bin, ('topic', 'hz', '/galvo/current', '--duration', '5', *WAIT),
        ('topic', 'hz', 'galvo/encoder', '--count', '12', '--window', '5', *WAIT))
    assert timed.returncode == 0, timed.stderr
    rates = [float(r) for r in re.findall(r'^average rate: ([0-9.]+)$', timed.stdout, re.M)]
    assert len(rates) >= 3, timed.stdout  # every second, and at the end
    assert rates[-1] == pytest.approx(expected, rel=0.15), timed.stdout
    assert counted.returncode == 0, counted.stderr
    last = counted.stdout.splitlines()[-2:]
    assert last[1].endswith(' window: 6'), counted.stdout  # 5 intervals of the 12 messages
    assert float(last[0].removeprefix('average rate: ')) == pytest.approx(expected, rel=0.3)


def test_echo_field_prints_one_field_of_each_message(driver: Proc, venv_bin: Path) -> None:
    move_id, stamp, angle, data, beyond, typo = together(
        venv_bin, ('echo', '/galvo/encoder', '--field', 'move_id', '--json', '--once', *WAIT),
        ('echo', '/galvo/current', '--field', 'header.stamp', '--once', *WAIT),
        ('echo', '/galvo/encoder', '--field', 'target_angle', '--json', '--once', *WAIT),
        ('echo', '/galvo/encoder', '--field', 'data', '--json', '--once', *WAIT),
        ('echo', '/galvo/encoder', '--field', 'data.512', '--once', *WAIT),
        ('echo', '/galvo/encoder', '--field', 'heder.stamp', '--once', *WAIT))
    # A tool whose DDS teardown hangs after its output is killed by its guard with one line
    # (docs/reliability.md, "Faults"): seen once in this test, under a full test run, with
    # six participants leaving at once. Its output is still checked; more than one such
    # kill, or any other failure, fails the test.
    killed = [p for p in (move_id, stamp, angle, data) if p.returncode != 0]
    for p in killed:
        assert (p.returncode, p.stderr.strip()) == (-9, TEARDOWN_KILLED), p.stderr
    assert len(killed) <= 1
    assert isinstance(json.loads(move_id.stdout), int)
    assert stamp.stdout.endswith('\n---\n')
    assert set(yaml.safe_load(stamp.stdout.removesuffix('---\n'))) == {'sec', 'nanosec'}
    assert json.loads(angle.stdout) in (0.3, -0.3)  # the driver's only angle, either way
    samples = json.loads(data.stdout)
    assert len(samples) == load_model(None).record_length
    assert all(isinstance(x, float) for x in samples)
    assert beyond.returncode == 1
    assert beyond.stderr.splitlines()[-1] == (
        'echo: a message on /galvo/encoder has no data.512: data has 512 elements, '
        'no element 512')
    assert typo.returncode == 1
    assert typo.stderr.splitlines()[-1] == (
        f"galvo-sysid echo: error: {MOVE_SAMPLES}: the message has no field 'heder' "
        '(fields: header, move_id, target_angle, sample_period, data)')
