"""``galvo-sysid bag recover`` (issue 12, defect 5), and what ``info``/``identify`` say about a
bag whose recording never finished: one line pointing at ``bag recover``, never a bag read as
empty with exit 0.

The killed recordings here are made without ROS (a writer process killed with SIGKILL); the
live ``galvo-sysid record`` is killed in test/field/test_recorder.py.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

VENV_BIN = Path(sys.executable).parent

KILLED_WRITER = """
import os, sys
from galvo_sysid.field.bags import CURRENT_TOPIC, ENCODER_TOPIC, BagWriter
from galvo_sysid.field.simulate import write_moves
from galvo_sysid.interfaces.topics import MOVE_SAMPLES
from galvo_sysid.sim.simulator import GalvoSimulator
bag = BagWriter(sys.argv[1], storage=sys.argv[2], flush_interval=3600.0)
bag.open()
bag.add_topic(CURRENT_TOPIC, MOVE_SAMPLES)
bag.add_topic(ENCODER_TOPIC, MOVE_SAMPLES)
moves = list(GalvoSimulator(seed=8).moves(angles=[0.3], moves_per_angle=240))
write_moves(bag, moves[:200])
bag.flush()  # 200 moves reach the file
write_moves(bag, moves[200:])  # 40 more wait in memory
os.kill(os.getpid(), 9)
"""


def run(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(VENV_BIN / 'galvo-sysid'), *map(str, args)],
                          capture_output=True, text=True, timeout=300, check=False)


def one_error(proc: subprocess.CompletedProcess[str], command: str) -> str:
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert 'Traceback' not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith(f'galvo-sysid {command}: error: ')
    return lines[0]


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_killed_recording_is_recovered_and_identified(tmp_path: Path, storage: str) -> None:
    bag = tmp_path / 'killed'
    subprocess.run([sys.executable, '-c', KILLED_WRITER, str(bag), storage], check=False,
                   timeout=300)
    for command in ('info', 'identify'):
        line = one_error(run(command, bag), command)
        assert line.endswith(f'bag {bag} is incomplete (recording was interrupted); '
                             f'run galvo-sysid bag recover {bag}')
    done = run('bag', 'recover', bag)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f'bag {bag}: recovered 400 messages of 2 topics, ')
    info = run('info', bag)
    assert info.returncode == 0, info.stderr
    assert 'messages: 400\n' in info.stdout
    ident = run('identify', bag)
    assert ident.returncode == 0, ident.stderr
    again = run('bag', 'reindex', bag)  # the alias; a complete bag is left as it is
    assert again.returncode == 0, again.stderr
    assert 'nothing to recover: 400 messages of 2 topics' in again.stdout


def test_cut_mcap_file_says_how_to_recover(tmp_path: Path) -> None:
    bag = tmp_path / 'sim'
    made = run('simulate', '--out', bag, '--angles', '0.3', '--moves-per-angle', '40')
    assert made.returncode == 0, made.stderr
    file = next(bag.glob('*.mcap'))
    with file.open('r+b') as f:
        f.truncate(file.stat().st_size - 100)  # the footer is gone
    line = one_error(run('info', bag), 'info')
    assert 'is incomplete (the mcap file' in line
    assert line.endswith(f'run galvo-sysid bag recover {bag}')
    assert run('bag', 'recover', bag).returncode == 0
    info = run('info', bag)
    assert info.returncode == 0, info.stderr
    assert 'messages: 80\n' in info.stdout  # only the summary was cut: every message kept


def test_bag_recover_refuses_what_is_not_a_bag(tmp_path: Path) -> None:
    assert 'bag not found' in one_error(run('bag', 'recover', tmp_path / 'nope'), 'bag')
    (tmp_path / 'dir').mkdir()
    assert 'not a rosbag2 bag' in one_error(run('bag', 'recover', tmp_path / 'dir'), 'bag')
    two = tmp_path / 'two'
    two.mkdir()
    (two / 'a.mcap').write_bytes(b'x')
    shutil.copy(two / 'a.mcap', two / 'b.mcap')
    assert 'it holds 2' in one_error(run('bag', 'recover', two), 'bag')
    usage = run('bag')
    assert usage.returncode == 2


def test_bag_help_teaches_recover() -> None:
    done = run('bag', 'recover', '--help')
    assert done.returncode == 0
    assert 'galvo-sysid bag recover /tmp/field1' in done.stdout
    assert 'bag' in run('--help').stdout
    record = run('record', '--help').stdout
    assert '--flush-interval' in record
    assert 'bag recover' in record
