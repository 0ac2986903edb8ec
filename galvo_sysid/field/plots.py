"""Plots people would rather look at than read (matplotlib, no display needed).

- :func:`plot_bode`: identified ``P_mech`` of each window (and the pooled estimate) against
  the reference model, magnitude and phase, like the paper's Fig. 10/11.
- :func:`plot_trends`: each modal parameter's relative deviation from the reference over the
  windows, with its uncertainty, the drift tolerance band, and the verdict's colour where
  that parameter raised it.
- :func:`identification_figure` / :func:`save_identification_plot`: both on one page, for
  ``galvo-sysid identify --plot FILE``.

Figures are built with :class:`matplotlib.figure.Figure` directly (no pyplot, no GUI backend),
so this works on a headless machine and from any thread.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model import REFERENCE_MODEL, TAU, ModalModel

if TYPE_CHECKING:
    import os
    from collections.abc import Sequence

    from numpy.typing import NDArray

    from galvo_sysid.field.results import BagIdentification, WindowResult

__all__ = [
    'LEVEL_COLORS',
    'bode_data',
    'check_plot_path',
    'identification_figure',
    'plot_bode',
    'plot_trends',
    'save_identification_plot',
]

LEVEL_COLORS = {'OK': 'tab:green', 'WARN': 'tab:orange', 'ERROR': 'tab:red',
                'STALE': 'tab:gray', 'MISMATCH': 'tab:purple'}
"""Marker colour of each drift level."""

_FORMATS = {'.png', '.pdf', '.svg'}


def bode_data(model: ModalModel, frequency: NDArray[np.float64]
              ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Magnitude [dB] and unwrapped phase [deg] of ``P_mech`` at ``frequency`` [Hz]."""
    h = model.frequency_response(2 * np.pi * frequency)
    magnitude = 20 * np.log10(np.abs(h))
    phase = np.degrees(np.unwrap(np.angle(h)))
    return magnitude, phase


def _frequency(sample_period: float = TAU, points: int = 800) -> NDArray[np.float64]:
    nyquist = 0.5 / sample_period
    return np.logspace(np.log10(nyquist / 250), np.log10(nyquist), points)


def plot_bode(ax_mag: Any, ax_phase: Any, models: Sequence[ModalModel], *,
              reference: ModalModel = REFERENCE_MODEL, pooled: ModalModel | None = None,
              frequency: NDArray[np.float64] | None = None) -> None:
    """Draw window models (thin, coloured by order), pooled (thick) and reference (dashed).

    Args:
        ax_mag: Axes for the magnitude [dB].
        ax_phase: Axes for the phase [deg].
        models: One identified model per window, in window order.
        reference: The reference model (Table I by default).
        pooled: The pooled estimate, if any.
        frequency: Frequencies [Hz]; default up to the Nyquist frequency of tau = 10 us (the
            paper's scanner).
    """
    from matplotlib import colormaps

    f = _frequency() if frequency is None else np.asarray(frequency, dtype=float)
    cmap = colormaps['viridis']
    for i, model in enumerate(models):
        mag, ph = bode_data(model, f)
        color = cmap(i / max(len(models) - 1, 1))
        label = 'windows (colour = order)' if i == 0 else None
        ax_mag.semilogx(f, mag, color=color, lw=0.7, alpha=0.6, label=label)
        ax_phase.semilogx(f, ph, color=color, lw=0.7, alpha=0.6)
    if pooled is not None:
        mag, ph = bode_data(pooled, f)
        ax_mag.semilogx(f, mag, color='tab:red', lw=1.8, label='pooled estimate')
        ax_phase.semilogx(f, ph, color='tab:red', lw=1.8)
    mag, ph = bode_data(reference, f)
    ax_mag.semilogx(f, mag, 'k--', lw=1.4, label='reference model')
    ax_phase.semilogx(f, ph, 'k--', lw=1.4)
    ax_mag.set_ylabel('magnitude [dB]')
    ax_mag.set_title('P_mech: identified vs reference')
    ax_mag.legend(loc='lower left', fontsize='small')
    ax_phase.set_ylabel('phase [deg]')
    ax_phase.set_xlabel('frequency [Hz]')
    for ax in (ax_mag, ax_phase):
        ax.grid(True, which='both', alpha=0.3)
        ax.set_xlim(f[0], f[-1])


