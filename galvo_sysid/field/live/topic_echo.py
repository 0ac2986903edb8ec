"""``echo``: a live topic's messages (or one field of each) printed as YAML or JSON lines."""

from __future__ import annotations

import json
import sys
import time
from typing import Any, TextIO

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.field.live.graph import (
    Stop,
    absolute,
    message_class,
    ros_node,
    say,
    subscription_qos,
    wait_for_publisher,
)
from galvo_sysid.field.live.text import field_path, format_yaml, message_to_dict, select_field

__all__ = ['echo']


def echo(topic: str, *, once: bool = False, as_json: bool = False, field: str | None = None,
         timeout: float | None = None, out: TextIO = sys.stdout,
         log: TextIO = sys.stderr) -> int:
    """Print a live topic's messages (YAML documents, or one JSON object per line).

    The type is found from the graph (waits for the topic to appear); the QoS matches the
    publishers, so a transient-local topic's last message is printed at once.

    Args:
        topic: Topic name (relative names are taken from ``/``).
        once: Exit after the first message.
        as_json: One JSON object per line instead of YAML.
        field: Print only this field of each message (``ros2 topic echo --field``): names
            joined by dots (``header.stamp``), a whole number picks a list's element
            (``natural_frequencies.0``). Checked against the type before subscribing.
        timeout: Give up after this many seconds without any message (exit code 1).
        out: Where messages go.
        log: Where status lines go.

    Returns:
        Process exit code: 0, or 1 on timeout or when a message lacks the list element
        ``field`` names.

    Raises:
        ConfigurationError: The topic's type is not installed, or it has no field ``field``.
    """
    import rclpy

    name = absolute(topic)
    path = field_path(field) if field is not None else None
    start = time.monotonic()
    count = 0
    failed: list[str] = []
    with Stop() as stop, ros_node('galvo_sysid_echo') as node:
        found = wait_for_publisher(node, name, tool='echo', stop=stop, start=start,
                                   timeout=timeout, log=log)
        if found is None:
            return 0 if stop.is_set() else 1
        msgtype, reliable, transient = found
        cls = message_class(msgtype)
        if path is not None:
            try:
                select_field(message_to_dict(cls()), path, known_only=True)
            except ConfigurationError as err:
                msg = f'{msgtype}: {err}'
                raise ConfigurationError(msg) from None

        def callback(message: Any) -> None:
            nonlocal count
            if failed:
                return
            data = message_to_dict(message)
            if path is not None:
                try:
                    data = select_field(data, path)
                except ConfigurationError as err:
                    failed.append(str(err))
                    return
            count += 1
            if as_json:
                out.write(json.dumps(data) + '\n')
            else:
                out.write(format_yaml(data) + '\n---\n')
            out.flush()

        node.create_subscription(cls, name, callback,
                                 subscription_qos(reliable=reliable, transient_local=transient,
                                                   depth=100))
        while not stop.is_set() and not (once and count) and not failed:
            rclpy.spin_once(node, timeout_sec=0.1)
            if count == 0 and timeout is not None and time.monotonic() - start > timeout:
                say(log, f'echo: no message on {name} within {timeout:g} s')
                return 1
    if failed:
        say(log, f'echo: a message on {name} has no {field}: {failed[0]}')
        return 1
    return 0
