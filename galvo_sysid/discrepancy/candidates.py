"""The candidate effects: each one fitted to the moves on top of a model, and scored.

Each candidate of :data:`~galvo_sysid.model.effects.EFFECT_NAMES` is fitted (its parameters
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

__all__ = ['LOCAL_LEFT', 'LOCAL_SIGMA', 'MAX_DAMPING', 'CandidateFit']

LOCAL_SIGMA = 5.0
"""An effect's residual is consistent with the noise where it acts if its weighted excess
there is at most this many noise standard deviations ..."""

LOCAL_LEFT = 0.05
"""... or if it leaves at most this share of the excess there (a large effect modelled
slightly imperfectly, e.g. Coulomb friction's stick-slip: its excess stands out from the
noise but is a small fraction of what the effect explained; right effects leave below 1 %
on simulated data, wrong ones 15 % to 100 %)."""

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
            return 'delay', self.base.base_delay + np.linspace(0.0, 4.0, 17) * t, same, same
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
        key, grid, value, _ = self._scalar_spec(name)
        cost = self._cost_of(name)
        x, _ = _scalar_search(lambda x: cost({key: value(x)}), grid)
        return {key: value(x)}, 1

    def refine(self, index: int) -> PlantModel:
        """The base model with effect ``index`` refitted locally, the others held."""
        effect = self.base.effects[index]
        params = effect.params()
        cost = self._cost_of(effect.name, index)
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
        excess, left = _where_it_acts(self.base_resid, resid)
        return CandidateFit(effect=name, parameters=params, n_parameters=p, cost=cost,
                            score=score, gap=self.comp.gap(model),
                            whiteness=self.comp.whiteness(model), local_excess=excess,
                            local_left=left, implausible=self.implausible(name, params),
                            model=model)

    def implausible(self, name: str, params: dict[str, float]) -> str:
        """Why fitted parameters are not physically plausible ('' if they are)."""
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
