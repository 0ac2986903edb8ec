"""``galvo-sysid commission``: a healthy scanner's bag in, its model file and Bode plot out.

The moves are paired and windowed exactly as the sysid node does it
(:class:`~galvo_sysid.monitor.pairing.MoveWindower`), the windows of the most common sample
period and record length are handed to :func:`galvo_sysid.ident.commission.commission`, and
the result is written as a plant-model file (:func:`galvo_sysid.model.save_model`) that then
configures the driver (a digital twin), the sysid node and the watchdog. The dwell between
records is read from the stamps of consecutive moves.
"""

from __future__ import annotations

import collections
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from galvo_sysid.errors import InvalidDataError
from galvo_sysid.ident.preprocess import check_travel
from galvo_sysid.monitor.parameters import defaults

if TYPE_CHECKING:
    import os
    from collections.abc import Callable

    from galvo_sysid.ident.commission import Commissioning
    from galvo_sysid.monitor.moves import Window

__all__ = ['BagCommissioning', 'commission_bag', 'commission_figure', 'format_commissioning']

_SYSID = defaults('sysid')
"""The sysid node's parameter defaults (commissioning windows its moves the same way)."""


@dataclass(frozen=True)
class BagCommissioning:
    """A commissioned bag.

    Attributes:
        bag: The bag read.
        result: What commissioning learnt (model, fit, measured response, steps).
        set_aside: Windows left out, with the reason (other sample period or length).
        rejected: Moves the windower set aside.
        seconds: Wall-clock time taken.
    """

    bag: Path
    result: Commissioning
    set_aside: tuple[str, ...]
    rejected: int
    seconds: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary: the model file's content, the steps, the windows used."""
        from galvo_sysid.model.files import model_to_dict

        r = self.result
        return {
            'bag': str(self.bag),
            'model': model_to_dict(r.model),
            'modes': r.n_modes,
            'resolved': list(r.fit.resolved),
            'fit_percent': r.fit.fit_percent,
            'steps': [{'modes': s.modes, 'chi2': s.chi2, 'bic': s.bic,
                       'added': None if math.isnan(s.added) else s.added, 'note': s.note}
                      for s in r.steps],
            'windows': r.windows,
            'selection_windows': r.selection_windows,
            'set_aside': list(self.set_aside),
            'rejected_moves': self.rejected,
            'warnings': list(r.warnings),
            'measured_current_lag': None if r.measured_lag is None else r.measured_lag.lag,
            'lag_search': [] if r.measured_lag is None else
            [{'assumed': a, 'fitted': f} for a, f in r.measured_lag.steps],
            'seconds': self.seconds,
        }


