"""What the simulator is told: the scanner, its controller, noise and recording; a move.

:class:`SimulatorConfig` gathers everything :class:`~galvo_sysid.sim.simulator.GalvoSimulator`
needs (the plant model, the design model of the controller, the move profiles, the encoder,
the noise); :class:`Move` is one recorded positioning move.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model.changes import Drift, StepChange
from galvo_sysid.model.paper import PAPER_MODEL
from galvo_sysid.model.plant import MAX_RECORD_LENGTH, PlantModel
from galvo_sysid.sim.controller import ControllerConfig
from galvo_sysid.sim.dither import DitherConfig
from galvo_sysid.sim.profiles import ProfileConfig

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

__all__ = ['DEFAULT_ENCODER_RESOLUTION', 'METHODS', 'Move', 'SimulatorConfig']

DEFAULT_ENCODER_RESOLUTION = 40.0 / 2**20
"""20 bits over +-20 deg [deg]."""

METHODS = ('auto', 'fast', 'exact')
"""Simulation paths: ``fast`` (linear plants), ``exact`` (sample by sample), ``auto``."""


@dataclass(frozen=True)
class SimulatorConfig:
    """Everything the simulator needs; defaults give the paper's nominal scanner.

    Attributes:
        plant: The simulated (true) plant, with effects; its sample period is the DSP's.
        design: Nominal model the controller, notches and feed-forward are designed on
            (None: the plant without its effects).
        controller: Feedback controller design parameters (None: designed from the model,
            see :func:`galvo_sysid.sim.controller.auto_controller_config`).
        profile: Move profile parameters.
        record_length: Recorded samples per move (None: the plant model's).
        dwell_length: Unrecorded samples after each record (None: the plant model's).
        encoder_resolution: Quantisation step of the encoder [deg]; 0 for none.
        encoder_range: Largest angle the scanner may be commanded to [deg].
        measurement_noise_std: RMS of the encoder noise before quantisation [deg].
        measurement_noise_corner: Corner of its first-order colouring [Hz] (inf: white).
        current_noise_std: RMS of the noise added to the motor current [A].
        current_noise_corner: Corner of its first-order colouring [Hz] (inf: white).
        drifts: Plant drifts.
        steps: Plant step changes.
        method: ``'auto'``, ``'fast'`` (linear plants only) or ``'exact'``.
        substeps: Sub-steps per sample over which saturation is evaluated.
        dither: Tones added to every move's current command (default: none).
    """

    plant: PlantModel = PAPER_MODEL
    design: PlantModel | None = None
    controller: ControllerConfig | None = None
    profile: ProfileConfig = field(default_factory=ProfileConfig)
    record_length: int | None = None
    dwell_length: int | None = None
    encoder_resolution: float = DEFAULT_ENCODER_RESOLUTION
    encoder_range: float = 20.0
    measurement_noise_std: float = 5e-5
    measurement_noise_corner: float = 20e3
    current_noise_std: float = 2e-3
    current_noise_corner: float = 10e3
    drifts: tuple[Drift, ...] = ()
    steps: tuple[StepChange, ...] = ()
    method: str = 'auto'
    substeps: int = 8
    dither: DitherConfig = field(default_factory=DitherConfig)

    def __post_init__(self) -> None:
        def check(name: str, *, positive: bool = False, allow_inf: bool = False) -> None:
            value = getattr(self, name)
            ok = (isinstance(value, int | float) and not math.isnan(value)
                  and (allow_inf or math.isfinite(value)) and (value > 0 if positive
                                                               else value >= 0))
            if not ok:
                kind = 'positive' if positive else 'non-negative'
                raise ConfigurationError(f'{name} must be {kind} and finite, got {value!r}')

        if not isinstance(self.plant, PlantModel):
            raise ConfigurationError('plant must be a PlantModel')
        if self.design is not None:
            if not isinstance(self.design, PlantModel):
                raise ConfigurationError('design must be a PlantModel')
            if abs(self.design.sample_period - self.plant.sample_period) > \
                    1e-9 * self.plant.sample_period:
                raise ConfigurationError('the design model and the plant have different '
                                         'sample periods')
        if self.record_length is None:
            object.__setattr__(self, 'record_length', self.plant.record_length)
        if self.dwell_length is None:
            object.__setattr__(self, 'dwell_length', self.plant.dwell_length)
        check('encoder_resolution')
        check('encoder_range', positive=True)
        check('measurement_noise_std')
        check('current_noise_std')
        check('measurement_noise_corner', positive=True, allow_inf=True)
        check('current_noise_corner', positive=True, allow_inf=True)
        for name in ('record_length', 'dwell_length', 'substeps'):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 0:
                raise ConfigurationError(f'{name} must be a non-negative integer, got {value!r}')
        if self.record < 16:
            raise ConfigurationError('record_length must be at least 16 samples')
        for name in ('record_length', 'dwell_length'):  # as a model file may declare
            if getattr(self, name) > MAX_RECORD_LENGTH:
                raise ConfigurationError(f'{name} must be at most {MAX_RECORD_LENGTH:,} '
                                         f'samples, got {getattr(self, name):,}')
        if self.substeps < 1:
            raise ConfigurationError('substeps must be >= 1')
        if self.method not in METHODS:
            raise ConfigurationError(f'method must be one of {METHODS}, got {self.method!r}')
        if not all(isinstance(d, Drift) for d in self.drifts):
            raise ConfigurationError('drifts must be Drift instances')
        if not isinstance(self.dither, DitherConfig):
            raise ConfigurationError('dither must be a DitherConfig')
        if not all(isinstance(s, StepChange) for s in self.steps):
            raise ConfigurationError('steps must be StepChange instances')

    @property
    def sample_period(self) -> float:
        """DSP sampling period [s] (the plant model's)."""
        return self.plant.sample_period

    @property
    def design_model(self) -> PlantModel:
        """The model the controller is designed on."""
        return self.design if self.design is not None else self.plant.nominal()

    @property
    def record(self) -> int:
        """Recorded samples per move."""
        assert self.record_length is not None
        return self.record_length

    @property
    def dwell(self) -> int:
        """Unrecorded samples after each record."""
        assert self.dwell_length is not None
        return self.dwell_length

    @property
    def move_length(self) -> int:
        """Samples per move, recorded plus dwell."""
        return self.record + self.dwell

    @property
    def moves_per_second(self) -> float:
        """Back-to-back move rate in simulated time."""
        return 1.0 / (self.move_length * self.sample_period)


@dataclass(frozen=True)
class Move:
    """One recorded positioning move.

    Attributes:
        move_id: Running number of the move.
        target_angle: Signed commanded rotation [deg].
        start_angle: Commanded angle at the start of the move [deg].
        stamp: Simulated time of the move's first sample [s].
        sample_period: Sampling period [s].
        current: Commanded current [A] as the DSP computes it, shape (N,).
        encoder: Encoder angle [deg] (quantised, noisy), shape (N,).
    """

    move_id: int
    target_angle: float
    start_angle: float
    stamp: float
    sample_period: float
    current: NDArray[np.float64]
    encoder: NDArray[np.float64]
