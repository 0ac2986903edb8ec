"""``galvo_driver``: a simulated galvano scanner doing positioning moves, published live.

Wraps :class:`galvo_sysid.sim.simulator.GalvoSimulator` (closed loop, the plant of the model
file ``model``, default the paper's Table I scanner; input dynamics, noise, quantised
encoder; the positioning controller designed from the model). Moves follow the paper's
schedule: for each angle of ``angles``, ``moves_per_angle`` moves alternating forward (+a)
and return (-a). Each move is
published on ``galvo/current`` and ``galvo/encoder`` (``MoveSamples``, same move_id, stamp =
the move's first sample: ``stamp_origin`` + simulated time).

Pace: ``rate_factor`` 1 is real time (165 moves/s back to back), 10 ten times faster, 0 as
fast as possible. Plant changes take effect from the next move when their parameters are set
(at start-up or live with ``galvo-sysid param set``, or ``ros2 param set`` on a full ROS 2
install): ``drift.*`` (a parameter drifting linearly), ``step.*`` (a step change) and
``effects`` (the physical effects, as the discrepancy workflow's JSON list).

The parameters are :data:`galvo_sysid.monitor.parameters.DRIVER_PARAMETERS`.

Run: ``galvo_driver --ros-args --params-file config/driver.yaml``.
"""

from __future__ import annotations

import json
import math
import sys
import threading
import time
from typing import TYPE_CHECKING, Any

from galvo_sysid_msgs.msg import MoveSamples
from rclpy.duration import Duration
from rclpy.node import Node

from galvo_sysid.errors import GalvoSysidError
from galvo_sysid.interfaces.messages import fill, fill_header, move_samples_fields
from galvo_sysid.interfaces.topics import CURRENT_TOPIC, ENCODER_TOPIC
from galvo_sysid.model import Drift, PlantModel, StepChange, load_model
from galvo_sysid.model.changes import plant_at
from galvo_sysid.model.effects import Effect, effects_from_json
from galvo_sysid.model.physics import check_parameter_name
from galvo_sysid.monitor.parameters import DRIVER_PARAMETERS, MAX_EFFECTS_TEXT
from galvo_sysid.nodes.command_line import print_help
from galvo_sysid.nodes.framework import (
    ParameterSet,
    logger,
    moves_qos,
    run_node,
)
from galvo_sysid.sim.config import SimulatorConfig
from galvo_sysid.sim.loop import ClosedLoop
from galvo_sysid.sim.simulator import GalvoSimulator

if TYPE_CHECKING:
    from collections.abc import Iterator, Sequence

    from galvo_sysid.sim.config import Move

__all__ = ['DriverNode', 'PlantChanges', 'check_values', 'main', 'simulator_config']


def _effects(text: str) -> tuple[Effect, ...]:
    """The ``effects`` parameter through the effect registry (size and nesting bounded
    before the JSON is parsed, each effect's parameters checked against their ranges)."""  # noqa: D205, D209
    return effects_from_json(text, where='effects', max_chars=MAX_EFFECTS_TEXT)


def check_values(values: dict[str, Any]) -> str | None:
    """Why the driver's parameter values do not go together, or None (no simulator needed;
    each value has passed its :meth:`~galvo_sysid.monitor.parameters.ParamSpec.check`)."""  # noqa: D205, D209
    if values['moves_per_angle'] % 2:
        return f'moves_per_angle must be even, got {values["moves_per_angle"]}'
    try:
        _effects(values['effects'])
        for key in ('drift.parameter', 'step.parameter'):
            if values[key]:
                check_parameter_name(values[key])
    except GalvoSysidError as err:
        return str(err)
    return None


def simulator_config(values: dict[str, Any]) -> SimulatorConfig:
    """The simulator of the driver's parameters: the model file, record and dwell lengths.

    Raises:
        ConfigurationError: Bad model file, lengths or dither modes (a model without a stable
            controller design included).
        InvalidDataError: The model file cannot be read.
    """
    from galvo_sysid.sim.dither import dither_for_modes

    model = load_model(values['model'] or None)
    record = values['record_length'] or None
    dwell = None if values['dwell_length'] < 0 else values['dwell_length']
    dither = dither_for_modes(values['dither.amplitude'], values['dither.modes'], model=model)
    return SimulatorConfig(plant=model, record_length=record, dwell_length=dwell, dither=dither)


