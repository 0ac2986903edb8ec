"""Live field tools over real DDS: record, replay, echo, against the project's nodes.

Every process is a separate OS process started from the venv's entry points, as a user would
(``galvo-sysid``, ``galvo_driver``, ``sysid``); conftest.py keeps the traffic on this machine
and on a domain of its own.
"""

from __future__ import annotations

import contextlib
import json
import signal
import subprocess
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest

from galvo_sysid.field.live import format_yaml, message_to_dict
from galvo_sysid.model import REFERENCE_MODEL

if TYPE_CHECKING:
    from collections.abc import Iterator

NUMERIC_FIELDS = ('input_delay', 'k0', 'residues', 'natural_frequencies', 'damping_ratios',
                  'k0_std', 'residues_std', 'natural_frequencies_std', 'damping_ratios_std',
                  'fit_percent', 'target_angle')


class Proc:
    """A child process with its output in files (no pipe can fill up and block it)."""

    def __init__(self, args: list[str], workdir: Path, name: str) -> None:
        self.out = workdir / f'{name}.out'
        self.err = workdir / f'{name}.err'
        with self.out.open('w') as out, self.err.open('w') as err:
            self.popen = subprocess.Popen(args, stdout=out, stderr=err)

    def stop(self, timeout: float = 15.0) -> int:
        if self.popen.poll() is None:
            self.popen.send_signal(signal.SIGINT)
            try:
                self.popen.wait(timeout)
            except subprocess.TimeoutExpired:
                self.popen.kill()
                self.popen.wait(5)
        return self.popen.returncode

    def wait(self, timeout: float) -> int:
        return self.popen.wait(timeout)

    @property
    def stdout(self) -> str:
        return self.out.read_text()

    @property
    def stderr(self) -> str:
        return self.err.read_text()


@contextlib.contextmanager
def processes(workdir: Path) -> Iterator[dict[str, Proc]]:
    procs: dict[str, Proc] = {}
    try:
        yield procs
    finally:
        for p in reversed(procs.values()):
            p.stop()


