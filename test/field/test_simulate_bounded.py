"""galvo_sysid.field.simulate: bounded memory, bounded options, atomic bags (issue 12: defects
11, 13 and 17)."""

from __future__ import annotations

import errno
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.field.bags import BagExistsError, BagReader, BagWriter, SetAside
from galvo_sysid.field.simulate import simulate_bag
from galvo_sysid.sim.simulator import GalvoSimulator


class DiskFullError(OSError):
    """What a write raises on a full disk, injected after some messages."""


def fail_after(monkeypatch: pytest.MonkeyPatch, messages: int,
               error: BaseException | None = None) -> None:
    """Make the bag writer fail after ``messages`` messages (a full disk, or Ctrl-C)."""
    original = BagWriter.write
    count = [0]

    def write(self: BagWriter, topic: str, timestamp: int, message: object) -> None:
        count[0] += 1
        if count[0] > messages:
            raise error or DiskFullError(errno.ENOSPC, 'No space left on device')
        original(self, topic, timestamp, message)

    monkeypatch.setattr(BagWriter, 'write', write)


def test_moves_are_written_as_they_are_simulated(monkeypatch: pytest.MonkeyPatch,
                                                 tmp_path: Path) -> None:
    """Defect 11: the whole schedule was built in memory before the first move was written.

    Four angles of a million moves each (the largest schedule allowed per angle): the writer
    fails after 200 messages, by then the memory taken must not have grown with the schedule
    (the list of its 4 million targets alone was about 130 MB).
    """
    fail_after(monkeypatch, 200)
    tracemalloc.start()
    try:
        with pytest.raises(DiskFullError):
            simulate_bag(tmp_path / 'huge', angles=[0.3, 0.6, 0.9, 1.2],
                         moves_per_angle=1_000_000, seed=1)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 40e6, f'{peak / 1e6:.0f} MB'
    assert list(tmp_path.iterdir()) == []  # and nothing is left behind (defect 17)


@pytest.mark.parametrize('error', [DiskFullError(errno.ENOSPC, 'No space left on device'),
                                   KeyboardInterrupt()])
def test_a_failed_run_leaves_nothing_and_the_rerun_works(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path, error: BaseException) -> None:
    """Defect 17: a failed simulate left an empty bag behind that blocked the re-run."""
    out = tmp_path / 'run'
    with monkeypatch.context() as patch:
        fail_after(patch, 10, error)
        with pytest.raises(type(error)):
            simulate_bag(out, angles=[0.3], moves_per_angle=40, seed=2)
    assert list(tmp_path.iterdir()) == []
    summary = simulate_bag(out, angles=[0.3], moves_per_angle=40, seed=2)
    assert summary.moves == 40
    assert sorted(p.name for p in out.iterdir()) == ['metadata.yaml', 'run.mcap']
    assert [p.name for p in tmp_path.iterdir()] == ['run']
    with BagReader(out) as bag:
        assert bag.info.message_count == 80
    with pytest.raises(BagExistsError):  # never overwritten
        simulate_bag(out, angles=[0.3], moves_per_angle=4)


def test_streamed_moves_are_the_simulators(tmp_path: Path) -> None:
    """Written in chunks, the moves of one angle are bit for bit the simulator's."""
    from galvo_sysid.field import simulate

    simulate_bag(tmp_path / 'b', angles=[0.6], moves_per_angle=2 * simulate.CHUNK + 130,
                 seed=4)
    expected = GalvoSimulator(seed=4).moves(angles=[0.6],
                                            moves_per_angle=2 * simulate.CHUNK + 130)
    with BagReader(tmp_path / 'b') as bag:
        halves = [h for h in bag.move_halves()
                  if not isinstance(h, SetAside) and h.signal == 'encoder']
    assert len(halves) == 2 * simulate.CHUNK + 130
    for half, move in zip(halves, expected, strict=True):
        assert half.move_id == move.move_id
        assert np.array_equal(half.data, move.encoder)


@pytest.mark.parametrize(('options', 'needle'), [
    ({'moves_per_angle': 1_000_002}, 'moves-per-angle must be an even number within 2..'),
    ({'moves_per_angle': 3}, 'even number'),
    ({'seed': -1}, 'seed must be a whole number within 0..2147483647'),
    ({'seed': 2**40}, 'seed must be'),
    ({'effects': ['input_delay:delay=1']}, 'delay must be > 0 and <= 0.01'),
])
def test_bad_options_are_refused_before_anything_is_written(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path, options: dict, needle: str) -> None:
    fail_after(monkeypatch, 0)  # refused before the first move is written
    with pytest.raises(ConfigurationError, match=needle):
        simulate_bag(tmp_path / 'x', angles=[0.3], **options)
    assert list(tmp_path.iterdir()) == []


def test_a_bag_larger_than_the_disk_is_refused(monkeypatch: pytest.MonkeyPatch,
                                               tmp_path: Path) -> None:
    import shutil

    usage = shutil.disk_usage(tmp_path)
    monkeypatch.setattr(shutil, 'disk_usage', lambda _: usage._replace(free=10_000_000))
    fail_after(monkeypatch, 0)  # refused before the first move is written
    with pytest.raises(ConfigurationError, match=r'more than the 0\.01 GB free'):
        simulate_bag(tmp_path / 'x', angles=[0.3, 0.6], moves_per_angle=10_000)
    assert list(tmp_path.iterdir()) == []
