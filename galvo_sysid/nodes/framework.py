"""What the three nodes share: QoS profiles, declared parameters, diagnostics, a main loop.

The parameters themselves (names, defaults, ranges) are :mod:`galvo_sysid.monitor.parameters`
and the topic names :mod:`galvo_sysid.interfaces.topics` (both without ROS); this module
declares the parameters with their ROS descriptors (:func:`descriptor`) and checks changes
(:class:`ParameterSet`). :func:`publish_diagnostic` publishes a node's status on
``/diagnostics``, its level a verdict level of :mod:`galvo_sysid.monitor.verdict`.
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.utilities import try_shutdown

from galvo_sysid.errors import ConfigurationError, GalvoSysidError, one_line
from galvo_sysid.monitor.verdict import ERROR, MISMATCH, OK, STALE, WARN

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Sequence

    from rclpy.impl.rcutils_logger import RcutilsLogger
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.publisher import Publisher

    from galvo_sysid.monitor.parameters import ParamSpec

__all__ = [
    'DIAGNOSTIC_LEVELS',
    'ParameterSet',
    'descriptor',
    'diagnostics_qos',
    'logger',
    'moves_qos',
    'publish_diagnostic',
    'results_qos',
    'run_node',
    'scanner_name',
]


def moves_qos(depth: int, *, reliability: str = 'reliable') -> QoSProfile:
    """Volatile; ``depth`` messages kept (0: keep all); reliable or best effort.

    A best-effort subscription also takes a reliable publisher's messages (lost ones are not
    resent: for a lossy link); a best-effort publisher only reaches best-effort subscribers.
    """
    policy = ReliabilityPolicy.BEST_EFFORT if reliability == 'best_effort' \
        else ReliabilityPolicy.RELIABLE
    if depth <= 0:
        return QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=policy,
                          durability=DurabilityPolicy.VOLATILE)
    return QoSProfile(depth=depth, reliability=policy, durability=DurabilityPolicy.VOLATILE)


def results_qos(depth: int = 10) -> QoSProfile:
    """Reliable, transient local: a late subscriber gets the last ``depth`` results."""
    return QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def diagnostics_qos() -> QoSProfile:
    """What diagnostic_aggregator and rqt_robot_monitor expect: reliable, volatile, depth 10."""
    return QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


DIAGNOSTIC_LEVELS = {OK: DiagnosticStatus.OK, WARN: DiagnosticStatus.WARN,
                     ERROR: DiagnosticStatus.ERROR, STALE: DiagnosticStatus.STALE,
                     MISMATCH: DiagnosticStatus.ERROR}
"""The diagnostic level of each verdict level (data not matching the model is an ERROR)."""


def publish_diagnostic(node: Node, publisher: Publisher, *, name: str, hardware_id: str,
                       level: int, message: str, values: Iterable[tuple[str, str]]) -> None:
    """Publish one status on ``/diagnostics`` (a ``DiagnosticArray`` stamped now).

    Args:
        node: The publishing node (its clock stamps the array).
        publisher: Its ``DiagnosticArray`` publisher.
        name: The status name, e.g. ``'scanner_1: plant drift'``.
        hardware_id: The scanner's name.
        level: A verdict level (:data:`DIAGNOSTIC_LEVELS` gives the diagnostic one).
        message: The status message.
        values: ``(key, value)`` pairs shown with the status.
    """
    status = DiagnosticStatus()
    status.level = DIAGNOSTIC_LEVELS[level]
    status.name = name
    status.hardware_id = hardware_id
    status.message = message
    status.values = [KeyValue(key=k, value=v) for k, v in values]
    array = DiagnosticArray()
    array.header.stamp = node.get_clock().now().to_msg()
    array.status = [status]
    publisher.publish(array)


def logger(node: Node) -> RcutilsLogger:
    """The node's logger (typed; rclpy leaves Node.get_logger unannotated)."""
    log: RcutilsLogger = node.get_logger()
    return log


def scanner_name(node: Node, given: str = '') -> str:
    """The scanner's name: ``given``, else the node's namespace without slashes, else 'galvo'."""
    if given:
        return given
    ns = node.get_namespace().strip('/').replace('/', '_')
    return ns or 'galvo'


