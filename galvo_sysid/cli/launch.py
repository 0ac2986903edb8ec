"""``galvo-sysid launch``: the driver, sysid and watchdog nodes together (like ``ros2 launch``).

The subcommand's parser and run function; :mod:`galvo_sysid.cli.main` picks it up through its
``PLUGINS`` list (:func:`register`). The processes: :mod:`galvo_sysid.field.launcher`.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

from galvo_sysid.cli.common import add_subcommand, positive

if TYPE_CHECKING:
    from collections.abc import Callable

__all__ = ['add_parser', 'register', 'run']

_DESCRIPTION = """\
Start the monitoring nodes of one scanner as child processes: galvo_driver (the simulated
scanner; leave it out with --no-driver when a real scanner publishes the moves), sysid and
watchdog, all in one namespace. The same set, with the same arguments, as
  ros2 launch galvo_sysid monitor.launch.py namespace:=NS model:=FILE driver:=false ...
on a full ROS 2 install (launch is not on PyPI).

Ctrl-C (SIGINT) or SIGTERM stops them: SIGINT to each node, SIGTERM to any still running
after --stop-timeout seconds, then SIGKILL. A node that ends by itself is said in one line;
the others keep running. Parameter files: --params-file FILE goes to every node (its sections
`/**/galvo_driver:`, `/**/sysid:`, `/**/watchdog:` or `/**:` say which node takes what);
--params-file NODE=FILE to that node only (e.g. sysid=config/sysid.yaml). Later files win;
--model wins over them."""

_EPILOG = """\
examples:
  galvo-sysid launch
  galvo-sysid launch --namespace scanner_1 --model scanner.yaml
  galvo-sysid launch --no-driver --params-file sysid=my_sysid.yaml \\
      --params-file watchdog=my_watchdog.yaml
  galvo-sysid echo /diagnostics           (in another terminal)

exit codes: 0 every node ended cleanly (stopped by Ctrl-C, or done), 1 a node failed or had to
be killed, 2 usage error"""


def _checked(parse: Callable[[str], Any]) -> Callable[[str], Any]:
    """An argparse type from a parser raising ConfigurationError (a usage error, exit 2)."""
    def check(text: str) -> Any:
        from galvo_sysid.errors import ConfigurationError

        try:
            return parse(text)
        except ConfigurationError as err:
            raise argparse.ArgumentTypeError(str(err)) from None
    return check


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``launch`` subcommand to an argparse subparsers object."""
    from galvo_sysid.field.launcher import STOP_TIMEOUT, normalize_namespace, parse_params_file

    p = add_subcommand(
        subparsers, 'launch', description=_DESCRIPTION, epilog=_EPILOG,
        help='start driver, sysid and watchdog together (like ros2 launch)')
    p.add_argument('--namespace', type=_checked(normalize_namespace), metavar='NS',
                   help="the scanner's namespace, e.g. scanner_1 (topics /scanner_1/galvo/...)")
    p.add_argument('--model', metavar='FILE',
                   help="plant-model file for all three nodes (default: the nodes' own, the "
                        "packaged model of the paper's scanner)")
    p.add_argument('--no-driver', action='store_true',
                   help='do not start the simulated scanner (a real one publishes the moves)')
    p.add_argument('--params-file', dest='params_files', action='append', default=[],
                   type=_checked(parse_params_file),
                   metavar='[NODE=]FILE',
                   help='parameter file for every node, or NODE=FILE for one (galvo_driver, '
                        'sysid, watchdog); may be given several times')
    p.add_argument('--stop-timeout', type=positive(float), default=STOP_TIMEOUT, metavar='S',
                   help='seconds a node has to stop after SIGINT (then SIGTERM, then SIGKILL)')
    return p


def register(subparsers: Any) -> None:
    """Add the subcommand and set :func:`run` as its function (``galvo_sysid.cli.main`` plugin)."""
    add_parser(subparsers).set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Start the nodes and wait until they end or are stopped; return the exit code.

    Raises:
        OSError: A node process could not be started (the caller prints one line).
    """
    from galvo_sysid.field.launcher import node_commands, supervise

    commands = node_commands(namespace=args.namespace or '', model=args.model or '',
                             driver=not args.no_driver, params_files=args.params_files)
    return supervise(commands, stop_timeout=args.stop_timeout)
