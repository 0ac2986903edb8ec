"""ROS 2 parameter files (``--params-file``) read strictly, as the nodes would take them.

:func:`load_node_parameters` gives ``galvo-sysid identify`` (``--sysid-params``,
``--watchdog-params``) the values a node would run with; the declared parameters are those of
:mod:`galvo_sysid.monitor.parameters`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from galvo_sysid.errors import ConfigurationError, InvalidDataError, one_line

if TYPE_CHECKING:
    import os

    from galvo_sysid.monitor.parameters import ParamSpec

__all__ = ['load_node_parameters']

_ROS_PARAMETERS = frozenset({'use_sim_time', 'start_type_description_service'})
"""Parameters every ROS 2 node has (not galvo_sysid's; a parameter file may set them)."""

_MAX_NESTING = 8
"""Deepest nesting of parameter names (``a.b.c...``) read from a parameter file."""


def load_node_parameters(path: str | os.PathLike[str], node: str) -> dict[str, Any]:
    """Read a ROS 2 parameter file (``--params-file``) for ``node``; nested names joined by '.'.

    Sections apply as ROS applies them: ``/**`` first, then sections naming the node (with or
    without namespace, e.g. ``sysid`` or ``/scanner_1/sysid``), later ones winning. The file is
    read by :func:`galvo_sysid.schema.load_yaml` (numbers as ROS reads them, no aliases) and
    checked as strictly as the node would take it: a node's section holds ``ros__parameters``
    only; each value has its parameter's declared type (:mod:`galvo_sysid.monitor.parameters`:
    ``10.7`` or ``"abc"`` is no ``window_size``, ``2`` no ``pair_timeout``: ROS refuses an
    integer for a floating-point parameter, write ``2.0``) and lies in its range; a name the
    node does not declare is refused, except, in a ``/**`` section, another galvo node's
    parameters and ROS's own (``use_sim_time``, ``qos_overrides...``). The watchdog's
    tolerances of modes beyond the declared three (``tolerances.k4``, ...) are read too.

    Returns:
        The node's parameters given in the file, by name, as written.

    Raises:
        ConfigurationError: Unreadable file, no section for the node, or a bad section, name
            or value (one line naming the file and the parameter).
    """
    from galvo_sysid.monitor.parameters import NODE_PARAMETERS
    from galvo_sysid.schema import load_yaml

    if node not in NODE_PARAMETERS:
        msg = f'unknown node {node!r}; known: {", ".join(NODE_PARAMETERS)}'
        raise ConfigurationError(msg)
    try:
        doc = load_yaml(path, what='parameter file')
    except InvalidDataError as err:  # missing, not a regular file, not text
        raise ConfigurationError(one_line(err)) from None
    except ConfigurationError as err:  # not valid YAML, an alias, too large
        raise ConfigurationError(f'cannot read parameter file {one_line(err)}') from None
    if not isinstance(doc, Mapping):
        msg = f'parameter file {path} is not a mapping of node names'
        raise ConfigurationError(msg)
    wildcard = [(str(k), v) for k, v in doc.items() if str(k) in {'/**', '**'}]
    named = [(str(k), v) for k, v in doc.items() if str(k).rstrip('/').split('/')[-1] == node]
    if not wildcard and not named:
        msg = f'parameter file {path} has no section for node {node!r} (nor /**)'
        raise ConfigurationError(msg)
    others = {s.name for name, specs in NODE_PARAMETERS.items() if name != node
              for s in specs}
    values: dict[str, Any] = {}
    for key, section in (*wildcard, *named):
        where = f'parameter file {path}: {key}'
        if not isinstance(section, Mapping) or set(section) - {'ros__parameters'}:
            msg = f'{where} must hold ros__parameters only'
            raise ConfigurationError(msg)
        params = section.get('ros__parameters')
        if params is None:
            continue
        for name, value in _flatten(params, where=f'{where}: ros__parameters').items():
            spec = _parameter_spec(node, name)
            if spec is None and node == 'watchdog' and name.startswith('reference.'):
                values[name] = value  # of older versions: reference_from_parameters says so
                continue
            if spec is None:
                if name in _ROS_PARAMETERS or name.startswith('qos_overrides.') or (
                        key in {'/**', '**'} and name in others):
                    continue  # ROS's own, or another node's in a section for all nodes
                msg = f'{where}: {node} has no parameter {_short(repr(name))} (a typo?)'
                raise ConfigurationError(msg)
            why = _parameter_type_error(spec, value) or spec.check(value)
            if why is not None:
                raise ConfigurationError(f'{where}: {_short(why)}')
            values[name] = value
    return values


def _flatten(tree: Any, *, where: str, prefix: str = '', depth: int = 0) -> dict[str, Any]:
    """A parameter file's nested mapping as ``{'a.b': value}`` (keys must be text)."""
    if not isinstance(tree, Mapping):
        msg = f'{where} must be a mapping of parameter names, got {type(tree).__name__}'
        raise ConfigurationError(msg)
    if depth > _MAX_NESTING:
        msg = f'{where}: parameter names nested deeper than {_MAX_NESTING}'
        raise ConfigurationError(msg)
    out: dict[str, Any] = {}
    for key, value in tree.items():
        if not isinstance(key, str):
            msg = f'{where}: parameter name {_short(repr(key))} is not text'
            raise ConfigurationError(msg)
        name = f'{prefix}{key}'
        if isinstance(value, Mapping):
            out.update(_flatten(value, where=where, prefix=f'{name}.', depth=depth + 1))
        else:
            out[name] = value
    return out


def _parameter_spec(node: str, name: str) -> ParamSpec | None:
    """The declared parameter ``name`` of ``node`` (the watchdog's tolerances of any mode of a
    model: up to :data:`~galvo_sysid.model.plant.MAX_MODES`), or None."""  # noqa: D205, D209
    from galvo_sysid.model.plant import MAX_MODES
    from galvo_sysid.monitor.parameters import NODE_PARAMETERS, tolerance_specs
    from galvo_sysid.monitor.tolerances import split_parameter_name

    for spec in NODE_PARAMETERS[node]:
        if spec.name == name:
            return spec
    if node == 'watchdog' and name.startswith('tolerances.'):
        split = split_parameter_name(name.split('.', 1)[1])
        if split is not None and 1 <= split[1] <= MAX_MODES:
            found = [s for s in tolerance_specs(split[1], first_mode=split[1]) if s.name == name]
            return found[0] if found else None
    return None


def _parameter_type_error(spec: ParamSpec, value: Any) -> str | None:
    """Why ``value`` does not have the type ROS gives ``spec`` (its default's), or None."""
    default = spec.default

    def kind(v: Any, *, article: bool = True) -> str:
        text = {bool: 'a boolean', int: 'an integer', float: 'a floating-point number',
                str: 'text', list: 'a list', type(None): 'null'}.get(type(v), type(v).__name__)
        return text if article else text.split(' ', 1)[-1]

    def number(v: Any) -> bool:
        return isinstance(v, int | float) and not isinstance(v, bool)

    if default is None:  # an optional number: dynamically typed
        ok = value is None or number(value)
        need = 'a number (or null: not set)'
    elif isinstance(default, list):
        item = type(default[0]) if default else float
        ok = isinstance(value, list) and all(type(v) is item for v in value)
        need = f'a list of {kind(item(), article=False)}s'
    else:
        ok = type(value) is type(default)
        need = kind(default)
        if isinstance(default, float) and type(value) is int:
            need += f' (ROS refuses an integer here: write {value}.0)'
    if ok:
        return None
    got = 'null' if value is None else f'{kind(value)} {_short(repr(value))}'
    return f'{spec.name} must be {need}, got {got}'


def _short(text: str, limit: int = 200) -> str:
    """``text`` cut to ``limit`` characters (a value quoted in an error line)."""
    return text if len(text) <= limit else f'{text[:limit - 3]}...'
