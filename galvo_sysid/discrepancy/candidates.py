"""The candidate effects: each one fitted to the moves on top of a model, and scored.

Each candidate of :data:`~galvo_sysid.model.effects.CANDIDATE_NAMES` is fitted (its parameters
minimise the comparison's cost J, see :mod:`galvo_sysid.discrepancy.compare`) and scored by
the drop of the Bayesian information criterion, score = 2 (J_model - J_candidate) - p ln(n)
(p fitted parameters, n real data points; the unmodelled resonance pays 2 ln(bins) more for
picking its frequency). The residual's whiteness (largest band excess of z^2) is reported
next to it. One-parameter effects are searched on a grid and refined; the unmodelled
resonance scans (omega, zeta) with its residue solved linearly, then refines all three.

A good score is not enough to name an effect (issue 14): each fit also says whether it
leaves a residual consistent with the noise where it acts (:func:`.spectra._where_it_acts`:
the weighted excess there in noise standard deviations, and the share of the excess it
leaves) and whether its parameters are physically plausible (a resonance needs a damping
ratio up to :data:`MAX_DAMPING` away from the search's bounds, a frequency inside the
searched band and away from the model's own modes: a resonance there says that a mode of
the model is off, which identification, not an added effect, answers). Which candidate is
accepted is the workflow's choice (:mod:`galvo_sysid.discrepancy.workflow`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.optimize import minimize, minimize_scalar

from galvo_sysid.discrepancy.plant import mode_pulse_responses
from galvo_sysid.discrepancy.spectra import (
    _fft_conv,
    _second_difference_spectrum,
    _stack,
    _where_it_acts,
)
from galvo_sysid.errors import ConfigurationError
from galvo_sysid.jsonsafe import finite_or_none
from galvo_sysid.model.effects import Effect
from galvo_sysid.model.plant import PlantModel

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from galvo_sysid.discrepancy.compare import Comparison

__all__ = ['LOCAL_LEFT', 'LOCAL_LEFT_EXPLAINED', 'LOCAL_SIGMA', 'MAX_DAMPING', 'CandidateFit']

LOCAL_SIGMA = 5.0
"""An effect's residual is consistent with the noise where it acts if its weighted excess
there is at most this many noise standard deviations ..."""

LOCAL_LEFT = 0.01
"""... or if it leaves at most this share of the excess there (a large effect modelled
slightly imperfectly, e.g. Coulomb friction's stick-slip: its excess stands out from the
noise but is a small fraction of what the effect explained; right effects leave below
0.5 % on simulated data, also from the independent simulator of test/discrepancy/heldout.py,
wrong ones 2 % to 100 %: an input delay standing in for a narrower amplifier 3-5 %, a pivot
spring and a long cogging period together for a hardening spring 1-2 %)."""

LOCAL_LEFT_EXPLAINED = 0.05
"""An effect that brings the whole gap within the verdict's tolerance (``named``) may leave up
to this share where it acts: Coulomb friction of 10 mA leaves 1.3-1.4 % there in one case of
five (its stick-slip follows the current noise, which the record does not hold) while the
whole residual is at the noise gap. Wrong candidates that pass the plausibility checks leave
more than 2 noise gaps overall."""

MAX_DAMPING = 0.25
"""Largest damping ratio of a plausible unmodelled resonance (fits that pass for other
effects, such as viscous friction or a delay, come out at 0.4-0.95)."""

_MODE_CLEARANCE = 2.0
"""An unmodelled resonance within this many frequency bins of a mode of the model is that
mode being off, not a new one."""

_MAX_RESONANCE = 0.95
"""Highest unmodelled resonance searched, as a fraction of the Nyquist frequency."""

_MIN_DAMPING = 1e-3
"""Smallest damping ratio an unmodelled resonance may be given (below it the fit is a
free sinusoid that chases noise rather than a mechanical mode)."""


@dataclass(frozen=True)
class CandidateFit:
    """One candidate effect fitted to the data.

    Attributes:
        effect: Effect name (``none``: the model as it is).
        parameters: Fitted parameters (see :data:`~galvo_sysid.model.effects.EFFECTS`).
        n_parameters: Parameters fitted.
        cost: J of the augmented model.
        score: BIC drop against the model without the candidate (0 for ``none``).
        gap: Gap of the augmented model.
        whiteness: Largest band excess of the augmented model's residual (noise standard
            deviations; noise alone stays below about 4).
        model: The augmented model.
        local_excess: The residual's weighted excess over the noise where the effect acts,
            in noise standard deviations (about 0 +- 1 for noise).
        local_left: The share of the excess there that the effect leaves.
        implausible: Why the fitted parameters are not physically plausible ('' if they
            are).
    """

    effect: str
    parameters: dict[str, float]
    n_parameters: int
    cost: float
    score: float
    gap: float
    whiteness: float
    model: PlantModel = field(repr=False, compare=False)
    local_excess: float = 0.0
    local_left: float = 0.0
    implausible: str = ''

    @property
    def consistent_where_it_acts(self) -> bool:
        """Whether it leaves a residual consistent with the noise where it acts."""
        return _consistent(self.local_excess, self.local_left)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: effect, score, parameters, cost, gap, whiteness, where it acts."""
        return {'effect': self.effect, 'score': finite_or_none(self.score),
                'parameters': dict(self.parameters), 'cost': finite_or_none(self.cost),
                'gap': finite_or_none(self.gap), 'whiteness': finite_or_none(self.whiteness),
                'local_excess': finite_or_none(self.local_excess),
                'local_left': finite_or_none(self.local_left),
                'consistent_where_it_acts': self.consistent_where_it_acts,
                'implausible': self.implausible}


