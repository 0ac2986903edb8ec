"""Parameter names, kinds and the tolerance rule (galvo_sysid.monitor.tolerances)."""

from __future__ import annotations

import pytest

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.monitor.tolerances import (
    DEFAULT_KIND_TOLERANCES,
    DEFAULT_TOLERANCES,
    builtin_tolerance,
    parameter_kind,
    parameter_names,
    resolve,
    split_parameter_name,
)


def test_names_and_kinds() -> None:
    assert parameter_names(2) == ('k0', 'k1', 'k2', 'omega_1', 'omega_2', 'zeta_1', 'zeta_2')
    assert [parameter_kind(n) for n in ('k0', 'k12', 'omega_3', 'zeta_1')] == \
        ['k0', 'k', 'omega', 'zeta']
    assert split_parameter_name('omega_12') == ('omega', 12)
    assert split_parameter_name('k0') == ('k0', 0)
    for bad in ('k01', 'omega_0', 'kappa_1', 'zeta'):
        assert split_parameter_name(bad) is None
        with pytest.raises(ConfigurationError, match='not a parameter name'):
            parameter_kind(bad)


def test_the_rule_own_entry_kind_builtin_name_builtin_kind() -> None:
    names = ('k0', 'k1', 'k4', 'omega_2', 'omega_4')
    assert resolve(names, {}, DEFAULT_TOLERANCES, DEFAULT_KIND_TOLERANCES) == \
        [0.02, 0.05, 0.08, 0.01, 0.01]
    assert resolve(names, {'k': 0.3, 'omega_4': 0.5}, DEFAULT_TOLERANCES,
                   DEFAULT_KIND_TOLERANCES) == [0.02, 0.3, 0.3, 0.01, 0.5]
    assert [builtin_tolerance(n) for n in ('k0', 'k3', 'k7', 'zeta', 'omega_9')] == \
        [0.02, 5.0, 0.08, 0.3, 0.01]
