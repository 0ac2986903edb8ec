"""Moves with one physical effect hidden, shared by the discrepancy tests (issue 6).

The data come from the closed-loop simulator (galvo_sysid.sim.simulator: controller, noise,
quantised encoder, the effect acting through the registry); the workflow sees only the
recorded moves and fits them with its open-loop plant (galvo_sysid.discrepancy.plant). Both
plants share the model's sampling code, which is checked against python-control in
test_plant.py. Moves: 0.1, 1 and 10 psi, 20 per angle (10 of each sign). The full sweep over
seeds is benchmarks/discrepancy_confusion.py. Results are cached, so that the test modules
share the analyses.
"""

from __future__ import annotations

import functools
from dataclasses import replace

from galvo_sysid.discrepancy import DiscrepancyResult, MoveSet, find_discrepancy
from galvo_sysid.model import PAPER_MODEL, PSI, TAU

ANGLES = (0.1 * PSI, PSI, 10 * PSI)
MOVES_PER_ANGLE = 20

Effects = tuple[tuple[str, tuple[tuple[str, float], ...]], ...]


def hidden_effects(*items: tuple[str, dict[str, float]]) -> Effects:
    return tuple((name, tuple(sorted(p.items()))) for name, p in items)


@functools.cache
def measured(effects: Effects, seed: int, moves_per_angle: int = MOVES_PER_ANGLE,
             noise: bool = True) -> MoveSet:
    """Moves of the simulated closed loop with hidden effects (the test's truth)."""
    from galvo_sysid.sim.config import SimulatorConfig
    from galvo_sysid.sim.simulator import GalvoSimulator

    plant = PAPER_MODEL
    for name, params in effects:
        plant = plant.with_effect(name, dict(params))
    cfg = SimulatorConfig(plant=plant)
    if not noise:
        cfg = replace(cfg, measurement_noise_std=0.0, current_noise_std=0.0,
                      encoder_resolution=0.0)
    sim = GalvoSimulator(config=cfg, seed=seed)
    return MoveSet.from_moves(sim.moves(angles=list(ANGLES), moves_per_angle=moves_per_angle))


@functools.cache
def analysed(effects: Effects, seed: int, max_effects: int = 3) -> DiscrepancyResult:
    return find_discrepancy(measured(effects, seed), max_effects=max_effects)


# effect, magnitude, relative tolerance of each parameter
CASES = [
    ('input_delay', {'delay': 1.9 * TAU}, {'delay': 0.01}),
    ('input_delay', {'delay': 2.6 * TAU}, {'delay': 0.01}),
    ('unmodeled_resonance', {'natural_frequency': 3e4, 'damping_ratio': 0.02, 'residue': 3e4},
     {'natural_frequency': 0.005, 'damping_ratio': 0.25, 'residue': 0.1}),
    ('unmodeled_resonance', {'natural_frequency': 3e4, 'damping_ratio': 0.02, 'residue': 1e5},
     {'natural_frequency': 0.005, 'damping_ratio': 0.1, 'residue': 0.05}),
    ('coulomb_friction', {'friction_current': 0.01}, {'friction_current': 0.1}),
    ('coulomb_friction', {'friction_current': 0.03}, {'friction_current': 0.1}),
    ('pivot_stiffness', {'natural_frequency': 200.0}, {'natural_frequency': 0.02}),
    ('pivot_stiffness', {'natural_frequency': 500.0}, {'natural_frequency': 0.02}),
    ('gain_change', {'gain_ratio': 0.97}, {'gain_ratio': 0.002}),
    ('gain_change', {'gain_ratio': 0.90}, {'gain_ratio': 0.002}),
    ('current_saturation', {'current_limit': 0.95}, {'current_limit': 0.005}),
    ('current_saturation', {'current_limit': 0.80}, {'current_limit': 0.005}),
    # issue 14's effects (one magnitude each here; two in benchmarks/discrepancy_confusion.py)
    ('viscous_friction', {'current_per_velocity': 1e-5}, {'current_per_velocity': 0.02}),
    ('cogging_torque', {'amplitude': 0.01, 'period': 0.7, 'phase': 0.9},
     {'amplitude': 0.05, 'period': 0.005, 'phase': 0.05}),
    ('encoder_cyclic_error', {'amplitude': 5e-4, 'period': 0.45, 'phase': -2.0},
     {'amplitude': 0.02, 'period': 0.005, 'phase': 0.02}),
    ('amplifier_bandwidth', {'bandwidth': 12e3}, {'bandwidth': 0.01}),
]
PAIRS = 12
"""CASES[:PAIRS] are the effects of issue 6 at two magnitudes each."""
