"""The folders are the architecture: imports only go down the layers, rclpy only at the top.

DEVELOPERS.md lists the subpackages in this order; a module may import its own subpackage and
the layers below it, never one above (function-level and type-only imports included).

Each name lives in one module and is imported from there: a module exports (``__all__``) only
what it defines, and ``from galvo_sysid.<module> import name`` names the module defining it
(a subpackage's ``__init__`` may gather its public API).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / 'galvo_sysid'

LAYERS = {
    'errors': 0, 'jsonsafe': 0, 'filters': 1, 'schema': 1, 'model': 2, 'ident': 3, 'sim': 3,
    'monitor': 4, 'interfaces': 5, 'field': 6, 'discrepancy': 7, 'cli': 8, 'nodes': 8,
}
"""Rank of each subpackage (and top-level module); equal ranks do not import each other."""

ROS_MODULES = ('rclpy', 'galvo_sysid_msgs', 'diagnostic_msgs', 'std_msgs', 'builtin_interfaces',
               'rcl_interfaces')
ROS_ALLOWED = ('nodes/', 'field/live/', 'field/demo.py')
"""Where ROS client code may be imported (the numerics never import it)."""


def _imports(path: Path) -> list[str]:
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'))):
        if isinstance(node, ast.Import):
            out.extend(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.append(node.module)
    return out


def _modules() -> list[Path]:
    return sorted(p for p in PACKAGE.rglob('*.py') if p.parent != PACKAGE
                  or p.name != '__init__.py')


def _layer(path: Path) -> str:
    rel = path.relative_to(PACKAGE)
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


def test_every_subpackage_has_a_layer() -> None:
    assert {_layer(p) for p in _modules()} <= set(LAYERS)


def _upward(path: Path) -> list[str]:
    own = _layer(path)
    out = []
    for name in _imports(path):
        parts = name.split('.')
        if parts[0] != 'galvo_sysid' or len(parts) < 2:
            continue
        target = parts[1]
        if target in LAYERS and target != own and LAYERS[target] >= LAYERS[own]:
            out.append(name)
    return out


def test_imports_go_down() -> None:
    bad = {str(p.relative_to(PACKAGE)): up for p in _modules() if (up := _upward(p))}
    assert not bad, f'imports upward: {bad}'


def test_ros_only_in_the_ros_layer() -> None:
    bad = {}
    for path in _modules():
        rel = path.relative_to(PACKAGE).as_posix()
        ros = [n for n in _imports(path) if n.split('.')[0] in ROS_MODULES]
        if ros and not rel.startswith(ROS_ALLOWED):
            bad[rel] = ros
    assert not bad, f'ROS imported outside nodes/ and field/live/: {bad}'


def test_the_check_sees_an_upward_import(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # function-level and type-only imports count: a model module importing the CLI is caught
    pkg = tmp_path / 'galvo_sysid'
    (pkg / 'model').mkdir(parents=True)
    src = pkg / 'model' / 'm.py'
    src.write_text('from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n'
                   '    from galvo_sysid.cli.main import main\n'
                   'def f():\n    import rclpy\n', encoding='utf-8')
    monkeypatch.setitem(globals(), 'PACKAGE', pkg)
    assert _upward(src) == ['galvo_sysid.cli.main']
    with pytest.raises(AssertionError, match=r'model/m\.py'):
        test_ros_only_in_the_ros_layer()


REPO = PACKAGE.parent
IMPORTERS = ('galvo_sysid', 'test', 'benchmarks', 'tools')
"""The folders whose imports of galvo_sysid are checked."""


def _defined(path: Path) -> set[str]:
    """The names a module defines at its top level (functions, classes, assignments)."""
    out: set[str] = set()
    for node in ast.parse(path.read_text(encoding='utf-8')).body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            out.add(node.name)
        elif isinstance(node, ast.Assign | ast.AnnAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            out.update(n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name))
    return out


def _exported(path: Path) -> list[str]:
    for node in ast.parse(path.read_text(encoding='utf-8')).body:
        if (isinstance(node, ast.Assign | ast.AnnAssign) and isinstance(node.value, ast.List)
                and any(isinstance(t, ast.Name) and t.id == '__all__'
                        for t in (node.targets if isinstance(node, ast.Assign)
                                  else [node.target]))):
            return [e.value for e in node.value.elts if isinstance(e, ast.Constant)]
    return []


def test_modules_export_only_what_they_define() -> None:
    bad = {}
    for path in sorted(PACKAGE.rglob('*.py')):
        if path.name != '__init__.py':
            other = sorted(set(_exported(path)) - _defined(path))
            if other:
                bad[str(path.relative_to(PACKAGE))] = other
    assert not bad, f're-exported (import them from where they are defined): {bad}'


def test_names_are_imported_from_their_module() -> None:
    bad = []
    defined: dict[Path, set[str]] = {}
    for folder in IMPORTERS:
        for path in sorted((REPO / folder).rglob('*.py')):
            for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'))):
                if not (isinstance(node, ast.ImportFrom) and node.level == 0 and node.module
                        and node.module.startswith('galvo_sysid.')):
                    continue
                module = REPO.joinpath(*node.module.split('.')).with_suffix('.py')
                if not module.is_file():  # a subpackage: its __init__ is its public API
                    continue
                if module not in defined:  # parsed once (setdefault would parse each time)
                    defined[module] = _defined(module)
                names = defined[module]
                bad.extend(f'{path.relative_to(REPO)}:{node.lineno}: {a.name} from '
                           f'{node.module}' for a in node.names if a.name not in names)
    assert not bad, 'not imported from the module defining it: ' + '; '.join(bad)
