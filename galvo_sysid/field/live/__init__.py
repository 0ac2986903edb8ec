"""Live ROS 2 tools behind ``galvo-sysid record|replay|echo|topic|param`` (rclpy).

They stand in for ``ros2 bag record``, ``ros2 bag play``, ``ros2 topic echo|list|hz`` and
``ros2 param`` where ros2cli/rosbag2 are not installed (a pip-only machine); the bags are
standard rosbag2.

- :func:`record` (:mod:`~galvo_sysid.field.live.recorder`) subscribes *raw* (serialized
  bytes, exactly as published) to topics of the live graph, with the message type and QoS
  taken from the publishers, and stores them with their definitions
  (:class:`~galvo_sysid.field.bags.BagWriter`); log time = receive time.
- :func:`replay` (:mod:`~galvo_sysid.field.live.player`) publishes a bag's serialized
  messages with their recorded timing scaled by a rate, after waiting for subscribers,
  optionally with ``/clock`` for ``use_sim_time``.
- :func:`echo` (:mod:`~galvo_sysid.field.live.topic_echo`) prints a live topic's messages
  as YAML (or JSON lines, :mod:`~galvo_sysid.field.live.text`), type found from the graph.
- :func:`param_list`, :func:`param_get`, :func:`param_set`, :func:`param_describe`,
  :func:`param_dump` (:mod:`~galvo_sysid.field.live.parameters`) call a node's standard
  parameter services; values read and printed by
  :mod:`~galvo_sysid.field.live.parameter_text` (no rclpy).
- :func:`topic_list` (:mod:`~galvo_sysid.field.live.topic_list`) prints the graph's topics,
  the galvo ones first; :func:`topic_hz` (:mod:`~galvo_sysid.field.live.topic_hz`) a
  topic's rate.

What they share (the node, QoS matching the publishers, message classes, Ctrl-C) is in
:mod:`~galvo_sysid.field.live.graph`. Each returns a process exit code and stops cleanly on
SIGINT/SIGTERM (Ctrl-C; the ``param`` calls, short, are interrupted by it: the command
line's exit code 130). rclpy is imported only when a tool runs.
"""

from galvo_sysid.field.live.graph import message_class
from galvo_sysid.field.live.parameters import (
    param_describe,
    param_dump,
    param_get,
    param_list,
    param_set,
)
from galvo_sysid.field.live.player import replay
from galvo_sysid.field.live.recorder import HIDDEN_TOPICS, RecordSummary, record
from galvo_sysid.field.live.text import format_yaml, message_to_dict
from galvo_sysid.field.live.topic_echo import echo
from galvo_sysid.field.live.topic_hz import topic_hz
from galvo_sysid.field.live.topic_list import topic_list

__all__ = [
    'HIDDEN_TOPICS',
    'RecordSummary',
    'echo',
    'format_yaml',
    'message_class',
    'message_to_dict',
    'param_describe',
    'param_dump',
    'param_get',
    'param_list',
    'param_set',
    'record',
    'replay',
    'topic_hz',
    'topic_list',
]
