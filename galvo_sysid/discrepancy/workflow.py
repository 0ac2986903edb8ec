"""The discrepancy workflow: name the effects a plant model misses, add them in turn.

:func:`find_discrepancy` compares the model with the moves
(:class:`~galvo_sysid.discrepancy.compare.Comparison`), fits and scores every candidate effect
(:mod:`galvo_sysid.discrepancy.candidates`) and accepts the best when its score exceeds
``threshold`` and it closes at least a quarter of the gap. The accepted effect is added to
the model, the effects added so far are refitted together, and the search repeats while the
gap stays above the noise, so several effects are found in turn. Where the model disagrees
before and after is :func:`~galvo_sysid.discrepancy.localise.localise`.

Every run ends in a verdict (:data:`~galvo_sysid.discrepancy.settings.VERDICTS`): ``named``
when the effects added leave at most ``tolerance`` noise gaps; ``unexplained`` when a
significant gap (above the noise gap) remains that no library effect explains, with where
it sits and how large it is (:class:`Remaining`); ``consistent`` when the given model
explains the moves within the noise. A significant gap is never answered with ``none``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from galvo_sysid.discrepancy.candidates import CandidateFit, _acceptable, _Fitter
from galvo_sysid.discrepancy.compare import Comparison, Diagnostics
from galvo_sysid.discrepancy.fallback import Proposal, propose
from galvo_sysid.discrepancy.localise import Localisation, localise
from galvo_sysid.discrepancy.settings import DEFAULT_THRESHOLD, DEFAULT_TOLERANCE
from galvo_sysid.errors import ConfigurationError
from galvo_sysid.jsonsafe import finite_or_none
from galvo_sysid.model.effects import CANDIDATE_NAMES
from galvo_sysid.model.paper import PAPER_MODEL
from galvo_sysid.model.plant import PlantModel

if TYPE_CHECKING:
    from galvo_sysid.discrepancy.moves import MoveSet

__all__ = [
    'DiscrepancyResult',
    'Remaining',
    'Step',
    'find_discrepancy',
]


@dataclass(frozen=True)
class Remaining:
    """The gap the final model leaves, against the noise floor, and where it sits.

    Attributes:
        gap: Gap of the final model (noise-floor units).
        noise_gap: Largest gap the noise alone gives (three standard deviations).
        significance: (J - J_noise) / sqrt(J_noise): the remaining cost's excess over the
            noise in its standard deviations (about 0 +- 1 for noise alone; the noise gap is
            3).
        significant: Whether the gap exceeds the noise gap.
        residual_rms: RMS of the mean residual over the record and the target angles [deg],
            each group's start offset and start velocity (a straight line) removed.
        floor_rms: RMS of that residual's noise floor (standard error of the mean) [deg].
        where: Where the final model still disagrees (frequency, move phase, move size).
    """

    gap: float
    noise_gap: float
    significance: float
    significant: bool
    residual_rms: float
    floor_rms: float
    where: Localisation

    @property
    def ratio(self) -> float:
        """The gap in noise gaps."""
        return self.gap / self.noise_gap if self.noise_gap > 0 else math.nan

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {'gap': finite_or_none(self.gap), 'noise_gap': finite_or_none(self.noise_gap),
                'ratio': finite_or_none(self.ratio),
                'significance': finite_or_none(self.significance),
                'significant': self.significant,
                'residual_rms_deg': finite_or_none(self.residual_rms),
                'floor_rms_deg': finite_or_none(self.floor_rms),
                'where': self.where.to_dict()}


def _remaining(comp: Comparison, diag: Diagnostics, where: Localisation) -> Remaining:
    """The remaining gap of a model's diagnostics, its significance and size."""
    noise = diag.cost_noise
    significance = (diag.cost - noise) / math.sqrt(noise) if noise > 0 else math.nan
    return Remaining(gap=diag.gap, noise_gap=comp.noise_gap, significance=float(significance),
                     significant=diag.gap > comp.noise_gap,
                     residual_rms=float(np.sqrt(np.mean(diag.detrended_residual**2))),
                     floor_rms=float(np.sqrt(np.mean(diag.detrended_floor**2))), where=where)


