"""``param``: a live node's parameters over the standard rcl_interfaces services.

What ``ros2 param list|get|set|dump|describe`` do, for a machine without ros2cli: the node's
``list_parameters``, ``get_parameters``, ``set_parameters`` and ``describe_parameters``
services (every rclpy or rclcpp node offers them; the galvo nodes check each change and
refuse a bad one with a reason, :mod:`galvo_sysid.nodes.framework`). Values are read and
printed by :mod:`~galvo_sysid.field.live.parameter_text`.

Each command first waits (at most ``timeout`` seconds) for the node to be discovered (a fresh
process finds the others in up to a few seconds: there is no ros2 daemon that knows the
graph already), then as long for its parameter services to match; a node not found gives one
line, ``param: node /x not found on the graph within 5 s``, and exit code 1. A request not
answered within 1.5 s is sent again (a fresh client's first request can be lost while the
node has not yet discovered the client's response reader), for at most ``timeout`` seconds.
"""

from __future__ import annotations

import sys
import time
from typing import TYPE_CHECKING, Any, TextIO

from galvo_sysid.field.live.graph import absolute, node_names, ros_node, say
from galvo_sysid.field.live.parameter_text import (
    KINDS,
    parameters_yaml,
    parse_value,
    value_line,
)

if TYPE_CHECKING:
    from rclpy.node import Node

__all__ = ['param_describe', 'param_dump', 'param_get', 'param_list', 'param_set']

_RESEND = 1.5
"""Seconds before a request without answer is sent again."""


class _UnansweredError(Exception):
    """The node did not answer within the timeout (said in one line by the caller)."""


class _Remote:
    """The parameter services of one node, called from a short-lived node of ours."""

    def __init__(self, node: Node, target: str, timeout: float) -> None:
        from rcl_interfaces.srv import (
            DescribeParameters,
            GetParameters,
            ListParameters,
            SetParameters,
        )

        self.node = node
        self.target = target
        self.timeout = timeout
        self.types = {'list': ListParameters, 'get': GetParameters, 'set': SetParameters,
                      'describe': DescribeParameters}
        services = {'list': 'list_parameters', 'get': 'get_parameters',
                    'set': 'set_parameters', 'describe': 'describe_parameters'}
        self.clients = {key: node.create_client(srv, f'{target}/{services[key]}')
                        for key, srv in self.types.items()}

    def find(self, log: TextIO) -> bool:
        """Wait until the node is on the graph, then until its services match (each at
        most ``timeout``); say why not."""  # noqa: D205, D209
        deadline = time.monotonic() + self.timeout
        while self.target not in node_names(self.node):
            if time.monotonic() > deadline:
                say(log, f'param: node {self.target} not found on the graph within '
                         f'{self.timeout:g} s')
                return False
            time.sleep(0.05)
        deadline = time.monotonic() + self.timeout
        while not all(c.service_is_ready() for c in self.clients.values()):
            if time.monotonic() > deadline:
                say(log, f'param: node {self.target} offers no parameter services (none '
                         f'matched within {self.timeout:g} s)')
                return False
            time.sleep(0.05)
        return True

    def call(self, key: str, **fields: Any) -> Any:
        """The node's answer to one request (sent again if unanswered).

        Raises:
            _UnansweredError: No answer before the deadline.
        """
        import rclpy

        client = self.clients[key]
        request = self.types[key].Request(**fields)
        deadline = time.monotonic() + self.timeout
        while True:
            future = client.call_async(request)
            resend = min(deadline, time.monotonic() + _RESEND)
            while not future.done() and time.monotonic() < resend:
                rclpy.spin_once(self.node, timeout_sec=0.05)
            if future.done():
                return future.result()
            future.cancel()
            if time.monotonic() >= deadline:
                raise _UnansweredError(f'param: node {self.target} did not answer '
                                  f'{client.srv_name} within {self.timeout:g} s')

    def names(self) -> list[str]:
        """Every parameter name the node declares, sorted."""
        return sorted(self.call('list', depth=0).result.names)

    def describe(self, names: list[str]) -> dict[str, Any]:
        """The descriptors of ``names`` the node has (an undeclared name: none at all)."""
        if not names:
            return {}
        out = self.call('describe', names=names).descriptors
        return {d.name: d for d in out} if len(out) == len(names) else {}

    def values(self, names: list[str]) -> dict[str, tuple[str, Any]]:
        """``(kind, value)`` of ``names`` (empty if one of them is undeclared)."""
        if not names:
            return {}
        out = self.call('get', names=names).values
        if len(out) != len(names):
            return {}
        return {n: _from_message(v) for n, v in zip(names, out, strict=True)}


