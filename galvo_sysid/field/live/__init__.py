"""Live ROS 2 tools behind ``galvo-sysid record``, ``replay`` and ``echo`` (rclpy).

They stand in for ``ros2 bag record``, ``ros2 bag play`` and ``ros2 topic echo`` where
ros2cli/rosbag2 are not installed (a pip-only machine); the bags are standard rosbag2.

- :func:`record` (:mod:`~galvo_sysid.field.live.recorder`) subscribes *raw* (serialized
  bytes, exactly as published) to topics of the live graph, with the message type and QoS
  taken from the publishers, and stores them with their definitions
  (:class:`~galvo_sysid.field.bags.BagWriter`); log time = receive time.
- :func:`replay` (:mod:`~galvo_sysid.field.live.player`) publishes a bag's serialized
  messages with their recorded timing scaled by a rate, after waiting for subscribers,
  optionally with ``/clock`` for ``use_sim_time``.
- :func:`echo` (:mod:`~galvo_sysid.field.live.topic_echo`) prints a live topic's messages
  as YAML (or JSON lines, :mod:`~galvo_sysid.field.live.text`), type found from the graph.

What they share (the node, QoS matching the publishers, message classes, Ctrl-C) is in
:mod:`~galvo_sysid.field.live.graph`. Each returns a process exit code and stops cleanly on
SIGINT/SIGTERM (Ctrl-C). rclpy is imported only when a tool runs.
"""

from galvo_sysid.field.live.graph import message_class
from galvo_sysid.field.live.player import replay
from galvo_sysid.field.live.recorder import HIDDEN_TOPICS, RecordSummary, record
from galvo_sysid.field.live.text import format_yaml, message_to_dict
from galvo_sysid.field.live.topic_echo import echo

__all__ = [
    'HIDDEN_TOPICS',
    'RecordSummary',
    'echo',
    'format_yaml',
    'message_class',
    'message_to_dict',
    'record',
    'replay',
]
