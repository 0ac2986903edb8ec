"""The plant-model file: one YAML file per scanner, read strictly, written readably.

Layout (version 2; version 1 files, without ``scanner``, ``band`` and the ``*_std`` keys,
are read too)::

    format: galvo_sysid/plant_model
    version: 2
    description: free text (optional)
    sample_period: 1.0e-05            # [s], the DSP period
    scanner:                          # optional: how moves are recorded (simulation defaults)
      record_length: 512              # samples per move's record
      dwell_length: 94                # samples between a record's end and the next move
    mechanics:
      k0: 3564000.0                   # [deg/(A s^2)]
      k0_std: 120.0                   # optional standard deviation (a commissioned model)
      modes:                          # ascending frequency
      - natural_frequency: 71080.0    # [rad/s]
        damping_ratio: 0.006218
        residue: 2069000.0            # [deg/(A s^2)]
        band: [54850.0, 92090.0]      # optional (all modes or none) [rad/s]
        std: {natural_frequency: 3.1, damping_ratio: 2.0e-05, residue: 7000.0}  # optional
    input_dynamics:
      computation_delay: 1            # whole sample periods
      lag_time_constant: 6.0e-06      # [s]
      lag_time_constant_std: 1.0e-08  # optional
      dead_time: 0.0                  # [s]
    effects:                          # see galvo_sysid.model.effects
    - {effect: coulomb_friction, parameters: {friction_current: 0.02}}

Reading is strict (:mod:`galvo_sysid.schema`): unknown keys, wrong types, values out of
range, aliases and files over 1 MB are refused with one line naming the file and the key.
"""

from __future__ import annotations

from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml  # type: ignore[import-untyped]  # PyYAML ships no stubs here

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.model.dynamics import MAX_COMPUTATION_DELAY, InputDynamics
from galvo_sysid.model.effects import MAX_EFFECTS, effects_from_list
from galvo_sysid.model.modal import MAX_DAMPING_RATIO, MAX_MAGNITUDE, ModalModel
from galvo_sysid.model.plant import MAX_MODES, MAX_RECORD_LENGTH, PlantModel
from galvo_sysid.schema import Section, check_number, load_yaml, parse_yaml

if TYPE_CHECKING:
    import os

__all__ = [
    'FORMAT',
    'PACKAGED_LABEL',
    'VERSION',
    'load_model',
    'model_from_dict',
    'model_from_yaml',
    'model_label',
    'model_to_dict',
    'model_to_yaml',
    'packaged_model_path',
    'save_model',
]

FORMAT = 'galvo_sysid/plant_model'
"""Value of the ``format`` key of a plant-model file."""

VERSION = 2
"""Version this galvo_sysid writes (it reads 1 and 2)."""

_V1_SAMPLE_PERIOD = 10e-6  # version 1 files could leave it out: the paper's 10 us
_MODE_KEYS = ('natural_frequency', 'damping_ratio', 'residue')


def packaged_model_path(name: str = 'paper_table1') -> Path:
    """Path of a model file shipped with the package (``paper_table1``: the paper's scanner).

    The same files are installed under ``share/galvo_sysid/models/``.
    """
    return Path(str(resources.files('galvo_sysid.model') / 'data' / f'{name}.yaml'))


