"""The watchdog's reference model and drift monitor from its parameters, by name.

One definition used by the watchdog node and by ``galvo-sysid identify --watchdog-params``:
:func:`reference_from_parameters` reads the reference model (the plant-model file of
parameter ``model``), :func:`monitor_from_parameters` builds the
:class:`~galvo_sysid.monitor.drift.DriftMonitor` of the tolerances ``tolerances.<name>`` /
``tolerances.<kind>`` (the rule: :mod:`galvo_sysid.monitor.tolerances`) and the options of
:data:`~galvo_sysid.monitor.parameters.MONITOR_PARAMETERS`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model import PlantModel, load_model, model_label
from galvo_sysid.monitor.drift import DriftMonitor
from galvo_sysid.monitor.parameters import MONITOR_PARAMETERS
from galvo_sysid.monitor.tolerances import KINDS, split_parameter_name

if TYPE_CHECKING:
    from collections.abc import Mapping

__all__ = ['monitor_from_parameters', 'reference_from_parameters']


def reference_from_parameters(values: Mapping[str, Any]) -> PlantModel:
    """The reference model from watchdog parameters: the model file ``model`` ('' or missing:
    the packaged model of the paper's scanner).

    Raises:
        ConfigurationError: The file is not a valid plant model, or the parameters still
            hold the ``reference.*`` values of older versions (the model file replaced them).
        InvalidDataError: The file cannot be read.
    """  # noqa: D205
    old = sorted(k for k in values if k.startswith('reference.'))
    if old:
        raise ConfigurationError(
            f'watchdog parameters {", ".join(old)} are no longer read: the reference is the '
            f'plant-model file of parameter model (e.g. one written by galvo-sysid commission)')
    path = values.get('model') or ''
    if not isinstance(path, str):
        raise ConfigurationError(f'watchdog parameter model must be a file name, got {path!r}')
    return load_model(path or None)


def monitor_from_parameters(values: Mapping[str, Any], *,
                            model: PlantModel | None = None) -> DriftMonitor:
    """The watchdog node's :class:`~galvo_sysid.monitor.drift.DriftMonitor` from its parameters.

    The reference model (the file of ``model``, see :func:`reference_from_parameters`), the
    tolerances ``tolerances.<name>`` and ``tolerances.<kind>`` given (the rule of
    :mod:`galvo_sysid.monitor.tolerances`; None means not given; a tolerance of a mode the
    reference lacks is refused: it would judge nothing, and says that the parameters were
    written for another scanner), and the options of
    :data:`~galvo_sysid.monitor.parameters.MONITOR_PARAMETERS`; other names are ignored and
    missing ones take the monitor's defaults (the node's).

    Args:
        values: Parameter values by name.
        model: The reference model already read from the file of ``values['model']`` (saves
            reading it again); None reads it.

    Raises:
        ConfigurationError: A value is not a number or out of range, an unknown tolerance
            name, a tolerance of a mode the reference lacks, or a bad model file.
        InvalidDataError: The model file cannot be read.
    """
    reference = reference_from_parameters(values) if model is None else model
    tolerances: dict[str, float] = {}
    for key, value in values.items():
        if not key.startswith('tolerances.') or value is None:
            continue
        name = key.split('.', 1)[1]
        split = split_parameter_name(name)
        if name not in KINDS and split is None:
            raise ConfigurationError(
                f'unknown watchdog parameter {key}: tolerances are named tolerances.k0, '
                f'tolerances.<kind> (k, omega, zeta) or tolerances.<parameter> (k1, omega_2, '
                f'zeta_3, ...)')
        if split is not None and split[1] > reference.n_modes:
            raise ConfigurationError(
                f'{key} is given, but the reference model '
                f'{model_label(values.get("model") or None)} has {reference.n_modes} mode(s): '
                f"no mode {split[1]} to judge (remove the tolerance, or give this scanner's "
                f'model file)')
        if isinstance(value, bool) or not isinstance(value, int | float | str):
            raise ConfigurationError(f'bad watchdog parameter {key}: not a number: {value!r}')
        try:
            tolerances[name] = float(value)
        except ValueError:
            raise ConfigurationError(f'bad watchdog parameter {key}: not a number: '
                                     f'{value!r}') from None
    options = {k: values[k] for k in MONITOR_PARAMETERS if k in values}
    return DriftMonitor(reference=reference.modal, tolerances=tolerances,
                        reference_name=model_label(values.get('model') or None), **options)
