"""``galvo-sysid record`` over real DDS when it is killed or the disk fills up (issue 12,
defect 5): the messages written before stay readable.

The recorder is a child process (the venv's ``galvo-sysid``) fed by this test's own
publishers (``test/ros_graph.py``) with seeded simulated moves; conftest.py keeps the traffic
on this machine and on a domain of its own. Waits are on events (what the bag says it holds,
the process ending), never fixed sleeps.
"""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest
import yaml  # type: ignore[import-untyped]
from full_disk import tmpfs

from galvo_sysid.sim.simulator import GalvoSimulator

if TYPE_CHECKING:
    from ros_graph import Graph

pytestmark = pytest.mark.filterwarnings('ignore::DeprecationWarning')

SEED = 31


def _cli(venv_bin: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(venv_bin / 'galvo-sysid'), *args], capture_output=True,
                          text=True, timeout=300, check=False)


def _paced(pubs: dict[str, Any], msgs: list[tuple[str, Any]]) -> None:
    """Publish at the moves' own pace (a driver's), not faster than their stamps advance.

    A burst of hundreds of moves published at once arrives with one topic's messages up to a
    second of stamps ahead of the other's (reliable delivery repairs what the burst lost),
    which a reader rightly takes for a jump in time; a driver never publishes so.
    """
    start = time.monotonic()
    first = None
    for signal, msg in msgs:
        stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        first = stamp if first is None else first
        ahead = (stamp - first) - (time.monotonic() - start)
        if ahead > 0.005:
            time.sleep(ahead)
        pubs[signal].publish(msg)


def _durable(bag: Path) -> int:
    """Messages the recording's metadata.yaml says reached the file (0 if none yet)."""
    try:
        info = yaml.safe_load((bag / 'metadata.yaml').read_text())
        return int(info['rosbag2_bagfile_information']['message_count'])
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError):
        return 0


def _publishers(graph: Graph) -> dict[str, Any]:
    from galvo_sysid_msgs.msg import MoveSamples
    from ros_graph import MOVES_QOS

    return {s: graph.node.create_publisher(MoveSamples, f'/galvo/{s}', MOVES_QOS)
            for s in ('current', 'encoder')}


def _record(graph: Graph, bag: Path, storage: str) -> Any:
    return graph.run([str(graph.venv_bin / 'galvo-sysid'), 'record', '--out', str(bag),
                      '--storage', storage, '/galvo/current', '/galvo/encoder'], 'record')


def _move_ids(bag: Path, topic: str) -> list[int]:
    from galvo_sysid.field.bags import BagReader

    with BagReader(bag) as reader:
        return [int(reader.deserialize(r).move_id)  # type: ignore[attr-defined]
                for r in reader.raw_messages([topic])]


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_killed_record_keeps_the_messages_before_the_kill(graph: Graph, tmp_path: Path,
                                                          storage: str) -> None:
    from ros_graph import move_messages, wait_matched

    bag = tmp_path / 'killed'
    recorder = _record(graph, bag, storage)
    pubs = _publishers(graph)
    moves = list(GalvoSimulator(seed=SEED).moves(angles=[0.3], moves_per_angle=220))
    msgs = move_messages(moves, t0=1000.0)
    first, rest = msgs[:400], msgs[400:]  # 100 moves of +0.3 and 100 of -0.3, then 20 more
    wait_matched(graph, pubs.values())
    _paced(pubs, first)
    # the recorder wrote them (its flush interval passed): what a crash must not lose
    graph.spin_until(lambda: _durable(bag) >= 400, 60, 'the first 400 messages in the bag')
    _paced(pubs, rest)
    recorder.kill()  # SIGKILL: no clean-up code runs

    for command in ('info', 'identify'):
        done = _cli(graph.venv_bin, command, str(bag))
        assert done.returncode == 1, done.stdout + done.stderr
        assert done.stderr.splitlines() == [
            f'galvo-sysid {command}: error: bag {bag} is incomplete (recording was '
            f'interrupted); run galvo-sysid bag recover {bag}']

    done = _cli(graph.venv_bin, 'bag', 'recover', str(bag))
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f'bag {bag}: recovered ')
    info = _cli(graph.venv_bin, 'info', str(bag))
    assert info.returncode == 0, info.stderr
    count = int(next(line.split()[1] for line in info.stdout.splitlines()
                     if line.startswith('messages:')))
    assert 400 <= count <= len(msgs)
    # what was kept is what was sent, in order, up to where the crash cut it
    current = _move_ids(bag, '/galvo/current')
    assert current == list(range(len(current)))
    assert len(current) >= 200

    ident = _cli(graph.venv_bin, 'identify', str(bag), '--json')
    assert ident.returncode == 0, ident.stderr
    windows = json.loads(ident.stdout)['windows']
    assert sorted(w['target_angle'] for w in windows) == [-0.3, 0.3]
    assert all(w['moves'] == 100 and not w['partial'] for w in windows)


def test_record_on_a_full_disk_stops_with_one_error_line(graph: Graph, tmp_path: Path) -> None:
    from ros_graph import move_messages, wait_matched

    with tmpfs(tmp_path / 'disk', '2m') as disk:
        bag = disk / 'full'
        recorder = _record(graph, bag, 'mcap')
        pubs = _publishers(graph)
        moves = GalvoSimulator(seed=SEED).moves(angles=[0.3], moves_per_angle=2000)
        msgs = iter(move_messages(moves, t0=1000.0))  # 4000 messages, 19 MB: more than 2 MB
        wait_matched(graph, pubs.values())

        def publish_some() -> bool:
            if not recorder.running:
                return True
            for signal, msg in (next(msgs, (None, None)) for _ in range(10)):
                if signal is not None:
                    pubs[signal].publish(msg)
            return False

        graph.spin_until(publish_some, 120, 'the recorder to stop on the full disk')
        assert recorder.popen.returncode == 1
        lines = recorder.text().splitlines()
        assert 'Traceback' not in recorder.text()
        errors = [line for line in lines if 'error' in line]
        assert len(errors) == 1, lines
        assert errors[0].startswith(f'galvo-sysid record: error: cannot write bag {bag}: '
                                    f'No space left on device; the bag is closed and keeps '
                                    f'the ')
        kept = int(errors[0].split('keeps the ')[1].split()[0].replace(',', ''))
        assert kept > 0
        info = _cli(graph.venv_bin, 'info', str(bag))  # readable as it is, no recovery
        assert info.returncode == 0, info.stderr
        assert f'messages: {kept}\n' in info.stdout
        current = _move_ids(bag, '/galvo/current')
        assert current == list(range(len(current)))
