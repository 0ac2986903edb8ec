"""Hostile bags (issue 12): a FIFO named like a bag (defect 16), a metadata.yaml that lies about
its counts (defect 15) or breaks the rosbag2 layout, a corrupted sqlite3 file."""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from galvo_sysid.field.bags import (
    CURRENT_TOPIC,
    ENCODER_TOPIC,
    BagReader,
    BagWriter,
    CorruptBagError,
    SetAside,
)
from galvo_sysid.field.offline import identify_bag
from galvo_sysid.interfaces.topics import MOVE_SAMPLES

BAGS = Path(__file__).resolve().parents[2] / 'bags'


def galvo(*args: str | Path, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(Path(sys.executable).parent / 'galvo-sysid'),
                           *map(str, args)], capture_output=True, text=True, timeout=timeout,
                          check=False)


def one_error_line(proc: subprocess.CompletedProcess[str], command: str) -> str:
    assert 'Traceback' not in proc.stderr, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert proc.returncode == 1
    assert lines[0].startswith(f'galvo-sysid {command}: error: ')
    return lines[0]


# ------------------------------------------------------------------ defect 16: FIFOs

@pytest.mark.parametrize('command', ['info', 'identify'])
@pytest.mark.parametrize('layout', ['file', 'directory', 'listed'])
def test_a_fifo_named_like_a_bag_is_refused_at_once(tmp_path: Path, command: str,
                                                    layout: str) -> None:
    """`info`/`identify` on a FIFO named *.mcap hung until killed (no writer ever came)."""
    if layout == 'file':
        bag = fifo = tmp_path / 'fifo.mcap'
    elif layout == 'directory':  # a directory without metadata.yaml and one storage "file"
        bag = tmp_path / 'bag'
        bag.mkdir()
        fifo = bag / 'bag.mcap'
    else:  # listed by a metadata.yaml
        bag = tmp_path / 'nominal'
        bag.mkdir()
        shutil.copy(BAGS / 'nominal' / 'metadata.yaml', bag)
        fifo = bag / 'nominal.mcap'
    os.mkfifo(fifo)
    proc = galvo(command, bag, timeout=30)  # a reader blocked in open() is killed at 30 s
    line = one_error_line(proc, command)
    assert 'a FIFO, not a regular file' in line
    assert str(fifo) in line


def test_other_special_files_are_refused(tmp_path: Path) -> None:
    bag = tmp_path / 'dev'
    bag.mkdir()
    (bag / 'dev.mcap').symlink_to('/dev/zero')
    with pytest.raises(CorruptBagError, match='a character device, not a regular file'), \
            BagReader(bag):
        pass


# ------------------------------------------------------------------ defect 15: counts claimed

def lying_copy(tmp_path: Path, count: str = '999999999999') -> Path:
    bag = tmp_path / 'meta'
    shutil.copytree(BAGS / 'nominal', bag)
    meta = bag / 'metadata.yaml'
    meta.write_text(meta.read_text().replace('message_count: 400', f'message_count: {count}'))
    return bag


def test_counts_are_the_storages_and_a_lie_is_said(tmp_path: Path) -> None:
    """A metadata.yaml claiming 1e12 messages was shown as fact: '1e+12 moves'."""
    bag = lying_copy(tmp_path)
    with BagReader(bag) as reader:
        info = reader.info
    assert [t.count for t in info.topics] == [400, 400]
    assert info.message_count == 800
    assert info.claims == (
        'metadata.yaml claims 999999999999 messages on /galvo/current, the storage holds 400 '
        '(shown)',
        'metadata.yaml claims 999999999999 messages on /galvo/encoder, the storage holds 400 '
        '(shown)')
    with BagReader(BAGS / 'nominal') as reader:
        assert reader.info.claims == ()  # an honest bag: nothing to say
    found = identify_bag(bag, window_size=100, pooling='inverse-variance', jobs=1)
    assert found.moves == 400


