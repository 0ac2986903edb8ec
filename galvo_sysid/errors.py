"""Typed exceptions raised by the galvo_sysid numerics, and :func:`one_line` to say them.

Every error the library raises on bad input or on a failed identification derives from
:class:`GalvoSysidError`, so callers (the nodes, the command-line tool) can catch one type,
report the message (:func:`one_line`) and go on with the rest of their data.
"""

from __future__ import annotations

__all__ = [
    'ConfigurationError',
    'GalvoSysidError',
    'IdentificationError',
    'InvalidDataError',
    'ModelMismatchError',
    'one_line',
]


class GalvoSysidError(Exception):
    """Base class of every error raised by galvo_sysid."""


class InvalidDataError(GalvoSysidError, ValueError):
    """Input data cannot be used: wrong shape, too short, NaN/Inf, no excitation."""


class IdentificationError(GalvoSysidError):
    """The data were valid but the fit failed, e.g. no physical mode in a band."""


class ConfigurationError(GalvoSysidError, ValueError):
    """A parameter or model description is out of range or inconsistent."""


class ModelMismatchError(IdentificationError):
    """The data do not match the configured plant model.

    Raised when the records have another sample period than the model, a mode of the fit
    ends at its band's edge, or the residual is far above the noise between the bands: the
    scanner is not the one the model describes (or has changed beyond its bands). Callers say
    so plainly (and suggest ``galvo-sysid commission``) instead of reporting parameter drift.
    """


def one_line(err: BaseException) -> str:
    """An error's message on one line (its type's name when it has none)."""
    return ' '.join(str(err).split()) or type(err).__name__
