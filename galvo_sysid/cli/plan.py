"""``galvo-sysid plan``: what a deployment's data will allow, before recording any.

The subcommand's parser and run function; :mod:`galvo_sysid.cli.main` picks it up through its
``PLUGINS`` list (:func:`register`). The numbers come from :func:`galvo_sysid.field.plan.plan`.
"""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any

from galvo_sysid.cli.common import (
    add_subcommand,
    dither_amplitude,
    parse_angle,
    positive,
    positive_at_most,
    print_json,
)
from galvo_sysid.errors import ConfigurationError

__all__ = ['add_parser', 'format_plan', 'register', 'run']

_DESCRIPTION = """\
Plan a deployment from the scanner's model file: how precisely each parameter will be known
from one window of N moves of a move mix, how many moves until a given change is
detectable, and what a dither (small tones at the resonances added to the current command)
buys and costs.

The numbers are Cramer-Rao bounds: the smallest standard deviations any unbiased estimator
can reach on such data (the refined fit reaches them within about 1.1-1.3x). They are
evaluated on probe windows of the closed-loop simulator with the model as the plant, its
controller designed from the model, and the simulator's noise levels unless given: give the
measured ones (--current-noise, --encoder-noise) for a real machine."""

_EPILOG = """\
examples:
  galvo-sysid plan --moves 100
  galvo-sysid plan --model scanner.yaml --angles 0.3 1.5 --change omega_3=-0.01
  galvo-sysid plan --target zeta_3=0.1 --dither-modes 3
  galvo-sysid plan --dither 10mA --dither-modes 3 --json

exit codes: 0 plan printed, 1 bad model or option value, 2 usage error"""


def _relative(text: str) -> tuple[str, float]:
    name, sep, value = text.partition('=')
    try:
        number = float(value)
    except ValueError:
        number = math.nan
    if not sep or not name or not math.isfinite(number):
        msg = f'expected PARAM=RELATIVE (e.g. omega_3=-0.01), got {text!r}'
        raise argparse.ArgumentTypeError(msg)
    name = name.strip()
    if number <= -1.0 and (name == 'k0' or not name.startswith('k')):
        msg = (f'{name} is positive: a relative change of {number:g} (to {1 + number:g} times '
               f'it) cannot happen; e.g. {name}=-0.01 is 1 % down')
        raise argparse.ArgumentTypeError(msg)
    return name, number


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``plan`` subcommand to an argparse subparsers object."""
    p = add_subcommand(
        subparsers, 'plan', description=_DESCRIPTION, epilog=_EPILOG,
        help='what the data of a deployment will allow (Cramer-Rao bounds, dither)')
    p.add_argument('--model', metavar='FILE', default=None,
                   help="the scanner's plant-model file (default: the paper's scanner)")
    p.add_argument('--angles', nargs='+', type=parse_angle, default=None, metavar='ANGLE',
                   help='target angles of the move mix [deg, or e.g. 1psi] (default: 1psi)')
    p.add_argument('--moves', type=positive(int), default=100, metavar='N',
                   help='moves per window (default: %(default)s, as the sysid node)')
    p.add_argument('--dither', type=dither_amplitude, default=0.0, metavar='AMPLITUDE',
                   help='planned dither tone amplitude [A, or e.g. 10mA] (default: none)')
    p.add_argument('--dither-modes', default='all', metavar='MODES',
                   help="resonances the dither tones sit at: 'all' or mode numbers, e.g. 3")
    p.add_argument('--change', action='append', type=_relative, default=[],
                   metavar='PARAM=REL', help='a relative change to detect, e.g. omega_3=-0.01: '
                   'moves per window until it exceeds --n-sigma std; repeatable')
    p.add_argument('--n-sigma', type=positive(float), default=3.0, metavar='S',
                   help="significance of a detected change (default: 3, the watchdog's)")
    p.add_argument('--target', action='append', type=_relative, default=[],
                   metavar='PARAM=REL', help='a relative std wanted, e.g. zeta_3=0.1: the '
                   'smallest dither (at --dither-modes) that reaches it; repeatable')
    p.add_argument('--current-noise', type=positive_at_most(10.0, 'A'), default=None,
                   metavar='A', help="rms current noise [A] (default: the simulator's)")
    p.add_argument('--encoder-noise', type=positive_at_most(10.0, 'deg'), default=None,
                   metavar='DEG',
                   help="rms encoder noise before quantisation [deg] (default: the simulator's)")
    p.add_argument('--json', action='store_true', help='print one JSON object on stdout')
    return p


def register(subparsers: Any) -> None:
    """Add the subcommand and set :func:`run` as its function (``galvo_sysid.cli.main`` plugin)."""
    add_parser(subparsers).set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the subcommand; return the exit code.

    Raises:
        GalvoSysidError: Bad model or option values (the caller prints one line).
    """
    from galvo_sysid.field.plan import plan
    from galvo_sysid.model import load_model
    from galvo_sysid.sim.dither import dither_for_modes

    model = load_model(args.model or None)
    for option in ('change', 'target'):
        names = [name for name, _ in getattr(args, option)]
        if len(set(names)) != len(names):
            raise ConfigurationError(f'--{option}: a parameter given twice')
    result = plan(model, angles=args.angles, moves=args.moves,
                  dither=dither_for_modes(args.dither, args.dither_modes, model=model),
                  current_noise=args.current_noise, encoder_noise=args.encoder_noise,
                  change=dict(args.change), n_sigma=args.n_sigma, target=dict(args.target))
    if args.json:
        print_json(result.to_dict())
    else:
        sys.stdout.write(format_plan(result))
    return 0


