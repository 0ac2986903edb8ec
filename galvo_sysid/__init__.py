"""galvo_sysid: online system identification and drift monitoring of galvano scanners.

Numerics live in plain modules (no rclpy): :mod:`galvo_sysid.plant`, ... ; the ROS 2 nodes
live in :mod:`galvo_sysid.nodes`; the command-line tool in :mod:`galvo_sysid.cli`.
"""

__version__ = '0.1.0'
