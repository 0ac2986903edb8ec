"""The simulated driver's stop: no move is published once ``close()`` has returned.

In one CI run ``galvo_driver`` ended with SIGSEGV when stopped: its publishing thread, still
simulating a move when ``close()`` gave up waiting for it, went on to publish on the
publishers the node's destruction frees. The node runs in its own context here, without
spinning (its thread publishes by itself).
"""

from __future__ import annotations

import threading
from typing import Any

import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter


def test_a_driver_closed_while_it_simulates_a_move_publishes_nothing_after() -> None:
    from galvo_sysid.nodes.driver_node import DriverNode

    context = Context()
    rclpy.init(context=context)
    node = DriverNode(context=context, namespace='/driver_close', parameter_overrides=[
        Parameter('wait_for_subscribers', value=1), Parameter('wait_timeout', value=0.5)])
    try:
        entered, release = threading.Event(), threading.Event()
        moves = node.sim.moves

        def slow(**kwargs: Any) -> Any:  # the simulation of the first moves takes a while
            entered.set()
            release.wait(20)
            yield from moves(**kwargs)

        node.sim.moves = slow  # before the thread's half-second wait for subscribers ends
        assert entered.wait(10), 'the driver never started simulating'
        node.close()  # gives up waiting for the thread after 5 s: it is still simulating
        published: list[Any] = []
        for pub in (node.current, node.encoder):
            pub.publish = published.append  # type: ignore[method-assign]
        release.set()
        node._thread.join(10)
        assert not node._thread.is_alive()
        assert published == []
        assert node.published == 0
    finally:
        release.set()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
