"""Windows handed to the fit processes through shared memory (galvo_sysid.monitor.handover):
the same records arrive, the blocks are removed, and without shared memory the pipe serves."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from monitor_fakes import echo_fit

from galvo_sysid.ident.warm import WarmStart
from galvo_sysid.model import REFERENCE_MODEL
from galvo_sysid.monitor import handover
from galvo_sysid.monitor.handover import WindowBuffer, take_window
from galvo_sysid.monitor.moves import Window
from galvo_sysid.monitor.scheduler import WindowScheduler

SHM = Path('/dev/shm')


def _window(index: int, moves: int, samples: int = 512, seed: int = 0) -> Window:
    rng = np.random.default_rng(seed)
    return Window(index=index, target_angle=-0.9, sample_period=1e-5,
                  current=rng.standard_normal((moves, samples)),
                  encoder=rng.standard_normal((moves, samples)),
                  move_ids=tuple(range(moves)), first_stamp=1.0, last_stamp=2.0,
                  warm_start=WarmStart(model=REFERENCE_MODEL, lag_time_constant=6e-6),
                  deadline=123.5)


def _exists(name: str) -> bool:
    return (SHM / name.lstrip('/')).exists()


def test_a_window_comes_out_of_the_block_as_it_went_in() -> None:
    buffer = WindowBuffer()
    gone: list[str] = []

    def put(w: Window, *, new_block: bool) -> None:
        before = buffer.name
        ticket = buffer.put(w)
        assert ticket is not None
        assert ticket.window.current.size == 0  # the records are not in the ticket
        got = take_window(ticket)
        np.testing.assert_array_equal(got.current, w.current)
        np.testing.assert_array_equal(got.encoder, w.encoder)
        assert dataclasses.replace(got, current=w.current, encoder=w.encoder) == w
        assert buffer.name is not None
        assert _exists(buffer.name)
        assert (buffer.name != before) == new_block, (w.current.shape, before, buffer.name)
        if new_block and before is not None:
            gone.append(before)
            assert not _exists(before)  # the block it replaced is removed

    try:
        first = _window(0, 100)  # 819 kB
        put(first, new_block=True)
        put(_window(1, 100, seed=1), new_block=False)  # the same size: reused
        small = _window(2, 7, samples=300, seed=2)  # 34 kB
        put(small, new_block=False)  # smaller, in a block under 1 MiB: reused
        put(_window(3, 150, seed=3), new_block=True)  # 1.2 MB: larger, a new block
        put(small, new_block=True)  # a block over 1 MiB and 4x the window: replaced
        put(_window(4, 1000, seed=4), new_block=True)  # 8.2 MB
        put(_window(5, 260, seed=5), new_block=False)  # 2.1 MB, over a quarter: reused
        put(_window(6, 220, seed=6), new_block=True)  # 1.8 MB, under a quarter: replaced
        put(first, new_block=False)
        last = buffer.name
    finally:
        buffer.close()
    assert len(gone) == 4
    assert buffer.name is None
    assert last is not None
    assert not _exists(last)


def test_records_that_are_not_two_float64_arrays_of_one_shape_go_whole() -> None:
    buffer = WindowBuffer()
    try:
        w = _window(0, 4)
        assert buffer.put(dataclasses.replace(w, current=w.current.astype(np.float32))) is None
        assert buffer.put(dataclasses.replace(w, encoder=w.encoder[:3])) is None
        assert buffer.put(dataclasses.replace(w, current=w.current[0], encoder=w.encoder[0])) \
            is None
        assert buffer.name is None
        assert not buffer.failed
    finally:
        buffer.close()


def _recording(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The names of the blocks the scheduler's buffers use."""
    names: list[str] = []
    put = WindowBuffer.put

    def recorded(self: WindowBuffer, window: Window) -> Any:
        ticket = put(self, window)
        if ticket is not None:
            names.append(ticket.name)
        return ticket

    monkeypatch.setattr(WindowBuffer, 'put', recorded)
    return names


