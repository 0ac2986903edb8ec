"""``galvo-sysid``: the command-line tool for recorded data and field work.

Subcommands (``galvo-sysid <command> --help`` explains each; one module each in
:mod:`galvo_sysid.cli` with ``add_parser(subparsers)`` and ``run(args) -> exit code``, the
shared pieces in :mod:`galvo_sysid.cli.common`):

- offline, no ROS graph needed: ``simulate`` (write a bag from the simulated scanner),
  ``identify`` (identify the plant from a bag), ``info`` (what a bag holds), and as
  plugins ``import`` (your own data, CSV / .npz / .mat, into a bag), ``commission``,
  ``discrepancy``, ``plan``;
- live, on the ROS 2 graph: ``record``, ``replay``, ``echo``, ``topic`` (``list``, ``hz``),
  ``param`` (``list``, ``get``, ``set``, ``describe``, ``dump``): stand-ins for ``ros2 bag
  record``, ``ros2 bag play``, ``ros2 topic echo|list|hz`` and ``ros2 param`` where ros2cli
  is not installed; ``launch`` (plugin: the three nodes as child processes, for ``ros2 launch
  galvo_sysid monitor.launch.py``).

Other modules add subcommands by being listed in :data:`PLUGINS` and defining
``register(subparsers)`` (see :func:`build_parser`).

Exit codes: 0 success, 1 bad input or nothing identified (one line on stderr, no traceback:
:func:`galvo_sysid.cli.common.guarded`), 2 wrong usage (an option's value refused by the
parser), 130 interrupted.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import sys
from typing import TYPE_CHECKING

from galvo_sysid import keep_freed_memory, limit_blas_threads
from galvo_sysid.cli import bag, echo, identify, info, param, record, replay, simulate, topic
from galvo_sysid.cli.common import Parser, guarded

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = ['COMMANDS', 'PLUGINS', 'build_parser', 'main']

PROG = 'galvo-sysid'

PLUGINS = ('galvo_sysid.cli.commission', 'galvo_sysid.cli.discrepancy', 'galvo_sysid.cli.plan',
           'galvo_sysid.cli.import_data', 'galvo_sysid.cli.launch')
"""Modules that add subcommands if present: each defines ``register(subparsers)``, which adds
its parser(s) and sets ``func`` (``args -> exit code``) as the parser default. ``register``
runs for every command except the built-in ones of :data:`COMMANDS` (so also for ``--help``
and the plugins' own commands); it should import nothing heavy: the numerics belong in
``func``. Errors of bad input raised by ``func`` become one line on stderr and exit code 1
(:func:`~galvo_sysid.cli.common.guarded`)."""

COMMANDS = ('simulate', 'identify', 'info', 'record', 'replay', 'echo', 'topic', 'param',
            'bag')
"""The built-in subcommands: running one of them registers no plugin (process start counts,
e.g. in identify's speed against real time)."""

_BUILTIN = (simulate, identify, info, record, replay, echo, topic, param, bag)  # as COMMANDS

_MAIN_HELP = """\
Field tools for galvano-scanner system identification (galvo_sysid).

The scanner's plant (a rigid-body mode plus three resonant modes) is identified from the
current and encoder records of ordinary positioning moves: topics /galvo/current and
/galvo/encoder (galvo_sysid_msgs/msg/MoveSamples, one message per move and signal).
Moves are grouped by target angle; every 100 moves of one angle form a window, which is
averaged and fitted (paper: Method A + ARX, or the refined fit), then judged for drift
against the reference model: a plant-model file (--model), by default the packaged model
of the paper's scanner (Table I). Data of another scanner are said to be so, not drift.
"""

_MAIN_EPILOG = """\
a first session (no ROS graph needed):
  galvo-sysid simulate --out /tmp/run1 --angles 1psi 2psi --moves-per-angle 200
  galvo-sysid info /tmp/run1
  galvo-sysid identify /tmp/run1
  galvo-sysid identify /tmp/run1 --json > run1.json
  galvo-sysid identify bags/drifting --plot drift.png

your own data (CSV, NumPy .npz or MATLAB .mat; the layout: galvo-sysid import --help):
  galvo-sysid import moves.npz --out /tmp/mine
  galvo-sysid identify /tmp/mine

your own scanner (commission once, then monitor):
  galvo-sysid commission healthy.mcap --out scanner.yaml --plot scanner_bode.png
  galvo-sysid identify later.mcap --model scanner.yaml

on a running system (galvo_driver, sysid, watchdog nodes):
  galvo-sysid launch --namespace scanner_1     # the three nodes (Ctrl-C stops them)
  galvo-sysid topic list -t
  galvo-sysid topic hz /galvo/current
  galvo-sysid echo /galvo/modal_parameters --once
  galvo-sysid echo /galvo/drift --field level
  galvo-sysid param set /galvo_driver step.factor 0.98
  galvo-sysid param dump /sysid > sysid_now.yaml
  galvo-sysid record --out /tmp/field1 --duration 30
  galvo-sysid replay /tmp/field1 --rate 2

exit codes: 0 ok, 1 bad input or nothing identified, 2 usage error, 130 interrupted
"""


def build_parser(*, plugins: bool = True) -> argparse.ArgumentParser:
    """The argument parser with every subcommand (and, if ``plugins``, those of
    :data:`PLUGINS` found installed)."""  # noqa: D205, D209
    parser = Parser(prog=PROG, description=_MAIN_HELP, epilog=_MAIN_EPILOG,
                    formatter_class=argparse.RawDescriptionHelpFormatter)
    from galvo_sysid import __version__

    parser.add_argument('--version', action='version', version=f'%(prog)s {__version__}')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND', required=True)
    for module in _BUILTIN:
        module.add_parser(sub).set_defaults(func=module.run)
    for name in PLUGINS if plugins else ():
        if importlib.util.find_spec(name) is not None:
            importlib.import_module(name).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``galvo-sysid``; return the exit code (see the module docs)."""
    # Before numpy is imported (the subcommands import it when they run); see
    # galvo_sysid.limit_blas_threads.
    limit_blas_threads()
    keep_freed_memory()
    words = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(plugins=not words or words[0] not in COMMANDS)
    args = parser.parse_args(words)
    return guarded(f'{PROG} {args.command}', lambda: args.func(args))


if __name__ == '__main__':  # pragma: no cover
    sys.exit(main())