@dataclass(frozen=True)
class Step:
    """One effect added by the workflow.

    Attributes:
        effect: Effect name.
        parameters: Its parameters.
        score: Its BIC drop.
        gap_before: Gap of the model before the step.
        gap_after: Gap after.
        whiteness_after: Largest band excess after (noise std units).
        candidates: Every candidate of this round, best first (``none`` included).
        model: The model after the step.
        local_excess: After the step (the effects refitted together), the residual's
            weighted excess over the noise where this effect acts, in noise standard
            deviations.
        local_left: The share of the excess there that it leaves.
        confirmed: Whether every effect added so far leaves a residual consistent with the
            noise where it acts (a step that is not, and that no later step confirms, is
            taken back: :attr:`DiscrepancyResult.tried`).
    """

    effect: str
    parameters: dict[str, float]
    score: float
    gap_before: float
    gap_after: float
    whiteness_after: float
    candidates: tuple[CandidateFit, ...]
    model: PlantModel = field(repr=False, compare=False)
    local_excess: float = 0.0
    local_left: float = 0.0
    confirmed: bool = True

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {'effect': self.effect, 'parameters': dict(self.parameters),
                'score': finite_or_none(self.score),
                'gap_before': finite_or_none(self.gap_before),
                'gap_after': finite_or_none(self.gap_after),
                'whiteness_after': finite_or_none(self.whiteness_after),
                'local_excess': finite_or_none(self.local_excess),
                'local_left': finite_or_none(self.local_left),
                'confirmed': self.confirmed,
                'candidates': [c.to_dict() for c in self.candidates]}


@dataclass(frozen=True)
class DiscrepancyResult:
    """What :func:`find_discrepancy` found.

    Attributes:
        verdict: One of :data:`~galvo_sysid.discrepancy.settings.VERDICTS`: ``named`` (the
            effects added explain the gap, up to ``tolerance`` noise gaps), ``unexplained``
            (the remaining gap is significant and no library effect explains it; any
            effects added explain only part of it) or ``consistent`` (the given model
            explains the moves within the noise).
        effect: The first (most significant) effect added; ``none`` when the model is
            consistent with the moves, ``unexplained`` when no effect was added to a
            significant gap.
        parameters: Its parameters in the final model (empty without an effect).
        gap_before: Gap of the given model.
        gap_after: Gap of the final model (every step added).
        candidates: The first round's candidates, best first (``none`` included).
        rounds: Every round's candidates (the last one found nothing, or stopped at
            ``max_effects``).
        steps: Every effect added, in order (each with its parameters as found in its
            round; ``parameters`` above and ``final_model`` hold the values refitted
            together with the later effects).
        initial_model: The model given.
        final_model: The model with every step added.
        where: Where the given model disagrees with the moves.
        where_after: Where the final model still does.
        threshold: Score a candidate needed.
        noise_gap: Largest gap the noise alone gives (about 0.1 % chance to exceed it).
        moves: Moves compared.
        remaining: The final model's gap against the noise, and where it sits.
        tolerance: Remaining gap (in noise gaps) still counted as explained by named effects.
        tried: Steps taken back: effects that scored and closed part of the gap but left a
            residual inconsistent with the noise where they act, and that no later effect
            made consistent (a good score is no name).
        before: Diagnostics of the given model (for reports).
        after: Diagnostics of the final model.
        proposal: When the verdict is ``unexplained``, the few dictionary terms that explain
            most of the remaining gap (:mod:`.fallback`; None if no term is worth it, or the
            verdict is not ``unexplained``): a proposal, never a name.
    """

    verdict: str
    effect: str
    parameters: dict[str, float]
    gap_before: float
    gap_after: float
    candidates: tuple[CandidateFit, ...]
    rounds: tuple[tuple[CandidateFit, ...], ...]
    steps: tuple[Step, ...]
    initial_model: PlantModel
    final_model: PlantModel
    where: Localisation
    where_after: Localisation
    threshold: float
    noise_gap: float
    moves: int
    remaining: Remaining
    tolerance: float
    tried: tuple[Step, ...]
    before: Diagnostics = field(repr=False, compare=False)
    after: Diagnostics = field(repr=False, compare=False)
    proposal: Proposal | None = None

    @property
    def sentence(self) -> str:
        """The verdict in one sentence (:func:`.report.verdict_sentence`)."""
        from galvo_sysid.discrepancy.report import verdict_sentence

        return verdict_sentence(self)

    def to_dict(self) -> dict[str, Any]:
        """The ``--json`` object.

        Keys: verdict, summary (the verdict's sentence), remaining (the remaining gap, its
        significance and where it sits), effect, parameters, gap_before, gap_after,
        candidates, steps, tried, proposal (the fallback's terms, or None), then where,
        where_after, moves, angles, threshold, noise_gap, tolerance and model (the final
        model).
        """
        from galvo_sysid.model.files import model_to_dict

        return {
            'verdict': self.verdict,
            'summary': self.sentence,
            'remaining': self.remaining.to_dict(),
            'effect': self.effect,
            'parameters': dict(self.parameters),
            'gap_before': finite_or_none(self.gap_before),
            'gap_after': finite_or_none(self.gap_after),
            'candidates': [c.to_dict() for c in self.candidates],
            'steps': [s.to_dict() for s in self.steps],
            'tried': [s.to_dict() for s in self.tried],
            'proposal': None if self.proposal is None else self.proposal.to_dict(),
            'where': self.where.to_dict(),
            'where_after': self.where_after.to_dict(),
            'moves': self.moves,
            'angles': [float(a) for a in self.before.angles],
            'threshold': self.threshold,
            'noise_gap': self.noise_gap,
            'tolerance': self.tolerance,
            'model': model_to_dict(self.final_model),
        }


