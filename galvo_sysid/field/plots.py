"""Plots people would rather look at than read (matplotlib, no display needed).

- :func:`plot_bode`: the measured frequency response of the averaged moves (with its
  +-2 std band and coherence) against the identified models (each window thin, the pooled
  estimate thick) and the reference (dashed), all from current to angle with the input
  dynamics and the zero-order hold, as the data see them.
- :func:`plot_trends`: each modal parameter's relative deviation from the reference over
  time, with its uncertainty, the WARN and tolerance bands, the verdict's colour where that
  parameter raised it, and unresolved modes drawn as such (not as numbers).
- :func:`identification_figure` / :func:`save_identification_plot`: both on one page, for
  ``galvo-sysid identify --plot FILE``.

Figures are built with :class:`matplotlib.figure.Figure` directly (no pyplot, no GUI backend),
so this works on a headless machine and from any thread.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from galvo_sysid.errors import ConfigurationError, InvalidDataError
from galvo_sysid.model import REFERENCE_MODEL, TAU, InputDynamics, ModalModel, parameter_mode
from galvo_sysid.model.dynamics import discretize

if TYPE_CHECKING:
    import os
    from collections.abc import Sequence

    from numpy.typing import NDArray

    from galvo_sysid.field.results import BagIdentification, WindowResult
    from galvo_sysid.ident.commission import FrequencyResponse

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
_MAG_LABEL = '|angle / current| [dB re 1 deg/A]'


def bode_data(model: ModalModel, frequency: NDArray[np.float64], *,
              dynamics: InputDynamics | None = None, sample_period: float | None = None
              ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Magnitude [dB re 1 deg/A] and unwrapped phase [deg] at ``frequency`` [Hz].

    Without ``dynamics``: ``P_mech`` alone (continuous time). With ``dynamics`` and
    ``sample_period``: the sampled plant from current command to encoder angle (input
    dynamics and zero-order hold included), as the moves measure it.
    """
    omega = 2 * np.pi * np.asarray(frequency, dtype=float)
    if dynamics is None or sample_period is None:
        h = model.frequency_response(omega)
    else:
        h = discretize(model, dynamics, sample_period).frequency_response(omega, sample_period)
    magnitude = 20 * np.log10(np.maximum(np.abs(h), 1e-300))
    phase = np.degrees(np.unwrap(np.angle(h)))
    if phase.size and phase[0] > 0:  # a double integrator starts at -180 deg, not +180
        phase -= 360.0 * math.ceil(phase[0] / 360.0)
    return magnitude, phase


def _frequency(sample_period: float = TAU, points: int = 800) -> NDArray[np.float64]:
    nyquist = 0.5 / sample_period
    return np.logspace(np.log10(nyquist / 250), np.log10(nyquist * 0.999), points)


def plot_bode(ax_mag: Any, ax_phase: Any, models: Sequence[ModalModel], *,
              reference: ModalModel = REFERENCE_MODEL, pooled: ModalModel | None = None,
              frequency: NDArray[np.float64] | None = None,
              dynamics: InputDynamics | None = None, sample_period: float | None = None,
              response: FrequencyResponse | None = None, ax_coh: Any = None) -> None:
    """Draw the measured response, the window models, the pooled one and the reference.

    Args:
        ax_mag: Axes for the magnitude [dB re 1 deg/A].
        ax_phase: Axes for the phase [deg].
        models: One identified model per window, in window order (thin, coloured by order).
        reference: The reference model (dashed; Table I by default).
        pooled: The pooled estimate, if any (thick).
        frequency: Frequencies [Hz]; default up to the Nyquist frequency of the sample period.
        dynamics: Input dynamics the models are drawn with (with ``sample_period``: current
            command to angle, as measured); without, ``P_mech`` alone.
        sample_period: Sample period [s] (default the paper's 10 us).
        response: The measured response of the averaged moves (drawn with +-2 std).
        ax_coh: Axes for the measured response's coherence (optional).
    """
    from matplotlib import colormaps

    t = TAU if sample_period is None else float(sample_period)
    f = _frequency(t) if frequency is None else np.asarray(frequency, dtype=float)
    t_draw = t if dynamics is not None else None
    if response is not None:
        # the first bins hold the records' leakage more than the plant: left out
        keep = slice(2, None)
        fr = response.omega[keep] / (2 * math.pi)
        h = response.response[keep]
        mag = np.abs(h)
        band = 2 * response.std[keep]
        ax_mag.fill_between(fr, 20 * np.log10(np.maximum(mag - band, mag * 1e-3)),
                            20 * np.log10(mag + band), color='tab:blue', alpha=0.2, lw=0,
                            label='measured +- 2 std')
        ax_mag.semilogx(fr, 20 * np.log10(mag), color='tab:blue', lw=0.9,
                        label='measured (averaged moves)')
        # the measured phase unwrapped along the pooled (else reference) model's: noise
        # does not add turns
        along = pooled if pooled is not None else reference
        _, ph_model = bode_data(along, fr, dynamics=dynamics, sample_period=t_draw)
        h_model = np.exp(1j * np.radians(ph_model))
        ax_phase.semilogx(fr, ph_model + np.degrees(np.angle(h / h_model)), color='tab:blue',
                          lw=0.9)
        if ax_coh is not None:
            ax_coh.semilogx(fr, response.coherence[keep], color='tab:blue', lw=0.9)
    elif ax_coh is not None:
        ax_coh.text(0.5, 0.5, 'no measured response', ha='center', va='center',
                    transform=ax_coh.transAxes)
    cmap = colormaps['viridis']
    for i, model in enumerate(models):
        mag_w, ph_w = bode_data(model, f, dynamics=dynamics, sample_period=t_draw)
        color = cmap(i / max(len(models) - 1, 1))
        label = 'windows (colour = order)' if i == 0 else None
        ax_mag.semilogx(f, mag_w, color=color, lw=0.7, alpha=0.6, label=label)
        ax_phase.semilogx(f, ph_w, color=color, lw=0.7, alpha=0.6)
    if pooled is not None:
        mag_p, ph_p = bode_data(pooled, f, dynamics=dynamics, sample_period=t_draw)
        ax_mag.semilogx(f, mag_p, color='tab:red', lw=1.6, label='pooled estimate')
        ax_phase.semilogx(f, ph_p, color='tab:red', lw=1.6)
    mag_r, ph_r = bode_data(reference, f, dynamics=dynamics, sample_period=t_draw)
    ax_mag.semilogx(f, mag_r, 'k--', lw=1.2, label='reference model')
    ax_phase.semilogx(f, ph_r, 'k--', lw=1.2)
    ax_mag.set_ylabel(_MAG_LABEL)
    ax_mag.set_title('current command to angle: measured, identified, reference'
                     if dynamics is not None else 'P_mech: identified vs reference')
    ax_mag.legend(loc='lower left', fontsize='small')
    ax_phase.set_ylabel('phase [deg]')
    axes = [ax_mag, ax_phase]
    if ax_coh is not None:
        ax_coh.set_ylabel('coherence [-]')
        ax_coh.set_ylim(0, 1.05)
        axes.append(ax_coh)
    axes[-1].set_xlabel('frequency [Hz]')
    for ax in axes:
        ax.grid(True, which='both', alpha=0.3)
        ax.set_xlim(f[0], f[-1])


