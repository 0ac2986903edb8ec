"""The data-driven fallback: a sparse model of a gap no library effect explains (issue 14).

When the verdict is ``unexplained``, :func:`propose` fits the remaining residual with a few
terms of a dictionary of physically meaningful functions of the measured motion (angle x
[deg], velocity v [deg/s], acceleration a [deg/s^2] from the encoder; measured current i
[A]): torque-side terms enter as an extra current (their effect on the encoder is the
model's response to that current, linearised about the measured motion as the periodic
candidates are, :meth:`._Fitter._periodic_basis`), reading-side terms are added to the
encoder's reading. Forward selection (orthogonal matching pursuit) takes at most
``max_terms`` terms, each only if its BIC drop (the workflow's score, with the same noise
weighting and look-elsewhere penalties for the term and its period) exceeds the threshold,
so noise alone proposes nothing. The result is a proposal, never a name: the verdict stays
``unexplained``. The dictionary's laws are :data:`galvo_sysid.model.terms.TERMS`, which the
registry's ``proposed_terms`` effect simulates: :meth:`Proposal.model` is the model with the
proposal added, :meth:`Proposal.to_yaml` its model file (``proposal.yaml`` of the report).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from galvo_sysid.discrepancy.candidates import _Fitter
from galvo_sysid.discrepancy.spectra import _fft_conv, _gap, _second_difference_spectrum, _stack
from galvo_sysid.jsonsafe import finite_or_none
from galvo_sysid.model.files import model_to_yaml
from galvo_sysid.model.terms import PERIODIC_TERMS, TERMS

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from galvo_sysid.discrepancy.compare import Comparison
    from galvo_sysid.model.plant import PlantModel

__all__ = ['DEFAULT_MAX_TERMS', 'Proposal', 'ProposedTerm', 'propose']

DEFAULT_MAX_TERMS = 3
"""Most dictionary terms a proposal holds."""

_TORQUE: dict[str, tuple[Callable[..., Any], str]] = {
    t.expression: (t.law, t.unit) for t in TERMS if t.side == 'current'}
_READING: dict[str, tuple[Callable[..., Any], str]] = {
    t.expression: (t.law, t.unit) for t in TERMS if t.side == 'reading'}
"""The dictionary's laws (name: (law of (x, v, a, i), unit of its coefficient)), from
:data:`galvo_sysid.model.terms.TERMS`, which the ``proposed_terms`` effect simulates."""

_COLLINEAR = 0.1
"""A term whose columns keep less than this share of their norm outside the terms already
selected adds nothing they do not say (x|x| and x^2 over moves of one sign)."""


@dataclass(frozen=True)
class ProposedTerm:
    """One dictionary term of a proposal.

    Attributes:
        term: The term's expression (``x^3``; periodic: ``sin(2 pi x / P)``).
        side: ``current`` (an extra current on the mechanics) or ``reading`` (added to the
            encoder's reading).
        coefficient: Its coefficient (periodic: the amplitude).
        unit: The coefficient's unit.
        period: The period [deg] of a periodic term (NaN otherwise).
        phase: A periodic term's phase [rad]: amplitude sin(2 pi x / P + phase).
        gap_after: The gap with this and the earlier terms (linearised).
        score: Its BIC drop when added.
    """

    term: str
    side: str
    coefficient: float
    unit: str
    period: float = math.nan
    phase: float = math.nan
    gap_after: float = math.nan
    score: float = math.nan

    @property
    def label(self) -> str:
        """The term as the text says it, its period filled in."""
        if math.isfinite(self.period):
            return self.term.replace('P)', f'{self.period:.3g} deg)')
        return self.term

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {'term': self.term, 'side': self.side,
                'coefficient': finite_or_none(self.coefficient), 'unit': self.unit,
                'period': finite_or_none(self.period), 'phase': finite_or_none(self.phase),
                'gap_after': finite_or_none(self.gap_after),
                'score': finite_or_none(self.score)}


@dataclass(frozen=True)
class Proposal:
    """The few dictionary terms that explain most of an unexplained gap.

    Attributes:
        terms: The terms, in the order selected (most explaining first).
        gap_before: The gap of the final model without them.
        gap_after: The gap with them (linearised about the measured motion).
        noise_gap: Largest gap the noise alone gives.
    """

    terms: tuple[ProposedTerm, ...]
    gap_before: float
    gap_after: float
    noise_gap: float

    @property
    def share_closed(self) -> float:
        """The share of the gap the terms close, 1 - gap_after / gap_before."""
        return 1.0 - self.gap_after / self.gap_before if self.gap_before > 0 else 0.0

    @property
    def sentence(self) -> str:
        """The proposal in one sentence."""
        parts = [f'{t.label} on the {"encoder reading" if t.side == "reading" else "current"}'
                 for t in self.terms]
        what = ('a term ~ ' if len(parts) == 1 else 'terms ~ ') + ' and '.join(parts)
        verb = 'closes' if len(parts) == 1 else 'close'
        return (f'{what} {verb} {100 * self.share_closed:.0f} % of the remaining gap '
                f'({self.gap_before:.3g} -> {self.gap_after:.3g}): a proposal, not a named '
                f'effect')

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (the ``proposal`` of ``--json``)."""
        return {'terms': [t.to_dict() for t in self.terms],
                'gap_before': finite_or_none(self.gap_before),
                'gap_after': finite_or_none(self.gap_after),
                'share_closed': finite_or_none(self.share_closed),
                'noise_gap': finite_or_none(self.noise_gap), 'sentence': self.sentence}

    def parameters(self) -> dict[str, float]:
        """The ``proposed_terms`` effect's parameters of the terms (:mod:`.model.terms`)."""
        out: dict[str, float] = {}
        for t in self.terms:
            if math.isfinite(t.period):
                prefix = next(f.prefix for f in PERIODIC_TERMS
                              if (f.side, f.expression) == (t.side, t.term))
                out.update({f'{prefix}_amplitude': t.coefficient, f'{prefix}_period': t.period,
                            f'{prefix}_phase': t.phase})
            else:
                out[next(x.parameter for x in TERMS
                         if (x.side, x.expression) == (t.side, t.term))] = t.coefficient
        return out

    def model(self, base: PlantModel) -> PlantModel:
        """``base`` (the model whose residual was fitted) with the terms added as the
        ``proposed_terms`` effect."""  # noqa: D205, D209
        return base.with_effect('proposed_terms', self.parameters())

    def to_yaml(self, base: PlantModel) -> str:
        """The model file of :meth:`model`, its header saying it holds a proposal."""
        lines = ['# galvo-sysid discrepancy: a data-driven proposal, not a named effect.',
                 '# The model the workflow ended with, plus its proposed_terms effect:'] + [
                 f'#   {t.label} on the {t.side}: {t.coefficient:.6g} {t.unit}'
                 + (f', phase {t.phase:.4g} rad' if math.isfinite(t.period) else '')
                 + f' (gap after: {t.gap_after:.4g})' for t in self.terms] + [
                 f'# gap {self.gap_before:.4g} -> {self.gap_after:.4g} (linearised; noise '
                 f'alone stays below {self.noise_gap:.3g}). Load it with --model to check.']
        return '\n'.join(lines) + '\n' + model_to_yaml(self.model(base))


@dataclass(frozen=True)
class _Column:
    """A dictionary entry: whitened columns (k, G 2F) per unit coefficient."""

    term: str
    side: str
    unit: str
    columns: NDArray[np.float64]
    period: float = math.nan
    extra: float = 0.0        # look-elsewhere: 2 ln(periods scanned)


class _Dictionary:
    """The dictionary's columns, linearised about the measured motion of the moves."""

    def __init__(self, comp: Comparison, base: PlantModel) -> None:
        self.fitter = _Fitter(comp, base)
        self.comp = comp
        x, v = self.fitter._base_motion()
        t = comp.moves.sample_period
        self.motion = (x, v, np.gradient(v, t, axis=1), comp.moves.current)
        self.h = comp.simulator(self.fitter.base_phys)._friction_response()
        self.bases = comp.basis(self.fitter.base_phys)

    def whiten(self, parts: list[NDArray[np.float64]], side: str) -> NDArray[np.float64]:
        """Whitened responses (k, G 2F) of per-move parts (M, N) on one side."""
        comp = self.comp
        out = []
        for x in parts:
            if side == 'current':     # less its value at the start (the holding current)
                x = x - x[:, :1]
            mean = np.stack([x[i].mean(axis=0) for i in comp.index])
            if side == 'current':
                mean = _fft_conv(mean, self.h[None, :], 0, mean.shape[1])
            spec = _second_difference_spectrum(mean)
            rows = []
            for g, q in enumerate(self.bases):
                m = _stack(spec[g] * comp.weights[g])
                rows.append(m - (m @ q) @ q.T)
            out.append(np.concatenate(rows))
        return np.stack(out)

    def columns(self) -> list[list[_Column]]:
        """Every family: one entry, or (periodic) one per period scanned."""
        x, v, a, i = self.motion
        fams = [[_Column(name, side, unit, self.whiten([law(x, v, a, i)], side))]
                for side, table in (('current', _TORQUE), ('reading', _READING))
                for name, (law, unit) in table.items()]
        periods = self.fitter._periods()
        extra = 2.0 * math.log(len(periods))
        for fam in PERIODIC_TERMS:
            side, term, unit = fam.side, fam.expression, fam.unit
            factor = i if fam.times_current else 1.0
            fams.append([_Column(term, side, unit, self.whiten(
                [factor * np.sin(2 * math.pi * x / p), factor * np.cos(2 * math.pi * x / p)],
                side), period=float(p), extra=extra) for p in periods])
        return fams


def _solve(a: NDArray[np.float64], r: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
    """Least squares r ~ a.T c: (cost left, c)."""
    c = np.linalg.lstsq(a.T, r, rcond=None)[0]
    e = r - a.T @ c
    return float(e @ e), np.asarray(c, dtype=np.float64)


def _collinear(held: NDArray[np.float64], new: NDArray[np.float64]) -> bool:
    """Whether columns ``new`` lie (nearly) in the span of ``held`` (both (k, D))."""
    q = np.linalg.qr(held.T)[0]
    rest = new.T - q @ (q.T @ new.T)
    return bool(np.all(np.linalg.norm(rest, axis=0) < _COLLINEAR * np.linalg.norm(new, axis=1)))


def propose(comparison: Comparison, model: PlantModel, *, threshold: float,
            min_improvement: float = 0.25,
            max_terms: int = DEFAULT_MAX_TERMS) -> Proposal | None:
    """Fit the model's residual with a few dictionary terms; None if none is worth it.

    Args:
        comparison: The comparison of the workflow (its noise floor and weights).
        model: The model whose residual is fitted (the workflow's final model).
        threshold: Score (BIC drop) a term needs.
        min_improvement: Share of the gap left before it that a term must close (as the
            workflow's effects: a small improvement on a large gap is significant but no
            explanation; a mode of the model that is off gets stand-ins closing 5-10 %).
        max_terms: Most terms selected.

    Returns:
        The proposal, or None when no term passes both.
    """
    dictionary = _Dictionary(comparison, model)
    resid = dictionary.fitter.base_resid.ravel()
    families = dictionary.columns()
    noise = comparison.noise_cost(dictionary.fitter.base_phys)
    log_n = math.log(comparison.n_real)
    choice = 2.0 * math.log(len(families))          # look-elsewhere: which family
    cost = float(resid @ resid)
    gap_before = _gap(cost, noise)
    chosen: list[_Column] = []
    scores: list[float] = []
    gaps: list[float] = []
    taken: set[int] = set()
    for _ in range(max_terms):
        held = [c.columns for c in chosen]
        best: tuple[float, float, int, _Column] | None = None
        for f, family in enumerate(families):
            if f in taken:
                continue
            for col in family:
                if held and _collinear(np.concatenate(held), col.columns):
                    continue
                new = _solve(np.concatenate([*held, col.columns]), resid)[0]
                p = col.columns.shape[0] + (1 if math.isfinite(col.period) else 0)
                score = 2.0 * (cost - new) - p * log_n - col.extra - choice
                if best is None or score > best[0]:
                    best = (score, new, f, col)
        if best is None or best[0] <= threshold or (
                _gap(best[1], noise) > (1.0 - min_improvement) * _gap(cost, noise)):
            break
        score, cost, f, col = best
        taken.add(f)
        chosen.append(col)
        scores.append(score)
        gaps.append(_gap(cost, noise))
    if not chosen:
        return None
    coef = _solve(np.concatenate([c.columns for c in chosen]), resid)[1]
    terms = []
    k = 0
    for col, score, gap in zip(chosen, scores, gaps, strict=True):
        if math.isfinite(col.period):
            s, c = float(coef[k]), float(coef[k + 1])
            terms.append(ProposedTerm(col.term, col.side, math.hypot(s, c), col.unit,
                                      col.period, math.atan2(c, s), gap, score))
        else:
            terms.append(ProposedTerm(col.term, col.side, float(coef[k]), col.unit,
                                      gap_after=gap, score=score))
        k += col.columns.shape[0]
    return Proposal(terms=tuple(terms), gap_before=gap_before, gap_after=gaps[-1],
                    noise_gap=comparison.noise_gap)
