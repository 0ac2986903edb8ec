"""The discrepancy report: figures and text of a discrepancy result.

The result is a :class:`~galvo_sysid.discrepancy.workflow.DiscrepancyResult`.

:func:`write_report` fills a directory with

- ``spectra.png``: each target angle's mean residual spectrum before (the given model) and
  after (every effect found added), with the noise floor of the mean,
- ``moves.png``: measured vs simulated mean moves and their residuals before/after, with the
  residual's noise floor (standard error of the mean),
- ``candidates.png``: the candidates' scores (BIC drop) of every round, with the threshold
  (the effect added green, one tried and taken back orange),
- ``where.png``: the excess over the noise by frequency band, by phase of the move and by
  move size, before and after,
- ``summary.txt`` (:func:`format_result`), ``result.json`` (the ``--json`` object) and
  ``model.yaml`` (the augmented model),
- ``proposal.yaml`` when the fallback proposed dictionary terms: a model file, the
  augmented model plus the terms as the ``proposed_terms`` effect (a proposal, not a named
  effect; its header says so), to load with ``--model``.

Plots use matplotlib's Agg backend (no display needed).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from galvo_sysid.discrepancy.candidates import _acceptable
from galvo_sysid.jsonsafe import json_safe
from galvo_sysid.model.effects import EFFECTS
from galvo_sysid.model.files import save_model

if TYPE_CHECKING:
    import os

    from galvo_sysid.discrepancy.localise import Localisation
    from galvo_sysid.discrepancy.workflow import DiscrepancyResult

__all__ = ['format_result', 'verdict_sentence', 'write_report']

def _params(params: dict[str, float], sample_period: float, effect: str) -> str:
    """An effect's parameters with their units (the registry's) and a readable form."""
    kind = EFFECTS.get(effect)
    units = {p.name: p.unit for p in kind.parameters} if kind is not None else {}
    parts = []
    for k, v in params.items():
        unit = units.get(k, '')
        text = f'{k}={v:.4g}' + (f' {unit}' if unit else '')
        if k == 'delay':
            text += f' ({v / sample_period:.3f} tau)'
        if k == 'natural_frequency':
            text += f' ({v / (2 * math.pi):.4g} Hz)'
        if k == 'bandwidth' and v > 0:
            text += f' (lag {1 / (2 * math.pi * v) / sample_period:.3f} tau)'
        parts.append(text)
    return ', '.join(parts)


def _added(result: DiscrepancyResult) -> str:
    """The effects the workflow added, with their final parameters."""
    t = result.initial_model.sample_period
    added = [e for e in result.final_model.effects if e not in result.initial_model.effects]
    return ' and '.join(f'{e.name} ({_params(e.params(), t, e.name)})' for e in added)


def verdict_sentence(result: DiscrepancyResult) -> str:
    """The verdict in one sentence: named, unexplained or consistent, with the numbers."""
    r = result.remaining
    noise = f'noise alone stays below {r.noise_gap:.2g}'
    if result.verdict == 'consistent':
        return (f'consistent: the model explains the moves within the noise (gap '
                f'{r.gap:.3g}; {noise}).')
    if result.verdict == 'named':
        names = _added(result)
        verb = 'explain' if ' and ' in names else 'explains'
        rest = (f'; the {r.gap:.3g} left is {r.ratio:.1f} noise gaps, within the tolerance '
                f'of {result.tolerance:g}' if r.significant else '')
        return (f'named: {names} {verb} the gap ({result.gap_before:.3g} -> {r.gap:.3g}; '
                f'{noise}{rest}).')
    partly = (f' (after {_added(result)}, which explained part of it: '
              f'{result.gap_before:.3g} -> {r.gap:.3g})' if result.steps else '')
    return (f'unexplained: a gap of {r.gap:.3g} remains ({r.ratio:.1f} x the noise gap, '
            f'{r.significance:.0f} noise std; mean residual {r.residual_rms:.2g} deg RMS '
            f'against a floor of {r.floor_rms:.2g} deg) that no library effect explains'
            f'{partly}: {r.where.phrase()}.')


def format_result(result: DiscrepancyResult, *, source: str = '') -> str:
    """The readable text ``galvo-sysid discrepancy`` prints without ``--json``."""
    t = result.initial_model.sample_period
    d = result.before
    angles = ', '.join(f'{a:+g}' for a in d.angles)
    lines = []
    head = f'{source}: ' if source else ''
    lines.append(f'{head}{result.moves} moves at {len(d.angles)} target angles ({angles} deg)')
    lines.append(f'model: {result.initial_model.description or result.initial_model}')
    lines.append('')
    lines.append(f'gap of the model: {result.gap_before:.3g}  (RMS of the unexplained mean '
                 f'residual in noise-floor units; noise alone stays below '
                 f'{result.noise_gap:.2g})')
    lines.append('where the model and the moves disagree:')
    lines.extend('  ' + line for line in result.where.summary())
    lines.append('')
    lines.append(f'candidates (score = BIC drop, above {result.threshold:g}; where it acts: '
                 f'excess in noise std, share of the excess left):')
    explained = result.tolerance * result.noise_gap
    for c in result.candidates:
        params = _params(c.parameters, t, c.effect) if c.parameters else '-'
        ok = _acceptable(c.local_excess, c.local_left, c.gap, explained)
        left = f'{100 * c.local_left:5.3g} %' if math.isfinite(c.local_left) else '    -  '
        local = ('' if c.effect == 'none' else
                 f'   where it acts {c.local_excess:8.3g} sd, left {left}'
                 f' {"ok" if ok else "NO"}')
        lines.append(f'  {c.effect:<20} {c.score:>12.4g}   gap after {c.gap:7.3g}   '
                     f'white {c.whiteness:7.3g}{local}   {params}'
                     + (f'   (implausible: {c.implausible})' if c.implausible else ''))
    lines.append('')
    lines.append(f'verdict: {verdict_sentence(result)}')
    if result.verdict == 'unexplained':
        lines.extend(_mode_hint(result))
        lines.extend(_proposal(result))
    if result.steps:
        head = 'found' if result.verdict == 'named' else 'added, explaining part of the gap'
        lines.append(f'{head}: {result.effect} ({_params(result.parameters, t, result.effect)})')
        for i, s in enumerate(result.steps, start=1):
            lines.append(f'  step {i}: {s.effect} ({_params(s.parameters, t, s.effect)}), score '
                         f'{s.score:.4g}, gap {s.gap_before:.3g} -> {s.gap_after:.3g}')
        final = [e for e in result.final_model.effects if e not in
                 result.initial_model.effects]
        lines.append('  final effects (refitted together): ' + '; '.join(
            f'{e.name} ({_params(e.params(), t, e.name)})' for e in final))
    for s in result.tried:
        params = _params(s.parameters, t, s.effect)
        lines.append(f'tried and taken back: {s.effect} ({params}), score {s.score:.4g}'
                     f', gap {s.gap_before:.3g} -> {s.gap_after:.3g}, but it leaves '
                     f'{100 * s.local_left:.3g} % of the excess where it acts '
                     f'({s.local_excess:.3g} noise std)')
    lines.append(f'gap: {result.gap_before:.3g} -> {result.gap_after:.3g}')
    if result.steps:
        lines.append('where the final model still disagrees:')
        lines.extend('  ' + line for line in result.where_after.summary())
    return '\n'.join(lines) + '\n'


def _proposal(result: DiscrepancyResult) -> list[str]:
    """The fallback's proposal: one sentence, then each term with its coefficient."""
    prop = result.proposal
    if prop is None:
        return ['  fallback: no term of the dictionary is worth its parameters']
    lines = [f'  fallback: {prop.sentence}']
    for t in prop.terms:
        phase = f', phase {t.phase:.3g} rad' if math.isfinite(t.phase) else ''
        lines.append(f'    {t.coefficient:.4g} {t.unit} * {t.label} on the {t.side}{phase}'
                     f' (score {t.score:.4g}, gap after {t.gap_after:.3g})')
    return lines


