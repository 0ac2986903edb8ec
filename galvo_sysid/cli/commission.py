"""``galvo-sysid commission``: learn a healthy scanner's model file from a bag of its moves.

The subcommand's parser and run function; :mod:`galvo_sysid.cli.main` picks it up through its
``PLUGINS`` list (:func:`register`).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from galvo_sysid.cli.common import (
    BAG_HELP,
    add_subcommand,
    check_output,
    positive,
    print_json,
)

__all__ = ['add_parser', 'register', 'run']

_DESCRIPTION = """\
Learn the model of a healthy scanner from its own moves, with no prior model: commission
once, then monitor.

The moves are grouped into windows of one target angle (as the sysid node does), and
  1. the frequency response of the averaged moves is measured, with its scatter and
     coherence (the Bode plot);
  2. the computation delay (whole samples) and the amplifier lag are estimated;
  3. resonant modes are added one at a time where they lower the fit's chi-square most;
     the number of modes is the one with the lowest Bayesian information criterion;
  4. the chosen model is fitted jointly to all windows: each parameter gets its standard
     deviation, each mode a frequency band.
The result is a plant-model file (YAML) for the driver (a digital twin), the sysid node and
the watchdog (their parameter `model`), and for `galvo-sysid identify --model`.

Record a few hundred moves of several sizes (e.g. 5 target angles x 200 moves); the moves
must excite the resonances a little, as ordinary positioning moves do. A current record that
is the coil current measured when the encoder is read (not the DSP's command) is commissioned
with --measured-current: the amplifier's lag is found, and identify takes the data with
--measured-current LAG."""

_EPILOG = """\
examples:
  galvo-sysid simulate --out /tmp/healthy --angles 0.1 0.3 1 3 --moves-per-angle 200
  galvo-sysid commission /tmp/healthy --out scanner.yaml --plot scanner_bode.png
  galvo-sysid identify /tmp/later --model scanner.yaml
  sysid --ros-args -p model:=scanner.yaml

exit codes: 0 model written, 1 bad input or nothing to commission from, 2 usage error"""


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``commission`` subcommand to an argparse subparsers object."""
    p = add_subcommand(
        subparsers, 'commission', description=_DESCRIPTION, epilog=_EPILOG,
        help="learn a healthy scanner's model file from a bag of its moves")
    p.add_argument('bag', help=BAG_HELP)
    p.add_argument('--out', required=True, metavar='MODEL.yaml',
                   help='plant-model file to write (not over an existing file without --force)')
    p.add_argument('--force', action='store_true',
                   help='replace the --out file (and --plot) if it exists')
    p.add_argument('--plot', metavar='FILE',
                   help='also write the Bode plot, measured against the model (.png/.pdf/.svg)')
    p.add_argument('--json', action='store_true', help='print one JSON object on stdout')
    p.add_argument('--max-modes', type=positive(int), default=6, metavar='N',
                   help='most resonant modes looked for')
    p.add_argument('--window-size', type=positive(int), default=100, metavar='N',
                   help='moves per window (default: %(default)s, as the sysid node)')
    p.add_argument('--measured-current', action='store_true',
                   help="the bag's current is the coil current measured when the encoder is "
                        "read (not the DSP's command): the amplifier lag is searched, and the "
                        'model describes the held current made with it (identify then needs '
                        '--measured-current LAG too)')
    p.add_argument('--namespace', metavar='NS',
                   help='scanner namespace when the bag holds several (e.g. /left)')
    return p


def register(subparsers: Any) -> None:
    """Add the subcommand and set :func:`run` as its function (``galvo_sysid.cli.main`` plugin)."""
    add_parser(subparsers).set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the subcommand; return the exit code.

    Raises:
        GalvoSysidError: Bad bag or data (the caller prints one line).
    """
    from galvo_sysid.field.commission import (
        commission_bag,
        commission_figure,
        format_commissioning,
    )
    from galvo_sysid.field.plots import check_plot_path
    from galvo_sysid.model.files import save_model

    check_output(args.out, reads=args.bag, force=args.force, what='model file')
    if args.plot:
        check_plot_path(args.plot)
        check_output(args.plot, reads=args.bag, force=True, what='plot file')
    verbose = not args.json and sys.stderr.isatty()

    def progress(text: str) -> None:
        if verbose:
            print(f'commission: {text}', file=sys.stderr)

    found = commission_bag(args.bag, namespace=args.namespace, window_size=args.window_size,
                           max_modes=args.max_modes, measured_current=args.measured_current,
                           progress=progress)
    path = save_model(found.result.model, args.out)
    if args.plot:
        commission_figure(found).savefig(args.plot, dpi=120)
    if args.json:
        print_json(found.to_dict())
    else:
        sys.stdout.write(format_commissioning(found, out=str(path)))
    if args.plot:
        print(f'commission: plot written to {args.plot}', file=sys.stderr)
    return 0
