"""How many fit processes are worth starting on this machine (CPUs, memory).

:func:`job_limit` caps ``galvo-sysid identify --jobs``
(:func:`~galvo_sysid.field.offline.identify_bag`): more processes than CPUs or than the
memory holds only cost.
"""

from __future__ import annotations

import os

__all__ = ['job_limit']

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
