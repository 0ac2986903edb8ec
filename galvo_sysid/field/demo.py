"""`make demo`: the three nodes live, a healthy scanner, then plant changes being flagged.

Starts ``galvo_driver`` (the simulated scanner, real time, the paper's 19 angles), ``sysid``
and ``watchdog`` as separate processes on this machine's ROS 2 graph, and prints one line per
identified window with the watchdog's verdict. Then it changes the simulated plant through
the driver's parameters, as an operator would with ``galvo-sysid param set`` (or
``ros2 param set`` on a full ROS 2 install):

1. healthy scanner: every window OK;
2. a step: omega_1 (first resonance) drops 2 %: flagged ERROR;
3. back to nominal, then omega_1 drifting down about 0.2 % per window: the trend is flagged
   (WARN) before any single window crosses the 1 % tolerance, then ERROR;
4. the driver stops: the watchdog reports STALE.

It stops by itself after about a minute and exits 0 if every change was flagged.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from galvo_sysid.interfaces.topics import (
    DIAGNOSTICS_TOPIC,
    DRIFT_TOPIC,
    RESULT_TOPIC,
    absolute_topic,
)
from galvo_sysid.monitor.verdict import ERROR, LEVEL_NAMES, STALE

if TYPE_CHECKING:
    from collections.abc import Callable

__all__ = ['main']

NS = '/demo_scanner'


@dataclass
class _Phase:
    name: str
    start_window: int
    flagged_at: int | None = None
    flag_level: int = 0
    flag_message: str = ''
    levels: list[int] = field(default_factory=list)


class _Demo:
    def __init__(self, log_dir: Path) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from galvo_sysid_msgs.msg import DriftStatus, ModalParameters
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from rclpy.signals import SignalHandlerOptions

        self.log_dir = log_dir
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self.context = Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node('demo', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.results: dict[int, Any] = {}
        self.verdicts: list[Any] = []
        self._waiting: dict[int, Any] = {}  # verdicts that came before their result
        self._ready: dict[int, Any] = {}  # verdicts waiting for an earlier window's
        self._next = 0  # the window shown next
        self.diagnostic_level: int | None = None
        self.node.create_subscription(ModalParameters, absolute_topic(RESULT_TOPIC, namespace=NS),
                                      self._on_result, qos)
        self.node.create_subscription(DriftStatus, absolute_topic(DRIFT_TOPIC, namespace=NS),
                                      self._on_verdict, qos)
        self.node.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, self._on_diagnostics,
                                      10)
        self.phases: list[_Phase] = []
        self.windows = 0

    # ---------------------------------------------------------------- processes
    def start(self, exe: str, *args: str) -> None:
        path = Path(sys.executable).parent / exe
        log = (self.log_dir / f'{exe}.log').open('w')
        self.procs[exe] = subprocess.Popen(
            [str(path), '--ros-args', '-r', f'__ns:={NS}', *args], stdout=log,
            stderr=subprocess.STDOUT)

    def stop(self, exe: str) -> None:
        proc = self.procs.get(exe)
        if proc is None or proc.poll() is not None:
            return
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)

    def close(self) -> None:
        for exe in list(self.procs):
            self.stop(exe)
        self.executor.shutdown()
        self.node.destroy_node()
        from rclpy.utilities import try_shutdown

        try_shutdown(context=self.context)

    # ---------------------------------------------------------------- ROS
    def spin_until(self, done: Callable[[], bool], timeout: float) -> bool:
        end = time.monotonic() + timeout
        while not done():
            if time.monotonic() > end:
                return False
            for exe, proc in self.procs.items():
                if exe != 'galvo_driver' and proc.poll() is not None:
                    raise RuntimeError(f'{exe} exited with code {proc.returncode}; see '
                                       f'{self.log_dir / (exe + ".log")}')
            self.executor.spin_once(timeout_sec=0.05)
        return True

    def set_driver(self, **values: Any) -> bool:
        from rclpy.parameter import Parameter
        from rclpy.parameter_client import AsyncParameterClient

        client = AsyncParameterClient(self.node, f'{NS}/galvo_driver')
        if not self.spin_until(client.services_are_ready, 20):
            return False
        future = client.set_parameters([Parameter(k.replace('__', '.'), value=v)
                                        for k, v in values.items()])
        if not self.spin_until(future.done, 20):
            return False
        result = future.result()
        return result is not None and all(r.successful for r in result.results)

    def _on_result(self, msg: Any) -> None:
        index = int(msg.window_index)
        self.results[index] = msg
        verdict = self._waiting.pop(index, None)
        if verdict is not None:
            self._ready[index] = verdict
            self._show_ready()

    def _show_ready(self, *, flush: bool = False) -> None:
        """Show the verdicts in window order (two fit processes finish out of order); a
        window that never comes is skipped once two later ones wait."""  # noqa: D205, D209
        while self._ready:
            if self._next not in self._ready:
                if not flush and len(self._ready) < 3:
                    return
                self._next = min(self._ready)
            self._show(self._ready.pop(self._next))
            self._next += 1

    def _on_diagnostics(self, msg: Any) -> None:
        for status in msg.status:
            if status.hardware_id == NS.strip('/'):
                self.diagnostic_level = int.from_bytes(status.level, 'little')

    def _on_verdict(self, msg: Any) -> None:
        self.verdicts.append(msg)
        level = int(msg.level)
        if level == STALE:
            self._show_ready(flush=True)
            print(f'  watchdog: STALE   {msg.message.removeprefix("STALE: ")}', flush=True)
            return
        self.windows += 1
        if int(msg.window_index) not in self.results:
            self._waiting[int(msg.window_index)] = msg
            return
        self._ready[int(msg.window_index)] = msg
        self._show_ready()

    def _show(self, msg: Any) -> None:
        level = int(msg.level)
        r = self.results.get(int(msg.window_index))
        text = msg.message.split(': ', 1)[-1]
        if r is None:
            print(f'  window {msg.window_index:3d}  -> {LEVEL_NAMES[level]:5s} {text}', flush=True)
        else:
            resolved = list(r.resolved) or [True] * len(r.natural_frequencies)
            omega = ' '.join(f'{w:7.0f}' if ok else f'{"unres.":>7}'
                             for w, ok in zip(r.natural_frequencies, resolved, strict=False))
            print(f'  window {msg.window_index:3d} {r.target_angle:+6.2f} deg {r.moves:3d} moves '
                  f'k0 {r.k0:.4g}  omega {omega} rad/s  fit {r.fit_percent:4.1f} %  '
                  f'-> {LEVEL_NAMES[level]:5s} {text}', flush=True)
        if self.phases:
            phase = self.phases[-1]
            phase.levels.append(level)
            if level and phase.flagged_at is None and int(msg.window_index) >= phase.start_window:
                phase.flagged_at = int(msg.window_index)
                phase.flag_level = level
                phase.flag_message = text

    def phase(self, name: str) -> _Phase:
        self._show_ready(flush=True)
        latest = max(self.results, default=-1)
        p = _Phase(name=name, start_window=latest + 1)
        self.phases.append(p)
        print(f'\n== {name}', flush=True)
        return p

    def run_windows(self, count: int, *, timeout: float) -> None:
        target = self.windows + count
        self.spin_until(lambda: self.windows >= target, timeout)


def main() -> int:
    """Run the demo; return the process exit code."""
    from galvo_sysid import keep_freed_memory, limit_blas_threads

    limit_blas_threads()  # before numpy is imported; the node processes inherit it
    keep_freed_memory()
    from galvo_sysid.model import REFERENCE_MODEL

    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 100))
    log_dir = Path(tempfile.mkdtemp(prefix='galvo_sysid_demo_'))
    os.environ.setdefault('ROS_LOG_DIR', str(log_dir / 'ros'))
    w1 = REFERENCE_MODEL.natural_frequencies[0]
    print('galvo_sysid demo: a simulated galvano scanner identified live over ROS 2.')
    print(f'  nodes: galvo_driver -> sysid -> watchdog in namespace {NS} '
          f'(ROS_DOMAIN_ID={os.environ["ROS_DOMAIN_ID"]}, logs in {log_dir})')
    print('  each window: 100 moves of one signed angle averaged and fitted (refined method);')
    print('  the watchdog compares every window with the reference model (paper Table I):')
    print(f'  tolerance omega_1 1 % of {w1:.0f} rad/s; the third mode is hardly observable.')
    demo = _Demo(log_dir)
    ok = True
    try:
        demo.start('sysid')
        demo.start('watchdog', '-p', 'stale_timeout:=3.0', '-p', 'publish_rate:=2.0')
        demo.start('galvo_driver', '-p', 'rate_factor:=1.0')
        print('\nstarting the nodes (the first window takes ~2 s of moves) ...', flush=True)
        demo.phase("1. healthy scanner (real time, the paper's 19 angles, forward and back)")
        demo.run_windows(10, timeout=60)

        p2 = demo.phase(f'2. plant change: omega_1 steps down 2 % ({w1:.0f} -> '
                        f'{0.98 * w1:.0f} rad/s), set live as a driver parameter')
        ok &= demo.set_driver(step__parameter='omega_1', step__factor=0.98)
        demo.run_windows(6, timeout=30)

        demo.phase('3. back to nominal, then omega_1 drifting down 0.3 %/s '
                   '(about 0.2 % per window)')
        ok &= demo.set_driver(step__factor=1.0, step__parameter='')
        demo.run_windows(4, timeout=30)
        p3 = demo.phase('   ... drift starts now')
        ok &= demo.set_driver(drift__parameter='omega_1', drift__rate=-0.003)
        demo.run_windows(10, timeout=40)

        demo.phase('4. the driver stops: no more results')
        demo.stop('galvo_driver')
        got_stale = demo.spin_until(lambda: demo.verdicts[-1].level == STALE, 10)
    except KeyboardInterrupt:
        print('\ninterrupted', file=sys.stderr)
        return 130
    except RuntimeError as err:
        print(f'\ndemo failed: {err}', file=sys.stderr)
        return 1
    finally:
        demo.close()
    print('\n== summary')
    healthy = demo.phases[0].levels
    print(f'  healthy windows: {len(healthy)}, verdicts '
          f'{", ".join(f"{LEVEL_NAMES[x]} {healthy.count(x)}" for x in sorted(set(healthy)))}')
    step_ok = p2.flagged_at is not None and p2.flag_level == ERROR
    if p2.flagged_at is not None:
        print(f'  step of omega_1: flagged {LEVEL_NAMES[p2.flag_level]} at window {p2.flagged_at} '
              f'({p2.flag_message})')
    else:
        print('  step of omega_1: NOT flagged')
    drift_ok = False
    if p3.flagged_at is not None:
        r = demo.results.get(p3.flagged_at)
        dev = (r.natural_frequencies[0] / w1 - 1) if r is not None else math.nan
        drift_ok = abs(dev) < 0.01
        print(f'  drift of omega_1: flagged {LEVEL_NAMES[p3.flag_level]} at window '
              f'{p3.flagged_at}, omega_1 then {100 * dev:+.2f} % (tolerance 1 %): '
              f'{p3.flag_message}')
    else:
        print('  drift of omega_1: NOT flagged')
    print(f'  driver stopped: {"STALE reported" if got_stale else "STALE NOT reported"}')
    success = ok and step_ok and drift_ok and got_stale and healthy.count(ERROR) == 0
    print('demo ' + ('finished: every change was flagged.' if success else
                     'finished, but not everything went as expected (see above).'))
    return 0 if success else 1


if __name__ == '__main__':
    raise SystemExit(main())
