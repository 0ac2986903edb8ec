"""``galvo-sysid record``: record galvo topics of the live ROS graph into a bag."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from galvo_sysid.cli.common import add_subcommand, positive
from galvo_sysid.interfaces.topics import GALVO_TOPICS

__all__ = ['add_parser', 'run']

_DESCRIPTION = (
    'Record topics of the running system into a new rosbag2 bag, like\n'
    "'ros2 bag record': raw subscriptions (the bytes exactly as published), message\n"
    'type and QoS taken from the publishers, the message definitions stored in the\n'
    'bag so any rosbag2 reader decodes it. Topics are picked up when they appear.\n'
    'Log time = receive time. Stops after --duration or on Ctrl-C (the bag is closed\n'
    'properly either way).\n'
    '\n'
    'A crash loses little: messages reach the file at least every --flush-interval\n'
    'seconds (mcap chunks, sqlite3 commits); a killed recording keeps them, and\n'
    "'galvo-sysid bag recover BAG' finishes the bag (until then, info and identify say it\n"
    'is incomplete). A full disk stops the recording with an error; the bag is closed\n'
    'with everything written before (disk space for that is held back while recording).')

_EPILOG = (
    'examples:\n'
    '  galvo-sysid record --out /tmp/field1 --duration 60\n'
    '  galvo-sysid record --out /tmp/left --storage sqlite3 /left/galvo/current '
    '/left/galvo/encoder\n'
    '  galvo-sysid record --out /tmp/everything --all\n'
    '  galvo-sysid bag recover /tmp/field1       # after a crash or kill')


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``record`` subcommand to an argparse subparsers object."""
    p = add_subcommand(
        subparsers, 'record', help='record galvo topics of the live ROS graph into a bag',
        description=_DESCRIPTION, epilog=_EPILOG)
    p.add_argument('--out', required=True, metavar='BAG', help='bag directory to create')
    p.add_argument('--duration', type=positive(float), default=None, metavar='S',
                   help='stop after S seconds (default: until Ctrl-C)')
    p.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap',
                   help='rosbag2 storage format')
    p.add_argument('--flush-interval', type=positive(float), default=1.0, metavar='S',
                   help='write received messages to the file at least every S seconds '
                        '(what a crash can lose)')
    p.add_argument('-a', '--all', action='store_true',
                   help='record every topic (except /rosout and /parameter_events)')
    p.add_argument('topics', nargs='*', metavar='TOPIC',
                   help=f'topics to record (default: {" ".join(GALVO_TOPICS)})')
    return p


def run(args: argparse.Namespace) -> int:
    """Record until ``--duration`` or Ctrl-C; the counts go to stderr. Return the exit code.

    Raises:
        GalvoSysidError: Output bag exists, a type is not installed, or writing failed (a
            full disk: the bag is closed with what was written before); the caller prints
            one line.
    """
    from galvo_sysid.field.live import record

    topics = args.topics or ([] if args.all else list(GALVO_TOPICS))
    summary = record(args.out, topics=topics, all_topics=args.all, duration=args.duration,
                     storage=args.storage, flush_interval=args.flush_interval)
    total = sum(summary.counts.values())
    print(f'record: {total} messages on {len(summary.counts)} topic(s) in '
          f'{summary.seconds:.1f} s -> {args.out} ({args.storage})', file=sys.stderr)
    for topic, count in sorted(summary.counts.items()):
        print(f'  {topic}: {count}', file=sys.stderr)
    if summary.error is not None:
        raise summary.error
    return 0