def _consistent(excess: float, left: float) -> bool:
    """The test of :attr:`CandidateFit.consistent_where_it_acts`."""
    return excess <= LOCAL_SIGMA or left <= LOCAL_LEFT


def _acceptable(excess: float, left: float, gap: float, explained: float) -> bool:
    """Whether an effect is consistent with the noise where it acts, for the workflow: as
    :func:`_consistent`, or leaving at most :data:`LOCAL_LEFT_EXPLAINED` there when the gap
    with it is at most ``explained`` (the verdict's tolerance)."""  # noqa: D205, D209
    return _consistent(excess, left) or (gap <= explained and left <= LOCAL_LEFT_EXPLAINED)


_PERIODIC = ('cogging_torque', 'encoder_cyclic_error')
"""Effects periodic in the angle: amplitude, period [deg], phase [rad]."""


def _periodic_params(period: float, sine: float, cosine: float) -> dict[str, float]:
    """Amplitude, period and phase of sine sin(theta) + cosine cos(theta)."""
    return {'amplitude': math.hypot(sine, cosine), 'period': period,
            'phase': math.atan2(cosine, sine)}


def _replace_effect(model: PlantModel, index: int, params: dict[str, float]) -> PlantModel:
    """The model with its effect ``index`` given new parameters."""
    effects = list(model.effects)
    effects[index] = Effect.create(effects[index].name, params)
    return replace(model, effects=tuple(effects))


def _scalar_search(objective: Callable[[float], float], grid: NDArray[np.float64]) -> tuple[
        float, float]:
    """Minimise a 1-D objective: coarse grid, then bounded refinement around the best."""
    values = np.array([objective(float(x)) for x in grid])
    best = int(np.argmin(values))
    lo = float(grid[max(best - 1, 0)])
    hi = float(grid[min(best + 1, len(grid) - 1)])
    x_best, f_best = float(grid[best]), float(values[best])
    if hi > lo:
        res = _bounded(objective, lo, hi)
        if float(res.fun) < f_best:
            x_best, f_best = float(res.x), float(res.fun)
    return x_best, f_best


def _bounded(objective: Callable[[float], float], lo: float, hi: float) -> Any:
    """Bounded scalar minimisation of ``objective`` on [lo, hi] (scipy's result)."""
    return minimize_scalar(objective, bounds=(lo, hi), method='bounded',
                           options={'xatol': 1e-4 * (hi - lo)})


def _nelder_mead(objective: Callable[[NDArray[np.float64]], float], x0: NDArray[np.float64],
                 *, steps: tuple[float, float, float], maxiter: int) -> Any:
    """Nelder-Mead from x0 (3,), the initial simplex stepping each coordinate in turn."""
    simplex = x0 + np.array([[0.0, 0.0, 0.0], [steps[0], 0.0, 0.0], [0.0, steps[1], 0.0],
                             [0.0, 0.0, steps[2]]])
    return minimize(objective, x0, method='Nelder-Mead',
                    options={'xatol': 1e-4, 'fatol': 1e-2, 'maxiter': maxiter,
                             'initial_simplex': simplex})


