"""What the three nodes share: QoS profiles, declared parameters, diagnostics, a main loop.

The parameters themselves (names, defaults, ranges) are :mod:`galvo_sysid.monitor.parameters`
and the topic names :mod:`galvo_sysid.interfaces.topics` (both without ROS); this module
declares the parameters with their ROS descriptors (:func:`descriptor`) and checks changes
(:class:`ParameterSet`). :func:`publish_diagnostic` publishes a node's status on
``/diagnostics``, its level a verdict level of :mod:`galvo_sysid.monitor.verdict`.
"""

from __future__ import annotations

import faulthandler
import re
import signal
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
from rcl_interfaces.srv import (
    DescribeParameters,
    GetParameters,
    GetParameterTypes,
    ListParameters,
    SetParameters,
    SetParametersAtomically,
)
from rclpy.exceptions import ParameterException, ParameterUninitializedException
from rclpy.executors import (
    ExternalShutdownException,
    MultiThreadedExecutor,
    SingleThreadedExecutor,
)
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.utilities import ok as rclpy_ok
from rclpy.utilities import try_shutdown

from galvo_sysid.errors import ConfigurationError, GalvoSysidError, InvalidDataError, one_line
from galvo_sysid.monitor.ratelog import RateLimitedLog
from galvo_sysid.monitor.verdict import ERROR, MISMATCH, OK, STALE, WARN

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Sequence

    from rclpy.impl.rcutils_logger import RcutilsLogger
    from rclpy.node import Node
    from rclpy.publisher import Publisher

    from galvo_sysid.monitor.parameters import ParamSpec

