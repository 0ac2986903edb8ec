"""``sysid``: online identification of the scanner, one window of moves at a time.

Subscribes to ``galvo/current`` and ``galvo/encoder`` (``MoveSamples``), pairs the halves by
move_id, collects ``window_size`` moves per signed target angle and publishes each window's
identified ``ModalParameters`` on ``galvo/modal_parameters`` (reliable, transient local).
The logic is :class:`galvo_sysid.monitor.tasks.SysidTask`; fits run on a worker thread (by
default in a child process), never in the subscription callbacks. The halves are taken in
batches, the two topics in turn (:class:`galvo_sysid.nodes.receiving.BatchReceiver`: a few
milliseconds later, at under half the CPU). The parameters are
:data:`galvo_sysid.monitor.parameters.SYSID_PARAMETERS`.

The scanner's plant model is the file of the read-only parameter ``model`` ('' = the packaged
model of the paper's scanner), read at start-up (a bad file: one line on stderr, exit code 2):
it sets the modes, bands, input dynamics and the sample period the moves must have. A window
whose data do not match it is published with ``status = STATUS_MISMATCH``, NaN parameters
and the reason, and the identification diagnostic turns ERROR: the scanner is not the one
the model describes (run ``galvo-sysid commission``).

Run: ``sysid --ros-args --params-file config/sysid.yaml [-r __ns:=/scanner_1]``.
"""

from __future__ import annotations

import functools
import sys
from typing import TYPE_CHECKING, Any

from diagnostic_msgs.msg import DiagnosticArray
from galvo_sysid_msgs.msg import ModalParameters, MoveSamples
from rclpy.node import Node

from galvo_sysid.errors import GalvoSysidError, one_line
from galvo_sysid.ident.warm import reference_start
from galvo_sysid.interfaces.messages import (
    fill,
    fill_header,
    modal_parameters_fields,
    read_move_samples,
    unidentified_fields,
)
from galvo_sysid.interfaces.topics import (
    CURRENT_TOPIC,
    DIAGNOSTICS_TOPIC,
    ENCODER_TOPIC,
    RESULT_TOPIC,
)
from galvo_sysid.model import PlantModel, load_model, model_label
from galvo_sysid.monitor.pairing import MoveWindower
from galvo_sysid.monitor.parameters import SYSID_PARAMETERS, WINDOWER_PARAMETERS
from galvo_sysid.monitor.scheduler import FitOutcome, node_fit
from galvo_sysid.monitor.tasks import SysidTask
from galvo_sysid.monitor.verdict import STATUS_MISMATCH
from galvo_sysid.nodes.command_line import print_help
from galvo_sysid.nodes.framework import (
    ParameterSet,
    diagnostics_qos,
    logger,
    moves_qos,
    publish_diagnostic,
    publish_while_up,
    results_qos,
    run_node,
    scanner_name,
)
from galvo_sysid.nodes.receiving import BatchReceiver

if TYPE_CHECKING:
    from collections.abc import Sequence

    from rclpy.timer import Timer

__all__ = ['SysidNode', 'main']

def _validate(values: dict[str, Any]) -> str | None:
    if values['samples'] and values['samples'] > values['max_samples']:
        return 'samples must be 0 or <= max_samples'
    budget = values['max_buffered_bytes']
    if budget - budget // 4 < 16 * values['window_size'] * (values['samples'] or 32):
        return 'max_buffered_bytes cannot hold one window (three quarters of it must)'
    if budget // 4 < 16 * values['max_samples']:
        return ('max_buffered_bytes cannot hold a waiting pair of the largest records '
                '(max_samples; a quarter of it must)')
    if values['samples'] and values['samples'] <= values['na'] + values['nb']:
        return 'records must be longer than na + nb samples'
    return None


