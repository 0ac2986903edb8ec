"""Reading and writing rosbag2 bags of galvo topics with rosbags (no ROS install needed).

Bags are standard rosbag2 recordings (mcap by default, sqlite3 on request) that carry the
message definitions of every topic, so any rosbag2 reader (``ros2 bag``, rosbags'
``AnyReader``, Foxglove) decodes them without having ``galvo_sysid_msgs`` installed.

- :mod:`~galvo_sysid.field.bags.reader`: :class:`BagReader`, :class:`BagInfo`,
  :class:`SetAside` (a message that could not be used);
- :mod:`~galvo_sysid.field.bags.writer`: :class:`BagWriter`, with the crash-safe storages of
  :mod:`~galvo_sysid.field.bags.storage_mcap` and :mod:`~galvo_sysid.field.bags.storage_sqlite3`
  (records: :mod:`~galvo_sysid.field.bags.mcap_records`; ``metadata.yaml``:
  :mod:`~galvo_sysid.field.bags.metadata`);
- :mod:`~galvo_sysid.field.bags.completeness` (a bag whose recording was interrupted, told
  apart), :mod:`~galvo_sysid.field.bags.recovery` (made readable again; its mcap scan:
  :mod:`~galvo_sysid.field.bags.mcap_scan`);
- :mod:`~galvo_sysid.field.bags.definitions`: the galvo topics as bags name them (absolute),
  the ``.msg`` definitions and the rosbags typestore (the topic and type names themselves are
  :mod:`galvo_sysid.interfaces.topics`);
- :mod:`~galvo_sysid.field.bags.errors`: :class:`BagError` (an
  :class:`~galvo_sysid.errors.InvalidDataError`) and its subclasses, with one-line messages.
"""

from galvo_sysid.field.bags.definitions import (
    CURRENT_TOPIC,
    DRIFT_TOPIC,
    ENCODER_TOPIC,
    MODAL_PARAMETERS_TOPIC,
    find_message_definition,
    galvo_typestore,
    msg_search_dirs,
    stamp_to_ns,
)
from galvo_sysid.field.bags.errors import (
    BagError,
    BagExistsError,
    BagNotFoundError,
    BagWriteError,
    CorruptBagError,
    IncompleteBagError,
    NoGalvoTopicsError,
    WrongTopicTypeError,
)
from galvo_sysid.field.bags.reader import BagInfo, BagReader, RawMessage, SetAside, TopicInfo
from galvo_sysid.field.bags.writer import BagWriter

__all__ = [
    'CURRENT_TOPIC',
    'DRIFT_TOPIC',
    'ENCODER_TOPIC',
    'MODAL_PARAMETERS_TOPIC',
    'BagError',
    'BagExistsError',
    'BagInfo',
    'BagNotFoundError',
    'BagReader',
    'BagWriteError',
    'BagWriter',
    'CorruptBagError',
    'IncompleteBagError',
    'NoGalvoTopicsError',
    'RawMessage',
    'SetAside',
    'TopicInfo',
    'WrongTopicTypeError',
    'find_message_definition',
    'galvo_typestore',
    'msg_search_dirs',
    'stamp_to_ns',
]
