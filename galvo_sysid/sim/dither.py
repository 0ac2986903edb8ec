"""A small excitation added to every move's current command: more information, little motion.

Ordinary positioning moves put little current into the high resonances (smooth profiles even
less), so their parameters are poorly determined however long one averages. A dither adds a
few tones at the model's resonances (or at given frequencies) to the current command during
the recorded part of every move, the same in every move (so averaging keeps it and removes
the noise), switched on and off smoothly (a Tukey window over the record) so it does not
ring the modes at its edges. A real servo driver takes the same parameters; the simulator
applies them here.

The cost is motion: the mirror follows the tones (about ``amplitude x |P(j omega)|``) and
the controller's reaction. :func:`galvo_sysid.field.plan.plan` tells what a dither buys and costs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from galvo_sysid.errors import ConfigurationError

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from galvo_sysid.model.plant import PlantModel

__all__ = ['MAX_DITHER', 'DitherConfig', 'dither_for_modes', 'dither_signal']

MAX_DITHER = 0.5
"""Largest tone amplitude accepted [A] (a dither is a small signal, not a move)."""


@dataclass(frozen=True)
class DitherConfig:
    """The dither added to every move's current command.

    Attributes:
        amplitude: Amplitude of each tone [A] (0: no dither).
        frequencies: Tone frequencies [rad/s] (None: the model's resonances).
        taper: Share of the record over which the tones fade in and out (Tukey window).
    """

    amplitude: float = 0.0
    frequencies: tuple[float, ...] | None = None
    taper: float = 0.2

    def __post_init__(self) -> None:
        if not (math.isfinite(self.amplitude) and 0 <= self.amplitude <= MAX_DITHER):
            raise ConfigurationError(f'the dither amplitude must be within 0..{MAX_DITHER} A, '
                                     f'got {self.amplitude!r}')
        if not (math.isfinite(self.taper) and 0 < self.taper <= 1):
            raise ConfigurationError(f'the dither taper must be in (0, 1], got {self.taper!r}')
        if self.frequencies is not None:
            if not 1 <= len(self.frequencies) <= 16:
                raise ConfigurationError('give 1-16 dither frequencies')
            for w in self.frequencies:
                if not (isinstance(w, int | float) and math.isfinite(w) and w > 0):
                    raise ConfigurationError(f'dither frequencies must be positive [rad/s], '
                                             f'got {w!r}')

    @property
    def active(self) -> bool:
        """Whether any dither is added."""
        return self.amplitude > 0


def dither_for_modes(amplitude: float, modes: str, *, model: PlantModel) -> DitherConfig:
    """The dither of ``amplitude`` [A] at some of the model's resonances.

    Args:
        amplitude: Amplitude of each tone [A] (0: none).
        modes: ``'all'`` (every resonance of the model) or the 1-based modes, comma-separated
            (e.g. ``'3'`` or ``'1,3'``).
        model: The scanner's plant model (its natural frequencies).

    Raises:
        ConfigurationError: A bad amplitude, or modes the model does not have.
    """
    text = modes.strip()
    if text in ('', 'all'):
        return DitherConfig(amplitude=amplitude)
    n = model.n_modes
    chosen: list[int] = []
    for item in text.split(','):
        item = item.strip()
        if not item.isdigit() or not 1 <= int(item) <= n or int(item) in chosen:
            raise ConfigurationError(f"dither modes must be 'all' or distinct mode numbers "
                                     f'1..{n} separated by commas, got {modes!r}')
        chosen.append(int(item))
    freqs = tuple(float(model.modal.natural_frequencies[i - 1]) for i in chosen)
    return DitherConfig(amplitude=amplitude, frequencies=freqs)


def dither_signal(config: DitherConfig, *, model: PlantModel, record: int,
                  length: int) -> NDArray[np.float64]:
    """The dither current [A] of one move: ``length`` samples, tones over the first ``record``.

    Raises:
        ConfigurationError: A frequency at or above the Nyquist frequency.
    """
    out = np.zeros(length)
    if not config.active:
        return out
    t = model.sample_period
    freqs = config.frequencies if config.frequencies is not None \
        else model.modal.natural_frequencies
    nyquist = math.pi / t
    for w in freqs:
        if w >= nyquist:
            raise ConfigurationError(f'dither frequency {w:.4g} rad/s is not below the Nyquist '
                                     f'frequency {nyquist:.4g} rad/s')
    k = np.arange(record, dtype=float)
    tones = sum(np.sin(w * t * k + math.pi * i * i / max(len(freqs), 1))
                for i, w in enumerate(freqs))
    out[:record] = config.amplitude * np.asarray(tones, dtype=float) * _tukey(record,
                                                                              config.taper)
    return out


def _tukey(n: int, share: float) -> NDArray[np.float64]:
    """Tukey window: cosine ramps over ``share`` of the samples, flat between."""
    ramp = max(1, round(share * n / 2))
    w = np.ones(n)
    edge = 0.5 - 0.5 * np.cos(np.pi * (np.arange(ramp) + 0.5) / ramp)
    w[:ramp] = edge
    w[n - ramp:] = edge[::-1]
    return w