@pytest.mark.parametrize('start_method', ['fork', 'spawn'])
def test_the_fit_processes_get_every_window_through_shared_memory_and_none_is_left(
        monkeypatch: pytest.MonkeyPatch, start_method: str) -> None:
    names = _recording(monkeypatch)
    windows = [_window(i, moves, seed=i) for i, moves in enumerate((100, 100, 120, 3, 100))]
    with WindowScheduler(echo_fit, processes=2, ordered=True, when_full='wait',
                         start_method=start_method, warm_up=False) as scheduler:
        for w in windows:
            scheduler.submit(w)
        outcomes = []
        while len(outcomes) < len(windows):
            outcomes += scheduler.take(block=True)
    assert len(names) == len(windows)  # every window went through a block
    for w, outcome in zip(windows, outcomes, strict=True):
        assert outcome.error is None
        cur, enc, shape, deadline, index, pid = outcome.result  # type: ignore[misc]
        assert (cur, enc, shape, deadline, index) == (float(w.current.sum()),
                                                      float(w.encoder.sum()), w.current.shape,
                                                      123.5, w.index)
        assert pid != os.getpid()  # fitted in a child
    assert not any(_exists(name) for name in set(names))


def test_without_shared_memory_the_windows_go_through_the_pipe(
        monkeypatch: pytest.MonkeyPatch) -> None:
    names = _recording(monkeypatch)

    class NoSharedMemory:
        def __init__(self, *args: object, **kwargs: object) -> None:
            raise OSError(28, 'No space left on device')

    monkeypatch.setattr(handover.shared_memory, 'SharedMemory', NoSharedMemory)
    windows = [_window(i, 50, seed=i) for i in range(3)]
    with WindowScheduler(echo_fit, processes=1, ordered=True, start_method='fork',
                         warm_up=False) as scheduler:
        for w in windows:
            scheduler.submit(w)
        outcomes = []
        while len(outcomes) < len(windows):
            outcomes += scheduler.take(block=True)
    assert names == []
    assert [o.result[0] for o in outcomes] == [float(w.current.sum()) for w in windows]  # type: ignore[index]


KILLED = """
import os, signal, sys, time
import numpy as np
from monitor_fakes import echo_fit
from galvo_sysid.monitor import handover
from galvo_sysid.monitor.moves import Window
from galvo_sysid.monitor.scheduler import WindowScheduler

names = set()
put = handover.WindowBuffer.put


def recorded(self, window):
    ticket = put(self, window)
    names.add(ticket.name)
    return ticket


handover.WindowBuffer.put = recorded
if __name__ == '__main__':
    scheduler = WindowScheduler(echo_fit, processes=2, start_method=sys.argv[1],
                                warm_up=False)
    for i in range(4):
        scheduler.submit(Window(index=i, target_angle=0.3, sample_period=1e-5,
                                current=np.ones((10, 64)), encoder=np.ones((10, 64)),
                                move_ids=tuple(range(10)), first_stamp=0.0, last_stamp=1.0))
    while scheduler.fitted < 4:
        time.sleep(0.05)
    print(' '.join(sorted(names)), flush=True)
    os.kill(os.getpid(), signal.SIGKILL)
"""


@pytest.mark.parametrize('start_method', ['spawn', 'forkserver'])
def test_a_killed_scheduler_leaves_no_block_behind(tmp_path: Path, start_method: str) -> None:
    """SIGKILLed, the scheduler leaves no shared block and no child: the run returns only
    once every process holding its output is gone (a child, the fork server)."""
    import subprocess
    import sys
    import time

    script = tmp_path / 'killed.py'
    script.write_text(KILLED, encoding='utf-8')
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(Path(__file__).parent), str(Path(__file__).parents[2])]))
    proc = subprocess.run([sys.executable, str(script), start_method], capture_output=True,
                          text=True, timeout=60, env=env, check=False)
    assert proc.returncode == -9, proc.stderr
    names = proc.stdout.split()
    assert names  # the windows went through blocks
    deadline = time.monotonic() + 10.0  # the resource tracker removes them once it sees
    while any(_exists(n) for n in names) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(_exists(n) for n in names)


def test_a_full_dev_shm_is_found_when_a_block_is_made_and_the_pipe_serves(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Into a full tmpfs the first write of a block's page kills the process with SIGBUS; the
    block's memory is reserved when it is made, so that fails as an error instead."""
    made: list[str] = []
    real = handover.shared_memory.SharedMemory

    def recorded(*args: Any, **kwargs: Any) -> Any:
        block = real(*args, **kwargs)
        made.append(block.name)
        return block

    def full(fd: int, offset: int, length: int) -> None:
        raise OSError(28, 'No space left on device')

    monkeypatch.setattr(handover.shared_memory, 'SharedMemory', recorded)
    monkeypatch.setattr(handover.os, 'posix_fallocate', full)
    buffer = WindowBuffer()
    try:
        assert buffer.put(_window(0, 10)) is None
        assert buffer.failed
        assert buffer.put(_window(1, 10)) is None  # not tried again
    finally:
        buffer.close()
    assert len(made) == 1
    assert not _exists(made[0])  # the block that could not be reserved is removed