def test_a_total_that_disagrees_with_the_topics_is_said(tmp_path: Path) -> None:
    """Only the top-level message_count wrong: it was not said (the topics' counts were)."""
    bag = tmp_path / 'total'
    shutil.copytree(BAGS / 'nominal', bag)
    meta = bag / 'metadata.yaml'
    text = meta.read_text()
    top = '\n  message_count: 800\n'  # the top level's (a file's is indented further)
    assert text.count(top) == 1
    meta.write_text(text.replace(top, '\n  message_count: 5000\n'))
    with BagReader(bag) as reader:
        info = reader.info
    assert info.message_count == 800
    assert info.claims == ('metadata.yaml claims 5000 messages in all, the storage holds 800 '
                           '(shown)',)
    proc = galvo('info', bag)
    assert proc.returncode == 0, proc.stderr
    assert 'messages: 800' in proc.stdout
    assert 'note: metadata.yaml claims 5000 messages in all' in proc.stdout


def test_the_commands_show_what_was_read(tmp_path: Path) -> None:
    bag = lying_copy(tmp_path)
    proc = galvo('identify', bag)
    assert proc.returncode == 0, proc.stderr
    head = proc.stdout.splitlines()[:3]
    assert ', 400 moves, 2.42 s;' in head[0]
    assert head[1].startswith('note: metadata.yaml claims 999999999999 messages on /galvo/')
    assert '1e+12' not in proc.stdout
    proc = galvo('info', bag)
    assert 'messages: 800' in proc.stdout
    assert 'note: metadata.yaml claims 999999999999 messages on /galvo/current' in proc.stdout


@pytest.mark.parametrize(('edit', 'needle'), [
    (('message_count: 400', 'message_count: abc'), 'message_count must be a whole number'),
    (('message_count: 400', 'message_count: -5'), 'message_count must be within'),
    (('message_count: 400', 'message_count: 1.0e+30'), 'message_count must be within'),
    (('  version: 9', '  version: 10'), 'version must be within 1..9'),
    (('  version: 9', '  version: "9"'), 'version must be a whole number'),
    (('  version: 9', '  version: 9\n  versoin: 9'), "unknown key(s) ['versoin']"),
    (('      name: /galvo/current', '      name: /galvo/current\n      nmae: x'),
     "unknown key(s) ['nmae']"),
    (('        depth: 10', '        depth: 10\n        dpeth: 10'), "unknown key(s) ['dpeth']"),
    (('        depth: 10', '        depth: [10]'), 'depth must be a whole number'),
    (('  - nominal.mcap', '  - ../../nominal.mcap\n  - ..'), "'..' is no file name"),
    (('  storage_identifier: mcap', '  storage_identifier: [mcap]'),
     'storage_identifier must be text'),
    (('  custom_data: null', '  custom_data: {a: [1]}'), 'a must be text'),
    (("  compression_format: ''\n  compression_mode: ''",
      "  compression_format: &a ''\n  compression_mode: *a"), 'aliases are not allowed'),
])
def test_metadata_is_read_strictly(tmp_path: Path, edit: tuple[str, str], needle: str) -> None:
    bag = tmp_path / 'bag'
    shutil.copytree(BAGS / 'nominal', bag)
    meta = bag / 'metadata.yaml'
    text = meta.read_text()
    assert edit[0] in text
    meta.write_text(text.replace(edit[0], edit[1], 1))
    with pytest.raises(CorruptBagError) as err, BagReader(bag):
        pass
    assert '\n' not in str(err.value)
    assert str(err.value).startswith(f'cannot read bag {bag}: ')
    assert needle in str(err.value)


def test_a_missing_storage_file_is_said(tmp_path: Path) -> None:
    bag = tmp_path / 'bag'
    shutil.copytree(BAGS / 'nominal', bag)
    (bag / 'nominal.mcap').rename(bag / 'other.mcap')
    with pytest.raises(CorruptBagError, match=r'nominal\.mcap: no such file'), BagReader(bag):
        pass


