"""``topic list``: the topics of the live graph and their types, the galvo topics first."""

from __future__ import annotations

import sys
import time
from typing import TYPE_CHECKING, TextIO

from galvo_sysid.field.live.graph import Stop, ros_node
from galvo_sysid.interfaces.topics import TOPIC_TYPES, galvo_topic

if TYPE_CHECKING:
    from collections.abc import Iterable

__all__ = ['topic_list']

_ORDER = list(TOPIC_TYPES)  # current, encoder, modal_parameters, drift


def _sorted(topics: Iterable[str]) -> list[str]:
    """Galvo topics first (by namespace, then current, encoder, results, drift), then the
    others by name."""  # noqa: D205, D209
    def key(topic: str) -> tuple[int, str, int, str]:
        relative = galvo_topic(topic)
        if relative is None:
            return 1, '', 0, topic
        return 0, topic[:-len(relative)], _ORDER.index(relative), topic
    return sorted(topics, key=key)


def _plural(n: int, word: str) -> str:
    return f'{n} {word}' + ('' if n == 1 else 's')


def topic_list(*, spin_time: float = 4.0, types: bool = False, verbose: bool = False,
               galvo_only: bool = False, out: TextIO = sys.stdout) -> int:
    """Print the topics of the live graph (``ros2 topic list``), the galvo topics first.

    Topics whose only endpoints are this tool's own node (``/rosout``, ``/parameter_events``
    on an otherwise empty graph) are left out.

    Args:
        spin_time: Seconds to let discovery find the graph (Ctrl-C ends it early); there is
            no ros2 daemon that would already know it.
        types: Print each topic's type: ``/galvo/drift [galvo_sysid_msgs/msg/DriftStatus]``.
        verbose: Types and the number of publishers and subscribers of each topic.
        galvo_only: Only the galvo topics (current, encoder, modal parameters, drift:
            :func:`~galvo_sysid.interfaces.topics.galvo_topic`), in any namespace.
        out: Where the lines go.

    Returns:
        Exit code: 0 (also when no topic was found: nothing is printed).
    """
    with Stop() as stop, ros_node('galvo_sysid_topic') as node:
        end = time.monotonic() + spin_time
        while not stop.is_set() and time.monotonic() < end:
            time.sleep(min(0.05, max(0.0, end - time.monotonic())))
        found = dict(node.get_topic_names_and_types())
        ours = (node.get_name(), node.get_namespace())
        counts: dict[str, tuple[int, int]] = {}
        for topic in found:
            counts[topic] = (
                sum((i.node_name, i.node_namespace) != ours
                    for i in node.get_publishers_info_by_topic(topic)),
                sum((i.node_name, i.node_namespace) != ours
                    for i in node.get_subscriptions_info_by_topic(topic)))
    lines = []
    for topic in _sorted(found):
        pubs, subs = counts[topic]
        if pubs + subs == 0 or (galvo_only and galvo_topic(topic) is None):
            continue
        line = topic
        if types or verbose:
            line += f' [{", ".join(found[topic])}]'
        if verbose:
            line += f' {_plural(pubs, "publisher")}, {_plural(subs, "subscriber")}'
        lines.append(line)
    out.write(''.join(line + '\n' for line in lines))
    out.flush()
    return 0