class PlantChanges:
    """Turns the driver's change parameters into simulator calls (no ROS)."""

    def __init__(self, simulator: GalvoSimulator) -> None:
        self.sim = simulator
        self._base: PlantModel = simulator.config.plant
        self._checked: tuple[Any, ...] | None = None

    def check(self, values: dict[str, Any]) -> None:
        """Check that the simulator can run the plant these values make, before any is
        applied: the effects (the registry's checks, then the plant they make) and a step
        change must leave the controller a stable closed loop.

        Raises:
            ConfigurationError: Why not (e.g. ``the closed loop is unstable on this plant``,
                an input delay below the input dynamics' own).
        """  # noqa: D205
        key = tuple(values[k] for k in ('effects', 'step.parameter', 'step.factor',
                                         'step.at_move'))
        if key == self._checked:
            return
        sim = self.sim
        physics = self._base.with_effects(_effects(values['effects'])).physics()
        plants = [physics]
        name, factor = values['step.parameter'], values['step.factor']
        if name and factor != 1.0:
            at = max(values['step.at_move'], sim.move_count)
            step = StepChange(parameter=name, value=factor, at=at, unit='move', relative=True)
            plants.append(plant_at(physics, time=sim.time, move=at, steps=[step]))
        for plant in plants:
            ClosedLoop(plant, sim.controller, sim.config)
        self._checked = key

    def apply(self, values: dict[str, Any], changed: set[str]) -> list[str]:
        """Apply the changes named in ``changed``; return what was done, one line each."""
        sim = self.sim
        done: list[str] = []
        if 'effects' in changed:
            plant = self._base.with_effects(_effects(values['effects']))
            sim.set_plant(plant)
            active = [e.to_dict() for e in plant.effects]
            done.append(f'plant effects: {json.dumps(active) if active else "none"}')
        if changed & {'drift.parameter', 'drift.rate', 'drift.unit', 'step.parameter',
                      'step.factor', 'step.at_move'}:
            sim.clear_changes()
            name, rate, unit = values['drift.parameter'], values['drift.rate'], values['drift.unit']
            if name and rate:
                start = sim.time if unit == 'second' else sim.move_count
                sim.add_drift(Drift(parameter=name, rate=rate, unit=unit, start=start))
                when = f't = {start:.3f} s' if unit == 'second' else f'move {start}'
                done.append(f'drift: {name} changes {100 * rate:+g} % per {unit} from {when}')
            name, factor = values['step.parameter'], values['step.factor']
            at = values['step.at_move']
            if name and factor != 1.0:
                at_move = sim.move_count if at < 0 else at
                sim.add_step(StepChange(parameter=name, value=factor, at=at_move, unit='move',
                                        relative=True))
                done.append(f'step: {name} x {factor:g} from move {at_move}')
            if not done:
                done.append('no drift or step change')
        return done