__all__ = [
    'DIAGNOSTIC_LEVELS',
    'MAX_REASON',
    'REJECTIONS_PER_SECOND',
    'SPIN_WAKE',
    'ParameterSet',
    'check_ros_arguments',
    'descriptor',
    'diagnostics_qos',
    'guard_parameter_services',
    'logger',
    'moves_qos',
    'publish_diagnostic',
    'publish_while_up',
    'results_qos',
    'run_node',
    'scanner_name',
    'short_reason',
    'spin',
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


def publish_while_up(node: Node, publisher: Publisher, msg: Any) -> bool:
    """Publish ``msg`` unless ROS has shut down (Ctrl-C: the context is gone while a worker
    thread still hands on a result); return whether it was published."""  # noqa: D205, D209
    if not node.context.ok():
        return False
    try:
        publisher.publish(msg)
    except _rclpy.RCLError:
        if node.context.ok():
            raise
        return False  # shut down between the check and the publish
    return True


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
    ends of its range are given, the low end is allowed and 0 has no special meaning).

    A default of None declares an optional number: dynamically typed, not set until given.
    """  # noqa: D205
    text = spec.text
    if spec.default is None:  # optional: dynamically typed, not set until given
        return ParameterDescriptor(description=text + ' (optional number)',
                                   read_only=spec.read_only, dynamic_typing=True)
    d = ParameterDescriptor(description=text, read_only=spec.read_only)
    if spec.low is not None and spec.high is not None and not spec.exclusive_low \
            and not spec.zero_off:
        if isinstance(spec.default, bool):
            pass
        elif isinstance(spec.default, int):
            d.integer_range = [IntegerRange(from_value=int(spec.low), to_value=int(spec.high),
                                            step=1)]
        elif isinstance(spec.default, float):
            d.floating_point_range = [FloatingPointRange(
                from_value=float(spec.low), to_value=float(spec.high), step=0.0)]
    return d


MAX_REASON = 300
"""Longest reason a refused parameter change returns [characters] (one line)."""

REJECTIONS_PER_SECOND = 5
"""Most 'parameter change rejected' log lines a second (the rest summed up)."""


def short_reason(text: str) -> str:
    """``text`` on one line, cut to :data:`MAX_REASON` characters."""
    line = ' '.join(text.split())
    return line if len(line) <= MAX_REASON else f'{line[:MAX_REASON - 3]}...'


def _refused(reason: str) -> SetParametersResult:
    return SetParametersResult(successful=False, reason=short_reason(reason))


def _unexpected(err: BaseException) -> str:
    return f'refused: unexpected {type(err).__name__} ({one_line(err)})'


class ParameterSet:
    """Declare parameters, validate them, and apply accepted changes: the one place every
    parameter a node accepts passes, at start-up and at run time.

    ``validate(values) -> reason | None`` sees the complete would-be parameter values (old
    ones updated by the change) after each value passed its :meth:`ParamSpec.check` (type,
    finite, range, element by element, lengths); ``apply(values, changed)`` is called after
    an accepted change and must either apply all of it or raise
    :class:`~galvo_sysid.errors.GalvoSysidError` having applied nothing (``validate`` should
    have caught it). A refused change, whatever the value or the error behind it, returns
    ``successful=false`` with a one-line reason and leaves the node's values as they were;
    nothing a parameter service request holds can end the node (the node's parameter
    services are guarded, :func:`guard_parameter_services`). Rejections are logged at most
    :data:`REJECTIONS_PER_SECOND` a second.
    """  # noqa: D205

    def __init__(self, node: Node, specs: Sequence[ParamSpec], *,
                 validate: Callable[[dict[str, Any]], str | None] | None = None,
                 apply: Callable[[dict[str, Any], set[str]], None] | None = None) -> None:
        self._node = node
        self.specs: dict[str, ParamSpec] = {}
        self._validate = validate
        self._apply = apply
        self._log = RateLimitedLog(logger(node).warning, per_second=REJECTIONS_PER_SECOND)
        self.values: dict[str, Any] = {}
        self._declare(specs)
        node.add_on_set_parameters_callback(self._on_set)
        guard_parameter_services(node, self._log)

    def extend(self, specs: Sequence[ParamSpec]) -> None:
        """Declare more parameters (e.g. ones that depend on a model read at start-up).

        Raises:
            ConfigurationError: A given value is not acceptable.
        """
        self._declare(specs)

    def _declare(self, specs: Sequence[ParamSpec]) -> None:
        for s in specs:
            try:
                self._node.declare_parameter(s.name, s.default, descriptor(s))
            except ParameterUninitializedException:
                raise ConfigurationError(
                    f'{s.name}: no value given (an empty list has no type)') from None
            self.specs[s.name] = s
            self.values[s.name] = self._node.get_parameter(s.name).value
        reason = self.check(self.values)
        if reason is not None:
            raise ConfigurationError(reason)

    def check(self, values: dict[str, Any]) -> str | None:
        """Why a set of values is not acceptable (one short line), or None.

        Each value passes its spec's check first, then the node's ``validate`` sees them all
        (a :class:`~galvo_sysid.errors.GalvoSysidError` it raises is a reason too).
        """
        for name, spec in self.specs.items():
            reason = spec.check(values[name])
            if reason is not None:
                return short_reason(reason)
        if self._validate is None:
            return None
        try:
            reason = self._validate(values)
        except GalvoSysidError as err:
            reason = str(err)
        return None if reason is None else short_reason(reason)

    def _on_set(self, params: list[Parameter]) -> SetParametersResult:
        try:
            result = self._change(params)
        except Exception as err:  # a parameter change never ends the node
            result = _refused(_unexpected(err))
        if not result.successful:
            self._log(f'parameter change rejected: {result.reason}',
                      key='parameter change rejected')
        return result

    def _change(self, params: list[Parameter]) -> SetParametersResult:
        new = dict(self.values)
        changed: set[str] = set()
        for p in params:
            if p.name not in self.specs:
                if not self._node.has_parameter(p.name):  # rclpy lets the name '' through
                    return _refused(f'no parameter {p.name!r}')
                continue  # ROS's own (use_sim_time, ...)
            if p.type_ == Parameter.Type.NOT_SET:  # rclpy would undeclare it for good
                keep = '' if self.specs[p.name].default is not None else \
                    f' (to go back to the built-in, set {self.specs[p.name].builtin!r})'
                return _refused(f'{p.name} cannot be unset{keep}')
            new[p.name] = p.value
            changed.add(p.name)
        reason = self.check(new)
        if reason is not None:
            return _refused(reason)
        if changed and self._apply is not None:
            try:
                self._apply(new, changed)
            except GalvoSysidError as err:  # validate should have caught it: nothing applied
                return _refused(str(err))
        self.values = new
        return SetParametersResult(successful=True)


_GUARDED = '_galvo_sysid_guarded'


def guard_parameter_services(node: Node, log: Callable[..., None]) -> None:
    """Make the node's parameter services answer every request, never raise.

    rclpy's parameter services raise on some requests (a parameter message of an unknown
    type: ``ValueError``), which would end the node from inside the executor. Each request
    to set parameters is answered per parameter (an error is that parameter's refusal with
    its reason); the other parameter services answer an empty response on an error.
    """
    for srv in node.services:
        if getattr(srv.callback, _GUARDED, False):
            continue
        if srv.srv_type is SetParameters:
            callback: Any = _set_each(srv.callback, log)
        elif srv.srv_type in (SetParametersAtomically, GetParameters, GetParameterTypes,
                              DescribeParameters, ListParameters):
            callback = _answer_always(srv.srv_type, srv.callback, log)
        else:
            continue
        setattr(callback, _GUARDED, True)
        srv.callback = callback


def _set_each(original: Callable[[Any, Any], Any], log: Callable[..., None]
              ) -> Callable[[Any, Any], Any]:
    def set_parameters(request: Any, response: Any) -> Any:
        for p in request.parameters:
            try:
                one = original(SetParameters.Request(parameters=[p]), SetParameters.Response())
                result = one.results[0]
            except Exception as err:  # the request's fault, not the node's
                result = _refused(_unexpected(err))
                log(f'parameter change rejected: {result.reason}',
                    key='parameter change rejected')
            response.results.append(result)
        return response
    return set_parameters


def _answer_always(srv_type: Any, original: Callable[[Any, Any], Any],
                   log: Callable[..., None]) -> Callable[[Any, Any], Any]:
    def answer(request: Any, response: Any) -> Any:
        try:
            return original(request, response)
        except Exception as err:  # the request's fault, not the node's
            log(f'parameter request refused: {_unexpected(err)}', key='parameter request')
            out = srv_type.Response()
            if srv_type is SetParametersAtomically:
                out.result = _refused(_unexpected(err))
            return out
    return answer


def check_ros_arguments(args: Sequence[str]) -> None:
    """Check what rcl would otherwise refuse with a traceback: each ``--params-file`` is a
    readable, safe YAML file (:func:`galvo_sysid.schema.load_yaml`: size cap, no aliases)
    holding a mapping of node names, each ``-p``/``-r`` rule has ``:=``.

    Raises:
        ConfigurationError: A bad argument or parameter file (one line naming it).
    """  # noqa: D205
    from galvo_sysid.schema import load_yaml

    ros = False
    items = list(args)
    for i, arg in enumerate(items):
        if arg == '--ros-args':
            ros = True
            continue
        if arg == '--':
            ros = False
        if not ros:
            continue
        value = items[i + 1] if i + 1 < len(items) else None
        if arg in ('-p', '--param', '-r', '--remap') and (value is None or ':=' not in value):
            raise ConfigurationError(f'{arg} needs NAME:=VALUE, got {value!r}')
        if arg in ('-p', '--param') and value is not None:
            _check_override(value)
        if arg == '--params-file':
            if value is None:
                raise ConfigurationError('--params-file needs a file')
            try:
                doc = load_yaml(value, what='parameter file')
            except InvalidDataError as err:
                raise ConfigurationError(one_line(err)) from None
            except ConfigurationError as err:
                raise ConfigurationError(f'cannot read parameter file {one_line(err)}') from None
            if not isinstance(doc, dict) or not all(
                    isinstance(v, dict) and isinstance(v.get('ros__parameters'), dict)
                    for v in doc.values()):
                raise ConfigurationError(
                    f'parameter file {value}: expected node names, each with ros__parameters')


def _check_override(rule: str) -> None:
    """A ``-p NAME:=VALUE`` value is what rcl takes: a scalar or a list of scalars of one type
    (rcl reads it as YAML; JSON text must be quoted)."""  # noqa: D205, D209
    from galvo_sysid.schema import parse_yaml

    name, _, text = rule.partition(':=')
    try:
        value = parse_yaml(text, source=f'-p {name}')
    except ConfigurationError as err:
        raise ConfigurationError(one_line(err)) from None
    items = value if isinstance(value, list) else [value]
    if isinstance(value, dict) or any(isinstance(v, list | dict) for v in items) or \
            len({type(v) for v in items}) > 1:
        raise ConfigurationError(
            f"-p {name}: a value is a number, text, true/false or a list of one of them; "
            f"quote text that looks like YAML: -p '{name}:=\"...\"'")


STOP_REPORT_AFTER = 8.0
"""Seconds a node's stop (its close, the node's and rclpy's shutdown) may take before it prints
every thread's stack to stderr (a hang in the field, or a test's stop timeout, then says where)."""

SPIN_WAKE = 0.5
"""Longest wait [s] of the node's executor before it looks whether its context was shut down.

