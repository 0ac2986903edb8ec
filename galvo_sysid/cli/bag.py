"""``galvo-sysid bag recover``: finish a bag whose recording was interrupted."""

from __future__ import annotations

import argparse
from typing import Any

from galvo_sysid.cli.common import BAG_HELP, HelpFormatter, add_subcommand

__all__ = ['add_parser', 'run']

_DESCRIPTION = (
    'Bag maintenance.\n'
    '\n'
    'recover (alias reindex): make a bag readable whose recording was killed, crashed or\n'
    'ran out of disk, keeping what is on disk: for mcap, every chunk up to the first\n'
    'damaged byte (the rest is cut and kept beside it, in <file>.cut, the index and\n'
    'footer are written); for sqlite3, every committed batch (the half-written one is\n'
    'rolled back). Then metadata.yaml is written from what the storage file holds (like\n'
    "'ros2 bag reindex'). Prints what was kept and what was lost. A complete, undamaged bag\n"
    'is left as it is (only its metadata.yaml is rewritten); a bag still being recorded is\n'
    'refused. A .mcap or .db3 file named among other such files of its directory is\n'
    'recovered alone (no metadata.yaml is written there).')

_EPILOG = (
    'examples:\n'
    '  galvo-sysid bag recover /tmp/field1\n'
    '  galvo-sysid info /tmp/field1')


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``bag`` subcommand (with ``recover``) to an argparse subparsers object."""
    p = add_subcommand(subparsers, 'bag', help='bag maintenance: recover an interrupted '
                       'recording', description=_DESCRIPTION, epilog=_EPILOG)
    sub = p.add_subparsers(dest='bag_command', metavar='ACTION', required=True)
    recover = sub.add_parser('recover', aliases=['reindex'], formatter_class=HelpFormatter,
                             help='make an interrupted recording readable',
                             description=_DESCRIPTION, epilog=_EPILOG)
    recover.add_argument('bag', help=BAG_HELP)
    return p


def run(args: argparse.Namespace) -> int:
    """Recover the bag; print what it holds now and what was lost. Return the exit code.

    Raises:
        BagError: Not a bag, nothing readable, or still being recorded (the caller prints
            one line).
    """
    from galvo_sysid.field.bags.recovery import recover

    result = recover(args.bag)
    print(f'bag {result.path}: {result.summary()}')
    return 0
