"""tools/test_durations.py and the order `make test` hands modules out in (test/conftest.py)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path
from types import ModuleType, SimpleNamespace
from typing import Any

import pytest

REPORT = """<?xml version="1.0" encoding="utf-8"?>
<testsuites><testsuite name="pytest" tests="4">
<testcase classname="test.ident.test_delay" name="test_a" time="1.25"/>
<testcase classname="test.ident.test_delay" name="test_b[x]" time="0.5"/>
<testcase classname="test.ident.test_refine.TestGroup" name="test_c" time="3.0"/>
<testcase classname="test.test_lint" name="test_mypy" time="2.0"/>
</testsuite></testsuites>
"""


@pytest.fixture
def conftest(pytestconfig: pytest.Config) -> ModuleType:
    """test/conftest.py as pytest loaded it (``import conftest`` may give another directory's
    conftest module: each is imported under that name)."""
    path = str(Path(__file__).with_name('conftest.py'))
    for plugin in pytestconfig.pluginmanager.get_plugins():
        if isinstance(plugin, ModuleType) and getattr(plugin, '__file__', None) == path:
            return plugin
    raise AssertionError(f'{path} is not loaded')


def _tool(repo: Path) -> ModuleType:
    spec = importlib.util.spec_from_file_location('test_durations_tool_under_test',
                                                  repo / 'tools' / 'test_durations.py')
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_tool_sums_each_modules_tests_longest_first(repo: Path, tmp_path: Path,
                                                         capsys) -> None:
    tool = _tool(repo)
    (tmp_path / 'junit.xml').write_text(REPORT, encoding='utf-8')
    out = tmp_path / 'durations.json'
    assert tool.main([str(tmp_path / 'junit.xml'), '--out', str(out)]) == 0
    written = json.loads(out.read_text(encoding='utf-8'))
    assert list(written.items()) == [('test/ident/test_refine.py', 3.0),
                                     ('test/test_lint.py', 2.0),
                                     ('test/ident/test_delay.py', 1.8)]
    assert '3 modules, 7 s' in capsys.readouterr().out


def test_the_tool_refuses_a_missing_or_empty_report(repo: Path, tmp_path: Path,
                                                     capsys) -> None:
    tool = _tool(repo)
    out = tmp_path / 'durations.json'
    assert tool.main([str(tmp_path / 'none.xml'), '--out', str(out)]) == 1
    (tmp_path / 'empty.xml').write_text('<testsuites/>', encoding='utf-8')
    assert tool.main([str(tmp_path / 'empty.xml'), '--out', str(out)]) == 1
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith('error: cannot read')
    assert err[1].endswith('has no test cases')
    assert not out.exists()


def test_the_committed_durations_name_existing_modules(repo: Path) -> None:
    """A renamed or removed module's entry would only mislead the order: none is left."""
    listed = json.loads((repo / 'test' / 'durations.json').read_text(encoding='utf-8'))
    assert [m for m in listed if not (repo / m).is_file()] == []
    assert all(isinstance(s, (int, float)) and s >= 0 for s in listed.values())


class _Config:
    """What the scheduler reads of pytest's config: two local workers."""

    option = SimpleNamespace(loadscopereorder=True)

    def __init__(self, dist: str = 'loadscope') -> None:
        self.dist = dist

    def getvalue(self, name: str) -> Any:
        assert name in ('tx', 'dist')
        return ['2*popen'] if name == 'tx' else self.dist


class _Node:
    """A worker that records the tests it is sent."""

    shutting_down = False

    def __init__(self, name: str) -> None:
        self.gateway = SimpleNamespace(id=name)
        self.sent: list[list[int]] = []

    def send_runtest_some(self, indices: list[int]) -> None:
        self.sent.append(indices)

    def shutdown(self) -> None:
        self.shutting_down = True


def test_the_shared_unit_holds_every_module_that_uses_the_cached_analyses(
        conftest: ModuleType) -> None:
    """A new module calling ``discrepancy_cases.analysed`` belongs in ``_SHARING``: on the
    other worker it would run its analyses again."""
    folder = conftest.REPO / 'test' / 'discrepancy'
    users = {f'test/discrepancy/{p.name}' for p in folder.glob('test_*.py')
             if 'analysed(' in p.read_text(encoding='utf-8')}
    assert users == set(conftest._SHARING)


def test_the_shared_analyses_are_one_unit(conftest: ModuleType) -> None:
    for module in conftest._SHARING:
        assert (conftest.REPO / module).is_file()
        assert conftest._scope(f'{module}::test_x[a]') == conftest._SHARED_ANALYSES
    assert conftest._scope('test/ident/test_delay.py::test_a') == 'test/ident/test_delay.py'
    seconds = conftest._seconds()
    listed = json.loads((conftest.REPO / 'test' / 'durations.json').read_text(encoding='utf-8'))
    assert seconds[conftest._SHARED_ANALYSES] == pytest.approx(
        sum(listed.get(m, 0.0) for m in conftest._SHARING))
    assert not set(seconds) & conftest._SHARING


def test_the_scheduler_hands_out_the_longest_unit_first(conftest: ModuleType) -> None:
    """Two workers, four units: each worker's first unit is one of the two longest (by
    durations.json, not xdist's own order, most tests first), the shared discrepancy modules
    go to one worker as one unit, and a module the file does not list comes last."""
    collection = [*(f'test/zz/test_unlisted.py::test_{i}' for i in range(4)),   # 0 s
                  *(f'test/test_lint.py::test_{i}' for i in range(3)),          # about 25 s
                  'test/cli/test_cli.py::test_a',                               # about 100 s
                  'test/discrepancy/test_localise.py::test_where_the_gap_is',
                  'test/discrepancy/test_candidates.py::test_x[1]']  # with localise: ~120 s
    assert conftest.pytest_xdist_make_scheduler(_Config('load'), None) is None
    sched = conftest.pytest_xdist_make_scheduler(_Config(), None)
    nodes = [_Node('gw0'), _Node('gw1')]
    for node in nodes:
        sched.add_node(node)
        sched.add_node_collection(node, collection)
    sched.schedule()
    first = {collection[node.sent[0][0]].split('::')[0] for node in nodes}
    assert first == {'test/cli/test_cli.py', 'test/discrepancy/test_localise.py'}
    shared = next(node for node in nodes
                  if collection[node.sent[0][0]].startswith('test/discrepancy'))
    assert sorted(shared.sent[0]) == [8, 9]
    # the two others follow as the workers run low, the longer first
    rest = [i for node in nodes for batch in node.sent[1:] for i in batch]
    assert rest == [4, 5, 6, 0, 1, 2, 3]


def test_the_suite_collects_without_xdist() -> None:
    """``pytest -p no:xdist`` (one process, e.g. to debug a test) loads test/conftest.py:
    its xdist hook is optional (an unknown hook stopped the run with an internal error)."""
    import subprocess
    import sys

    here = Path(__file__)
    proc = subprocess.run(
        [sys.executable, '-m', 'pytest', '-p', 'no:xdist', '-p', 'no:cacheprovider',
         '--collect-only', '-q', str(here)],
        cwd=here.parents[1], capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert 'test_the_suite_collects_without_xdist' in proc.stdout
