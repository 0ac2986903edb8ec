"""galvo_sysid.field.jobs.fork_map: the joint fit's scans shared with forked children."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from galvo_sysid.field.jobs import fork_map

# Run in a fresh interpreter: a thread another test left running in this worker would make
# fork_map (rightly) stay in one process.
_SCRIPT = """
import json, os, sys
from galvo_sysid.field.jobs import fork_map

parent = os.getpid()
out = {}
for processes in (2, 3):
    out[f'ok{processes}'] = fork_map(lambda x: (x * x, os.getpid()), list(range(7)),
                                     processes=processes)

def fails_in_children(x):
    if os.getpid() != parent:
        raise RuntimeError('child')
    return (x + 1, os.getpid())

out['child_fails'] = fork_map(fails_in_children, list(range(5)))

def dies_in_children(x):
    if os.getpid() != parent:
        os._exit(3)
    return (-x, os.getpid())

out['child_dies'] = fork_map(dies_in_children, list(range(4)))
try:
    fork_map(lambda x: 1 / (x - 2), [0, 1, 2, 3])
except ZeroDivisionError:
    out['raised'] = True
children = set()
for task in os.listdir(f'/proc/{parent}/task'):
    with open(f'/proc/{parent}/task/{task}/children') as f:
        children |= set(f.read().split())
out['children_left'] = sorted(children)
out['parent'] = parent
print(json.dumps(out))
"""


def test_fork_map_is_a_map_shared_with_children_that_fail_safe() -> None:
    """The results of a plain map, in order, made in 2 and 3 processes; a child that raises
    or dies has its share made here; an error of ``fn`` is raised here; no child is left."""
    proc = subprocess.run([sys.executable, '-c', _SCRIPT], capture_output=True, text=True,
                          timeout=120, check=False, cwd=Path(__file__).parents[2])
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    parent = out['parent']
    for processes in (2, 3):
        results = out[f'ok{processes}']
        assert [r[0] for r in results] == [x * x for x in range(7)]
        pids = [r[1] for r in results]
        assert pids[0] == parent
        assert len(set(pids)) == processes  # each share made in its own process
        assert pids == sorted(pids, key=pids.index)  # contiguous shares, in order
    assert out['child_fails'] == [[x + 1, parent] for x in range(5)]
    assert out['child_dies'] == [[-x, parent] for x in range(4)]
    assert out['raised'] is True
    assert out['children_left'] == []


def test_fork_map_stays_in_this_process_while_another_thread_runs() -> None:
    """A forked child would inherit the other threads' locks held: no fork then."""
    stop = threading.Event()
    thread = threading.Thread(target=stop.wait, daemon=True)
    thread.start()
    try:
        got = fork_map(lambda x: (x, os.getpid()), list(range(6)))
    finally:
        stop.set()
        thread.join()
    assert got == [(x, os.getpid()) for x in range(6)]


@pytest.mark.parametrize('items', [[], [5]])
def test_fork_map_of_fewer_than_two_items_is_a_loop(items: list[int]) -> None:
    assert fork_map(lambda x: (x, os.getpid()), items) == [(x, os.getpid()) for x in items]
