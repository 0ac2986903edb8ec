"""``galvo-sysid info``: what a bag holds (like ``ros2 bag info``)."""

from __future__ import annotations

import argparse
from typing import Any

from galvo_sysid.cli.common import BAG_HELP, add_subcommand

__all__ = ['add_parser', 'run']


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``info`` subcommand to an argparse subparsers object."""
    p = add_subcommand(
        subparsers, 'info', help='show what a bag holds',
        description='Topics, types, message counts and time range of a bag '
                    '(like ros2 bag info). The counts are those of the storage files; '
                    "where the bag's metadata.yaml claims others, a note says so.")
    p.add_argument('bag', help=BAG_HELP)
    return p


def run(args: argparse.Namespace) -> int:
    """Print the bag's topics, types, counts and time range; return the exit code.

    Raises:
        BagError: The bag cannot be read (the caller prints one line).
    """
    from galvo_sysid.field.bags import BagReader

    with BagReader(args.bag) as bag:
        info = bag.info
    span = (info.end - info.start) * 1e-9
    print(f'bag:      {info.path}')
    print(f'storage:  {info.storage}')
    print(f'messages: {info.message_count}')
    print(f'time:     {info.start * 1e-9:.6f} s .. {info.end * 1e-9:.6f} s ({span:.3f} s)')
    print('topics:')
    width = max((len(t.topic) for t in info.topics), default=0)
    for t in info.topics:
        latched = ', transient local' if t.transient_local else ''
        print(f'  {t.topic:<{width}}  {t.msgtype}  ({t.count} messages{latched})')
    for claim in info.claims:  # metadata.yaml is a claim: the storage's counts are shown
        print(f'note: {claim}')
    return 0
