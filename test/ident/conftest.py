"""Closed-loop windows shared by the identification tests (simulated once per session)."""

from __future__ import annotations

import numpy as np
import pytest

from galvo_sysid.model import PSI
from galvo_sysid.sim.simulator import simulate_window


@pytest.fixture(scope='session')
def windows_1psi() -> list[tuple[np.ndarray, np.ndarray]]:
    """Windows of 100 closed-loop moves at 1 psi, noise seeds 0-7 (those of seeds 0-2 are
    among the 57 windows of benchmarks/paper_pipeline.py)."""
    return [simulate_window(PSI, moves=100, seed=seed) for seed in range(8)]
