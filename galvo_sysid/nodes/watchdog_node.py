"""``watchdog``: is the identified plant drifting from its reference model?

Subscribes to ``galvo/modal_parameters`` and judges each window with
:class:`galvo_sysid.monitor.drift.DriftMonitor`: publishes a ``DriftStatus`` per window on
``galvo/drift`` and, at ``publish_rate``, a ``diagnostic_msgs/DiagnosticArray`` on
``/diagnostics`` (hardware_id = the scanner's name, one key/value per parameter's deviation).
With no result for ``stale_timeout`` seconds the state is STALE (also published once on
``galvo/drift``); it recovers with the next result.

The reference is one model file, the read-only parameter ``model`` ('' = the packaged model
of the paper's scanner, Table I), read at start-up (a bad file: one line on stderr, exit code
2). Tolerances are ``tolerances.<name>`` (``tolerances.omega_2``, declared for every mode of
the model) and the kind defaults ``tolerances.k``, ``tolerances.omega``, ``tolerances.zeta``
for the modes without their own; not set, the built-in defaults apply (the rule:
:mod:`galvo_sysid.monitor.tolerances`). A window whose data did not match the model the sysid
node used (``status`` not OK), or with another number of modes, gives a MISMATCH verdict
(diagnostic level ERROR), never a drift.

The logic is :class:`galvo_sysid.monitor.tasks.WatchdogTask`; the parameters are
:data:`galvo_sysid.monitor.parameters.WATCHDOG_PARAMETERS`.

Run: ``watchdog --ros-args --params-file config/watchdog.yaml [-r __ns:=/scanner_1]``.
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, Any

from diagnostic_msgs.msg import DiagnosticArray
from galvo_sysid_msgs.msg import DriftStatus, ModalParameters
from rclpy.node import Node

from galvo_sysid.errors import GalvoSysidError
from galvo_sysid.interfaces.messages import (
    diagnostic_values,
    drift_status_fields,
    fill,
    fill_header,
    result_from_msg,
    stamp_to_seconds,
    status_from_msg,
)
from galvo_sysid.interfaces.topics import DIAGNOSTICS_TOPIC, DRIFT_TOPIC, RESULT_TOPIC
from galvo_sysid.model import PlantModel, load_model, model_label
from galvo_sysid.monitor.parameters import DECLARED_MODES, WATCHDOG_PARAMETERS, tolerance_specs
from galvo_sysid.monitor.reference import monitor_from_parameters
from galvo_sysid.monitor.tasks import WatchdogTask
from galvo_sysid.monitor.verdict import OK, STALE, DriftVerdict
from galvo_sysid.nodes.command_line import print_help
from galvo_sysid.nodes.framework import (
    ParameterSet,
    diagnostics_qos,
    logger,
    publish_diagnostic,
    results_qos,
    run_node,
    scanner_name,
)

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = ['WatchdogNode', 'main']

class WatchdogNode(Node):
    """The watchdog node (see the module docs)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('watchdog', **kwargs)
        self.log = logger(self)
        self._models: dict[str, PlantModel] = {}
        self.params = ParameterSet(self, WATCHDOG_PARAMETERS, validate=self._validate,
                                   apply=self._apply)
        self.reference = self._model(self.params.values['model'])
        if self.reference.n_modes > DECLARED_MODES:
            self.params.extend(tolerance_specs(self.reference.n_modes,
                                               first_mode=DECLARED_MODES + 1))
        v = self.params.values
        self.task = WatchdogTask(monitor_from_parameters(v, model=self.reference),
                                 stale_timeout=v['stale_timeout'])
        self.scanner = scanner_name(self, v['hardware_id'])
        self.drift = self.create_publisher(DriftStatus, DRIFT_TOPIC, results_qos())
        self.diagnostics = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC,
                                                 diagnostics_qos())
        self.create_subscription(ModalParameters, RESULT_TOPIC, self._on_result,
                                 results_qos(depth=100))
        self.create_timer(1.0 / v['publish_rate'], self._on_timer)
        self._last_level: int | None = None
        self.log.info(f'judging {self.resolve_topic_name(RESULT_TOPIC)} against the reference '
                      f'model {model_label(v["model"])} ({self.reference}); verdicts on '
                      f'{self.resolve_topic_name(DRIFT_TOPIC)}, diagnostics on '
                      f'{DIAGNOSTICS_TOPIC} as {self.scanner!r}')

    def _model(self, path: str) -> PlantModel:
        """The model file read once (the parameter is read-only)."""
        if path not in self._models:
            self._models[path] = load_model(path or None)
        return self._models[path]

    def _validate(self, values: dict[str, Any]) -> str | None:
        try:
            monitor_from_parameters(values, model=self._model(values['model']))
        except GalvoSysidError as err:
            return str(err)
        return None

    def _apply(self, values: dict[str, Any], changed: set[str]) -> None:
        if 'hardware_id' in changed:
            self.scanner = scanner_name(self, values['hardware_id'])
        if 'stale_timeout' in changed:
            self.task.stale_timeout = float(values['stale_timeout'])
        if changed - {'hardware_id', 'stale_timeout'}:
            self.task.monitor = monitor_from_parameters(values, model=self.reference)
            self.log.info('tolerances or options changed: trend history restarted')

    def _on_result(self, msg: ModalParameters) -> None:
        try:
            result = result_from_msg(msg)
            status = status_from_msg(msg)
        except GalvoSysidError as err:
            self.log.warning(f'ModalParameters message set aside: {err}')
            return
        verdict = self.task.on_result(result, window_index=int(msg.window_index),
                                      status=status.status, status_message=status.message)
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
        age = self.task.age
        extra = {'windows judged': str(self.task.windows_judged),
                 'last result age [s]': 'none yet' if age is None else f'{age:.1f}'}
        publish_diagnostic(self, self.diagnostics, name=f'{self.scanner}: plant drift',
                           hardware_id=self.scanner, level=verdict.level,
                           message=verdict.message,
                           values=diagnostic_values(verdict, extra=extra))


def main(args: Sequence[str] | None = None) -> int:
    """Entry point of ``watchdog``."""
    argv = sys.argv if args is None else args
    if print_help('watchdog', argv):  # before rclpy starts
        return 0
    return run_node(WatchdogNode, args=argv)


if __name__ == '__main__':
    raise SystemExit(main())
