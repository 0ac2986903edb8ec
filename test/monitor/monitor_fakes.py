"""Fakes shared by the monitor tests: results, windows, an outcome collector, halves."""

from __future__ import annotations

import threading
import time

import numpy as np

from galvo_sysid.errors import IdentificationError
from galvo_sysid.ident import IdentificationResult
from galvo_sysid.model import REFERENCE_MODEL
from galvo_sysid.monitor.moves import MoveHalf, Window
from galvo_sysid.monitor.scheduler import FitOutcome
from galvo_sysid.sim.simulator import GalvoSimulator

M = REFERENCE_MODEL


def fake_result(angle: float = 0.3, moves: int = 2, omega_scale: float = 1.0,
                ) -> IdentificationResult:
    return IdentificationResult(
        target_angle=angle, moves=moves, input_delay=1.6e-5, lag_time_constant=6e-6,
        k0=M.k0, residues=M.residues,
        natural_frequencies=tuple(w * omega_scale for w in M.natural_frequencies),
        damping_ratios=M.damping_ratios, k0_std=0.0, residues_std=(0.0,) * 3,
        natural_frequencies_std=(0.0,) * 3, damping_ratios_std=(0.0,) * 3,
        fit_percent=95.0, method='refined')


def window(index: int, moves: int = 2) -> Window:
    return Window(index=index, target_angle=0.3, sample_period=1e-5,
                  current=np.zeros((moves, 64)), encoder=np.zeros((moves, 64)),
                  move_ids=tuple(range(moves)), first_stamp=0.0, last_stamp=1.0)


class Collector:
    def __init__(self) -> None:
        self.items: list[FitOutcome] = []
        self.event = threading.Event()
        self.expected = 0

    def __call__(self, outcome: FitOutcome) -> None:
        self.items.append(outcome)
        if len(self.items) >= self.expected:
            self.event.set()


def slow_fit(w: Window, *, delay: float = 0.05) -> IdentificationResult:
    time.sleep(delay)
    if w.index == 3:
        raise IdentificationError('no physical mode 2 in its band')
    if w.index == 4:
        raise RuntimeError('boom')
    return fake_result(moves=w.moves)


def halves_of(sim: GalvoSimulator, angles: list[float], moves_per_angle: int) -> list[MoveHalf]:
    out = []
    for m in sim.moves(angles=angles, moves_per_angle=moves_per_angle):
        for sig, data in (('current', m.current), ('encoder', m.encoder)):
            out.append(MoveHalf(sig, m.move_id, m.target_angle, m.sample_period, m.stamp, data))
    return out


def echo_fit(w: Window) -> tuple[float, float, tuple[int, ...], float | None, int, int]:
    """What a fit process got of the window: its records' sums and shape, its deadline and
    index, and this process's id (picklable, for the scheduler's child processes)."""
    import os

    return (float(w.current.sum()), float(w.encoder.sum()), w.current.shape, w.deadline,
            w.index, os.getpid())