def _mode_hint(result: DiscrepancyResult) -> list[str]:
    """A hint when the unexplained residual sits at the model's own modes."""
    freqs = [w / (2 * math.pi) for w in result.initial_model.modal.natural_frequencies]
    hits = sorted({f for b in result.remaining.where.main_bands for f in freqs
                   if b.low <= f <= b.high})
    if not hits:
        return []
    where = ', '.join(f'{f / 1e3:.3g} kHz' for f in hits)
    return [f'  the residual sits at the mode(s) of the model at {where}: their modal '
            f'parameters may be off or drifting - identify them (galvo-sysid identify)']


# --------------------------------------------------------------------------- figures


def _pyplot() -> Any:
    import matplotlib as mpl

    mpl.use('Agg')
    import matplotlib.pyplot as plt

    return plt


def _save(plt: Any, fig: Any, path: Path) -> None:
    """Lay out a figure, write it (100 dpi) and close it."""
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _grid(n: int) -> tuple[int, int]:
    cols = 2 if n > 1 else 1
    return math.ceil(n / cols), cols


def _plot_spectra(result: DiscrepancyResult, path: Path) -> None:
    plt = _pyplot()
    before, after = result.before, result.after
    n = before.angles.shape[0]
    rows, cols = _grid(n)
    fig, axes = plt.subplots(rows, cols, figsize=(6 * cols, 2.8 * rows), squeeze=False,
                             sharex=True)
    f = before.frequencies
    for g in range(rows * cols):
        ax = axes[g // cols][g % cols]
        if g >= n:
            ax.set_visible(False)
            continue
        ax.loglog(f, before.residual_spectrum[g], color='tab:red', lw=0.8,
                  label=f'before (gap {before.group_gaps[g]:.2g})')
        if result.steps:
            ax.loglog(f, after.residual_spectrum[g], color='tab:green', lw=0.8,
                      label=f'after (gap {after.group_gaps[g]:.2g})')
        ax.loglog(f, before.noise_spectrum[g], color='0.3', ls='--', lw=1.0,
                  label='noise floor')
        ax.set_title(f'{before.angles[g]:+g} deg ({before.counts[g]} moves)', fontsize=9)
        ax.set_ylabel('|mean residual| [deg]', fontsize=8)
        ax.grid(True, which='both', alpha=0.3)
        ax.legend(fontsize=7, loc='upper right')
        if g // cols == rows - 1:
            ax.set_xlabel('frequency [Hz]')
    fig.suptitle('Mean residual spectra (random ringing of the modes projected out) vs the '
                 'noise floor of the mean', fontsize=10)
    _save(plt, fig, path)


def _plot_moves(result: DiscrepancyResult, path: Path) -> None:
    plt = _pyplot()
    before, after = result.before, result.after
    n = before.angles.shape[0]
    fig, axes = plt.subplots(2, n, figsize=(3.2 * n, 5.5), squeeze=False)
    t = before.time * 1e3
    for g in range(n):
        ax = axes[0][g]
        ax.plot(t, before.measured[g], color='k', lw=1.2, label='measured')
        ax.plot(t, before.simulated[g], color='tab:red', lw=0.8, ls='--', label='model')
        if result.steps:
            ax.plot(t, after.simulated[g], color='tab:green', lw=0.8, ls=':',
                    label='augmented')
        ax.set_title(f'{before.angles[g]:+g} deg', fontsize=9)
        ax.set_xlabel('time [ms]', fontsize=8)
        if g == 0:
            ax.set_ylabel('angle - start [deg]', fontsize=8)
            ax.legend(fontsize=7)
        ax2 = axes[1][g]
        fl = before.residual_floor[g]
        ax2.fill_between(t, -2 * fl, 2 * fl, color='0.85', label='+-2 noise floor')
        ax2.plot(t, before.residual[g], color='tab:red', lw=0.8, label='before')
        if result.steps:
            ax2.plot(t, after.residual[g], color='tab:green', lw=0.8, label='after')
        ax2.set_xlabel('time [ms]', fontsize=8)
        if g == 0:
            ax2.set_ylabel('mean residual [deg]', fontsize=8)
            ax2.legend(fontsize=7)
        for a in (ax, ax2):
            a.tick_params(labelsize=7)
            a.grid(True, alpha=0.3)
    fig.suptitle('Mean of the moves: measured vs simulated (driven by the measured current)',
                 fontsize=10)
    _save(plt, fig, path)


def _plot_candidates(result: DiscrepancyResult, path: Path) -> None:
    plt = _pyplot()
    rounds = list(result.rounds)
    fig, axes = plt.subplots(1, len(rounds), figsize=(4.5 * len(rounds), 3.6), squeeze=False)
    for i, cands in enumerate(rounds):
        ax = axes[0][i]
        names = [c.effect for c in cands]
        scores = [c.score for c in cands]
        added = [*result.steps, *result.tried]      # one per round that added an effect
        step = added[i] if i < len(added) else None
        accepted = i < len(result.steps)
        color = 'tab:green' if accepted else 'tab:orange'
        colors = [color if step is not None and c.effect == step.effect else 'tab:gray'
                  for c in cands]
        ax.barh(range(len(names)), scores, color=colors)
        ax.set_yticks(range(len(names)), names, fontsize=8)
        ax.invert_yaxis()
        ax.set_xscale('symlog', linthresh=10)
        ax.axvline(result.threshold, color='tab:red', ls='--', lw=1, label='threshold')
        ax.set_xlabel('score (BIC drop)', fontsize=8)
        if step is not None:
            title = (f'round {i + 1}: {step.effect} added' if accepted else
                     f'round {i + 1}: {step.effect} tried, taken back')
        elif cands[0].effect != 'none' and cands[0].score > result.threshold:
            title = f'round {i + 1}: nothing added (no candidate passes the checks)'
        else:
            title = f'round {i + 1}: nothing added'
        ax.set_title(title, fontsize=9)
        ax.grid(True, axis='x', alpha=0.3)
        if i == 0:
            ax.legend(fontsize=7)
    fig.suptitle(f'Candidate effects - verdict: {result.verdict}', fontsize=10)
    _save(plt, fig, path)


def _plot_where(result: DiscrepancyResult, path: Path) -> None:
    plt = _pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.4))
    pairs: list[tuple[str, Localisation, str]] = [('before', result.where, 'tab:red')]
    if result.steps:
        pairs.append(('after', result.where_after, 'tab:green'))
    width = 0.4
    for j, (label, loc, color) in enumerate(pairs):
        centres = np.array([math.sqrt(max(b.low, 1.0) * b.high) for b in loc.bands])
        axes[0].semilogx(centres, [b.excess for b in loc.bands], 'o-', color=color,
                         label=label, ms=3)
        x = np.arange(len(loc.phases)) + (j - 0.5 * (len(pairs) - 1)) * width
        axes[1].bar(x, list(loc.phases.values()), width=width, color=color, label=label)
        axes[2].loglog(loc.angles, np.maximum(loc.gaps, 1e-3), 'o-', color=color, label=label)
    axes[0].axhline(5, color='0.4', ls='--', lw=1, label='significant')
    axes[0].set_xlabel('frequency [Hz]')
    axes[0].set_ylabel('excess of z^2 [noise std]')
    axes[0].set_yscale('symlog', linthresh=5)
    axes[0].set_ylim(bottom=-5)
    axes[0].set_title('by frequency band', fontsize=9)
    axes[1].set_xticks(range(len(result.where.phases)), list(result.where.phases), fontsize=8)
    axes[1].set_ylabel('share of the excess per sample')
    axes[1].set_title('by phase of the move', fontsize=9)
    axes[2].set_xlabel('|target angle| [deg]')
    axes[2].set_ylabel('gap')
    axes[2].set_title(f'by move size: {result.where.size_trend}', fontsize=9)
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    _save(plt, fig, path)


