"""``galvo-sysid replay``: publish a bag onto the live ROS graph (like ``ros2 bag play``)."""

from __future__ import annotations

import argparse
from typing import Any

from galvo_sysid.cli.common import BAG_HELP, add_subcommand, positive

__all__ = ['add_parser', 'run']

_DESCRIPTION = (
    "Publish a bag's messages with their recorded timing, like 'ros2 bag play'.\n"
    'Waits (up to --wait seconds) until every topic has a subscriber, so nothing is\n'
    'lost at the start. --rate scales the timing; --clock publishes /clock with the\n'
    "bag's time for nodes run with use_sim_time:=true; --loop starts over at the end\n"
    '(the sysid node notices time jumping back and starts fresh windows).')

_EPILOG = (
    'examples:\n'
    '  galvo-sysid replay bags/nominal\n'
    '  galvo-sysid replay bags/drifting --rate 5 --loop\n'
    '  galvo-sysid replay run1 --clock --topics /galvo/current /galvo/encoder')


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``replay`` subcommand to an argparse subparsers object."""
    p = add_subcommand(
        subparsers, 'replay', help='publish a bag onto the live ROS graph',
        description=_DESCRIPTION, epilog=_EPILOG)
    p.add_argument('bag', help=BAG_HELP)
    p.add_argument('--rate', type=positive(float), default=1.0, metavar='R',
                   help="speed factor (2 = twice as fast; 'inf' = as fast as possible)")
    p.add_argument('--loop', action='store_true', help='start over at the end')
    p.add_argument('--clock', action='store_true', help="publish /clock with the bag's time")
    p.add_argument('--topics', nargs='+', metavar='TOPIC', help='only these topics')
    p.add_argument('--wait', type=float, default=10.0, metavar='S',
                   help='wait at most S seconds for subscribers')
    return p


def run(args: argparse.Namespace) -> int:
    """Publish the bag; return the exit code.

    Raises:
        GalvoSysidError: The bag cannot be read, a type is not installed (the caller prints
            one line).
    """
    from galvo_sysid.field.live import replay

    replay(args.bag, rate=args.rate, loop=args.loop, clock=args.clock, topics=args.topics,
           wait=args.wait)
    return 0
