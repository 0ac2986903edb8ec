"""galvo_sysid: online system identification and drift monitoring of galvano scanners.

Numerics live in plain modules that never import rclpy (``plant``, ``delay``, ``arx``,
``modal``, ``paper``, ``refine``, ``identify``, ``simulator``, ``pairing``, ``drift``, ...);
the ROS 2 nodes live in :mod:`galvo_sysid.nodes`; the command-line tool in
:mod:`galvo_sysid.cli.main`.

Importing the package changes nothing in the process (no environment variables); the entry
points call :func:`limit_blas_threads` before numpy is imported and :func:`keep_freed_memory`
(``galvo-sysid`` in its main, the nodes in :mod:`galvo_sysid.nodes`, which their modules
import first), and :func:`bounded_dds_memory` before rclpy starts (the nodes, and the live
tools of :mod:`galvo_sysid.field.live`).
"""

from __future__ import annotations

import ctypes
import importlib
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping

__all__ = ['BLAS_THREAD_VARIABLES', 'FASTDDS_DEFAULTS', '__version__', 'bounded_dds_memory',
           'keep_freed_memory', 'lazy_names', 'limit_blas_threads']

__version__ = '0.1.0'

BLAS_THREAD_VARIABLES = ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS')
"""The environment variables that set the thread count of numpy's and scipy's BLAS."""


def limit_blas_threads() -> None:
    """Give BLAS one thread, unless the environment already says otherwise.

    The fits solve many small dense problems: a multi-threaded BLAS makes them 2-8x slower on
    a 2-core machine and competes with the ROS executor threads (parallel windows use
    processes instead). BLAS reads the variables when it is loaded, so an entry point calls
    this before anything imports numpy or scipy; a variable set before Python starts wins.
    """
    for name in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(name, '1')


def lazy_names(package: str, where: Mapping[str, str]) -> Callable[[str], Any]:
    """A subpackage's module ``__getattr__`` that loads each public name when first used.

    So that importing one light module of a subpackage (say ``galvo_sysid.ident.methods``)
    does not import the whole subpackage's API (the fits and :mod:`scipy.optimize`).

    Args:
        package: The subpackage (its ``__name__``).
        where: Public name -> the submodule defining it.
    """
    def getattr_(name: str) -> Any:
        module = where.get(name)
        if module is None:
            raise AttributeError(f'module {package!r} has no attribute {name!r}')
        value = getattr(importlib.import_module(f'{package}.{module}'), name)
        setattr(sys.modules[package], name, value)
        return value
    return getattr_


_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3   # glibc's mallopt parameters
_MMAP_THRESHOLD = 32 * 2**20   # glibc's largest: blocks up to 32 MiB come from the heap
_TRIM_THRESHOLD = 2**31 - 1    # free memory at the heap's top is kept


def keep_freed_memory() -> bool:
    """Make the C library keep freed memory for reuse instead of returning it (glibc only).

    A window's fit allocates and frees arrays of 1-10 MB thousands of times. By default glibc
    serves such blocks by mmap and returns them (and trims its heap), so every new block
    costs page faults anew: about 10 % of a fit's time here (median 98 -> 88 ms per window,
    same results). With ``mallopt`` blocks up to 32 MiB come from the heap and the heap is
    not trimmed: the process keeps its peak use, which the fits' temporaries bound, and
    reuses it. Setting one of the two alone is slower than neither (it ends glibc's
    adaptive thresholds). A user who set ``MALLOC_MMAP_THRESHOLD_`` or
    ``MALLOC_TRIM_THRESHOLD_`` keeps them; another C library is left alone.

    Returns:
        Whether the setting was made.
    """
    if 'MALLOC_MMAP_THRESHOLD_' in os.environ or 'MALLOC_TRIM_THRESHOLD_' in os.environ:
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    return bool(mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD)
                and mallopt(_M_TRIM_THRESHOLD, _TRIM_THRESHOLD))


FASTDDS_DEFAULTS = Path(__file__).with_name('data') / 'fastdds_defaults.xml'
"""Fast DDS profile of galvo_sysid's processes: readers free each sample's buffer."""


def bounded_dds_memory() -> None:
    """Make Fast DDS readers free received buffers, unless the user configured Fast DDS.

    rmw_fastrtps keeps every pooled receive buffer at the size of the largest message that
    ever used it, so a flood of oversized messages holds up to ``qos_depth`` times the largest
    message even though the sysid node refuses them before decoding (1.9 GiB after 30 s of
    40 MB records). :data:`FASTDDS_DEFAULTS` gives readers DYNAMIC history memory; this points
    Fast DDS to it (``FASTRTPS_DEFAULT_PROFILES_FILE``, ``RMW_FASTRTPS_USE_QOS_FROM_XML=1``).
    A user who set either variable, or another RMW, keeps their own configuration: their
    profile should then give readers DYNAMIC memory too (``config/fastdds_localhost.xml``
    does). Call before rclpy starts; Fast DDS reads the variables once.
    """
    if os.environ.get('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp') not in ('', 'rmw_fastrtps_cpp'):
        return
    if 'FASTRTPS_DEFAULT_PROFILES_FILE' in os.environ or \
            'RMW_FASTRTPS_USE_QOS_FROM_XML' in os.environ or not FASTDDS_DEFAULTS.is_file():
        return
    os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(FASTDDS_DEFAULTS)
    os.environ['RMW_FASTRTPS_USE_QOS_FROM_XML'] = '1'