def _from_message(value: Any) -> tuple[str, Any]:
    """``(kind, value)`` of an ``rcl_interfaces/msg/ParameterValue``."""
    from rclpy.parameter import parameter_value_to_python

    kind = KINDS[value.type] if 0 <= value.type < len(KINDS) else f'type {value.type}'
    try:
        python = parameter_value_to_python(value)
    except RuntimeError:  # a type code rclpy does not know
        python = None
    if isinstance(python, list):
        python = [int(v) if isinstance(v, bytes) else v for v in python]
    return kind, python


def _to_message(kind: str, value: Any) -> Any:
    """An ``rcl_interfaces/msg/ParameterValue`` of a ``(kind, value)``."""
    from rcl_interfaces.msg import ParameterValue

    field = {'boolean': 'bool_value', 'integer': 'integer_value', 'double': 'double_value',
             'string': 'string_value', 'boolean array': 'bool_array_value',
             'integer array': 'integer_array_value', 'double array': 'double_array_value',
             'string array': 'string_array_value'}[kind]
    message = ParameterValue(type=KINDS.index(kind))
    setattr(message, field, value)
    return message


def _run(target: str, timeout: float, log: TextIO, work: Any) -> int:
    """Find the node, then ``work(remote) -> exit code``; one line for a silent node."""
    name = absolute(target)
    with ros_node('galvo_sysid_param') as node:
        remote = _Remote(node, name, timeout)
        if not remote.find(log):
            return 1
        try:
            return int(work(remote))
        except _UnansweredError as err:
            say(log, str(err))
            return 1


def _no_parameter(remote: _Remote, name: str, log: TextIO) -> int:
    say(log, f'param: node {remote.target} has no parameter {name!r} (galvo-sysid param '
             f'list {remote.target})')
    return 1


def param_list(target: str, *, types: bool = False, prefix: str = '', timeout: float = 5.0,
               out: TextIO = sys.stdout, log: TextIO = sys.stderr) -> int:
    """Print the node's parameter names, one a line, sorted (``ros2 param list NODE``).

    Args:
        target: The node (``/sysid``, ``sysid``, ``/scanner_1/sysid``).
        types: Print each name's kind too: ``name (double)``.
        prefix: Only names starting with this.
        timeout: Wait at most this long [s] for the node and each answer.
        out: Where the names go.
        log: Where a failure is said.

    Returns:
        Exit code: 0, or 1 when the node was not found or did not answer.
    """
    def work(remote: _Remote) -> int:
        names = [n for n in remote.names() if n.startswith(prefix)]
        kinds = {n: KINDS[d.type] if 0 <= d.type < len(KINDS) else str(d.type)
                 for n, d in remote.describe(names).items()} if types else {}
        for n in names:
            out.write(f'{n} ({kinds.get(n, "?")})\n' if types else f'{n}\n')
        out.flush()
        return 0
    return _run(target, timeout, log, work)


def param_get(target: str, name: str, *, hide_type: bool = False, timeout: float = 5.0,
              out: TextIO = sys.stdout, log: TextIO = sys.stderr) -> int:
    """Print one parameter's value (``ros2 param get NODE NAME``): ``Double value is: 2.5``.

    Returns:
        Exit code: 0; 1 when the node has no such parameter, was not found or did not answer.
    """
    def work(remote: _Remote) -> int:
        values = remote.values([name])
        if name not in values:
            return _no_parameter(remote, name, log)
        kind, value = values[name]
        out.write(value_line(kind, value, hide_type=hide_type) + '\n')
        out.flush()
        return 0
    return _run(target, timeout, log, work)