def _times(windows: Sequence[WindowResult]) -> tuple[NDArray[np.float64], str]:
    """Each window's end, in seconds since the first move (window index without stamps)."""
    first = np.array([w.first_stamp for w in windows], dtype=float)
    last = np.array([w.last_stamp for w in windows], dtype=float)
    if np.all(np.isfinite(last)) and np.all(np.isfinite(first)) and np.ptp(last) > 0:
        return last - float(first.min()), "time since the bag's first move [s]"
    return np.array([w.window_index for w in windows], dtype=float), 'window'


def plot_trends(axes: Sequence[Any], windows: Sequence[WindowResult], *,
                names: Sequence[str] | None = None, warn_fraction: float = 0.5) -> str:
    """Relative deviation [%] of each parameter over time, WARN and tolerance bands shaded.

    Args:
        axes: One axes per parameter.
        windows: Identified windows (their drift verdicts give deviation, std, tolerance).
        names: Parameters to draw, one per axes (default: the verdicts' names in order).
        warn_fraction: The monitor's WARN threshold as a fraction of the tolerance.

    Returns:
        The x axis' label (time since the first move, or the window index without stamps).
    """
    if not windows:
        for ax in axes:
            ax.text(0.5, 0.5, 'no window', ha='center', va='center', transform=ax.transAxes)
        return 'window'
    all_names = list(windows[0].drift.names)
    chosen = list(all_names if names is None else names)
    if len(chosen) > len(axes):
        msg = f'{len(chosen)} parameters but only {len(axes)} axes'
        raise ConfigurationError(msg)
    x, xlabel = _times(windows)
    order = np.argsort(x, kind='stable')
    for ax, name in zip(axes, chosen, strict=False):
        j = all_names.index(name)
        mode = parameter_mode(name)
        resolved = np.array([mode == 0 or mode > len(w.result.resolved)
                             or bool(w.result.resolved[mode - 1]) for w in windows])
        dev = 100 * np.array([w.drift.relative_deviation[j] for w in windows])
        std = 100 * np.array([w.drift.relative_std[j] if j < len(w.drift.relative_std)
                              else np.nan for w in windows])
        tol = 100 * float(np.nanmax([w.drift.tolerance[j] for w in windows]))
        shown = resolved & np.isfinite(dev)
        reach = np.abs(dev) + 2 * np.where(np.isfinite(std), std, 0.0)
        data_span = float(np.max(reach[shown])) if shown.any() else 0.0
        if not math.isfinite(tol) or tol <= 0:
            tol = math.inf
        span = max(data_span, tol) if tol <= 4 * max(data_span, 1e-12) else 1.5 * data_span
        if span <= 0 or not math.isfinite(span):
            span = tol if math.isfinite(tol) else 1.0
        warn = warn_fraction * tol
        ax.axhspan(-min(warn, 2 * span), min(warn, 2 * span), color='tab:green', alpha=0.10,
                   lw=0)
        for sign in (-1, 1):
            ax.axhspan(sign * min(warn, 2 * span), sign * min(tol, 2 * span),
                       color='tab:orange', alpha=0.12, lw=0)
        ax.axhline(0.0, color='k', lw=0.6)
        ax.plot(x[order][shown[order]], dev[order][shown[order]], color='0.6', lw=0.6)
        ax.errorbar(x[shown], dev[shown],
                    yerr=np.where(np.isfinite(std[shown]), std[shown], 0.0), fmt='none',
                    ecolor='0.5', lw=0.7)
        for xi, di, ok, w in zip(x, dev, shown, windows, strict=True):
            if not ok:  # an unresolved mode: no number, a mark on the axis
                ax.plot(xi, 0.0, 'x', ms=5, color='tab:gray')
                continue
            c = (LEVEL_COLORS.get(w.drift.level_name, 'k') if name in w.drift.flagged
                 else LEVEL_COLORS['OK'])
            ax.plot(xi, di, 'o', ms=4, mec=c, mfc='none' if w.partial else c)
        title = name
        if math.isfinite(tol) and tol > 1.15 * span:
            title += f' (tolerance +-{tol:.3g} % off scale)'
        if not shown.all():
            title += f'; x = unresolved in {int((~shown).sum())}'
        ax.set_title(title, fontsize='small')
        ax.tick_params(labelsize='x-small')
        ax.grid(True, alpha=0.3)
        ax.set_ylim(-1.15 * span, 1.15 * span)
        ax.set_ylabel('[%]', fontsize='x-small')
    for ax in axes[len(chosen):]:
        ax.set_visible(False)
    return xlabel


