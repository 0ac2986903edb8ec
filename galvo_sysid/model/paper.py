"""The paper's scanner: its model file, its angles, its accuracy table.

The values of Table I (the servo analyzer's curve fit, regarded as the true plant) live in
one place, the packaged model file ``galvo_sysid/model/data/paper_table1.yaml`` (installed
as ``share/galvo_sysid/models/paper_table1.yaml``); :data:`PAPER_MODEL` is that file read.
It is the default wherever no model is given (the nodes' ``model`` parameter left empty).
"""

from __future__ import annotations

from galvo_sysid.model.files import load_model
from galvo_sysid.model.modal import ModalModel
from galvo_sysid.model.plant import PlantModel

__all__ = [
    'PAPER_ANGLES',
    'PAPER_MODEL',
    'PAPER_TABLE_II',
    'PSI',
    'REFERENCE_MODEL',
    'TAU',
]

PAPER_MODEL: PlantModel = load_model(None)
"""The paper's scanner: Table I modes, one sample of DSP delay, 0.6-sample amplifier lag."""

REFERENCE_MODEL: ModalModel = PAPER_MODEL.modal
"""The paper's Table I as a modal model."""

TAU = PAPER_MODEL.sample_period
"""Sampling period of the paper's DSP [s] (10 us)."""

PSI = 0.3
"""The paper's unit rotation angle psi [deg]."""

PAPER_ANGLES: tuple[float, ...] = tuple(
    round(f * PSI, 10) for f in (*[i / 10 for i in range(1, 10)], *range(1, 11))
)
"""The 19 rotation angles of the paper's experiments, 0.1 psi ... 10 psi [deg]."""

PAPER_TABLE_II: dict[str, dict[str, float]] = {
    'A': {'k0': -3.638, 'k1': 6.301, 'k2': -23.13, 'k3': 61.93, 'omega_1': 0.5523,
          'omega_2': 1.053, 'omega_3': 1.690, 'zeta_1': -9.581, 'zeta_2': -8.513,
          'zeta_3': 655.4},
    'B': {'k0': -3.583, 'k1': 0.8503, 'k2': -25.15, 'k3': -612.4, 'omega_1': 0.9544,
          'omega_2': 1.082, 'omega_3': 2.531, 'zeta_1': 136.2, 'zeta_2': 5.023,
          'zeta_3': 1216.0},
}
"""The paper's Table II: relative errors [%] of its identified model, methods A and B."""
