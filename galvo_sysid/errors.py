"""Typed exceptions raised by the galvo_sysid numerics.

Every error the library raises on bad input or on a failed identification derives from
:class:`GalvoSysidError`, so callers (the nodes, the command-line tool) can catch one type,
report the message and go on with the rest of their data.
"""

from __future__ import annotations

__all__ = [
    'ConfigurationError',
    'GalvoSysidError',
    'IdentificationError',
    'InvalidDataError',
]


class GalvoSysidError(Exception):
    """Base class of every error raised by galvo_sysid."""


class InvalidDataError(GalvoSysidError, ValueError):
    """Input data cannot be used: wrong shape, too short, NaN/Inf, no excitation."""


class IdentificationError(GalvoSysidError):
    """The data were valid but the fit failed, e.g. no physical mode in a band."""


class ConfigurationError(GalvoSysidError, ValueError):
    """A parameter or model description is out of range or inconsistent."""
