"""``galvo-sysid param``: a live node's parameters (like ``ros2 param``)."""

from __future__ import annotations

import argparse
from typing import Any

from galvo_sysid.cli.common import HelpFormatter, add_subcommand, positive

__all__ = ['add_parser', 'run']

_DESCRIPTION = (
    "List, read, change and save a running node's parameters, like 'ros2 param', over\n"
    "the standard parameter services of every ROS 2 node. NODE is the node's full name\n"
    '(/galvo_driver, /sysid, /watchdog, /scanner_1/sysid; a name without / is taken from\n'
    '/). A value is read as ros2 param reads it (YAML: 2.5, 100, true, [0.3, 0.6], text),\n'
    'numbers as on the command line -p NAME:=VALUE (1e-6 is a float), and fitted to the\n'
    "parameter's declared type: 2 for a floating-point parameter is 2.0, any text for a\n"
    'text parameter is that text. The node checks the value and refuses a bad one with a\n'
    'reason (exit code 1). On a full ROS 2 install, ros2 param does the same.')

_EPILOG = (
    'examples:\n'
    '  galvo-sysid param list /sysid\n'
    '  galvo-sysid param get /watchdog stale_timeout\n'
    '  galvo-sysid param set /galvo_driver step.parameter omega_1\n'
    '  galvo-sysid param set /galvo_driver step.factor 0.98\n'
    '  galvo-sysid param describe /sysid window_size\n'
    '  galvo-sysid param dump /sysid > sysid_now.yaml   # then: sysid --ros-args '
    '--params-file sysid_now.yaml\n'
    '\n'
    'exit codes: 0 ok, 1 node not found or silent, no such parameter, or the value refused')

_ACTIONS = {
    'list': ("print the names of the node's parameters, sorted", ()),
    'get': ("print a parameter's value ('Double value is: 2.5')", ('name',)),
    'set': ('set a parameter: "Set parameter successful", or the node\'s reason (exit 1)',
            ('name', 'value')),
    'describe': ("print a parameter's type, description and range", ('name',)),
    'dump': ('print every parameter as a --params-file (/node: ros__parameters: ...)', ()),
}


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``param`` subcommand (and its actions) to an argparse subparsers object."""
    p = add_subcommand(subparsers, 'param', help="a live node's parameters (like ros2 param)",
                       description=_DESCRIPTION, epilog=_EPILOG)
    actions = p.add_subparsers(dest='action', metavar='ACTION', required=True)
    for action, (text, positionals) in _ACTIONS.items():
        a = actions.add_parser(action, help=text, description=text[0].upper() + text[1:] + '.',
                               formatter_class=HelpFormatter)
        a.add_argument('node', metavar='NODE', help='the node, e.g. /sysid')
        if 'name' in positionals:
            a.add_argument('name', metavar='NAME', help='the parameter, e.g. window_size')
        if 'value' in positionals:
            a.add_argument('value', metavar='VALUE', help='the new value (YAML: 2.5, [0.3], text)')
        a.add_argument('--timeout', type=positive(float), default=5.0, metavar='S',
                       help='wait at most S seconds for the node and for each answer')
        if action == 'list':
            a.add_argument('--types', action='store_true', help="show each parameter's type")
            a.add_argument('--prefix', default='', metavar='TEXT',
                           help='only parameters whose name starts with TEXT')
        if action == 'get':
            a.add_argument('--hide-type', action='store_true', help='print the value only')
    return p


def run(args: argparse.Namespace) -> int:
    """Run the action on the live node; return the exit code (see the description)."""
    from galvo_sysid.field.live import (
        param_describe,
        param_dump,
        param_get,
        param_list,
        param_set,
    )

    if args.action == 'list':
        return param_list(args.node, types=args.types, prefix=args.prefix,
                          timeout=args.timeout)
    if args.action == 'get':
        return param_get(args.node, args.name, hide_type=args.hide_type, timeout=args.timeout)
    if args.action == 'set':
        return param_set(args.node, args.name, args.value, timeout=args.timeout)
    if args.action == 'describe':
        return param_describe(args.node, args.name, timeout=args.timeout)
    return param_dump(args.node, timeout=args.timeout)
