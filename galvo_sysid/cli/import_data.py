"""``galvo-sysid import``: your own scanner data (CSV, NumPy .npz, MATLAB .mat) into a bag.

The subcommand's parser and run function; :mod:`galvo_sysid.cli.main` picks it up through its
``PLUGINS`` list (:func:`register`). The reading and checking are
:mod:`galvo_sysid.field.importing`'s.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from galvo_sysid.cli.common import add_subcommand, parse_angle, positive

__all__ = ['FORMATS', 'MAX_BYTES', 'add_parser', 'register', 'run']

FORMATS = ('csv', 'npz', 'mat')
"""galvo_sysid.field.importing.FORMATS, written out so that building the parser loads no numpy
(a test checks the two agree)."""

MAX_BYTES = 1 << 30
"""galvo_sysid.field.importing.MAX_BYTES, written out likewise."""

_DESCRIPTION = """\
Write the moves of your own scanner data, recorded by other means than rosbag2, into a
standard bag that every galvo-sysid command reads (identify, commission, discrepancy,
replay): per move one MoveSamples on /galvo/current and one on /galvo/encoder, as
`galvo-sysid simulate` writes them. No ROS graph is used.

Units: current [A], encoder [deg] (the raw angle: a record's first sample is its start
angle), target angle [deg] (the signed commanded rotation of the move: +0.3 forward, -0.3
back), sample period [s], stamp [s].

NumPy .npz (numpy.savez) and MATLAB .mat (v4 to v7; not v7.3/HDF5: save with -v7) files
hold named arrays of real numbers:
  current        (moves, samples)       current [A], one row per move           required
  encoder        (moves, samples)       encoder [deg], one row per move         required
  target_angle   (moves,) or one value  signed target angle [deg], each or all
  sample_period  one value              sample period [s]
  stamp          (moves,)               each move's first sample [s], increasing
  move_id        (moves,)               whole numbers >= 0, all different
  length         (moves,)               samples used of each row (records of unequal
                                        length, padded to one width; padding ignored)
A 1-D current/encoder is one move; vectors may be rows or columns; other arrays are ignored.

CSV: a header line, then one row per sample; the rows of a move together, in order:
  move,current,encoder,target_angle
  0,0.1622,-3.8147e-05,0.3
  0,0.4851,-3.8147e-05,0.3
  ...
Columns, any order (a name may carry its unit: "current [A]"): move (or move_id: the
move's id, a whole number >= 0), current [A], encoder [deg] (these three required),
target_angle [deg] and stamp [s] (the same on each row of a move), sample_period [s] (the
same on every row). Comma-separated (tab or semicolon if the header uses it); "#" lines
and blank lines are skipped; other columns are ignored. Moves may differ in length.

Not in the file: --sample-period (then required), --target-angle (one angle for every
move). Without stamps the records are put back to back from time 0.

Refused with one line (exit code 1), leaving no bag: missing arrays or columns, wrong
shapes, non-numbers, NaN or infinity, empty files or records, records under 32 samples,
a sample period outside 1e-7..0.1 s, a zero target angle or one beyond 90 deg, repeated
move ids, stamps not increasing, a file or its arrays (as float64) above --max-bytes
(checked before loading), an existing output bag; and moves whose encoder travels against
their target angle, or 10 times more or less than it (an encoder not in degrees; turn off
with --no-travel-check).

Identify then forms windows of 100 moves (identify --window-size) of one signed target
angle and one record length."""

_EPILOG = """\
examples:
  galvo-sysid import moves.npz --out /tmp/mine
  galvo-sysid import moves.csv --out /tmp/mine --sample-period 1e-5
  galvo-sysid import moves.mat --out /tmp/mine --target-angle 0.3 --storage sqlite3
  galvo-sysid identify /tmp/mine --json

  the file, from Python (current, encoder: (moves, samples) arrays) or MATLAB:
    numpy.savez('moves.npz', current=current, encoder=encoder, target_angle=angles,
                sample_period=1e-5)
    save('moves.mat', 'current', 'encoder', 'target_angle', 'sample_period', '-v7')

exit codes: 0 bag written, 1 bad input (one line on stderr, no bag left), 2 usage error"""


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``import`` subcommand to an argparse subparsers object."""
    p = add_subcommand(
        subparsers, 'import', description=_DESCRIPTION, epilog=_EPILOG,
        help='write your own data (CSV, NumPy .npz, MATLAB .mat) into a bag')
    p.add_argument('file', help='the data: .csv (or .txt, .tsv), .npz or .mat')
    p.add_argument('--out', required=True, metavar='BAG',
                   help='bag directory to create (it appears when complete: a refused or '
                        'failed import leaves nothing)')
    p.add_argument('--format', choices=FORMATS, default=None,
                   help="the file's format (default: from its suffix)")
    p.add_argument('--sample-period', type=float, default=None, metavar='SECONDS',
                   help='sample period [s], e.g. 1e-5 for 100 kHz (required if the file has '
                        'none; if it has one, they must agree)')
    p.add_argument('--target-angle', type=parse_angle, default=None, metavar='DEG',
                   help="one signed target angle [deg] for every move, if the file has none; "
                        "'1psi' = 0.3 deg")
    p.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap',
                   help='rosbag2 storage format')
    p.add_argument('--max-bytes', type=positive(int), default=MAX_BYTES, metavar='N',
                   help='refuse a file, or its arrays as float64, larger than this '
                        '(default: %(default)s = 1 GiB)')
    p.add_argument('--current-lead', type=int, default=0, metavar='N',
                   help='the current record leads the encoder by N samples (a coil current '
                        'measured when the encoder is read: 1); each current is moved N '
                        'samples earlier and the records shortened by N (commission says '
                        'when data look like this)')
    p.add_argument('--measured-current', type=float, default=None, metavar='LAG',
                   help='the current records are the coil current measured when the encoder '
                        "is read, behind the amplifier's first-order lag of time constant LAG "
                        '[s] (1 / (2 pi x its current-loop bandwidth); 0: none): each is '
                        'turned into the held current that drives it, a sample shorter '
                        '(commission then fits a lag near LAG if LAG is right)')
    p.add_argument('--no-travel-check', action='store_true',
                   help="do not check the encoder's travel against the target angles")
    return p


def register(subparsers: Any) -> None:
    """Add the subcommand and set :func:`run` as its function (``galvo_sysid.cli.main`` plugin)."""
    add_parser(subparsers).set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write the bag; its summary goes to stderr. Return the exit code.

    Raises:
        GalvoSysidError: Bad file, data or option; the output bag exists (the caller prints
            one line).
    """
    from galvo_sysid.field.importing import import_bag

    summary = import_bag(args.file, args.out, format=args.format,
                         sample_period=args.sample_period, target_angle=args.target_angle,
                         storage=args.storage, max_bytes=args.max_bytes,
                         check_travel=not args.no_travel_check,
                         current_lead=args.current_lead,
                         measured_lag=args.measured_current)
    print(summary, file=sys.stderr)
    return 0
