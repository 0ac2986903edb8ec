"""``galvo-sysid replay`` publishes the moves only by default; ``--topics``, ``--remap``
(issue 15: a bag's recorded results are stale, and replay waited 10 s for a subscriber on
/galvo/drift).

The bag holds 10 moves and two recorded results of each kind; the test's own node counts
what arrives on each topic. Each replay is a separate process, as a user runs it.
"""

from __future__ import annotations

import subprocess
from collections import Counter
from typing import TYPE_CHECKING, Any

import pytest

from galvo_sysid.field.bags import BagWriter
from galvo_sysid.field.simulate import write_moves
from galvo_sysid.interfaces.topics import (
    DRIFT_STATUS,
    GALVO_TOPICS,
    MODAL_PARAMETERS,
    MOVE_SAMPLES,
)
from galvo_sysid.sim.simulator import GalvoSimulator

if TYPE_CHECKING:
    from pathlib import Path

    from ros_graph import Graph, Proc

CURRENT, ENCODER, RESULTS, DRIFT = GALVO_TOPICS
MOVES = 10


@pytest.fixture(scope='module')
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """10 moves (20 messages) and 2 recorded results on each result topic."""
    from galvo_sysid_msgs.msg import DriftStatus, ModalParameters
    from rclpy.serialization import serialize_message

    path = tmp_path_factory.mktemp('replay') / 'with_results'
    with BagWriter(path) as writer:
        writer.add_topic(CURRENT, MOVE_SAMPLES)
        writer.add_topic(ENCODER, MOVE_SAMPLES)
        writer.add_topic(RESULTS, MODAL_PARAMETERS, transient_local=True)
        writer.add_topic(DRIFT, DRIFT_STATUS)
        write_moves(writer, GalvoSimulator(seed=4).moves(angles=[0.3], moves_per_angle=MOVES))
        for i in range(2):
            writer.write_raw(RESULTS, 10_000_000 * (i + 1),
                             serialize_message(ModalParameters(window_index=i)))
            writer.write_raw(DRIFT, 10_000_000 * (i + 1),
                             serialize_message(DriftStatus(window_index=i)))
    return path


def listen(graph: Graph, topics: dict[str, str]) -> Counter[str]:
    """Count the messages arriving on ``topics`` (name -> type); reliable, volatile."""
    from ros_graph import MOVES_QOS

    from galvo_sysid.field.live.graph import message_class

    counts: Counter[str] = Counter()
    for topic, msgtype in topics.items():
        def count(_: Any, topic: str = topic) -> None:
            counts[topic] += 1
        graph.node.create_subscription(message_class(msgtype), topic, count, MOVES_QOS)
    return counts


def replay(graph: Graph, venv_bin: Path, bag: Path, name: str, *args: str) -> Proc:
    return graph.run([str(venv_bin / 'galvo-sysid'), 'replay', str(bag), '--rate', 'inf',
                      *args], name)


def test_replay_publishes_only_the_moves_by_default(graph: Graph, venv_bin: Path,
                                                     bag: Path) -> None:
    # nobody listens on /galvo/drift: before, replay waited --wait seconds for it
    counts = listen(graph, {CURRENT: MOVE_SAMPLES, ENCODER: MOVE_SAMPLES,
                            RESULTS: MODAL_PARAMETERS})
    proc = replay(graph, venv_bin, bag, 'replay', '--wait', '60')
    graph.spin_until(lambda: not proc.running, 40, 'the replay to end')
    assert proc.popen.returncode == 0, proc.text()
    graph.spin_until(lambda: counts[CURRENT] == counts[ENCODER] == MOVES, 10, 'the moves')
    graph.spin_for(0.5)
    assert counts == {CURRENT: MOVES, ENCODER: MOVES}  # no recorded result
    lines = proc.text().splitlines()
    assert lines[0] == (f'replay: publishing {CURRENT}, {ENCODER} (not {DRIFT}, {RESULTS}: '
                        '--topics or --all-topics publish them)')
    assert lines[-1] == f'replay: published {2 * MOVES} messages'
    assert not any('no subscriber' in line for line in lines), lines


def test_replay_topics_and_remap(graph: Graph, venv_bin: Path, bag: Path) -> None:
    moved = '/scanner_1/galvo/current'
    renamed = '/other/drift'
    counts = listen(graph, {CURRENT: MOVE_SAMPLES, ENCODER: MOVE_SAMPLES, moved: MOVE_SAMPLES,
                            DRIFT: DRIFT_STATUS, renamed: DRIFT_STATUS})
    remapped = replay(graph, venv_bin, bag, 'remapped', '--wait', '30',
                      '--remap', f'{CURRENT}:={moved}')
    results = replay(graph, venv_bin, bag, 'results', '--wait', '30', '--topics', DRIFT,
                     '--remap', f'{DRIFT}:={renamed}')
    graph.spin_until(lambda: not remapped.running and not results.running, 40,
                     'the replays to end')
    assert remapped.popen.returncode == 0, remapped.text()
    assert results.popen.returncode == 0, results.text()
    graph.spin_until(lambda: counts[moved] == counts[ENCODER] == MOVES and counts[renamed] == 2,
                     10, 'the messages')
    graph.spin_for(0.5)
    assert counts == {moved: MOVES, ENCODER: MOVES, renamed: 2}
    assert results.text().splitlines()[0] == (
        f'replay: publishing {DRIFT} as {renamed} (not {CURRENT}, {ENCODER}, {RESULTS}: '
        '--topics or --all-topics publish them)')


@pytest.mark.parametrize(('args', 'said'), [
    (('--topics', '/galvo/drift', '/nope'), 'holds no topic /nope; it holds /galvo/current'),
    (('--remap', '/galvo/drift:=/x'), 'remap /galvo/drift: not a topic the replay publishes'),
    (('--all-topics', '--remap', '/galvo/current:=/galvo/encoder'),
     'remap gives /galvo/current and /galvo/encoder one name'),
    (('--wait', '7200'), 'wait must be within 0..3600 s'),
])
def test_replay_refuses_bad_choices_in_one_line(venv_bin: Path, bag: Path,
                                                args: tuple[str, ...], said: str) -> None:
    out = subprocess.run([str(venv_bin / 'galvo-sysid'), 'replay', str(bag), *args],
                         capture_output=True, text=True, timeout=60, check=False)
    assert out.returncode == 1
    [line] = out.stderr.splitlines()
    assert line.startswith('galvo-sysid replay: error: '), line
    assert said in line, line


def test_replay_of_a_bag_without_moves_says_what_it_holds(venv_bin: Path,
                                                          tmp_path: Path) -> None:
    path = tmp_path / 'results_only'
    with BagWriter(path) as writer:
        writer.add_topic(DRIFT, DRIFT_STATUS)
    out = subprocess.run([str(venv_bin / 'galvo-sysid'), 'replay', str(path)],
                         capture_output=True, text=True, timeout=60, check=False)
    assert out.returncode == 1
    assert out.stderr.splitlines() == [
        f'galvo-sysid replay: error: bag {path} holds no move topic ({CURRENT}, {ENCODER}, '
        f'in any namespace); it holds {DRIFT}: choose with --topics or --all-topics']
