"""``galvo-sysid echo``: print the messages of a live topic (like ``ros2 topic echo``)."""

from __future__ import annotations

import argparse
from typing import Any

from galvo_sysid.cli.common import add_subcommand, positive

__all__ = ['add_parser', 'run']

_DESCRIPTION = (
    "Print a live topic's messages as YAML, like 'ros2 topic echo': the type is\n"
    'found from the graph (waits until the topic appears), the QoS follows the\n'
    'publishers, so /galvo/modal_parameters (transient local) shows the latest\n'
    'window at once. --field prints one field of each message (like ros2 topic echo\n'
    '--field): names joined by dots; a whole number picks an element of a list.')

_EPILOG = (
    'examples:\n'
    '  galvo-sysid echo /galvo/modal_parameters --once\n'
    '  galvo-sysid echo /galvo/drift --json\n'
    '  galvo-sysid echo /galvo/modal_parameters --field natural_frequencies\n'
    '  galvo-sysid echo /galvo/drift --field level\n'
    '  galvo-sysid echo /galvo/encoder --field header.stamp.sec\n'
    '  galvo-sysid echo /diagnostics --timeout 5')


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``echo`` subcommand to an argparse subparsers object."""
    p = add_subcommand(
        subparsers, 'echo', help='print the messages of a live topic',
        description=_DESCRIPTION, epilog=_EPILOG)
    p.add_argument('topic', help='topic name')
    p.add_argument('--once', action='store_true', help='exit after the first message')
    p.add_argument('--json', action='store_true', help='one JSON object per line')
    p.add_argument('--field', metavar='A.B', default=None,
                   help='print only this field of each message (e.g. header.stamp, '
                        'natural_frequencies.0)')
    p.add_argument('--timeout', type=positive(float), default=None, metavar='S',
                   help='exit with code 1 when no message came within S seconds')
    return p


def run(args: argparse.Namespace) -> int:
    """Print the topic's messages; return the exit code (1: none within ``--timeout``).

    Raises:
        GalvoSysidError: The topic's type is not installed, or has no such ``--field`` (the
            caller prints one line).
    """
    from galvo_sysid.field.live import echo

    return echo(args.topic, once=args.once, as_json=args.json, field=args.field,
                timeout=args.timeout)
