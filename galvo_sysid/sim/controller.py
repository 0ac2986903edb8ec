"""The digital positioning controller of the simulated galvano scanner, and its loop margins.

The feedback part of the 2-DOF controller (the feed-forward and the reference are in
:mod:`galvo_sysid.sim.profiles`) is a PID-type compensator as a galvo DSP would run it at the
sampling period tau = 10 us: a lead (the D part with its filter), a PI part, an optional
low-pass, and one notch per nominal resonance, all as second-order sections discretised with
the bilinear transform (prewarped at each notch and low-pass frequency)::

    C(z) = K * lead(z) * PI(z) * [low-pass(z)] * prod_i notch_i(z)

The gain ``K`` puts the loop's gain crossover at ``crossover_frequency`` on the design model
(a :class:`~galvo_sysid.model.plant.PlantModel`: its modes, computation delay and amplifier
lag). Without an explicit configuration the design follows the model
(:func:`auto_controller_config`): the crossover is the smaller of a fourteenth of the first
resonance (a usual galvo tuning rule; the notches take care of the resonances) and the
frequency where the equivalent input delay costs 0.15 rad (8.6 deg) of phase, also kept an
eighth of Nyquist below, rounded down to two significant digits; lead ratio 4, integral
corner at a tenth of the crossover, notches of depth 0.02/0.3 at every mode. The margins are
checked with python-control (:func:`loop_margins`, on the discrete loop including the delay
and the lag): at least 6 dB and 30 deg, else the crossover is lowered step by step; a model
for which no such design exists is refused with :class:`ConfigurationError`. For the paper's
scanner this gives 800 Hz, about 15 dB gain margin and 46 deg phase margin.
"""

from __future__ import annotations

import functools
import math
import warnings
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model.dynamics import DiscreteStateSpace
from galvo_sysid.model.dynamics import discretize as discretize_plant

if TYPE_CHECKING:
    from numpy.typing import ArrayLike, NDArray

    from galvo_sysid.model.plant import PlantModel

__all__ = [
    'Controller',
    'ControllerConfig',
    'LoopMargins',
    'auto_controller_config',
    'closed_loop_poles',
    'design_controller',
    'loop_frequency_response',
    'loop_margins',
]

Section = tuple[tuple[float, float, float], tuple[float, float, float]]


@dataclass(frozen=True)
class ControllerConfig:
    """Design parameters of the feedback controller.

    Attributes:
        crossover_frequency: Gain crossover of the loop on the design plant [Hz].
        lead_ratio: Lead zero at crossover / ratio, pole at crossover * ratio.
        integral_ratio: PI corner as a fraction of the crossover frequency.
        notch_frequencies: Notch centres [rad/s]; ``None`` uses the design model's resonances.
        notch_depth: Damping ratio of the notch numerator (depth = depth/width ratio).
        notch_width: Damping ratio of the notch denominator.
        lowpass_frequency: Corner of an optional second-order low-pass [Hz]; ``None`` for none.
        lowpass_damping: Damping ratio of that low-pass.
    """

    crossover_frequency: float = 800.0
    lead_ratio: float = 4.0
    integral_ratio: float = 0.1
    notch_frequencies: tuple[float, ...] | None = None
    notch_depth: float = 0.02
    notch_width: float = 0.3
    lowpass_frequency: float | None = None
    lowpass_damping: float = 0.7

    def __post_init__(self) -> None:
        def positive(name: str, value: float) -> None:
            if not (math.isfinite(value) and value > 0):
                raise ConfigurationError(f'{name} must be positive and finite, got {value!r}')

        positive('crossover_frequency', self.crossover_frequency)
        positive('notch_width', self.notch_width)
        positive('lowpass_damping', self.lowpass_damping)
        if not (math.isfinite(self.lead_ratio) and self.lead_ratio >= 1):
            raise ConfigurationError(f'lead_ratio must be >= 1, got {self.lead_ratio!r}')
        if not (math.isfinite(self.integral_ratio) and self.integral_ratio >= 0):
            raise ConfigurationError(f'integral_ratio must be >= 0, got {self.integral_ratio!r}')
        if not (math.isfinite(self.notch_depth) and 0 <= self.notch_depth < self.notch_width):
            raise ConfigurationError('notch_depth must be >= 0 and below notch_width')
        if self.notch_frequencies is not None:
            for w in self.notch_frequencies:
                positive('notch frequency', w)
        if self.lowpass_frequency is not None:
            positive('lowpass_frequency', self.lowpass_frequency)


