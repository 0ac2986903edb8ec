"""What the scanner is.

One model type, :class:`PlantModel` (modal mechanics, input dynamics, physical effects, sample
period, recording, bands, uncertainty), read from and written to one YAML file; one effect
registry (:data:`EFFECTS`); :class:`Physics`, the plant with its effects acting, which the
simulator and the discrepancy workflow run; the exact zero-order hold and the delay split.

Modules: ``modal`` (Eq. 1, bands), ``dynamics`` (input dynamics, ZOH, delay split),
``effects`` (the registry), ``physics``, ``plant``, ``changes`` (drifts and steps),
``sampling`` (exact sampling with sub-steps), ``files`` (the YAML file), ``paper`` (the
paper's scanner).
"""

from galvo_sysid.model.changes import Drift, StepChange, plant_at
from galvo_sysid.model.dynamics import (
    DiscreteStateSpace,
    InputDynamics,
    discretize,
    modal_state_space,
    simulate,
    split_delay,
    zoh,
)
from galvo_sysid.model.effects import EFFECT_NAMES, EFFECTS, Effect, parse_effect
from galvo_sysid.model.files import (
    load_model,
    model_from_yaml,
    model_label,
    model_to_yaml,
    save_model,
)
from galvo_sysid.model.modal import (
    ModalModel,
    default_bands,
    parameter_mode,
    parameter_names,
    parameter_unit,
    relative_errors,
)
from galvo_sysid.model.paper import (
    PAPER_ANGLES,
    PAPER_MODEL,
    PAPER_TABLE_II,
    PSI,
    REFERENCE_MODEL,
    TAU,
)
from galvo_sysid.model.physics import Physics
from galvo_sysid.model.plant import PlantModel

__all__ = [
    'EFFECTS',
    'EFFECT_NAMES',
    'PAPER_ANGLES',
    'PAPER_MODEL',
    'PAPER_TABLE_II',
    'PSI',
    'REFERENCE_MODEL',
    'TAU',
    'DiscreteStateSpace',
    'Drift',
    'Effect',
    'InputDynamics',
    'ModalModel',
    'Physics',
    'PlantModel',
    'StepChange',
    'default_bands',
    'discretize',
    'load_model',
    'modal_state_space',
    'model_from_yaml',
    'model_label',
    'model_to_yaml',
    'parameter_mode',
    'parameter_names',
    'parameter_unit',
    'parse_effect',
    'plant_at',
    'relative_errors',
    'save_model',
    'simulate',
    'split_delay',
    'zoh',
]
