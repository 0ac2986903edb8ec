"""The ROS 2 nodes of galvo_sysid: thin rclpy layers over the plain task objects.

- :mod:`~galvo_sysid.nodes.driver_node` (``galvo_driver``): the simulated scanner.
- :mod:`~galvo_sysid.nodes.sysid_node` (``sysid``): online identification per window.
- :mod:`~galvo_sysid.nodes.watchdog_node` (``watchdog``): drift verdicts and diagnostics.
"""
