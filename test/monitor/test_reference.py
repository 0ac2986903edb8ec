"""The watchdog's reference model and monitor from its parameters
(galvo_sysid.monitor.reference)."""

from __future__ import annotations

import inspect

import pytest

from galvo_sysid.errors import ConfigurationError, InvalidDataError
from galvo_sysid.model import PAPER_MODEL, REFERENCE_MODEL, ModalModel, save_model
from galvo_sysid.monitor.drift import DriftMonitor
from galvo_sysid.monitor.parameters import MONITOR_PARAMETERS, WATCHDOG_PARAMETERS
from galvo_sysid.monitor.reference import monitor_from_parameters, reference_from_parameters


def test_monitor_from_parameters_is_the_watchdog_nodes(tmp_path) -> None:
    declared = {p.name: p.default for p in WATCHDOG_PARAMETERS}
    # every option is a watchdog parameter and a DriftMonitor argument of the same name
    assert set(MONITOR_PARAMETERS) <= set(declared)
    assert set(MONITOR_PARAMETERS) <= set(inspect.signature(DriftMonitor).parameters)
    assert not any(n.startswith('reference.') for n in declared)  # one source: the model file
    nodes = monitor_from_parameters(declared)
    plain = DriftMonitor()
    for name in ('reference', 'tolerances', 'noise_floor', *MONITOR_PARAMETERS):
        assert getattr(nodes, name) == getattr(plain, name), name
    # values reach the monitor (step_fraction too: it was once left out offline)
    other = PAPER_MODEL.with_modal(ModalModel(
        k0=3.0e6, residues=REFERENCE_MODEL.residues,
        natural_frequencies=REFERENCE_MODEL.natural_frequencies,
        damping_ratios=REFERENCE_MODEL.damping_ratios))
    path = save_model(other, tmp_path / 'other.yaml')
    custom = monitor_from_parameters({**declared, 'step_fraction': 0.8, 'n_sigma': 2.0,
                                      'tolerances.omega_1': 0.02, 'model': str(path),
                                      'hardware_id': 'ignored'})
    assert (custom.step_fraction, custom.n_sigma) == (0.8, 2.0)
    assert custom.tolerances['omega_1'] == 0.02
    assert custom.reference.k0 == 3.0e6
    assert custom.reference_name == str(path)
    assert monitor_from_parameters({}).reference == REFERENCE_MODEL  # missing: defaults
    assert monitor_from_parameters({'model': ''}).reference == REFERENCE_MODEL
    with pytest.raises(ConfigurationError, match='no longer read'):
        monitor_from_parameters({'reference.k0': 3.0e6})
    with pytest.raises(InvalidDataError):
        monitor_from_parameters({'model': str(tmp_path / 'missing.yaml')})
    with pytest.raises(ConfigurationError, match='not a number'):
        monitor_from_parameters({'tolerances.k0': 'tight'})
    with pytest.raises(ConfigurationError, match='tolerance'):
        monitor_from_parameters({'tolerances.k0': -1.0})
    with pytest.raises(ConfigurationError, match='unknown'):
        monitor_from_parameters({'tolerances.kappa_1': 0.1})
    # a mode the reference lacks: refused in words (it was ignored without a word)
    with pytest.raises(ConfigurationError, match=r'tolerances.k9 is given, but the reference '
                       r'model .* has 3 mode\(s\): no mode 9 to judge'):
        monitor_from_parameters({'tolerances.k9': 0.1})
    assert monitor_from_parameters({'tolerances.k9': None}).tolerances == plain.tolerances


def test_reference_from_parameters() -> None:
    assert reference_from_parameters({}) == PAPER_MODEL
    assert reference_from_parameters({'model': ''}) == PAPER_MODEL
    with pytest.raises(ConfigurationError, match='must be a file name'):
        reference_from_parameters({'model': 3})
