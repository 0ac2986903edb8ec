"""``watchdog``: is the identified plant drifting from its reference model?

Subscribes to ``galvo/modal_parameters`` and judges each window with
:class:`galvo_sysid.monitor.drift.DriftMonitor` (reference model and tolerances from parameters;
default Table I): publishes a ``DriftStatus`` per window on ``galvo/drift`` and, at
``publish_rate``, a ``diagnostic_msgs/DiagnosticArray`` on ``/diagnostics`` (hardware_id =
the scanner's name, one key/value per parameter's deviation). With no result for
``stale_timeout`` seconds the state is STALE (also published once on ``galvo/drift``); it
recovers with the next result.

Run: ``watchdog --ros-args --params-file config/watchdog.yaml [-r __ns:=/scanner_1]``.
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from galvo_sysid_msgs.msg import DriftStatus, ModalParameters
from rclpy.node import Node

from galvo_sysid.errors import ConfigurationError, GalvoSysidError
from galvo_sysid.interfaces.messages import (
    diagnostic_values,
    drift_status_fields,
    fill,
    fill_header,
    result_from_msg,
    stamp_to_seconds,
)
from galvo_sysid.model import REFERENCE_MODEL
from galvo_sysid.monitor.drift import (
    DEFAULT_TOLERANCES,
    ERROR,
    OK,
    STALE,
    WARN,
    DriftVerdict,
    monitor_from_parameters,
    parameter_names,
    reference_from_parameters,
)
from galvo_sysid.monitor.online import WatchdogTask
from galvo_sysid.nodes.framework import (
    DIAGNOSTICS_TOPIC,
    DRIFT_TOPIC,
    RESULT_TOPIC,
    ParameterSet,
    ParamSpec,
    diagnostics_qos,
    logger,
    results_qos,
    run_node,
    scanner_name,
)

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = ['PARAMETERS', 'WatchdogNode', 'main']

_NAMES = parameter_names(REFERENCE_MODEL.n_modes)
_LEVEL_BYTES = {OK: DiagnosticStatus.OK, WARN: DiagnosticStatus.WARN,
                ERROR: DiagnosticStatus.ERROR, STALE: DiagnosticStatus.STALE}

PARAMETERS = (
    ParamSpec('reference.k0', REFERENCE_MODEL.k0, 'reference rigid-body gain k0', -1e12, 1e12),
    ParamSpec('reference.residues', list(REFERENCE_MODEL.residues),
              'reference residues k_i (ascending frequency)', -1e12, 1e12),
    ParamSpec('reference.natural_frequencies', list(REFERENCE_MODEL.natural_frequencies),
              'reference natural frequencies omega_i [rad/s]', 0.0, 1e9, exclusive_low=True),
    ParamSpec('reference.damping_ratios', list(REFERENCE_MODEL.damping_ratios),
              'reference damping ratios zeta_i', 0.0, 10.0, exclusive_low=True),
    *(ParamSpec(f'tolerances.{n}', DEFAULT_TOLERANCES[n],
                f'relative tolerance of {n} (0.01 = 1 %)', 0.0, 1e6, exclusive_low=True)
      for n in _NAMES),
    ParamSpec('warn_fraction', 0.5, 'a significant deviation past this fraction of its '
              'tolerance warns', 0.0, 1.0),
    ParamSpec('n_sigma', 3.0, 'deviations within this many standard deviations are noise',
              0.0, 100.0),
    ParamSpec('trend_windows', 8, 'windows in the drift trend test (0: off)', 0, 1000),
    ParamSpec('trend_min_windows', 3, 'fewest windows before the trend test speaks', 3, 1000),
    ParamSpec('trend_sigma', 4.0, 'trend slope significance needed [standard errors]',
              0.0, 100.0),
    ParamSpec('trend_fraction', 0.3, 'a trend is flagged once past this fraction of the '
              'tolerance', 0.0, 1.0),
    ParamSpec('step_fraction', 0.5, 'a jump between windows past this fraction of the '
              'tolerance restarts the trend history', 0.0, 1e6),
    ParamSpec('min_fit_percent', 75.0, 'windows fitting worse than this warn [%]', -1e9, 100.0),
    ParamSpec('stale_timeout', 5.0, 'STALE after this long without a result [s]',
              0.0, 1e6, exclusive_low=True),
    ParamSpec('publish_rate', 1.0, 'diagnostics per second', 0.0, 1000.0, exclusive_low=True,
              read_only=True),
    ParamSpec('hardware_id', '', "the scanner's name in diagnostics (default: the namespace)"),
)


def _validate(values: dict[str, Any]) -> str | None:
    try:
        model = reference_from_parameters(values)
    except ConfigurationError as err:
        return f'reference model: {err}'
    if model.n_modes != REFERENCE_MODEL.n_modes:
        return (f'the reference must have {REFERENCE_MODEL.n_modes} resonant modes like the '
                f'identification, got {model.n_modes}')
    try:
        monitor_from_parameters(values)
    except ConfigurationError as err:
        return str(err)
    return None


class WatchdogNode(Node):
    """The watchdog node (see the module docs)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('watchdog', **kwargs)
        self.log = logger(self)
        self.params = ParameterSet(self, PARAMETERS, validate=_validate, apply=self._apply)
        v = self.params.values
        self.task = WatchdogTask(monitor_from_parameters(v), stale_timeout=v['stale_timeout'])
        self.scanner = scanner_name(self, v['hardware_id'])
        self.drift = self.create_publisher(DriftStatus, DRIFT_TOPIC, results_qos())
        self.diagnostics = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC,
                                                 diagnostics_qos())
        self.create_subscription(ModalParameters, RESULT_TOPIC, self._on_result,
                                 results_qos(depth=100))
        self.create_timer(1.0 / v['publish_rate'], self._on_timer)
        self._last_level: int | None = None
        self.log.info(f'judging {self.resolve_topic_name(RESULT_TOPIC)} against the reference '
                      f'model; verdicts on {self.resolve_topic_name(DRIFT_TOPIC)}, diagnostics '
                      f'on {DIAGNOSTICS_TOPIC} as {self.scanner!r}')

    def _apply(self, values: dict[str, Any], changed: set[str]) -> None:
        if 'hardware_id' in changed:
            self.scanner = scanner_name(self, values['hardware_id'])
        if 'stale_timeout' in changed:
            self.task.stale_timeout = float(values['stale_timeout'])
        if changed - {'hardware_id', 'stale_timeout'}:
            self.task.monitor = monitor_from_parameters(values)
            self.log.info('reference or tolerances changed: trend history restarted')

    def _on_result(self, msg: ModalParameters) -> None:
        try:
            result = result_from_msg(msg)
        except GalvoSysidError as err:
            self.log.warning(f'ModalParameters message set aside: {err}')
            return
        verdict = self.task.on_result(result, window_index=int(msg.window_index))
        if self._last_level == STALE:
            self.log.info(f'{self.scanner}: identification results arrive again')
        self._publish_verdict(verdict, stamp=stamp_to_seconds(msg.header.stamp))
        text = f'window {verdict.window_index} ({result.target_angle:+g} deg): {verdict.message}'
        if verdict.level != OK:
            self.log.warning(text)
        elif self._last_level != OK:
            self.log.info(text)
        self._last_level = verdict.level

    def _publish_verdict(self, verdict: DriftVerdict, *, stamp: float) -> None:
        msg = fill(DriftStatus(), drift_status_fields(verdict))
        fill_header(msg, stamp=stamp, frame_id=self.scanner)
        self.drift.publish(msg)

    def _on_timer(self) -> None:
        verdict, became_stale = self.task.poll()
        now = self.get_clock().now().nanoseconds * 1e-9
        if became_stale:
            self.log.warning(f'{self.scanner}: {verdict.message}')
            self._publish_verdict(verdict, stamp=now)
            self._last_level = STALE
        status = DiagnosticStatus()
        status.level = _LEVEL_BYTES[verdict.level]
        status.name = f'{self.scanner}: plant drift'
        status.hardware_id = self.scanner
        status.message = verdict.message
        age = self.task.age
        extra = {'windows judged': str(self.task.windows_judged),
                 'last result age [s]': 'none yet' if age is None else f'{age:.1f}'}
        status.values = [KeyValue(key=k, value=v)
                         for k, v in diagnostic_values(verdict, extra=extra)]
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = [status]
        self.diagnostics.publish(array)


def main(args: Sequence[str] | None = None) -> int:
    """Entry point of ``watchdog``."""
    return run_node(WatchdogNode, args=sys.argv if args is None else args)

if __name__ == '__main__':
    raise SystemExit(main())