@dataclass(frozen=True)
class Controller:
    """A designed discrete controller u = C(z) e as a gain times second-order sections.

    Attributes:
        gain: Overall gain K [A/deg].
        sections: Second-order sections ((b0, b1, b2), (1, a1, a2)) in z^-1.
        sample_period: Sampling period [s].
    """

    gain: float
    sections: tuple[Section, ...]
    sample_period: float

    def frequency_response(self, omega: ArrayLike) -> NDArray[np.complex128]:
        """Return C(exp(j omega T)) at the angular frequencies ``omega`` [rad/s]."""
        zi = np.exp(-1j * np.asarray(omega, dtype=float) * self.sample_period)
        h = np.full(zi.shape, self.gain, dtype=np.complex128)
        for (b0, b1, b2), (a0, a1, a2) in self.sections:
            h *= (b0 + b1 * zi + b2 * zi * zi) / (a0 + a1 * zi + a2 * zi * zi)
        return h

    def state_space(self) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                   NDArray[np.float64], float]:
        """Return (A, B, C, D) of x[k+1] = A x + B e, u = C x + D e (sections in series)."""
        a = np.zeros((0, 0))
        b = np.zeros(0)
        c = np.zeros(0)
        d = float(self.gain)
        for (b0, b1, b2), (_, a1, a2) in self.sections:
            # Section in transposed direct form II: states s1, s2.
            sa = np.array([[-a1, 1.0], [-a2, 0.0]])
            sb = np.array([b1 - a1 * b0, b2 - a2 * b0])
            sc = np.array([1.0, 0.0])
            sd = b0
            n = a.shape[0]
            # Series: section input = previous output (c x + d e).
            na = np.zeros((n + 2, n + 2))
            na[:n, :n] = a
            na[n:, :n] = np.outer(sb, c)
            na[n:, n:] = sa
            nb = np.concatenate([b, sb * d])
            nc = np.concatenate([sd * c, sc])
            a, b, c, d = na, nb, nc, sd * d
        return a, b, c, d


@dataclass(frozen=True)
class LoopMargins:
    """Stability margins of the discrete loop L = C(z) P(z).

    Attributes:
        gain_margin_db: Gain margin [dB] (inf if the phase never crosses -180 deg).
        phase_margin: Phase margin [deg].
        stability_margin: Minimum distance of L to -1 (1 / peak of the sensitivity).
        gain_crossover_frequency: Where |L| = 1 [Hz].
        phase_crossover_frequency: Where the gain margin is read [Hz].
        closed_loop_stable: Whether all closed-loop poles lie inside the unit circle.
    """

    gain_margin_db: float
    phase_margin: float
    stability_margin: float
    gain_crossover_frequency: float
    phase_crossover_frequency: float
    closed_loop_stable: bool


def _bilinear(num: tuple[float, ...], den: tuple[float, ...], sample_period: float,
              prewarp: float | None = None) -> Section:
    """Bilinear transform of (num/den)(s), polynomials of order <= 2 given highest first."""
    nb = (0.0,) * (3 - len(num)) + tuple(num)
    na = (0.0,) * (3 - len(den)) + tuple(den)
    c = 2.0 / sample_period if prewarp is None else prewarp / math.tan(prewarp * sample_period / 2)

    first_order = nb[0] == 0 and na[0] == 0

    def convert(p: tuple[float, ...]) -> tuple[float, float, float]:
        p2, p1, p0 = p
        if first_order:  # without the common factor (1 + 1/z) of the second-order form
            return (p1 * c + p0, p0 - p1 * c, 0.0)
        return (p2 * c * c + p1 * c + p0, 2 * (p0 - p2 * c * c), p2 * c * c - p1 * c + p0)

    bz, az = convert(nb), convert(na)
    return ((bz[0] / az[0], bz[1] / az[0], bz[2] / az[0]), (1.0, az[1] / az[0], az[2] / az[0]))