class SysidNode(Node):
    """The sysid node (see the module docs)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('sysid', **kwargs)
        self.log = logger(self)
        self.params = ParameterSet(self, SYSID_PARAMETERS, validate=_validate, apply=self._apply)
        v = self.params.values
        self.model: PlantModel = load_model(v['model'] or None)
        self.results = self.create_publisher(ModalParameters, RESULT_TOPIC, results_qos())
        self.task = SysidTask(self._fit_function(v), self._publish,
                              warn=self.log.warning, windower=self._windower_args(v),
                              queue_size=v['queue_size'], processes=v['fit_processes'],
                              warnings_per_second=v['warnings_per_second'],
                              warm_start=v['warm_start'], model_path=v['model'],
                              fit_budget=1e-3 * v['fit_budget_ms'],
                              measured_lag=(v['measured_current_lag']
                                            if v['current'] == 'measured' else None),
                              reference=reference_start(self.model))
        qos = moves_qos(v['qos_depth'], reliability=v['qos_reliability'])
        # raw: the serialized bytes; the record's length is read before any sample is decoded.
        # In batches: the executor's every wait costs more than a half does (receiving.py).
        self.receiver = BatchReceiver()
        for signal, topic in (('current', CURRENT_TOPIC), ('encoder', ENCODER_TOPIC)):
            self.receiver.subscribe(self, MoveSamples, topic,
                                    functools.partial(self._on_half, signal=signal), qos,
                                    raw=True)
        self.create_timer(0.25, self.task.tick)
        self._stats_timer: Timer | None = None
        self._stats_every(v['stats_period'])
        self.diagnostics = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC,
                                                 diagnostics_qos())
        self._reported = self.task.stats()
        if v['diagnostics_period'] > 0:
            self.create_timer(v['diagnostics_period'], self._publish_diagnostics)
        self.log.info(
            f'identifying windows of {v["window_size"]} moves ({v["method"]}) from '
            f'{self.resolve_topic_name(CURRENT_TOPIC)} and '
            f'{self.resolve_topic_name(ENCODER_TOPIC)} -> '
            f'{self.resolve_topic_name(RESULT_TOPIC)}; model {model_label(v["model"])}: '
            f'{self.model}')

    def _windower_args(self, values: dict[str, Any]) -> dict[str, Any]:
        return {**{k: values[k] for k in WINDOWER_PARAMETERS},
                'sample_period': self.model.sample_period}

    def _fit_function(self, values: dict[str, Any]) -> functools.partial[Any]:
        return node_fit(method=values['method'], model=self.model, na=values['na'],
                        nb=values['nb'])

    def _apply(self, values: dict[str, Any], changed: set[str]) -> None:
        if changed & set(WINDOWER_PARAMETERS):
            old = self.task.windower
            self.task.windower = MoveWindower(**self._windower_args(values),
                                              first_index=old.next_index)
            held = sum(old.fill_levels().values())
            self.log.warning(
                f'window settings changed ({", ".join(sorted(changed))}): {held} buffered '
                f'moves and {old.pending} unpaired halves discarded')
        if 'warm_start' in changed:
            self.task.warm_start = values['warm_start']
        if 'fit_budget_ms' in changed:
            self.task.fit_budget = 1e-3 * values['fit_budget_ms']
        if changed & {*WINDOWER_PARAMETERS, 'method', 'na', 'nb', 'warm_start'}:
            self.task.clear_starts()  # the next window of each angle searches afresh
        if 'stats_period' in changed:
            self._stats_every(values['stats_period'])
        if changed & {'method', 'na', 'nb'}:
            self.task.fitter.set_fit(self._fit_function(values))
            self.log.info(f'identification now {values["method"]} '
                          f'(na={values["na"]}, nb={values["nb"]})')

    def _on_half(self, raw: bytes, *, signal: str) -> None:
        try:
            msg = read_move_samples(raw)
        except GalvoSysidError as err:
            self.task.set_aside(f'{signal}: {one_line(err)}')
            return
        self.task.add_serialized(msg, signal=signal)

    def _publish(self, outcome: FitOutcome) -> None:
        w = outcome.window
        model = self.params.values['model']
        if outcome.result is None:
            if outcome.mismatch:  # said plainly downstream: not identified, and why
                msg = fill(ModalParameters(), unidentified_fields(
                    window_index=w.index, target_angle=w.target_angle, moves=w.moves,
                    n_modes=self.model.n_modes, status=STATUS_MISMATCH,
                    status_message=self.task.mismatch_text(outcome.error or ''), model=model))
                fill_header(msg, stamp=w.last_stamp)
                publish_while_up(self, self.results, msg)
            return
        msg = fill(ModalParameters(), modal_parameters_fields(outcome.result,
                                                              window_index=w.index, model=model))
        fill_header(msg, stamp=w.last_stamp)
        if not publish_while_up(self, self.results, msg):  # a fit finished while stopping
            return
        r = outcome.result
        self.log.info(
            f'window {w.index}: {w.target_angle:+g} deg, {w.moves} moves, fit '
            f'{r.fit_percent:.1f} %, omega = '
            f'{", ".join(f"{x:.5g}" for x in r.natural_frequencies)} rad/s '
            f'(queued {1e3 * outcome.queued:.0f} ms, fit {1e3 * outcome.fit_time:.0f} ms)')

    def _stats_every(self, period: float) -> None:
        """Log the counters every ``period`` seconds from now on (0: never)."""
        if self._stats_timer is not None:
            self.destroy_timer(self._stats_timer)
            self._stats_timer = None
        if period > 0:
            self._stats_timer = self.create_timer(period, self._log_stats)

    def _log_stats(self) -> None:
        s = self.task.stats()
        self.log.info('counters: ' + ', '.join(f'{k}={v}' for k, v in s.items()))

    def _publish_diagnostics(self) -> None:
        """Counters on /diagnostics: ERROR when windows do not match the model, WARN when moves
        were set aside or windows lost lately (:meth:`SysidTask.health`)."""  # noqa: D205, D209
        now = self.task.stats()
        level, message = self.task.health(self._reported, now=now)
        self._reported = now
        scanner = scanner_name(self, self.params.values['hardware_id'])
        values = [(k, str(x)) for k, x in now.items()]
        values.append(('model', model_label(self.params.values['model'])))
        lag = self.task.measured_lag
        values.append(('current', 'command' if lag is None else
                       f'measured, made held with an amplifier lag of {lag:.6g} s'))
        publish_diagnostic(self, self.diagnostics, name=f'{scanner}: identification',
                           hardware_id=scanner, level=level, message=message, values=values)

    def close(self) -> None:
        """Stop the fit workers (queued windows are finished for up to 2 s)."""
        self.task.close(timeout=2.0)


def main(args: Sequence[str] | None = None) -> int:
    """Entry point of ``sysid``."""
    argv = sys.argv if args is None else args
    if print_help('sysid', argv):  # before rclpy starts
        return 0
    return run_node(SysidNode, args=argv)


if __name__ == '__main__':
    raise SystemExit(main())
