"""The errors of bag reading and writing: :class:`BagError` and its subclasses.

Each is an :class:`~galvo_sysid.errors.InvalidDataError` whose message is one line naming the
bag and the reason.
"""

from __future__ import annotations

from galvo_sysid.errors import InvalidDataError

__all__ = [
    'BagError',
    'BagExistsError',
    'BagNotFoundError',
    'BagWriteError',
    'CorruptBagError',
    'IncompleteBagError',
    'NoGalvoTopicsError',
    'WrongTopicTypeError',
    'reason',
]


class BagError(InvalidDataError):
    """A bag cannot be used; the message is one line naming the bag and the reason."""


class BagNotFoundError(BagError, FileNotFoundError):
    """The bag path does not exist."""


class CorruptBagError(BagError):
    """The bag exists but cannot be read: not a bag, corrupt or truncated."""


class NoGalvoTopicsError(BagError):
    """The bag holds no ``galvo/current`` and ``galvo/encoder`` topics."""


class WrongTopicTypeError(BagError):
    """A galvo topic in the bag has another message type than expected."""


class BagExistsError(BagError, FileExistsError):
    """The output bag already exists (bags are never overwritten)."""


class IncompleteBagError(CorruptBagError):
    """The bag was not closed (its recording was interrupted or still runs, or it was cut).

    ``galvo-sysid bag recover`` makes it readable.
    """


class BagWriteError(BagError, OSError):
    """Writing a bag failed (e.g. a full disk); the message says what the bag kept."""


def reason(err: BaseException) -> str:
    """A library error (rosbags, the storage) as one line to quote in a :class:`BagError`.

    The error's arguments joined, whitespace collapsed, without a final full stop; the
    error's type name when it says nothing.
    """
    text = ' '.join(str(a) for a in err.args) if err.args else type(err).__name__
    text = ' '.join(text.split())
    return text.rstrip('.') or type(err).__name__