def descriptor(spec: ParamSpec) -> ParameterDescriptor:
    """The ROS descriptor of a parameter (with IntegerRange / FloatingPointRange when both
    ends of its range are given and the low end is allowed).

    A default of None declares an optional number: dynamically typed, not set until given.
    """  # noqa: D205
    text = spec.text
    if spec.default is None:  # optional: dynamically typed, not set until given
        return ParameterDescriptor(description=text + ' (optional number)',
                                   read_only=spec.read_only, dynamic_typing=True)
    d = ParameterDescriptor(description=text, read_only=spec.read_only)
    if spec.low is not None and spec.high is not None and not spec.exclusive_low:
        if isinstance(spec.default, bool):
            pass
        elif isinstance(spec.default, int):
            d.integer_range = [IntegerRange(from_value=int(spec.low), to_value=int(spec.high),
                                            step=1)]
        elif isinstance(spec.default, float):
            d.floating_point_range = [FloatingPointRange(
                from_value=float(spec.low), to_value=float(spec.high), step=0.0)]
    return d


class ParameterSet:
    """Declare parameters, validate them, and apply accepted changes.

    ``validate(values) -> reason | None`` sees the complete would-be parameter values (old
    ones updated by the change); ``apply(values, changed)`` is called after an accepted
    change. A rejected change leaves the node's values as they were.
    """

    def __init__(self, node: Node, specs: Sequence[ParamSpec], *,
                 validate: Callable[[dict[str, Any]], str | None] | None = None,
                 apply: Callable[[dict[str, Any], set[str]], None] | None = None) -> None:
        self._node = node
        self.specs = {s.name: s for s in specs}
        self._validate = validate
        self._apply = apply
        for s in specs:
            node.declare_parameter(s.name, s.default, descriptor(s))
        self.values: dict[str, Any] = {
            s.name: node.get_parameter(s.name).value for s in specs}
        reason = self.check(self.values)
        if reason is not None:
            raise ConfigurationError(reason)
        node.add_on_set_parameters_callback(self._on_set)

    def extend(self, specs: Sequence[ParamSpec]) -> None:
        """Declare more parameters (e.g. ones that depend on a model read at start-up).

        Raises:
            ConfigurationError: A given value is not acceptable.
        """
        for s in specs:
            self._node.declare_parameter(s.name, s.default, descriptor(s))
            self.specs[s.name] = s
            self.values[s.name] = self._node.get_parameter(s.name).value
        reason = self.check(self.values)
        if reason is not None:
            raise ConfigurationError(reason)

    def check(self, values: dict[str, Any]) -> str | None:
        """Why a set of values is not acceptable, or None."""
        for name, spec in self.specs.items():
            reason = spec.check(values[name])
            if reason is not None:
                return reason
        return self._validate(values) if self._validate else None

    def _on_set(self, params: list[Parameter]) -> SetParametersResult:
        new = dict(self.values)
        changed: set[str] = set()
        for p in params:
            if p.name in self.specs:
                new[p.name] = p.value
                changed.add(p.name)
        reason = self.check(new)
        if reason is not None:
            logger(self._node).warning(f'parameter change rejected: {reason}')
            return SetParametersResult(successful=False, reason=reason)
        self.values = new
        if changed and self._apply is not None:
            try:
                self._apply(new, changed)
            except ConfigurationError as err:  # pragma: no cover - validate should catch it
                return SetParametersResult(successful=False, reason=str(err))
        return SetParametersResult(successful=True)


def run_node(factory: Callable[[], Node], *, args: Sequence[str] | None = None,
             threads: int = 1) -> int:
    """Create the node and spin it until Ctrl-C / SIGTERM; return an exit code.

    A configuration error (e.g. a parameter file with an out-of-range value) is printed as
    one line and gives exit code 2; Ctrl-C gives 0 without a traceback.
    """
    rclpy.init(args=None if args is None else list(args))
    node: Node | None = None
    code = 0
    try:
        node = factory()
        executor = MultiThreadedExecutor(num_threads=threads) if threads > 1 else None
        if executor is None:
            rclpy.spin(node)
        else:
            executor.add_node(node)
            executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (GalvoSysidError, ParameterException) as err:
        print(f'error: {one_line(err)}', file=sys.stderr)
        code = 2
    finally:
        if node is not None:
            close = getattr(node, 'close', None)
            if callable(close):
                close()
            node.destroy_node()
        try_shutdown()
    return code
