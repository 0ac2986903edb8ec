"""What a bag reader and a bag writer share: opened by ``with``, closed again at its end."""

from __future__ import annotations

import abc
from typing import TYPE_CHECKING, Self

if TYPE_CHECKING:
    from types import TracebackType

__all__ = ['BagFile']


class BagFile(abc.ABC):
    """A bag that is opened and closed; as a context manager, ``with`` does both."""

    @abc.abstractmethod
    def open(self) -> None:
        """Open the bag."""

    @abc.abstractmethod
    def close(self) -> None:
        """Close the bag (idempotent)."""

    def __enter__(self) -> Self:
        self.open()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
