"""``echo``: a live topic's messages printed as YAML or JSON lines."""

from __future__ import annotations

import json
import sys
import time
from typing import Any, TextIO

from galvo_sysid.field.live.graph import (
    Stop,
    absolute,
    message_class,
    publisher_qos,
    ros_node,
    say,
    subscription_qos,
)
from galvo_sysid.field.live.text import format_yaml, message_to_dict

__all__ = ['echo']


def echo(topic: str, *, once: bool = False, as_json: bool = False,
         timeout: float | None = None, out: TextIO = sys.stdout,
         log: TextIO = sys.stderr) -> int:
    """Print a live topic's messages (YAML documents, or one JSON object per line).

    The type is found from the graph (waits for the topic to appear); the QoS matches the
    publishers, so a transient-local topic's last message is printed at once.

    Args:
        topic: Topic name (relative names are taken from ``/``).
        once: Exit after the first message.
        as_json: One JSON object per line instead of YAML.
        timeout: Give up after this many seconds without any message (exit code 1).
        out: Where messages go.
        log: Where status lines go.

    Returns:
        Process exit code: 0, or 1 on timeout.

    Raises:
        ConfigurationError: The topic's type is not installed.
    """
    import rclpy

    name = absolute(topic)
    start = time.monotonic()
    count = 0
    with Stop() as stop, ros_node('galvo_sysid_echo') as node:
        msgtype = None
        offered = None
        said: set[str] = set()  # the waiting lines said (each once)
        while not stop.is_set():
            types = dict(node.get_topic_names_and_types()).get(name)
            offered = publisher_qos(node, name) if types else None
            if types and offered is not None:  # a publisher, not only other subscribers
                msgtype = types[0]
                break
            elapsed = time.monotonic() - start
            if timeout is not None and elapsed > timeout:
                say(log, f'echo: topic {name} did not appear within {timeout:g} s')
                return 1
            if types and 'subscribers' not in said:
                say(log, f'echo: waiting for a publisher on {name} (it has subscribers only)...')
                said.add('subscribers')
            elif not said and elapsed > 1.0:
                say(log, f'echo: waiting for a publisher on {name}...')
                said.add('publisher')
            time.sleep(0.1)
        if msgtype is None or offered is None:
            return 0
        reliable, transient = offered

        def callback(message: Any) -> None:
            nonlocal count
            count += 1
            data = message_to_dict(message)
            if as_json:
                out.write(json.dumps(data) + '\n')
            else:
                out.write(format_yaml(data) + '\n---\n')
            out.flush()

        node.create_subscription(message_class(msgtype), name, callback,
                                 subscription_qos(reliable=reliable, transient_local=transient,
                                                   depth=100))
        while not stop.is_set() and not (once and count):
            rclpy.spin_once(node, timeout_sec=0.1)
            if count == 0 and timeout is not None and time.monotonic() - start > timeout:
                say(log, f'echo: no message on {name} within {timeout:g} s')
                return 1
    return 0