rclpy's Ctrl-C / SIGTERM handling wakes the executor and then shuts the context down, from
another thread: an executor that wakes in between finds the context still valid, waits again,
and no one wakes it (seen once in CI: the driver spun on for 10 s after SIGINT until killed).
"""


def spin(node: Node, *, threads: int = 1, wake: float = SPIN_WAKE) -> None:
    """Run the node's callbacks until its context is shut down (Ctrl-C, SIGTERM).

    Like ``rclpy.spin``, but no wait lasts longer than ``wake`` seconds (see
    :data:`SPIN_WAKE`), so a shutdown whose wake-up was lost still ends the spin. The bound
    is one timer of the node's own, not ``spin_once``'s timeout, which makes a new rcl timer
    for every wait.
    """
    executor = (MultiThreadedExecutor(num_threads=threads, context=node.context) if threads > 1
                else SingleThreadedExecutor(context=node.context))
    timer = node.create_timer(wake, _wake_up)
    try:
        executor.add_node(node)
        while node.context.ok():
            executor.spin_once()
    except ExternalShutdownException:  # the context went down during a wait: the same end
        pass
    finally:
        executor.shutdown(timeout_sec=wake)
        node.destroy_timer(timer)


def _wake_up() -> None:
    """The callback of :func:`spin`'s timer: its only job is to end the executor's wait."""


def run_node(factory: Callable[[], Node], *, args: Sequence[str] | None = None,
             threads: int = 1) -> int:
    """Create the node and spin it until Ctrl-C / SIGTERM; return an exit code.

    A configuration error (a parameter file that cannot be read or parsed, a bad ROS
    argument, an out-of-range value) is printed as one line and gives exit code 2; Ctrl-C
    gives 0 without a traceback. A node that seems hung says where it is: ``kill -USR1 <pid>``
    prints every thread's stack to stderr, and so does a stop that takes over
    :data:`STOP_REPORT_AFTER`.
    """
    try:
        if args is not None:
            check_ros_arguments(args)
        rclpy.init(args=None if args is None else list(args))
    except (ConfigurationError, _rclpy.RCLError, _rclpy.UnknownROSArgsError) as err:
        text = one_line(err)
        if isinstance(err, _rclpy.UnknownROSArgsError):
            text = f'unknown ROS arguments {text}'
            if "'--help'" in text or "'-h'" in text:
                text += ' (the usage: --help before --ros-args)'
        text = re.sub(r', at /\S+:\d+', '', text).removeprefix('failed to initialize rcl: ')
        print(f'error: {text}', file=sys.stderr)
        return 2
    if hasattr(signal, 'SIGUSR1'):  # kill -USR1 <pid>: every thread's stack on stderr
        faulthandler.register(signal.SIGUSR1, all_threads=True)
    node: Node | None = None
    code = 0
    try:
        node = factory()
        spin(node, threads=threads)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except _rclpy.RCLError:
        # Ctrl-C / SIGTERM shut the context down, but the KeyboardInterrupt fell into a
        # finaliser (Python ignores it there) and the spin went on to fail on the dead
        # context: a stop all the same. On a live context it is an error.
        if rclpy_ok():
            raise
    except (GalvoSysidError, ParameterException) as err:
        print(f'error: {one_line(err)}', file=sys.stderr)
        code = 2
    finally:
        # A stop that hangs says where (every thread's stack on stderr), then goes on waiting.
        faulthandler.dump_traceback_later(STOP_REPORT_AFTER, exit=False)
        try:
            if node is not None:
                close = getattr(node, 'close', None)
                if callable(close):
                    close()
                node.destroy_node()
            try_shutdown()
        finally:
            faulthandler.cancel_dump_traceback_later()
    return code