class _Fitter:
    """Fits the candidate effects to the moves, on top of a base model."""

    def __init__(self, comparison: Comparison, base: PlantModel) -> None:
        self.comp = comparison
        self.base = base
        self.base_phys = base.physics()
        self.base_resid = comparison.whitened(base)
        self.base_cost = float(np.sum(self.base_resid * self.base_resid))
        self.max_current = float(np.max(np.abs(comparison.moves.current)))
        enc = comparison.moves.encoder
        self.max_velocity = max(float(np.max(np.abs(np.diff(enc, axis=1)))), 1e-12) / (
            comparison.moves.sample_period)
        self._motion: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None

    def _cost_of(self, name: str, index: int | None = None) -> Callable[[dict[str, float]],
                                                                         float]:
        """Cost of the base model with effect ``name`` set (or effect ``index`` replaced)."""
        def cost(params: dict[str, float]) -> float:
            try:
                if index is None:
                    model = self.base.with_effect(name, params)
                else:
                    model = _replace_effect(self.base, index, params)
            except ConfigurationError:
                return math.inf
            return self.comp.cost(model, ringing=self.base_phys)
        return cost

    def _scalar_spec(self, name: str) -> tuple[str, NDArray[np.float64],
                                               Callable[[float], float],
                                               Callable[[float], float]]:
        """(parameter, search grid, grid value -> parameter, parameter -> grid value)."""
        t = self.base.sample_period

        def same(x: float) -> float:
            return x
        if name == 'input_delay':
            lowest = self.base.base_delay
            if self.base_phys.lag_time_constant != self.base.dynamics.lag_time_constant:
                # an amplifier_bandwidth effect: the lag is the physics' one
                lowest += self.base_phys.lag_time_constant - self.base.dynamics.lag_time_constant
            return 'delay', lowest + np.linspace(0.0, 4.0, 17) * t, same, same
        if name == 'viscous_friction':
            return ('current_per_velocity',
                    np.linspace(0.0, 0.2, 11) * self.max_current / self.max_velocity, same, same)
        if name == 'amplifier_bandwidth':
            # the lag time constant is searched, 0 to 4 samples (0: no lag)
            def bandwidth(x: float) -> float:
                return 1.0 / (2 * math.pi * x) if x > 0 else math.inf

            def lag(v: float) -> float:
                return 1.0 / (2 * math.pi * v) if math.isfinite(v) else 0.0
            return 'bandwidth', np.linspace(0.0, 4.0, 17) * t, bandwidth, lag
        if name == 'gain_change':
            return 'gain_ratio', np.linspace(0.5, 1.5, 21), same, same
        if name == 'coulomb_friction':
            return 'friction_current', np.linspace(0.0, 0.2, 11) * self.max_current, same, same
        if name == 'current_saturation':
            return ('current_limit', np.linspace(0.25, 1.0, 16) * self.max_current, same,
                    same)
        if name == 'pivot_stiffness':
            # the spring's effect grows with w^2: search in w^2, up to 3000 rad/s
            def root(x: float) -> float:
                return math.sqrt(max(x, 1.0))

            def square(v: float) -> float:
                return v * v
            return 'natural_frequency', np.linspace(0.0, 1.0, 16)**2 * 3000.0**2, root, square
        raise ConfigurationError(f'unknown effect {name!r}')

    def fit(self, name: str) -> tuple[dict[str, float], int]:
        """Fitted parameters of one candidate and their number."""
        if name == 'unmodeled_resonance':
            return self._fit_resonance(), 3
        if name in _PERIODIC:
            return self._fit_periodic(name), 3
        key, grid, value, _ = self._scalar_spec(name)
        cost = self._cost_of(name)
        x, _ = _scalar_search(lambda x: cost({key: value(x)}), grid)
        return {key: value(x)}, 1

    def refine(self, index: int) -> PlantModel:
        """The base model with effect ``index`` refitted locally, the others held."""
        effect = self.base.effects[index]
        params = effect.params()
        cost = self._cost_of(effect.name, index)
        if effect.name in _PERIODIC:
            new_model = self._refine_periodic(effect.name, params, cost, steps=(0.005, 0.1, 0.1),
                                              maxiter=40)
            return (self.base if new_model is None else
                    _replace_effect(self.base, index, new_model))
        if effect.name == 'unmodeled_resonance':
            w0, z0, k0 = (params['natural_frequency'], params['damping_ratio'],
                          params['residue'])
            scale = abs(k0) if k0 else 1.0

            def objective(x: NDArray[np.float64]) -> float:
                zeta = z0 * math.exp(float(x[1]))
                if not _MIN_DAMPING <= zeta <= 0.95:
                    return math.inf
                return cost({'natural_frequency': w0 * math.exp(float(x[0])),
                             'damping_ratio': zeta, 'residue': scale * float(x[2])})
            x0 = np.array([0.0, 0.0, k0 / scale])
            res = _nelder_mead(objective, x0, steps=(0.01, 0.1, 0.05), maxiter=80)
            if float(res.fun) >= objective(x0):
                return self.base
            x = res.x
            new = {'natural_frequency': w0 * math.exp(float(x[0])),
                   'damping_ratio': z0 * math.exp(float(x[1])), 'residue': scale * float(x[2])}
            return _replace_effect(self.base, index, new)
        key, grid, value, inverse = self._scalar_spec(effect.name)
        start = inverse(params[key])
        width = float(grid[1] - grid[0])
        lo, hi = max(start - width, float(grid[0])), start + width
        res = _bounded(lambda x: cost({key: value(x)}), lo, hi)
        if float(res.fun) >= cost({key: params[key]}):
            return self.base
        return _replace_effect(self.base, index, {key: value(float(res.x))})

    def _fit_resonance(self) -> dict[str, float]:
        """Scan (omega, zeta) with the residue solved linearly, then refine all three.

        For each grid point the extra mode's response to the groups' mean extended records
        (its ringing from the previous moves included) is fitted to the base model's
        whitened residual by weighted least squares; the best point starts a Nelder-Mead
        refinement of the full model's cost.
        """
        comp = self.comp
        base_phys = self.base_phys
        resid = comp.whitened(base_phys)                  # (G, 2F)
        n = comp.moves.samples
        t = comp.moves.sample_period
        nyquist = math.pi / t
        lowest = 2 * math.pi / (n * t)
        w_max = _MAX_RESONANCE * nyquist
        grid_w, grid_z = np.meshgrid(np.geomspace(2 * lowest, w_max, 64),
                                     np.array([0.003, 0.01, 0.03, 0.1, 0.3]))
        omegas, zetas = grid_w.ravel(), grid_z.ravel()
        length = comp.mean_ext.shape[1]
        pulse = mode_pulse_responses(omegas, zetas, gain=base_phys.gain_ratio,
                                     lag=base_phys.lag_time_constant, delay=base_phys.pure_delay,
                                     sample_period=t, length=length)
        resp = _fft_conv(comp.mean_ext[None, :, :], pulse[:, None, :], length - n, length)
        resp_s = _second_difference_spectrum(resp)                       # (P, G, F)
        num = np.zeros(omegas.shape[0])
        den = np.zeros(omegas.shape[0])
        bases = comp.basis(base_phys)
        for g in range(len(comp.index)):
            m = _stack(resp_s[:, g] * comp.weights[g])                   # (P, 2F)
            m -= (m @ bases[g]) @ bases[g].T
            num += m @ resid[g]
            den += np.sum(m * m, axis=1)
        with np.errstate(divide='ignore', invalid='ignore'):
            k = np.where(den > 0, num / den, 0.0)
        drop = k * num
        best = int(np.argmax(drop))
        w0, z0, k0 = float(omegas[best]), float(zetas[best]), float(k[best])
        scale = abs(k0) if k0 != 0 else 1.0
        cost = self._cost_of('unmodeled_resonance')

        def objective(x: NDArray[np.float64]) -> float:
            omega, zeta = math.exp(x[0]), math.exp(x[1])
            if not (lowest <= omega <= w_max and _MIN_DAMPING <= zeta <= 0.95):
                return math.inf
            return cost({'natural_frequency': omega, 'damping_ratio': zeta,
                         'residue': float(x[2]) * scale})

        x0 = np.array([math.log(w0), math.log(z0), math.copysign(1.0, k0)])
        res = _nelder_mead(objective, x0, steps=(0.03, 0.3, 0.2), maxiter=120)
        x = res.x if float(res.fun) <= objective(x0) else x0
        return {'natural_frequency': math.exp(float(x[0])),
                'damping_ratio': math.exp(float(x[1])),
                'residue': float(x[2]) * scale}

    # ------------------------------------------------------------------ periodic effects

    def _periods(self) -> NDArray[np.float64]:
        """Periods [deg] scanned for an effect periodic in the angle.

        From 4 samples of motion at the fastest speed (shorter periods alias within a sample)
        to the angle the moves span (a longer period shows the moves less than one period: a
        smooth trend over the moves, such as a spring, not a periodic effect), in steps that
        shift the phase over the span by an eighth of a period.
        """
        enc = self.comp.moves.encoder
        span = max(float(enc.max() - enc.min()), 1e-6)
        low = max(4.0 * self.max_velocity * self.comp.moves.sample_period, 1e-3)
        high = max(span, 2.0 * low)
        out = [low]
        while out[-1] < high:
            out.append(out[-1] * (1.0 + min(out[-1] / (8.0 * span), 0.125)))
        return np.asarray(out, dtype=np.float64)

    def _periodic_basis(self, name: str, period: float) -> list[NDArray[np.float64]]:
        """Whitened responses (2, 2F) per group to the sine and cosine parts of the effect.

        Linearised about the measured moves: the cogging torque's current of the measured
        angle, less its value at the start (the holding current takes it), drives the
        mechanics; the encoder's error of the measured angle is added.
        """
        comp = self.comp
        y, vel = self._base_motion()
        k = 2 * math.pi / period
        if name == 'cogging_torque':
            half = 0.5 * k * vel * comp.moves.sample_period
            sinc = np.sinc(half / math.pi)
            theta = k * y + half
            parts = [np.sin(theta) * sinc - np.sin(k * y[:, :1]),
                     np.cos(theta) * sinc - np.cos(k * y[:, :1])]
            h = comp.simulator(self.base_phys)._friction_response()
            means = [np.stack([x[i].mean(axis=0) for i in comp.index]) for x in parts]
            resp = [_fft_conv(mx, h[None, :], 0, mx.shape[1]) for mx in means]
        else:
            parts = [np.sin(k * y), np.cos(k * y)]
            resp = [np.stack([x[i].mean(axis=0) for i in comp.index]) for x in parts]
        spec = [_second_difference_spectrum(r) for r in resp]              # (G, F) each
        bases = comp.basis(self.base_phys)
        out = []
        for g in range(len(comp.index)):
            m = np.stack([_stack(sp[g] * comp.weights[g]) for sp in spec])   # (2, 2F)
            m -= (m @ bases[g]) @ bases[g].T
            out.append(m)
        return out

    def _base_motion(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The measured shaft angle [deg] and velocity [deg/s] per move (cached).

        The measured angle, not the base model's: driven open loop by a current that
        compensates a torque the base model lacks, the model drifts far from the moves
        (0.02 A of cogging: up to a degree), while the encoder is within its noise of the
        angle the effect acts at.
        """
        if self._motion is None:
            sim = self.comp.simulator(self.base_phys)
            y = sim.true_start(self.comp.moves.encoder)
            vel = np.asarray(np.gradient(y, self.comp.moves.sample_period, axis=1),
                             dtype=np.float64)
            self._motion = (y, vel)
        return self._motion

    def _fit_periodic(self, name: str) -> dict[str, float]:
        """Scan the period with the sine and cosine amplitudes solved linearly.

        For each period of :meth:`_periods` the linearised responses are fitted to the base
        model's whitened residual by least squares; the three best periods are refined on
        that linearised fit.
        """
        resid = self.base_resid

        def linear(period: float) -> tuple[float, NDArray[np.float64]]:
            a = np.zeros((2, 2))
            b = np.zeros(2)
            for g, m in enumerate(self._periodic_basis(name, period)):
                a += m @ m.T
                b += m @ resid[g]
            try:
                coef = np.asarray(np.linalg.solve(a, b), dtype=np.float64)
            except np.linalg.LinAlgError:
                return 0.0, np.zeros(2)
            return float(b @ coef), coef

        periods = self._periods()
        drops = np.array([linear(float(p))[0] for p in periods])
        period, drop = float(periods[int(np.argmax(drops))]), float(np.max(drops))
        for best in np.argsort(-drops)[:3]:       # the three best periods, refined
            lo = float(periods[max(best - 1, 0)])
            hi = float(periods[min(best + 1, len(periods) - 1)])
            if hi > lo:
                res = _bounded(lambda x: -linear(math.exp(x))[0], math.log(lo), math.log(hi))
                if -float(res.fun) > drop:
                    period, drop = math.exp(float(res.x)), -float(res.fun)
        coef = linear(period)[1]
        # linearised about the measured moves, the fit is close: on simulated cogging within
        # 0.2 % of the amplitude and 0.1 % of the cost drop of the full model's optimum (the
        # effects refitted together are refined on the full model, :meth:`refine`)
        return _periodic_params(period, float(coef[0]), float(coef[1]))

    def _refine_periodic(self, name: str, params: dict[str, float],
                         cost: Callable[[dict[str, float]], float], *,
                         steps: tuple[float, float, float], maxiter: int) -> dict[
                             str, float] | None:
        """Nelder-Mead on (log period, sine and cosine amplitudes) from ``params``; None if
        it finds nothing better."""  # noqa: D205, D209
        p0, a0, ph0 = params['period'], params['amplitude'], params['phase']
        scale = a0 if a0 > 0 else 1e-6

        def unpack(x: NDArray[np.float64]) -> dict[str, float]:
            return _periodic_params(p0 * math.exp(float(x[0])), scale * float(x[1]),
                                    scale * float(x[2]))

        def objective(x: NDArray[np.float64]) -> float:
            return cost(unpack(x))
        x0 = np.array([0.0, a0 * math.cos(ph0) / scale, a0 * math.sin(ph0) / scale])
        res = _nelder_mead(objective, x0, steps=steps, maxiter=maxiter)
        if not float(res.fun) < objective(x0):
            return None
        return unpack(res.x)

    def candidate(self, name: str) -> CandidateFit:
        """Fit and score one candidate, and check it where it acts."""
        params, p = self.fit(name)
        model = self.base.with_effect(name, params)
        resid = self.comp.whitened(model, ringing=self.base_phys)
        cost = float(np.sum(resid * resid))
        score = 2.0 * (self.base_cost - cost) - p * math.log(self.comp.n_real)
        if name == 'unmodeled_resonance':
            # look-elsewhere: the frequency is picked among about n_bins resolvable ones
            score -= 2.0 * math.log(self.comp.n_bins)
        elif name in _PERIODIC:
            # ... and the period among the scanned ones
            score -= 2.0 * math.log(len(self._periods()))
        excess, left = _where_it_acts(self.base_resid, resid)
        return CandidateFit(effect=name, parameters=params, n_parameters=p, cost=cost,
                            score=score, gap=self.comp.gap(model),
                            whiteness=self.comp.whiteness(model), local_excess=excess,
                            local_left=left, implausible=self.implausible(name, params),
                            model=model)

    def implausible(self, name: str, params: dict[str, float]) -> str:
        """Why fitted parameters are not physically plausible ('' if they are)."""
        if name in _PERIODIC:
            periods = self._periods()
            if not 1.02 * periods[0] < params['period'] < 0.98 * periods[-1]:
                return (f'period {params["period"]:.4g} deg at the edge of the searched '
                        f'{periods[0]:.3g}-{periods[-1]:.3g} deg (a trend over the moves or an '
                        f'alias within a sample, not a periodic effect)')
            return ''
        if name != 'unmodeled_resonance':
            return ''
        comp = self.comp
        w, zeta = params['natural_frequency'], params['damping_ratio']
        bin_w = 2 * math.pi * float(comp.frequencies[0])
        for i, wi in enumerate(self.base_phys.natural_frequencies, start=1):
            if abs(w - wi) < _MODE_CLEARANCE * bin_w:
                return (f"at the model's own mode {i} ({wi / (2 * math.pi):.4g} Hz): that "
                        f'mode is off, not missing')
        if zeta > MAX_DAMPING:
            return (f'damping ratio {zeta:.3g} above {MAX_DAMPING:g}: no resonance (a '
                    f'broad correction standing in for another effect)')
        if zeta <= 1.05 * _MIN_DAMPING:
            return f'damping ratio {zeta:.3g} at the search bound (a free sinusoid)'
        if w >= 0.99 * _MAX_RESONANCE * math.pi / comp.moves.sample_period or w < 2 * bin_w:
            return f'frequency {w / (2 * math.pi):.4g} Hz at the edge of the searched band'
        return ''

    def where_it_acts(self, index: int) -> tuple[float, float]:
        """Where the base model's effect ``index`` acts: (excess, share left) of the base."""
        without = replace(self.base, effects=tuple(
            e for i, e in enumerate(self.base.effects) if i != index))
        ringing = without.physics()
        return _where_it_acts(self.comp.whitened(without, ringing=ringing),
                              self.comp.whitened(self.base, ringing=ringing))

    def none(self) -> CandidateFit:
        """The base model as it is."""
        return CandidateFit(effect='none', parameters={}, n_parameters=0, cost=self.base_cost,
                            score=0.0, gap=self.comp.gap(self.base),
                            whiteness=self.comp.whiteness(self.base), model=self.base)
