"""Bags that survive a crash and a full disk (issue 12, defect 5): field/bags/storage_mcap.py,
storage_sqlite3.py, the recording mode of writer.py, completeness.py and recovery.py, without ROS.

A recording's writer is killed (SIGKILL, no clean-up runs), cut at random bytes, damaged or
starved of disk space; what was written before must stay readable after
``recover`` (or at once, for a full disk) and an unfinished bag must never read as empty.
"""

from __future__ import annotations

import errno
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from full_disk import tmpfs

from galvo_sysid.field.bags import (
    CURRENT_TOPIC,
    BagError,
    BagReader,
    BagWriteError,
    BagWriter,
    CorruptBagError,
    IncompleteBagError,
)
from galvo_sysid.field.bags import storage_mcap as storage_module
from galvo_sysid.field.bags.completeness import check_complete
from galvo_sysid.field.bags.recovery import recover
from galvo_sysid.field.bags.writer import LOCK_NAME
from galvo_sysid.interfaces.topics import MOVE_SAMPLES

STORAGES = ['mcap', 'sqlite3']
SAMPLES = 600  # about one move record of the paper's scanner (4.8 kB a message)


def _message(bag: BagWriter, i: int, rng: np.random.Generator) -> object:
    return bag.move_samples(stamp=1.0 + 0.006 * i, move_id=i, target_angle=0.3,
                            sample_period=1e-5, data=rng.normal(size=SAMPLES))


def _expected(n: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.normal(size=SAMPLES) for _ in range(n)]


def _decoded(bag: Path) -> list[tuple[int, np.ndarray]]:
    """(move id, data) of every message in the bag, in log-time order."""
    with BagReader(bag) as reader:
        out = []
        for raw in reader.raw_messages():
            msg = reader.deserialize(raw)
            out.append((int(msg.move_id), np.asarray(msg.data)))  # type: ignore[attr-defined]
    return out


def _read_ids(bag: Path) -> list[int]:
    return [i for i, _ in _decoded(bag)]


def _assert_prefix(bag: Path, seed: int) -> int:
    """The bag holds the first k messages written, intact; return k."""
    found = _decoded(bag)
    ids = [i for i, _ in found]
    assert ids == list(range(len(ids)))
    expected = _expected(len(ids), seed)
    for i, data in found:
        np.testing.assert_array_equal(data, expected[i])
    return len(ids)


# --------------------------------------------------------------------------- a killed writer

WRITER = """
import sys, numpy as np
from galvo_sysid.field.bags import BagWriter, CURRENT_TOPIC
from galvo_sysid.interfaces.topics import MOVE_SAMPLES
bag, storage, seed = sys.argv[1], sys.argv[2], int(sys.argv[3])
rng = np.random.default_rng(seed)
w = BagWriter(bag, storage=storage, flush_interval=0.1)
w.open()
w.add_topic(CURRENT_TOPIC, MOVE_SAMPLES)
i = 0
while True:
    msg = w.move_samples(stamp=1.0 + 0.006 * i, move_id=i, target_angle=0.3,
                         sample_period=1e-5, data=rng.normal(size=600))
    w.write(CURRENT_TOPIC, 10**9 + 6 * 10**6 * i, msg)
    i += 1
    print(i, w.kept, flush=True)
"""


def _progress(out: Path) -> tuple[int, int]:
    """(messages written, messages in the file) on the writer's last complete line."""
    lines = out.read_text().split('\n')  # the last item: a line cut short, or ''
    if len(lines) < 2:
        return 0, 0
    written, kept = lines[-2].split()
    return int(written), int(kept)