def identification_figure(found: BagIdentification, *,
                          reference: ModalModel | None = None) -> Any:
    """One page: Bode plot with the measured response (left), parameter trends (right).

    ``reference`` defaults to the one the windows were judged against (``found.reference``).

    Raises:
        InvalidDataError: No window was identified (nothing to draw).
    """
    from matplotlib.figure import Figure

    if not found.windows:
        raise InvalidDataError('no window identified: nothing to plot')
    if reference is None:
        reference = found.reference if found.reference is not None else REFERENCE_MODEL

    fig = Figure(figsize=(16, 9.5), layout='constrained')
    outer = fig.add_gridspec(1, 2, width_ratios=(1.0, 1.25))
    left = outer[0].subgridspec(3, 1, height_ratios=(1.5, 1.0, 0.5))
    ax_mag = fig.add_subplot(left[0])
    ax_phase = fig.add_subplot(left[1], sharex=ax_mag)
    ax_coh = fig.add_subplot(left[2], sharex=ax_mag)
    plot_bode(ax_mag, ax_phase, [w.result.model for w in found.windows], reference=reference,
              pooled=None if found.pooled is None else found.pooled.model,
              frequency=_frequency(found.sample_period),
              dynamics=found.dynamics, sample_period=found.sample_period,
              response=found.response, ax_coh=ax_coh)
    names = list(reference.parameters())
    cols = 2
    rows = -(-len(names) // cols)
    right = outer[1].subgridspec(rows, cols)
    axes = [fig.add_subplot(right[i // cols, i % cols]) for i in range(rows * cols)]
    xlabel = plot_trends(axes, found.windows, names=names, warn_fraction=found.warn_fraction)
    for ax in axes[-cols:]:
        ax.set_xlabel(xlabel, fontsize='small')
    fig.suptitle(f'{found.info.path.name}: {len(found.windows)} window(s), method '
                 f'{found.method}, model {found.model_name}\nright: deviation from the '
                 f'reference [%]; green = within {found.warn_fraction:g} x tolerance, orange = '
                 f'up to the tolerance (WARN), beyond = ERROR; orange/red points raised '
                 f'WARN/ERROR, hollow = partial window, x = unresolved mode (no number)',
                 fontsize='medium')
    return fig


def check_plot_path(path: str | os.PathLike[str]) -> Path:
    """Return ``path`` if it names a writable plot file (.png, .pdf or .svg).

    Raises:
        ConfigurationError: Unsupported file type, missing directory, or a directory.
    """
    out = Path(path)
    if out.suffix.lower() not in _FORMATS:
        msg = f'plot file must end in one of {", ".join(sorted(_FORMATS))}: {out}'
        raise ConfigurationError(msg)
    if not out.parent.is_dir():
        msg = f'directory of the plot file does not exist: {out.parent}'
        raise ConfigurationError(msg)
    if out.is_dir():
        raise ConfigurationError(f'the plot file is a directory: {out}')
    return out


def save_identification_plot(found: BagIdentification, path: str | os.PathLike[str]) -> Path:
    """Write :func:`identification_figure` to ``path`` (.png, .pdf or .svg); return the path.

    Raises:
        ConfigurationError: Unsupported file type.
        InvalidDataError: No window was identified (no file is written).
    """
    out = check_plot_path(path)
    fig = identification_figure(found)
    fig.savefig(out, dpi=110)
    return out
