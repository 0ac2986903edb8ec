"""The galvo topics as bags name them, and the message definitions for rosbags.

The topic and message-type names are :mod:`galvo_sysid.interfaces.topics`' (one source); the
topics here are their absolute names without namespace, as bags record them. The
``galvo_sysid_msgs`` definitions are taken from the installed interface package
(``<prefix>/share/galvo_sysid_msgs/msg``) or, in a source checkout, from ``msg_defs/msg``.
"""

from __future__ import annotations

import os
import re
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore

from galvo_sysid.field.bags.errors import BagError
from galvo_sysid.interfaces.topics import DRIFT_STATUS, GALVO_TOPICS, MODAL_PARAMETERS, MOVE_SAMPLES

if TYPE_CHECKING:
    from collections.abc import Iterable

    from rosbags.typesys.store import Typestore

__all__ = [
    'CURRENT_TOPIC',
    'DRIFT_TOPIC',
    'ENCODER_TOPIC',
    'MODAL_PARAMETERS_TOPIC',
    'ensure_type',
    'find_message_definition',
    'galvo_typestore',
    'msg_search_dirs',
    'split_type',
    'stamp_to_ns',
]

CURRENT_TOPIC, ENCODER_TOPIC, MODAL_PARAMETERS_TOPIC, DRIFT_TOPIC = GALVO_TOPICS
"""The topics the galvo nodes publish, as bags name them (absolute, without namespace):
``/galvo/current``, ``/galvo/encoder``, ``/galvo/modal_parameters``, ``/galvo/drift``."""

_GALVO_MSGS = MOVE_SAMPLES.split('/', 1)[0]
_TYPE_RE = re.compile(r'^([A-Za-z][A-Za-z0-9_]*)/(?:msg/)?([A-Za-z][A-Za-z0-9_]*)$')
_SOURCE_MSG_DIR = Path(__file__).resolve().parents[3] / 'msg_defs' / 'msg'
"""``msg_defs/msg`` of a source checkout (``galvo_sysid/field/bags/`` is three levels down)."""


def msg_search_dirs(package: str = _GALVO_MSGS) -> list[Path]:
    """Directories that may hold ``<package>``'s ``.msg`` files, most preferred first.

    The installed interface package (``sys.prefix``, then each ``AMENT_PREFIX_PATH`` entry)
    comes before the source checkout's ``msg_defs/msg`` (only for ``galvo_sysid_msgs``).
    """
    prefixes = [Path(sys.prefix)]
    prefixes += [Path(p) for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    dirs = [prefix / 'share' / package / 'msg' for prefix in prefixes]
    if package == _GALVO_MSGS:
        dirs.append(_SOURCE_MSG_DIR)
    unique: list[Path] = []
    for d in dirs:
        if d not in unique:
            unique.append(d)
    return unique


def split_type(msgtype: str) -> tuple[str, str]:
    """``'pkg/msg/Name'`` or ``'pkg/Name'`` -> ``('pkg', 'Name')``.

    Raises:
        BagError: Not a message type name.
    """
    match = _TYPE_RE.match(msgtype)
    if not match:
        msg = f'not a ROS 2 message type name: {msgtype!r}'
        raise BagError(msg)
    return match.group(1), match.group(2)


def find_message_definition(msgtype: str) -> str | None:
    """Return the ``.msg`` text of ``msgtype`` (``pkg/msg/Name``) if installed, else None."""
    package, name = split_type(msgtype)
    for d in msg_search_dirs(package):
        path = d / f'{name}.msg'
        if path.is_file():
            return path.read_text(encoding='utf-8')
    return None


def ensure_type(typestore: Typestore, msgtype: str, _seen: set[str] | None = None) -> None:
    """Register ``msgtype`` (and unknown field types) in ``typestore`` from ``.msg`` files.

    Raises:
        BagError: A definition cannot be found or parsed.
    """
    package, name = split_type(msgtype)
    full = f'{package}/msg/{name}'
    if full in typestore.fielddefs:
        return
    seen = set() if _seen is None else _seen
    if full in seen:
        return
    seen.add(full)
    text = find_message_definition(full)
    if text is None:
        msg = (f'no message definition found for {full} (looked in '
               f'{", ".join(str(d) for d in msg_search_dirs(package))})')
        raise BagError(msg)
    try:
        types = get_types_from_msg(text, full)
    except TypesysError as err:
        msg = f'cannot parse the definition of {full}: {err}'
        raise BagError(msg) from None
    for _, fields in types.values():
        for _, desc in fields:
            for dep in _field_type_names(desc):
                if dep not in typestore.fielddefs and dep not in types:
                    ensure_type(typestore, dep, seen)
    typestore.register(types)


def _field_type_names(desc: Any) -> list[str]:
    """Names of the message types a rosbags field description refers to."""
    names: list[str] = []
    if isinstance(desc, tuple):
        for part in desc:
            if isinstance(part, str) and '/' in part:
                names.append(part)
            elif isinstance(part, tuple):
                names.extend(_field_type_names(part))
    return names


def galvo_typestore(extra_types: Iterable[str] = ()) -> Typestore:
    """A rosbags typestore: ROS 2 Jazzy's standard types plus ``galvo_sysid_msgs``.

    Args:
        extra_types: Further ``pkg/msg/Name`` types to register from installed ``.msg``
            files (their unknown field types too).

    Raises:
        BagError: A definition cannot be found or parsed.
    """
    typestore = get_typestore(Stores.ROS2_JAZZY)
    for msgtype in (MOVE_SAMPLES, MODAL_PARAMETERS, DRIFT_STATUS, *extra_types):
        ensure_type(typestore, msgtype)
    return typestore


def stamp_to_ns(stamp: float) -> int:
    """Seconds as float -> integer nanoseconds (rounded)."""
    return round(stamp * 1e9)