MIN_GAIN_MARGIN_DB = 6.0
"""Smallest gain margin an automatic design accepts [dB]."""

MIN_PHASE_MARGIN = 30.0
"""Smallest phase margin an automatic design accepts [deg]."""


def _two_digits_down(x: float) -> float:
    """Round down to two significant digits (800 Hz, not 807.8 Hz)."""
    scale = 10.0 ** (math.floor(math.log10(x)) - 1)
    return math.floor(x / scale * (1 + 1e-12)) * scale


def auto_controller_config(model: PlantModel) -> ControllerConfig:
    """The first automatic design of a model's controller (see the module docs).

    Raises:
        ConfigurationError: The model leaves no room for a crossover.
    """
    delay = model.equivalent_delay
    limits = [1.0 / model.sample_period / 2 / 8]      # an eighth of Nyquist [Hz]
    if model.n_modes:
        limits.append(model.modal.natural_frequencies[0] / (2 * math.pi) / 14)
    if delay > 0:
        limits.append(0.15 / (2 * math.pi * delay))
    crossover = min(limits)
    if not (math.isfinite(crossover) and crossover > 0):
        raise ConfigurationError(f'no crossover frequency for this model ({model})')
    return ControllerConfig(crossover_frequency=_two_digits_down(crossover))


def design_controller(model: PlantModel, *,
                      config: ControllerConfig | None = None) -> Controller:
    """Design the feedback controller for a nominal plant model.

    Args:
        model: Design (nominal) model; its modes get the notches, its input dynamics and
            sample period are the loop's.
        config: Design parameters; None designs from the model (:func:`auto_controller_config`
            with the crossover lowered until the margins hold, see the module docs).

    Returns:
        The discrete controller with the gain set for the requested crossover.

    Raises:
        ConfigurationError: Bad parameters, or (automatic design) no stable design with the
            required margins.
    """
    if config is not None:
        return _design(model, config)
    return _automatic_design(model)


@functools.lru_cache(maxsize=64)
def _automatic_design(model: PlantModel) -> Controller:
    """:func:`design_controller` without a config, kept per model (a design checks the loop's
    margins on 4,000 frequencies, about 0.3 s; every simulated window of a scanner asks for
    the same one; the model and the controller are immutable)."""  # noqa: D205, D209
    cfg = auto_controller_config(model)
    plant = discretize_plant(model.modal, model.dynamics, model.sample_period)
    tried = []
    for _ in range(12):
        controller = _design(model, cfg)
        m = loop_margins(controller, plant)
        tried.append(f'{cfg.crossover_frequency:g} Hz: gain margin {m.gain_margin_db:.1f} dB, '
                     f'phase margin {m.phase_margin:.1f} deg'
                     + ('' if m.closed_loop_stable else ', unstable'))
        if (m.closed_loop_stable and m.gain_margin_db >= MIN_GAIN_MARGIN_DB
                and m.phase_margin >= MIN_PHASE_MARGIN):
            return controller
        cfg = replace(cfg, crossover_frequency=_two_digits_down(0.8 * cfg.crossover_frequency))
    raise ConfigurationError(
        f'no stable positioning controller with {MIN_GAIN_MARGIN_DB:g} dB / '
        f'{MIN_PHASE_MARGIN:g} deg margins for this model ({model}); tried '
        + '; '.join(tried[:3]) + (' ...' if len(tried) > 3 else ''))