def model_to_dict(model: PlantModel) -> dict[str, Any]:
    """The model as plain data (the layout of the module docs)."""
    m, d = model.modal, model.dynamics
    std = model.std_by_name()
    bands = model.bands
    modes = []
    for i, (k, w, z) in enumerate(zip(m.residues, m.natural_frequencies, m.damping_ratios,
                                      strict=True), start=1):
        mode: dict[str, Any] = {'natural_frequency': float(w), 'damping_ratio': float(z),
                                'residue': float(k)}
        if bands is not None:
            mode['band'] = [float(bands[i - 1][0]), float(bands[i - 1][1])]
        names = {'natural_frequency': f'omega_{i}', 'damping_ratio': f'zeta_{i}',
                 'residue': f'k{i}'}
        if any(n in std for n in names.values()):
            mode['std'] = {key: float(std[n]) for key, n in names.items() if n in std}
        modes.append(mode)
    mech: dict[str, Any] = {'k0': float(m.k0)}
    if 'k0' in std:
        mech['k0_std'] = float(std['k0'])
    mech['modes'] = modes
    dyn: dict[str, Any] = {'computation_delay': int(d.computation_delay),
                           'lag_time_constant': float(d.lag_time_constant)}
    if 'lag_time_constant' in std:
        dyn['lag_time_constant_std'] = float(std['lag_time_constant'])
    dyn['dead_time'] = float(d.dead_time)
    out: dict[str, Any] = {'format': FORMAT, 'version': VERSION}
    if model.description:
        out['description'] = model.description
    out.update({
        'sample_period': float(model.sample_period),
        'scanner': {'record_length': model.record_length, 'dwell_length': model.dwell_length},
        'mechanics': mech,
        'input_dynamics': dyn,
        'effects': [e.to_dict() for e in model.effects],
    })
    return out


def model_from_dict(data: Any, *, source: str = 'model') -> PlantModel:
    """Build a model from plain data (the layout of the module docs), strictly.

    Raises:
        ConfigurationError: Wrong layout, unknown or missing keys, bad values (the message
            names ``source`` and the key).
    """
    if not isinstance(data, Mapping):  # e.g. another text file given as the model
        got = 'nothing' if data is None else f'a {type(data).__name__}'
        raise ConfigurationError(f'{source}: not a plant model file (a YAML mapping with '
                                 f'sample_period, mechanics, ... expected; it holds {got})')
    top = Section(data, source)
    fmt = top.data.get('format', FORMAT)
    if fmt != FORMAT:
        raise ConfigurationError(f'{source}: format {fmt!r} is not {FORMAT!r}')
    version = top.data.get('version', 1)
    if version not in (1, 2) or isinstance(version, bool):
        raise ConfigurationError(f'{source}: unsupported version {version!r} (this galvo_sysid '
                                 f'reads versions 1 and 2)')
    v2 = version == 2
    top = Section(data, source, keys=('format', 'version', 'description', 'sample_period',
                                      *(('scanner',) if v2 else ()), 'mechanics',
                                      'input_dynamics', 'effects'))
    t = top.number('sample_period', None if v2 else _V1_SAMPLE_PERIOD, low=1e-8, high=1.0)
    scanner = top.section('scanner', keys=('record_length', 'dwell_length'), optional=True) \
        if v2 else None
    record = scanner.integer('record_length', 512, low=16, high=MAX_RECORD_LENGTH) \
        if scanner is not None else 512
    dwell = scanner.integer('dwell_length', 94, low=0, high=MAX_RECORD_LENGTH) \
        if scanner is not None else 94
    mech_keys = ('k0', 'modes', *(('k0_std',) if v2 else ()))
    mech = top.section('mechanics', keys=mech_keys)
    assert mech is not None
    k0 = mech.number('k0', low=0.0, high=MAX_MAGNITUDE, low_open=True)
    std: dict[str, float] = {}
    if 'k0_std' in mech:
        std['k0'] = mech.number('k0_std', low=0.0)
    residues, freqs, damps, bands = [], [], [], []
    mode_keys = (*_MODE_KEYS, *(('band', 'std') if v2 else ()))
    for i, raw in enumerate(mech.items('modes', max_items=MAX_MODES), start=1):
        mode = Section(raw, f'{mech.where}: modes[{i}]', keys=mode_keys)
        freqs.append(mode.number('natural_frequency', low=0.0, high=1e8, low_open=True))
        damps.append(mode.number('damping_ratio', low=0.0, high=MAX_DAMPING_RATIO,
                                 low_open=True))
        residues.append(mode.number('residue', low=-MAX_MAGNITUDE, high=MAX_MAGNITUDE))
        if 'band' in mode:
            bands.append(_band(mode.data['band'], f'{mode.where}: band'))
        if 'std' in mode:
            s = mode.section('std', keys=_MODE_KEYS)
            assert s is not None
            for key, name in (('residue', f'k{i}'), ('natural_frequency', f'omega_{i}'),
                              ('damping_ratio', f'zeta_{i}')):
                if key in s:
                    std[name] = s.number(key, low=0.0)
    if bands and len(bands) != len(freqs):
        raise ConfigurationError(f'{mech.where}: give a band for every mode or for none')
    dyn = top.section('input_dynamics', optional=True,
                      keys=('computation_delay', 'lag_time_constant', 'dead_time',
                            *(('lag_time_constant_std',) if v2 else ())))
    if dyn is None:
        dyn = Section({}, f'{source}: input_dynamics')
    delay = dyn.integer('computation_delay', 1, low=0, high=MAX_COMPUTATION_DELAY)
    lag = dyn.number('lag_time_constant', 0.6 * t, low=0.0, high=1000 * t)
    dead = dyn.number('dead_time', 0.0, low=0.0, high=1000 * t)
    if 'lag_time_constant_std' in dyn:
        std['lag_time_constant'] = dyn.number('lag_time_constant_std', low=0.0)
    description = top.text('description', '')
    try:
        modal = ModalModel(k0=k0, residues=tuple(residues), natural_frequencies=tuple(freqs),
                           damping_ratios=tuple(damps))
        effects = effects_from_list(top.items('effects', max_items=MAX_EFFECTS),
                                    where=f'{source}: effects')
        return PlantModel(modal=modal, dynamics=InputDynamics(
            computation_delay=delay, lag_time_constant=lag, dead_time=dead),
            sample_period=t, effects=effects, description=description,
            bands=tuple(bands) if bands else None, uncertainty=tuple(std.items()),
            record_length=record, dwell_length=dwell)
    except ConfigurationError as err:
        text = str(err)
        raise ConfigurationError(text if text.startswith(source) else f'{source}: {text}') \
            from None


