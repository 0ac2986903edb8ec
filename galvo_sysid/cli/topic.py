"""``galvo-sysid topic``: the topics of the live graph and their rates (like ``ros2 topic``)."""

from __future__ import annotations

import argparse
from typing import Any

from galvo_sysid.cli.common import HelpFormatter, add_subcommand, positive

__all__ = ['add_parser', 'run']

_DESCRIPTION = (
    "The live graph's topics, like 'ros2 topic list' and 'ros2 topic hz' (for the\n"
    "messages themselves: galvo-sysid echo). 'list' prints the topics, the galvo ones\n"
    '(current, encoder, modal_parameters, drift, in any namespace) first; it waits\n'
    '--spin-time seconds for discovery, as there is no ros2 daemon that knows the graph\n'
    "already. 'hz' prints a topic's rate every second over a window of messages until\n"
    'Ctrl-C, --count or --duration, then once more.')

_EPILOG = (
    'examples:\n'
    '  galvo-sysid topic list -t\n'
    '  galvo-sysid topic list --galvo -v\n'
    '  galvo-sysid topic hz /galvo/current\n'
    '  galvo-sysid topic hz /galvo/modal_parameters --duration 60\n'
    '  galvo-sysid topic hz /galvo/encoder --count 1000 --window 500')


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``topic`` subcommand (``list``, ``hz``) to an argparse subparsers object."""
    p = add_subcommand(subparsers, 'topic', help="the live graph's topics and their rates "
                       '(like ros2 topic list/hz)', description=_DESCRIPTION, epilog=_EPILOG)
    actions = p.add_subparsers(dest='action', metavar='ACTION', required=True)
    a = actions.add_parser('list', help='print the topics (the galvo ones first)',
                           description='Print the topics of the live graph, the galvo ones '
                           'first.', formatter_class=HelpFormatter)
    a.add_argument('-t', '--show-types', action='store_true', help="each topic's type too")
    a.add_argument('-v', '--verbose', action='store_true',
                   help='types and the number of publishers and subscribers')
    a.add_argument('--galvo', action='store_true', help='only the galvo topics')
    a.add_argument('--spin-time', type=positive(float), default=4.0, metavar='S',
                   help='seconds to wait for discovery')
    h = actions.add_parser('hz', help="print a topic's rate",
                           description="Print a topic's rate every second (messages per "
                           'second over the last --window intervals, arrival times).',
                           formatter_class=HelpFormatter)
    h.add_argument('topic', help='topic name')
    h.add_argument('--window', '-w', type=positive(int), default=10_000, metavar='N',
                   help='intervals the rate is taken over')
    h.add_argument('--count', type=positive(int), default=None, metavar='N',
                   help='stop after N messages')
    h.add_argument('--duration', type=positive(float), default=None, metavar='S',
                   help='stop S seconds after subscribing')
    h.add_argument('--timeout', type=positive(float), default=None, metavar='S',
                   help='exit with code 1 when no message came within S seconds')
    return p


def run(args: argparse.Namespace) -> int:
    """Run the action; return the exit code (``hz``: 1 when no rate could be taken)."""
    from galvo_sysid.field.live import topic_hz, topic_list

    if args.action == 'list':
        return topic_list(spin_time=args.spin_time, types=args.show_types,
                          verbose=args.verbose, galvo_only=args.galvo)
    return topic_hz(args.topic, window=args.window, count=args.count, duration=args.duration,
                    timeout=args.timeout)