def find_discrepancy(moves: MoveSet, model: PlantModel = PAPER_MODEL, *,
                     threshold: float = DEFAULT_THRESHOLD, max_effects: int = 3,
                     min_gap: float | None = None, min_improvement: float = 0.25,
                     tolerance: float = DEFAULT_TOLERANCE,
                     effects: Sequence[str] = CANDIDATE_NAMES, fallback: bool = True,
                     progress: Callable[[str], None] | None = None) -> DiscrepancyResult:
    """Compare a model with measured moves, name the missing effects and add them.

    Args:
        moves: The measured moves (at least 3 of each target angle).
        model: The model to start from (default: the nominal plant).
        threshold: Score (BIC drop) a candidate needs to be accepted.
        max_effects: Most effects added.
        min_gap: After an effect is added, the search goes on only while the gap is at
            least this; default :attr:`Comparison.noise_gap` (below it the model explains the
            moves within the noise).
        min_improvement: A candidate is accepted only if it also closes at least this
            fraction of the gap (statistically significant but practically irrelevant
            additions are left out).
        tolerance: After effects were added, a remaining gap up to this many noise gaps
            still counts as explained (verdict ``named``); above it the verdict is
            ``unexplained``.
        effects: Candidate effects to try (of :data:`~galvo_sysid.model.effects.CANDIDATE_NAMES`;
            the fallback's ``proposed_terms`` is never one).
        fallback: When the verdict is ``unexplained``, fit the remaining residual with a few
            terms of a dictionary of functions of the measured motion and current
            (:func:`.fallback.propose`): ``proposal`` of the result.
        progress: Called with a short text before each candidate fit.

    Returns:
        The result; its ``verdict`` says whether effects were named, a significant gap is
        left unexplained or the model is consistent with the moves.

    Raises:
        InvalidDataError: Too few moves.
        ConfigurationError: Unknown effect name or bad settings.
    """
    unknown = [e for e in effects if e not in CANDIDATE_NAMES]
    if unknown:
        raise ConfigurationError(f'unknown candidate effect(s) {unknown}; expected '
                                 f'{CANDIDATE_NAMES}')
    for ok, what, value in ((math.isfinite(threshold), 'the threshold must be finite',
                             threshold),
                            (max_effects >= 0, 'max_effects must be >= 0', max_effects),
                            (0 <= min_improvement < 1, 'min_improvement must be within 0..1',
                             min_improvement),
                            (math.isfinite(tolerance) and tolerance >= 1,
                             'the tolerance must be >= 1 (noise gaps)', tolerance)):
        if not ok:
            raise ConfigurationError(f'{what}, got {value!r}')
    comp = Comparison(moves, model)
    if min_gap is None:
        min_gap = comp.noise_gap
    explained = tolerance * comp.noise_gap          # a gap the verdict counts as explained
    current = model
    steps: list[Step] = []
    where_added: list[int] = []                # index of each step's effect in the model
    first: tuple[CandidateFit, ...] | None = None
    rounds: list[tuple[CandidateFit, ...]] = []
    confirmed: tuple[PlantModel, int, list[int], dict[int, tuple[float, float]]] = (
        model, 0, [], {})
    step_index: list[int] = []                 # the model index of each step's effect
    for round_index in range(max_effects + 1):
        if round_index and (round_index >= max_effects or comp.gap(current) < min_gap):
            break   # enough effects, or the model explains the moves within the noise
        fitter = _Fitter(comp, current)
        fits = [fitter.none()]
        for name in effects:
            if progress is not None:
                progress(f'step {round_index + 1}: fitting {name}')
            fits.append(fitter.candidate(name))
        ranked = tuple(sorted(fits, key=lambda c: -c.score))
        rounds.append(ranked)
        if first is None:
            first = ranked
        gap_now = fits[0].gap
        eligible = [c for c in ranked if c.effect != 'none' and c.score > threshold
                    and c.gap <= (1.0 - min_improvement) * gap_now and not c.implausible]
        if not eligible or max_effects == 0:
            break
        # an effect consistent with the noise where it acts first; else the best one,
        # provisionally: it stays only if a later effect makes both consistent
        best = next((c for c in eligible if _acceptable(c.local_excess, c.local_left, c.gap,
                                                         explained)), eligible[0])
        current = best.model
        index = (len(current.effects) - 1 if best.effect == 'unmodeled_resonance' else
                 [e.name for e in current.effects].index(best.effect))
        if index not in where_added:
            where_added.append(index)
        if len(where_added) > 1:   # several effects now: refit them together, twice
            for _ in range(2):
                for i in where_added:
                    if progress is not None:
                        progress(f'step {round_index + 1}: refitting {current.effects[i].name}')
                    current = _Fitter(comp, current).refine(i)
        checks = {i: _Fitter(comp, current).where_it_acts(i) for i in where_added}
        gap_after = comp.gap(current)
        ok = all(_acceptable(*checks[i], gap_after, explained) for i in where_added)
        excess, left = checks[index]
        step_index.append(index)
        steps.append(Step(effect=best.effect, parameters=current.effects[index].params(),
                          score=best.score, gap_before=gap_now, gap_after=gap_after,
                          whiteness_after=comp.whiteness(current), candidates=ranked,
                          model=current, local_excess=excess, local_left=left, confirmed=ok))
        if ok:
            confirmed = (current, len(steps), list(where_added), checks)
    current, kept, where_added, checks = confirmed
    tried = tuple(steps[kept:])
    steps = [replace(s, confirmed=True, local_excess=checks[i][0], local_left=checks[i][1])
             for s, i in zip(steps[:kept], step_index, strict=False)]
    if steps:
        names = ', '.join(str(current.effects[i]) for i in where_added)
        current = replace(current, description=f'{model.description or "model"} + found '
                                               f'by galvo-sysid discrepancy: {names}')
    assert first is not None
    before = comp.diagnostics(model)
    after = comp.diagnostics(current) if steps else before
    where, where_after = localise(before), localise(after) if steps else None
    remaining = _remaining(comp, after, where_after or where)
    head = steps[0] if steps else None
    if head is None:
        verdict = 'unexplained' if remaining.significant else 'consistent'
        effect = 'none' if verdict == 'consistent' else 'unexplained'
    else:
        verdict = 'named' if remaining.gap <= tolerance * comp.noise_gap else 'unexplained'
        effect = head.effect
    proposal = None
    if fallback and verdict == 'unexplained':
        if progress is not None:
            progress('fallback: fitting dictionary terms')
        proposal = propose(comp, current, threshold=threshold,
                           min_improvement=min_improvement)
    return DiscrepancyResult(
        verdict=verdict, effect=effect,
        parameters=current.effects[where_added[0]].params() if head else {},
        gap_before=comp.gap(model), gap_after=comp.gap(current), candidates=first,
        rounds=tuple(rounds), steps=tuple(steps), initial_model=model, final_model=current,
        where=where, where_after=where_after or where, threshold=threshold,
        noise_gap=comp.noise_gap, moves=moves.moves, remaining=remaining,
        tolerance=tolerance, tried=tried, before=before, after=after, proposal=proposal)