@pytest.mark.parametrize('storage', STORAGES)
def test_killed_writer_keeps_what_reached_the_file(tmp_path: Path, storage: str) -> None:
    bag = tmp_path / 'bag'
    out = tmp_path / 'writer.out'
    with out.open('w') as stdout:
        proc = subprocess.Popen([sys.executable, '-c', WRITER, str(bag), storage, '7'],
                                stdout=stdout)
    try:
        end = time.monotonic() + 60
        while _progress(out)[1] < 300:  # a few flushes happened
            assert proc.poll() is None, 'the writer stopped'
            assert time.monotonic() < end, 'the writer did not progress'
            time.sleep(0.05)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    written, kept = _progress(out)
    # never read as empty, never a traceback: a clear error naming the way out
    with pytest.raises(IncompleteBagError, match=r'recording was interrupted.*bag recover'):
        check_complete(bag)
    with pytest.raises(IncompleteBagError) as err, BagReader(bag):
        pass
    assert '\n' not in str(err.value)
    result = recover(bag)
    assert result.interrupted
    assert result.flush_interval == pytest.approx(0.1)
    assert kept <= result.messages <= written + 1  # + the one being written when killed
    assert _assert_prefix(bag, 7) == result.messages
    assert not (bag / LOCK_NAME).exists()
    check_complete(bag)  # complete now
    again = recover(bag)  # and left as it is
    assert again.messages == result.messages
    assert 'nothing to recover' in again.summary()


# --------------------------------------------------------------------------- cut and damaged


