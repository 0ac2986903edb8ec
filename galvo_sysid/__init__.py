"""galvo_sysid: online system identification and drift monitoring of galvano scanners.

Numerics live in plain modules that never import rclpy (``plant``, ``delay``, ``arx``,
``modal``, ``paper``, ``refine``, ``identify``, ``simulator``, ``pairing``, ``drift``, ...);
the ROS 2 nodes live in :mod:`galvo_sysid.nodes`; the command-line tool in
:mod:`galvo_sysid.cli.main`.
"""

import os

# The fits are many small dense problems; a multi-threaded BLAS makes them 2-8x slower on a
# 2-core machine and competes with the ROS executor threads. Users may still override this
# by setting the variable before starting Python.
for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')

__version__ = '0.1.0'