class DriverNode(Node):
    """The driver node (see the module docs)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('galvo_driver', **kwargs)
        self.log = logger(self)
        self._lock = threading.Lock()
        self._ready = False  # the simulator's checks apply once it exists
        self.params = ParameterSet(self, DRIVER_PARAMETERS, validate=self._validate,
                                   apply=self._apply)
        v = self.params.values
        self.sim = GalvoSimulator(config=simulator_config(v), seed=v['seed'])
        self.sim.check_angles(v['angles'])
        self.changes = PlantChanges(self.sim)
        self.changes.check(v)
        self._ready = True
        for line in self.changes.apply(v, {n for n in v if n.startswith(('drift.', 'step.',
                                                                          'effects'))}):
            self.log.info(line)
        qos = moves_qos(v['qos_depth'], reliability=v['qos_reliability'])
        self.current = self.create_publisher(MoveSamples, CURRENT_TOPIC, qos)
        self.encoder = self.create_publisher(MoveSamples, ENCODER_TOPIC, qos)
        self.published = 0
        self._stop = threading.Event()
        # held while a move is published: close() takes it after setting _stop, so no publish
        # is in flight or starts once it returns (the node's publishers are then destroyed)
        self._publishing = threading.Lock()
        self._thread = threading.Thread(target=self._run, name='galvo-driver', daemon=True)
        self._thread.start()

    def _validate(self, values: dict[str, Any]) -> str | None:
        """The values together, then (once the simulator runs) what it can simulate: the
        angles on this scanner, the plant of the effects and a step."""  # noqa: D205, D209
        reason = check_values(values)
        if reason is not None or not self._ready:
            return reason
        with self._lock:
            self.sim.check_angles(values['angles'])
            self.changes.check(values)
        return None

    def _apply(self, values: dict[str, Any], changed: set[str]) -> None:
        with self._lock:
            for line in self.changes.apply(values, changed):
                self.log.info(line)

    def _schedule(self) -> Iterator[Move]:
        cycle = 0
        while not self._stop.is_set():
            v = self.params.values
            if v['cycles'] and cycle >= v['cycles']:
                return
            yield from self.sim.moves(angles=[float(a) for a in v['angles']],
                                      moves_per_angle=int(v['moves_per_angle']))
            cycle += 1

    def _wait_for_subscribers(self) -> bool:
        need = self.params.values['wait_for_subscribers']
        timeout = self.params.values['wait_timeout']
        if not need:
            return True
        self.log.info(f'waiting for {need} subscriber(s) on {self.current.topic_name} and '
                      f'{self.encoder.topic_name}')
        end = time.monotonic() + timeout if timeout > 0 else math.inf
        while not self._stop.is_set():
            if min(self.current.get_subscription_count(),
                   self.encoder.get_subscription_count()) >= need:
                return True
            if time.monotonic() > end:
                self.log.warning('no subscribers yet; starting anyway')
                return True
            self._stop.wait(0.05)
        return False

    def _run(self) -> None:
        try:
            self._publish_moves()
        except Exception as err:  # a crash here must be said, not lost with the thread
            if self._stop.is_set() or not self.context.ok():
                return  # shutting down (Ctrl-C): publishing may fail, nothing to say
            what = str(err) if isinstance(err, GalvoSysidError) else \
                f'unexpected {type(err).__name__}: {err}'
            self.log.error(f'simulation stopped: {what}')

    def _publish_moves(self) -> None:
        if not self._wait_for_subscribers():
            return
        origin = self.get_clock().now().nanoseconds * 1e-9
        wall0 = time.monotonic()
        sim0 = self.sim.time
        v = self.params.values
        self.log.info(f'moving: {len(v["angles"])} angles x {v["moves_per_angle"]} moves, '
                      f'rate factor {v["rate_factor"]:g}')
        moves = self._schedule()
        while not self._stop.is_set():
            with self._lock:
                move = next(moves, None)
            if move is None:
                break
            cfg = self.sim.config
            rate = float(self.params.values['rate_factor'])
            if rate > 0:  # publish when the move has happened (its record is complete)
                due = wall0 + (move.stamp - sim0 + cfg.record * cfg.sample_period) / rate
                delay = due - time.monotonic()
                if delay > 0 and self._stop.wait(delay):
                    break
                if delay < -1.0:  # fell behind (e.g. a rate change): do not burst to catch up
                    wall0 -= delay
            self._publish(move, stamp=origin + move.stamp)
        with self._publishing:
            if self._stop.is_set():
                return
            for pub in (self.current, self.encoder):
                pub.wait_for_all_acked(Duration(seconds=10))
        if not self._stop.is_set():
            self.log.info(f'schedule done after {self.published} moves')
            if self.params.values['exit_when_done']:
                import os
                import signal

                os.kill(os.getpid(), signal.SIGINT)

    def _publish(self, move: Move, *, stamp: float) -> None:
        with self._publishing:
            if self._stop.is_set():  # closed while the move was simulated
                return
            for pub, data in ((self.current, move.current), (self.encoder, move.encoder)):
                msg = fill(MoveSamples(), move_samples_fields(
                    move_id=move.move_id, target_angle=move.target_angle,
                    sample_period=move.sample_period, data=data))
                fill_header(msg, stamp=stamp)
                pub.publish(msg)
            self.published += 1

    def close(self) -> None:
        """Stop publishing: when this returns no move is being published or will be, even if
        the thread is still simulating one (a publish on the publishers the node's destruction
        frees ended the process with SIGSEGV once in a CI run)."""  # noqa: D205, D209
        self._stop.set()
        with self._publishing:
            pass
        self._thread.join(timeout=5.0)


def main(args: Sequence[str] | None = None) -> int:
    """Entry point of ``galvo_driver``."""
    argv = sys.argv if args is None else args
    if print_help('galvo_driver', argv):  # before rclpy starts
        return 0
    return run_node(DriverNode, args=argv)


if __name__ == '__main__':
    raise SystemExit(main())
