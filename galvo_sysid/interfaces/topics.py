"""Topic names and their message types: one source for the nodes, bags and the tools.

The nodes use the relative names (a namespace per scanner prefixes them, e.g.
``-r __ns:=/scanner_1`` gives ``/scanner_1/galvo/current``), except :data:`DIAGNOSTICS_TOPIC`.
Bags and the command-line tools name topics absolutely: :func:`absolute_topic`, and
:data:`GALVO_TOPICS` (:data:`MOVE_TOPICS`: the moves only) for the scanner without
namespace; :func:`galvo_topic` tells a galvo topic in any namespace. What each node subscribes to
and publishes is :data:`NODE_TOPICS` (the nodes' ``--help``; a test checks it on a live graph).
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Mapping

__all__ = [
    'CURRENT_TOPIC',
    'DIAGNOSTICS_TOPIC',
    'DIAGNOSTIC_ARRAY',
    'DRIFT_STATUS',
    'DRIFT_TOPIC',
    'ENCODER_TOPIC',
    'GALVO_TOPICS',
    'MODAL_PARAMETERS',
    'MOVE_SAMPLES',
    'MOVE_TOPICS',
    'NODE_TOPICS',
    'RESULT_TOPIC',
    'SIGNAL_TOPICS',
    'TOPIC_TYPES',
    'NodeTopics',
    'absolute_topic',
    'galvo_topic',
]

CURRENT_TOPIC = 'galvo/current'
"""Commanded current of each move (``MoveSamples``)."""
ENCODER_TOPIC = 'galvo/encoder'
"""Encoder angle of each move (``MoveSamples``)."""
RESULT_TOPIC = 'galvo/modal_parameters'
"""Each window's identified modal parameters (``ModalParameters``)."""
DRIFT_TOPIC = 'galvo/drift'
"""Each window's drift verdict (``DriftStatus``)."""
DIAGNOSTICS_TOPIC = '/diagnostics'
"""``diagnostic_msgs/DiagnosticArray`` (absolute: one topic for every scanner)."""

MOVE_SAMPLES = 'galvo_sysid_msgs/msg/MoveSamples'
MODAL_PARAMETERS = 'galvo_sysid_msgs/msg/ModalParameters'
DRIFT_STATUS = 'galvo_sysid_msgs/msg/DriftStatus'
"""Message types of the galvo topics (as rosbag2 names them)."""
DIAGNOSTIC_ARRAY = 'diagnostic_msgs/msg/DiagnosticArray'
"""Message type of :data:`DIAGNOSTICS_TOPIC`."""

SIGNAL_TOPICS: Mapping[str, str] = MappingProxyType({'current': CURRENT_TOPIC,
                                                     'encoder': ENCODER_TOPIC})
"""The topic of each half of a move, by signal (``MoveHalf.signal``)."""

TOPIC_TYPES: Mapping[str, str] = MappingProxyType({
    CURRENT_TOPIC: MOVE_SAMPLES, ENCODER_TOPIC: MOVE_SAMPLES, RESULT_TOPIC: MODAL_PARAMETERS,
    DRIFT_TOPIC: DRIFT_STATUS})
"""The message type of each galvo topic."""


def absolute_topic(topic: str, *, namespace: str = '') -> str:
    """The absolute name of a topic in a namespace; an absolute name is returned as it is.

    Example: ``absolute_topic(CURRENT_TOPIC, namespace='scanner_1') ==
    '/scanner_1/galvo/current'``; without namespace ``'/galvo/current'``.
    """
    if topic.startswith('/'):
        return topic
    ns = namespace.strip('/')
    return f'/{ns}/{topic}' if ns else f'/{topic}'


GALVO_TOPICS = (absolute_topic(CURRENT_TOPIC), absolute_topic(ENCODER_TOPIC),
                absolute_topic(RESULT_TOPIC), absolute_topic(DRIFT_TOPIC))
"""The topics the galvo nodes publish, without namespace: ``/galvo/current``,
``/galvo/encoder``, ``/galvo/modal_parameters``, ``/galvo/drift`` (what bags record)."""

MOVE_TOPICS = GALVO_TOPICS[:2]
"""The topics of the moves themselves, without namespace: ``/galvo/current``,
``/galvo/encoder`` (what ``galvo-sysid replay`` publishes unless told otherwise; the other
two are results, computed afresh by the nodes from the moves)."""


def galvo_topic(topic: str) -> str | None:
    """Which galvo topic an absolute name is, in any namespace, or None.

    Example: ``galvo_topic('/scanner_1/galvo/drift') == DRIFT_TOPIC``;
    ``galvo_topic('/galvo/current') == CURRENT_TOPIC``; ``galvo_topic('/rosout') is None``.
    """
    for relative in TOPIC_TYPES:
        if topic.endswith('/' + relative):
            return relative
    return None


@dataclass(frozen=True)
class NodeTopics:
    """The topics of one node: ``(topic, message type)`` pairs, names as the node uses them."""

    subscribes: tuple[tuple[str, str], ...]
    publishes: tuple[tuple[str, str], ...]


NODE_TOPICS: Mapping[str, NodeTopics] = MappingProxyType({
    'galvo_driver': NodeTopics(
        subscribes=(),
        publishes=((CURRENT_TOPIC, MOVE_SAMPLES), (ENCODER_TOPIC, MOVE_SAMPLES))),
    'sysid': NodeTopics(
        subscribes=((CURRENT_TOPIC, MOVE_SAMPLES), (ENCODER_TOPIC, MOVE_SAMPLES)),
        publishes=((RESULT_TOPIC, MODAL_PARAMETERS), (DIAGNOSTICS_TOPIC, DIAGNOSTIC_ARRAY))),
    'watchdog': NodeTopics(
        subscribes=((RESULT_TOPIC, MODAL_PARAMETERS),),
        publishes=((DRIFT_TOPIC, DRIFT_STATUS), (DIAGNOSTICS_TOPIC, DIAGNOSTIC_ARRAY))),
})
"""What each node (by node name) subscribes to and publishes, besides ROS's own topics
(``/rosout``, ``/parameter_events``)."""