def _small_chunk_bag(path: Path, n: int, seed: int, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setattr(storage_module, 'CHUNK_BYTES', 12_000)  # 2-3 messages a chunk
    rng = np.random.default_rng(seed)
    with BagWriter(path) as bag:
        bag.add_topic(CURRENT_TOPIC, MOVE_SAMPLES)
        for i in range(n):
            bag.write(CURRENT_TOPIC, 10**9 + i, _message(bag, i, rng))
    return next(path.glob('*.mcap'))


def _chunks(file: Path) -> list[tuple[int, int, int]]:
    """(start, end, messages) of each chunk, from the complete file's index."""
    from rosbags.rosbag2.storage_mcap import McapReader

    reader = McapReader(file)
    reader.open()
    try:
        return [(c.chunk_start_offset, c.chunk_start_offset + c.chunk_length,
                 sum(c.channel_count.values())) for c in reader.chunks]
    finally:
        reader.close()


def test_recover_keeps_every_chunk_before_the_cut(tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    original = _small_chunk_bag(tmp_path / 'whole', 40, 3, monkeypatch)
    chunks = _chunks(original)
    assert len(chunks) > 10
    size = original.stat().st_size
    rng = np.random.default_rng(12)
    cuts = sorted({int(c) for c in rng.integers(8, size, 12)} | {chunks[3][1], chunks[3][1] + 3,
                                                                 size - 1})
    for k, cut in enumerate(cuts):
        bag = tmp_path / f'cut{k}'
        shutil.copytree(original.parent, bag)
        with (bag / original.name).open('r+b') as f:
            f.truncate(cut)
        with pytest.raises(IncompleteBagError, match='no footer'):
            check_complete(bag)
        result = recover(bag)
        want = sum(n for _, end, n in chunks if end <= cut)
        assert result.messages == want, (cut, result.summary())
        assert _assert_prefix(bag, 3) == want
        kept = [i for i, (_, end, _) in enumerate(chunks) if end <= cut]
        if kept and kept[-1] + 1 < len(chunks):  # what is cut: the rest after the last unit
            after = chunks[kept[-1] + 1][0]  # its message indexes end where the next starts
            good = after if after <= cut else chunks[kept[-1]][1]
            assert result.dropped_bytes == cut - good


def _damaged(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, *, finished: bool) -> tuple[
        Path, Path, list[tuple[int, int, int]], bytes]:
    """A copy of a 30-message bag (seed 5) with one flipped bit in its fifth chunk's data;
    unless ``finished``, cut after its last chunk (no summary: an interrupted recording).
    Returns the bag, its storage file, the chunks and the file's bytes."""
    original = _small_chunk_bag(tmp_path / 'whole', 30, 5, monkeypatch)
    chunks = _chunks(original)
    bag = tmp_path / 'damaged'
    shutil.copytree(original.parent, bag)
    file = bag / original.name
    data = bytearray(file.read_bytes())
    start, end, _ = chunks[4]
    data[(start + end) // 2] ^= 0xFF
    if not finished:
        data = data[: chunks[-1][1]]
    file.write_bytes(bytes(data))
    return bag, file, chunks, bytes(data)


def test_recover_stops_at_a_damaged_chunk(tmp_path: Path,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    bag, _, chunks, _ = _damaged(tmp_path, monkeypatch, finished=False)
    result = recover(bag)
    assert result.messages == sum(n for _, _, n in chunks[:4])
    assert _assert_prefix(bag, 5) == result.messages


def test_a_finished_bag_damaged_inside_keeps_what_is_cut_beside_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A complete file (footer and all) with one chunk damaged: the recovery keeps the chunks
    before it in the bag and the rest, byte for byte, in ``<file>.cut`` (a second recovery
    does not overwrite it); no reader takes the ``.cut`` file for the bag's storage."""
    bag, file, chunks, data = _damaged(tmp_path, monkeypatch, finished=True)
    result = recover(bag)
    assert result.messages == sum(n for _, _, n in chunks[:4])
    assert result.cut_to == file.with_name(file.name + '.cut')
    assert result.cut_to.read_bytes() == bytes(data[len(data) - result.dropped_bytes:])
    assert f'kept in {result.cut_to}' in result.summary()
    assert _assert_prefix(bag, 5) == result.messages
    with file.open('ab') as f:  # damaged again at its end: a second cut, its own file
        f.write(b'\x00' * 100)
    again = recover(bag)
    assert again.cut_to == file.with_name(file.name + '.cut.1')
    assert result.cut_to.read_bytes() == bytes(data[len(data) - result.dropped_bytes:])


def test_a_storage_file_among_others_is_recovered_alone(tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """A cut .mcap file named among other .mcap files of its directory (not a bag
    directory): that file is repaired, no metadata.yaml is written beside it."""
    original = _small_chunk_bag(tmp_path / 'whole', 20, 3, monkeypatch)
    chunks = _chunks(original)
    loose = tmp_path / 'loose'
    loose.mkdir()
    for name in ('a.mcap', 'b.mcap'):
        shutil.copy(original, loose / name)
    with (loose / 'b.mcap').open('r+b') as f:
        f.truncate(chunks[5][1] + 3)
    result = recover(loose / 'b.mcap')
    assert result.alone
    assert result.path == loose / 'b.mcap'
    assert result.messages == sum(n for _, _, n in chunks[:6])
    assert not (loose / 'metadata.yaml').exists()
    assert (loose / 'a.mcap').read_bytes() == original.read_bytes()


def test_recover_refuses_what_it_cannot_use(tmp_path: Path) -> None:
    with pytest.raises(BagError, match='not found'):
        recover(tmp_path / 'nope')
    (tmp_path / 'empty').mkdir()
    with pytest.raises(CorruptBagError, match=r'one \.mcap or \.db3 file'):
        recover(tmp_path / 'empty')
    garbage = tmp_path / 'garbage'
    garbage.mkdir()
    (garbage / 'garbage.mcap').write_bytes(np.random.default_rng(1).bytes(5000))
    with pytest.raises(CorruptBagError, match='not an mcap file'):
        recover(garbage)


# --------------------------------------------------------------------------- while recording


@pytest.mark.parametrize('storage', STORAGES)
def test_a_bag_being_recorded_is_said_so_and_not_recovered(tmp_path: Path,
                                                           storage: str) -> None:
    rng = np.random.default_rng(2)
    with BagWriter(tmp_path / 'live', storage=storage, flush_interval=0.01) as bag:
        bag.add_topic(CURRENT_TOPIC, MOVE_SAMPLES)
        for i in range(5):
            bag.write(CURRENT_TOPIC, 10**9 + i, _message(bag, i, rng))
        with pytest.raises(IncompleteBagError, match='still being recorded'), \
                BagReader(tmp_path / 'live'):
            pass
        with pytest.raises(BagError, match='still being recorded'):
            recover(tmp_path / 'live')
    assert not (tmp_path / 'live' / LOCK_NAME).exists()
    assert _read_ids(tmp_path / 'live') == list(range(5))


def test_an_unfinished_sqlite3_file_is_not_read_as_empty(tmp_path: Path) -> None:
    """A bag killed before any batch was committed (as the old writer always was)."""
    bag = tmp_path / 'old'
    code = ('import os, sys\n'
            'from galvo_sysid.field.bags import BagWriter, CURRENT_TOPIC\n'
            'from galvo_sysid.interfaces.topics import MOVE_SAMPLES\n'
            'w = BagWriter(sys.argv[1], storage="sqlite3")\n'  # no flush_interval: one batch
            'w.open()\n'
            'w.add_topic(CURRENT_TOPIC, MOVE_SAMPLES)\n'
            'w.write_raw(CURRENT_TOPIC, 1, b"\\x00\\x01\\x00\\x00" + bytes(100))\n'
            'os.kill(os.getpid(), 9)\n')
    subprocess.run([sys.executable, '-c', code, str(bag)], check=False, timeout=60)
    assert not (bag / 'metadata.yaml').exists()
    with pytest.raises(IncompleteBagError, match='incomplete'), BagReader(bag):
        pass
    result = recover(bag)
    assert result.rolled_back
    assert result.messages == 0  # the uncommitted message is gone, and said so
    assert 'rolled back' in result.summary()
    with BagReader(bag) as reader:
        assert reader.info.message_count == 0


# --------------------------------------------------------------------------- a full disk


def _fill(bag: BagWriter, seed: int, *, every: int = 10,
          limit: int = 5000) -> tuple[int, BagWriteError]:
    """Write until writing fails, flushing every ``every`` messages (the clock's part in
    flushing is left out: it depends on the machine's speed)."""
    rng = np.random.default_rng(seed)
    for i in range(limit):
        try:
            bag.write(CURRENT_TOPIC, 10**9 + i, _message(bag, i, rng))
            if i % every == every - 1:
                bag.flush()
        except BagWriteError as err:
            return i, err
    raise AssertionError('the disk never filled up')


def _lost(text: str) -> int:
    """The messages a write error says were lost (0 if it says none)."""
    import re

    found = re.search(r'([\d,]+) messages not yet written are lost', text)
    return int(found.group(1).replace(',', '')) if found else 0


@pytest.mark.parametrize('storage', STORAGES)
def test_full_disk_stops_cleanly_and_keeps_what_was_written(tmp_path: Path,
                                                            storage: str) -> None:
    with tmpfs(tmp_path / 'disk', '2m') as disk:
        bag = BagWriter(disk / 'bag', storage=storage, flush_interval=3600.0)
        bag.open()
        bag.add_topic(CURRENT_TOPIC, MOVE_SAMPLES)
        tried, err = _fill(bag, 11)
        text = str(err)
        assert '\n' not in text
        assert 'No space left on device' in text
        assert 'the bag is closed and keeps the' in text
        with pytest.raises(BagWriteError):  # and stays stopped
            bag.write_raw(CURRENT_TOPIC, 1, b'')
        bag.close()  # idempotent, no second error
        assert not (disk / 'bag' / LOCK_NAME).exists()
        check_complete(disk / 'bag')  # closed, no recovery needed
        kept = _assert_prefix(disk / 'bag', 11)
        assert kept == bag.kept > 0
        assert kept + _lost(text) in (tried, tried + 1)  # every message accounted for


def test_a_failed_write_keeps_the_file_whole(tmp_path: Path,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """The lowest write call fails (ENOSPC) part-way through a chunk: no torn chunk stays."""
    real = os.pwrite
    state = {'budget': 150_000}

    def pwrite(fd: int, data: bytes | memoryview, offset: int) -> int:
        if len(data) > state['budget'] > 0:
            n = real(fd, bytes(data)[: state['budget'] // 2], offset)  # a short write first
            state['budget'] = 0
            return n
        if state['budget'] == 0:
            state['budget'] = -1  # the next call fails; then the space is back
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        if state['budget'] > 0:
            state['budget'] -= len(data)
        return real(fd, data, offset)

    monkeypatch.setattr(storage_module, 'CHUNK_BYTES', 20_000)  # 4-5 messages a chunk
    bag = BagWriter(tmp_path / 'bag', flush_interval=10.0)
    bag.open()
    bag.add_topic(CURRENT_TOPIC, MOVE_SAMPLES)
    monkeypatch.setattr(storage_module.os, 'pwrite', pwrite)
    tried, err = _fill(bag, 4)
    monkeypatch.undo()
    assert 'No space left on device' in str(err)
    check_complete(tmp_path / 'bag')
    kept = _assert_prefix(tmp_path / 'bag', 4)
    assert kept == bag.kept > 0
    assert kept + _lost(str(err)) in (tried, tried + 1)
