"""galvo_sysid: online system identification and drift monitoring of galvano scanners.

Numerics live in plain modules that never import rclpy (``plant``, ``delay``, ``arx``,
``modal``, ``paper``, ``refine``, ``identify``, ``simulator``, ``pairing``, ``drift``, ...);
the ROS 2 nodes live in :mod:`galvo_sysid.nodes`; the command-line tool in
:mod:`galvo_sysid.cli.main`.

Importing the package changes nothing in the process (no environment variables); the entry
points call :func:`limit_blas_threads` before numpy is imported (``galvo-sysid`` in its main,
the nodes in :mod:`galvo_sysid.nodes`, which their modules import first).
"""

from __future__ import annotations

import os

__all__ = ['BLAS_THREAD_VARIABLES', '__version__', 'limit_blas_threads']

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
