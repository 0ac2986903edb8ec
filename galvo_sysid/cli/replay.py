"""``galvo-sysid replay``: publish a bag onto the live ROS graph (like ``ros2 bag play``)."""

from __future__ import annotations

import argparse
from typing import Any

from galvo_sysid.cli.common import BAG_HELP, add_subcommand, finite_float, positive

__all__ = ['add_parser', 'remap_rule', 'run']

_DESCRIPTION = (
    "Publish a bag's moves with their recorded timing, like 'ros2 bag play': the\n"
    'move topics /galvo/current and /galvo/encoder (in any namespace) only, since the\n'
    "bag's recorded results (/galvo/modal_parameters, /galvo/drift) are stale and the\n"
    'nodes compute them afresh; --topics or --all-topics publish others, --remap\n'
    'renames them. Before publishing, waits up to --wait seconds (default 10; 0: no\n'
    'wait; at most 3600) until each published topic has a subscriber, so nothing is\n'
    'lost at the start, then publishes anyway. --rate scales the timing; --clock\n'
    "publishes /clock with the bag's time for nodes run with use_sim_time:=true (not\n"
    'waited for); --loop starts over at the end (the sysid node notices time jumping\n'
    'back and starts fresh windows).')

_EPILOG = (
    'examples:\n'
    '  galvo-sysid replay bags/nominal\n'
    '  galvo-sysid replay bags/drifting --rate 5 --loop\n'
    '  galvo-sysid replay run1 --clock --wait 0\n'
    '  galvo-sysid replay run1 --topics /galvo/modal_parameters   # the recorded results\n'
    '  galvo-sysid replay run1 --remap /galvo/current:=/scanner_1/galvo/current \\\n'
    '                              /galvo/encoder:=/scanner_1/galvo/encoder')


def remap_rule(text: str) -> tuple[str, str]:
    """An argument type: ``OLD:=NEW``, two topic names.

    Raises:
        argparse.ArgumentTypeError: Not two names joined by ``:=``.
    """
    old, sep, new = text.partition(':=')
    if not sep or not old.strip('/') or not new.strip('/') or any(
            c.isspace() for c in text):
        msg = f'not OLD:=NEW (two topic names): {text!r}'
        raise argparse.ArgumentTypeError(msg)
    return old, new


def _wait(text: str) -> float:
    """An argument type: seconds, finite, 0 or more (the player bounds them further)."""
    value = finite_float(text)
    if value < 0:
        msg = f'must be >= 0: {text!r}'
        raise argparse.ArgumentTypeError(msg)
    return value


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
    topics = p.add_mutually_exclusive_group()
    topics.add_argument('--topics', nargs='+', metavar='TOPIC',
                        help='publish these topics of the bag (default: the move topics)')
    topics.add_argument('--all-topics', action='store_true',
                        help='publish every topic of the bag, recorded results included')
    p.add_argument('--remap', nargs='+', action='extend', type=remap_rule, metavar='OLD:=NEW',
                   help='publish topic OLD as NEW')
    p.add_argument('--wait', type=_wait, default=10.0, metavar='S',
                   help='wait at most S seconds for subscribers on the published topics')
    return p


def run(args: argparse.Namespace) -> int:
    """Publish the bag; return the exit code.

    Raises:
        GalvoSysidError: The bag cannot be read, a type is not installed (the caller prints
            one line).
    """
    from galvo_sysid.field.live import replay

    replay(args.bag, rate=args.rate, loop=args.loop, clock=args.clock, topics=args.topics,
           all_topics=args.all_topics, remap=dict(args.remap or ()), wait=args.wait)
    return 0