def test_an_alias_bomb_in_metadata_is_refused(tmp_path: Path) -> None:
    bag = tmp_path / 'bag'
    shutil.copytree(BAGS / 'nominal', bag)
    bomb = '\n'.join([' a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]'] + [
        f' a{i}: &a{i} [{", ".join([f"*a{i - 1}"] * 9)}]' for i in range(1, 8)])
    meta = bag / 'metadata.yaml'
    meta.write_text(meta.read_text().replace('  custom_data: null',
                                             '  custom_data:\n ' + bomb.replace('\n', '\n ')))
    line = one_error_line(galvo('info', bag), 'info')
    assert 'aliases are not allowed' in line


# ------------------------------------------------------------------ a corrupted sqlite3 file

def nominal_halves() -> list:
    with BagReader(BAGS / 'nominal') as bag:
        return [h for h in bag.move_halves() if not isinstance(h, SetAside)]


def write_bag(path: Path, halves: list, storage: str = 'mcap') -> Path:
    with BagWriter(path, storage=storage) as bag:
        bag.add_topic(CURRENT_TOPIC, MOVE_SAMPLES)
        bag.add_topic(ENCODER_TOPIC, MOVE_SAMPLES)
        for h in halves:
            bag.write(CURRENT_TOPIC if h.signal == 'current' else ENCODER_TOPIC,
                      max(0, round(h.stamp * 1e9)),
                      bag.move_samples(stamp=h.stamp, move_id=h.move_id,
                                       target_angle=h.target_angle,
                                       sample_period=h.sample_period, data=h.data))
    return path


@pytest.mark.parametrize('start', [0.0, 0.1, 0.5, 0.9])
def test_a_corrupted_sqlite3_bag_gives_a_clear_error_or_its_readable_part(
        tmp_path: Path, start: float) -> None:
    """Bytes flipped in a stretch of the file (08_misc_offline.sh's `flip`), at several
    places: each command says what is wrong in one line, or reads what it can."""
    bag = write_bag(tmp_path / 'sq', nominal_halves(), storage='sqlite3')
    db = next(bag.glob('*.db3'))
    data = bytearray(db.read_bytes())
    first = int(len(data) * start)
    for offset in range(first, min(len(data), first + 20_000), 31):
        data[offset] ^= 0xFF
    db.write_bytes(bytes(data))
    for command, *options in (('info',), ('identify',),
                              ('discrepancy', '--max-moves-per-angle', '10')):
        proc = galvo(command, bag, *options, timeout=300)
        assert 'Traceback' not in proc.stderr, (command, proc.stderr)
        if proc.returncode != 0:
            assert len(proc.stderr.strip().splitlines()) == 1, (command, proc.stderr)
            assert proc.stderr.startswith(f'galvo-sysid {command}: error: ')


def test_moves_beyond_any_measurement_are_set_aside_in_discrepancy(tmp_path: Path) -> None:
    """`discrepancy` on 1e300-scaled moves ended in a LinAlgError traceback (defect 13)."""
    halves = []
    for h in nominal_halves():
        data = h.data.copy()
        if h.target_angle == 0.3 and h.move_id % 7 == 0:
            data[5] = math.nan
        if h.target_angle == -0.3 and h.move_id % 7 == 1:
            data[5] = math.inf
        if h.target_angle == 1.5:
            data = data * 1e300
        if h.target_angle == -1.5 and h.signal == 'encoder':
            data = np.full_like(data, 1e308)
        halves.append(replace(h, data=data))
    bag = write_bag(tmp_path / 'nan_inf_big', halves)
    from galvo_sysid.discrepancy.moves import read_moves

    moves, rejected = read_moves(bag, max_moves_per_angle=10)
    assert sorted({float(a) for a in moves.target_angle}) == [-0.3, 0.3]
    reasons = {r['reason'] for r in rejected}
    assert any('beyond +-1e+06: no measurement' in r for r in reasons)
    proc = galvo('discrepancy', bag, '--max-moves-per-angle', '10', '--json', timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert 'Traceback' not in proc.stderr
