"""BatchReceiver over real DDS: many messages per wake-up, the inputs taken in turn."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from ros_graph import MOVES_QOS
from std_msgs.msg import String

from galvo_sysid.nodes.receiving import BatchReceiver

if TYPE_CHECKING:
    from ros_graph import Graph

MESSAGES = 60  # per topic


def _burst(graph: Graph, receiver: BatchReceiver) -> list[tuple[str, int]]:
    """Publish MESSAGES on each of two topics in turn, let them all wait, then spin."""
    node = graph.node
    seen: list[tuple[str, int]] = []
    pubs = {}
    for name in ('a', 'b'):
        topic = f'batch_{name}'
        receiver.subscribe(node, String, topic,
                           lambda msg, name=name: seen.append((name, int(msg.data))), MOVES_QOS)
        pubs[name] = node.create_publisher(String, topic, MOVES_QOS)
    graph.spin_until(lambda: all(p.get_subscription_count() for p in pubs.values()), 10,
                     'the subscriptions')
    for i in range(MESSAGES):
        for pub in pubs.values():
            pub.publish(String(data=str(i)))
    time.sleep(0.5)  # every message waits in its queue before the first is taken
    graph.spin_until(lambda: len(seen) == 2 * MESSAGES, 10, 'every message')
    return seen


def test_waiting_messages_are_taken_in_batches_one_input_after_the_other(graph: Graph) -> None:
    receiver = BatchReceiver()
    seen = _burst(graph, receiver)
    for name in ('a', 'b'):  # each input in its order, none lost or repeated
        assert [i for n, i in seen if n == name] == list(range(MESSAGES))
    # in turn: neither input more than one message ahead of the other
    lead = [sum(1 if n == 'a' else -1 for n, _ in seen[: k + 1]) for k in range(len(seen))]
    assert max(abs(x) for x in lead) <= 1
    assert receiver.taken == 2 * MESSAGES
    assert receiver.wakeups <= 2  # the executor woke once (twice if a wait raced the burst)


def test_a_wake_up_takes_at_most_its_limit(graph: Graph) -> None:
    receiver = BatchReceiver(gather=0.0, limit=5)
    seen = _burst(graph, receiver)
    assert sorted(seen) == sorted((n, i) for n in 'ab' for i in range(MESSAGES))
    assert receiver.wakeups >= 2 * MESSAGES // 6  # 1 + 5 per wake-up at most
    lead = [sum(1 if n == 'a' else -1 for n, _ in seen[: k + 1]) for k in range(len(seen))]
    assert max(abs(x) for x in lead) <= 2  # the executor's own takes come in turn too
