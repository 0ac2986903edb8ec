"""Topic names and message conversions, between ROS messages and plain values.

- :mod:`~galvo_sysid.interfaces.topics`: the topic names and their message types;
- :mod:`~galvo_sysid.interfaces.messages`: conversions between ``galvo_sysid_msgs`` messages
  and the plain values of the numerics (no rclpy: duck typing).
"""