def format_plan(result: Any) -> str:
    """The readable plan ``plan`` prints without ``--json``."""
    from galvo_sysid.model import parameter_unit

    ref = result.model
    mix = ', '.join(f'{a:g}' for a in result.angles)
    lines = [f'moves per window: {result.moves}; angles {mix} deg; dither: '
             + (f'{1e3 * result.dither.amplitude:g} mA per tone'
                if result.dither.amplitude > 0 else 'none'), '',
             'Cramer-Rao std of one window (relative to the value) [%]:']
    angles = list(result.window_std)
    lines.append(f'  {"param":<8} {"value":>12} {"unit":<12} ' + ' '.join(
        f'{f"{a:g} deg":>10}' for a in angles) + (f' {"all":>10}' if len(angles) > 1 else ''))
    for name, value in ref.items():
        cells = [100 * result.window_std[a][name] / abs(value) for a in angles]
        if len(angles) > 1:
            cells.append(100 * result.pooled_std[name] / abs(value))
        lines.append(f'  {name:<8} {value:12.6g} {parameter_unit(name):<12} '
                     + ' '.join(f'{c:10.3g}' for c in cells))
    if result.unresolved:
        lines.append(f'  mode(s) {", ".join(str(i) for i in result.unresolved)}: a single '
                     'window will not place them (residue within 5 std of zero): reported '
                     'unresolved')
    if result.dither.amplitude > 0:
        counts = (f' ({result.position_error / result.encoder_resolution:.2g} encoder counts)'
                  if result.encoder_resolution > 0 else '')
        lines.append(f'  the dither adds {result.position_error:.3g} deg rms to the angle'
                     f'{counts}')
    if result.moves_to_detect:
        lines += ['', f'moves per window to detect a change at {result.n_sigma:g} std (and, '
                      f'for a mode, to resolve it):']
        for name, need in result.moves_to_detect.items():
            lines.append(f'  {name}: ' + (f'{need}' if need is not None else 'more than 10^7'))
    if result.dither_for_target:
        lines += ['', 'smallest dither reaching each target std:']
        for name, found in result.dither_for_target.items():
            lines.append(f'  {name}: ' + ('none of the amplitudes tried (up to 0.2 A)'
                                          if found is None else
                                          f'{1e3 * found[0]:g} mA, adding {found[1]:.3g} deg '
                                          f'rms to the angle'))
    return '\n'.join(lines) + '\n'