def plot_trends(axes: Sequence[Any], windows: Sequence[WindowResult], *,
                names: Sequence[str] | None = None) -> None:
    """Relative deviation [%] of each parameter over the windows, tolerance band shaded.

    Args:
        axes: One axes per parameter.
        windows: Identified windows (their drift verdicts give deviation, std, tolerance).
        names: Parameters to draw, one per axes (default: the verdicts' names in order).
    """
    if not windows:
        for ax in axes:
            ax.text(0.5, 0.5, 'no window', ha='center', va='center', transform=ax.transAxes)
        return
    all_names = list(windows[0].drift.names)
    chosen = list(all_names if names is None else names)
    if len(chosen) > len(axes):
        msg = f'{len(chosen)} parameters but only {len(axes)} axes'
        raise ConfigurationError(msg)
    x = np.array([w.window_index for w in windows], dtype=float)
    for ax, name in zip(axes, chosen, strict=False):
        # a point takes its window's verdict colour only if this parameter raised it
        colors = [LEVEL_COLORS.get(w.drift.level_name, 'k') if name in w.drift.flagged
                  else LEVEL_COLORS['OK'] for w in windows]
        j = all_names.index(name)
        dev = 100 * np.array([w.drift.relative_deviation[j] for w in windows])
        std = 100 * np.array([w.drift.relative_std[j] if j < len(w.drift.relative_std)
                              else np.nan for w in windows])
        tol = 100 * np.array([w.drift.tolerance[j] for w in windows])
        ax.fill_between(x, -tol, tol, color='tab:green', alpha=0.12, step='mid', lw=0)
        ax.axhline(0.0, color='k', lw=0.6)
        ax.errorbar(x, dev, yerr=np.where(np.isfinite(std), std, 0.0), fmt='none',
                    ecolor='0.5', lw=0.7)
        for xi, di, ci, w in zip(x, dev, colors, windows, strict=True):
            ax.plot(xi, di, 'o', ms=4, mec=ci, mfc='none' if w.partial else ci)
        ax.set_title(name, fontsize='small')
        ax.tick_params(labelsize='x-small')
        ax.grid(True, alpha=0.3)
        finite = dev[np.isfinite(dev)]
        span = max(float(np.max(np.abs(finite))) if finite.size else 0.0, float(tol.max()))
        ax.set_ylim(-1.15 * span, 1.15 * span)
    for ax in axes[len(chosen):]:
        ax.set_visible(False)


def identification_figure(found: BagIdentification, *,
                          reference: ModalModel | None = None) -> Any:
    """One page: Bode plot (left) and parameter trends with tolerance bands (right).

    ``reference`` defaults to the one the windows were judged against (``found.reference``).
    """
    from matplotlib.figure import Figure

    if reference is None:
        reference = found.reference if found.reference is not None else REFERENCE_MODEL

    fig = Figure(figsize=(16, 9), layout='constrained')
    outer = fig.add_gridspec(1, 2, width_ratios=(1.0, 1.25))
    left = outer[0].subgridspec(2, 1, height_ratios=(1.4, 1.0))
    ax_mag = fig.add_subplot(left[0])
    ax_phase = fig.add_subplot(left[1], sharex=ax_mag)
    plot_bode(ax_mag, ax_phase, [w.result.model for w in found.windows], reference=reference,
              pooled=None if found.pooled is None else found.pooled.model,
              frequency=_frequency(found.sample_period))
    names = list(reference.parameters())
    cols = 2
    rows = -(-len(names) // cols)
    right = outer[1].subgridspec(rows, cols)
    axes = [fig.add_subplot(right[i // cols, i % cols]) for i in range(rows * cols)]
    plot_trends(axes, found.windows, names=names)
    for ax in axes[-cols:]:
        ax.set_xlabel('window', fontsize='small')
    fig.suptitle(f'{found.info.path.name}: {len(found.windows)} window(s), method '
                 f'{found.method}; deviation from reference [%], shaded = drift tolerance, '
                 f'orange/red = flagged WARN/ERROR, hollow = partial window')
    return fig


def check_plot_path(path: str | os.PathLike[str]) -> Path:
    """Return ``path`` if it names a writable plot file (.png, .pdf or .svg).

    Raises:
        ConfigurationError: Unsupported file type or missing directory.
    """
    out = Path(path)
    if out.suffix.lower() not in _FORMATS:
        msg = f'plot file must end in one of {", ".join(sorted(_FORMATS))}: {out}'
        raise ConfigurationError(msg)
    if not out.parent.is_dir():
        msg = f'directory of the plot file does not exist: {out.parent}'
        raise ConfigurationError(msg)
    return out


def save_identification_plot(found: BagIdentification, path: str | os.PathLike[str]) -> Path:
    """Write :func:`identification_figure` to ``path`` (.png, .pdf or .svg); return the path.

    Raises:
        ConfigurationError: Unsupported file type.
    """
    out = check_plot_path(path)
    fig = identification_figure(found)
    fig.savefig(out, dpi=110)
    return out