def _windows(bag: str | os.PathLike[str], *, namespace: str | None,
             window_size: int) -> tuple[list[Window], int]:
    from galvo_sysid.field.bags import BagReader
    from galvo_sysid.monitor.pairing import MoveWindower

    pairer = MoveWindower(window_size=window_size)
    windows: list[Window] = []
    rejected = 0
    with BagReader(bag) as reader:
        for _, completed, unread in reader.feed(pairer, namespace=namespace):
            rejected += int(unread is not None)
            windows.extend(completed)
            rejected += len(pairer.pop_rejections())
    windows.extend(pairer.flush(min_moves=max(3, window_size // 2)))
    rejected += len(pairer.pop_rejections())
    return windows, rejected


def _dwell(windows: list[Window], sample_period: float, samples: int) -> int:
    """Samples between one record's end and the next move's start, from the stamps."""
    stamps = sorted(s for w in windows for s in (w.first_stamp, w.last_stamp))
    gaps = np.diff(np.array(stamps)) / sample_period - samples
    gaps = gaps[(gaps >= 0) & (gaps < 10 * samples)]
    return round(float(np.min(gaps))) if gaps.size else 0


def commission_bag(bag: str | os.PathLike[str], *, namespace: str | None = None,
                   window_size: int = _SYSID['window_size'], max_modes: int = 6,
                   measured_current: bool = False,
                   progress: Callable[[str], None] | None = None) -> BagCommissioning:
    """Commission the scanner whose moves a bag holds.

    Args:
        bag: The bag (directory, ``.mcap`` or ``.db3``).
        namespace: Scanner namespace when the bag holds several.
        window_size: Moves per window; default: the sysid node's ``window_size`` (100).
        max_modes: Most resonant modes looked for.
        measured_current: The bag's current is the coil current measured when the encoder
            is read: the amplifier lag is searched and the model describes the held current
            made with it (:func:`galvo_sysid.ident.commission.commission`).
        progress: Called with a line of text at each step.

    Returns:
        The commissioned model and its evidence.

    Raises:
        BagError: Missing, corrupt or truncated bag, no galvo topics.
        InvalidDataError: Fewer than two usable windows.
        IdentificationError: No fit succeeded.
    """
    from galvo_sysid.ident.commission import commission

    start = time.perf_counter()
    windows, rejected = _windows(bag, namespace=namespace, window_size=window_size)
    if not windows:
        raise InvalidDataError(f'no window of {window_size} moves of one target angle in '
                               f'{bag}: commissioning needs a few hundred moves')
    kinds = collections.Counter((w.sample_period, w.current.shape[1]) for w in windows)
    (period, samples), _ = kinds.most_common(1)[0]
    used = [w for w in windows if (w.sample_period, w.current.shape[1]) == (period, samples)]
    aside = [f'window {w.index} ({w.target_angle:g} deg): sample period '
             f'{w.sample_period:.6g} s and {w.current.shape[1]} samples, not '
             f'{period:.6g} s and {samples}' for w in windows if w not in used]
    travelled = []  # windows whose moves travel their target angle (units, sign, topics)
    for w in used:
        try:
            check_travel(w.encoder, w.target_angle)
        except InvalidDataError as err:
            aside.append(f'window {w.index} ({w.target_angle:g} deg): {err}')
        else:
            travelled.append(w)
    if len(travelled) < 2:
        why = f' ({aside[-1]})' if len(used) > len(travelled) else ''
        raise InvalidDataError(f'commissioning needs at least 2 windows of one sample period, '
                               f'found {len(travelled)} in {bag}{why}')
    used, set_aside = travelled, tuple(aside)
    description = (f'commissioned by galvo-sysid from {Path(bag).name} on '
                   f'{time.strftime("%Y-%m-%d")}: {len(used)} windows, '
                   f'{sum(w.moves for w in used)} moves, '
                   f'{len({w.target_angle for w in used})} target angles')
    result = commission([(w.current, w.encoder) for w in used], sample_period=period,
                        max_modes=max_modes, record_length=samples - int(measured_current),
                        dwell_length=_dwell(used, period, samples), description=description,
                        measured_current=measured_current, progress=progress)
    if result.measured_lag is not None:  # the file says which current it describes
        note = (f'; its current: the held current made from the measured coil current with '
                f'an amplifier lag of {result.measured_lag.lag:.6g} s (--measured-current '
                f'{result.measured_lag.lag:.6g})')
        result = replace(result, model=replace(result.model,
                                               description=result.model.description + note))
    return BagCommissioning(bag=Path(bag), result=result, set_aside=set_aside,
                            rejected=rejected, seconds=time.perf_counter() - start)


def format_commissioning(found: BagCommissioning, *, out: str | None = None) -> str:
    """The readable report of ``galvo-sysid commission``."""
    r = found.result
    m = r.model
    t = m.sample_period
    lines = [f'bag: {found.bag}; {r.windows} windows in the pooled fit, '
             f'{r.selection_windows} in the order selection; {found.seconds:.1f} s', '',
             'order selection (chi2 about the number of rows, '
             f'{r.rows}, for an adequate model):',
             f'  {"modes":>5} {"chi2/rows":>10} {"BIC":>12}  added',
             *(f'  {s.modes:>5} {s.chi2 / r.rows:10.4g} {s.bic:12.6g}  '
               + ('-' if math.isnan(s.added) else f'{s.added / (2e3 * math.pi):.4g} kHz')
               + (f'  ({s.note})' if s.note else '') for s in r.steps),
             '',
             f'model: {m.n_modes} resonant mode(s), sample period {t * 1e6:.4g} us, records of '
             f'{m.record_length} samples, dwell {m.dwell_length}; fit {r.fit.fit_percent:.2f} %',
             f'  computation delay {m.dynamics.computation_delay} sample(s), amplifier lag '
             f'{m.dynamics.lag_time_constant * 1e6:.3g} us '
             f'(+- {m.std_by_name().get("lag_time_constant", math.nan) * 1e6:.2g} us)']
    std = m.std_by_name()
    lines.append(f'  k0 = {m.modal.k0:.6g} +- {std.get("k0", math.nan):.3g} deg/(A s^2)')
    lines.append(f'  {"mode":>4} {"f [kHz]":>9} {"+-":>8} {"zeta":>9} {"+-":>8} '
                 f'{"k [deg/(A s^2)]":>16} {"+-":>9}  band [kHz]')
    resolved = r.fit.resolved
    for i, (k, w, z) in enumerate(zip(m.modal.residues, m.modal.natural_frequencies,
                                      m.modal.damping_ratios, strict=True), start=1):
        lo, hi = m.mode_bands()[i - 1]
        flag = '' if resolved[i - 1] else '  unresolved'
        sw = std.get(f'omega_{i}', math.nan) / (2e3 * math.pi)
        lines.append(
            f'  {i:>4} {w / (2e3 * math.pi):9.4f} {sw:8.2g}'
            f' {z:9.4g} {std.get(f"zeta_{i}", math.nan):8.2g} {k:16.5g} '
            f'{std.get(f"k{i}", math.nan):9.2g}  {lo / (2e3 * math.pi):.3g}..'
            f'{hi / (2e3 * math.pi):.3g}{flag}')
    if not m.n_modes and r.warnings:
        lines.append('  no resonant mode found (see the warnings)')
    elif not m.n_modes:
        lines.append("  no resonant mode found: these moves do not excite the scanner's "
                     "resonances above the noise (see the order selection's last note); the "
                     'model is the rigid body alone, and monitoring with it judges k0 and the '
                     'lag only. Record faster moves, or add a dither at the resonances, to '
                     'commission the modes')
    if r.measured_lag is not None:
        lag = r.measured_lag.lag
        lines += ['', f'measured current: amplifier lag {lag * 1e6:.4g} us ({lag / t:.3g} T), '
                      f'found in {len(r.measured_lag.steps)} fits; the model describes the '
                      f'held current made with it, behind no computation delay. Identify '
                      f'with it: galvo-sysid identify BAG --model MODEL --measured-current '
                      f'{lag:.6g} (or import files with --measured-current {lag:.6g})']
    lines += [f'  WARNING: {text}' for text in r.warnings]
    for text in found.set_aside:
        lines.append(f'  set aside: {text}')
    if found.rejected:
        lines.append(f'  {found.rejected} move(s) or message(s) set aside by the pairing')
    if out:
        lines += ['', f'model written to {out}; use it with:',
                  f'  sysid    --ros-args -p model:={out}',
                  f'  watchdog --ros-args -p model:={out}',
                  f'  galvo_driver --ros-args -p model:={out}   # a digital twin',
                  f'  galvo-sysid identify BAG --model {out}']
    return '\n'.join(lines) + '\n'


def commission_figure(found: BagCommissioning) -> Any:
    """Bode plot of the measured response (with +-2 std and coherence) and the model's."""
    from matplotlib.figure import Figure

    from galvo_sysid.model.dynamics import discretize

    r = found.result
    resp = r.response
    m = r.model
    f = resp.omega / (2 * math.pi)
    fig = Figure(figsize=(9, 8), layout='constrained')
    ax_mag, ax_phase, ax_coh = fig.subplots(3, 1, sharex=True,
                                            gridspec_kw={'height_ratios': [3, 2, 1]})
    mag = np.abs(resp.response)
    ax_mag.fill_between(f, 20 * np.log10(np.maximum(mag - 2 * resp.std, mag * 1e-3)),
                        20 * np.log10(mag + 2 * resp.std), color='tab:blue', alpha=0.25,
                        label='measured +- 2 std (scatter of moves and windows)')
    ax_mag.semilogx(f, 20 * np.log10(mag), color='tab:blue', lw=1, label='measured (H1)')
    model_h = discretize(m.modal, m.dynamics, m.sample_period).frequency_response(
        resp.omega, m.sample_period)
    ax_mag.semilogx(f, 20 * np.log10(np.abs(model_h)), color='k', lw=1.5,
                    label=f'commissioned model ({m.n_modes} modes)')
    phase = np.degrees(np.unwrap(np.angle(resp.response)))
    ax_phase.semilogx(f, phase, color='tab:blue', lw=1)
    ax_phase.semilogx(f, np.degrees(np.unwrap(np.angle(model_h))), color='k', lw=1.5)
    ax_coh.semilogx(f, resp.coherence, color='tab:blue', lw=1)
    for i, (w, ok) in enumerate(zip(m.modal.natural_frequencies, r.fit.resolved, strict=True),
                                start=1):
        for ax in (ax_mag, ax_phase, ax_coh):
            ax.axvline(w / (2 * math.pi), color='tab:red' if ok else 'tab:gray', lw=0.8,
                       ls='-' if ok else ':')
        ax_mag.annotate(f'{i}' if ok else f'{i}?', (w / (2 * math.pi), 1.0),
                        xycoords=('data', 'axes fraction'), ha='center', va='top')
    ax_mag.set_ylabel('|angle / current| [dB re 1 deg/A]')
    ax_phase.set_ylabel('phase [deg]')
    ax_coh.set_ylabel('coherence')
    ax_coh.set_ylim(0, 1.05)
    ax_coh.set_xlabel('frequency [Hz]')
    ax_mag.legend(loc='lower left', fontsize='small')
    ax_mag.set_title(f'{found.bag.name}: measured response of the averaged moves and the '
                     f'commissioned model (modes marked; "?" unresolved)', fontsize='medium')
    for ax in (ax_mag, ax_phase, ax_coh):
        ax.grid(True, which='both', alpha=0.3)
    return fig