def param_set(target: str, name: str, text: str, *, timeout: float = 5.0,
              out: TextIO = sys.stdout, log: TextIO = sys.stderr) -> int:
    """Set one parameter (``ros2 param set NODE NAME VALUE``); the node accepts or refuses.

    ``text`` is read by :func:`~galvo_sysid.field.live.parameter_text.parse_value`, fitted to
    the kind the node declares (``describe_parameters``).

    Returns:
        Exit code: 0 and ``Set parameter successful`` on ``out``; 1 and ``Set parameter
        failed: <the node's reason>`` on ``log`` when the node refused the value; 1 when the
        node has no such parameter, was not found or did not answer.
    """
    def work(remote: _Remote) -> int:
        described = remote.describe([name]).get(name)
        if described is None and name not in remote.names():
            return _no_parameter(remote, name, log)
        declared = KINDS[described.type] if described is not None and \
            0 <= described.type < len(KINDS) and not described.dynamic_typing else None
        kind, value = parse_value(text, declared=declared)
        from rcl_interfaces.msg import Parameter

        results = remote.call('set', parameters=[Parameter(name=name,
                                                            value=_to_message(kind, value))])
        result = results.results[0] if results.results else None
        if result is not None and result.successful:
            out.write('Set parameter successful' + (f': {result.reason}' if result.reason
                                                    else '') + '\n')
            out.flush()
            return 0
        reason = result.reason if result is not None and result.reason else \
            'no reason given'
        say(log, f'Set parameter failed: {reason}')
        return 1
    return _run(target, timeout, log, work)


def param_describe(target: str, name: str, *, timeout: float = 5.0,
                   out: TextIO = sys.stdout, log: TextIO = sys.stderr) -> int:
    """Print a parameter's descriptor (``ros2 param describe NODE NAME``): kind,
    description, read-only, range.

    Returns:
        Exit code: 0; 1 when the node has no such parameter, was not found or did not answer.
    """  # noqa: D205
    def work(remote: _Remote) -> int:
        d = remote.describe([name]).get(name)
        if d is None:
            return _no_parameter(remote, name, log)
        kind = KINDS[d.type] if 0 <= d.type < len(KINDS) else str(d.type)
        lines = [f'Parameter name: {name}',
                 f'  Type: {"dynamic" if d.dynamic_typing else kind}']
        if d.description:
            lines.append(f'  Description: {d.description}')
        constraints = ['    Read only: true'] if d.read_only else []
        for r in d.integer_range:
            constraints += [f'    Min value: {r.from_value}', f'    Max value: {r.to_value}']
        for r in d.floating_point_range:
            constraints += [f'    Min value: {r.from_value!r}',
                            f'    Max value: {r.to_value!r}']
        if d.additional_constraints:
            constraints.append(f'    {d.additional_constraints}')
        if constraints:
            lines += ['  Constraints:', *constraints]
        out.write('\n'.join(lines) + '\n')
        out.flush()
        return 0
    return _run(target, timeout, log, work)


def param_dump(target: str, *, timeout: float = 5.0, out: TextIO = sys.stdout,
               log: TextIO = sys.stderr) -> int:
    r"""Print every parameter of the node as a ROS 2 parameter file (``ros2 param dump``).

    The output (``/node:\n  ros__parameters: ...``) is what ``--params-file`` takes: it
    starts the same node with the same values (read-only ones included). Parameters without a
    value (an optional number not set) are left out.

    Returns:
        Exit code: 0, or 1 when the node was not found or did not answer.
    """
    def work(remote: _Remote) -> int:
        names = remote.names()
        values = remote.values(names)
        if len(values) != len(names):  # a parameter undeclared between the two requests
            values = remote.values(remote.names())
        kept = {n: v for n, (kind, v) in values.items() if kind != 'not set'}
        out.write(parameters_yaml(remote.target, kept))
        out.flush()
        return 0
    return _run(target, timeout, log, work)