def wait_for(predicate: object, timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():  # type: ignore[operator]
            return
        time.sleep(0.1)
    raise AssertionError(f'timed out waiting for {what}')


def test_message_to_dict_and_yaml() -> None:
    from galvo_sysid_msgs.msg import ModalParameters

    msg = ModalParameters(window_index=3, target_angle=-0.3, moves=100, k0=3.5e6,
                          residues=[1.0, -2.5], natural_frequencies=[7.1e4, 1.2e5],
                          damping_ratios=[0.006, 0.007], fit_percent=float('nan'))
    msg.header.frame_id = "it's"
    data = message_to_dict(msg)
    assert data['header'] == {'stamp': {'sec': 0, 'nanosec': 0}, 'frame_id': "it's"}
    assert data['residues'] == [1.0, -2.5]
    assert data['moves'] == 100
    text = format_yaml(data)
    lines = text.splitlines()
    assert lines[:4] == ['header:', '  stamp:', '    sec: 0', '    nanosec: 0']
    assert "  frame_id: 'it''s'" in lines
    assert 'residues:' in lines
    assert '- -2.5' in lines
    assert 'residues_std: []' in lines
    assert 'fit_percent: .nan' in lines
    import yaml

    parsed = yaml.safe_load(text)
    assert parsed['residues'] == [1.0, -2.5]
    assert parsed['header']['frame_id'] == "it's"
    assert parsed['natural_frequencies'] == [7.1e4, 1.2e5]


def test_record_identify_round_trip_on_live_driver(venv_bin: Path, tmp_path: Path) -> None:
    bag = tmp_path / 'recorded'
    with processes(tmp_path) as procs:
        procs['record'] = Proc([str(venv_bin / 'galvo-sysid'), 'record', '--out', str(bag),
                                '/galvo/current', '/galvo/encoder'], tmp_path, 'record')
        procs['driver'] = Proc([str(venv_bin / 'galvo_driver'), '--ros-args',
                                '-p', 'angles:=[0.3]', '-p', 'moves_per_angle:=200',
                                '-p', 'cycles:=1', '-p', 'rate_factor:=4.0',
                                '-p', 'seed:=11', '-p', 'exit_when_done:=true'],
                               tmp_path, 'driver')
        assert procs['driver'].wait(90) == 0, procs['driver'].stderr
        assert procs['record'].stop() == 0, procs['record'].stderr
    assert 'record: 400 messages on 2 topic(s)' in procs['record'].stderr
    proc = subprocess.run([str(venv_bin / 'galvo-sysid'), 'identify', str(bag), '--json'],
                          capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out['rejected'] == []
    assert sorted(w['target_angle'] for w in out['windows']) == [-0.3, 0.3]
    assert all(w['moves'] == 100 and not w['partial'] for w in out['windows'])
    pooled = out['pooled']
    assert pooled['k0'] == pytest.approx(REFERENCE_MODEL.k0, rel=0.01)
    assert pooled['natural_frequencies'][0] == pytest.approx(
        REFERENCE_MODEL.natural_frequencies[0], rel=0.002)
    # the recorded messages are the driver's: the simulator with the same seed (to rounding:
    # the driver's process may sum in another order, e.g. BLAS threads)
    from galvo_sysid.field.bags import BagReader
    from galvo_sysid.monitor.moves import MoveHalf
    from galvo_sysid.sim.simulator import GalvoSimulator

    expected = {m.move_id: m for m in GalvoSimulator(seed=11).moves(angles=[0.3],
                                                                    moves_per_angle=200)}
    with BagReader(bag) as reader:
        halves = [h for h in reader.move_halves() if isinstance(h, MoveHalf)]
    assert len(halves) == 400
    for h in halves:
        move = expected[h.move_id]
        np.testing.assert_allclose(h.data, move.current if h.signal == 'current'
                                   else move.encoder, rtol=1e-12, atol=1e-15)


def test_replay_into_sysid_equals_offline_identify(venv_bin: Path, tmp_path: Path) -> None:
    bag = tmp_path / 'sim'
    cli = str(venv_bin / 'galvo-sysid')
    made = subprocess.run([cli, 'simulate', '--out', str(bag), '--angles', '1psi',
                           '--moves-per-angle', '200', '--seed', '21'],
                          capture_output=True, text=True, timeout=120, check=False)
    assert made.returncode == 0, made.stderr
    offline = subprocess.run([cli, 'identify', str(bag), '--json'], capture_output=True,
                             text=True, timeout=120, check=False)
    assert offline.returncode == 0, offline.stderr
    expected = {w['window_index']: w for w in json.loads(offline.stdout)['windows']}
    assert len(expected) == 2
    with processes(tmp_path) as procs:
        procs['sysid'] = Proc([str(venv_bin / 'sysid')], tmp_path, 'sysid')
        procs['echo'] = Proc([cli, 'echo', '/galvo/modal_parameters', '--json'], tmp_path,
                             'echo')
        replay = Proc([cli, 'replay', str(bag), '--rate', '2', '--wait', '60'], tmp_path,
                      'replay')
        procs['replay'] = replay
        assert replay.wait(120) == 0, replay.stderr
        assert 'published 400 messages' in replay.stderr
        echo = procs['echo']
        wait_for(lambda: len(echo.stdout.splitlines()) >= 2, 90, 'two ModalParameters')
        # a late echo still sees the last result (transient local) and prints YAML
        once = subprocess.run([cli, 'echo', '/galvo/modal_parameters', '--once',
                               '--timeout', '30'], capture_output=True, text=True, timeout=60,
                              check=False)
    assert once.returncode == 0, once.stderr
    assert once.stdout.rstrip().endswith('---')
    assert '\nk0: ' in once.stdout
    assert 'moves: 100' in once.stdout
    live = [json.loads(line) for line in echo.stdout.splitlines()]
    assert {m['window_index'] for m in live} == set(expected)
    for msg in live:
        want = expected[msg['window_index']]
        assert msg['moves'] == want['moves']
        for name in NUMERIC_FIELDS:
            got = np.atleast_1d(np.asarray(msg[name], dtype=float))
            ref = np.atleast_1d(np.asarray(want[name], dtype=float))
            assert got.shape == ref.shape, name
            np.testing.assert_array_less(np.abs(got - ref), 1e-6 * np.abs(ref) + 1e-300,
                                         err_msg=name)


def test_replay_publishes_clock(venv_bin: Path, tmp_path: Path) -> None:
    bag = tmp_path / 'sim'
    cli = str(venv_bin / 'galvo-sysid')
    made = subprocess.run([cli, 'simulate', '--out', str(bag), '--angles', '0.3',
                           '--moves-per-angle', '20'], capture_output=True, text=True,
                          timeout=120, check=False)
    assert made.returncode == 0, made.stderr
    with processes(tmp_path) as procs:
        procs['replay'] = Proc([cli, 'replay', str(bag), '--clock', '--loop', '--wait', '0'],
                               tmp_path, 'replay')
        echo = subprocess.run([cli, 'echo', '/clock', '--once', '--json', '--timeout', '60'],
                              capture_output=True, text=True, timeout=90, check=False)
    assert echo.returncode == 0, echo.stderr
    clock = json.loads(echo.stdout)['clock']
    t = clock['sec'] + clock['nanosec'] * 1e-9
    assert 0.0 <= t <= 20 * 606e-5 + 0.01  # within the bag's simulated time


def test_echo_timeout_is_one_line(venv_bin: Path) -> None:
    proc = subprocess.run([str(venv_bin / 'galvo-sysid'), 'echo', '/no_such_topic',
                           '--timeout', '1'], capture_output=True, text=True, timeout=60,
                          check=False)
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines() == [
        'echo: topic /no_such_topic did not appear within 1 s']


LATCHED_PUBLISHER = """
import time, rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy, DurabilityPolicy
from galvo_sysid_msgs.msg import ModalParameters
rclpy.init()
node = rclpy.create_node('latched_publisher')
qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                 durability=DurabilityPolicy.TRANSIENT_LOCAL)
pub = node.create_publisher(ModalParameters, 'latched_test', qos)
pub.publish(ModalParameters(window_index=42, moves=7))
time.sleep(30)
"""


LISTENER = """
import time, rclpy
from galvo_sysid_msgs.msg import ModalParameters
rclpy.init()
node = rclpy.create_node('plain_listener')
node.create_subscription(ModalParameters, 'latched_test', lambda m: None, 10)
end = time.monotonic() + 40
while time.monotonic() < end:
    rclpy.spin_once(node, timeout_sec=0.1)
"""


def test_echo_and_record_wait_for_a_publisher(venv_bin: Path, tmp_path: Path) -> None:
    """A topic known only from a subscriber must not fix the QoS before a publisher shows."""
    import sys

    cli = str(venv_bin / 'galvo-sysid')
    bag = tmp_path / 'latched'
    with processes(tmp_path) as procs:
        # a subscriber-only endpoint makes the topic visible before any publisher exists
        procs['listener'] = Proc([sys.executable, '-c', LISTENER], tmp_path, 'listener')
        procs['record'] = Proc([cli, 'record', '--out', str(bag), '/latched_test'], tmp_path,
                               'record')
        procs['echo'] = Proc([cli, 'echo', '/latched_test', '--once', '--json'], tmp_path,
                             'echo')
        # both have seen the topic, from the listener only (no publisher, so no QoS yet)
        wait_for(lambda: 'has subscribers only' in procs['record'].stderr, 30,
                 'the recorder to see the topic without a publisher')
        wait_for(lambda: '(it has subscribers only)' in procs['echo'].stderr, 30,
                 'echo to see the topic without a publisher')
        # the message is published at once, before the new publisher is matched with anyone:
        # only transient-local subscriptions get it
        procs['publisher'] = Proc([sys.executable, '-c', LATCHED_PUBLISHER], tmp_path, 'pub')
        echo = procs['echo']
        assert echo.wait(40) == 0, echo.stderr
        wait_for(lambda: 'subscribed to /latched_test' in procs['record'].stderr, 30,
                 'the recorder to subscribe')
        time.sleep(1.0)
    assert json.loads(echo.stdout)['window_index'] == 42
    from galvo_sysid.field.bags import BagReader

    with BagReader(bag) as reader:
        info = {t.topic: t for t in reader.info.topics}
        assert info['/latched_test'].count == 1
        assert info['/latched_test'].transient_local
