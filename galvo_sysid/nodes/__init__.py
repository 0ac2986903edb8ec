"""The ROS 2 nodes of galvo_sysid: thin rclpy layers over the plain task objects.

- :mod:`~galvo_sysid.nodes.driver_node` (``galvo_driver``): the simulated scanner.
- :mod:`~galvo_sysid.nodes.sysid_node` (``sysid``): online identification per window.
- :mod:`~galvo_sysid.nodes.watchdog_node` (``watchdog``): drift verdicts and diagnostics.

Starting a node limits BLAS to one thread unless the user set the thread count
(:func:`galvo_sysid.limit_blas_threads`): the console scripts import a node module, which
imports this package first, so the call here comes before any node module imports numpy.
Importing :mod:`galvo_sysid.nodes` (or a node module) therefore sets
:data:`galvo_sysid.BLAS_THREAD_VARIABLES` that are not set yet; importing the rest of
galvo_sysid changes nothing in the process.

It also calls :func:`galvo_sysid.keep_freed_memory` (the fits reuse freed memory rather than
fault it in anew; the fit processes are forked and inherit it).

Likewise it calls :func:`galvo_sysid.bounded_dds_memory` before rclpy starts: unless the user
configured Fast DDS, readers free each received buffer (an oversized message no longer keeps
its size in the DDS receive pool).
"""

from galvo_sysid import bounded_dds_memory, keep_freed_memory, limit_blas_threads

limit_blas_threads()  # before the node modules import numpy
keep_freed_memory()
bounded_dds_memory()  # before rclpy creates a participant
