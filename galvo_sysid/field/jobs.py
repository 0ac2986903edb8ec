"""How many fit processes are worth starting here, and a map over forked processes.

:func:`job_limit` caps ``galvo-sysid identify --jobs``
(:func:`~galvo_sysid.field.offline.identify_bag`): more processes than CPUs or than the
memory holds only cost. :func:`fork_map` shares the joint fit's scans over the windows with
forked children (the joint fit comes after the windows' fits, when their processes are gone).
"""

from __future__ import annotations

import contextlib
import os
import pickle
import signal
import threading
from typing import TYPE_CHECKING, Any, TypeVar

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

__all__ = ['fork_map', 'job_limit']

_T = TypeVar('_T')
_R = TypeVar('_R')

JOB_BYTES = 200_000_000
"""Memory set aside per fit process when :func:`job_limit` caps the processes [bytes] (a
forked child fitting windows of 100 moves of 512 samples peaks near 60 MB; the rest is
margin for longer records and the parent's own share)."""


def job_limit() -> tuple[int, str]:
    """The most fit processes worth starting here, and why (``'2 CPU(s)'``, ...).

    The CPUs this process may run on (more processes only take turns), and the memory
    available (``MemAvailable`` of ``/proc/meminfo``, where there is one) over
    :data:`JOB_BYTES`: ``identify --jobs 40`` must not start 41 processes on two cores.
    """
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cpus = os.cpu_count() or 1
    limit, why = max(1, cpus), f'{max(1, cpus)} CPU(s)'
    available = _available_memory()
    if available is not None and available // JOB_BYTES < limit:
        limit = max(1, available // JOB_BYTES)
        why = f'{available / 1e9:.1f} GB of memory available'
    return limit, why


def _available_memory() -> int | None:
    """``MemAvailable`` of ``/proc/meminfo`` [bytes], None where unknown."""
    try:
        with open('/proc/meminfo', encoding='ascii') as f:
            for line in f:
                if line.startswith('MemAvailable:'):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def fork_map(fn: Callable[[_T], _R], items: Sequence[_T], *, processes: int = 2) -> list[_R]:
    """``[fn(x) for x in items]``, shared in order between this process and forked children.

    This process takes the first share; each child inherits the data (nothing is pickled but
    its results), works through its share and sends the results back. Each result is made by
    the same call on the same data as in a plain loop, so the list is the same, bit for bit.
    Where a fork is unsafe or fails, the loop runs here alone: one process or item, no
    ``os.fork``, other threads running in this process (a child would inherit their locks
    held), or the fork refused. A child that fails in any way has its share done here (an
    error ``fn`` raises is then raised here). Children are reaped, also when this process's
    share raises.

    Args:
        fn: Called once per item; its results must pickle.
        items: The work.
        processes: This process and the children: at most this many, each with at least one
            item.

    Returns:
        The results, in the order of ``items``.
    """
    n = len(items)
    count = min(int(processes), n)
    if count < 2 or not hasattr(os, 'fork') or threading.active_count() > 1:
        return [fn(x) for x in items]
    bounds = [n * j // count for j in range(count + 1)]
    pending: dict[int, tuple[int, int]] = {}  # share -> (child's pid, read end of its pipe)
    try:
        for j in range(1, count):
            try:
                pending[j] = _fork_share(fn, items[bounds[j]: bounds[j + 1]])
            except OSError:
                break  # no more processes: the rest is done here
        out = [fn(x) for x in items[: bounds[1]]]
        for j in range(1, count):
            got: list[_R] | None = _collect(*pending[j]) if j in pending else None
            pending.pop(j, None)
            out += got if got is not None else [fn(x) for x in items[bounds[j]: bounds[j + 1]]]
        return out
    finally:
        for pid, fd in pending.values():  # on an error here: no child is left behind
            with contextlib.suppress(OSError):
                os.close(fd)
            _reap(pid, kill=True)


def _fork_share(fn: Callable[[_T], _R], share: Sequence[_T]) -> tuple[int, int]:
    """Fork a child that sends ``[fn(x) for x in share]`` pickled down a pipe."""
    read, write = os.pipe()
    try:
        pid = os.fork()
    except OSError:
        os.close(read)
        os.close(write)
        raise
    if pid == 0:  # the child: never returns, never runs the parent's exit handlers
        code = 1
        try:
            os.close(read)
            data = pickle.dumps([fn(x) for x in share], protocol=pickle.HIGHEST_PROTOCOL)
            with os.fdopen(write, 'wb') as f:
                f.write(data)
            code = 0
        finally:
            os._exit(code)
    os.close(write)
    return pid, read


def _collect(pid: int, fd: int) -> list[Any] | None:
    """A child's results, or None if it failed (it is reaped either way)."""
    with os.fdopen(fd, 'rb') as f:
        data = f.read()
    ok = _reap(pid, kill=False) == 0 and bool(data)
    try:
        return list(pickle.loads(data)) if ok else None  # our own child's bytes
    except (pickle.UnpicklingError, EOFError, ValueError):
        return None


def _reap(pid: int, *, kill: bool) -> int:
    """Wait for a child (killed first if ``kill``); its exit status (-1 where unknown)."""
    if kill:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    try:
        _, status = os.waitpid(pid, 0)
    except ChildProcessError:
        return -1
    return os.waitstatus_to_exitcode(status)