def _design(model: PlantModel, cfg: ControllerConfig) -> Controller:
    """The controller of one configuration (gain set for its crossover)."""
    sample_period = model.sample_period
    nyquist = math.pi / sample_period
    wc = 2 * math.pi * cfg.crossover_frequency
    if wc * cfg.lead_ratio >= nyquist:
        raise ConfigurationError('crossover_frequency * lead_ratio must stay below Nyquist')
    secs: list[Section] = [
        _bilinear((cfg.lead_ratio / wc, 1.0), (1 / (wc * cfg.lead_ratio), 1.0), sample_period),
    ]
    if cfg.integral_ratio > 0:
        secs.append(_bilinear((1.0, cfg.integral_ratio * wc), (1.0, 0.0), sample_period))
    if cfg.lowpass_frequency is not None:
        wl = 2 * math.pi * cfg.lowpass_frequency
        if wl >= nyquist:
            raise ConfigurationError('lowpass_frequency must be below Nyquist')
        secs.append(_bilinear((wl * wl,), (1.0, 2 * cfg.lowpass_damping * wl, wl * wl),
                              sample_period, prewarp=wl))
    notches = (model.modal.natural_frequencies if cfg.notch_frequencies is None
               else cfg.notch_frequencies)
    for w in notches:
        if w >= nyquist:
            raise ConfigurationError(f'notch frequency {w} rad/s is above Nyquist')
        secs.append(_bilinear((1.0, 2 * cfg.notch_depth * w, w * w),
                              (1.0, 2 * cfg.notch_width * w, w * w), sample_period, prewarp=w))
    unit = Controller(gain=1.0, sections=tuple(secs), sample_period=sample_period)
    plant = discretize_plant(model.modal, model.dynamics, sample_period)
    om = np.array([wc])
    loop = unit.frequency_response(om) * plant.frequency_response(om, sample_period)
    return Controller(gain=float(1 / abs(loop[0])), sections=tuple(secs),
                      sample_period=sample_period)


def loop_frequency_response(controller: Controller, plant: DiscreteStateSpace,
                            omega: ArrayLike) -> NDArray[np.complex128]:
    """Return the loop gain L = C P at ``omega`` [rad/s] for a discretised plant."""
    om = np.asarray(omega, dtype=float)
    return controller.frequency_response(om) * plant.frequency_response(
        om, controller.sample_period)


def closed_loop_poles(controller: Controller, plant: DiscreteStateSpace) -> NDArray[np.complex128]:
    """Return the poles of the unity-feedback loop (controller on e = r - y)."""
    ac, bc, cc, dc = controller.state_space()
    n, m = plant.a.shape[0], ac.shape[0]
    a = np.zeros((n + m, n + m))
    a[:n, :n] = plant.a - dc * np.outer(plant.b, plant.c)
    a[:n, n:] = np.outer(plant.b, cc)
    a[n:, :n] = -np.outer(bc, plant.c)
    a[n:, n:] = ac
    return np.asarray(np.linalg.eigvals(a), dtype=np.complex128)


def loop_margins(controller: Controller, plant: DiscreteStateSpace, *,
                 points: int = 4000) -> LoopMargins:
    """Gain, phase and stability margins of the discrete loop with delay and lag included.

    The loop's frequency response is evaluated on a dense logarithmic grid from 1 Hz to just
    below Nyquist and handed to python-control's ``stability_margins`` (as an FRD, which
    avoids the ill-conditioned polynomial products of a high-order transfer function).

    Args:
        controller: The feedback controller.
        plant: Discretised plant (with its input dynamics).
        points: Number of frequency points.

    Returns:
        The margins and whether the closed loop is stable (from its poles).
    """
    import control

    tau = controller.sample_period
    p = plant
    omega = np.logspace(np.log10(2 * math.pi), np.log10(math.pi / tau * (1 - 1e-6)), points)
    resp = loop_frequency_response(controller, p, omega)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        gm, pm, sm, wg, wp, _ = control.stability_margins(control.frd(resp, omega))
    stable = bool(np.all(np.abs(closed_loop_poles(controller, p)) < 1))
    return LoopMargins(
        gain_margin_db=float(20 * np.log10(gm)) if np.isfinite(gm) and gm > 0 else math.inf,
        phase_margin=float(pm),
        stability_margin=float(sm),
        gain_crossover_frequency=float(wp / (2 * math.pi)),
        phase_crossover_frequency=float(wg / (2 * math.pi)),
        closed_loop_stable=stable,
    )
