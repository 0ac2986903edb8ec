"""A window's records handed to a fit process through shared memory, not a pipe.

A window of 100 moves of 512 samples is 819 kB of current and encoder records. Pickled into
the process pool's pipe, it took 3.0 ms to reach an idle fit process on the quiet machine
(1.4 ms of it pickling, the rest 64 kB pipe chunks passed one at a time between the two
processes) and 5.7 ms at the 99th percentile beside two busy processes, where every chunk
waits for the other process to be scheduled; through shared memory 0.8 and 2.2 ms
(``benchmarks/handover_speed.py``, 2026-11-27). Each worker thread of the
:class:`~galvo_sysid.monitor.scheduler.WindowScheduler` owns one block of shared memory
(:class:`multiprocessing.shared_memory.SharedMemory`), reused window after window and
replaced when a window does not fit or needs far less (:data:`SHRINK`). It copies the
records in, hands the fit process a :class:`Ticket` (the block's name, the records' shape
and the window without its records) and waits for the outcome before it writes the next
window. The fit process copies the records out and fits the same arrays as before, so the
numbers do not change.

The blocks are registered with :mod:`multiprocessing`'s resource tracker, which removes
them if the process that made them is killed; :meth:`WindowBuffer.close` removes them
otherwise. Where shared memory cannot be had (no ``/dev/shm``, or it is full: a block's
memory is reserved when it is made, so a full ``/dev/shm`` is an error there, not a SIGBUS
at the first write), the window goes through the pipe as before (:meth:`WindowBuffer.put`
returns None).
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass, replace
from multiprocessing import shared_memory
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from galvo_sysid.monitor.moves import Window

__all__ = ['Ticket', 'WindowBuffer', 'take_window']

_EMPTY = np.zeros((0, 0))

SHRINK = 4
"""A block more than this many times a window's size (and over 1 MiB) is replaced by one of
the window's size: one long window does not hold its memory for the node's life."""


@dataclass(frozen=True)
class Ticket:
    """What a fit process needs to take a window out of a :class:`WindowBuffer`.

    Attributes:
        name: The shared-memory block's name.
        shape: The records' shape (M, N); current first, then encoder, float64.
        window: The window, its records left out.
    """

    name: str
    shape: tuple[int, int]
    window: Window


class WindowBuffer:
    """One worker thread's block of shared memory for the windows it hands over.

    Not thread-safe: one worker thread uses it, one window at a time.
    """

    def __init__(self) -> None:
        self._block: shared_memory.SharedMemory | None = None
        self.failed = False
        """Shared memory could not be had: windows go through the pipe."""

    @property
    def name(self) -> str | None:
        """The current block's name (None before the first window or after :meth:`close`)."""
        return None if self._block is None else self._block.name

    def put(self, window: Window) -> Ticket | None:
        """Copy the window's records into the block; its ticket, or None to send it whole.

        None where the records are not two float64 (M, N) arrays of one shape, or where
        shared memory cannot be had (then never tried again by this buffer).
        """
        cur, enc = window.current, window.encoder
        if self.failed or cur.ndim != 2 or cur.shape != enc.shape or \
                cur.dtype != np.float64 or enc.dtype != np.float64 or not cur.size:
            return None
        size = cur.nbytes + enc.nbytes
        if self._block is None or self._block.size < size or \
                self._block.size > max(SHRINK * size, 1 << 20):
            self.close()
            try:
                self._block = _allocated(size)
            except OSError:
                self.failed = True
                return None
        buf = self._block.buf
        np.ndarray(cur.shape, dtype=np.float64, buffer=buf)[...] = cur
        np.ndarray(enc.shape, dtype=np.float64, buffer=buf, offset=cur.nbytes)[...] = enc
        rows, cols = cur.shape
        return Ticket(name=self._block.name, shape=(int(rows), int(cols)),
                      window=replace(window, current=_EMPTY, encoder=_EMPTY))

    def close(self) -> None:
        """Remove the block (a later :meth:`put` makes a new one)."""
        block, self._block = self._block, None
        if block is not None:
            block.close()
            with contextlib.suppress(FileNotFoundError):  # removed already (the tracker)
                block.unlink()


def _allocated(size: int) -> shared_memory.SharedMemory:
    """A new block of ``size`` bytes, its memory reserved now.

    A block is a file in ``/dev/shm`` (tmpfs) whose pages are found only when first written:
    into a full ``/dev/shm`` that write would kill the process with SIGBUS. Reserving them
    (``posix_fallocate``) fails instead with an OSError the caller can take.
    """
    block = shared_memory.SharedMemory(create=True, size=size)
    if hasattr(os, 'posix_fallocate'):  # Linux (not macOS)
        fd: int = block._fd  # type: ignore[attr-defined]  # its file (POSIX; not in the stubs)
        try:
            os.posix_fallocate(fd, 0, size)
        except OSError:
            block.close()
            block.unlink()
            raise
    return block


def take_window(ticket: Ticket) -> Window:
    """In the fit process: the window of ``ticket``, its records copied out of the block."""
    block = shared_memory.SharedMemory(name=ticket.name)
    try:
        rows, cols = ticket.shape
        n = rows * cols
        flat = np.ndarray((2 * n,), dtype=np.float64, buffer=block.buf)
        cur = flat[:n].reshape(rows, cols).copy()
        enc = flat[n:].reshape(rows, cols).copy()
        del flat  # no view of the block may outlive it
    finally:
        block.close()
    return replace(ticket.window, current=cur, encoder=enc)