def write_report(result: DiscrepancyResult, directory: str | os.PathLike[str], *,
                 source: str = '') -> list[Path]:
    """Write the report's figures, summary, JSON and augmented model; return the files.

    Args:
        result: What :func:`~galvo_sysid.discrepancy.workflow.find_discrepancy` found.
        directory: Report directory (created if needed).
        source: Name of the data (e.g. the bag) for the summary.
    """
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    for name, plot in (('spectra.png', _plot_spectra), ('moves.png', _plot_moves),
                       ('candidates.png', _plot_candidates), ('where.png', _plot_where)):
        plot(result, out / name)
        files.append(out / name)
    summary = out / 'summary.txt'
    summary.write_text(format_result(result, source=source), encoding='utf-8')
    files.append(summary)
    data = out / 'result.json'
    data.write_text(json.dumps(json_safe(result.to_dict()), indent=1, allow_nan=False) + '\n',
                    encoding='utf-8')
    files.append(data)
    files.append(save_model(result.final_model, out / 'model.yaml'))
    if result.proposal is not None:
        proposal = out / 'proposal.yaml'
        tmp = proposal.with_name('.proposal.yaml.tmp')
        tmp.write_text(result.proposal.to_yaml(result.final_model), encoding='utf-8')
        tmp.replace(proposal)
        files.append(proposal)
    return files