def _band(value: Any, where: str) -> tuple[float, float]:
    if not isinstance(value, list) or len(value) != 2:
        raise ConfigurationError(f'{where} must be [low, high] in rad/s, got {value!r}')
    lo = check_number(value[0], f'{where}[0]', low=0.0, high=1e9, low_open=True)
    hi = check_number(value[1], f'{where}[1]', low=lo, high=1e9, low_open=True)
    return lo, hi


_HEADER = """\
# galvo_sysid plant model (layout: galvo_sysid/model/files.py).
# Units: angles deg, currents A, times s, frequencies rad/s, residues and k0 deg/(A s^2).
"""


def model_to_yaml(model: PlantModel) -> str:
    """The model as YAML text (with a short header comment)."""
    body = str(yaml.safe_dump(model_to_dict(model), sort_keys=False, default_flow_style=None,
                              width=100))
    return _HEADER + body


def model_from_yaml(text: str, *, source: str = 'model') -> PlantModel:
    """Parse YAML text into a model.

    Raises:
        ConfigurationError: Not YAML, or not a valid plant model.
    """
    return model_from_dict(parse_yaml(text, source=source), source=source)


def save_model(model: PlantModel, path: str | os.PathLike[str]) -> Path:
    """Write the model as YAML (atomically: a temporary file renamed); return the path."""
    out = Path(path)
    tmp = out.with_name(f'.{out.name}.tmp')
    tmp.write_text(model_to_yaml(model), encoding='utf-8')
    tmp.replace(out)
    return out


PACKAGED_LABEL = 'paper_table1 (packaged)'


def model_label(path: str | os.PathLike[str] | None = None) -> str:
    """How messages name a model file: the path, or ``'paper_table1 (packaged)'`` for None/''."""
    return PACKAGED_LABEL if path is None or str(path) == '' else str(path)


def load_model(path: str | os.PathLike[str] | None = None) -> PlantModel:
    """Read a model file (None or '': the packaged model of the paper's scanner).

    Raises:
        InvalidDataError: The file cannot be read.
        ConfigurationError: It is not a valid plant model.
    """
    p = packaged_model_path() if path is None or str(path) == '' else Path(path)
    return model_from_dict(load_yaml(p, what='plant model'), source=str(p))
