"""A bag's ``metadata.yaml``: what rosbag2 readers expect, from what a storage holds.

:func:`bag_metadata` builds its content from what a storage has durably written (used while
recording, :mod:`galvo_sysid.field.bags.writer`, and by the recovery,
:mod:`galvo_sysid.field.bags.recovery`); :func:`metadata_text` is its text.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import yaml  # type: ignore[import-untyped]  # PyYAML ships no stubs here
from rosbags.rosbag2.metadata import dump_qos_v9

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from rosbags.interfaces import Qos

__all__ = ['StoredTopic', 'bag_metadata', 'metadata_text']


@dataclass(frozen=True)
class StoredTopic:
    """A topic as ``metadata.yaml`` describes it."""

    name: str
    msgtype: str
    count: int
    qos: list[Qos] = field(default_factory=list)
    digest: str = ''
    serialization_format: str = 'cdr'


def bag_metadata(*, storage: str, file_name: str, topics: Sequence[StoredTopic],
                 span: tuple[int, int] | None, custom: Mapping[str, str] | None = None,
                 compression: str = '') -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` of ``metadata.yaml`` (rosbag2 version 9).

    Args:
        storage: ``'mcap'`` or ``'sqlite3'``.
        file_name: The storage file's name.
        topics: The topics with their message counts.
        span: Log times of the first and last message [ns] (None: no message).
        custom: ``custom_data`` entries.
        compression: ``compression_format`` (``''``: none, or per mcap chunk).
    """
    count = sum(t.count for t in topics)
    start, end = span if span is not None and count else (0, 0)
    duration = max(0, end - start)
    return {
        'version': 9,
        'storage_identifier': storage,
        'relative_file_paths': [file_name],
        'duration': {'nanoseconds': duration},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': count,
        'topics_with_message_count': [
            {'topic_metadata': {'name': t.name, 'type': t.msgtype,
                                'serialization_format': t.serialization_format,
                                'offered_qos_profiles': dump_qos_v9(list(t.qos)),
                                'type_description_hash': t.digest},
             'message_count': t.count}
            for t in topics],
        'compression_format': compression,
        'compression_mode': '',
        'files': [{'path': file_name, 'starting_time': {'nanoseconds_since_epoch': start},
                   'duration': {'nanoseconds': duration}, 'message_count': count}],
        'custom_data': dict(custom) if custom else None,
        'ros_distro': 'rosbags',
    }


def metadata_text(info: Mapping[str, Any], *, inner: bool = False) -> str:
    """``metadata.yaml``'s text (``inner``: without the top key, as stored in the file)."""
    data = info if inner else {'rosbag2_bagfile_information': info}
    text: str = yaml.safe_dump(data, default_flow_style=False, sort_keys=False)
    return text
