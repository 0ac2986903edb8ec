"""Speed of the closed-loop simulator: moves per second for each path and effect.

Run: ``python benchmarks/simulator_speed.py [--quick]``. Prints a table of simulated moves per
second (each move = 512 recorded + 94 dwell samples = 6.06 ms of scanner time; real time is
165 moves/s) and how far the fast and exact paths agree.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable

import numpy as np

from galvo_sysid.model import PAPER_ANGLES, PAPER_MODEL, Drift, PlantModel
from galvo_sysid.sim.config import SimulatorConfig
from galvo_sysid.sim.simulator import GalvoSimulator, simulate_window


def _rate(run: Callable[[], int], repeat: int) -> float:
    best = math.inf
    count = 0
    for _ in range(repeat):
        start = time.perf_counter()
        count = run()
        best = min(best, time.perf_counter() - start)
    return count / best


def _schedule(config: SimulatorConfig, moves_per_angle: int) -> Callable[[], int]:
    def run() -> int:
        sim = GalvoSimulator(config=config, seed=1)
        return sum(1 for _ in sim.moves(angles=PAPER_ANGLES, moves_per_angle=moves_per_angle))
    return run


def _single(config: SimulatorConfig, count: int) -> Callable[[], int]:
    def run() -> int:
        sim = GalvoSimulator(config=config, seed=1)
        for i in range(count):
            sim.run_move(0.3 if i % 2 == 0 else -0.3)
        return count
    return run


def _window() -> int:
    simulate_window(0.3, moves=100, seed=1)
    return 200  # the return moves are simulated too


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--quick', action='store_true', help='fewer moves, one repeat')
    args = parser.parse_args()
    fast_n, exact_n, repeat = (20, 2, 1) if args.quick else (200, 20, 3)

    def cfg(**kwargs: object) -> SimulatorConfig:
        return SimulatorConfig(**kwargs)  # type: ignore[arg-type]

    def effects(**kwargs: float) -> PlantModel:
        names = {'friction_current': ('coulomb_friction', 'friction_current'),
                 'gain_ratio': ('gain_change', 'gain_ratio'),
                 'current_limit': ('current_saturation', 'current_limit'),
                 'pivot_frequency': ('pivot_stiffness', 'natural_frequency')}
        model = PAPER_MODEL
        for key, value in kwargs.items():
            if key == 'dead_time':
                model = model.with_effect('input_delay', {'delay': model.base_delay + value})
            else:
                model = model.with_effect(names[key][0], {names[key][1]: value})
        return model

    rows = [
        ('fast', f'nominal, 19 angles x {fast_n} (a bag)',
         _schedule(cfg(), fast_n), 19 * fast_n),
        ('fast', 'nominal, simulate_window(100) (+100 returns)', _window, 200),
        ('fast', 'nominal, run_move one at a time', _single(cfg(), 200), 200),
        ('fast', 'omega_1 drifting (plant rebuilt every move)',
         _schedule(cfg(drifts=(Drift('omega_1', -0.01),)), exact_n * 2), 38 * exact_n),
        ('fast', 'dead time + pivot + gain (linear effects)',
         _schedule(cfg(plant=effects(dead_time=4e-6, pivot_frequency=400.0,
                                     gain_ratio=1.1)), fast_n), 19 * fast_n),
        ('exact', 'nominal, quantiser in the loop',
         _schedule(cfg(method='exact'), exact_n), 19 * exact_n),
        ('exact', 'Coulomb friction 0.01 A',
         _schedule(cfg(plant=effects(friction_current=0.01)), exact_n), 19 * exact_n),
        ('exact', 'current saturation 0.6 A',
         _schedule(cfg(plant=effects(current_limit=0.6)), exact_n), 19 * exact_n),
        ('exact', 'friction 0.01 A + saturation 0.6 A',
         _schedule(cfg(plant=effects(friction_current=0.01, current_limit=0.6)), exact_n),
         19 * exact_n),
    ]
    print(f'{"path":6} {"case":48} {"moves":>6} {"moves/s":>9} {"x real time":>11}')
    for path, name, run, count in rows:
        rate = _rate(run, repeat)
        print(f'{path:6} {name:48} {count:6d} {rate:9.0f} {rate / 165.0:11.1f}')

    # Agreement of the two paths (same noise; quantiser off, since the fast path models it
    # as its equivalent noise).
    def moves(method: str) -> list[np.ndarray]:
        sim = GalvoSimulator(config=SimulatorConfig(method=method, encoder_resolution=0.0),
                             seed=3)
        return [m.encoder for m in sim.moves(angles=PAPER_ANGLES, moves_per_angle=2)]

    diff = max(float(np.abs(a - b).max()) for a, b in zip(moves('fast'), moves('exact'),
                                                          strict=True))
    print(f'\nfast vs exact, 38 moves, quantiser off: max |encoder difference| = {diff:.1e} deg')


if __name__ == '__main__':
    main()
