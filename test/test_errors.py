"""The typed exceptions and their one-line text (galvo_sysid.errors)."""

from __future__ import annotations

from galvo_sysid.errors import (
    ConfigurationError,
    GalvoSysidError,
    IdentificationError,
    ModelMismatchError,
    one_line,
)


def test_one_line() -> None:
    assert one_line(ValueError('bad\n  value\tthere')) == 'bad value there'
    assert one_line(KeyboardInterrupt()) == 'KeyboardInterrupt'
    assert one_line(ConfigurationError('window_size must be >= 2')) == \
        'window_size must be >= 2'


def test_one_type_catches_them_all() -> None:
    assert issubclass(ModelMismatchError, IdentificationError)
    assert issubclass(ConfigurationError, GalvoSysidError)
    assert issubclass(ConfigurationError, ValueError)
