"""The discrepancy workflow: name the effects a plant model misses, add them in turn.

:func:`find_discrepancy` compares the model with the moves
(:class:`~galvo_sysid.discrepancy.compare.Comparison`), fits and scores every candidate effect
(:mod:`galvo_sysid.discrepancy.candidates`) and accepts the best when its score exceeds
``threshold`` and it closes at least a quarter of the gap. The accepted effect is added to
the model, the effects added so far are refitted together, and the search repeats while the
gap stays above the noise, so several effects are found in turn. ``none`` is the answer when
no candidate is worth its parameters. Where the model disagrees before and after is
:func:`~galvo_sysid.discrepancy.localise.localise`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

from galvo_sysid.discrepancy.candidates import CandidateFit, _Fitter
from galvo_sysid.discrepancy.compare import Comparison, Diagnostics
from galvo_sysid.discrepancy.localise import Localisation, localise
from galvo_sysid.errors import ConfigurationError
from galvo_sysid.jsonsafe import finite_or_none
from galvo_sysid.model.effects import EFFECT_NAMES, EFFECTS
from galvo_sysid.model.paper import PAPER_MODEL
from galvo_sysid.model.plant import PlantModel

if TYPE_CHECKING:
    from galvo_sysid.discrepancy.moves import MoveSet

__all__ = [
    'DEFAULT_THRESHOLD',
    'DiscrepancyResult',
    'Step',
    'find_discrepancy',
]

DEFAULT_THRESHOLD = 10.0
"""Score (BIC drop) a candidate needs to be accepted."""


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
    """

    effect: str
    parameters: dict[str, float]
    score: float
    gap_before: float
    gap_after: float
    whiteness_after: float
    candidates: tuple[CandidateFit, ...]
    model: PlantModel = field(repr=False, compare=False)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {'effect': self.effect, 'parameters': dict(self.parameters),
                'score': finite_or_none(self.score),
                'gap_before': finite_or_none(self.gap_before),
                'gap_after': finite_or_none(self.gap_after),
                'whiteness_after': finite_or_none(self.whiteness_after),
                'candidates': [c.to_dict() for c in self.candidates]}


@dataclass(frozen=True)
class DiscrepancyResult:
    """What :func:`find_discrepancy` found.

    Attributes:
        effect: The first (most significant) effect added, or ``none``.
        parameters: Its parameters in the final model (empty for ``none``).
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
        before: Diagnostics of the given model (for reports).
        after: Diagnostics of the final model.
    """

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
    before: Diagnostics = field(repr=False, compare=False)
    after: Diagnostics = field(repr=False, compare=False)

    def to_dict(self) -> dict[str, Any]:
        """The ``--json`` object.

        Keys: effect, parameters, gap_before, gap_after, candidates, steps, then where,
        where_after, moves, angles, threshold, noise_gap and model (the final model).
        """
        from galvo_sysid.model.files import model_to_dict

        return {
            'effect': self.effect,
            'parameters': dict(self.parameters),
            'gap_before': finite_or_none(self.gap_before),
            'gap_after': finite_or_none(self.gap_after),
            'candidates': [c.to_dict() for c in self.candidates],
            'steps': [s.to_dict() for s in self.steps],
            'where': self.where.to_dict(),
            'where_after': self.where_after.to_dict(),
            'moves': self.moves,
            'angles': [float(a) for a in self.before.angles],
            'threshold': self.threshold,
            'noise_gap': self.noise_gap,
            'model': model_to_dict(self.final_model),
        }


def find_discrepancy(moves: MoveSet, model: PlantModel = PAPER_MODEL, *,
                     threshold: float = DEFAULT_THRESHOLD, max_effects: int = 3,
                     min_gap: float | None = None, min_improvement: float = 0.25,
                     effects: Sequence[str] = EFFECT_NAMES,
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
        effects: Candidate effects to try.
        progress: Called with a short text before each candidate fit.

    Returns:
        The result; ``effect`` is ``none`` when the model explains the moves.

    Raises:
        InvalidDataError: Too few moves.
        ConfigurationError: Unknown effect name or bad settings.
    """
    unknown = [e for e in effects if e not in EFFECTS]
    if unknown:
        raise ConfigurationError(f'unknown effect(s) {unknown}; expected {EFFECT_NAMES}')
    if not (math.isfinite(threshold) and max_effects >= 0 and 0 <= min_improvement < 1):
        raise ConfigurationError(
            'threshold must be finite, max_effects >= 0 and 0 <= min_improvement < 1')
    comp = Comparison(moves, model)
    if min_gap is None:
        min_gap = comp.noise_gap
    current = model
    steps: list[Step] = []
    where_added: list[int] = []                # index of each step's effect in the model
    first: tuple[CandidateFit, ...] | None = None
    rounds: list[tuple[CandidateFit, ...]] = []
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
        best = ranked[0]
        relevant = best.gap <= (1.0 - min_improvement) * fits[0].gap
        if best.effect == 'none' or best.score <= threshold or not relevant or max_effects == 0:
            break
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
        steps.append(Step(effect=best.effect, parameters=current.effects[index].params(),
                          score=best.score, gap_before=fits[0].gap, gap_after=comp.gap(current),
                          whiteness_after=comp.whiteness(current), candidates=ranked,
                          model=current))
    if steps:
        names = ', '.join(str(current.effects[i]) for i in where_added)
        current = replace(current, description=f'{model.description or "model"} + found '
                                               f'by galvo-sysid discrepancy: {names}')
    assert first is not None
    before = comp.diagnostics(model)
    after = comp.diagnostics(current) if steps else before
    head = steps[0] if steps else None
    return DiscrepancyResult(
        effect=head.effect if head else 'none',
        parameters=current.effects[where_added[0]].params() if head else {},
        gap_before=comp.gap(model), gap_after=comp.gap(current), candidates=first,
        rounds=tuple(rounds), steps=tuple(steps), initial_model=model, final_model=current,
        where=localise(before), where_after=localise(after), threshold=threshold,
        noise_gap=comp.noise_gap, moves=moves.moves, before=before, after=after)
